"""Parity with Adobe's render: every capture of the reference folder through
our default pipeline, compared with the Adobe DNG SDK's final render.

The reference (``../shared/data/raw/reference/adobe_dng_sdk_1.7.1/``, its
README and ``index.json``) holds ``dng_validate -cs1 -16`` renders of real
DNGs nobody here made: a GoPro HERO6 and a FUSION capture (12 and 9 MP,
downscaled ×½ with ``INTER_AREA`` on the 16-bit sRGB values, then rounded to
8 bit), the Canon 550D chart and the LG G4 linear DNG (full size, 8 bit).
Each file is read and run through ``Pipeline.default(look)`` without the
correction (no lens profile matches these cameras) up to the display image;
the orientation is applied, the result rounded to 16 bit, downscaled as the
reference was, rounded to 8 bit, and compared with Adobe's image:

* CIEDE2000 (CIE 142-2001; colour-science's ``delta_E_CIE2000``) between
  the two in CIELAB (sRGB decoded, D65 white), mean and 95th percentile,
  over the pixels unclipped in both (every channel in 1..254);
* mean L* of each, and the "colour only" difference: CIEDE2000 with our
  L* replaced by Adobe's, pixel by pixel;
* the mean CIELAB chroma C*ab where Adobe's render is near white (every
  channel above 0.95), ours beside Adobe's: clipped highlights must render
  neutral.

Targets (issue "render as Adobe's DNG SDK does"): mean ΔE00 ≤ 1.0 and p95
≤ 3.0 per file for the default ``adobe`` look, near-white chroma ≤ 3 on
both GoPro files. The ``linear`` look (scene-referred, no tone curve) is
measured too, for scale: it is not meant to match.

Usage: python -m benchmarks.adobe_parity [--looks adobe linear] [--files NAME ...]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import json  # noqa: E402

import numpy as np  # noqa: E402

RAW = _harness.ROOT.parent / "shared" / "data" / "raw"
REFERENCE = RAW / "reference" / "adobe_dng_sdk_1.7.1"
#: Adobe's render counts as near white where every channel exceeds this
NEAR_WHITE = 0.95
#: the targets: per-file mean and 95th-percentile CIEDE2000, near-white chroma
TARGETS = {"mean_de00": 1.0, "p95_de00": 3.0, "near_white_chroma": 3.0}
#: the files whose near-white chroma has a target (the GoPro captures)
CHROMA_FILES = ("gopro_HERO6_GOPR0024", "gopro_FUSION_GPFR7066")


def reference_index() -> dict:
    """``index.json`` of the reference folder ({} when the data is absent)."""
    path = REFERENCE / "index.json"
    return json.loads(path.read_text()) if path.is_file() else {}


def render(name: str, look: str = "adobe") -> np.ndarray:
    """``RAW/name.dng`` through ``Pipeline.default(look)`` (no correction,
    no encoding): the display image, upright, (H, W, 3) float32 in [0, 1]."""
    from isp import Pipeline
    from isp.io.read import read_raw
    from modules.common.encoding import apply_orientation

    pipeline = Pipeline.default(look, correction={"model": "none"})
    pipeline = Pipeline([s for s in pipeline.stages if s.name not in ("jpeg", "png", "tiff")])
    frame = read_raw(RAW / f"{name}.dng")
    out = pipeline.run(frame)
    return np.clip(apply_orientation(np.asarray(out.data), frame.meta.orientation), 0.0, 1.0)


def at_reference_scale(img: np.ndarray, shape) -> np.ndarray:
    """``img`` made as the reference was: rounded to 16 bit, ``INTER_AREA``
    down to ``shape`` when smaller, rounded to 8 bit (uint8)."""
    import cv2

    u16 = np.round(np.asarray(img, np.float64) * 65535.0).astype(np.uint16)
    if u16.shape[:2] != tuple(shape[:2]):
        u16 = cv2.resize(u16, (int(shape[1]), int(shape[0])), interpolation=cv2.INTER_AREA)
    return np.round(u16 / 257.0).astype(np.uint8)


def adobe_render(name: str) -> np.ndarray:
    """Adobe's render of ``name``: (H, W, 3) uint8 sRGB, RGB order."""
    import cv2

    entry = reference_index()[name]
    return cv2.imread(str(REFERENCE / entry["render_srgb8"]), cv2.IMREAD_COLOR)[..., ::-1]


def srgb8_to_lab(img: np.ndarray) -> np.ndarray:
    """CIELAB (D65) of 8-bit sRGB."""
    import colour

    d65 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    return colour.XYZ_to_Lab(colour.sRGB_to_XYZ(np.asarray(img, np.float64) / 255.0), d65)


def compare(ours: np.ndarray, adobe: np.ndarray) -> dict:
    """The figures of the module docstring for two 8-bit sRGB images of one shape."""
    from colour.difference import delta_E_CIE2000

    if ours.shape != adobe.shape:
        raise ValueError(f"shapes differ: ours {ours.shape}, Adobe's {adobe.shape}")
    unclipped = np.all((ours > 0) & (ours < 255) & (adobe > 0) & (adobe < 255), axis=-1)
    lab_o, lab_a = srgb8_to_lab(ours), srgb8_to_lab(adobe)
    o, a = lab_o[unclipped], lab_a[unclipped]
    de = delta_E_CIE2000(o, a)
    matched = o.copy()
    matched[:, 0] = a[:, 0]
    out = {"pixels": int(unclipped.size), "unclipped_fraction": float(unclipped.mean()),
           "mean_de00": float(de.mean()), "p95_de00": float(np.percentile(de, 95)),
           "max_de00": float(de.max()),
           "mean_L_ours": float(o[:, 0].mean()), "mean_L_adobe": float(a[:, 0].mean()),
           "colour_only_de00": float(delta_E_CIE2000(matched, a).mean())}
    white = np.all(adobe / 255.0 > NEAR_WHITE, axis=-1)
    out["near_white_fraction"] = float(white.mean())
    if white.any():
        out["near_white_chroma"] = float(np.hypot(lab_o[white, 1], lab_o[white, 2]).mean())
        out["adobe_near_white_chroma"] = float(np.hypot(lab_a[white, 1], lab_a[white, 2]).mean())
    return out


def parity(name: str, look: str = "adobe") -> dict:
    """:func:`compare` of our ``look`` against Adobe's render of ``name``."""
    adobe = adobe_render(name)
    return compare(at_reference_scale(render(name, look), adobe.shape), adobe)


def meets_targets(name: str, figures: dict) -> bool:
    """Whether one file's figures meet :data:`TARGETS`."""
    ok = figures["mean_de00"] <= TARGETS["mean_de00"] and figures["p95_de00"] <= TARGETS["p95_de00"]
    if name in CHROMA_FILES and "near_white_chroma" in figures:
        ok = ok and figures["near_white_chroma"] <= TARGETS["near_white_chroma"]
    return ok


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--looks", nargs="+", default=["adobe", "linear"], choices=["adobe", "linear"])
    ap.add_argument("--files", nargs="+", help="reference names (default: every file in index.json)")
    args = ap.parse_args(argv)
    index = reference_index()
    if not index:
        raise SystemExit(f"no reference renders at {REFERENCE} (the shared data is absent)")
    names = args.files or list(index)
    results: dict = {look: {} for look in args.looks}
    print(f"{'look':<7s} {'file':<22s} {'ΔE00 mean':>9s} {'p95':>6s} {'L* ours':>8s} {'Adobe':>6s} "
          f"{'colour':>7s} {'white C*':>9s} {'Adobe':>6s}  target")
    for look in args.looks:
        for name in names:
            f = parity(name, look)
            results[look][name] = f
            ok = meets_targets(name, f) if look == "adobe" else None
            chroma = (f"{f['near_white_chroma']:9.2f} {f['adobe_near_white_chroma']:6.2f}"
                      if "near_white_chroma" in f else f"{'-':>9s} {'-':>6s}")
            print(f"{look:<7s} {name:<22s} {f['mean_de00']:9.2f} {f['p95_de00']:6.2f} "
                  f"{f['mean_L_ours']:8.1f} {f['mean_L_adobe']:6.1f} {f['colour_only_de00']:7.2f} "
                  f"{chroma}  {'' if ok is None else ('met' if ok else 'MISSED')}")
    summary = {"targets": TARGETS, "near_white": NEAR_WHITE}
    if "adobe" in results:
        summary["all_targets_met"] = all(meets_targets(n, f) for n, f in results["adobe"].items())
        summary["worst_mean_de00"] = max(f["mean_de00"] for f in results["adobe"].values())
        summary["worst_p95_de00"] = max(f["p95_de00"] for f in results["adobe"].values())
    return _harness.publish("adobe_parity", {**summary, "looks": results}, args, argv)


if __name__ == "__main__":
    main()

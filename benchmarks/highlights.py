"""Clipped highlights: ``clip`` (neutral by ``dng_render``'s camera-white
clamp) against ``reconstruct`` (inpaint opposed, :mod:`modules.highlights`),
on the real GoPro captures against Adobe's render and on synthetic scenes
whose truth is known.

Real files (``../shared/data/raw/gopro_HERO6_GOPR0024.dng``,
``gopro_FUSION_GPFR7066.dng``): each rendered through the stages before
``correction`` with each look's parameters (no correction: no profile
matches these lenses), then

=====================  ===================================================
``adobe clip``         ``highlights`` (clip) → ``dng_render``: the default
``adobe reconstruct``  ``highlights`` (reconstruct) → ``dng_render``
``adobe unclamped``    ``dng_render`` with ``clip_white = false``, for
                       ``clip`` and ``reconstruct`` (what reconstruction
                       gives where the clamp does not undo it)
``linear``             ``luminance`` → ``ccm`` → ``gamma``, without and
                       with ``reconstruct``
=====================  ===================================================

and compared with Adobe's render (``reference/adobe_dng_sdk_1.7.1/``, made
by ``dng_validate -cs1 -16``, orientation applied, downscaled ×½ with
``INTER_AREA`` on the 16-bit sRGB values as its README says; ours is
downscaled the same way): the mean CIELAB chroma C*ab (D65) of our render
where Adobe's is near white (every channel > 0.95), Adobe's own chroma there
beside it. ``reconstruct`` runs at its default threshold (0.99 of white)
and at 0.95, below the GoPro green's saturation (15583 of the declared
16383).

Synthetic scenes: smooth gradients, luminance 0.25 → 3.0 of white across,
hue down the frame (:data:`SCENES`: grey; a drift from sky blue to warm,
saturation 0.3; the whole hue circle, saturation 0.35, where the colour
round a clipped area changes fastest), balanced camera RGB as truth; to raw
through a non-neutral white (camera neutral 0.5, 1, 0.65), clipped at white,
sampled on an RGGB mosaic, then ``white_balance``, ``demosaic``,
``highlights``. Error against the truth: CIEDE2000 with both read as linear
sRGB scaled so the brightest truth is white, mean over the pixels clipped in
one, two and three raw channels; the mean over the unclipped pixels of the
band just below white that the stage may count as clipped (within
``SLACK`` below its threshold, beside a clipped area); and the largest over
the pixels below that band in every raw channel. ``clip`` is scored as ``dng_render`` leaves
it (every channel clamped at the camera white) and as it enters that stage
(pass-through).

Timing: ``reconstruct`` on the HERO6's 12 MP camera-RGB frame, median of
``--runs`` (one warm-up), 2 threads.

Usage: python -m benchmarks.highlights [--runs 3] [--skip-real]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import json  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

RAW = _harness.ROOT.parent / "shared" / "data" / "raw"
REFERENCE = RAW / "reference" / "adobe_dng_sdk_1.7.1"
FILES = ("gopro_HERO6_GOPR0024", "gopro_FUSION_GPFR7066")
#: Adobe's render counts as near white where every channel exceeds this
NEAR_WHITE = 0.95
#: the camera neutral of the synthetic scene (a daylight-like white on a phone sensor)
SYNTH_NEUTRAL = (0.5, 1.0, 0.65)


# --------------------------------------------------------------------------
# colour helpers

def srgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """CIELAB (D65) of sRGB-encoded values in [0, 1]."""
    import colour

    xyz = colour.sRGB_to_XYZ(rgb)
    return colour.XYZ_to_Lab(xyz, colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])


def linear_to_lab(rgb: np.ndarray) -> np.ndarray:
    """CIELAB (D65) of linear sRGB values (not clipped)."""
    import colour

    xyz = colour.RGB_to_XYZ(rgb, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False)
    return colour.XYZ_to_Lab(xyz, colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])


def chroma(lab: np.ndarray) -> np.ndarray:
    """C*ab of CIELAB values."""
    return np.hypot(lab[..., 1], lab[..., 2])


# --------------------------------------------------------------------------
# real files

def camera_frame(path: Path, look: str = "adobe"):
    """The file through every stage of ``look`` before the correction slot
    (camera RGB, balanced)."""
    from isp import Pipeline
    from isp.io.read import read_raw
    from isp.pipeline import LOOK_PARAMS, look_stages

    names = look_stages(look)
    return Pipeline.from_names(names[:names.index("correction")], LOOK_PARAMS[look],
                               start="raw").run(read_raw(path))


def display(frame, names: list[str], overrides: dict) -> np.ndarray:
    """``frame`` (camera RGB) through ``names``: the display image, upright,
    clipped to [0, 1], float32."""
    from isp import Pipeline
    from modules.common.encoding import apply_orientation

    out = Pipeline.from_names(names, overrides, start="camera_rgb").run(frame)
    return np.clip(apply_orientation(out.data, frame.meta.orientation), 0.0, 1.0).astype(np.float32)


def at_reference_scale(img: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``img`` as the reference was made: 16-bit rounding, then ``INTER_AREA``
    down to ``shape`` (when smaller)."""
    import cv2

    u16 = np.round(img * 65535.0).astype(np.uint16)
    if u16.shape[:2] != tuple(shape):
        u16 = cv2.resize(u16, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    return u16.astype(np.float32) / 65535.0


def adobe_render(name: str) -> np.ndarray:
    """Adobe's render of ``name`` as float32 sRGB in [0, 1] (RGB order)."""
    import cv2

    index = json.loads((REFERENCE / "index.json").read_text())
    bgr = cv2.imread(str(REFERENCE / index[name]["render_srgb8"]), cv2.IMREAD_UNCHANGED)
    return bgr[..., ::-1].astype(np.float32) / 255.0


def real_file(name: str, thresholds=(0.99, 0.95)) -> dict:
    """Near-white chroma of each variant on one file (see the module docstring)."""
    ref = adobe_render(name)
    mask = np.all(ref > NEAR_WHITE, axis=2)
    frame = camera_frame(RAW / f"{name}.dng")
    scene = camera_frame(RAW / f"{name}.dng", "linear")
    out = {"near_white_px": int(mask.sum()), "near_white_fraction": float(mask.mean()),
           "adobe_chroma": float(chroma(srgb_to_lab(ref[mask])).mean())}

    def score(img):
        return float(chroma(srgb_to_lab(at_reference_scale(img, ref.shape[:2])[mask])).mean())

    adobe, linear = ["highlights", "dng_render"], ["highlights", "luminance", "ccm", "gamma"]
    clip = display(frame, adobe, {"highlights": {"mode": "clip"}})
    out["adobe_clip"] = score(clip)
    out["adobe_unclamped_clip"] = score(display(frame, adobe, {"dng_render": {"clip_white": False}}))
    out["linear_clip"] = score(display(scene, linear, {}))
    for t in thresholds:
        rec = {"highlights": {"mode": "reconstruct", "threshold": t}}
        img = display(frame, adobe, rec)
        out[f"adobe_reconstruct_{t}"] = score(img)
        out[f"adobe_reconstruct_{t}_max_diff_vs_clip"] = float(np.abs(img - clip).max())
        out[f"adobe_unclamped_reconstruct_{t}"] = score(
            display(frame, adobe, {**rec, "dng_render": {"clip_white": False}}))
        out[f"linear_reconstruct_{t}"] = score(display(scene, linear, rec))
    return out


# --------------------------------------------------------------------------
# synthetic scene

#: the synthetic scenes: hue down the frame (degrees, per row) and saturation
SCENES = {
    "grey": (None, 0.0),
    "sky to warm": ((200.0, 30.0), 0.3),
    "hue circle": ((0.0, 360.0), 0.35),
}


def synthetic_truth(scene: str = "sky to warm", height: int = 192, width: int = 512) -> np.ndarray:
    """(H, W, 3) float32 balanced camera RGB: luminance 0.25 → 3.0 of white
    (log ramp) across; down the frame the hue runs over the scene's range
    (:data:`SCENES`; the mean of the three channels is the luminance)."""
    hues, saturation = SCENES[scene]
    lum = 0.25 * 12.0 ** np.linspace(0.0, 1.0, width)
    if hues is None:
        hue = np.zeros((height, 1))
    else:
        hue = np.deg2rad(np.linspace(hues[0], hues[1], height, endpoint=hues[1] - hues[0] < 360))[:, None]
    tint = 1.0 + saturation * np.stack([np.cos(hue), np.cos(hue - 2 * np.pi / 3),
                                        np.cos(hue + 2 * np.pi / 3)], axis=-1)
    return (tint * lum[None, :, None]).astype(np.float32)


def synthetic_capture(truth: np.ndarray, neutral=SYNTH_NEUTRAL, cfa: str = "RGGB", meta=None):
    """A raw_linear mosaic frame of ``truth`` (balanced camera RGB) seen
    through camera neutral ``neutral``, clipped at white; and the raw
    clip mask (H, W, 3) of the truth."""
    from isp import CFA, CameraMeta, Domain, Frame

    raw = truth * np.asarray(neutral, np.float32)
    clipped = raw >= 1.0
    pattern = CFA.parse(cfa).pattern
    h, w, _ = raw.shape
    mosaic = np.empty((h, w), np.float32)
    for i in range(2):
        for j in range(2):
            mosaic[i::2, j::2] = np.minimum(raw[i::2, j::2, pattern[i, j]], 1.0)
    meta = (meta or CameraMeta()).replace(cfa=CFA.parse(cfa), as_shot_neutral=tuple(neutral),
                                          raw_size=(h, w))
    return Frame(mosaic, Domain.RAW_LINEAR, meta), clipped


def delta_e(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """CIEDE2000 between linear-sRGB images."""
    import colour

    return colour.delta_E(linear_to_lab(a), linear_to_lab(b), method="CIE 2000")


def synthetic(scene: str) -> dict:
    """CIEDE2000 of each variant against the truth on one synthetic scene."""
    from isp import create_stage

    truth = synthetic_truth(scene)
    frame, clipped = synthetic_capture(truth)
    cam = create_stage("demosaic")(create_stage("white_balance")(frame))
    n = np.asarray(cam.neutral)
    clamp = np.float32((1.0 / n).min())            # the camera white, balanced: the lowest level
    variants = {
        "clip (dng_render clamp)": np.minimum(cam.data, clamp),
        "clip (pass-through)": cam.data,
        "reconstruct": create_stage("highlights", mode="reconstruct")(cam).data,
    }
    k = clipped.sum(axis=2)
    regions = {"1": k == 1, "2": k == 2, "3": k == 3}
    # below where the stage may count a channel as clipped, in every raw channel
    from modules.highlights import SLACK, Highlights

    below = Highlights().threshold * (1.0 - SLACK)
    far = np.all(truth * np.asarray(SYNTH_NEUTRAL, np.float32) < below, axis=2)
    band = (k == 0) & ~far
    # keep off the frame border, where demosaic differs from the interior
    inner = np.zeros(k.shape, bool)
    inner[4:-4, 4:-4] = True
    scale = 1.0 / float(truth.max())
    out = {"pixels": {**{r: int((m & inner).sum()) for r, m in regions.items()}, "band": int((band & inner).sum())}}
    for label, img in variants.items():
        de = delta_e(img * scale, truth * scale)
        row = {f"de00_clipped_{r}": float(de[m & inner].mean()) for r, m in regions.items()}
        row["de00_band"] = float(de[band & inner].mean())
        row["de00_unclipped_max"] = float(de[far & inner].max())
        out[label] = row
    return out


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--skip-real", action="store_true", help="only the synthetic scene")
    args = ap.parse_args(argv)

    results = {"synthetic": {scene: synthetic(scene) for scene in SCENES}}
    print("synthetic scenes: mean CIEDE2000 against the truth, by how many raw channels clipped")
    print(f"  {'scene':<12s} {'variant':<26s} {'1':>7s} {'2':>7s} {'3':>7s} {'band':>7s} {'below max':>10s}")
    for scene, rows in results["synthetic"].items():
        for label, row in rows.items():
            if label == "pixels":
                continue
            print(f"  {scene:<12s} {label:<26s} {row['de00_clipped_1']:7.2f} {row['de00_clipped_2']:7.2f} "
                  f"{row['de00_clipped_3']:7.2f} {row['de00_band']:7.2f} {row['de00_unclipped_max']:10.2g}")

    missing = [f for f in FILES if not (RAW / f"{f}.dng").exists()] + \
        ([] if (REFERENCE / "index.json").exists() else ["reference/adobe_dng_sdk_1.7.1"])
    if args.skip_real or missing:
        if missing:
            print(f"real files skipped: {', '.join(missing)} absent from {RAW}")
        return _harness.publish("highlights", results, args, argv)

    from modules.highlights import Highlights

    print("real files: mean C*ab where Adobe's render is near white (every channel > 0.95)")
    results["real"] = {}
    for name in FILES:
        row = real_file(name)
        results["real"][name] = row
        print(f"  {name}: {row['near_white_px']} px ({100 * row['near_white_fraction']:.2f} %), "
              f"Adobe {row['adobe_chroma']:.2f}")
        for k, v in row.items():
            if k.startswith(("adobe_", "linear_")) and k != "adobe_chroma":
                print(f"    {k:<45s} {v:8.3f}")

    frame = camera_frame(RAW / f"{FILES[0]}.dng")
    for t in (0.99, 0.95):
        stage = Highlights(mode="reconstruct", threshold=t)
        timing = _harness.measure(lambda: stage(frame), runs=args.runs)
        results[f"reconstruct_{t}_12mp_s"] = timing.as_dict(4)
        print(f"reconstruct (threshold {t}) on {frame.data.shape[1]}x{frame.data.shape[0]}: {timing}")
    return _harness.publish("highlights", results, args, argv)


if __name__ == "__main__":
    main()

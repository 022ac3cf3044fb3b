"""Seams: the tiled correction against the whole frame, on a photograph.

The correction stage's tiles must leave no seam: at most 1 DN at 8 bits
against an untiled run. This runs
:class:`modules.correction.Correction` on a Kodak photograph (kodim07 from
``../shared/data/latent``, resized to 2100 × 1500, taken to linear light by
the sRGB curve at half exposure, plus Gaussian noise of each ``--noise``
σ), once in tiles (``--tile``, 512 px by default: 20 tiles, so that
seams cross every kind of content; the model's own tile leaves a frame
this size one or two) and once whole (``tile_size = 0``, the same
reflected border), and reports the largest difference in DN of the sRGB-encoded
8-bit output (:func:`export.onnx_export.srgb_dn`) and its 99.99th
percentile, for each model at its own ``tile_overlap`` and at each of
``--overlaps``.

Run::

    python -m benchmarks.seams                                  # the packaged model
    python -m benchmarks.seams --model OLD.int8.onnx --overlaps 32 64 96

Last line: a JSON object ``{model: {overlap: {noise: {max_dn, p9999_dn,
max_abs_linear}}}}``.
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

IMAGE = "latent/Kodak24/kodim07.png"


def photograph(data: Path, size=(2100, 1500)) -> np.ndarray:
    """kodim07 as linear camera-like RGB, (H, W, 3) float32 at half exposure."""
    import cv2

    from modules.gamma import srgb_eotf

    path = data / IMAGE
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise SystemExit(f"seams: {path}: not found (the shared data folder is needed)")
    img = cv2.resize(img[:, :, ::-1].astype(np.float32) / 255, size, interpolation=cv2.INTER_CUBIC).clip(0, 1)
    return (0.5 * srgb_eotf(img)).astype(np.float32)


def seam_errors(model, img: np.ndarray, overlap: int | None, tile: int | None = None) -> dict:
    """Tiled (``tile`` px; None: the model's own) against whole-frame output
    of ``model`` on ``img`` (H, W, 3)."""
    from export.onnx_export import srgb_dn
    from isp import CFA, CameraMeta, Domain, Frame
    from modules.correction import Correction

    h, w = img.shape[:2]
    frame = Frame(img, Domain.CAMERA_RGB, CameraMeta(cfa=CFA.RGGB, raw_size=(h, w), active_area=(0, 0, h, w)))
    tiled = Correction(model=model, overlap=overlap, tile_size=tile)(frame).data
    whole = Correction(model=model, overlap=overlap, tile_size=0)(frame).data
    d = np.abs(srgb_dn(tiled) - srgb_dn(whole))
    return {"max_dn": round(float(d.max()), 3), "p9999_dn": round(float(np.quantile(d, 0.9999)), 3),
            "max_abs_linear": round(float(np.abs(tiled - whole).max()), 6)}


def main(argv=None) -> dict:
    from restoration.synth.defaults import DATA

    ap = _harness.parser(__doc__)
    ap.add_argument("--model", nargs="+", default=["default"], help="ONNX files (default: the packaged model)")
    ap.add_argument("--overlaps", type=int, nargs="*", default=[], help="margins to try besides each model's own")
    ap.add_argument("--noise", type=float, nargs="+", default=[0.005, 0.02], help="noise σ (linear)")
    ap.add_argument("--tile", type=int, default=512, help="tile side, context included (px; default 512)")
    args = ap.parse_args(argv)
    base = photograph(DATA)
    rng = np.random.default_rng(0)
    frames = {s: np.clip(base + s * rng.standard_normal(base.shape).astype(np.float32), 0, 1) for s in args.noise}
    out = {}
    for m in args.model:
        from modules.correction import Correction

        own = Correction(model=m).info.overlap
        res = out[m] = {}
        for ov in [None, *args.overlaps]:
            key = f"{own} (its own)" if ov is None else str(ov)
            res[key] = {str(s): seam_errors(m, f, ov, args.tile) for s, f in frames.items()}
            for s, r in res[key].items():
                print(f"{m}: overlap {key} px, noise σ {s}: max {r['max_dn']} DN, 99.99th percentile "
                      f"{r['p9999_dn']} DN (8-bit sRGB)", flush=True)
    return _harness.publish("seams", out, args, argv)


if __name__ == "__main__":
    main()

"""How much of the lens blur the packaged correction takes back, on images
and lenses it never saw: PSNR and SSIM per field ring on the held-out test
set.

The test set: the four latent images held out of the packaged model's
training (``split_pairs`` with the training config's seed held out kodim07,
kodim11, kodim21 and McMaster 5) × ``--samples`` lenses drawn within
tolerance of the e9 design and never trained on, ``--positions`` places per
field ring and image, the training's 32 µm PSF windows; PSNR (dB) and SSIM
in display sRGB after the pipeline's stages that follow the slot
(:func:`restoration.evaluate.rings.evaluate`, what ``isp eval`` runs). The
non-blind baseline is Wiener deconvolution with the true PSF and the true
noise level.

Run::

    python -m benchmarks.correction_quality                       # the packaged INT8 model
    python -m benchmarks.correction_quality --model out/e9_default/model.pt

Last line: the record, whose ``results`` hold ``rings`` (per ring:
``psnr_uncorrected``, ``psnr_corrected``, ``psnr_baseline``, the SSIMs,
``crops``), ``overall`` and ``timing``.
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import os  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

from isp.errors import InputError  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
PACKAGED = ROOT / "modules" / "models" / "e9_default.int8.onnx"
LENS = DATA / "lenses" / "phone" / "US-12210142-B2-e9.zmx"
#: the latent images the packaged model's training held out (its validation images)
HELD_OUT = ("Kodak24/kodim07.png", "Kodak24/kodim11.png", "Kodak24/kodim21.png", "McMaster/5.tif")


def held_out_folder(into: Path) -> Path:
    """A folder of links to the held-out images (the evaluation reads a folder)."""
    for rel in HELD_OUT:
        src = DATA / "latent" / rel
        if not src.is_file():
            raise InputError(src, "held-out test image missing (../shared/data is needed)")
        os.symlink(src, into / rel.replace("/", "_"))
    return into


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--model", default=str(PACKAGED), help="checkpoint or ONNX file (default: the packaged model)")
    ap.add_argument("--samples", type=int, default=2, help="unseen lenses drawn within tolerance (default 2)")
    ap.add_argument("--positions", type=int, default=2, help="places per ring and image (default 2)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    from isp.runtime.executor import create_executor
    from restoration.evaluate.rings import EvalSettings, evaluate

    if not LENS.is_file():
        raise InputError(LENS, "lens file missing (../shared/data is needed)")
    settings = EvalSettings(samples=args.samples, positions=args.positions, seed=args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        report = evaluate(args.model, held_out_folder(Path(tmp)), LENS, settings,
                          executor=create_executor("processes", 2, progress=False))
    rings = report["rings"]
    for name, r in rings.items():
        print(f"FoV {name}: uncorrected {r['psnr_uncorrected']:.2f} dB, corrected {r['psnr_corrected']:.2f} dB, "
              f"Wiener {r['psnr_baseline']:.2f} dB ({r['crops']} crops)")
    result = {"model": Path(args.model).name, "rings": rings, "overall": report["overall"],
              "timing": report.get("timing")}
    return _harness.publish("correction_quality", result, args, argv)


if __name__ == "__main__":
    main()

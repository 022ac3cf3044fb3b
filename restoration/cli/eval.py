"""``isp eval``: PSNR and SSIM per field ring of a correction model on
proxy cameras it was not trained on (:mod:`restoration.evaluate.rings`).

Reached from ``isp eval ...`` and imported only then. A checkpoint needs
torch; an ``.onnx`` file runs through onnxruntime. Errors print one line
and exit with code 2, like the rest of ``isp`` (:mod:`isp.cli.run`).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from isp.cli.arguments import float_range, int_grid
from isp.errors import ConfigError, InputError
from isp.runtime.executor import add_executor_argument

from restoration.synth.optics import PSF_DEFAULTS

EPILOG = """\
examples:
  isp eval runs/doconv/best.pt --images ../shared/data/latent/Kodak24 --lens proxy.json --json eval.json
  isp eval doconv.onnx --images test_images/ --lens phone.zmx --samples 8 --json eval.json --baseline rl
  isp eval best.pt --images test_images/ --lens proxy.json --samples 2 --size 128 --limit 4 --json quick.json
  isp eval best.pt --images test_images/ --lens phone.zmx --exposure 0,0 --noise-scale 0.25,0.25 --json bright.json

The test set is synthesised like the training pairs (`isp synth`), on lenses drawn within
tolerance around the proxy from SeedSequence(SEED, spawn_key=(2,)) -- training draws from
spawn_key=(0,), so none of them was seen in training (--with-proxy adds the proxy itself).
Each image's centre crop is placed on the field rings FoV 0.1, 0.5 and 0.9 (normalised radius,
1 at the sensor corner; rings [0, 0.2), [0.4, 0.6), [0.8, 1]) and scored in sRGB after the
pipeline's stages that follow the correction slot, for the uncorrected pipeline, the model and
a non-blind deconvolution with the true PSF (scikit-image Wiener or Richardson-Lucy).

The JSON holds `rings` ("0.1", "0.5", "0.9": psnr_/ssim_ uncorrected, corrected, baseline),
`overall`, `per_image`, `per_lens`, `crops`, `settings` and `timing`.
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp eval``."""
    from restoration.evaluate.baseline import BASELINES

    p.description = ("Evaluate a correction model (checkpoint or ONNX) on synthesised images through "
                     "proxy cameras not seen in training: PSNR and SSIM per field ring, against the "
                     "uncorrected pipeline and a classical non-blind deconvolution.")
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("model", help="checkpoint (restoration.nn.checkpoint) or exported .onnx file")
    p.add_argument("--images", required=True, help="folder of latent sRGB test images (recursive)")
    p.add_argument("--lens", required=True, help="the proxy camera's lens file (lens/v1 JSON, .zmx, fitted proxy)")
    p.add_argument("--json", required=True, metavar="OUT", help="report file (written atomically)")
    p.add_argument("--samples", type=int, default=4,
                   help="lenses drawn within tolerance, unseen in training (default 4)")
    p.add_argument("--with-proxy", action="store_true", help="also evaluate the proxy lens itself")
    p.add_argument("--baseline", choices=BASELINES, default="wiener",
                   help="classical non-blind deconvolution with the true PSF (default wiener)")
    p.add_argument("--seed", type=int, default=0, help="seed of the lens draws, colours, noise, places (default 0)")
    p.add_argument("--size", type=int, default=256, help="scored crop side in pixels (default 256)")
    p.add_argument("--border", type=int, default=32,
                   help="context synthesised and corrected around each crop, not scored (default 32)")
    p.add_argument("--positions", type=int, default=1, help="placements per ring and image (default 1)")
    p.add_argument("--limit", type=int, help="use only the first N images (sorted)")
    p.add_argument("--tolerance-scale", type=float, default=1.0,
                   help="scale of the default tolerances for drawn lenses (default 1, as training)")
    p.add_argument("--camera", action="append", metavar="DNG",
                   help="phone DNG for the colour models (repeatable; default those of `isp synth`)")
    p.add_argument("--no-noise", action="store_true", help="no sensor noise")
    p.add_argument("--exposure", type=float_range, metavar="LO,HI",
                   help="luminosity compression in EV (default: training's, 0,2)")
    p.add_argument("--noise-scale", type=float_range, metavar="LO,HI",
                   help="factor on the NoiseProfile, log-uniform (default: training's, 0.5,2)")
    p.add_argument("--threads", type=int, default=2, help="onnxruntime threads (default 2)")
    p.add_argument("--device", metavar="FILE",
                   help="a device calibration (device/v1) for a model conditioned on the device: what it reads "
                        "for every crop (e.g. the fitted proxy's of the device whose true lens is --lens, "
                        "with --samples 0 --with-proxy)")
    g = p.add_argument_group("PSF maps (use the training set's settings)")
    g.add_argument("--psf-n", type=int, default=PSF_DEFAULTS["n"],
                   help="PSF window in samples of half a pixel (default a 32 µm window, 64 samples on 1 µm "
                        "pixels)")
    g.add_argument("--psf-grid", type=int_grid, default=PSF_DEFAULTS["grid"], metavar="ROWS,COLS",
                   help="regions of the PSF map (default 15,20)")
    g.add_argument("--psf-cache", metavar="DIR", help="PSF-map cache folder")
    g.add_argument("--workers", type=int, default=2, help="processes for the PSF maps (default 2)")
    add_executor_argument(g)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")


def _finite(x):
    """JSON has no NaN/inf: they become null."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x


def _limited_images(images: Path, limit: int, work_dir: Path) -> Path:
    """A folder of links to the first ``limit`` images (sorted), so the
    evaluation reads only those."""
    from restoration.synth.pairs import find_latents

    files = find_latents(images)[:limit]
    work_dir.mkdir(parents=True, exist_ok=True)
    for f in files:
        link = work_dir / f.relative_to(images).as_posix().replace("/", "__")
        link.symlink_to(f.resolve())
    return work_dir


def run(args: argparse.Namespace) -> int:
    """Evaluate, write the JSON report, print the table per ring."""
    import tempfile

    from isp.runtime.executor import pool_executor

    from restoration.evaluate.rings import EvalSettings, evaluate

    model, images, lens = Path(args.model), Path(args.images), Path(args.lens)
    if not model.exists():
        raise InputError(model, "no such model file (a checkpoint or an .onnx export)")
    if not images.is_dir():
        raise InputError(images, "image folder not found")
    if not lens.exists():
        raise InputError(lens, "no such lens file")
    if args.samples < 0 or (args.samples == 0 and not args.with_proxy):
        raise ConfigError(f"--samples must be ≥ 1 (or 0 with --with-proxy), got {args.samples}")
    if args.limit is not None and args.limit < 1:
        raise ConfigError(f"--limit must be ≥ 1, got {args.limit}")
    device = None
    if args.device:
        from isp.io.device import DeviceCalibration

        device = DeviceCalibration.load(args.device)
    out = Path(args.json)
    if out.exists() and out.is_dir():
        raise InputError(out, "is a folder; give a file name for the JSON report")
    with tempfile.TemporaryDirectory(prefix="isp-eval-") as tmp:
        img_dir = images if args.limit is None else _limited_images(images, args.limit, Path(tmp) / "images")
        settings = EvalSettings(size=args.size, border=args.border, positions=args.positions, baseline=args.baseline,
                                samples=args.samples, seed=args.seed, tolerance_scale=args.tolerance_scale,
                                with_proxy=args.with_proxy, noise=False if args.no_noise else None,
                                exposure_ev=args.exposure, noise_scale=args.noise_scale)
        report = evaluate(model, img_dir, lens, settings, cameras=args.camera,
                          psf_options={"n": args.psf_n, "grid": args.psf_grid}, cache_dir=args.psf_cache,
                          threads=args.threads, executor=pool_executor(args.workers, progress=not args.quiet, executor=args.executor),
                          device=device)
    if args.limit is not None:
        report["images"]["dir"] = str(images)
    from isp.io.files import write_bytes_atomic

    write_bytes_atomic(out, (json.dumps(_finite(report), indent=1) + "\n").encode())
    _print_table(report)
    print(f"wrote {out} ({report['overall']['crops']} crops, {report['timing']['wall']:.1f} s)")
    return 0


def _print_table(report: dict) -> None:
    def f(v, fmt):
        return format(v, fmt) if v is not None else "—"

    print(f"{'ring':>5} {'crops':>5}  {'PSNR unc':>8} {'corr':>6} {'base':>6}   {'SSIM unc':>8} {'corr':>6} {'base':>6}")
    for name, r in list(report["rings"].items()) + [("all", report["overall"])]:
        print(f"{name:>5} {r['crops']:>5}  {f(r['psnr_uncorrected'], '8.2f')} {f(r['psnr_corrected'], '6.2f')} "
              f"{f(r['psnr_baseline'], '6.2f')}   {f(r['ssim_uncorrected'], '8.4f')} "
              f"{f(r['ssim_corrected'], '6.4f')} {f(r['ssim_baseline'], '6.4f')}")


"""``isp synth``: training pairs for the correction slot (paper, section 4.1).

Reached from ``isp synth ...`` and imported only then; it needs numpy,
OpenCV and the calibration toolkit, not torch. Errors print one line and
exit with code 2, like the rest of ``isp`` (:mod:`isp.cli.run`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from isp.cli.arguments import float_range, int_grid
from isp.errors import ConfigError, InputError
from isp.runtime.executor import add_executor_argument

from restoration.synth.defaults import DATA, DEFAULT_CAMERAS
from restoration.synth.optics import PSF_DEFAULTS
from restoration.synth.pairs import POSITIONS

EPILOG = f"""\
examples:
  isp synth --lens proxy.json --samples 1 -o pairs/                # single sample: the proxy lens
  isp synth --lens proxy.json --samples 8 -o pairs8/ --pairs 5000  # proxy + 7 lenses within tolerance
  isp synth --lens phone.zmx --samples 4 --tolerance-scale 0.5 -o half_tol/
  isp synth --lens proxy.json -o pairs/ --latent my_images/ --camera phone1.dng --camera phone2.dng

Each pair: a --size × --size crop of a latent sRGB image (the target) taken back to raw-like
camera RGB with a real phone's colour metadata, blurred by the PSFs of a random position on
the sensor, mosaicked, made noisy (DNG NoiseProfile), white-balanced and demosaiced by the
pipeline's own stages: the input the correction slot sees. Shards (.npz) and a
manifest.json (seed, lenses, inputs and data hashes) go to the output folder; read them
with restoration.train.dataset.SynthPairs.

defaults: latent images from {DATA / 'latent'}; camera metadata from
{', '.join(str(DATA / c) for c in DEFAULT_CAMERAS)}.
PSF maps are cached in $ISP_CACHE/psf (else ~/.cache/phone-isp/psf).
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp synth``."""
    p.description = ("Synthesise training pairs (camera RGB input, sRGB target) from latent images "
                     "through a proxy camera (paper, section 4.1).")
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("--lens", required=True,
                   help="lens file (lens/v1 JSON, .zmx, ...) or fitted proxy file; data:REST is REST in the "
                        "shared data folder")
    p.add_argument("--samples", type=int, default=1,
                   help="1: the lens itself (single sample); N: the lens and N-1 lenses drawn within "
                        "tolerance (multiple samples); default 1")
    p.add_argument("-o", "--output", required=True, help="output folder (shards + manifest.json)")
    p.add_argument("--pairs", type=int, default=1000, help="number of pairs (default 1000)")
    p.add_argument("--size", type=int, default=256, help="crop side in pixels (default 256)")
    p.add_argument("--latent", default=str(DATA / "latent"), help="folder of latent sRGB images (recursive)")
    p.add_argument("--camera", action="append", metavar="DNG",
                   help="phone DNG whose colour metadata is drawn from (repeatable; the first is also "
                        "the sensor: CFA, levels, NoiseProfile)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random draw (default 0)")
    p.add_argument("--workers", type=int, default=None,
                   help="processes (default 2), or shards in flight on Ray (default its CPUs)")
    add_executor_argument(p)
    p.add_argument("--tolerance-scale", type=float, default=1.0,
                   help="scale of the default tolerances for drawn lenses (default 1)")
    p.add_argument("--shard-size", type=int, default=100, help="pairs per shard file (default 100)")
    p.add_argument("--pixel-um", type=float, metavar="UM",
                   help="the pairs' pixel pitch, µm: the lens file's sensor area at this pitch (default the lens "
                        "file's; a proxy fitted to a binned capture carries that capture's pitch)")
    g = p.add_argument_group("what the pairs look like")
    g.add_argument("--exposure", type=float_range, default=(0.0, 2.0), metavar="LO,HI",
                   help="luminosity compression in EV (default 0,2)")
    g.add_argument("--cct", type=float_range, default=(2850.0, 7500.0), metavar="LO,HI",
                   help="scene white in kelvin (default 2850,7500)")
    g.add_argument("--noise-scale", type=float_range, default=(0.5, 2.0), metavar="LO,HI",
                   help="ISO-like factor on the NoiseProfile, log-uniform (default 0.5,2)")
    g.add_argument("--no-noise", action="store_true", help="no sensor noise")
    g.add_argument("--blend", choices=("bilinear", "nearest"), default="bilinear",
                   help="PSF interpolation between region centres, or one PSF per region (default bilinear)")
    g.add_argument("--demosaic", default="malvar2004", help="the pipeline's demosaic method (default malvar2004)")
    g.add_argument("--tone", choices=("none", "reinhard", "aces"), default="none",
                   help="the pipeline's luminance tone curve (default none)")
    g.add_argument("--positions", choices=POSITIONS, default="frame",
                   help="where crops lie: 'frame' (default) uniformly over the frame, each field ring in "
                        "proportion to its area; 'radius' at a field radius uniform from the centre to the "
                        "corner, as many pairs in the corners as in the centre")
    g = p.add_argument_group("PSF maps")
    g.add_argument("--psf-n", type=int, default=PSF_DEFAULTS["n"],
                   help="PSF window in samples of half a pixel (default a 32 µm window, 64 samples on 1 µm "
                        "pixels: a drawn lens's corner PSF keeps >= 95 %% of its light, against 68 %% at 16 µm)")
    g.add_argument("--psf-grid", type=int_grid, default=PSF_DEFAULTS["grid"], metavar="ROWS,COLS",
                   help="regions of the PSF map (default 15,20 as the paper; 30,40 cuts the blur's "
                        "interpolation error about 3x for 4x the PSFs)")
    g.add_argument("--psf-cache", metavar="DIR", help="PSF-map cache folder")
    g = p.add_argument_group("device descriptors (for a network shared by every device of the design)")
    g.add_argument("--basis", metavar="BASIS.npz",
                   help="the design's descriptor basis (`isp calib basis`): each lens's device/v1 descriptor "
                        "goes into the manifest, and a conditioned network (variant `device`) reads the "
                        "pair's")
    g.add_argument("--device-components", type=int, default=16, metavar="K",
                   help="descriptor components kept (default 16)")
    p.add_argument("--force", action="store_true", help="replace a previous set in the output folder")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    """Plan (lenses, PSF maps, inputs) and generate the pairs."""
    from isp.runtime.executor import pool_executor

    from restoration.synth.pairs import SynthSettings, generate, plan

    if args.samples < 1:
        raise ConfigError(f"--samples must be ≥ 1, got {args.samples}")
    if args.pairs < 1 or (args.workers is not None and args.workers < 1) or args.shard_size < 1:
        raise ConfigError("--pairs, --workers and --shard-size must be ≥ 1")
    from restoration.train.config import resolve_path

    args.lens = str(resolve_path(args.lens))     # data:REST, as in a training config
    if not Path(args.lens).exists():
        raise InputError(args.lens, "no such lens file")
    if args.pixel_um is not None and not 0.2 <= args.pixel_um <= 20.0:
        raise ConfigError(f"--pixel-um {args.pixel_um:g}: between 0.2 and 20 µm")
    if args.device_components < 1:
        raise ConfigError(f"--device-components {args.device_components}: at least 1")
    cameras = args.camera or [str(DATA / c) for c in DEFAULT_CAMERAS]
    executor = pool_executor(args.workers, progress=not args.quiet, executor=args.executor)
    settings = SynthSettings(size=args.size, exposure_ev=args.exposure, cct_k=args.cct, noise_scale=args.noise_scale,
                             noise=not args.no_noise, blend=args.blend, demosaic=args.demosaic, tone=args.tone,
                             positions=args.positions)
    p = plan(args.lens, samples=args.samples, latent_dir=args.latent, cameras=cameras, seed=args.seed,
             settings=settings, tolerance_scale=args.tolerance_scale,
             psf_options={"n": args.psf_n, "grid": args.psf_grid},
             cache_dir=args.psf_cache, pixel_um=args.pixel_um, executor=executor, basis=args.basis,
             device_components=args.device_components)
    m = generate(p, args.output, args.pairs, shard_size=args.shard_size, force=args.force, executor=executor)
    print(f"wrote {m['pairs']} pairs of {m['size']}×{m['size']} in {len(m['shards'])} shards to {args.output} "
          f"({m['_seconds']:.1f} s; {len(p.maps)} lens{'es' if len(p.maps) > 1 else ''}; "
          f"data sha256 {m['data_sha256'][:16]}…)")
    return 0


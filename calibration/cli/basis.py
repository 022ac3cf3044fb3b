"""``isp calib basis``: a lens design's descriptor basis, learned from lenses
drawn within its tolerances (:func:`calibration.fit.device.learn_basis`).

A device's calibration (``device/v1``, written by ``isp calib fit --basis``)
is its fitted proxy's PSFs on this basis: one basis per lens design, made
once, shipped with the design's lens profile.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from isp.errors import ConfigError
from isp.runtime.executor import add_executor_argument

EPILOG = """examples:
  isp calib basis e9.zmx -o e9_basis.npz                     # 150 lenses drawn, 5 x 7 regions
  isp calib basis e9.zmx --draws 40 --components 16 -o quick.npz
  isp calib fit --lens e9.zmx --measured capture.dng --basis e9_basis.npz -o dev3/   # dev3/device.json
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp calib basis``."""
    from calibration.fit.device import DEFAULT_COMPONENTS, DEFAULT_GRID

    p.description = __doc__.split("\n\n")[0].replace("``", "`")
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("lens", help="lens file of the design (lens/v1 .json, Zemax .zmx, ...)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.npz", help="the basis file")
    p.add_argument("--draws", type=int, default=150,
                   help="lenses drawn within tolerance (default 150; a PSF map each, cached on disk)")
    p.add_argument("--components", type=int, default=DEFAULT_COMPONENTS,
                   help=f"principal components kept per region (default {DEFAULT_COMPONENTS})")
    p.add_argument("--grid", type=int, nargs=2, default=list(DEFAULT_GRID), metavar=("R", "C"),
                   help=f"field regions (default {DEFAULT_GRID[0]} {DEFAULT_GRID[1]})")
    p.add_argument("--seed", type=int, default=0, help="of the draws (default 0)")
    p.add_argument("--tolerance-scale", type=float, default=1.0, help="multiplies every tolerance (default 1)")
    p.add_argument("--workers", type=int, default=None, help="processes per PSF map (default 2)")
    add_executor_argument(p)


def run(args: argparse.Namespace) -> int:
    """Draw the lenses, map their PSFs, keep the principal components; write the basis."""
    from calibration.fit.device import learn_basis
    from calibration.optics.io import read_lens
    from isp.runtime.executor import pool_executor

    if args.draws < 2:
        raise ConfigError(f"--draws {args.draws}: at least 2")
    if not 1 <= args.components <= 1024:
        raise ConfigError(f"--components {args.components}: between 1 and 1024")
    if min(args.grid) < 1:
        raise ConfigError(f"--grid {args.grid[0]} {args.grid[1]}: two counts ≥ 1")
    if not args.tolerance_scale > 0:
        raise ConfigError(f"--tolerance-scale {args.tolerance_scale:g}: must be positive")
    out = Path(args.output)
    if out.suffix != ".npz":
        raise ConfigError(f"{out}: the basis is a .npz file")
    t0 = time.perf_counter()
    lens = read_lens(args.lens)
    # the file's stem names the design: a patent's embodiments share the prescription's name
    basis = learn_basis(lens, args.draws, seed=args.seed, grid=tuple(args.grid), components=args.components,
                        tolerance_scale=args.tolerance_scale,
                        executor=pool_executor(args.workers, executor=args.executor),
                        progress=True, name=Path(args.lens).stem)
    basis.save(out)
    ex = basis.explained
    marks = ", ".join(f"{k} components {ex[k - 1]:.1%}" for k in (1, 4, 8, 16, 32) if k <= basis.size)
    print(f"{basis.lens}: {basis.draws} lenses drawn, {basis.grid[0]} × {basis.grid[1]} regions; "
          f"variance held: {marks}")
    print(f"wrote {out} (basis {basis.key[:12]}, {time.perf_counter() - t0:.0f} s)")
    return 0

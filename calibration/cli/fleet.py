"""``isp calib fleet``: a production line's captures to one ``device/v1``
calibration each, on a local pool or a Ray cluster, with the fleet's
report (:mod:`calibration.fleet`)."""

from __future__ import annotations

import argparse

from calibration.cli.arguments import coarse_grid
from isp.runtime.executor import add_executor_argument

EPILOG = """examples:
  isp calib fleet captures/ --lens e9.zmx -o devices/
  isp calib fleet captures/ --lens e9.zmx -o devices/ --executor ray://head:10001
  ISP_EXECUTOR=ray isp calib fleet captures/ --lens e9.zmx -o devices/ --effects none

what it writes (DEVICES_DIR):
  <capture>.device.json   each module's calibration (isp process --device FILE), written atomically
  fleet.json, fleet.md    per device: SFRA error before/after, noise floor, effects kept, unexplained
                          residual, SFRA over the design's per field ring (the yield check); the
                          yield, the modules unlike the fleet (error above 1.5 x its median),
                          failures, throughput
  fleet.png               errors against the noise floor, SFRA over the nominal design's in the worst ring

Run again on the same folders to resume: a device whose file names its capture's SHA-256 is kept,
an interrupted one left no file and is fitted. A capture that fails is listed with its error; the
others go on (exit code 1 where any failed). On a cluster every node reads the captures and writes
the devices folder (a shared file system) and has this package installed.
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp calib fleet``."""
    from calibration.fit.device import DEFAULT_COMPONENTS
    from calibration.fit.proxy import MAX_ITER, N_PARAMS, RESTARTS
    from calibration.loop.effects import list_effects

    p.description = ("Calibrate every chart capture of a folder (a production line's modules): the proxy fit, "
                     "then the loop's effects, one device/v1 file each, and the fleet's report.")
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("captures", metavar="CAPTURES_DIR", help="folder of chart captures (DNG, TIFF, PNG, SFR JSON)")
    p.add_argument("--lens", required=True, help="the design's lens file (lens/v1 .json, Zemax .zmx, ...)")
    p.add_argument("--basis", default="auto", metavar="BASIS.npz",
                   help="the design's descriptor basis (isp calib basis); 'auto' (default): the one a lens profile "
                        "ships for this design (the packaged e9's)")
    p.add_argument("-o", "--output", required=True, metavar="DEVICES_DIR", help="folder of device files and the report")
    p.add_argument("--n-params", type=int, default=N_PARAMS, help=f"perturbations fitted (default {N_PARAMS})")
    p.add_argument("--max-iter", type=int, default=MAX_ITER, help=f"fit iterations at most (default {MAX_ITER})")
    p.add_argument("--restarts", type=int, default=RESTARTS,
                   help=f"other starts where a fit ends far above noise (default {RESTARTS})")
    p.add_argument("--coarse", type=int, nargs=2, default=[5, 7], metavar=("R", "C"),
                   help="the fit's coarse sub-grid of regions (default 5 7; 0 0: all observations)")
    p.add_argument("--fine-iter", type=int, default=0, metavar="N",
                   help="iterations on all observations after the coarse stage (default 0: the line's quick fit)")
    p.add_argument("--effects", default=None, metavar="A,B|none",
                   help=f"loop effects to try after the fit (default all: {', '.join(list_effects())}; none: no loop)")
    p.add_argument("--max-effects", type=int, default=2, help="most effects kept per device (default 2)")
    p.add_argument("--folds", type=int, default=3, help="the loop's cross-validation folds (default 3)")
    p.add_argument("--loop-iter", type=int, default=12,
                   help="iterations of the loop's refit of lens and effects after each effect kept (default 12)")
    p.add_argument("--components", type=int, default=DEFAULT_COMPONENTS,
                   help=f"descriptor components per device file (default {DEFAULT_COMPONENTS})")
    p.add_argument("--min-sfra-ratio", type=float, default=0.7, metavar="R",
                   help="the specification: a module whose measured SFRA in any field ring is below R times the "
                        "nominal design's fails it (default 0.7)")
    p.add_argument("--channel", help="R, G, B, L or all (default G; grey images: L)")
    p.add_argument("--encoding", choices=("linear", "srgb"), default="linear", help="image codes (default linear)")
    p.add_argument("--pixel-um", type=float, metavar="UM", help="pixel pitch, µm (default: each capture's)")
    p.add_argument("--workers", type=int, default=None,
                   help="devices at once (default 2 on this machine; on Ray, the cluster's CPUs)")
    add_executor_argument(p)


def run(args: argparse.Namespace) -> int:
    """Calibrate the fleet; 1 where any capture failed."""
    from isp.runtime.executor import pool_executor

    from calibration.fleet import UNLIKE, FleetSettings, parse_effects, run_fleet

    coarse = coarse_grid(args.coarse)
    s = FleetSettings(n_params=args.n_params, max_iter=args.max_iter, restarts=args.restarts, coarse=coarse,
                      fine_iter=args.fine_iter if coarse else None, components=args.components,
                      effects=parse_effects(args.effects), max_effects=args.max_effects, loop_iter=args.loop_iter,
                      folds=args.folds, channel=args.channel, encoding=args.encoding, pixel_um=args.pixel_um,
                      min_sfra_ratio=args.min_sfra_ratio)
    ex = pool_executor(args.workers, progress=True, executor=args.executor,
                       imports=("rawpy", "calibration.fleet"))
    with ex:
        rep = run_fleet(args.captures, args.lens, args.basis, args.output, s, executor=ex)
    rate = f" ({rep['devices_per_hour']:.0f}/hour on {rep['executor']})" if rep["devices_per_hour"] else ""
    print(f"{rep['devices']} device(s) in {args.output}: {rep['fitted_now']} fitted now{rate}, "
          f"{rep['failed']} failed; below specification: {', '.join(rep['below_spec']) or 'none'}; "
          f"report {args.output}/fleet.md, fleet.png")
    if rep["unlike_the_fleet"]:
        print(f"unlike the fleet (calibrated error above {UNLIKE:g} x its median; to inspect): "
              f"{', '.join(rep['unlike_the_fleet'])}")
    for name, why in rep["not_taken"].items():
        print(f"not taken: {name}: {why}")
    return 1 if rep["failed"] else 0

"""``isp calib spot``: spot diagrams at fractions of the half field of view."""

from __future__ import annotations

import argparse

from isp.cli.arguments import numbers


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp calib spot``."""
    p.description = "Spot diagrams at fractions of the half field of view."
    p.epilog = "example:\n  isp calib spot e9.json --fields 0,0.5,0.7,1 --plot spots.png"
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("lens")
    p.add_argument("--fields", default="0,0.5,0.7,1", help="fractions of the half-FOV (default 0,0.5,0.7,1)")
    p.add_argument("--rays", type=int, default=10000, help="rays per field (default 10000)")
    p.add_argument("--plot", metavar="OUT.png")


def run(args: argparse.Namespace) -> int:
    """Trace the spots; print their RMS radii; ``--plot`` the diagrams."""
    from calibration.optics.io import read_lens
    from calibration.optics.spot import plot_spot_diagram, spot
    from calibration.report import save_figure

    lens = read_lens(args.lens)
    fracs = numbers(args.fields)
    spots = [spot(lens, (0.0, f * lens.half_fov_deg), n=args.rays, aiming="real") for f in fracs]
    for f, sp in zip(fracs, spots):
        print(f"field {f:4.2f}: RMS {sp.rms_radius('centroid') * 1e3:.3f} µm (centroid), "
              f"{sp.rms_radius('chief') * 1e3:.3f} µm (chief)")
    if args.plot:
        save_figure(plot_spot_diagram(spots), args.plot)
        print(f"wrote {args.plot}")
    return 0

"""``isp calib``: the calibration toolkit's command line.

Reached from ``isp calib ...``; imported only then, so the ISP's own
commands never load the optics code. Sub-commands:

``lens``
    Read a lens file (lens/v1 JSON, Zemax .zmx, optiland, DeepLens,
    rayoptics), print first-order data, vignetting and spot sizes over the
    field; optionally convert it to lens/v1.
``spot``
    Spot diagrams over the field (PNG).
``psf``
    A polychromatic PSF at one field, or the PSF map over the sensor
    (cached), with a plot.
``simulate``
    A simulated capture (slanted-edge chart) through a nominal or perturbed
    lens, written as a DNG that ``isp process`` reads like a real one.
``sfr``
    ISO 12233 slanted-edge SFR of an image, an ROI or a whole chart.
``fit``
    Fit a proxy camera to a measurement: lens/v1 + fitted perturbation, and
    a report.
``basis``
    A lens design's descriptor basis: principal components of the PSFs of
    lenses drawn within its tolerances (what ``fit --basis`` projects a
    device on).
``loop``
    Close the loop on a measurement: fit, find the effects the model lacks,
    refit, report before/after.
``fleet``
    A folder of chart captures (a production line's modules) to one
    device calibration each, resumable, on any executor, with the fleet's
    report (yield, errors against the noise floor).

Each sub-command is a module of this package with ``add_arguments(parser)``
and ``run(args)`` (:data:`SUBCOMMANDS`). Errors print one line and exit
with code 2, like the rest of ``isp`` (:mod:`isp.cli.run`).
"""

from __future__ import annotations

import argparse

from isp.cli.commands import Command, add_subcommands

EPILOG = """\
examples:
  isp calib lens phone.zmx                       # first-order data, vignetting, spots
  isp calib lens phone.zmx --save phone.json     # convert to lens/v1
  isp calib spot phone.json --plot spots.png
  isp calib psf phone.json --field 0,25 --plot psf.png
  isp calib psf phone.json --map --plot psf_map.png
  isp calib simulate phone.json -o capture.dng --perturb random --seed 3
  isp calib sfr capture.png --chart --json sfr.json --plot sfr.png
  isp calib fit --lens phone.zmx --measured capture.dng -o proxy/  # proxy camera (paper Alg. 1)
  isp calib basis phone.zmx -o phone_basis.npz    # once per lens design
  isp calib fit --lens phone.zmx --measured capture.dng --basis phone_basis.npz -o dev/   # + dev/device.json
  isp calib loop --lens parametric --measured edge.jpg --encoding srgb -o edge_loop/
  isp calib fleet captures/ --lens phone.zmx --basis phone_basis.npz -o devices/ --executor ray
"""

#: the sub-commands, in the order ``isp calib --help`` lists them
SUBCOMMANDS = (
    Command("lens", "first-order data, vignetting and spots of a lens file", module="calibration.cli.lens"),
    Command("spot", "spot diagrams over the field", module="calibration.cli.spot"),
    Command("psf", "a polychromatic PSF, or the PSF map over the sensor", module="calibration.cli.psf"),
    Command("simulate", "a simulated chart capture written as DNG", module="calibration.cli.simulate"),
    Command("sfr", "ISO 12233 slanted-edge SFR of an image, ROI or chart", module="calibration.cli.sfr"),
    Command("fit", "fit a proxy camera (lens perturbations) to a measured SFR", module="calibration.cli.fit"),
    Command("basis", "a lens design's device-descriptor basis, from lenses drawn within tolerance",
            module="calibration.cli.basis"),
    Command("loop", "fit, find the effects the model lacks, refit; report before/after",
            module="calibration.cli.loop"),
    Command("fleet", "a production line: one device calibration per chart capture, on a pool or a Ray cluster",
            module="calibration.cli.fleet"),
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The sub-commands of ``isp calib`` and their options."""
    p.description = "Calibration toolkit: lens models, ray tracing, PSFs, simulated captures, slanted-edge SFR."
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.set_defaults(func=lambda args: _no_command(p))
    # only the chosen sub-command's module is imported: `isp calib sfr` starts without the fitter
    add_subcommands(p, SUBCOMMANDS)


def _no_command(parser: argparse.ArgumentParser) -> int:
    parser.print_help()
    return 2


def run(args: argparse.Namespace) -> int:
    """Run the chosen sub-command (``isp calib`` alone: the help, exit code 2)."""
    return int(args.func(args) or 0)

"""``isp calib`` and ``isp demo``: argument parsing for the calibration toolkit; calls library functions only.

The two commands' records (:class:`isp.cli.commands.Command`) are here, and
``pyproject.toml`` names them in the ``isp.commands`` entry-point group:
importing this package imports nothing else, so ``isp --help`` lists them
without loading the toolkit. ``calib``'s sub-commands are in
:mod:`.main` (lens, spot, psf, simulate, sfr), :mod:`.fit` and :mod:`.loop`;
``demo`` is :mod:`.demo`.

May import: everything in ``calibration`` and ``isp`` (here at the top
level: :mod:`isp.cli.commands` only).
"""

from isp.cli.commands import Command

CALIB = Command("calib", "lens files, ray tracing, PSFs, simulated captures, SFR", module="calibration.cli.main")
DEMO = Command("demo", "write a synthetic phone capture (DNG) and process it", module="calibration.cli.demo")

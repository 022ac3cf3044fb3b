"""Options that several ``isp calib`` sub-commands share."""

from __future__ import annotations

import argparse

from isp.errors import ConfigError


def add_device_arguments(p: argparse.ArgumentParser) -> None:
    """``--perturb``, ``--seed``, ``--cache``: which device of the lens
    (:func:`calibration.simulate.device.device_lens`) and where its PSFs are cached."""
    p.add_argument("--perturb", metavar="random|FILE.json",
                   help="a device: 'random' within the default tolerances, or {name: value} JSON "
                        "(e.g. {\"e1.decenter_x\": 0.003})")
    p.add_argument("--seed", type=int, default=0, help="seed for --perturb random and noise")
    p.add_argument("--cache", metavar="DIR", help="PSF cache folder (default $ISP_CACHE or ~/.cache)")


def coarse_grid(values) -> tuple[int, int] | None:
    """``--coarse R C``: the coarse stage's sub-grid, or None for ``0 0``
    (off); ConfigError for anything else."""
    rows, cols = values
    if min(rows, cols) < 0 or (0 in (rows, cols) and (rows or cols)):
        raise ConfigError(f"--coarse {rows} {cols}: two positive counts, or 0 0 (off)")
    return (rows, cols) if rows > 0 else None

"""Fixtures of the PSF tests: e9, and e9 perturbed with four fields
traced both per field and in one batch."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.optics import trace as tr
from calibration.optics.perturb import apply
from calibration.optics.psf import map as M
from calibration.optics.psf import pupil


@pytest.fixture(scope="module")
def e9(e9_lens):
    """The e9 phone lens (:func:`tests.conftest.e9_lens`)."""
    return e9_lens


BATCH_PERTURBATION = {"e1.decenter_x": 0.003, "e3.tilt_yz": 0.03, "s4.thickness": 0.004}
BATCH_POINTS_MM = [[0.0, 0.0], [1.0, 0.5], [-2.6, 1.9], [2.7, -2.0]]   # the last two vignetted


@pytest.fixture(scope="module")
def batch(e9):
    """A perturbed e9, four fields (centre to corner) traced both ways with
    real aiming at 24 pupil samples."""
    pl = apply(e9, BATCH_PERTURBATION)
    fields = M.chief_ray_fields(pl, np.array(BATCH_POINTS_MM))
    samples, lam = 24, 520.0
    grid = pupil.pupil_points(samples)
    z_pupil = pupil.exit_pupil_z(pl)
    rays = tr.field_pupil_rays(pl, fields, grid, lam, aiming="real")
    tn = pupil.nodes_from_trace(pl, rays, tr.trace_to_exit(pl, rays), fields, grid[:-1], samples, z_pupil)
    singles = []
    for f in fields:
        r = tr.pupil_rays(pl, tuple(f), samples, lam, aiming="real", pupil=grid)
        singles.append(pupil.pupil_from_trace(pl, r, tr.trace_to_exit(pl, r), tuple(f), samples, z_pupil))
    return pl, fields, tn, singles

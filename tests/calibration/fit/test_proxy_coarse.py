"""Coarse-to-fine proxy fits (kind: property): the sub-grid keeps rows and
columns spread edge to edge, corners in; a fit on a sub-grid refined on all
regions recovers a known device as well as the fit on all regions from the
start."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers import e9_device

NAMES = ["e1.decenter_x", "s17.thickness"]
U_TRUE = np.array([0.8, 0.6])


@pytest.fixture(scope="module")
def grid_device():
    return e9_device(NAMES, U_TRUE, grid=(4, 6), noise=0.003, rng=3)


def one_per_region(obs, grid):
    """``obs``'s first observation moved to the centre of every region of ``grid``."""
    rows, cols = grid
    r, c = np.divmod(np.arange(rows * cols), cols)
    first = obs.subset(np.zeros(rows * cols, int))
    return first.with_fields(x_px=(c + 0.5) / cols * obs.sensor.width_px, y_px=(r + 0.5) / rows * obs.sensor.height_px,
                             grid=(rows, cols))


def test_the_sub_grid_spans_the_field_corners_included(grid_device):
    from calibration.fit.proxy import coarse_subset

    _, obs = grid_device
    full = one_per_region(obs, (15, 20))
    mask = coarse_subset(full, (5, 7))
    kept = full.region[mask]
    assert sorted(set(kept[:, 0])) == [0, 4, 7, 10, 14]
    assert sorted(set(kept[:, 1])) == [0, 3, 6, 10, 13, 16, 19]
    assert mask.sum() == 35
    # nothing to gain on a grid no larger than twice the sub-grid, or below the least count
    assert coarse_subset(one_per_region(obs, (5, 7)), (5, 7)) is None
    assert coarse_subset(full, (5, 7), min_obs=36) is None


def test_coarse_to_fine_recovers_the_device_as_the_full_fit_does(grid_device):
    from calibration.fit.proxy import fit_proxy

    lens, obs = grid_device
    kw = dict(names=NAMES, residuals="sfra", workers=1, max_iter=6, progress=False, restarts=0)
    full = fit_proxy(lens, obs, coarse=None, **kw)
    staged = fit_proxy(lens, obs, coarse=(2, 3), **kw)
    # rows 0 and 3, columns 0, 2 and 5 of 4 × 6: 6 of 24 regions, two edges each
    assert staged.coarse["observations"] == 12 and not full.coarse
    assert len(staged.observations) == len(obs) == 48
    assert staged.evaluations > staged.coarse["evaluations"] > 0
    err_full = np.abs(full.u - U_TRUE).max()
    err_staged = np.abs(staged.u - U_TRUE).max()
    assert err_full < 0.1 and err_staged < max(0.1, 1.5 * err_full)
    assert staged.result.merit <= 1.1 * full.result.merit

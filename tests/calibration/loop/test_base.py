"""The loop's lens base starts its fit where ``fit_proxy`` puts it (kind:
property): on a device with two known perturbations, the start recovers
them, and `close_loop` fits from that start."""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers import e9_device

NAMES = ["e1.decenter_x", "e2.tilt_yz"]
U_TRUE = np.array([0.8, -0.6])


@pytest.fixture(scope="module")
def lens_base():
    from calibration.loop.base import LensBase

    lens, obs = e9_device(NAMES, U_TRUE, grid=(3, 4), noise=0.003, rng=4, n=96, pupil_samples=64, n_wavelengths=3)
    return LensBase(lens, obs, names=NAMES)


def test_the_start_recovers_the_device(lens_base):
    start = lens_base.start()
    assert np.abs(start - U_TRUE).max() < 0.15, start
    # the nominal lens, where the loop used to start, is far off
    assert np.abs(lens_base.x0 - U_TRUE).max() > 0.5


def test_close_loop_fits_from_the_start(lens_base, monkeypatch):
    from calibration.loop import closure as loop
    seen = []
    fit = loop._fit

    def spy(prob, p0, *a, **k):
        seen.append(np.array(p0[:len(NAMES)]))
        return fit(prob, p0, *a, **k)

    monkeypatch.setattr(loop, "_fit", spy)
    monkeypatch.setattr(type(lens_base), "start", lambda self, progress=False: U_TRUE.copy())
    loop.close_loop(lens_base, lens_base.obs, effects=[], progress=False)
    np.testing.assert_allclose(seen[0], U_TRUE)

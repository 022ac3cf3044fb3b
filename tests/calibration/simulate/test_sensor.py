"""The simulated sensor (calibration/simulate/sensor.py): Bayer mosaic,
Poisson–Gaussian noise, quantisation and clipping, the NoiseProfile from
photo-electrons.

Kind: property (each test marked): statistics against the NoiseProfile,
exact values.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.simulate.sensor import (
    SensorModel,
    add_noise,
    dn_to_linear,
    expose,
    mosaic,
    quantise,
)
from isp.frame import CFA


# -- Bayer sampling -------------------------------------------------------------------------

@pytest.mark.property
def test_property_mosaic_and_levels():
    """property: mosaic() puts R, G, B at the CFA sites of each pattern."""
    rgb = np.stack([np.full((4, 6), v) for v in (1.0, 2.0, 3.0)], axis=-1)
    for cfa in CFA:
        m = mosaic(rgb, cfa)
        assert np.array_equal(m[:2, :2], cfa.pattern + 1.0)


# -- noise and quantisation -----------------------------------------------------------------

@pytest.mark.property
@pytest.mark.parametrize("level", [0.0, 0.005, 0.05, 0.3, 0.7, 0.95])
def test_property_noise_variance_matches_profile(level):
    """property: on a flat field (4e5 samples) the variance of the stored
    data in 0..1 units (black removed) is S·x + O of the NoiseProfile
    (quantisation included, Sheppard-corrected) within 2.5 % (sampling
    s.e. of a variance: sqrt(2/N) = 0.22 %), and the mean is x within 5 s.e."""
    sm = SensorModel(width_px=2, height_px=2)             # 10 bit, black 64, (S, O) = (2e-4, 2e-6)
    s, o = sm.noise_profile
    n = 400_000
    y = dn_to_linear(expose(np.full(n, level), sm, rng=7), sm)
    var = s * level + o
    assert abs(y.var() / var - 1.0) < 0.025
    assert abs(y.mean() - level) < 5 * math.sqrt(var / n)


@pytest.mark.property
def test_property_quantisation_and_clipping():
    """property: noise-free values are stored as round(B + x·(W − B));
    overexposure clips at white, negative signals at 0 DN; uint16."""
    sm = SensorModel(width_px=2, height_px=2, bit_depth=12, black_level=256.0)
    x = np.array([-0.2, 0.0, 1e-4, 0.25, 0.5, 0.999, 1.0, 1.5, 7.0])
    dn = expose(x, sm, noise=False)
    assert dn.dtype == np.uint16
    assert dn.tolist() == [0, 256, 256, 1216, 2176, 4091, 4095, 4095, 4095]
    noisy = expose(np.full(10_000, 1.2), sm, rng=0)
    assert noisy.max() == 4095 and np.all(noisy == 4095)
    assert np.array_equal(quantise(x, sm), dn)


@pytest.mark.property
def test_property_poisson_part_is_discrete():
    """property: without read noise, the signal is S times an integer
    (photo-electrons), mean x/S."""
    y = add_noise(np.full(50_000, 0.01), (1e-3, 0.0), rng=2) / 1e-3
    assert np.allclose(y, np.round(y)) and abs(y.mean() - 10.0) < 0.05


@pytest.mark.property
def test_property_from_electrons():
    """property: NoiseProfile from the photo-electron scale."""
    sm = SensorModel.from_electrons(8000, 3.0, gain=2.0, width_px=4, height_px=4)
    assert sm.noise_profile == pytest.approx((2 / 8000, (3 * 2 / 8000) ** 2))
    assert sm.electrons_at_white == pytest.approx(4000)

"""The optical image's building blocks (calibration/simulate/optical_image.py):
exact sub-cell polygon coverage, and a PSF array as a sensor kernel.

Kind: property (each test marked).
"""

from __future__ import annotations


import numpy as np
import pytest

from calibration.simulate.optical_image import (
    Kernel,
    edge_profile,
    polygon_coverage,
)
from tests.helpers import gaussian_psf as gaussian


@pytest.mark.property
def test_property_polygon_coverage_is_exact_area():
    """property: sub-cell coverage sums to the polygon's area (shoelace) and
    stays in [0, 1]."""
    v = np.array([[3.2, 1.1], [11.7, 2.9], [9.4, 10.6], [2.5, 8.8]])
    cov = polygon_coverage(v, 0.0, 0.0, 14, 13, 1.0)
    area = 0.5 * abs(np.dot(v[:, 0], np.roll(v[:, 1], -1)) - np.dot(v[:, 1], np.roll(v[:, 0], -1)))
    assert cov.min() >= 0 and cov.max() <= 1
    assert abs(cov.sum() - area) < 1e-9


@pytest.mark.property
def test_property_kernel_keeps_its_moments():
    """property: a PSF array becomes a sensor kernel without a flip (the
    calibration.optics.psf.map convention: rows along +y = down the sensor), its
    centroid in pixels = the PSF's in µm / pixel pitch."""
    g = gaussian(0.8, 0.35, 41, shift_um=(0.7, -0.35))
    k = Kernel.from_psf_array(g, 0.35, 1.4)
    mean, cov = k.moments()
    assert mean == pytest.approx([0.5, -0.25], abs=1e-6)
    assert cov[0, 0] == pytest.approx((0.8 / 1.4) ** 2, rel=1e-4)
    prof = edge_profile(k, (0.0, 1.0))                  # a horizontal edge: the y shift moves it up
    assert float(prof(-0.25)) == pytest.approx(0.5, abs=1e-6)

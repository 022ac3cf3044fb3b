"""Spectral weighting (calibration/optics/psf/spectral.py): Gauss
quadrature exactness (analytic) and polychromatic = weighted sum
(property).
"""

from __future__ import annotations

import numpy as np

import calibration.optics.psf as P
from tests.calibration.optics.psf.helpers import perfect_lens

import pytest

pytestmark = pytest.mark.property


def test_analytic_gauss_quadrature_is_exact_for_polynomials():
    """analytic: an n-node rule for the G channel's spectral measure
    integrates λ^k exactly (1e-10 relative) for k ≤ 2n − 1, nodes inside the
    support, weights positive and summing to the total."""
    wl, c = P.spectral_response("G")
    for n in (1, 2, 3, 5):
        x, w = P.spectral_quadrature(wl, c, n)
        assert np.all(w > 0) and abs(w.sum() - 1) < 1e-12
        assert wl[c > 0].min() <= x.min() and x.max() <= wl[c > 0].max()
        t = (wl - 550.0) / 100.0
        tx = (x - 550.0) / 100.0
        for k in range(2 * n):
            assert np.isclose(np.sum(w * tx ** k), np.sum(c * t ** k), rtol=1e-10, atol=1e-12)


def test_property_polychromatic_is_the_weighted_sum():
    """property: a polychromatic PSF equals Σ w_k PSF(λ_k) on the common grid
    (each monochromatic PSF normalised, same centre) to 1e-14; its
    wavelengths are the Gauss nodes of the channel."""
    lens = perfect_lens()
    kw = {"pupil_samples": 32, "n": 24, "pitch_um": 0.6}
    poly = P.polychromatic_psf(lens, 0.3, "R", method="fft", n_wavelengths=3, **kw)
    assert len(poly.wavelengths_nm) == 3 and abs(sum(poly.weights) - 1) < 1e-12
    acc = sum(w * P.fft_psf(lens, 0.3, lam, center=poly.center_mm, **kw).data
              for lam, w in zip(poly.wavelengths_nm, poly.weights))
    assert np.abs(acc - poly.data).max() < 1e-14
    wl = np.array([500.0, 600.0])
    two = P.polychromatic_psf(lens, 0.3, (wl, [1.0, 3.0]), method="huygens", **kw)
    assert two.wavelengths_nm == (500.0, 600.0) and two.weights == (0.25, 0.75)

"""The PSF record (calibration/optics/psf/result.py): every method's PSF
sums to 1 and rebinning keeps energy and centroid (kind: property).
"""

from __future__ import annotations

import numpy as np

import calibration.optics.psf as P
from tests.calibration.optics.psf.helpers import LAM, perfect_lens

import pytest

pytestmark = pytest.mark.property


def test_property_energy_normalisation_and_resampling():
    """property: every PSF sums to 1 (1e-12); rebinning onto a coarser grid
    that covers the window keeps the energy to 1e-12 and the centroid to
    1e-9 µm (cells split exactly)."""
    lens = perfect_lens()
    ps = [P.huygens_psf(lens, 0.2, LAM, pupil_samples=32, n=32, pitch_um=0.5),
          P.debye_psf(lens, 0.2, LAM, pupil_samples=32, n=32, pitch_um=0.5),
          P.fft_psf(lens, 0.2, LAM, pupil_samples=64, n=32, pitch_um=0.5),
          P.polychromatic_psf(lens, 0.2, "G", method="fft", pupil_samples=32, n=32, pitch_um=0.5)]
    for p in ps:
        assert abs(p.data.sum() - 1) < 1e-12 and p.data.dtype == np.float64
    p = ps[2]
    q = p.resample(1.0, 20)
    assert abs(q.data.sum() - 1) < 1e-12
    assert np.allclose(q.centroid_um, p.centroid_um, atol=1e-9)
    small = p.resample(0.5, 8)
    assert small.data.sum() < 1 and abs(p.resample(0.5, 8, normalize=True).data.sum() - 1) < 1e-12
    assert np.allclose(p.resample(p.pitch_um, p.n).data, p.data, atol=1e-15)

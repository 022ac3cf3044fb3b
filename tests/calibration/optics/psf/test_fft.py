"""FFT PSFs of e9 (calibration/optics/psf/fft.py): coma from a decentred
element, and the PSF centroid on the side of the geometric spot's
(kind: property; the e9 tests need ``../shared/data``).
"""

from __future__ import annotations

import numpy as np

import calibration.optics.psf as P
from calibration.optics import trace as tr
from calibration.optics.perturb import apply
from tests.calibration.optics.psf.helpers import LAM

import pytest

pytestmark = pytest.mark.property


def test_property_decentred_element_gives_coma_on_axis(e9):
    """property: element 1 decentred 5 µm in y (the default tolerance) puts
    coma on axis: the PSF's y-centroid leaves its peak (measured −0.7 µm,
    nominal 0 to 1e-3 µm) and the PSF loses its y-mirror symmetry, while
    x-mirror symmetry (the decenter is in the y–z plane) stays."""
    kw = {"pupil_samples": 64, "n": 49, "pitch_um": 0.2}
    nom = P.fft_psf(e9, 0.0, LAM, **kw)
    dec = P.fft_psf(apply(e9, {"e1.decenter_y": 0.005}), 0.0, LAM, **kw)
    assert abs(nom.centroid_um[1] - nom.peak_um[1]) < 0.01
    assert abs(dec.centroid_um[1] - dec.peak_um[1]) > 0.3
    assert 1 - P.ncc(dec.data, dec.data[::-1]) > 0.05
    assert 1 - P.ncc(nom.data, nom.data[::-1]) < 1e-9
    assert np.abs(dec.data - dec.data[:, ::-1]).max() < 1e-9 * dec.data.max()


def test_property_psf_centroid_follows_the_ray_centroid(e9):
    """property (orientation): at +0.7 field the e9 PSF's centroid lies on
    the same side as the geometric spot's centroid, relative to the chief
    ray, and near it (PSF +0.19 µm, rays +0.15 µm weighted by 1/N; the
    rest is the slowly converging first moment of the flare). A flipped
    row axis would give −0.19."""
    fld = (0.0, 0.7 * e9.half_fov_deg)
    p = P.fft_psf(e9, fld, LAM, pupil_samples=96, n=96, pitch_um=0.3)
    r = tr.pupil_rays(e9, fld, 64, LAM, distribution="grid", aiming="real")
    res = tr.trace_to_image(e9, r)
    pos, nz = res.position[res.valid, :2], res.direction[res.valid, 2]
    geo = ((pos / nz[:, None]).sum(axis=0) / (1 / nz).sum() - np.asarray(p.center_mm)) * 1e3
    assert geo[1] > 0.1 and abs(p.centroid_um[1] - geo[1]) < 0.1
    assert abs(p.centroid_um[0]) < 0.01

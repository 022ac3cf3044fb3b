"""The three diffraction models against closed forms and each other
(calibration/optics/psf/{huygens,fft,debye,strehl}.py).

Kinds, as labelled on each test: analytic — the Airy pattern of an
aberration-free pupil (first dark ring at 1.22 λN, Strehl 1, the Airy
energy inside a square window); property — Huygens ↔ FFT ↔ Debye
agreement, mirror symmetry of the nominal lens and its breaking by a
tilt, bit-for-bit zero perturbation, errors that name the valid choices.

The e9 tests need ``../shared/data`` (they skip with the reason without
it). No published PSF figures exist for these lenses; the thresholds are
stated with the values measured when they were written.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import j1

import calibration.optics.psf as P
from calibration.optics.perturb import apply
from tests.calibration.optics.psf.helpers import FN, LAM, first_zero_um, perfect_lens, real_working_f_number

pytestmark = pytest.mark.property


@pytest.mark.parametrize("method", P.METHODS)
def test_analytic_perfect_lens_airy_zero_and_strehl(method):
    """analytic: the aberration-free singlet's PSF is the Airy pattern: first
    zero at 1.22 λN within 2 % (N = 1/(2 sin u'), the real image-space
    working F/#, 4.09 here; the paraxial 4.0 differs by 2.3 % at this
    aperture because the hyperboloid's sag moves the marginal ray's exit
    point). Measured: +0.7 % (Huygens, Debye), +1.4 % (FFT: its affine
    pupil map). Strehl ≥ 0.99 (1 to 1e-12)."""
    lens = perfect_lens()
    n_w = real_working_f_number(lens)
    p = FN[method](lens, 0.0, LAM, pupil_samples=64, n=65, pitch_um=LAM * 1e-3 * 4.0 / 8)
    airy = 1.22 * LAM * 1e-3 * n_w
    assert abs(first_zero_um(p) / airy - 1) < 0.02
    assert P.strehl_ratio(lens, 0.0, LAM, method=method, pupil_samples=64) >= 0.99


def airy_energy_in_square(half_width_um: float, lam_nm: float, n_w: float) -> float:
    """Share of the Airy pattern's energy inside the square |x|, |y| ≤ a
    (midpoint rule on 1600² points; total energy 4(λN)²/π)."""
    ln = lam_nm * 1e-3 * n_w
    g = (np.arange(1600) + 0.5) / 1600 * 2 * half_width_um - half_width_um
    v = math.pi * np.hypot(g[:, None], g[None, :]) / ln
    i = (2 * j1(v) / v) ** 2
    return float(i.sum() * (g[1] - g[0]) ** 2 / (4 * ln * ln / math.pi))


@pytest.mark.parametrize("method", P.METHODS)
def test_analytic_window_energy_is_the_airy_energy(method):
    """analytic: the absolute normalisation (energy-conserving wavelet
    amplitudes, ``PSF.window_energy``) gives the Airy pattern's energy in
    the sampled square window within 1 % (measured 0.9523 Huygens, 0.9568 FFT
    vs 0.9546)."""
    lens = perfect_lens()
    pitch = LAM * 1e-3 * 4.0 / 8
    p = FN[method](lens, 0.0, LAM, pupil_samples=64, n=65, pitch_um=pitch)
    expect = airy_energy_in_square(32.5 * pitch, LAM, real_working_f_number(lens))
    assert abs(p.window_energy - expect) < 0.01


@pytest.mark.parametrize("frac", [0.0, 0.7])
def test_property_huygens_fft_and_debye_agree_on_e9(e9, frac):
    """property: Huygens and FFT PSFs of e9 on one grid agree: NCC ≥ 0.999
    (the issue asks ≥ 0.98; measured 0.99999 on axis and at 0.7 field); the
    Debye PSF is within 0.2 % of the Huygens peak (measured 0.002 % / 0.01 %);
    the three Strehl ratios within 0.005 (0.900 / 0.833 at 587.6 nm)."""
    fld = (0.0, frac * e9.half_fov_deg)
    kw = {"pupil_samples": 64, "n": 48, "pitch_um": 0.25}
    h = P.huygens_psf(e9, fld, LAM, **kw)
    f = P.fft_psf(e9, fld, LAM, **kw)
    d = P.debye_psf(e9, fld, LAM, **kw)
    assert h.center_mm == f.center_mm == d.center_mm
    assert P.ncc(h.data, f.data) >= 0.999
    assert np.abs(d.data - h.data).max() < 2e-3 * h.data.max()
    s = [P.strehl_ratio(e9, fld, LAM, method=m, pupil_samples=64) for m in P.METHODS]
    assert 0.5 < s[0] < 1 and max(s) - min(s) < 0.005


def mirror_mismatch(lens, theta, method="fft"):
    """Max |PSF(+θy) flipped in y − PSF(−θy)| / peak (odd n: the flip is about the centre sample)."""
    fn = FN[method]
    a = fn(lens, (0.0, theta), LAM, pupil_samples=48, n=33, pitch_um=0.3)
    b = fn(lens, (0.0, -theta), LAM, pupil_samples=48, n=33, pitch_um=0.3)
    return float(np.abs(a.data[::-1] - b.data).max() / a.data.max()), a, b


@pytest.mark.parametrize("method", P.METHODS)
def test_property_nominal_psfs_mirror_in_y(e9, method):
    """property: the nominal lens is symmetric about the x–z plane, so the
    PSFs at ±θy mirror each other (measured 5e-13 of the peak; the real
    aiming's forward differences are not mirror-symmetric, so not 0)."""
    err, a, b = mirror_mismatch(e9, 18.4, method)
    assert err < 1e-9
    assert a.center_mm[0] == b.center_mm[0] == 0.0 and math.isclose(a.center_mm[1], -b.center_mm[1], rel_tol=1e-12)


def test_property_tilted_element_breaks_the_mirror_symmetry(e9):
    """property: element 3 tilted by 0.05° about x (tilt_yz, the default
    tolerance is 0.05°) breaks it measurably (measured 29 % of the peak;
    0.01° gives 6 %)."""
    assert mirror_mismatch(apply(e9, {"e3.tilt_yz": 0.05}), 18.4)[0] > 0.05


@pytest.mark.parametrize("method", P.METHODS)
def test_property_zero_perturbation_is_bit_for_bit_nominal(e9, method):
    """property: a zero perturbation (empty, or zero values) reproduces the
    nominal PSF bit for bit."""
    fn = FN[method]
    kw = {"pupil_samples": 32, "n": 24, "pitch_um": 0.4}
    ref = fn(e9, 20.0, LAM, **kw)
    for pert in ({}, {"e1.decenter_y": 0.0, "s3.thickness": 0.0}):
        p = fn(apply(e9, pert), 20.0, LAM, **kw)
        assert np.array_equal(p.data, ref.data) and p.center_mm == ref.center_mm


def test_property_bad_input_is_refused_with_the_valid_choices():
    """property: errors name the valid choices or what to change."""
    lens = perfect_lens()
    with pytest.raises(P.PSFError, match="valid: huygens, fft, debye"):
        P.polychromatic_psf(lens, 0.0, "G", method="zemax")
    with pytest.raises(P.PSFError, match="'R', 'G', 'B'"):
        P.spectral_response("IR")
    with pytest.raises(P.PSFError, match="'chief', 'centroid'"):
        P.fft_psf(lens, 0.0, LAM, center="peak", pupil_samples=16, n=8)
    with pytest.raises(P.PSFError, match="increase pupil_samples"):
        P.fft_psf(lens, 0.0, LAM, pupil_samples=8, n=64, pitch_um=2.0)
    with pytest.raises(P.PSFError, match="positive integer"):
        P.huygens_psf(lens, 0.0, LAM, n=0)

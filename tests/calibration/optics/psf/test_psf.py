"""Tests of calibration/optics/psf/core.py (Huygens and FFT PSFs) and calibration/optics/psf/map.py.

Kinds, as labelled on each test:

* analytic — against closed forms: the Airy pattern of an aberration-free
  pupil (first dark ring at 1.22 λN, Strehl 1, the Airy energy inside a
  square window), Gauss quadrature exactness;
* property — invariants: Huygens ↔ FFT agreement, mirror symmetry of the
  nominal lens and its breaking by a tilt, coma from a decenter, bit-for-bit
  zero perturbation, energy normalisation, polychromatic = weighted sum,
  the map's symmetry shortcut = the full computation, cache behaviour,
  sensor orientation.

The e9 tests need ``../shared/data`` (they skip with the reason without
it). No published PSF figures exist for these lenses; the thresholds are
stated with the values measured when they were written.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
import pytest
from tests.helpers import data_file
from scipy.special import j1

from calibration.optics.psf import core as P
from calibration.optics.psf import map as M
from calibration.optics import trace as tr
from calibration.optics.lens import Lens, Sensor, Surface
from calibration.optics.materials import Material
from calibration.optics.perturb import apply

LAM = 587.6
FN = {"huygens": P.huygens_psf, "fft": P.fft_psf, "debye": P.debye_psf}


def perfect_lens(n=1.5, c=-0.1, f_number=4.0):
    """Plano-convex singlet, collimated light entering the flat side (the
    stop), leaving through the hyperboloid k = −n²: focuses on axis without
    aberration at f = 1/((1−n)c) behind the vertex (20 mm here)."""
    glass = Material("g", n, math.inf, "constant")
    f = 1.0 / ((1.0 - n) * c)
    return Lens((Surface(0.0, thickness=3.0, material=glass, stop=True), Surface(c, -n * n, (), f)),
                epd=f / f_number, half_fov_deg=1.0, sensor=Sensor(1.0, 200, 150))


def real_working_f_number(lens, lam=LAM):
    """1/(2 n' sin u') of the real marginal ray (image-space NA)."""
    r = tr.pupil_rays(lens, (0, 0), 1, lam, aiming="real", pupil=np.array([[0.0, 1.0]]))
    d = tr.trace_to_exit(lens, r).direction[0]
    return 1.0 / (2.0 * math.hypot(d[0], d[1]))


def first_zero_um(p: P.PSF) -> float:
    """First minimum of the row through the centre, +x side (parabolic refinement)."""
    row = p.data[p.n // 2]
    k = p.n // 2 + 1
    while row[k + 1] < row[k]:
        k += 1
    y0, y1, y2 = row[k - 1], row[k], row[k + 1]
    return float(p.offsets_um()[k] + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2) * p.pitch_um)


@pytest.fixture(scope="module")
def e9():
    from calibration.optics.io.lens_json import read_lens

    return read_lens(data_file("lenses", "phone", "US-12210142-B2-e9.zmx"))


# -- analytic: the aberration-free pupil ----------------------------------------------

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


# -- property: the two methods, symmetry, perturbations ----------------------------------

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


# -- property: normalisation, resampling, polychromatic ------------------------------------

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


# -- property: the map -----------------------------------------------------------------------------

SMALL = {"grid": (3, 4), "channels": ("G", "R"), "n": 16, "pitch_um": 1.0, "pupil_samples": 24, "n_wavelengths": 1,
         "progress": False}


def test_property_sensor_frame_and_regions(e9):
    """property: pixel ↔ image-plane mapping round trips; region centres
    are antisymmetric about the axis; +θy lands on larger rows (image +y is
    down the sensor array); region_of inverts the region bounds."""
    s = e9.sensor
    x, y = M.sensor_to_image([0, s.width_px - 1], [0, s.height_px - 1], s)
    assert np.allclose(x, [-0.5 * (s.width_px - 1) * 1e-3, 0.5 * (s.width_px - 1) * 1e-3])
    assert np.allclose(M.image_to_sensor(x, y, s), [[0, s.width_px - 1], [0, s.height_px - 1]])
    c = M.region_centers_mm(s, (15, 20))
    assert np.array_equal(c, -c[::-1, ::-1])
    f = M.chief_ray_fields(e9, c[[0, 14, 7], [0, 19, 10]])
    assert f[0, 0] < 0 and f[0, 1] < 0 and f[1, 0] > 0 and f[1, 1] > 0 and f[2, 1] == 0
    m = M.PSFMap(np.zeros((15, 20, 1, 3, 3)), 0.5, c, np.zeros((15, 20, 2)), ("G",), s)
    for r, col in [(0, 0), (7, 10), (14, 19), (3, 17)]:
        x0, x1, y0, y1 = m.region_bounds_px(r, col)
        assert m.region_of(x0, y0) == (r, col) and m.region_of(x1 - 1e-6, y1 - 1e-6) == (r, col)
        cx, cy = M.image_to_sensor(*c[r, col], s)
        assert m.region_of(cx, cy) == (r, col)


def test_property_chief_ray_inversion_lands_on_target(e9):
    """property: the real chief ray (real aiming) of the solved field lands
    on the requested image point within 1e-8 mm, corners included."""
    c = M.region_centers_mm(e9.sensor, (15, 20))
    pts = c[[0, 3, 7, 14], [0, 12, 10, 19]]
    fields = M.chief_ray_fields(e9, pts)
    for p, fld in zip(pts, fields):
        r = tr.pupil_rays(e9, tuple(fld), 1, e9.primary_nm, aiming="real", pupil=np.zeros((1, 2)))
        hit = tr.trace_to_image(e9, r, clip=False).position[0, :2]
        assert np.abs(hit - p).max() < 1e-8


def test_property_map_matches_single_psfs_and_symmetry_shortcut(e9, tmp_path):
    """property: the nominal map (symmetry shortcut: one quadrant mirrored)
    equals the full computation to float32 rounding, and each entry equals
    polychromatic_psf at the region's field and centre."""
    sym = M.psf_map(e9, cache=False, **SMALL)
    full = M.psf_map(e9, cache=False, symmetry="none", **SMALL)
    assert sym.psfs.dtype == np.float32 and sym.psfs.shape == (3, 4, 2, 16, 16)
    assert np.allclose(sym.psfs.sum(axis=(3, 4)), 1, atol=1e-6)
    assert np.abs(sym.psfs - full.psfs).max() < 1e-6 * full.psfs.max()
    assert np.allclose(sym.field_deg, full.field_deg, atol=1e-9)
    r, c = 0, 3
    one = P.polychromatic_psf(e9, tuple(sym.field_deg[r, c]), "R", method="debye", n_wavelengths=1,
                              pupil_samples=24, n=16, pitch_um=sym.pitch_um, center=tuple(sym.centers_mm[r, c]),
                              aim_each_wavelength=False)
    got = sym.psf(r, c, "R")
    assert np.abs(got.data - one.data).max() < 1e-6 * one.data.max()
    assert got.center_mm == tuple(sym.centers_mm[r, c])


def test_property_map_cache_and_files(e9, tmp_path):
    """property: a second call hits the cache and returns identical arrays;
    to_npz/from_npz round trips; the key changes with the perturbation and
    not with the lens's name, and a zero perturbation keeps it."""
    a = M.psf_map(e9, cache_dir=tmp_path, **SMALL)
    files = list(tmp_path.glob("*.npz"))
    assert [f.name for f in files] == [f"{a.key}.npz"]
    mtime = files[0].stat().st_mtime_ns
    b = M.psf_map(e9, cache_dir=tmp_path, **SMALL)
    assert np.array_equal(a.psfs, b.psfs) and b.key == a.key and files[0].stat().st_mtime_ns == mtime
    c = M.PSFMap.from_npz(M.PSFMap.to_npz(a, tmp_path / "x" / "map.npz"))
    assert np.array_equal(c.psfs, a.psfs) and c.sensor == a.sensor and c.channels == a.channels
    assert np.array_equal(c.channel_weights, a.channel_weights) and c.settings == a.settings
    st = a.settings
    k0 = M.cache_key(e9, st)
    assert k0 == a.key
    assert M.cache_key(apply(e9, {"e1.decenter_x": 0.0}), st) == k0
    assert M.cache_key(e9.replace(name="other", metadata={"path": "x"}), st) == k0
    assert M.cache_key(apply(e9, {"e1.decenter_x": 1e-4}), st) != k0
    assert M.cache_key(apply(e9, {"m2.nd": 1e-5}), st) != k0
    assert M.cache_key(e9, {**st, "n": 17}) != k0


def test_property_plot_psf_map(e9, tmp_path):
    """property: the mosaic is written."""
    m = M.psf_map(e9, cache=False, **SMALL)
    out = M.plot_psf_map(m, tmp_path / "map.png", channel="G", scale="log")
    assert out.exists() and out.stat().st_size > 1000


@pytest.mark.slow
def test_property_full_map_of_a_perturbed_e9(e9):
    """property (slow): a 15 × 20 × 3 map of a perturbed e9 (no symmetry,
    2 worker processes) is normalised; element 1 decentred by its 5 µm
    tolerance blurs beyond a 16 µm window (32 samples, the default until
    2026-11-26: 71 % of the energy inside, measured) and the map says so
    with a warning."""
    with pytest.warns(UserWarning, match="increase n"):
        m = M.psf_map(apply(e9, {"e1.decenter_y": 0.005}), n=32, cache=False, progress=False, workers=2)
    assert m.psfs.shape == (15, 20, 3, 32, 32)
    assert np.allclose(m.psfs.sum(axis=(3, 4)), 1, atol=1e-5)
    assert 0.6 < m.window_energy.min() < 0.9 and m.window_energy.max() <= 1.0
    assert not np.allclose(m.psfs[7, 10], m.psfs[7, 10, :, ::-1, :], atol=1e-3)


def test_default_window_is_32_um_whatever_the_pixel(e9):
    """property: the default window is :data:`WINDOW_UM` (32 µm) wide, not a
    sample count: on e9's 1 µm pixels 64 samples at 0.5 µm, and there the
    same decentred element 1 keeps ≥ 90 % of every region's energy (0.933
    measured) where 32 samples keep 0.82 and warn; 2.8 µm pixels keep 32
    samples (45 µm)."""
    pl = apply(e9, {"e1.decenter_y": 0.005})
    kw = dict(grid=(3, 4), channels=("G",), n_wavelengths=1, cache=False, progress=False, workers=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = M.psf_map(pl, **kw)
    assert m.psfs.shape[-2:] == (64, 64) and m.psfs.shape[-1] * m.pitch_um == pytest.approx(M.WINDOW_UM)
    assert m.window_energy.min() > M.WINDOW_ENERGY_WARN
    with pytest.warns(UserWarning, match="increase n"):
        narrow = M.psf_map(pl, n=32, **kw)
    assert narrow.window_energy.min() < m.window_energy.min() - 0.05
    assert M.default_psf_n(1.4) == 32 and M.default_psf_n(0.25) == 128


def test_a_map_window_past_the_pupil_replica_period_is_refused(e9):
    """analytic: 64 pupil samples across e9's pupil make the diffracted
    field periodic with period λ·N·64 ≈ 66 µm at G's shortest node (527 nm,
    N = 1.95); 64 samples of 1.4 µm (2.8 µm pixels: 90 µm, what `isp synth --psf-n 64`
    gave there) are refused with the pupil grid that would do; the default
    window on those pixels (32 samples, 45 µm) is not."""
    from calibration.optics.lens import Sensor

    sensor = Sensor(2.807, 2000, 1500)
    kw = dict(grid=(1, 1), channels=("G",), n_wavelengths=1, cache=False, progress=False, workers=1, sensor=sensor)
    with pytest.raises(P.PSFError, match=r"replica period \(≈ 65.7 µm .* pupil_samples ≥ 88 "):
        M.psf_map(e9, n=64, **kw)
    assert M.psf_map(e9, **kw).psfs.shape[-1] == 32


# -- property: the SFR model's batched path = the per-field path ------------------------------
#
# calibration.fit.forward_model traces and diffracts every field node at once (one
# trace per wavelength, batched pupil fits and Debye sums); the per-field
# functions are its oracle. Exact refactors agree to the tracer's Newton
# tolerance (1e-12 mm), i.e. ~1e-10 of the PSF peak.

BATCH_PERTURBATION = {"e1.decenter_x": 0.003, "e3.tilt_yz": 0.03, "s4.thickness": 0.004}
BATCH_POINTS_MM = [[0.0, 0.0], [1.0, 0.5], [-2.6, 1.9], [2.7, -2.0]]   # the last two vignetted


@pytest.fixture(scope="module")
def batch(e9):
    """A perturbed e9, four fields (centre to corner) traced both ways with
    real aiming at 24 pupil samples."""
    pl = apply(e9, BATCH_PERTURBATION)
    fields = M.chief_ray_fields(pl, np.array(BATCH_POINTS_MM))
    samples, lam = 24, 520.0
    pupil = P._pupil_points(samples)
    z_pupil = P._exit_pupil_z(pl)
    rays = tr.field_pupil_rays(pl, fields, pupil, lam, aiming="real")
    tn = P._finish_nodes(pl, rays, tr.trace_to_exit(pl, rays), fields, pupil[:-1], samples, z_pupil)
    singles = []
    for f in fields:
        r = tr.pupil_rays(pl, tuple(f), samples, lam, aiming="real", pupil=pupil)
        singles.append(P._finish(pl, r, tr.trace_to_exit(pl, r), tuple(f), samples, z_pupil))
    return pl, fields, tn, singles


def test_property_batched_rays_match_per_field_rays(batch):
    """property: field_pupil_rays (paraxial and real aiming) and the batched
    trace give every field the rays pupil_rays and _finish give it alone."""
    pl, fields, tn, singles = batch
    assert tn.valid.sum(axis=1).min() < 0.75 * tn.valid.shape[1]          # vignetting is exercised
    for k, one in enumerate(singles):
        node = tn.node(k)
        assert np.array_equal(node.ix, one.ix) and np.array_equal(node.iy, one.iy)
        for name in ("pos", "dirn", "opl", "chief_pos", "chief_dir"):
            np.testing.assert_allclose(getattr(node, name), getattr(one, name), rtol=0, atol=1e-11)
    pupil = P._pupil_points(8)
    both = tr.field_pupil_rays(pl, fields, pupil, 600.0)
    for k, f in enumerate(fields):
        one = tr.pupil_rays(pl, tuple(f), 8, 600.0, aiming="paraxial", pupil=pupil)
        sl = slice(k * len(pupil), (k + 1) * len(pupil))
        np.testing.assert_allclose(both.origin[sl], one.origin, rtol=0, atol=1e-12)
        np.testing.assert_allclose(both.direction[sl], one.direction, rtol=0, atol=1e-15)
        np.testing.assert_allclose(both.opl[sl], one.opl, rtol=0, atol=1e-12)
    with pytest.raises(tr.TraceError, match="aiming"):
        tr.field_pupil_rays(pl, fields, pupil, 600.0, aiming="nope")


def test_property_batched_pupil_fit_matches_per_field_fit(batch):
    """property: the pupil fits of all fields at once (_node_jacobians) equal
    the per-field fit; a field with too few rays for degree 4 takes the
    per-field path."""
    _, _, tn, singles = batch
    for k, one in enumerate(singles):
        np.testing.assert_allclose(tn.jac[k, tn.valid[k]], P._solid_angle_jacobian(one.p, one.dirn), rtol=1e-10)
        assert np.all(tn.jac[k, ~tn.valid[k]] == 0)
    few = tn.valid.copy()
    keep = np.flatnonzero(few[0])[:40]
    few[0] = False
    few[0, keep] = True
    j = P._node_jacobians(tn.p, tn.dirn, few)
    np.testing.assert_allclose(j[0, keep], P._solid_angle_jacobian(tn.p[keep], tn.dirn[0, keep]), rtol=1e-12)


@pytest.mark.parametrize("dz_um", [0.0, 4.0])
def test_property_batched_debye_psfs_match_per_field_psfs(batch, dz_um):
    """property: _debye_nodes in complex128 gives the per-field Debye PSFs
    (_mono of _sphere) to 1e-9 of the peak, in focus and with a per-field
    image-plane shift; its complex64 default stays within 1e-6."""
    _, _, tn, singles = batch
    o = P._grid_offsets_mm(24, 0.5)
    z = tn.z_image + dz_um * 1e-3 * np.array([1.0, -1.0, 0.5, 0.0])
    centre = tn.chief_image_points(z)
    ref = np.stack([P._mono(P._sphere(tn.node(k, z[k]), centre[k]), "debye", o, o)[0] for k in range(len(tn))])
    single = np.stack([P._mono(P._sphere(dataclasses.replace(one, z_image=z[k]), centre[k]), "debye", o, o)[0]
                       for k, one in enumerate(singles)])
    np.testing.assert_allclose(single, ref, rtol=0, atol=1e-9 * ref.max())
    exact = P._debye_nodes(tn, centre, z, o, o, dtype=np.complex128)
    np.testing.assert_allclose(exact, ref, rtol=0, atol=1e-9 * ref.max())
    np.testing.assert_allclose(P._debye_nodes(tn, centre, z, o, o), ref, rtol=0, atol=1e-6 * ref.max())
    # and each field's window energy is the per-field PSF's (PSF.window_energy)
    e_ref = [P._mono(P._sphere(tn.node(k, z[k]), centre[k]), "debye", o, o)[1] for k in range(len(tn))]
    np.testing.assert_allclose(P._debye_nodes(tn, centre, z, o, o, dtype=np.complex128, energy=True)[1], e_ref,
                               rtol=1e-9)


@pytest.mark.parametrize("one_thread", [True, False])
@pytest.mark.parametrize("dtype", [np.complex128, np.complex64])
def test_property_gemm_paths_agree(monkeypatch, one_thread, dtype):
    """property: _a_bt (one complex GEMM, or real GEMMs in blocks that
    OpenBLAS keeps on one thread) is a @ bᵀ."""
    monkeypatch.setattr(P, "_blas_on_one_thread", lambda: one_thread)
    rng = np.random.default_rng(1)
    a, b = ((rng.standard_normal((3, n, 301)) + 1j * rng.standard_normal((3, n, 301))).astype(dtype) for n in (5, 7))
    ref = np.einsum("kim,kjm->kij", a.astype(complex), b.astype(complex))
    tol = 1e-12 if dtype == np.complex128 else 2e-5
    np.testing.assert_allclose(P._a_bt(a, b), ref, rtol=0, atol=tol * np.abs(ref).max())


@pytest.mark.parametrize("n", [1, 2, 7, 32])
def test_property_phasor_doubling_is_the_exponential(n):
    """property: the phasor tables by doubling equal exp(i k o)·scale."""
    rng = np.random.default_rng(2)
    k = rng.uniform(-2e4, 2e4, (2, 50))
    o = (np.arange(n) - n // 2) * 4e-4
    scale = rng.standard_normal((2, 50)) + 1j * rng.standard_normal((2, 50))
    ref = scale[..., None, :] * np.exp(1j * k[..., None, :] * o[:, None])
    np.testing.assert_allclose(P._phasors(k, o, scale=scale), ref, rtol=1e-12)   # phases up to 130 rad
    np.testing.assert_allclose(P._phasors(k, o, scale=scale, dtype=np.complex64), ref, rtol=2e-6)


def test_property_row_medians():
    """property: the masked row medians equal np.median of each row's kept
    values (odd, even and empty rows)."""
    rng = np.random.default_rng(3)
    a = rng.standard_normal((5, 9))
    mask = rng.random((5, 9)) < 0.6
    mask[0] = True
    mask[1] = False
    mask[2, :] = False
    mask[2, [1, 4]] = True
    got = P._row_medians(a, mask)
    assert np.isnan(got[1])
    for i in (0, 2, 3, 4):
        assert got[i] == np.median(a[i][mask[i]])


def test_property_dropping_failed_rays_and_fitted_start_change_nothing(batch, monkeypatch):
    """property: dropping failed rays from a chunk (done without ``record``)
    and starting Newton from the fitted conic (trace._start_conic) leave
    the traced rays as the plain loop has them, to the Newton tolerance."""
    pl, fields, _, _ = batch
    rays = tr.field_pupil_rays(pl, fields, P._pupil_points(24), 520.0, aiming="real")
    fast = tr.trace_to_exit(pl, rays)
    kept = tr.trace_to_exit(pl, rays, record=True)            # carries failed rays as placeholders
    geo = tr._compile(pl, 520.0)
    assert any(s.start != (s.c, s.kc2) for s in geo if s.kind == tr._ASPHERE)
    monkeypatch.setattr(tr, "_start_conic", lambda c, kc2, *_: (c, kc2))
    base = tr.trace_to_exit(pl, rays)                         # Newton from the base conics
    assert not fast.valid.all()
    for other in (kept, base):
        assert np.array_equal(fast.status, other.status) and np.array_equal(fast.surface, other.surface)
        np.testing.assert_allclose(fast.position, other.position, rtol=0, atol=1e-11)
        np.testing.assert_allclose(fast.direction, other.direction, rtol=0, atol=1e-11)
        np.testing.assert_allclose(fast.opl, other.opl, rtol=0, atol=1e-11)

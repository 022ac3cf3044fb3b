"""Simulated captures (paper eq. 14): edge and chart rendering, Bayer
sampling, relative illumination, Poisson–Gaussian noise, quantisation, DNG
output (calibration.simulate.capture, optical_image, chart, sensor, and
calibration.optics.illumination).

Kinds, as marked on each test:

* property (analytic) — against a closed form (the exact Gaussian slanted edge of
  calibration.sfr.synthetic, the separable Gaussian rectangle, the cos⁴ law of a
  thin lens with its stop at the lens), at the tolerance of the method;
* published — against a cited figure (../shared/data/lenses/README.md);
* property — round trips, statistics, invariances, reproducibility.

PSF maps here are calibration.optics.psf.map.PSFMap objects filled with Gaussian
PSFs (no ray tracing), so the tests run in seconds.
"""

from __future__ import annotations

import math
import time
from types import SimpleNamespace

import numpy as np
import pytest

from calibration.optics.illumination import (
    RelativeIllumination,
    relative_illumination,
    ri_cos4,
)
from calibration.simulate.capture import (
    Chart,
    ImagingError,
    SensorModel,
    Shape,
    _map_weights,
    blur_image,
    render_chart,
    render_slanted_edge,
    shading_gain_maps,
    simulate_capture,
    slanted_square_chart,
    write_capture,
)
from calibration.simulate.optical_image import (
    Kernel,
    KernelBank,
    aperture_decimate,
    convolve,
    edge_profile,
    polygon_coverage,
)
from calibration.optics.lens import Lens, Sensor, Surface
from calibration.optics.materials import model_material
from calibration.optics.psf.map import PSFMap, region_centers_mm
from calibration.simulate.sensor import (
    SensorError,
    add_noise,
    dn_to_linear,
    expose,
    mosaic,
    quantise,
)
from calibration.sfr.esfr import measure_sfr
from calibration.sfr.synthetic import _int_phi, mtf50_of
from calibration.sfr.synthetic import render_slanted_edge as exact_edge
from isp.frame import CFA
from tests.helpers import reference

E9 = reference("lens_figures.json")["e9"]

# -- fixtures -----------------------------------------------------------------------

def gaussian(sigma_um: float, pitch_um: float, n: int = 65, *, sigma_y_um: float | None = None,
             theta_deg: float = 0.0, shift_um=(0.0, 0.0)) -> np.ndarray:
    """(n, n) samples of a (rotated, elliptical, shifted) Gaussian, summing
    to 1, in the calibration.optics.psf.result grid convention (centre n//2)."""
    o = (np.arange(n) - n // 2) * pitch_um
    x, y = np.meshgrid(o - shift_um[0], o - shift_um[1])
    t = math.radians(theta_deg)
    u, v = x * math.cos(t) + y * math.sin(t), -x * math.sin(t) + y * math.cos(t)
    sy = sigma_um if sigma_y_um is None else sigma_y_um
    g = np.exp(-0.5 * (u * u / sigma_um ** 2 + v * v / sy ** 2))
    return g / g.sum()


def psf(data, pitch_um):
    return SimpleNamespace(data=np.asarray(data), pitch_um=float(pitch_um), center_mm=(0.0, 0.0))


def gaussian_map(sensor: Sensor, grid, sigma_um, pitch_um: float | None = None, n: int = 49) -> PSFMap:
    """A PSFMap of Gaussians; ``sigma_um(row, col, channel)`` → σ in µm."""
    pitch = sensor.pixel_pitch_um / 4 if pitch_um is None else pitch_um
    rows, cols = grid
    ps = np.empty((rows, cols, 3, n, n), np.float32)
    for r in range(rows):
        for c in range(cols):
            for k in range(3):
                ps[r, c, k] = gaussian(sigma_um(r, c, k), pitch, n)
    return PSFMap(ps, pitch, region_centers_mm(sensor, grid), np.zeros((rows, cols, 2)), ("R", "G", "B"), sensor)


def box_gaussian_cdf(t, sigma: float, a: float = 1.0):
    """Φ(t/σ) averaged over a pixel aperture of width a (pixels)."""
    return sigma / a * (_int_phi((t + a / 2) / sigma) - _int_phi((t - a / 2) / sigma))


def smooth_ri(sensor: Sensor, corner: float = 0.36) -> RelativeIllumination:
    """A smooth phone-like falloff, ``corner`` at the sensor's corner."""
    hd = sensor.half_diagonal_mm
    r = np.linspace(0.0, 1.05 * hd, 24)
    return RelativeIllumination.from_samples(r, 1.0 - (1.0 - corner) * (r / hd) ** 2)


def thin_singlet(f_mm: float = 20.0, f_number: float = 10.0, sensor: Sensor | None = None) -> Lens:
    """Equiconvex n = 1.5 singlet, stop at its front surface, image at the
    paraxial focus: distortion-free to third order."""
    from calibration.optics import paraxial
    r = 2 * 0.5 * f_mm
    lens = Lens((Surface(curvature=1 / r, thickness=0.3, material=model_material(1.5), stop=True),
                 Surface(curvature=-1 / r, thickness=f_mm)), f_number=f_number, half_fov_deg=20.0,
                sensor=sensor or Sensor(1.0, 400, 300), name="test singlet")
    return lens.with_surface(1, thickness=paraxial.first_order(lens).bfl)


# -- analytic: edges --------------------------------------------------------------------

@pytest.mark.property
@pytest.mark.parametrize("angle", [0.0, 5.0, 10.0, 26.565, 45.0])
@pytest.mark.parametrize("horizontal", [False, True])
@pytest.mark.parametrize("sigma_px,q", [(0.6, 0.25), (1.0, 0.25), (1.0, 0.5), (2.0, 0.5)])
def test_analytic_edge_matches_exact_gaussian(angle, horizontal, sigma_px, q):
    """analytic: a slanted edge through a Gaussian PSF object (pixel pitch
    1.4 µm, PSF pitch q·1.4 µm) and the square pixel aperture equals
    calibration.sfr.synthetic's exact rendering. Required < 1e-3 of the step;
    the exact edge-area integral reaches ~2e-6 (tolerance 2e-5), at 0° and
    45° too (where the PSF's projected samples form a coarse comb that the
    band-limiting low-pass removes)."""
    pitch = 1.4
    p = psf(gaussian(sigma_px * pitch, q * pitch, 129), q * pitch)
    h, w = 40, 56
    centre = (123.3, 77.8)
    r = render_slanted_edge(p, centre, (h, w), angle, horizontal=horizontal, pixel_pitch_um=pitch)
    x0, y0 = r.box[:2]
    ref = exact_edge((h, w), angle, sigma_px, center=(centre[0] - x0, centre[1] - y0), horizontal=horizontal)
    for c in range(3):
        assert np.abs(r.optical[:, :, c] - ref).max() < 2e-5


@pytest.mark.property
@pytest.mark.parametrize("angle", [5.0, 10.0])
def test_analytic_edge_mtf50(angle):
    """analytic: measure_sfr on the rendered edge gives the analytic MTF50
    of Gaussian ⊗ pixel (sfr_synth.mtf50_of) within 0.5 % (σ = 1 px; the
    e-SFR's ¼-px binning alone lowers it by ≈ 0.24 %, calibration.sfr.esfr)."""
    p = psf(gaussian(1.0, 0.25, 65), 0.25)
    r = render_slanted_edge(p, (300.0, 200.0), (100, 128), angle, pixel_pitch_um=1.0)
    res = measure_sfr(r.optical[:, :, 1])
    assert abs(res.mtf50 / mtf50_of(1.0, angle) - 1.0) < 0.005


@pytest.mark.property
def test_analytic_fill_factor_edge():
    """analytic: a fill factor of 0.64 is a centred aperture of 0.8 px:
    the axis-aligned edge is Φ averaged over 0.8 px."""
    p = psf(gaussian(0.7, 0.25, 65), 0.25)
    r = render_slanted_edge(p, (50.0, 50.0), (8, 20), 0.0, pixel_pitch_um=1.0, fill_factor=0.64, low=0.0, high=1.0)
    x = np.arange(r.box[0], r.box[0] + 20) - 50.0
    assert np.abs(r.optical[0, :, 0] - box_gaussian_cdf(x, 0.7, 0.8)).max() < 2e-5


# -- analytic: polygons and corners ---------------------------------------------------------

@pytest.mark.property
def test_analytic_rectangle_with_corners():
    """analytic: an axis-aligned rectangle through an isotropic Gaussian
    (σ = 1 px) and the pixel box is separable,
    ``[G(x − x0) − G(x − x1)]·[G(y − y0) − G(y − y1)]``. Edges are exact
    (< 2e-5); the corners, rendered on the 8× supersampled grid, within
    5e-4 of the step (measured 2.0e-4)."""
    sensor = Sensor(1.0, 120, 100)
    pm = gaussian_map(sensor, (1, 1), lambda r, c, k: 1.0, pitch_um=0.25, n=65)
    x0, x1, y0, y1 = 30.3, 80.6, 20.7, 70.2
    shape = Shape(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]), 0.0)
    chart = Chart((100, 120), 1.0, (shape,))
    r = render_chart(chart, pm, SensorModel.from_sensor(sensor), rgb=True, noise=False)
    X, Y = np.meshgrid(np.arange(120.0), np.arange(100.0))
    cov = (box_gaussian_cdf(X - x0, 1.0) - box_gaussian_cdf(X - x1, 1.0)) * \
          (box_gaussian_cdf(Y - y0, 1.0) - box_gaussian_cdf(Y - y1, 1.0))
    err = np.abs(r.optical[:, :, 1] - (1.0 - cov))
    assert err.max() < 5e-4
    assert err[40:50, :].max() < 2e-5 and err[:, 50:60].max() < 2e-5      # mid-edges: exact


@pytest.mark.property
def test_property_chart_matches_supersampled_bruteforce():
    """property: a 5° square through an anisotropic, off-centre PSF (a
    rotated elliptical Gaussian plus a displaced weak lobe: coma-like)
    rendered by render_chart (exact edges + 8× corners) agrees with a
    brute-force 16× supersampled rendering of the whole frame within 1e-3
    of the step."""
    sensor = Sensor(1.0, 96, 80)
    g = 0.85 * gaussian(0.9, 0.25, 65, sigma_y_um=0.6, theta_deg=30) + \
        0.15 * gaussian(0.8, 0.25, 65, shift_um=(1.2, 0.7))
    pm = PSFMap(np.broadcast_to(g.astype(np.float32), (1, 1, 3, 65, 65)).copy(), 0.25,
                region_centers_mm(sensor, (1, 1)), np.zeros((1, 1, 2)), ("R", "G", "B"), sensor)
    chart = slanted_square_chart(80, 96, (1, 1), fill=0.6)
    r = render_chart(chart, pm, SensorModel.from_sensor(sensor), rgb=True, noise=False)
    s = 16
    k = KernelBank.from_psf(pm).resampled((0, 0), 1, 1 / s)
    cov = polygon_coverage(chart.shapes[0].vertices, -0.5 + 0.5 / s, -0.5 + 0.5 / s, 96 * s, 80 * s, 1 / s)
    brute = chart.background[1] + (chart.shapes[0].level[1] - chart.background[1]) * \
        aperture_decimate(convolve(cov, k), s)
    assert np.abs(r.optical[:, :, 1] - brute).max() < 1e-3


@pytest.mark.property
def test_property_polygon_coverage_is_exact_area():
    """property: sub-cell coverage sums to the polygon's area (shoelace) and
    stays in [0, 1]."""
    v = np.array([[3.2, 1.1], [11.7, 2.9], [9.4, 10.6], [2.5, 8.8]])
    cov = polygon_coverage(v, 0.0, 0.0, 14, 13, 1.0)
    area = 0.5 * abs(np.dot(v[:, 0], np.roll(v[:, 1], -1)) - np.dot(v[:, 1], np.roll(v[:, 0], -1)))
    assert cov.min() >= 0 and cov.max() <= 1
    assert abs(cov.sum() - area) < 1e-9


# -- raster scenes: tiles and seams -------------------------------------------------------

@pytest.mark.property
def test_property_tiled_blur_equals_whole_frame_convolution(rng):
    """property: per-region-tile convolution with identical PSFs in every
    region equals one whole-frame convolution (tiling adds no seam: the
    tiles are padded from the neighbouring scene), for both blends."""
    sensor = Sensor(1.0, 90, 64)
    pm = gaussian_map(sensor, (2, 3), lambda r, c, k: 1.1, pitch_um=0.5, n=33)
    img = rng.random((64, 90, 3))
    whole = convolve(img[:, :, 1], KernelBank.from_psf(pm).resampled((0, 0), 1, 1.0))
    for blend in ("nearest", "bilinear"):
        out = blur_image(img, pm, blend=blend)
        assert np.abs(out[:, :, 1] - whole).max() < 1e-12


@pytest.mark.property
def test_property_blend_of_distinct_psfs(rng):
    """property: with different PSFs per region, "nearest" is each region's
    own convolution and "bilinear" the tent-weighted sum of the regions'
    convolutions. The seam of "nearest" (the step across the border beyond
    the texture's own) is the difference of the neighbours' images, ≈ 0.07
    of the texture's range here; "bilinear" has none beyond the 1/40 px⁻¹
    change of its weights."""
    sensor = Sensor(1.0, 80, 40)
    pm = gaussian_map(sensor, (1, 2), lambda r, c, k: (0.6, 2.0)[c], pitch_um=0.5, n=49)
    img = rng.random((40, 80))
    bank = KernelBank.from_psf(pm)
    c0 = convolve(img, bank.resampled((0, 0), 1, 1.0))
    c1 = convolve(img, bank.resampled((0, 1), 1, 1.0))
    near = blur_image(img, pm, blend="nearest")
    assert np.abs(near[:, :40] - c0[:, :40]).max() < 1e-12 and np.abs(near[:, 40:] - c1[:, 40:]).max() < 1e-12
    x = np.arange(80.0)
    t = np.clip((x - 19.5) / 40.0, 0.0, 1.0)          # region centres at x = 19.5 and 59.5
    blend = blur_image(img, pm, blend="bilinear")
    assert np.abs(blend - ((1 - t) * c0 + t * c1)).max() < 1e-12
    # the seam: the step across the border beyond the texture's own step
    seam_nearest = np.abs((near[:, 40] - near[:, 39]) - (c1[:, 40] - c1[:, 39])).mean()
    own = (1 - t[40]) * (c0[:, 40] - c0[:, 39]) + t[40] * (c1[:, 40] - c1[:, 39])
    seam_bilinear = np.abs((blend[:, 40] - blend[:, 39]) - own).mean()
    assert seam_nearest > 0.05                         # σ 0.6 vs 2.0 px on uniform noise: ≈ 0.07
    assert seam_bilinear < 0.05 * seam_nearest         # the weights move by 1/40 per pixel


@pytest.mark.property
def test_property_supersampled_raster_matches_vector_chart():
    """property: a chart rasterised at 8× (exact sub-cell coverage) and blurred
    by blur_image(supersample=8) agrees with the vector renderer within
    5e-4 (both O(h²) on the sub-cells at the corners; exact edges)."""
    sensor = Sensor(1.0, 100, 80)
    pm = gaussian_map(sensor, (1, 1), lambda r, c, k: (0.8, 1.0, 1.3)[k], pitch_um=0.25, n=65)
    chart = slanted_square_chart(80, 100, (1, 1))
    vec = render_chart(chart, pm, SensorModel.from_sensor(sensor), rgb=True, noise=False).optical
    ras = blur_image(chart.rasterize(8), pm, supersample=8)
    assert np.abs(vec - ras)[6:-6, 6:-6].max() < 5e-4


# -- Bayer sampling -------------------------------------------------------------------------

@pytest.mark.property
@pytest.mark.parametrize("cfa", list(CFA))
def test_property_bayer_sites_take_their_channel(cfa):
    """property: with a different PSF (σ = 0.7, 1.0, 1.5 px) and level per
    channel, every CFA site of the rendered edge equals the exact edge of
    its own channel; an odd ROI origin shifts the phase."""
    sigmas, lows, highs = (0.7, 1.0, 1.5), (0.1, 0.2, 0.3), (0.5, 0.7, 0.9)
    psfs = [psf(gaussian(s, 0.25, 97), 0.25) for s in sigmas]
    sm = SensorModel(pixel_pitch_um=1.0, width_px=200, height_px=160, cfa=cfa)
    centre = (101.5, 79.5)
    r = render_slanted_edge(psfs, centre, (30, 46), 8.0, low=lows, high=highs, sensor=sm, noise=False)
    x0, y0 = r.box[:2]
    assert (x0, y0) == (79, 65)                         # both odd: the phase changes
    assert r.cfa == cfa.shifted(y0, x0)
    pat = r.cfa.pattern
    for i in range(2):
        for j in range(2):
            c = int(pat[i, j])
            ref = exact_edge((30, 46), 8.0, sigmas[c], low=lows[c], high=highs[c], center=(centre[0] - x0, centre[1] - y0))
            assert np.abs(r.signal[i::2, j::2] - ref[i::2, j::2]).max() < 2e-5


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
def test_property_noise_on_a_simulated_flat_capture():
    """property: the whole path (PSF map, chart-free raster scene, CFA,
    noise, quantisation) keeps the NoiseProfile: per CFA channel, the
    variance of a flat capture is S·x + O within 3 %."""
    sensor = Sensor(1.0, 400, 300)
    pm = gaussian_map(sensor, (3, 4), lambda r, c, k: 1.0, pitch_um=0.5, n=33)
    sm = SensorModel.from_sensor(sensor, cfa="GRBG", noise_profile=(4e-4, 1e-5))
    levels = np.array([0.2, 0.5, 0.35])
    scene = np.broadcast_to(levels, (300, 400, 3))
    raw, _ = simulate_capture(None, scene, psfmap=pm, sensor=sm, lens_shading="none", rng=3)
    y = dn_to_linear(raw, sm)
    pat = np.tile(sm.cfa.pattern, (150, 200))
    for c in range(3):
        v = y[pat == c]
        assert abs(v.mean() - levels[c]) < 5 * math.sqrt((4e-4 * levels[c] + 1e-5) / v.size)
        assert abs(v.var() / (4e-4 * levels[c] + 1e-5) - 1.0) < 0.03


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


# -- relative illumination -----------------------------------------------------------------

@pytest.mark.property
def test_analytic_ri_cos4_thin_lens():
    """analytic: a thin F/10 singlet with its stop at the lens is free of
    distortion (third order) and pupil aberration, so flux conservation
    gives the cos⁴ law: within 0.003 of cos⁴θ up to 20° (measured ≤ 0.002;
    the real singlet's residual distortion is ≈ 0.4 %), 1 on axis, falling
    monotonically."""
    lens = thin_singlet()
    ri = relative_illumination(lens, samples=5, max_height_mm=20 * math.tan(math.radians(20)), pupil_samples=32)
    assert ri.value[0] == 1.0 and ri.height_mm[0] == 0.0
    assert np.all(np.diff(ri.value) < 0)
    assert np.abs(ri.value - ri_cos4(ri.field_deg)).max() < 0.003
    assert ri.transmitted.min() == 1.0


@pytest.mark.property
def test_property_ri_image_space_assumes_a_focused_image():
    """property: Rimmer's image-space solid angle assumes the sensor is the
    bundles' focus; on the field-curved singlet the off-axis bundles focus
    before the sensor and it *rises* off axis (documented in
    calibration.optics.illumination), while flux conservation falls as cos⁴."""
    lens = thin_singlet()
    h = 20 * math.tan(math.radians(15))
    img = relative_illumination(lens, samples=3, max_height_mm=h, pupil_samples=24, method="image_space")
    flux = relative_illumination(lens, samples=3, max_height_mm=h, pupil_samples=24)
    assert img.value[-1] > 1.0 > flux.value[-1]


@pytest.mark.property
def test_property_ri_on_sensor():
    """property: the per-pixel map is 1 at the centre, falls toward the
    corners and is symmetric; beyond the last sample the last value holds."""
    sensor = Sensor(2.0, 64, 48)
    ri = smooth_ri(sensor)
    m = ri.on_sensor(sensor)
    assert m.shape == (48, 64)
    assert abs(m[23:25, 31:33].mean() - 1.0) < 1e-3
    assert np.allclose(m, m[::-1, ::-1]) and np.allclose(m, m[:, ::-1])
    assert m.min() == pytest.approx(m[0, 0]) and m[0, 0] < 0.4
    assert float(ri(10.0)) == pytest.approx(float(ri.value[-1]))


@pytest.mark.published
def test_published_e9_relative_illumination(e9_lens):
    """published + property: US-12210142-B2-e9 (F/1.95, 36.8° half field;
    ../shared/data/lenses/README.md: "about 77 % of the stop-filling rays
    pass at 0.7 field and 46 % at full field"). The transmitted fractions
    of the RI bundles match within ±2 points (as tests/calibration/optics/test_trace.py's
    vignetting test; 2-digit figure, grid of 64 across); RI falls monotonically from 1 and, at the sensor
    corner, lies in a plausible phone range (0.1–0.4; we get ≈ 0.18, with
    a vignetting cliff over the last 20 µm). Flux conservation and Rimmer's
    image-space method agree within 1 % of the axial value."""
    flux = relative_illumination(e9_lens, samples=9, pupil_samples=32)
    img = relative_illumination(e9_lens, samples=9, pupil_samples=32, method="image_space")
    assert flux.value[0] == 1.0
    assert np.all(np.diff(flux.value) <= 1e-3)
    corner = float(flux(e9_lens.sensor.half_diagonal_mm))
    assert 0.1 < corner < 0.4
    at = relative_illumination(e9_lens, fields_deg=[0.7 * e9_lens.half_fov_deg, e9_lens.half_fov_deg], pupil_samples=64)
    (f07, t07), (f10, t10) = ((v["field"], v["fraction"]) for v in E9["vignetting_pass_fraction"])
    assert (f07, f10) == (0.7, 1.0)
    assert abs(at.transmitted[1] - t07) < 0.02 and abs(at.transmitted[2] - t10) < 0.02
    common = np.intersect1d(np.round(flux.height_mm, 9), np.round(img.height_mm, 9))
    a = flux(common)
    b = img(common)
    assert np.abs(a - b).max() < 0.01


# -- DNG round trip and the ISP ---------------------------------------------------------------

@pytest.fixture(scope="module")
def flat_capture(tmp_path_factory):
    """A flat 400×300 capture with a smooth RI (0.36 at the corner) and
    GainMaps, noise-free, written as a DNG."""
    sensor = Sensor(1.4, 400, 300)
    pm = gaussian_map(sensor, (3, 4), lambda r, c, k: 1.4, pitch_um=0.7, n=33)
    sm = SensorModel.from_sensor(sensor, cfa="GRBG")
    scene = np.broadcast_to(np.array([0.6, 0.6, 0.6]), (300, 400, 3))
    raw, meta = simulate_capture(None, scene, psfmap=pm, sensor=sm, relative_illumination=smooth_ri(sensor),
                                 noise=False)
    path = write_capture(tmp_path_factory.mktemp("dng") / "flat.dng", capture=(raw, meta))
    return SimpleNamespace(path=path, raw=raw, meta=meta, sensor=sm)


@pytest.mark.property
def test_property_dng_round_trip(flat_capture):
    """property: read_raw gives back the mosaic and the metadata written:
    CFA, black and white levels, NoiseProfile, colour matrix, neutral and
    the four per-phase GainMaps (17 × 23 points, float32 gains)."""
    from isp.io.read import read_raw

    fr = read_raw(flat_capture.path)
    m, w = fr.meta, flat_capture.meta
    assert np.array_equal(fr.data.astype(np.uint16), flat_capture.raw)
    assert m.cfa is CFA.GRBG
    assert float(np.ravel(m.black_level)[0]) == 64.0 and m.white_level == (1023.0,)
    assert len(m.noise_profile) == 1 and np.allclose(m.noise_profile[0], (2e-4, 2e-6), rtol=1e-12)
    assert np.allclose(m.color_matrix_1, w.color_matrix_1, atol=1e-6)
    assert m.as_shot_neutral == pytest.approx(w.as_shot_neutral, abs=1e-6)
    ops = m.opcodes[2]
    assert len(ops) == 4 and all(op.name == "GainMap" for op in ops)
    for got, want in zip(ops, w.opcodes[2]):
        assert got.gains.shape == (17, 23, 1)
        assert np.array_equal(got.gains, want.gains)
        assert (got.area.top, got.area.left, got.area.row_pitch, got.area.col_pitch) == \
               (want.area.top, want.area.left, 2, 2)


@pytest.mark.property
def test_property_black_level_and_lens_shading_flatten_the_capture(flat_capture):
    """property: the ISP's own black_level + lens_shading stages undo the
    simulated relative illumination: 10 × 10-pixel block means of each CFA
    colour vary by < 1 % (measured 0.2 %) over the frame."""
    from isp.pipeline import Pipeline
    from isp.io.read import read_raw

    out = Pipeline.from_names(["black_level", "lens_shading"]).run(read_raw(flat_capture.path))
    x = np.asarray(out.data, dtype=np.float64)
    pat = np.tile(CFA.GRBG.pattern, (150, 200))
    for c in range(3):
        b = np.nanmean(np.where(pat == c, x, np.nan).reshape(30, 10, 40, 10), axis=(1, 3))
        assert (b.max() - b.min()) / b.mean() < 0.01


@pytest.mark.property
def test_property_capture_goes_through_the_default_pipeline(flat_capture):
    """property: the simulated DNG runs through `isp process`'s default
    pipeline to display RGB like a real capture."""
    from isp.frame import Domain
    from isp.pipeline import Pipeline
    from isp.io.read import read_raw

    seen = []
    Pipeline.default().run(read_raw(flat_capture.path), on_step=lambda i, st, fr, dt: seen.append(fr.domain))
    assert Domain.DISPLAY_RGB in seen or Domain.ENCODED in seen


@pytest.mark.property
def test_property_gain_map_weights_match_the_reader():
    """property: the LSQ fit's interpolation weights are the DNG SDK's
    (isp.opcodes.GainMap.evaluate)."""
    from isp.opcodes import GainMap

    g = np.random.default_rng(0).random((5, 7)).astype(np.float32)
    op = GainMap.spanning_image(g)
    rows, cols = np.arange(0, 30, 3), np.arange(0, 44, 5)
    want = op.evaluate(rows, cols, 30, 44).astype(np.float64)
    got = _map_weights(rows, 30, 5) @ g.astype(np.float64) @ _map_weights(cols, 44, 7).T
    assert np.abs(got - want).max() < 1e-5


# -- charts through the whole path -----------------------------------------------------------

@pytest.mark.property
def test_property_chart_roi_matches_its_region():
    """property: a chart on a 3 × 4 PSF map (σ by column: 1.0, 1.25, 1.5,
    1.75 px) renders each square with its own region's PSF: an edge ROI
    of region (1, 2) equals the exact Gaussian edge of σ = 1.5 px (< 2e-5),
    and its e-SFR gives that region's analytic MTF50 within 1.5 % (the
    55-px-wide ROI's LSF window alone adds ≈ 0.9 %, calibration.sfr.esfr notes)."""
    sensor = Sensor(1.0, 800, 600)
    sig = lambda r, c, k: 1.0 + 0.25 * c
    pm = gaussian_map(sensor, (3, 4), sig, pitch_um=0.5, n=41)
    chart = slanted_square_chart(600, 800, (3, 4))
    r = render_chart(chart, pm, SensorModel.from_sensor(sensor), rgb=True, noise=False)
    roi = next(q for q in chart.rois if q.cell == (1, 2) and q.side == "right")
    x, y, w, h = roi.box
    sq = next(s for s in chart.shapes if s.cell == (1, 2))
    ref = exact_edge((h, w), roi.angle_deg, 1.5, low=sq.level[1], high=chart.background[1],
                     center=(roi.point[0] - x, roi.point[1] - y))
    got = r.optical[y:y + h, x:x + w, 1]
    assert np.abs(got - ref).max() < 2e-5
    res = measure_sfr(got)
    assert abs(res.mtf50 / mtf50_of(1.5, roi.angle_deg) - 1.0) < 0.015


@pytest.mark.property
def test_property_reproducible_with_a_seed():
    """property: the same seed gives the same mosaic; another seed another."""
    sensor = Sensor(1.0, 200, 150)
    pm = gaussian_map(sensor, (2, 2), lambda r, c, k: 1.0, pitch_um=0.5, n=33)
    chart = slanted_square_chart(150, 200, (2, 2), colorchecker=False)
    sm = SensorModel.from_sensor(sensor)
    kw = {"psfmap": pm, "sensor": sm, "relative_illumination": smooth_ri(sensor)}
    a, _ = simulate_capture(None, chart, rng=11, **kw)
    b, _ = simulate_capture(None, chart, rng=np.random.default_rng(11), **kw)
    c, _ = simulate_capture(None, chart, rng=12, **kw)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert a.dtype == np.uint16 and a.shape == (150, 200)


@pytest.mark.property
def test_property_colorchecker_chart():
    """property: the ColorChecker chart puts 24 patches in the central 4 × 6
    cells; a rendered patch centre has its camera RGB (no blur reaches it)."""
    chart = slanted_square_chart(300, 400, (6, 8), colorchecker=True)
    patches = [s for s in chart.shapes if s.kind == "patch"]
    assert len(patches) == 24
    sensor = Sensor(1.0, 400, 300)
    pm = gaussian_map(sensor, (1, 1), lambda r, c, k: 1.0, pitch_um=0.5, n=33)
    r = render_chart(chart, pm, SensorModel.from_sensor(sensor), rgb=True, noise=False)
    p = patches[7]
    cx, cy = p.vertices.mean(axis=0)
    assert np.allclose(r.optical[round(cy), round(cx)], p.level, atol=1e-9)


# -- bad input -------------------------------------------------------------------------------------

@pytest.mark.property
def test_bad_input_is_refused_with_the_reason():
    """property: errors at the public boundary name the problem."""
    sensor = Sensor(1.0, 40, 30)
    sm = SensorModel.from_sensor(sensor)
    pm = gaussian_map(sensor, (1, 1), lambda r, c, k: 1.0, pitch_um=0.5, n=17)
    with pytest.raises(ImagingError, match="blend"):
        render_chart(slanted_square_chart(30, 40, (1, 1)), pm, sm, blend="cubic")
    with pytest.raises(ImagingError, match="chart is"):
        render_chart(slanted_square_chart(32, 40, (1, 1)), pm, sm)
    with pytest.raises(ImagingError, match="pixel_pitch_um"):
        render_slanted_edge(psf(gaussian(1.0, 0.25, 17), 0.25), (10, 10), 8, 5.0)
    with pytest.raises(ImagingError, match="not a PSF"):
        render_slanted_edge(np.ones((5, 5)), (10, 10), 8, 5.0, pixel_pitch_um=1.0)
    with pytest.raises(ImagingError, match="does not fit"):
        render_slanted_edge(pm, (2, 2), 8, 5.0, sensor=sm)
    with pytest.raises(ImagingError, match="positive"):
        shading_gain_maps(np.zeros((8, 8)), "RGGB")
    with pytest.raises(SensorError, match="bit_depth"):
        SensorModel(bit_depth=20)
    with pytest.raises(SensorError, match="black_level"):
        SensorModel(black_level=2000.0)
    with pytest.raises(ImagingError, match="convex"):
        Shape(np.array([[0, 0], [4, 0], [1, 1], [0, 4]]), 0.5)
    with pytest.raises(ImagingError, match="lens_shading"):
        simulate_capture(None, psfmap=pm, sensor=sm, lens_shading="baked")


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


# -- speed (slow) --------------------------------------------------------------------------------

@pytest.mark.property
@pytest.mark.slow
def test_property_12mp_chart_in_under_a_minute():
    """property (slow): a 4000 × 3000 chart (15 × 20 slanted squares and a
    ColorChecker) through a 15 × 20 Gaussian PSF map renders with noise in
    under 60 s (measured 19 s on an idle 2-core machine, up to 46 s with
    other jobs on it; the real e9 map, wider kernels: 27 s)."""
    sensor = Sensor(1.0, 4000, 3000)
    pm = gaussian_map(sensor, (15, 20), lambda r, c, k: 0.8 + 0.02 * (r + c) + 0.1 * k, pitch_um=0.25, n=65)
    chart = slanted_square_chart(3000, 4000, (15, 20), colorchecker=True)
    t0 = time.perf_counter()
    r = render_chart(chart, pm, SensorModel.from_sensor(sensor), rng=1)
    assert time.perf_counter() - t0 < 60.0
    assert r.raw.shape == (3000, 4000) and np.isfinite(r.signal).all()

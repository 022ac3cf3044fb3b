"""Effects put into a simulated capture's mosaic (calibration/simulate/injected.py).

Kind: property (analytic). Each injection against a closed form: the
unsharp mask's and the crosstalk kernel's transfer on a sinusoid, the
sensor surface a focus shift, a tilt or a curvature makes (and that the
capture hands its PSF map), lateral colour's radial shift from an impulse's centroid,
glare's share of the light; and in a whole capture, a "light" injection
acts before the noise and a "chain" one after it (sharpening amplifies the
noise only as a chain effect).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from tests.helpers import gaussian_psf_map

from calibration.optics.lens import Sensor
from calibration.simulate.capture import simulate_capture
from calibration.simulate.injected import INJECTIONS, make_injection
from calibration.simulate.sensor import SensorModel, dn_to_linear
from isp.errors import ConfigError
from isp.frame import CFA

pytestmark = pytest.mark.property


def plane_sinusoid(shape, f_cycles_per_plane_px, axis=1):
    """A mosaic whose four planes each hold cos(2π f u), u the plane column (or row)."""
    h, w = shape
    out = np.empty(shape)
    for dy in (0, 1):
        for dx in (0, 1):
            ph, pw = out[dy::2, dx::2].shape
            u = np.arange(pw if axis == 1 else ph)
            wave = 0.5 + 0.2 * np.cos(2 * np.pi * f_cycles_per_plane_px * u)
            out[dy::2, dx::2] = wave[None, :] if axis == 1 else wave[:, None]
    return out


def amplitude(mosaic, f):
    """The amplitude at ``f`` of the first plane's middle row, away from the borders."""
    row = mosaic[0::2, 0::2][mosaic.shape[0] // 4, 40:-40]
    u = np.arange(row.size)
    return 2 * abs(np.mean((row - row.mean()) * np.exp(-2j * np.pi * f * u)))


@pytest.mark.parametrize("f", [0.05, 0.125, 0.25])
def test_sharpening_transfer_is_the_unsharp_mask(f):
    k, s = 0.8, 1.0
    m = plane_sinusoid((200, 480), f)
    out = make_injection("sharpening", gain=k, sigma_px=s).apply(m, CFA.RGGB)
    want = 1 + k * (1 - math.exp(-2 * math.pi ** 2 * s ** 2 * f ** 2))
    assert amplitude(out, f) / 0.2 == pytest.approx(want, rel=2e-3)


def test_crosstalk_leaks_to_the_four_neighbours_and_keeps_the_charge():
    m = np.zeros((9, 9))
    m[4, 4] = 1.0
    out = make_injection("pixel_crosstalk", leak=0.04).apply(m, CFA.GRBG)
    assert out[4, 4] == pytest.approx(0.84) and out[3, 4] == out[5, 4] == out[4, 3] == out[4, 5] == pytest.approx(0.04)
    assert out.sum() == pytest.approx(1.0) and out[3, 3] == 0.0


def second_moment_sigma(img, y, x, r=12):
    """σ (plane px) of an impulse's response at plane position (y, x)."""
    win = img[y - r:y + r + 1, x - r:x + r + 1]
    u = np.arange(-r, r + 1)
    return math.sqrt(float((win.sum(axis=0) * u ** 2).sum() / win.sum()))


def impulses(shape, spots):
    m = np.zeros(shape)
    for y, x in spots:
        for dy in (0, 1):
            for dx in (0, 1):
                m[2 * y + dy, 2 * x + dx] = 1.0
    return m


def test_optics_injections_move_the_sensor_surface():
    """Closed forms at image-plane points (mm): a focus shift is Δz
    everywhere, a tilt θy about y is x·tan θy (θx about x: y·tan θx), a
    curved sensor dz_corner·(r/r_corner)²; two add."""
    from calibration.simulate.capture import surface_dz_mm

    pts = np.array([[0.0, 0.0], [2.0, 0.0], [0.0, -1.5], [2.0, 1.5]])
    half = 2.5
    focus = surface_dz_mm([make_injection("focus_shift", dz_um=6.0)], pts, half)
    assert focus == pytest.approx([0.006] * 4)
    tilt = surface_dz_mm([make_injection("sensor_tilt", tilt_x_deg=0.2, tilt_y_deg=-0.1)], pts, half)
    tx, ty = math.tan(math.radians(0.2)), math.tan(math.radians(-0.1))
    assert tilt == pytest.approx([0.0, 2.0 * ty, -1.5 * tx, 2.0 * ty + 1.5 * tx])
    curved = [make_injection("field_curvature", dz_corner_um=8.0)]
    assert surface_dz_mm(curved, pts, half) == pytest.approx([0.0, 0.008 * 0.64, 0.008 * 0.36, 0.008])
    both = surface_dz_mm(curved + [make_injection("focus_shift", dz_um=6.0)], pts, half)
    assert both == pytest.approx(surface_dz_mm(curved, pts, half) + 0.006)
    assert surface_dz_mm([make_injection("sharpening", gain=0.5, sigma_px=1.0)], pts, half) is None


def test_a_capture_computes_its_psf_map_on_the_moved_surface(monkeypatch, e9_lens):
    """simulate_capture hands the PSF map the surface at each region's
    centre (the map's own plumbing: tests/calibration/optics/psf/test_map.py),
    and refuses an optics injection with a ready-made map."""
    from calibration.optics import psf
    from calibration.optics.psf.map import region_centers_mm
    from calibration.simulate.capture import ImagingError

    sensor = Sensor(2.0, 160, 120)
    seen = {}

    def fake_psf_map(lens, settings, image_dz_mm=None, **kw):
        seen["dz"] = image_dz_mm
        return gaussian_psf_map(sensor, settings.grid, lambda r, c, k: 1.0, pitch_um=0.5, n=17)

    monkeypatch.setattr(psf.map, "psf_map", fake_psf_map)
    lens = e9_lens.replace(sensor=sensor)
    tilt = make_injection("sensor_tilt", tilt_x_deg=0.0, tilt_y_deg=0.3)
    scene = np.broadcast_to(np.array([0.4, 0.4, 0.4]), (120, 160, 3))
    simulate_capture(lens, scene, lens_shading="none", noise=False, injections=[tilt],
                     psf_map_options={"grid": (3, 4)})
    x = region_centers_mm(sensor, (3, 4))[..., 0]
    assert seen["dz"] == pytest.approx(x * math.tan(math.radians(0.3)))
    pm = gaussian_psf_map(sensor, (3, 4), lambda r, c, k: 1.0, pitch_um=0.5, n=17)
    with pytest.raises(ImagingError, match="optics injection"):
        simulate_capture(None, scene, psfmap=pm, sensor=SensorModel.from_sensor(sensor), injections=[tilt])


def test_lateral_colour_moves_red_radially_by_its_corner_shift():
    h, w = 240, 320
    m = impulses((h, w), [(20, 30)])
    out = make_injection("lateral_ca", red_px_at_corner=2.0, blue_px_at_corner=0.0).apply(m, CFA.RGGB)
    red, green = out[0::2, 0::2], out[0::2, 1::2]        # RGGB: R at (0, 0), G at (0, 1)
    ys, xs = np.mgrid[0:red.shape[0], 0:red.shape[1]]
    cy, cx = (red.shape[0] - 1) / 2, (red.shape[1] - 1) / 2
    moved = np.hypot((red * ys).sum() / red.sum() - cy, (red * xs).sum() / red.sum() - cx)
    was = math.hypot(20 - cy, 30 - cx)
    half = 0.5 * math.hypot(*red.shape)
    assert moved - was == pytest.approx(2.0 / 2 * was / half, rel=0.02)   # plane px: half the sensor px
    assert np.array_equal(green, m[0::2, 1::2])


def test_glare_moves_its_share_into_the_halo():
    m = impulses((400, 400), [(100, 100)])
    out = make_injection("veiling_glare", share=0.1, halo_sigma_px=10.0).apply(m, CFA.RGGB)[0::2, 0::2]
    assert out[100, 100] == pytest.approx(0.9 + 0.1 / (2 * math.pi * 100), rel=1e-2)
    assert out.sum() == pytest.approx(1.0, rel=1e-6)


def test_light_acts_before_the_noise_and_chain_after_it():
    """A flat capture's noise: unchanged by a sharpening put in before the
    noise (a flat field has nothing to sharpen), amplified by one after it
    (white noise through (1 + k) − k·G has (1 + k)² − 2k(1 + k)·g₀ + k²·Σg²
    times the plain noise's variance, g₀ the Gaussian kernel's centre weight)."""
    sensor = Sensor(1.0, 400, 300)
    pm = gaussian_psf_map(sensor, (3, 4), lambda r, c, k: 1.0, pitch_um=0.5, n=33)
    sm = SensorModel.from_sensor(sensor, cfa="GRBG", noise_profile=(4e-4, 1e-5))
    scene = np.broadcast_to(np.array([0.4, 0.4, 0.4]), (300, 400, 3))
    sharp = dict(gain=1.0, sigma_px=1.0)
    plain = dn_to_linear(simulate_capture(None, scene, psfmap=pm, sensor=sm, lens_shading="none", rng=3)[0], sm)
    inj = make_injection("sharpening", **sharp)
    before = type(inj)(inj.effect, inj.params, "light", inj.apply)
    light = dn_to_linear(simulate_capture(None, scene, psfmap=pm, sensor=sm, lens_shading="none", rng=3,
                                          injections=[before])[0], sm)
    chain = dn_to_linear(simulate_capture(None, scene, psfmap=pm, sensor=sm, lens_shading="none", rng=3,
                                          injections=[inj])[0], sm)
    inner = (slice(20, -20), slice(20, -20))
    v0, vl, vc = plain[inner].var(), light[inner].var(), chain[inner].var()
    assert vl == pytest.approx(v0, rel=0.05)
    from scipy.ndimage import gaussian_filter

    d = np.zeros((41, 41))
    d[20, 20] = 1.0
    g = gaussian_filter(d, 1.0, truncate=4.0)
    ratio = 4.0 - 4.0 * g[20, 20] + (g ** 2).sum()
    assert vc / v0 == pytest.approx(ratio, rel=0.06)


def test_unknown_effect_or_parameters_are_refused():
    with pytest.raises(ConfigError, match="no injection"):
        make_injection("dust", share=0.1)
    with pytest.raises(ConfigError, match="takes gain, sigma_px"):
        make_injection("sharpening", gain=0.5)
    assert set(INJECTIONS) <= set(__import__("calibration.loop.effects", fromlist=["list_effects"]).list_effects())


@pytest.mark.parametrize("angle", [0.0, 30.0])
def test_motion_blur_is_the_box_along_its_direction(angle):
    """A smooth vertical edge (Gaussian σ 1.5 px) moved L px along θ: across
    the edge a box of L·cos θ, so the profile is Φ ⊗ box, in closed form
    (σ/w)·[G((x + w/2)/σ) − G((x − w/2)/σ)], G(z) = zΦ(z) + φ(z)."""
    from scipy.stats import norm

    from calibration.simulate.injected import motion_blur

    sigma, length = 1.5, 4.0
    x = np.arange(128) - 63.5
    img = np.broadcast_to(norm.cdf(x / sigma), (64, 128)).copy()
    out = motion_blur(img, length, angle)[32]
    w = length * math.cos(math.radians(angle))

    def g(z):
        return z * norm.cdf(z) + norm.pdf(z)

    want = sigma / w * (g((x + w / 2) / sigma) - g((x - w / 2) / sigma))
    assert np.abs(out - want)[8:-8].max() < 2e-4


@pytest.mark.parametrize("f", [0.05, 0.125, 0.2])
def test_longitudinal_colour_blurs_red_by_its_disc_and_leaves_green(f):
    """A colour focused off the sensor: the R plane's sinusoid falls by the
    disc's OTF 2 J₁(πDf)/(πDf) (scipy's Bessel J₁ as the oracle), the G
    planes keep theirs."""
    from scipy.special import j1

    m = plane_sinusoid((240, 400), f)
    d = 3.0
    out = make_injection("longitudinal_ca", red_disc_px=d, blue_disc_px=0.0).apply(m, CFA.RGGB)
    x = math.pi * d * f
    assert amplitude(out, f) / amplitude(m, f) == pytest.approx(2 * j1(x) / x, abs=2e-3)
    assert np.allclose(out[0::2, 1::2], m[0::2, 1::2]) and np.allclose(out[1::2, 1::2], m[1::2, 1::2])


def test_effects_outside_the_registry():
    """The denoiser halves a flat plane's noise and leaves a strong edge
    (its range σ far below the step) within 1 % of the step; JPEG at
    quality 100 keeps a plane within 8-bit rounding (and at 20 loses
    detail); the smudge takes its share from an impulse at its centre into
    the halo and leaves one far from it. None is a registry effect."""
    from calibration.loop.effects import list_effects
    from calibration.simulate.injected import OUTSIDE

    assert not set(OUTSIDE) & set(list_effects())
    rng = np.random.default_rng(0)
    h, w = 120, 160
    step = np.where(np.arange(w)[None, :] < w // 2, 0.2, 0.8) * np.ones((h, 1))
    noisy = step + rng.normal(0.0, 0.01, step.shape)
    out = make_injection("denoise", sigma_range=0.03, sigma_px=1.5).apply(noisy, CFA.RGGB)
    flat = (slice(10, -10), slice(10, 60))
    assert out[flat].std() < 0.5 * noisy[flat].std()
    assert np.abs(out - step)[:, 70:90].max() < 0.05 * 0.6
    assert np.abs(make_injection("jpeg", quality=100).apply(step, CFA.RGGB) - step).max() <= 1.5 / 255
    coarse = make_injection("jpeg", quality=20).apply(noisy, CFA.RGGB)
    assert np.abs(coarse - noisy)[flat].std() > 0.005
    m = impulses((240, 320), [(60, 80), (10, 10)])                         # the plane centre, a corner
    out = make_injection("haze", share=0.2, halo_sigma_px=10.0, x=0.0, y=0.0, radius=0.2).apply(m, CFA.RGGB)
    plane = out[0::2, 0::2]
    assert plane[60, 80] == pytest.approx(0.8 + 0.2 / (2 * math.pi * 100), rel=1e-2)
    assert plane[10, 10] == pytest.approx(1.0, abs=1e-3)

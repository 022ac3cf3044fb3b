"""LSF asymmetry (the odd transfer SFR drops) against rendered-and-measured
edges, Monte-Carlo noise and the lens model (kind: property)."""

from types import SimpleNamespace

import numpy as np
import pytest

from calibration.simulate.capture import render_slanted_edge
from calibration.sfr.esfr import measure_sfr
from calibration.sfr.asymmetry import esf_bin_noise, lsf_direction, model_odd_bands, odd_bands, odd_bands_std

pytestmark = pytest.mark.property

PITCH_UM, PIXEL_UM = 0.6, 1.2
PITCH_PX = PITCH_UM / PIXEL_UM


def coma_psf(dx: float, dy: float, m: int = 33) -> np.ndarray:
    """A core and a weaker, wider satellite at (dx, dy) px: a one-sided tail."""
    o = (np.arange(m) - m // 2) * PITCH_PX
    x, y = np.meshgrid(o, o)
    p = np.exp(-(x ** 2 + y ** 2) / (2 * 0.6 ** 2)) + 0.35 * np.exp(-((x - dx) ** 2 + (y - dy) ** 2) / (2 * 0.9 ** 2))
    return p / p.sum()


def measured(psf, horizontal: bool, dark_to_bright: bool, angle: float = 5.0, noise: float = 0.0, rng=None):
    lo, hi = (0.2, 0.8) if dark_to_bright else (0.8, 0.2)
    size = (64, 96) if horizontal else (96, 64)
    r = render_slanted_edge(SimpleNamespace(data=psf, pitch_um=PITCH_UM), (48.0, 48.0), size, angle,
                            horizontal=horizontal, low=lo, high=hi, pixel_pitch_um=PIXEL_UM, noise=False)
    img = r.optical[:, :, 0]
    if noise:
        img = img + rng.normal(0.0, noise, img.shape)
    return measure_sfr(img)


def test_symmetric_lsf_has_no_odd_part_wherever_it_sits():
    """Zero for a symmetric LSF whatever its position: exactly on a bin,
    to the sampling's 1e-6 between bins (an asymmetric one is ≥ 1e-2)."""
    s = np.arange(256) * 0.25
    for centre, tol in ((32.0, 1e-12), (31.3, 1e-6), (40.1, 1e-6)):
        lsf = np.exp(-(s - centre) ** 2 / (2 * 1.3 ** 2)) + 0.1 * np.exp(-(s - centre) ** 2 / 18.0)
        np.testing.assert_allclose(odd_bands(lsf, 0.25), 0.0, atol=tol)


def test_small_frequency_limit_is_the_third_cumulant():
    """A(f) → (2πf)³ κ₃ / 6 for f → 0 (a window far wider than the LSF: at
    ``HALF_WIDTH_PX`` the window's curvature takes 3 % off here)."""
    from calibration.sfr.asymmetry import _odd

    s = np.arange(-800, 801) * 0.01
    lsf = np.where(s > -0.2, np.exp(-(s + 0.2) / 0.2), 0.0)          # exponential: κ₃ = 2·0.2³
    lsf = np.convolve(lsf, np.exp(-np.arange(-50, 51) ** 2 / 50.0), mode="same")   # Gaussian: adds no κ₃
    k3 = 2 * 0.2 ** 3
    f = 0.05
    a = _odd(lsf[None], s, 40.0, bands=((f, f),))[0, 0]
    assert a == pytest.approx((2 * np.pi * f) ** 3 * k3 / 6.0, rel=0.02)


@pytest.mark.parametrize("dx,dy", [(1.5, 0.0), (-1.5, 0.0), (0.0, 1.5), (0.0, -1.5), (1.0, 1.0)])
@pytest.mark.parametrize("horizontal", [False, True])
@pytest.mark.parametrize("dark_to_bright", [False, True])
def test_measured_asymmetry_matches_the_model(dx, dy, horizontal, dark_to_bright):
    """ISO 12233 measurement of an edge rendered through a one-sided PSF has
    the asymmetry the model predicts from the PSF alone, with the sign of the
    tail's side, for both polarities and orientations (≤ 3 % + 5e-4)."""
    psf = coma_psf(dx, dy)
    r = measured(psf, horizontal, dark_to_bright)
    normal = (95.0 if horizontal else -5.0) % 180.0
    meas = odd_bands(r.lsf, r.esf_step_px)
    model = model_odd_bands(psf[None], PITCH_PX, [normal])[0]
    np.testing.assert_allclose(meas, model, rtol=0.03, atol=5e-4)
    # the tail's side sets the sign: along the LSF's direction (+x or +y)
    along = dy if horizontal else dx
    if abs(along) > 0.5:
        assert np.all(np.sign(meas[1:]) == np.sign(along))


def test_noise_propagation_matches_monte_carlo():
    """The linearised σ of each band agrees with the spread of 150 noisy
    measurements within 20 %."""
    rng = np.random.default_rng(3)
    psf = coma_psf(1.5, 0.0)
    vals, preds = [], []
    for _ in range(150):
        r = measured(psf, False, True, noise=0.01, rng=rng)
        vals.append(odd_bands(r.lsf, r.esf_step_px))
        preds.append(odd_bands_std(r.lsf, r.esf_step_px, esf_bin_noise(r.noise, r.rows_used, 4)))
    np.testing.assert_allclose(np.median(preds, axis=0), np.std(vals, axis=0), rtol=0.2)


def test_lsf_direction():
    np.testing.assert_allclose(lsf_direction([0.0, 10.0, 170.0, 45.0, 90.0, 134.0, 135.0]),
                               [0.0, 10.0, -10.0, 45.0, 90.0, 134.0, -45.0])


@pytest.fixture(scope="module")
def e9_device(e9_lens):
    from calibration.optics.psf import map as M
    from isp.runtime.executor import pool_executor
    from calibration.optics.perturb import apply
    from calibration.fit.synthetic_devices import synthetic_observations
    from calibration.fit.forward_model import ModelSettings, SfrModel

    lens = e9_lens
    true = {"e1.decenter_x": 0.002, "e2.tilt_yz": 0.02}
    pl = apply(lens, true)
    pm = M.psf_map(pl, M.PSFMapSettings(grid=(3, 4), channels=("G",), n=96, pupil_samples=64, n_wavelengths=3),
                   cache=False, executor=pool_executor(None))
    obs = synthetic_observations(pm, noise=0.0)
    return lens, true, pl, obs, SfrModel(lens, obs, ModelSettings())


def test_lens_model_reproduces_measured_asymmetry(e9_device):
    """Edges rendered through independent PSF maps of a decentred and tilted
    e9 (real aiming, 3 wavelengths) and measured: the forward model plus its
    measurement bias reproduces their asymmetry to ≤ 0.002 RMS per band; the
    nominal lens is off by ≥ 10× that, and so is the mirror-image
    perturbation, whose SFRA is just as far off — the sign of a decenter
    lives in the phase."""
    from calibration.optics.perturb import apply

    lens, true, pl, obs, m = e9_device
    b = m.measurement_biases(pl)
    fit = np.sqrt(np.mean((obs.odd - m.predict_odd(pl) - b.odd) ** 2, axis=0))
    assert np.all(fit < 0.002)
    nominal = np.sqrt(np.mean((obs.odd - m.predict_odd(lens) - b.odd) ** 2, axis=0))
    mirror_lens = apply(lens, {k: -v for k, v in true.items()})
    mirror = np.sqrt(np.mean((obs.odd - m.predict_odd(mirror_lens) - b.odd) ** 2, axis=0))
    assert np.all(nominal[1:] > 10 * fit[1:])
    assert np.all(mirror[1:] > 20 * fit[1:])


def test_observations_keep_the_asymmetry_through_json(e9_device, tmp_path):
    from calibration.fit.observations import Observations

    obs = e9_device[3]
    back = Observations.load(obs.save(tmp_path / "obs.json"))
    np.testing.assert_allclose(back.odd, obs.odd)
    np.testing.assert_allclose(back.odd_std, obs.odd_std)
    sub = obs.subset(np.arange(len(obs)) % 2 == 0)
    np.testing.assert_allclose(sub.odd, obs.odd[::2])


def test_asymmetry_residuals_resolve_the_mirror_ambiguity(e9_device):
    """Started at the mirror image of the truth (−decenter, −tilt), a fit to
    SFRA alone settles in the mirror's basin (the tilt keeps the wrong sign:
    SFRA cannot see which way coma points); with the asymmetry residuals the
    same fit reaches the truth within 0.15 tolerances."""
    from calibration.fit.proxy import ProxyFitSettings, fit_proxy, parameter_space
    from isp.runtime.executor import create_executor

    lens, true, _, obs, _ = e9_device
    names = list(true)
    u_true = np.array([true[n] for n in names]) / parameter_space(lens, names).tolerance
    serial = create_executor("serial")
    odd = fit_proxy(lens, obs, ProxyFitSettings(residuals="odd", max_iter=8, restarts=0), names=names, x0=-u_true,
                    executor=serial)
    np.testing.assert_allclose(odd.u, u_true, atol=0.15)
    sfra = fit_proxy(lens, obs, ProxyFitSettings(residuals="sfra", max_iter=8, restarts=0), names=names, x0=-u_true,
                     executor=serial)
    assert np.max(np.abs(sfra.u - u_true)) > 0.5
    assert odd.errors()["after"]["sfra_rms"] < 0.5 * sfra.errors()["after"]["sfra_rms"]


def test_fast_and_linearised_paths_agree():
    """The GEMM path (fits) and the sine path that also gives the gradient
    (noise propagation) compute the same A."""
    from calibration.sfr.asymmetry import _odd

    s = np.arange(300) * 0.25
    lsf = np.stack([np.exp(-(s - 30) ** 2 / 3) + 0.3 * np.exp(-(s - 31.5 - k) ** 2 / 5) for k in (0.0, 0.7, -1.2)])
    fast = _odd(lsf, s, 6.0)
    slow, _ = _odd(lsf, s, 6.0, gradient=True)
    np.testing.assert_allclose(fast, slow, atol=1e-12)
    assert np.all(np.abs(fast[:, 1:]) > 1e-3)

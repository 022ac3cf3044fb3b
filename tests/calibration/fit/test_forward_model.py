"""The fast SFR forward model (calibration.fit.forward_model), kind:
property: the MTF of a Gaussian PSF against its closed form, the model
against the full render-and-measure path, and the re-measurement of a render
as its observation was measured (an edge on a raw mosaic's green plane is
measured on that plane)."""

import numpy as np
import pytest

from calibration.fit.forward_model import ModelSettings, SfrModel, measure_like, mtf_along, sfra_of
from calibration.sfr.esfr import measure_sfr, measure_sfr_bayer

pytestmark = pytest.mark.property


def test_mtf_of_a_gaussian_psf_is_analytic():
    """Projection-slice: a Gaussian PSF of σ px has MTF exp(−2π²σ²f²) along any normal."""
    q, s = 0.25, 0.8
    o = (np.arange(65) - 32) * q
    g = np.exp(-(o[None] ** 2 + o[:, None] ** 2) / (2 * s * s))
    f = np.linspace(0, 1, 33)
    m = mtf_along(np.stack([g / g.sum()] * 3), q, [0.0, 30.0, 100.0], f)
    np.testing.assert_allclose(m, np.exp(-2 * np.pi ** 2 * s * s * f ** 2)[None].repeat(3, 0), atol=1e-3)


def test_sfra_of_flat_curve():
    f = np.linspace(0, 1, 129)
    assert sfra_of(f, np.ones((1, 129)))[0] == pytest.approx(0.5)


@pytest.fixture(scope="module")
def device(e9_lens):
    from calibration.optics.psf import map as M
    from isp.runtime.executor import pool_executor
    from calibration.optics.perturb import apply
    from calibration.fit.synthetic_devices import synthetic_observations

    lens = e9_lens
    pl = apply(lens, {"e1.decenter_x": 0.002, "e2.tilt_yz": 0.02})
    pm = M.psf_map(pl, M.PSFMapSettings(grid=(3, 4), channels=("G",), n=96, pupil_samples=64, n_wavelengths=3),
                   cache=False, executor=pool_executor(None))
    return lens, pl, synthetic_observations(pm, noise=0.0)


def test_model_matches_render_and_measure(device):
    """Noise-free: the model + its measurement bias reproduce the ISO-measured
    SFRA of edges rendered through independent PSF maps (real aiming, 3
    wavelengths) to ≤ 0.002 cycles/pixel RMS."""
    lens, pl, obs = device
    m = SfrModel(lens, obs, ModelSettings())
    pred = m.predict(pl).sfra
    bias = m.noise_bias(pl)
    d = obs.sfra - pred - bias
    assert np.sqrt(np.mean(d ** 2)) < 0.002
    # and the perturbation matters far more than that: the nominal lens is off
    d0 = obs.sfra - m.predict(lens).sfra
    assert np.sqrt(np.mean(d0 ** 2)) > 5 * np.sqrt(np.mean(d ** 2))


def _node_psfs_per_field(model, lens, defocus_mm=None, method="debye"):
    """The oracle of SfrModel.node_psfs: every node traced alone (its real
    aim, pupil_rays, pupil_from_trace) and diffracted alone (reference_sphere,
    monochromatic_samples)."""
    import dataclasses

    from calibration.optics.perturb import nominal
    from calibration.optics.psf.methods import monochromatic_samples
    from calibration.optics.psf.pupil import exit_pupil_z, pupil_from_trace, pupil_points, reference_sphere
    from calibration.optics.psf.sampling import grid_offsets_mm
    from calibration.optics.trace import Rays, pupil_rays, trace_to_exit

    pl, s = nominal(lens), model.settings
    pupil, z_pupil = pupil_points(s.pupil_samples), exit_pupil_z(pl)
    k = len(model.fields)
    dz = np.zeros(k) if defocus_mm is None else np.broadcast_to(defocus_mm, (k,))
    o = grid_offsets_mm(model.psf_n, model.pitch_um)
    ref = int(np.argmin(np.abs(model.wavelengths - pl.nominal.primary_nm)))
    ep, status = model._aim
    out = np.zeros((k, len(model.channels), model.psf_n, model.psf_n))
    for i, f in enumerate(model.fields):
        fd = (float(f[0]), float(f[1]))
        trs = []
        for lam in model.wavelengths:
            r = pupil_rays(pl, fd, s.pupil_samples, float(lam), aiming="paraxial", pupil=ep[i])
            r = Rays(r.origin, r.direction, float(lam), r.opl, status[i], pupil, r.field_deg)
            t = pupil_from_trace(pl, r, trace_to_exit(pl, r), fd, s.pupil_samples, z_pupil)
            trs.append(dataclasses.replace(t, z_image=t.z_image + dz[i]))
        centre = trs[ref].chief_image_point()
        for j, t in enumerate(trs):
            data = monochromatic_samples(reference_sphere(t, centre), method, o, o, workers=1)[0]
            out[i] += model.wl_weights[:, j, None, None] * data[None]
    return out


@pytest.mark.parametrize("defocus_um", [None, 3.0])
def test_node_psfs_all_nodes_at_once_match_each_node_alone(device, monkeypatch, defocus_um):
    """property: the batched node PSFs (one trace per wavelength for all
    nodes, batched pupil fits and Debye sums) equal the per-node path, to
    1e-9 of the peak with complex128 sums and 1e-6 with the default
    complex64 ones; in focus and with a per-node defocus (the trace reused)."""
    from calibration.optics.psf import debye
    lens, pl, obs = device
    m = SfrModel(lens, obs, ModelSettings(pupil_samples=32, psf_n=32))
    dz = None if defocus_um is None else np.linspace(-1.0, 1.0, len(m.regions)) * defocus_um * 1e-3
    ref = _node_psfs_per_field(m, pl, dz)
    np.testing.assert_allclose(m.node_psfs(pl, dz), ref, rtol=0, atol=1e-6 * ref.max())
    monkeypatch.setattr(debye, "DEBYE_SUM_DTYPE", np.complex128)
    np.testing.assert_allclose(m.node_psfs(pl, dz), ref, rtol=0, atol=1e-9 * ref.max())


def test_node_psfs_other_methods_go_node_by_node(device):
    """property: a method other than "debye" takes the per-node PSFs on the
    batched trace."""
    lens, pl, obs = device
    m = SfrModel(lens, obs, ModelSettings(pupil_samples=32, psf_n=32, method="fft"))
    ref = _node_psfs_per_field(m, pl, method="fft")
    np.testing.assert_allclose(m.node_psfs(pl), ref, rtol=0, atol=1e-9 * ref.max())


def test_sfra_of_is_the_trapezoid_to_half_nyquist_on_every_row():
    """The one-product SFRA equals, row by row, the trapezoid over the
    samples up to 0.5 cycles/pixel with the end value interpolated
    (written out here with numpy), on grids that end past 0.5, exactly on
    it and irregular ones; samples past the end are not read (NaN there
    changes nothing); NaN where a grid stops short of 0.5."""
    from calibration.sfr.edge import area_to
    from calibration.fit.forward_model import sfra_of

    def trapezoid(f, s):
        n = int(np.searchsorted(f, 0.5, side="right"))
        x, y = np.append(f[:n], 0.5), np.append(s[:n], np.interp(0.5, f, s))
        return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(x)))

    rng = np.random.default_rng(5)
    grids = [np.linspace(0, 1, 65), np.linspace(0, 0.5, 33), np.append(0.0, np.sort(rng.random(49)) * 0.9),
             np.linspace(0, 0.6, 7)]
    for f in grids:
        s = rng.random((6, f.size))
        want = [trapezoid(f, r) for r in s]
        assert np.allclose(sfra_of(f, s), want, rtol=0, atol=1e-14)
        assert np.allclose([area_to(f, r) for r in s], want, rtol=0, atol=1e-14)
    f = np.linspace(0, 1, 65)
    s = rng.random((2, f.size))
    s[:, 40:] = np.nan
    assert np.isfinite(sfra_of(f, s)).all() and np.isfinite(area_to(f, s[0]))
    assert np.isnan(sfra_of(np.linspace(0, 0.4, 9), np.ones((2, 9)))).all()


def test_a_window_past_the_pupil_replica_period_is_refused(device):
    """32 pupil samples across e9 (N ≈ 1.95) repeat the diffracted field
    every ≈ 0.48 µm · 1.95 · 32 ≈ 30 µm: a 32 µm window is refused (it would
    fold the tails onto the core), a 24 µm one is not."""
    from calibration.fit.forward_model import FAST_JACOBIAN

    lens, _, obs = device
    with pytest.raises(ValueError, match=r"replica period .*pupil_samples ≥ 3[3-6]"):
        SfrModel(lens, obs, ModelSettings(pupil_samples=32, psf_n=64))
    SfrModel(lens, obs, FAST_JACOBIAN)


def test_window_energy_matches_the_psf_map_and_grows_with_the_window(device):
    """SfrModel.window_energy (the batched Debye sums' share of the
    exit-pupil power on the window) equals psf_map's per-region window
    energy (per-field path, its own chief-ray aiming) within 0.01, is ≈ 1
    on a generous window and falls on a small one."""
    from calibration.optics.psf import map as M
    from isp.runtime.executor import pool_executor
    lens, pl, obs = device
    m = SfrModel(lens, obs, ModelSettings(psf_n=32))
    e = m.window_energy(pl)
    pm = M.psf_map(pl, M.PSFMapSettings(grid=obs.grid, channels=("G",), n=32, pupil_samples=48, n_wavelengths=2),
                   cache=False, executor=pool_executor(None))
    ref = np.array([pm.window_energy[r, c, 0] for r, c in obs.region])
    np.testing.assert_allclose(e, ref, atol=0.01)
    wide = SfrModel(lens, obs, ModelSettings(psf_n=96, pupil_samples=64)).window_energy(pl)
    small = SfrModel(lens, obs, ModelSettings(psf_n=12)).window_energy(pl)
    assert np.all(wide > 0.97) and np.all(wide >= e - 1e-9) and np.all(e > small)
    assert small.min() < 0.8


def test_the_psf_window_is_as_wide_in_micrometres_whatever_the_pixel(device):
    """The window is set in µm (``window_um``): 64 samples at half of a 1 µm
    pixel, 24 at half of a 2.8 µm one, about 32 µm both times and inside the
    pupil sampling's replica period (≈ 45 µm here). A 64-sample window on
    2.8 µm pixels would be 90 µm, past it (`isp calib loop` on such a
    capture stopped with an internal error)."""
    from calibration.optics.lens import Sensor
    from calibration.fit.observations import Observations

    lens, pl, obs = device
    fine = SfrModel(lens, obs)
    assert fine.psf_n == 64 and fine.psf_n * fine.pitch_um == pytest.approx(32.0)
    d = obs.to_dict()
    scale = 2000 / obs.sensor.width_px
    pitch = obs.sensor.pixel_pitch_um / scale
    d["sensor"].update(width_px=2000, height_px=1500, pixel_pitch_um=pitch)
    for o in d["observations"]:
        o["x_px"] *= scale
        o["y_px"] *= scale
    coarse_obs = Observations.from_dict(d)
    coarse_lens = lens.replace(sensor=Sensor(pixel_pitch_um=pitch, width_px=2000, height_px=1500))
    coarse = SfrModel(coarse_lens, coarse_obs)
    assert coarse.psf_n == 24 and 32.0 <= coarse.psf_n * coarse.pitch_um < 32.0 + 2 * coarse.pitch_um
    with pytest.raises(ValueError, match="replica period"):
        SfrModel(coarse_lens, coarse_obs, ModelSettings(psf_n=64))
    sfra = coarse.predict(pl).sfra
    assert np.all(np.isfinite(sfra)) and np.all(sfra > 0)


def test_measure_like_takes_the_mosaic_plane_of_a_raw_observation(make_observations):
    from calibration.sfr.synthetic import render_slanted_edge

    img = 0.2 + 0.6 * render_slanted_edge((96, 64), 5.0, 1.0)
    raw = measure_like(make_observations(1, {"measure": "raw", "cfa": "GRBG", "sfr_method": "accurate"}), 0)(img)
    assert raw.sfra == measure_sfr_bayer(img, "GRBG", channel="G", method="accurate").sfra
    image = make_observations(1, {"measure": "image", "sfr_method": "accurate"})
    assert measure_like(image, 0)(img).sfra == measure_sfr(img, method="accurate").sfra
    assert raw.sfra != pytest.approx(measure_sfr(img).sfra, abs=1e-6)


def test_measure_like_uses_the_method_the_observations_were_measured_with(make_observations):
    """A set that names its SFR method is modelled with it; one that names
    none was measured by the standard's ("iso")."""
    from calibration.sfr.synthetic import render_slanted_edge

    img = 0.2 + 0.6 * render_slanted_edge((96, 64), 5.0, 1.0)
    iso, accurate = measure_sfr(img, method="iso").sfra, measure_sfr(img, method="accurate").sfra
    assert iso != pytest.approx(accurate, abs=1e-5)
    assert measure_like(make_observations(1, {"measure": "image"}), 0)(img).sfra == iso
    assert measure_like(make_observations(1, {"measure": "image", "sfr_method": "iso"}), 0)(img).sfra == iso
    raw = make_observations(1, {"measure": "raw", "cfa": "RGGB", "sfr_method": "iso"})
    assert measure_like(raw, 0)(img).sfra == measure_sfr_bayer(img, "RGGB", channel="G", method="iso").sfra


@pytest.mark.parametrize("x, y, h, w, edge_dx", [(600, 400, 32, 42, 3.3), (1000, 800, 32, 42, -4.1),
                                                 (200, 1000, 40, 36, 1.7)])
def test_an_observation_is_rendered_as_its_capture_was(x, y, h, w, edge_dx):
    """A raw edge measured off its ROI's middle through a PSF whose centroid
    is off its centre sample: the model's render of the observation (its
    ROI's shape, the edge where it was measured less the PSF's own shift)
    measures as the capture did, to 1e-4 cycles/pixel of SFRA; rendered as a
    tall ROI through its centre it was 4–7e-3 off."""
    import dataclasses
    from types import SimpleNamespace

    from calibration.fit.forward_model import render_observation
    from calibration.fit.measurements import _edge_item
    from calibration.fit.observations import Observations
    from calibration.optics.lens import Sensor
    from calibration.sfr.chart import EdgeROI
    from calibration.simulate.capture import render_slanted_edge

    q, pixel_um = 0.5, 2.0
    o = (np.arange(33) - 16) * q
    g = np.exp(-((o[None] - 0.7) ** 2 + (o[:, None] + 0.3) ** 2) / (2 * 0.9 ** 2))   # centroid (+0.7, −0.3) px
    psf = g / g.sum()
    centre = (x + (w - 1) / 2, y + (h - 1) / 2)
    cap = render_slanted_edge(SimpleNamespace(data=psf, pitch_um=q * pixel_um), centre, (h, w), 5.0, low=0.2,
                              high=0.7, pixel_pitch_um=pixel_um, noise=False,
                              edge_px=(centre[0] + edge_dx, centre[1])).optical[:, :, 0]
    r = measure_sfr_bayer(np.pad(cap, ((y, 0), (x, 0))), "RGGB", channel="G", method="accurate", box=(x, y, w, h))
    roi = EdgeROI(x, y, w, h, 5.0, "vertical", 0.5, 0.0, "tangential", 0)
    obs = Observations.from_sfr_results([_edge_item(roi, r, 2000, 1500)], Sensor(pixel_pitch_um=pixel_um,
                                                                                   width_px=2000, height_px=1500))
    obs = dataclasses.replace(obs.with_fields(roi=np.array([[x, y, w, h]])),
                              meta={"measure": "raw", "cfa": "RGGB", "sfr_method": "accurate"})
    img = render_observation(psf, q * pixel_um, pixel_um, obs, 0, 1.0)
    assert img.shape == (h, w)
    assert measure_like(obs, 0)(img).sfra == pytest.approx(r.sfra, abs=1e-4)


def test_antithetic_spread_is_the_spread_of_one_noisy_measurement():
    """Independent reference: the SFRA's standard deviation over many
    independent noisy renders of one edge. The antithetic estimate from
    the same number of renders matches it; the half-differences alone (the
    part odd in the noise) miss the even part a magnitude has."""
    from scipy.special import erf

    from calibration.fit.forward_model import antithetic_spread

    h, w, t = 64, 48, np.radians(5.0)                # a short ROI at a low SNR: the SFR's
    ys, xs = np.mgrid[:h, :w]                        # high frequencies are mostly noise
    d = np.cos(t) * (xs - (w - 1) / 2) - np.sin(t) * (ys - (h - 1) / 2)
    clean = 0.25 + 0.4 * 0.5 * (1 + erf(d / (1.2 * np.sqrt(2))))
    rng = np.random.default_rng(1)
    sigma, n = 0.05, 160
    independent = [measure_sfr(clean + rng.normal(0, sigma, clean.shape)).sfra for _ in range(n)]
    pairs = []
    for _ in range(n // 2):
        z = rng.normal(0, sigma, clean.shape)
        pairs += [measure_sfr(clean + z).sfra, measure_sfr(clean - z).sfra]
    reference = float(np.std(independent, ddof=1))
    pairs = np.array(pairs)
    assert antithetic_spread(pairs) == pytest.approx(reference, rel=0.25)      # measured 0.93–1.16
    half_only = float(np.sqrt(np.mean((0.5 * (pairs[0::2] - pairs[1::2])) ** 2)))
    assert half_only < 0.85 * float(antithetic_spread(pairs))                 # measured 0.63–0.69


def test_node_psfs_with_a_plane_per_colour_are_each_colour_in_its_own_plane(device):
    """property: a defocus per node and colour (longitudinal colour) gives
    each colour the PSFs the whole model has with that colour's plane for
    every node (each wavelength traced to the planes of the colours it
    counts in); one plane for all colours is the per-node defocus."""
    import dataclasses

    lens, pl, obs = device
    rgb = dataclasses.replace(obs, channel=np.full(len(obs), "L"))
    m = SfrModel(lens, rgb, ModelSettings(pupil_samples=32, psf_n=32))
    assert m.channels == ("R", "G", "B")
    k = len(m.regions)
    dz = np.stack([np.full(k, 4e-3), np.zeros(k), np.linspace(-6e-3, 6e-3, k)], axis=1)
    per_colour = m.node_psfs(pl, dz)
    for c in range(3):
        alone = m.node_psfs(pl, dz[:, c])
        np.testing.assert_allclose(per_colour[:, c], alone[:, c], rtol=0, atol=1e-9 * alone.max())
    same = np.linspace(-2e-3, 2e-3, k)
    np.testing.assert_allclose(m.node_psfs(pl, np.repeat(same[:, None], 3, 1)), m.node_psfs(pl, same),
                               rtol=0, atol=1e-9 * per_colour.max())
    assert np.abs(per_colour[:, 0] - m.node_psfs(pl)[:, 0]).max() > 0.01 * per_colour.max()

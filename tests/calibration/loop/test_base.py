"""The loop's base models (calibration.loop.base), kind: property.

The lens base starts its fit where ``fit_proxy`` puts it: on a device with
two known perturbations, the start recovers them, and ``close_loop`` fits
from that start. The model re-measures its renders as the observations
were measured: an edge measured on a raw mosaic's green plane has half the
pixels of the full image, so its SFRA scatters about √2 more under the same
pixel noise, and the re-rendered spread, which the loop takes as each
observation's σ, shows that."""

from __future__ import annotations

import numpy as np
import pytest

from isp.runtime.executor import pool_executor

from calibration.loop.base import _edge_bias

pytestmark = pytest.mark.property

NAMES = ["e1.decenter_x", "e2.tilt_yz"]
U_TRUE = np.array([0.8, -0.6])


@pytest.fixture(scope="module")
def lens_base(make_e9_device):
    from calibration.loop.base import LensBase

    lens, obs = make_e9_device(NAMES, U_TRUE, grid=(3, 4), noise=0.003, rng=4, n=96, pupil_samples=64, n_wavelengths=3)
    return LensBase(lens, obs, names=NAMES)


def test_the_start_recovers_the_device(lens_base):
    start = lens_base.start()
    assert np.abs(start - U_TRUE).max() < 0.15, start
    # the nominal lens, where the loop used to start, is far off
    assert np.abs(lens_base.x0 - U_TRUE).max() > 0.5


def test_close_loop_fits_from_the_start(lens_base, monkeypatch):
    from calibration.loop import closure as loop
    seen = []
    fit = loop._fit

    def spy(prob, p0, *a, **k):
        seen.append(np.array(p0[:len(NAMES)]))
        return fit(prob, p0, *a, **k)

    monkeypatch.setattr(loop, "_fit", spy)
    monkeypatch.setattr(type(lens_base), "start", lambda self, executor=None: U_TRUE.copy())
    rep = loop.close_loop(lens_base, lens_base.obs, effects=[], executor=pool_executor(None))
    np.testing.assert_allclose(rep.base_x_before, U_TRUE)     # no polish: the base is where start() put it
    assert rep.defocus_um == pytest.approx(lens_base.defocus_um(U_TRUE)) and rep.to_dict()["defocus_um"] == rep.defocus_um
    surface = loop.sensor_surface(lens_base, U_TRUE, [])
    assert rep.sensor_surface == pytest.approx(surface) and rep.to_dict()["sensor_surface"] == rep.sensor_surface
    assert rep.sensor_surface["defocus_um"] == pytest.approx(rep.defocus_um, abs=2.0)   # the plane's constant
    assert loop.surface_text(surface) in loop.summary(rep)
    assert seen == []
    monkeypatch.setattr(loop, "START_POLISH", 1)                # a polish starts there too
    loop.close_loop(lens_base, lens_base.obs, effects=[], executor=pool_executor(None))
    np.testing.assert_allclose(seen[0], U_TRUE)


def test_the_sensor_defocus_is_the_last_gap_where_nothing_else_moves_focus(lens_base):
    """Beyond the last surface rays are straight: moving the sensor by d
    (the last gap + d) moves the best focus by exactly −d, whatever the
    other perturbations; a focus shift the loop keeps adds its Δz, a tilt
    about the centre nothing."""
    from calibration.fit.proxy import FOCUS_TOLERANCE_MM, focus_name
    from calibration.loop.base import LensBase
    from calibration.loop.closure import sensor_defocus_um
    from calibration.loop.effects import create_effect

    base = LensBase(lens_base.nominal, lens_base.obs, names=[focus_name(lens_base.nominal), NAMES[0]])
    tilted = base.defocus_um([0.0, 1.5])
    assert abs(tilted) > 0.05                                   # a decentred element moves focus itself
    assert base.defocus_um([0.0, 0.0]) == pytest.approx(0.0, abs=1e-9)
    for d_um in (-12.0, 7.0):
        u = 1e-3 * d_um / FOCUS_TOLERANCE_MM
        assert base.defocus_um([u, 1.5]) - tilted == pytest.approx(d_um, abs=1e-6)
    x = np.array([0.0, 1.5])
    effects = [(create_effect("focus_shift"), [4.0]), (create_effect("sensor_tilt"), [0.2, -0.3])]
    assert sensor_defocus_um(base, x, effects) == pytest.approx(tilted + 4.0, abs=1e-9)


def test_the_sensor_surface_is_the_registry_optics_and_the_lens_image_surface(lens_base):
    """The reported sensor surface: on the design, the optical effects kept
    come back exactly as their parameters (focus shift, tilt about x and y,
    curvature at the corner); a decentred element tilts the lens's own image
    surface, and moving the sensor (the last gap) then moves the defocus by
    exactly its Δz everywhere, leaving tilt and curvature as they were."""
    from calibration.fit.proxy import FOCUS_TOLERANCE_MM, focus_name
    from calibration.loop.base import LensBase
    from calibration.loop.closure import sensor_surface
    from calibration.loop.effects import create_effect

    base = LensBase(lens_base.nominal, lens_base.obs, names=[focus_name(lens_base.nominal), NAMES[0]])
    effects = [(create_effect("focus_shift"), [4.0]), (create_effect("sensor_tilt"), [0.2, -0.3]),
               (create_effect("field_curvature"), [6.0])]
    got = sensor_surface(base, [0.0, 0.0], effects)
    want = {"defocus_um": 4.0, "tilt_x_deg": 0.2, "tilt_y_deg": -0.3, "curvature_um": 6.0, "rms_left_um": 0.0}
    assert got == pytest.approx(want, abs=1e-6)
    tilted = sensor_surface(base, [0.0, 1.5], [])
    assert abs(tilted["tilt_x_deg"]) + abs(tilted["tilt_y_deg"]) > 0.01
    u = 1e-3 * 7.0 / FOCUS_TOLERANCE_MM
    moved = sensor_surface(base, [u, 1.5], [])
    assert moved["defocus_um"] - tilted["defocus_um"] == pytest.approx(7.0, abs=1e-6)
    for k in ("tilt_x_deg", "tilt_y_deg", "curvature_um"):
        assert moved[k] == pytest.approx(tilted[k], abs=1e-6)


def test_a_lens_base_travels_to_a_worker_without_its_caches(lens_base):
    """Pickled (a worker's payload), a lens base is rebuilt from its lens,
    observations and settings: a few hundred kB where its model's caches
    would be tens of MB, and the same predictions."""
    import pickle

    x = 0.5 * U_TRUE
    want = lens_base.predict(x).sfra
    blob = pickle.dumps(lens_base)
    assert len(blob) < 1_000_000, len(blob)
    np.testing.assert_allclose(pickle.loads(blob).predict(x).sfra, want, rtol=0, atol=1e-12)


def test_the_joint_refit_on_workers_lands_where_the_serial_one_does(lens_base):
    """The refit after an effect is kept, on two workers with the cheaper
    Jacobian model refreshed every third step, against the serial fit with
    a full-model Jacobian at every step, both from a start 0.3 tolerance
    units off the device: the same parameters (within 0.05 units) and
    χ² (within 5 %), both near the device."""
    from calibration.loop import closure as loop

    prob = loop_problem(lens_base)
    start = U_TRUE + np.array([0.3, -0.3])
    lo, hi = np.asarray(lens_base.lower, float), np.asarray(lens_base.upper, float)
    p_pool, _ = loop._joint_fit(prob, start, lo, hi, 8, pool_executor(2))
    p_serial, _ = loop._fit(prob, start, lo, hi, np.ones(len(start), bool), max_iter=8)
    chi2 = [prob.errors(prob.predict(p))["chi2_per_obs"] for p in (p_pool, p_serial)]
    assert np.abs(p_pool - p_serial).max() < 0.05, (p_pool, p_serial)
    assert abs(chi2[0] / chi2[1] - 1.0) < 0.05, chi2
    assert np.abs(p_pool - U_TRUE).max() < 0.15, p_pool
    assert loop._bind_problem(prob, pool_executor(1)) is None      # serial: the plain fit


def test_a_candidate_tried_on_workers_scores_as_in_this_process(lens_base):
    """A candidate effect's fold fits on two workers give the gain, fitted
    values and folds that the same fits give in this process (to 1e-4:
    the workers' one BLAS thread sums in another order, which the fits'
    steps carry on)."""
    from calibration.loop import closure as loop
    from calibration.loop.effects import create_effect

    prob = loop_problem(lens_base)
    fold = loop._folds(lens_base.obs, 3, 0)
    e = create_effect("pixel_crosstalk")
    serial = loop._cv_gain(prob, U_TRUE, e, fold, 3)
    with loop._bind_problem(prob, pool_executor(2), cheap=False) as pool:
        pooled = loop._cv_gain(prob, U_TRUE, e, fold, 3, pool)
    assert pooled[0] == pytest.approx(serial[0], rel=1e-4)
    np.testing.assert_allclose(pooled[3], serial[3], rtol=1e-4)
    np.testing.assert_allclose([f[:2] for f in pooled[4]], [f[:2] for f in serial[4]], rtol=1e-4)


def loop_problem(lens_base):
    """The loop's weighted problem on ``lens_base`` with its noise at the device."""
    from calibration.loop import closure as loop

    a0, c0, sd0 = lens_base.measurement_bias(U_TRUE)
    return loop._Problem(lens_base, lens_base.obs, a0, c0, loop._sigma_law(lens_base.obs, sd0))


def test_a_raw_observation_re_rendered_scatters_as_a_mosaic_plane_does(make_observations):
    """Spread of four noisy re-renders per observation, median over 60: on
    the green plane it is 1.3–2.5× the full image's (√2 from half the pixels;
    the plane's coarser ESF bins add some)."""
    def otf(nu, normal):
        return np.exp(-2 * np.pi ** 2 * 0.6 ** 2 * np.asarray(nu) ** 2)

    sd_image = np.median(_edge_bias(make_observations(60, {"measure": "image"}), otf)[2][:, 0])
    sd_raw = np.median(_edge_bias(make_observations(60, {"measure": "raw", "cfa": "RGGB"}), otf)[2][:, 0])
    assert 1.3 < sd_raw / sd_image < 2.5, (sd_raw, sd_image)   # 1.81 measured

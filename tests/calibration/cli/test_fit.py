"""`isp calib fit` end to end (kind: property): a perturbed e9 device
measured on a small field grid; the fitted proxy file reads back as the
nominal lens plus the fitted perturbation and predicts the measurement
better than the nominal lens; bad input gives one line, exit code 2 and no
output folder."""

from __future__ import annotations

import json

import numpy as np
import pytest

from isp.cli.main import main
from isp.runtime.executor import create_executor

pytestmark = pytest.mark.property


@pytest.fixture(scope="module")
def device_obs(tmp_path_factory, e9_lens):
    from calibration.fit.proxy import parameter_space
    from calibration.fit.synthetic_devices import synthetic_observations
    from calibration.optics.psf.map import PSFMapSettings, psf_map
    from isp.runtime.executor import pool_executor

    lens = e9_lens
    names = ["e1.decenter_x", "s17.thickness"]
    truth = parameter_space(lens, names).apply(np.array([0.8, 0.6]) * parameter_space(lens, names).tolerance)
    pm = psf_map(truth, PSFMapSettings(grid=(2, 3), channels=("G",), n=32, pupil_samples=32, n_wavelengths=2),
                 executor=pool_executor(None))
    obs = synthetic_observations(pm, noise=0.003, rng=1)
    path = tmp_path_factory.mktemp("fit") / "obs.json"
    obs.save(path)
    return lens, path


def test_fit_writes_a_proxy_lens_that_beats_the_nominal(capsys, tmp_path, device_obs, e9_zmx):
    from calibration.fit.proxy import load_proxy

    lens, obs_path = device_obs
    out = tmp_path / "proxy"
    code = main(["calib", "fit", "--lens", str(e9_zmx),
                 "--measured", str(obs_path), "-o", str(out), "--n-params", "2", "--max-iter", "4",
                 "--workers", "1", "--restarts", "1"])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    for f in ("proxy.json", "fit.json", "merit.png", "sfra_maps.png", "parameters.png"):
        assert (out / f).is_file(), f
    # an e9 module's calibration, on the basis the packaged e9 profile ships (--basis auto)
    from calibration.fit.device import DescriptorBasis
    from isp.io.device import DeviceCalibration
    from isp.profiles import get_profile

    cal = DeviceCalibration.load(out / "device.json")
    assert cal.basis == DescriptorBasis.load(get_profile("e9").basis).key and cal.grid == (5, 7)
    fit = json.loads((out / "fit.json").read_text())
    assert fit["errors"]["after"]["sfra_rms"] < 0.5 * fit["errors"]["before"]["sfra_rms"]
    # the median |residual| (σ) falls with χ², above the floor's 0.67 here (two parameters), and is printed
    e = fit["errors"]
    assert 0.67 < e["after"]["median_abs_z"] < 0.5 * e["before"]["median_abs_z"]
    # the same residuals as χ²: their median |z| within a factor 2 of a Gaussian's, 0.674 √χ²
    assert 0.5 < e["after"]["median_abs_z"] / (0.674 * np.sqrt(e["after"]["chi2_per_obs"])) < 2.0
    assert f"{e['after']['median_abs_z']:.2f} σ" in printed.out
    assert all(np.isfinite(p["std"]) for p in fit["parameters"])
    # two parameters cannot fit this device: the fit ends far above the noise floor and tries one restart
    assert len(fit["restarts"]) == 1 and "1 other starts tried" in printed.out
    proxy = load_proxy(out / "proxy.json")
    # the proxy file reads back as the nominal lens plus exactly the fitted perturbation
    assert len(proxy.nominal.surfaces) == len(lens.surfaces)
    back = proxy.perturbation.as_dict()
    fitted = {p["name"]: p["value"] for p in fit["parameters"]}
    assert any(abs(v) > 0 for v in fitted.values())
    for name, value in fitted.items():
        assert back.get(name, 0.0) == pytest.approx(value, rel=1e-9, abs=1e-15)


def test_missing_measurement_is_one_line_exit_2(capsys, tmp_path, e9_zmx):
    out = tmp_path / "proxy"
    code = main(["calib", "fit", "--lens", str(e9_zmx),
                 "--measured", str(tmp_path / "nope.json"), "-o", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "nope.json" in err and "\n" not in err and "Traceback" not in err
    assert not out.exists()


def test_screened_fit_on_two_workers_starts_from_the_screening_secants(device_obs):
    """fit_proxy with its own screening on a pool: one pool serves the
    screening (every candidate parameter) and the fit (its points embedded
    in that space, zeros elsewhere, which is the same lens: checked to
    1e-12); the fit's first Jacobian is the screening's, so its first record
    holds one evaluation, and the proxy still beats the nominal lens."""
    from calibration.fit.proxy import ProxyFitSettings, _residuals, fit_proxy, parameter_space, residual_bias
    from calibration.fit.observations import Observations
    from calibration.fit.forward_model import SfrModel

    lens, obs_path = device_obs
    obs = Observations.load(obs_path)
    names = ["e1.decenter_x", "e2.tilt_zx", "s17.thickness", "e3.decenter_y"]
    model = SfrModel(lens, obs)
    bias = residual_bias(model, lens, "sfra")
    u = np.array([0.7, -0.4])
    sub = _residuals(model, parameter_space(lens, ["e1.decenter_x", "s17.thickness"]), bias, u)
    full = _residuals(model, parameter_space(lens, names), bias, np.array([0.7, 0.0, -0.4, 0.0]))
    assert np.allclose(sub, full, rtol=0, atol=1e-12)

    fit = fit_proxy(lens, obs, ProxyFitSettings(n_params=3, residuals="sfra", max_iter=3, restarts=0),
                    executor=create_executor("processes", 2))
    assert len(fit.space.names) == 3 and "s17.thickness" in fit.space.names
    assert fit.result.history[0]["evaluations"] == 1
    e = fit.errors()
    assert e["after"]["sfra_rms"] < 0.5 * e["before"]["sfra_rms"]


def test_a_tolerance_prior_adds_one_residual_per_parameter_and_holds_them_near_nominal(device_obs):
    """ProxyFitSettings(prior=σ): the residuals end with u/σ (a Gaussian prior,
    MAP), the screening's secant Jacobian gains the prior's rows (the first
    record still one evaluation), and a tight prior keeps the parameters
    far closer to the nominal lens than the free fit puts them."""
    from calibration.fit.proxy import ProxyFitSettings, fit_proxy
    from calibration.fit.observations import Observations

    lens, obs_path = device_obs
    obs = Observations.load(obs_path)
    kw = dict(n_params=3, residuals="sfra", max_iter=3, restarts=0)
    with create_executor("processes", 2) as ex:
        free = fit_proxy(lens, obs, ProxyFitSettings(**kw), executor=ex)
        tight = fit_proxy(lens, obs, ProxyFitSettings(prior=0.005, **kw), executor=ex)
    assert tight.result.residuals.size == free.result.residuals.size + 3
    np.testing.assert_allclose(tight.result.residuals[-3:], tight.u / 0.005, rtol=1e-12)
    assert tight.result.history[0]["evaluations"] == 1
    assert np.linalg.norm(tight.u) < 0.5 * np.linalg.norm(free.u)


def test_scipy_fits_restart_as_dls_fits_do(device_obs):
    """The multistart is not tied to the optimiser: TRF that ends far above
    the noise floor (three parameters for this device) tries the same
    seeded starts, counts their evaluations, and keeps a start only if it
    ends lower."""
    from calibration.fit.proxy import ProxyFitSettings, fit_proxy
    from calibration.fit.observations import Observations

    lens, obs_path = device_obs
    obs = Observations.load(obs_path)
    names = ["e1.decenter_x", "s17.thickness", "e3.decenter_y"]
    kw = dict(residuals="sfra", method="scipy", max_iter=3)
    serial = create_executor("serial")
    plain = fit_proxy(lens, obs, ProxyFitSettings(restarts=0, **kw), names=names, executor=serial)
    again = fit_proxy(lens, obs, ProxyFitSettings(restarts=2, seed=5, **kw), names=names, executor=serial)
    assert plain.restarts == [] and len(again.restarts) == 2
    assert again.result.merit <= plain.result.merit
    assert again.evaluations > plain.evaluations
    kept = [t for t in again.restarts if t.get("kept")]
    assert (again.result.merit < plain.result.merit) == bool(kept)


@pytest.mark.parametrize("bad", [["--coarse", "-1", "7"], ["--coarse", "0", "7"], ["--bootstrap", "-1"],
                                 ["--fine-iter", "-1"], ["--fine-iter", "0", "--coarse", "0", "0"]])
def test_a_bad_option_is_one_line_exit_2(capsys, tmp_path, device_obs, bad, e9_zmx):
    _, obs_path = device_obs
    out = tmp_path / "proxy"
    code = main(["calib", "fit", "--lens", str(e9_zmx),
                 "--measured", str(obs_path), "-o", str(out), *bad])
    err = capsys.readouterr().err.strip()
    assert code == 2 and bad[0] in err and "\n" not in err and "Traceback" not in err
    assert not out.exists()


def test_a_wider_window_grows_the_pupil_grid_with_it(capsys, tmp_path, device_obs, e9_zmx):
    """`--window-um 48`: past the default pupil grid's replica period on e9
    (≈ 45 µm), so the pupil grid grows in proportion (48 → 72 samples) and
    the fit runs and records both; a window out of range is one line."""
    _, obs_path = device_obs
    lens = str(e9_zmx)
    out = tmp_path / "proxy"
    code = main(["calib", "fit", "--lens", lens, "--measured", str(obs_path), "-o", str(out), "--n-params", "2",
                 "--max-iter", "1", "--workers", "1", "--restarts", "0", "--coarse", "0", "0",
                 "--window-um", "48"])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    settings = json.loads((out / "fit.json").read_text())["settings"]
    assert settings["window_um"] == 48.0 and settings["pupil_samples"] == 72
    code = main(["calib", "fit", "--lens", lens, "--measured", str(obs_path), "-o", str(tmp_path / "p2"),
                 "--window-um", "4"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "--window-um" in err and "\n" not in err and not (tmp_path / "p2").exists()
    # --widen from a window at or past the widest it tries: nothing to widen, one line
    code = main(["calib", "fit", "--lens", lens, "--measured", str(obs_path), "-o", str(tmp_path / "p3"),
                 "--widen", "--window-um", "200"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "--widen" in err and "128" in err and "\n" not in err and not (tmp_path / "p3").exists()


def test_a_fit_tried_several_ways_keeps_the_lowest_chi2(capsys, tmp_path, device_obs, e9_zmx):
    """`--try`: a fit of one iteration, tried again with five from the same
    start (damped least squares only takes steps that lower the merit), so
    the longer fit ends lower and is the one written; fit.json lists both;
    an option --try cannot change is one line, exit 2, no folder."""
    _, obs_path = device_obs
    out = tmp_path / "proxy"
    base = ["calib", "fit", "--lens", str(e9_zmx), "--measured", str(obs_path), "--n-params", "2",
            "--workers", "1", "--restarts", "0", "--coarse", "0", "0", "--basis", "none"]
    code = main([*base, "-o", str(out), "--max-iter", "1", "--try", "--max-iter 5"])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    fit = json.loads((out / "fit.json").read_text())
    tries = fit["settings"]["tries"]
    assert [t["options"] for t in tries] == ["(as given)", "--max-iter 5"]
    kept = min(tries, key=lambda t: t["chi2_per_obs"])
    assert kept["kept"] and sum(t["kept"] for t in tries) == 1
    assert fit["errors"]["after"]["chi2_per_obs"] == pytest.approx(kept["chi2_per_obs"], abs=1e-3)
    assert kept["options"] == "--max-iter 5" and tries[1]["chi2_per_obs"] < tries[0]["chi2_per_obs"], tries
    assert "← kept" in printed.out
    code = main([*base, "-o", str(tmp_path / "p2"), "--try", "--lens other.zmx"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "--try" in err and "--lens" in err and "\n" not in err and not (tmp_path / "p2").exists()


def test_a_try_changes_only_the_fitting_options_it_names():
    """`--try` strings: the options named replace the command line's, the
    rest are kept; a one-option try comes as `--try=--widen`; anything else
    is a one-line ConfigError naming the try."""
    import argparse

    from calibration.cli.fit import _try_options
    from isp.errors import ConfigError

    given = argparse.Namespace(n_params=24, restarts=4, max_iter=20, window_um=None, widen=False, method="dls",
                               residuals="auto", lens="e2.zmx", tries=None, kinds=("decenter", "tilt"),
                               stage=None)
    got = _try_options(given, "--n-params 48 --restarts 12")
    assert (got.n_params, got.restarts, got.max_iter, got.widen, got.lens) == (48, 12, 20, False, "e2.zmx")
    assert got.kinds == ("decenter", "tilt")
    assert _try_options(given, "--widen").widen and given.widen is False
    assert _try_options(given, "--kinds curvature,conic,focus").kinds == ("curvature", "conic", "focus")
    every = _try_options(given, "--kinds all --n-params 92 --stage 24")
    assert (every.n_params, every.stage, given.stage) == (92, 24, None)
    assert {"curvature", "conic", "nd", "vd", "decenter", "tilt", "thickness", "focus"} == set(every.kinds)
    for bad, word in [("--lens other.zmx", "--lens"), ("--n-params x", "--n-params"), ("--widen --window-um 200", "128"),
                      ("--restarts -1", "--restarts"), ('"--n-params 48', "quotation"), ("--kinds curv", "curv"), ("--stage 0", "--stage")]:
        with pytest.raises(ConfigError, match=word) as e:
            _try_options(given, bad)
        assert "\n" not in str(e.value) and "--try" in str(e.value)

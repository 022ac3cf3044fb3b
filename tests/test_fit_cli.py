"""`isp calib fit` end to end (kind: property): a perturbed e9 device
measured on a small field grid; the fitted proxy file reads back as the
nominal lens plus the fitted perturbation and predicts the measurement
better than the nominal lens; bad input gives one line, exit code 2 and no
output folder."""

from __future__ import annotations

import json

import numpy as np
import pytest

from isp.cli import main
from tests.helpers import data_file


@pytest.fixture(scope="module")
def device_obs(tmp_path_factory):
    from calibration.lens_io import read_lens
    from calibration.proxy import parameter_space
    from calibration.proxy_synth import synthetic_observations
    from calibration.psf_map import psf_map

    lens = read_lens(data_file("lenses", "phone", "US-12210142-B2-e9.zmx"))
    names = ["e1.decenter_x", "s17.thickness"]
    truth = parameter_space(lens, names).apply(np.array([0.8, 0.6]) * parameter_space(lens, names).tolerance)
    pm = psf_map(truth, grid=(2, 3), channels=("G",), n=32, pupil_samples=32, n_wavelengths=2, progress=False)
    obs = synthetic_observations(pm, noise=0.003, rng=1)
    path = tmp_path_factory.mktemp("fit") / "obs.json"
    obs.save(path)
    return lens, path


def test_fit_writes_a_proxy_lens_that_beats_the_nominal(capsys, tmp_path, device_obs):
    from calibration.proxy import load_proxy

    lens, obs_path = device_obs
    out = tmp_path / "proxy"
    code = main(["calib", "fit", "--lens", str(data_file("lenses", "phone", "US-12210142-B2-e9.zmx")),
                 "--measured", str(obs_path), "-o", str(out), "--n-params", "3", "--max-iter", "4",
                 "--workers", "1"])
    assert code == 0, capsys.readouterr().err
    for f in ("proxy.json", "fit.json", "merit.png", "sfra_maps.png", "parameters.png"):
        assert (out / f).is_file(), f
    fit = json.loads((out / "fit.json").read_text())
    assert fit["errors"]["after"]["sfra_rms"] < 0.5 * fit["errors"]["before"]["sfra_rms"]
    assert all(np.isfinite(p["std"]) for p in fit["parameters"])
    proxy = load_proxy(out / "proxy.json")
    # the proxy file reads back as the nominal lens plus exactly the fitted perturbation
    assert len(proxy.nominal.surfaces) == len(lens.surfaces)
    back = proxy.perturbation.as_dict()
    fitted = {p["name"]: p["value"] for p in fit["parameters"]}
    assert any(abs(v) > 0 for v in fitted.values())
    for name, value in fitted.items():
        assert back.get(name, 0.0) == pytest.approx(value, rel=1e-9, abs=1e-15)


def test_missing_measurement_is_one_line_exit_2(capsys, tmp_path):
    out = tmp_path / "proxy"
    code = main(["calib", "fit", "--lens", str(data_file("lenses", "phone", "US-12210142-B2-e9.zmx")),
                 "--measured", str(tmp_path / "nope.json"), "-o", str(out)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "nope.json" in err and "\n" not in err and "Traceback" not in err
    assert not out.exists()

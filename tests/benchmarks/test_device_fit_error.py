"""benchmarks/device_fit_error.py: a fitted device file against its truth
(kind: property). The oracle is arithmetic on descriptors built here: a
known offset gives a known RMS error, and the pooled correlation follows
the rows."""

import json

import numpy as np
import pytest

from benchmarks import device_fit_error
from isp.io.device import DeviceCalibration

pytestmark = pytest.mark.property


def _module(folder, truth, fitted, chi2):
    (folder / "fit").mkdir(parents=True)
    DeviceCalibration("lens", "d" * 64, "b" * 12, truth).save(folder / "true_device.json")
    DeviceCalibration("lens", "d" * 64, "b" * 12, fitted).save(folder / "fit" / "device.json")
    (folder / "fit" / "fit.json").write_text(json.dumps({
        "errors": {"after": {"chi2_per_obs": chi2, "sfra_rms": 0.01}},
        "parameters": [{"name": f"p{k}"} for k in range(24)], "seconds": 60.0}))


def test_the_error_is_the_rms_of_fitted_minus_true_in_spreads(tmp_path):
    rng = np.random.default_rng(0)
    truth = rng.normal(size=(5, 7, 16))
    _module(tmp_path / "e9_0_0", truth, truth + 0.5, 20.0)
    r = device_fit_error.module_error(tmp_path / "e9_0_0")
    assert r["descriptor_rms_error"] == pytest.approx(0.5, abs=1e-4)
    assert r["correlation"] == pytest.approx(1.0, abs=1e-3)   # an offset keeps the shape
    assert r["chi2_per_obs"] == 20.0 and r["n_params"] == 24
    assert device_fit_error.module_error(tmp_path / "missing") is None


def test_the_pooled_correlation_follows_the_fits(tmp_path):
    rng = np.random.default_rng(1)
    for k, (offset, chi2) in enumerate([(0.2, 15.0), (0.4, 30.0), (0.8, 60.0)]):
        truth = rng.normal(size=(5, 7, 16))
        _module(tmp_path / "work" / f"e2_0_{k}", truth, truth + offset, chi2)
    out = device_fit_error.main(["--work", f"e2={tmp_path / 'work'}", "--results", str(tmp_path / "res")])
    res = out
    assert res["fits"] == 3
    assert res["folders"]["e2"]["mean_descriptor_error"] == pytest.approx(np.mean([0.2, 0.4, 0.8]), abs=1e-3)
    assert res["chi2_error_correlation"] == pytest.approx(1.0, abs=1e-3)   # error exactly linear in χ² here

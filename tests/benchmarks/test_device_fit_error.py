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


def test_the_best_of_several_runs_is_each_modules_lowest_chi2_and_never_reads_the_truth(tmp_path):
    """``--best-into``: per module the run whose fit ended at the lowest
    χ²/obs, copied whole; a run whose file is nearer the truth at a higher
    χ² is not chosen (the line has no truth to choose by)."""
    rng = np.random.default_rng(2)
    truth = [rng.normal(size=(5, 7, 16)) for _ in range(2)]
    # module 0: run a lower χ² and farther from the truth; module 1: run b lower
    for run, rows in {"a": [(0.6, 10.0), (0.3, 40.0)], "b": [(0.2, 12.0), (0.5, 20.0)]}.items():
        for k, (offset, chi2) in enumerate(rows):
            _module(tmp_path / run / f"e2_0_{k}", truth[k], truth[k] + offset, chi2)
    out = device_fit_error.main(["--work", f"a={tmp_path / 'a'}", f"b={tmp_path / 'b'}",
                                 "--best-into", str(tmp_path / "best"), "--results", str(tmp_path / "res")])
    assert out["chosen"] == {"e2_0_0": "a", "e2_0_1": "b"}
    best = {r["module"]: r for r in out["folders"]["best"]["modules"]}
    assert best["e2_0_0"]["descriptor_rms_error"] == pytest.approx(0.6, abs=1e-4)
    assert best["e2_0_1"]["chi2_per_obs"] == 20.0
    assert out["fits"] == 4                                        # the copies are not pooled twice
    assert (tmp_path / "best" / "e2_0_1" / "true_device.json").is_file()

"""The proxy benchmark's paired verdicts (benchmarks/proxy.py::paired):
the interval is Student's t over the devices (kind: published — scipy's
one-sample t-test interval is the reference), and the verdict follows it;
merging runs, the summary and device naming (kind: property)."""

import json

import numpy as np
import pytest
from scipy.stats import ttest_1samp

from benchmarks.proxy import FOVS, load_cases, paired, summarise


def _case(lens, device, mse: dict, ssim: dict):
    fk = [f"{f:g}" for f in FOVS]
    return {"lens": lens, "device": device, "noise": 0.004,
            "methods": {m: {"sfr_mse": {k: v for k in fk}, "ssim": {k: ssim[m] for k in fk}}
                        for m, v in mse.items()}}


@pytest.mark.published
def test_the_interval_is_students_t_over_devices_and_the_verdicts_follow_it():
    other = [2.0, 3.0, 1.5, 2.5]      # ref wins by 1.5–3× on every device
    mixed = [0.5, 2.0, 0.8, 1.6]      # ref wins on two, loses on two
    cases = [_case("L", d, {"ours_shape": 1.0, "scipy": other[d], "pixel": mixed[d], "nominal": 9.0, "truth": 0.5},
                   {"ours_shape": 0.95, "scipy": 0.95 - 0.01 * (d + 1), "pixel": 0.96, "nominal": 0.5, "truth": 0.97})
             for d in range(4)]
    comp = paired(cases, "ours_shape", ["nominal", "truth", "pixel", "scipy", "ours_shape"])
    cell = comp["sfr_mse"]["L"]["0.5"]
    assert "nominal" not in cell and "truth" not in cell and "ours_shape" not in cell
    ref = ttest_1samp(np.log(other), 0.0).confidence_interval(0.95)
    s = cell["scipy"]
    assert s["mean"] - s["half_width"] == pytest.approx(ref.low, rel=1e-9)
    assert s["mean"] + s["half_width"] == pytest.approx(ref.high, rel=1e-9)
    assert s["ratio"] == pytest.approx(np.exp(np.mean(np.log(other))))
    assert (s["verdict"], s["wins"], s["n"]) == ("better", 4, 4)
    assert cell["pixel"]["verdict"] == "tied" and cell["pixel"]["wins"] == 2
    # SSIM: higher is better; ref − other = 0.01·(d + 1) > 0 everywhere, and −0.01 against pixel
    assert comp["ssim"]["L"]["0.9"]["scipy"]["verdict"] == "better"
    assert comp["ssim"]["L"]["0.9"]["pixel"]["verdict"] == "worse"
    # logs from before the registered SSIM: no such comparison rather than a KeyError
    assert "ssim_registered" not in comp
    for c in cases:
        for m, r in c["methods"].items():
            r["ssim_registered"] = dict(r["ssim"], **{"0.9": r["ssim"]["0.9"] + (0.02 if m == "ours_shape" else 0)})
    reg = paired(cases, "ours_shape", ["pixel", "ours_shape"])["ssim_registered"]["L"]
    assert reg["0.9"]["pixel"]["verdict"] == "better" and reg["0.5"]["pixel"]["verdict"] == "worse"


@pytest.mark.property
def test_runs_of_the_same_devices_merge_into_one_case(tmp_path):
    a = _case("L", 0, {"nominal": 9.0, "scipy": 2.0}, {"nominal": 0.5, "scipy": 0.9})
    b = _case("L", 0, {"nominal": 9.0, "ours_shape": 1.0}, {"nominal": 0.5, "ours_shape": 0.9})
    for name, case in (("a.log", a), ("b.log", b)):
        (tmp_path / name).write_text("some progress\n" + json.dumps({"cases": [case]}) + "\n")
    cases, methods = load_cases([tmp_path / "a.log", tmp_path / "b.log"])
    assert len(cases) == 1 and methods == ["nominal", "scipy", "ours_shape"]


@pytest.mark.property
def test_the_summary_counts_the_parameters_left_on_the_bounds():
    fk = {k: 1.0 for k in ("0.1", "0.5", "0.9")}
    rec = lambda u: {"sfr_mse": fk, "sfr_mse_truth": fk, "ssim": fk, "seconds": 1.0, "evaluations": 1, "u": u}
    cases = [{"noise": 0.004, "methods": {"ours_shape": rec([2.0, -1.9999, 0.5])}},
             {"noise": 0.004, "methods": {"ours_shape": rec([1.99, 0.0, -2.0])}}]
    assert summarise(cases, ["ours_shape"])["0.004"]["ours_shape"]["at_bounds"] == [1, 2]


@pytest.mark.property
def test_merits_are_compared_only_between_fits_of_the_same_residuals():
    """merit_comparison: scipy_shape and ours_box minimise ours_shape's
    residuals and are compared (devices where ours ends lower, geometric-mean
    ratio); scipy (SFRA only), the pixel fit and ours_prior (its merit holds
    the prior's terms) are not."""
    from benchmarks.proxy import merit_comparison

    merits = [{"ours_shape": 100.0, "scipy_shape": 90.0, "ours_box": 110.0, "scipy": 5.0, "pixel": 1.0,
               "ours_prior": 120.0},
              {"ours_shape": 100.0, "scipy_shape": 160.0, "ours_box": 110.0, "scipy": 5.0, "pixel": 1.0,
               "ours_prior": 120.0}]
    cases = [{"lens": "L", "device": d, "methods": {m: {"merit": v} for m, v in mm.items()}}
             for d, mm in enumerate(merits)]
    out = merit_comparison(cases, "ours_shape", list(merits[0]))
    assert set(out) == {"scipy_shape", "ours_box"}
    assert out["scipy_shape"]["ref_lower"] == 1 and out["ours_box"]["ref_lower"] == 2
    assert out["scipy_shape"]["ratio"] == pytest.approx(np.sqrt(0.9 * 1.6))


@pytest.mark.property
def test_only_names_a_device_by_lens_token_and_index():
    """``--only e11:3`` picks device 3 of the e11 lens and nothing else
    (a token is the lens name's last part, as ``--lenses`` takes it)."""
    from benchmarks.proxy import _is_case

    assert _is_case("e11:3", "US-11933948-B2-e11", 3)
    assert not _is_case("e11:3", "US-11933948-B2-e11", 0)
    assert not _is_case("e1:3", "US-11933948-B2-e11", 3)
    assert _is_case("US-11906710-B2-e1:4", "US-11906710-B2-e1", 4)


@pytest.mark.property
def test_the_truth_lens_rendered_as_a_device_gives_back_its_own_clean_edges(e9_lens):
    """``ssim_device``'s renderer is the devices' own: the truth lens through
    it reproduces the noise-free edges the measurement was made from (to
    rounding), and a perturbed lens does not."""
    from benchmarks.proxy import device_map, render_as_device
    from calibration.fit.proxy import default_names, parameter_space
    from calibration.fit.synthetic_devices import synthetic_observations

    lens = e9_lens
    space = parameter_space(lens, default_names(lens))
    truth = space.apply(np.random.default_rng(4).uniform(-1, 1, len(space.names)) * space.tolerance)
    grid = (2, 3)
    _, edges = synthetic_observations(device_map(truth, grid), noise=0.004, rng=2, return_edges=True)
    back = render_as_device(truth, edges, grid)
    assert len(back) == len(edges) == 12
    for b, e in zip(back, edges):
        np.testing.assert_allclose(b, e.clean, rtol=0, atol=1e-12)
    other = render_as_device(lens, edges, grid)
    assert max(np.abs(o - e.clean).max() for o, e in zip(other, edges)) > 1e-3

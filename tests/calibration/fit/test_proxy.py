"""The proxy fit (calibration.fit.proxy), kind: property.

Multistart of a fit that ends far above the noise floor (``restart``): a
Latin-hypercube of probes, the best continued and kept only if it ends
lower. Coarse-to-fine fits: the sub-grid keeps rows and columns spread
edge to edge, corners in; a fit on a sub-grid refined on all regions
recovers a known device as well as the fit on all regions from the start.
"""

from __future__ import annotations

import numpy as np
import pytest

from isp.errors import ConfigError
from isp.runtime.executor import create_executor

from calibration.fit.dls import DLSSettings, DlsResult, damped_least_squares
from calibration.fit.proxy import PROBE_ITER, restart

pytestmark = pytest.mark.property


def _two_basins(x):
    """Residuals with a local minimum near x = 0.02 (merit ≈ 0.47) and the
    global one near π/4 (merit ≈ 0.007): ``(x − 0.7, 3 sin 4x)``."""
    return np.array([x[0] - 0.7, 3.0 * np.sin(4.0 * x[0])])


def _local(start, iters):
    return damped_least_squares(_two_basins, np.atleast_1d(start), lower=np.array([-2.0]), upper=np.array([2.0]),
                                settings=DLSSettings(h=1e-4, max_iter=iters))


def test_restart_leaves_a_local_minimum_for_the_global_one():
    first = _local(np.zeros(1), 20)
    assert first.x[0] == pytest.approx(0.02, abs=0.02) and first.merit > 0.4     # stuck next to the start
    best, tried = restart(_local, first, 4, 20, seed=3)
    # the global minimum of (x − 0.7)² + 9 sin²(4x), by a dense grid: the oracle
    grid = np.linspace(-2, 2, 400001)
    g = grid[np.argmin((grid - 0.7) ** 2 + 9 * np.sin(4 * grid) ** 2)]
    assert best.x[0] == pytest.approx(g, abs=1e-4)
    assert best.merit < 0.01
    assert len(tried) == 4 and [t.get("kept") for t in tried].count(True) == 1
    assert best.evaluations > first.evaluations            # every run counted
    assert len(best.history) > len(first.history)          # the path that won, after the first
    again, tried_again = restart(_local, first, 4, 20, seed=3)
    assert tried_again == tried and again.x[0] == best.x[0]   # seeded


def _fake(merit: float, evaluations: int = 10) -> DlsResult:
    r = np.array([np.sqrt(merit)])
    return DlsResult(np.zeros(2), r, np.zeros((1, 2)), np.eye(2), [{"merit": merit}], evaluations, "fake")


def test_restart_keeps_the_first_fit_when_no_start_does_better():
    """Probes all worse than the first fit: nothing is continued, the first
    fit is returned with the probes' evaluations added; the starts lie in
    the ±1-tolerance box, one per stratum in each parameter."""
    seen = []

    def local(start, iters):
        seen.append((np.array(start), iters))
        return _fake(5.0)

    first = _fake(1.0, evaluations=7)
    best, tried = restart(local, first, 4, 15, seed=0)
    assert best.merit == first.merit and best.evaluations == 7 + 4 * 10
    assert [it for _, it in seen] == [PROBE_ITER] * 4                       # probes only
    assert all("final_merit" not in t for t in tried)
    starts = np.array([s for s, _ in seen])
    assert np.all(np.abs(starts) <= 1.0)
    for j in range(2):   # a Latin hypercube: each quarter of [-1, 1] holds one start
        assert sorted(np.floor((starts[:, j] + 1.0) * 2).astype(int).tolist()) == [0, 1, 2, 3]


def test_restart_drops_a_continued_probe_that_ends_worse():
    """The best probe is continued for the rest of the budget, but kept only
    if it ends below the first fit."""
    merits = iter([3.0, 0.5, 4.0, 6.0, 2.0])     # four probes, then the continuation of probe 1

    def local(start, iters):
        return _fake(next(merits))

    best, tried = restart(local, _fake(1.0), 4, 15)
    assert best.merit == 1.0 and tried[1]["final_merit"] == 2.0 and tried[1]["kept"] is False


def test_a_probe_near_the_first_fit_is_continued():
    """After five iterations a probe is still falling: one within
    CONTINUE_WITHIN of the first fit's merit is continued, and kept when it
    ends lower; one beyond it is not continued at all."""
    from calibration.fit.proxy import CONTINUE_WITHIN

    merits = iter([1.2, 3.0, 4.0, 6.0, 0.8])
    best, tried = restart(lambda start, iters: _fake(next(merits)), _fake(1.0), 4, 15)
    assert 1.2 < CONTINUE_WITHIN
    assert best.merit == pytest.approx(0.8) and tried[0]["kept"] is True
    far = iter([CONTINUE_WITHIN * 1.01, 3.0, 4.0, 6.0])
    best, tried = restart(lambda start, iters: _fake(next(far)), _fake(1.0), 4, 15)
    assert best.merit == 1.0 and all("final_merit" not in t for t in tried)


# Coarse-to-fine fits

NAMES = ["e1.decenter_x", "s17.thickness"]
U_TRUE = np.array([0.8, 0.6])


@pytest.fixture(scope="module")
def grid_device(make_e9_device):
    return make_e9_device(NAMES, U_TRUE, grid=(4, 6), noise=0.003, rng=3)


def one_per_region(obs, grid):
    """``obs``'s first observation moved to the centre of every region of ``grid``."""
    rows, cols = grid
    r, c = np.divmod(np.arange(rows * cols), cols)
    first = obs.subset(np.zeros(rows * cols, int))
    return first.with_fields(x_px=(c + 0.5) / cols * obs.sensor.width_px, y_px=(r + 0.5) / rows * obs.sensor.height_px,
                             grid=(rows, cols))


def test_the_sub_grid_spans_the_field_corners_included(grid_device):
    from calibration.fit.proxy import coarse_subset

    _, obs = grid_device
    full = one_per_region(obs, (15, 20))
    mask = coarse_subset(full, (5, 7))
    kept = full.region[mask]
    assert sorted(set(kept[:, 0])) == [0, 4, 7, 10, 14]
    assert sorted(set(kept[:, 1])) == [0, 3, 6, 10, 13, 16, 19]
    assert mask.sum() == 35
    # nothing to gain on a grid no larger than twice the sub-grid, or below the least count
    assert coarse_subset(one_per_region(obs, (5, 7)), (5, 7)) is None
    # a fit of more parameters gets a larger sub-grid, spread the same way, as long as it halves the field
    grown = coarse_subset(full, (5, 7), min_obs=36)
    assert grown.sum() == 48
    assert {0, 14} <= set(full.region[grown][:, 0]) and {0, 19} <= set(full.region[grown][:, 1])
    assert coarse_subset(full, (5, 7), min_obs=151) is None


def test_coarse_to_fine_recovers_the_device_as_the_full_fit_does(grid_device):
    from calibration.fit.proxy import ProxyFitSettings, fit_proxy

    lens, obs = grid_device
    kw = dict(residuals="sfra", max_iter=6, restarts=0)
    serial = create_executor("serial")
    full = fit_proxy(lens, obs, ProxyFitSettings(coarse=None, **kw), names=NAMES, executor=serial)
    staged = fit_proxy(lens, obs, ProxyFitSettings(coarse=(2, 3), **kw), names=NAMES, executor=serial)
    # rows 0 and 3, columns 0, 2 and 5 of 4 × 6: 6 of 24 regions, two edges each
    assert staged.coarse["observations"] == 12 and not full.coarse
    assert len(staged.observations) == len(obs) == 48
    assert staged.evaluations > staged.coarse["evaluations"] > 0
    err_full = np.abs(full.u - U_TRUE).max()
    err_staged = np.abs(staged.u - U_TRUE).max()
    assert err_full < 0.1 and err_staged < max(0.1, 1.5 * err_full)
    assert staged.result.merit <= 1.1 * full.result.merit
    # fine_iter = 0: the sub-grid's fit is the result, its observations the sub-grid's, no evaluation on the rest
    quick = fit_proxy(lens, obs, ProxyFitSettings(coarse=(2, 3), fine_iter=0, **kw), names=NAMES, executor=serial)
    assert len(quick.observations) == 12 and quick.coarse["refined"] is False
    assert quick.evaluations == quick.coarse["evaluations"] < staged.evaluations
    assert np.abs(quick.u - U_TRUE).max() < 0.25


def test_a_staged_coarse_fit_leads_with_a_few_parameters_and_recovers_the_device(grid_device):
    """``stage_params``: the coarse stage also fits its most sensitive
    parameter(s) first, then all of them from there, and keeps the better
    coarse fit; the device is recovered as by the fit of all at once, both
    stages' evaluations counted."""
    from calibration.fit.proxy import ProxyFitSettings, fit_proxy

    lens, obs = grid_device
    kw = dict(residuals="sfra", max_iter=6, restarts=0, coarse=(2, 3))
    serial = create_executor("serial")
    plain = fit_proxy(lens, obs, ProxyFitSettings(**kw), names=NAMES, executor=serial)
    staged = fit_proxy(lens, obs, ProxyFitSettings(stage_params=1, **kw), names=NAMES, executor=serial)
    assert list(staged.space.names) == NAMES
    assert np.abs(staged.u - U_TRUE).max() < 0.1
    assert staged.coarse["evaluations"] > plain.coarse["evaluations"]
    # the staged start is recorded beside the restarts, and the better coarse fit kept
    (rec,) = [r for r in staged.restarts if r["start"] == "1 first"]
    assert rec["kept"] == (rec["final_merit"] < plain.coarse["merit"])
    with pytest.raises(ConfigError, match="stage_params"):
        ProxyFitSettings(stage_params=0)


def test_every_kind_spans_what_a_module_drawn_within_tolerance_is_perturbed_in(e9_lens):
    """``--kinds all`` (:data:`ALL_KINDS`): the perturbations ``isp calib
    simulate --perturb random`` draws for a module (the design's default
    tolerance space), and focus, which assembly sets; the default kinds
    are the assembly's alone, a strict subset."""
    from calibration.fit.proxy import ALL_KINDS, FIT_KINDS, default_names, focus_name
    from calibration.optics.perturb import ParameterSpace

    drawn = set(ParameterSpace.default(e9_lens).names)
    every = default_names(e9_lens, ALL_KINDS)
    assert set(every) == drawn | {focus_name(e9_lens)} and len(every) == len(set(every))
    assert set(default_names(e9_lens, FIT_KINDS)) < set(every)
    assert any(n.endswith(".curvature") for n in drawn) and any(n.endswith(".conic") for n in drawn)


@pytest.fixture(scope="module")
def power_device(make_e9_device):
    """An e9 device whose one perturbation is a power error (0.9 tolerance on surface 4's curvature)."""
    return make_e9_device(["s4.curvature"], np.array([0.9]), grid=(4, 6), noise=0.003, rng=3)


def test_a_power_error_is_fitted_by_the_kinds_that_make_it_not_mimicked_by_assembly(power_device):
    """``kinds``: a device with a power error, which decenters, tilts, gaps
    and focus (the default kinds) can only mimic: screened from those, the
    fit ends at tens of times the χ² of a fit of the true parameter alone
    (the reference); screened from curvatures and focus, at a quarter of
    the assembly fit's or less, whichever surfaces' powers it uses (they
    are near-degenerate: it picks others than surface 4 and stops above
    the reference)."""
    from calibration.fit.proxy import FIT_KINDS, ProxyFitSettings, fit_proxy

    lens, obs = power_device
    kw = dict(residuals="sfra", max_iter=6, restarts=0, coarse=None, n_params=3)
    serial = create_executor("serial")

    def chi2(fit):
        return fit.errors()["after"]["chi2_per_obs"]

    truth = chi2(fit_proxy(lens, obs, ProxyFitSettings(**kw), names=["s4.curvature"], executor=serial))
    assembly = fit_proxy(lens, obs, ProxyFitSettings(kinds=FIT_KINDS, **kw), executor=serial)
    power = fit_proxy(lens, obs, ProxyFitSettings(kinds=("curvature", "focus"), **kw), executor=serial)
    assert not any("curvature" in n for n in assembly.space.names)
    assert all(n.endswith(("curvature", "thickness")) for n in power.space.names)
    assert chi2(assembly) > 20 * truth
    assert truth < chi2(power) < chi2(assembly) / 4
    with pytest.raises(ConfigError, match="kinds"):
        ProxyFitSettings(kinds=("power",))


def test_a_fit_whose_lens_spills_out_of_the_window_is_redone_wider(grid_device):
    """``widen``: the fitted lens keeps less than 90 % of some observation's
    light inside a 4 µm window (e9's PSF is several µm wide); the fit is
    redone 1.5× wider each time until it keeps 90 % (here, within 32 µm), each
    narrower try recorded with its energy, the seconds summed. Without it
    the one fit is the result."""
    from calibration.fit.forward_model import ModelSettings
    from calibration.fit.proxy import WIDEN_FACTOR, ProxyFitSettings, fit_proxy
    from calibration.optics.psf.map import WINDOW_ENERGY_WARN

    lens, obs = grid_device
    kw = dict(residuals="sfra", max_iter=1, restarts=0, coarse=None, model=ModelSettings(window_um=4.0))
    serial = create_executor("serial")
    narrow = fit_proxy(lens, obs, ProxyFitSettings(**kw), names=NAMES, executor=serial)
    assert narrow.window_energy < WINDOW_ENERGY_WARN and "widened" not in narrow.settings
    wide = fit_proxy(lens, obs, ProxyFitSettings(widen=True, **kw), names=NAMES, executor=serial)
    tried = wide.settings["widened"]
    assert tried[0]["window_um"] == 4.0 and tried[0]["window_energy_min"] == round(narrow.window_energy, 4)
    assert all(t["window_energy_min"] < WINDOW_ENERGY_WARN for t in tried)
    assert wide.settings["window_um"] == pytest.approx(4.0 * WIDEN_FACTOR ** len(tried))
    assert wide.window_energy >= WINDOW_ENERGY_WARN and wide.settings["window_um"] <= 32.0
    assert wide.seconds >= sum(t["seconds"] for t in tried)
    with pytest.raises(ConfigError, match="widen"):
        ProxyFitSettings(widen=1)


def test_widening_stops_where_a_wider_window_recovers_no_light(monkeypatch):
    """Light lost for another reason than the window's size (a module of e2
    kept 78 % of a region's light in 32 µm, 81 % in 48, 82 % in 72): one
    widening is tried, the next is not, since 48 µm recovered 3 of the 22
    missing points (under :data:`WIDEN_RECOVERS` of them); the 48 µm fit is
    the result. Where each widening recovers most of it, it goes on."""
    from types import SimpleNamespace

    import calibration.fit.proxy as proxy
    from calibration.fit.forward_model import ModelSettings

    def fake(energies):
        calls = []

        def fit(nominal, obs, cfg, names, x0, executor):
            w = (cfg.model or ModelSettings()).window_um
            calls.append(w)
            return SimpleNamespace(window_energy=energies[w], seconds=1.0, settings={"window_um": w})
        return fit, calls

    fit, calls = fake({32.0: 0.78, 48.0: 0.81, 72.0: 0.82, 108.0: 0.83, 128.0: 0.83})
    monkeypatch.setattr(proxy, "_fit_proxy", fit)
    out = proxy.fit_proxy(None, None, proxy.ProxyFitSettings(widen=True))
    assert calls == [32.0, 48.0] and out.settings["window_um"] == 48.0
    assert [t["window_um"] for t in out.settings["widened"]] == [32.0] and out.seconds == 2.0
    fit, calls = fake({32.0: 0.5, 48.0: 0.7, 72.0: 0.85, 108.0: 0.95})
    monkeypatch.setattr(proxy, "_fit_proxy", fit)
    out = proxy.fit_proxy(None, None, proxy.ProxyFitSettings(widen=True))
    assert calls == [32.0, 48.0, 72.0, 108.0] and out.window_energy == 0.95


def test_a_device_focused_beyond_two_tolerances_is_fitted_at_its_focus(make_e9_device):
    """A module's best focus moves with its tolerance stack (up to 56 µm on
    e9 devices drawn within tolerance): the fit's focus range is
    ±FOCUS_BOUND tolerances, not the others' ±2. A device 35 µm out of focus
    (3.5 tolerances) with a decenter is fitted at its focus, to within 3 µm
    (measured 33.0 µm: the device's PSFs are the map's, the fit's model its
    own), where a ±2 bound would hold it at 20."""
    from calibration.fit.proxy import FOCUS_BOUND, ProxyFitSettings, fit_proxy

    assert FOCUS_BOUND * 10 >= 56
    lens, obs = make_e9_device(["e1.decenter_x", "s17.thickness"], np.array([0.8, 3.5]), grid=(4, 6), noise=0.003,
                               rng=3)
    fit = fit_proxy(lens, obs, ProxyFitSettings(residuals="sfra", max_iter=12, restarts=0, coarse=None),
                    names=["e1.decenter_x", "s17.thickness"], executor=create_executor("serial"))
    u = dict(zip(fit.space.names, fit.u))
    assert u["s17.thickness"] == pytest.approx(3.5, abs=0.3)

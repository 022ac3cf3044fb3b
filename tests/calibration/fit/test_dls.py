"""The damped least-squares core: closed forms and the statistics of least
squares (kind: property), and scipy's ``least_squares`` on the same
residuals (kind: published)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.optimize import least_squares

from calibration.fit.dls import DLSSettings, damped_least_squares


@pytest.mark.property
def test_linear_problem_reaches_the_normal_equations_solution(rng):
    B = rng.normal(size=(40, 5))
    y = rng.normal(size=40)
    res = damped_least_squares(lambda x: B @ x - y, np.zeros(5),
                               lower=-1e3 * np.ones(5), upper=1e3 * np.ones(5),
                               settings=DLSSettings(h=1e-3, gtol=1e-10))
    ref = np.linalg.lstsq(B, y, rcond=None)[0]
    assert np.allclose(res.x, ref, atol=1e-6)
    # covariance of a unit-noise linear problem is (BᵀB)⁻¹ × max(1, χ²_red)
    chi2 = res.merit / (40 - 5)
    assert np.allclose(res.covariance, np.linalg.inv(B.T @ B) * max(1.0, chi2), rtol=1e-5)


@pytest.mark.published
def test_nonlinear_fit_matches_scipy(rng):
    t = np.linspace(0, 4, 60)
    truth = np.array([2.0, 1.3, 0.4])
    y = truth[0] * np.exp(-truth[1] * t) + truth[2] + rng.normal(0, 0.01, t.size)

    def f(p):
        return (p[0] * np.exp(-p[1] * t) + p[2] - y) / 0.01

    lo, hi = np.array([0.0, 0.0, -5.0]), np.array([10.0, 10.0, 5.0])
    ours = damped_least_squares(f, np.array([1.0, 0.5, 0.0]),
                                lower=lo, upper=hi, settings=DLSSettings(h=1e-6, gtol=1e-8))
    ref = least_squares(f, np.array([1.0, 0.5, 0.0]), bounds=(lo, hi), x_scale="jac")
    assert np.allclose(ours.x, ref.x, rtol=1e-4, atol=1e-5)
    assert ours.merit <= ref.cost * 2 * (1 + 1e-6)
    # the uncertainty is the true spread's order (noise 0.01)
    assert np.all(ours.std < 0.05) and np.all(ours.std > 1e-4)


@pytest.mark.property
def test_bounds_hold_and_stop_on_the_boundary():
    # minimum at x = 3, bound at 2
    res = damped_least_squares(lambda x: np.array([x[0] - 3.0, 0.1 * (x[1] - 1.0)]), np.array([0.0, 0.0]),
                               lower=np.array([-2.0, -2.0]), upper=np.array([2.0, 2.0]), settings=DLSSettings(h=1e-4))
    assert res.x[0] == pytest.approx(2.0) and res.x[1] == pytest.approx(1.0, abs=1e-3)


@pytest.mark.property
def test_strongly_nonlinear_parameter_converges():
    # Rosenbrock as least squares: the curved valley needs damping
    def f(x):
        return np.array([10 * (x[1] - x[0] ** 2), 1 - x[0]])

    res = damped_least_squares(f, np.array([-1.2, 1.0]),
                               lower=np.full(2, -5.0), upper=np.full(2, 5.0),
                               settings=DLSSettings(h=1e-6, max_iter=200, gtol=1e-10, ftol=0.0))
    assert np.allclose(res.x, [1.0, 1.0], atol=1e-4)
    assert all(h["merit"] <= h0["merit"] + 1e-12 for h0, h in zip(res.history, res.history[1:]))


@pytest.mark.property
def test_stops_at_the_noise_floor():
    calls = []

    def f(x):
        calls.append(1)
        return np.array([x[0] - 1.0, 1.0, 1.0])   # irreducible part: φ/M ≥ 2/3

    res = damped_least_squares(f, np.array([5.0]),
                               lower=[-10.0], upper=[10.0], settings=DLSSettings(h=1e-4, target_chi2=0.7))
    # stops where the χ² left to gain is below 1: (x − 1)² < 1 on top of φ/M ≤ 0.7
    assert res.reason == "noise floor" and res.merit / 3 <= 0.7 and abs(res.x[0] - 1.0) < 0.3


T = np.linspace(0.0, 3.0, 120)
TRUTH = np.array([40.0, 1.3, 5.0, -3.0, 2.0, 0.7])


def _decay_sine(seed: int, sigma: float):
    """Residuals of a decaying exponential + sine + quadratic fitted to its
    own samples plus noise of ``sigma`` (data in units of σ = 1), a start
    20 % off the truth, and scipy's minimum from there (the oracle)."""
    def model(x):
        return x[0] * np.exp(-x[1] * T) + x[2] * np.sin(x[3] * T) + x[4] * T + x[5] * T * T

    y = model(TRUTH) + sigma * np.random.default_rng(seed).standard_normal(T.size)

    def f(x):
        return model(x) - y

    x0 = TRUTH * 0.8
    return f, x0, least_squares(f, x0, xtol=1e-14, ftol=1e-14, gtol=1e-14)


@pytest.mark.property
def test_the_noise_floor_stop_lands_within_one_chi2_of_the_minimum():
    """Property (statistics of least squares): a minimum's χ² is about
    M − N, so φ/M ≤ 1 alone stops a fit with about N of χ² still to gain.
    With the gain test the fit ends within 1 of the minimum that scipy
    finds (the oracle), on every noise draw, and the stop that looked at
    φ/M alone would have stopped earlier on most of them."""
    early = 0
    for seed in range(5):
        f, x0, best = _decay_sine(seed, sigma=1.0)   # σ = 1: φ is a χ²
        phi_min = float(np.sum(best.fun ** 2))
        res = damped_least_squares(f, x0,
                                   lower=np.full(6, -100.0), upper=np.full(6, 100.0),
                                   settings=DLSSettings(h=1e-6, target_chi2=1.0, max_iter=200))
        assert res.merit - phi_min < 1.0, (seed, res.merit, phi_min, res.reason)
        assert phi_min < T.size - 6 + 3 * np.sqrt(2 * (T.size - 6))   # a χ²(M − N) draw
        early += any(h["merit"] / T.size <= 1.0 and h["merit"] - phi_min > 1.0 for h in res.history)
    assert early >= 3


@pytest.mark.property
def test_with_no_chi2_target_it_stops_within_one_scaled_unit_of_the_minimum():
    """A model that cannot reach the noise (residuals 3× their stated σ: χ²
    per degree of freedom about 9): ``target_chi2=inf`` stops on the gain
    left alone, in units of φ/(M − N), and ends within one such unit of
    scipy's minimum (the oracle), its parameters within their (scaled) 1-σ
    uncertainty of it; and on most draws further than one plain unit of χ²
    from it, where a stop in plain units would have gone on."""
    sooner = 0
    for seed in range(4):
        f, x0, best = _decay_sine(seed, sigma=3.0)
        phi_min = float(np.sum(best.fun ** 2))
        unit = phi_min / (T.size - 6)
        assert unit > 5.0
        res = damped_least_squares(f, x0,
                                   lower=np.full(6, -100.0), upper=np.full(6, 100.0),
                                   settings=DLSSettings(h=1e-6, target_chi2=np.inf, max_iter=200))
        assert res.reason == "noise floor" and res.merit - phi_min < unit, (seed, res.merit, phi_min)
        assert np.all(np.abs(res.x - best.x) < res.std), (seed, res.x - best.x, res.std)
        sooner += res.merit - phi_min > 1.0
    assert sooner >= 2


@pytest.mark.property
def test_steps_stay_within_the_trust_radius():
    # the Gauss–Newton step is 7.07 long; the first step must respect Δ = 0.1 (and keep GN's direction)
    y = np.array([5.0, -4.0, 3.0])
    res = damped_least_squares(lambda x: x - y, np.zeros(3),
                               lower=np.full(3, -1e3), upper=np.full(3, 1e3),
                               settings=DLSSettings(h=1e-3, radius=0.1, max_iter=1))
    assert 0.05 <= np.linalg.norm(res.x) <= 0.1 + 1e-12
    assert np.allclose(res.x / np.linalg.norm(res.x), y / np.linalg.norm(y), atol=1e-9)
    # without a radius the same damping takes (nearly) the whole Gauss–Newton step
    free = damped_least_squares(lambda x: x - y, np.zeros(3),
                                lower=np.full(3, -1e3), upper=np.full(3, 1e3),
                                settings=DLSSettings(h=1e-3, radius=None, max_iter=1))
    assert np.linalg.norm(free.x) > 0.9 * np.linalg.norm(y)


@pytest.mark.property
def test_central_differences_are_exact_on_a_quadratic():
    from calibration.fit.dls import forward_jacobian

    def many(points):
        return [np.array([p[0] ** 2 + 3 * p[1], p[1] ** 2]) for p in points]

    x = np.array([1.0, 2.0])
    f0 = many([x])[0]
    lo, hi = np.full(2, -10.0), np.full(2, 10.0)
    exact = np.array([[2.0, 3.0], [0.0, 4.0]])
    central = forward_jacobian(many, x, f0, 0.5, lo, hi, central=True)
    forward = forward_jacobian(many, x, f0, 0.5, lo, hi)
    assert np.allclose(central, exact, atol=1e-12)
    # forward differences are off by h·f''/2 = 0.5 on the diagonal
    assert np.allclose(forward - exact, [[0.5, 0.0], [0.0, 0.5]], atol=1e-12)


@pytest.mark.property
def test_cheap_jacobian_reaches_the_same_minimum(rng):
    t = np.linspace(0, 4, 50)
    y = 2.0 * np.exp(-1.3 * t) + 0.4

    def f(p):
        return (p[0] * np.exp(-p[1] * t) + p[2] - y) / 0.01

    def cheap(points):   # a coarser model: every other sample's slope, scaled back up
        return [np.repeat(f(p)[::2], 2)[: t.size] for p in points]

    lo, hi = np.array([0.0, 0.0, -5.0]), np.array([10.0, 10.0, 5.0])
    res = damped_least_squares(f, np.array([1.0, 0.5, 0.0]),
                               lower=lo, upper=hi, jac_many=cheap,
                               settings=DLSSettings(h=1e-6, gtol=1e-9, max_iter=60))
    assert np.allclose(res.x, [2.0, 1.3, 0.4], atol=2e-3)


def _two_peaks(rng):
    """Two Gaussian peaks (6 parameters, 120 residuals, noise 0.01): the
    residual function, a start and the solver's keywords."""
    t = np.linspace(-1, 1, 120)
    truth = np.array([1.0, -0.3, 0.2, 0.8, 0.4, 0.15])

    def model(p):
        return (p[0] * np.exp(-(t - p[1]) ** 2 / (2 * p[2] ** 2))
                + p[3] * np.exp(-(t - p[4]) ** 2 / (2 * p[5] ** 2)))

    y = model(truth) + rng.normal(0, 0.01, t.size)

    def f(p):
        return (model(p) - y) / 0.01

    lo, hi = np.array([0, -1, 0.05, 0, -1, 0.05]), np.array([3, 1, 1, 3, 1, 1.0])
    x0 = np.array([0.7, -0.2, 0.3, 0.6, 0.3, 0.25])
    return f, x0, {"lower": lo, "upper": hi, "settings": DLSSettings(h=1e-6, gtol=1e-6, ftol=1e-8, max_iter=100)}


@pytest.mark.property
def test_broyden_reuse_reaches_the_same_minimum_with_fewer_evaluations(rng):
    # the secant updates must not change the answer, and must get near it for fewer
    # evaluations than a Jacobian every step
    f, x0, kw = _two_peaks(rng)
    full = damped_least_squares(f, x0, **kw)
    reuse = damped_least_squares(f, x0, **{**kw, "settings": dataclasses.replace(kw["settings"], refresh=2)})
    assert reuse.merit == pytest.approx(full.merit, rel=1e-8)
    assert np.allclose(reuse.x, full.x, atol=1e-5)
    assert any(h.get("secant") for h in reuse.history)

    def evaluations_to(res, merit):
        return next(h["evaluations"] for h in res.history if h["merit"] <= merit)

    near = full.merit * 1.01
    assert evaluations_to(reuse, near) < 0.7 * evaluations_to(full, near)
    # the merit never rises, secant steps included
    assert all(h["merit"] <= h0["merit"] + 1e-9 for h0, h in zip(reuse.history, reuse.history[1:]))


@pytest.mark.property
def test_broyden_update_is_exact_on_a_linear_map(rng):
    from calibration.fit.dls import broyden_update

    B = rng.normal(size=(5, 3))
    A = np.zeros((5, 3))
    for dx in np.eye(3):   # three independent secants recover a linear map exactly
        A = broyden_update(A, dx, B @ dx)
    assert np.allclose(A, B, atol=1e-12)


@pytest.mark.property
def test_a_wide_secant_start_jacobian_reaches_the_same_minimum(rng):
    # the proxy fit starts from its screening's secants (h = 0.5 tolerances): a start
    # Jacobian that is only roughly right must not change the answer, must save the first
    # finite-difference Jacobian, and a wrong shape is refused
    f, x0, kw = _two_peaks(rng)
    f0 = f(x0)
    wide = np.stack([(f(x0 + 0.05 * e) - f0) / 0.05 for e in np.eye(6)], axis=1)
    full = damped_least_squares(f, x0, **kw)
    started = damped_least_squares(f, x0, jac0=wide, **kw)
    assert started.merit == pytest.approx(full.merit, rel=1e-8)
    assert np.allclose(started.x, full.x, atol=1e-5)
    assert started.history[0]["evaluations"] == 1 and full.history[0]["evaluations"] == 1 + 6
    assert started.history[1]["secant"]
    with pytest.raises(ValueError, match="jac0"):
        damped_least_squares(f, x0, jac0=wide[:, :5], **kw)


@pytest.mark.property
def test_bracketed_trials_let_the_damping_fall_and_halve_the_iterations_on_a_linear_problem():
    """A linear problem is its own Gauss–Newton model: the bolder of two
    trials always wins, so bracketed trials divide λ by 4 (and the gain rule
    by 3) every step and reach the solution in half the iterations; trials
    that only add damping (bracket=False) fall by 3 a step."""
    rng = np.random.default_rng(0)
    a = rng.normal(size=(40, 6)) @ np.diag([1, 1, 0.3, 0.1, 0.03, 0.01])   # condition 100
    b = a @ rng.uniform(-1, 1, 6)
    runs = {br: damped_least_squares(lambda x: a @ x - b, np.zeros(6),
                                     lower=-2 * np.ones(6), upper=2 * np.ones(6),
                                     settings=DLSSettings(trials=2, max_iter=30, h=1e-3, bracket=br, gtol=1e-10,
                                                          ftol=1e-12, jacobian="forward"))
            for br in (False, True)}
    lam = {br: [h["lambda"] for h in r.history] for br, r in runs.items()}
    assert lam[True][1] == pytest.approx(lam[True][0] / 12) and lam[False][1] == pytest.approx(lam[False][0] / 3)
    iters = {br: len(r.history) - 1 for br, r in runs.items()}
    assert runs[True].merit < 1e-12 and runs[False].merit < 1e-12
    assert 2 * iters[True] <= iters[False], iters


@pytest.mark.property
def test_box_step_is_the_damped_models_minimiser_in_the_box():
    """bounds="box": the step minimises ‖AΔ + f‖² + Δᵀ D Δ inside the box
    (oracle: scipy's lsq_linear on the augmented system [A; √D], trust-region
    reflective, a different algorithm from the step's BVLS); clipping the
    free step does not, on some of the same problems."""
    from scipy.optimize import lsq_linear

    from calibration.fit.dls import _damped_step

    clip_worse = 0
    for seed in range(40):
        rng = np.random.default_rng(seed)
        a = rng.normal(size=(30, 8)) @ (np.eye(8) + 0.8 * rng.normal(size=(8, 8)))
        f = 5 * rng.normal(size=30)
        eps = np.full(8, 0.5)
        x = rng.uniform(-2, 2, 8)
        lo, hi = -2 - x, 2 - x
        q = lambda d: np.sum((a @ d + f) ** 2) + d @ (eps * d)   # noqa: E731
        ref = lsq_linear(np.vstack([a, np.diag(np.sqrt(eps))]), -np.concatenate([f, np.zeros(8)]),
                         bounds=(lo, hi), method="trf", tol=1e-12)
        box = _damped_step(a.T @ a, a.T @ f, np.arange(8), eps, None, (lo, hi))
        assert np.all(box >= lo - 1e-12) and np.all(box <= hi + 1e-12)
        assert q(box) <= q(ref.x) * (1 + 1e-8)
        clip = np.clip(_damped_step(a.T @ a, a.T @ f, np.arange(8), eps, None), lo, hi)
        clip_worse += q(clip) > q(ref.x) * (1 + 1e-3)
    assert clip_worse >= 10


@pytest.mark.property
def test_box_steps_reach_the_bounded_solution_in_fewer_iterations():
    """Six bounded linear problems whose solutions sit on 1–4 bounds: both
    bound rules reach scipy's lsq_linear solution; the box steps in fewer
    iterations all told (41 against 54 when written)."""
    from scipy.optimize import lsq_linear

    iters = {"clip": 0, "box": 0}
    for seed in range(6):
        rng = np.random.default_rng(seed)
        a = rng.normal(size=(40, 8)) @ (np.eye(8) + 0.8 * rng.normal(size=(8, 8)))
        b = a @ rng.uniform(-3, 3, 8) + rng.normal(size=40)
        ref = lsq_linear(a, b, bounds=(-2, 2), tol=1e-12)
        assert np.any(ref.active_mask != 0)
        for rule in iters:
            r = damped_least_squares(lambda x: a @ x - b, np.zeros(8),
                                     lower=-2 * np.ones(8), upper=2 * np.ones(8),
                                     settings=DLSSettings(trials=2, max_iter=30, h=1e-3, gtol=1e-10, ftol=1e-12,
                                                          jacobian="forward", bounds=rule))
            np.testing.assert_allclose(r.x, ref.x, atol=1e-6)
            iters[rule] += len(r.history) - 1
    assert iters["box"] < 0.85 * iters["clip"], iters

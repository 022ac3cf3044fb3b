"""Damped least squares with per-parameter dynamic damping (paper §3.2,
eqs. 17–22, Algorithm 1).

The problem: residuals ``f(u)`` (M values, already divided by their
measurement uncertainty) of N parameters ``u`` in *tolerance units* (the
perturbation divided by its tolerance, so every parameter's natural scale is
1), bounded to ``|u_j| ≤ bound``. Each iteration computes the Jacobian by
forward differences (eq. 22, ``A_ij = (f(u + h e_j) − f(u)) / h``; the
columns are independent lens evaluations, run by the caller's executor) and
takes the damped step of eq. 21,

    ΔP = −(AᵀA + D)⁻¹ Aᵀf,   D = diag(ε_j),

then accepts it if the merit ``φ = fᵀf`` fell.

Damping rule (the paper's supplement describes dynamic per-parameter
damping without the formula; this is ours, and why):

``ε_j = λ · d · s_j``

* ``d``: the mean of ``diag(AᵀA)`` (``scaling="levenberg"``, the default),
  so λ is dimensionless. The parameters are already in tolerance units —
  the paper's point of scaling by tolerances is that one unit means the same
  to every parameter — so the damping is the same for all before ``s_j``,
  and it bounds the step in the same metric as the trust radius below.
  ``scaling="marquardt"`` (``d_j = (AᵀA)_jj``) is kept for callers whose
  parameters are not naturally scaled; on the e9 benchmark device it ended
  at a 1.4 % higher merit after 13 Jacobians.
* ``λ`` follows the gain ratio ρ = (actual fall of φ) / (fall predicted by
  the linear model of eq. 20): ρ > 0.75 → λ/3 (the model is trusted: move
  towards Gauss–Newton), ρ < 0.25 → 2λ, a rejected step (φ rose) → 4λ and
  the step is retried from the same point without a new Jacobian.
* ``s_j ≥ 1`` measures each parameter's own non-linearity: after an accepted
  step, ``ν_j = ‖A_new[:, j] − A_old[:, j]‖ / ‖A_old[:, j]‖`` is how much the
  sensitivity to parameter j changed over the step; ``s_j ← max(1,
  s_j/2, (ν_j/τ)²)`` with τ = 0.3. The linear model (eq. 20) is only as good
  as the Jacobian's stability along each direction, so parameters whose
  columns change fast (a decenter near a vignetting edge, a conic near a
  caustic) are damped harder and individually, while the well-behaved ones
  keep Gauss–Newton-sized steps; the factor relaxes by half per step once
  the non-linearity is gone.

Trust radius (added after the e9 benchmark, where the first Gauss–Newton
step had a norm of 5.5 tolerances in a ±2 box and threw five parameters
onto bounds they never left: the fit stalled at 60× scipy's TRF merit): the
step's 2-norm is held within a radius Δ (parameter units; tolerance units
for proxy fits, so Δ = 1 means "one tolerance"). If the damped step is
longer, the damping of all parameters is raised (× 2 until it fits) —
Moré's LM/trust-region equivalence, so the step keeps the damped direction
instead of being truncated. Δ doubles after a step with ρ > 0.75 that used
at least half of it and halves after ρ < 0.25 or a rejection.

Parallel trials: when the caller evaluates points in parallel
(``fun_many``, 2 worker processes by default) each step tries ``trials``
dampings at once — the same wall time as one — and keeps the lowest
merit; a rejection then costs one round instead of one per damping. By
default every trial is at least as damped as the last step (ε, 4ε, … at
radii Δ, Δ/2, …), so whenever the damper trial wins λ rises, however well
the linear model held. ``bracket=True`` tries both sides instead (two
trials: ε/4 at 2Δ and ε at Δ); on a linear problem it needs half the
iterations (``tests/calibration/fit/test_dls.py``), but on the 12 synthetic devices of
``benchmarks/proxy.py`` (shape residuals, 15 iterations) it ended at a
lower merit on 7 and a higher one on 5 (e9's third device: 6,114 against
4,142), and its SFR error at FoV 0.9 trailed scipy TRF's by 7 % (5 %
without): so it is not the default.

Bounds: a step is clipped to the box; a parameter at a bound whose gradient
points outward is held fixed for the step (projected Gauss–Newton).
``bounds="box"`` instead takes the damped model's minimiser inside the box
(a bounded-variable least-squares solve on the Cholesky factor of
``AᵀA + D``): a clipped step leaves the other parameters where the clipped
one's motion had sent them. On six random bounded linear problems it needs
41 iterations in all against 54 (``tests/calibration/fit/test_dls.py``). On the 12
synthetic devices of ``benchmarks/proxy.py`` (devices 3–5 of each phone
lens, method ``ours_box``) it ended at a lower merit than scipy's TRF on 7
(the clipped steps: 4) but tied with the clipped steps in SFR error
(0.93× / 1.01× / 0.99× at FoV 0.1 / 0.5 / 0.9) and left as many
parameters on the bounds: so it is not the default.

Jacobian accuracy: forward differences are biased by O(h·f''), which near
the minimum swamps the small gradient (on e9 the fit crawled with ρ ≈ 0.1
even for steps of 0.01 tolerances: the linear model, not the step, was
wrong). ``jacobian="auto"`` therefore switches to central differences (2N
evaluations, O(h²)) once the merit stalls or two steps in a row have
ρ < 0.25, and only stops on a stall after that.

Jacobian reuse (``refresh`` > 1): a finite-difference Jacobian costs N
lens evaluations, a step ``trials`` (one round on the workers), so on a
phone lens the Jacobians are ~90 % of a fit. Between finite-difference
Jacobians the matrix is updated from the residuals the steps evaluated
anyway — Broyden's rank-one secant update [Broyden 1965], ``A ← A + (Δf −
A Δx) Δxᵀ / ‖Δx‖²``, from every trial of the round (each is a secant from
the same point), the accepted one last so that it holds exactly — for up to
``refresh − 1`` accepted steps in a row. A fresh finite-difference Jacobian
is taken instead after a step whose gain ratio fell below 0.25, before a
rejection is answered with more damping, and before the fit may stop on a
stalled merit: a secant Jacobian is only trusted while its steps keep
their promise. The non-linearity factors ``s_j`` compare finite-difference
Jacobians only. A start Jacobian handed in (``jac0``, e.g. the wider
secants a parameter screening already evaluated at ``x0``) is trusted the
same way: as a secant one, replaced by finite differences at the first
sign that it misleads.

Stopping (Algorithm 1's ``‖Aᵀf + εΔP‖ ≫ 0`` made concrete): the projected
gradient's largest component below ``gtol``, or φ falling by less than
``ftol`` relatively over two accepted steps, or the noise floor, or
``max_iter`` iterations.

The noise floor (residuals in units of their noise, φ a χ²): φ/M at most
``target_chi2`` *and* less than one unit of χ² left to gain in the
linearised model, ``‖f‖² − min_δ ‖f + A δ‖² < 1`` over the free
parameters. φ/M ≤ 1 alone stops short: a least-squares minimum has
χ² ≈ M − N (its degrees of freedom), so a fit that crosses M still has
about N to gain, and its parameters are off by about their 1-σ
uncertainty. On the synthetic devices of ``benchmarks/proxy.py`` where
φ/M ≤ 1 alone would stop the fit, scipy's TRF goes on to a merit 4–10 %
lower. The unit is φ/(M − N) where that is above 1
(a model that cannot reach the noise; its parameters' uncertainty is
scaled the same way), so that ``target_chi2=inf`` stops a fit once what
is left to gain is within the parameters' uncertainty, whatever χ² the
model leaves.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from isp.errors import ConfigError

NONLINEARITY_TAU = 0.3


@dataclass
class DlsResult:
    """Outcome of :func:`damped_least_squares`.

    Attributes
    ----------
    x : (N,) ndarray
        Parameters in the caller's units (tolerance units for proxy fits).
    residuals : (M,) ndarray
        f(x).
    jacobian : (M, N) ndarray
        The last Jacobian (at ``x`` if the last step was accepted and
        re-linearised, else at the previous point).
    covariance : (N, N) ndarray
        (AᵀA)⁻¹ scaled by the reduced χ² when it exceeds 1: the parameters'
        uncertainty from the residuals' (unit-variance) noise.
    history : list of dict
        Per iteration: merit, λ, accepted, step norm, evaluations so far.
    evaluations : int
        Calls of the residual function.
    reason : str
        Why it stopped.
    seconds : float
    """

    x: np.ndarray
    residuals: np.ndarray
    jacobian: np.ndarray
    covariance: np.ndarray
    history: list = field(default_factory=list)
    evaluations: int = 0
    reason: str = ""
    seconds: float = 0.0

    @property
    def merit(self) -> float:
        return float(self.residuals @ self.residuals)

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0, None))


def forward_jacobian(fun_many: Callable[[Sequence[np.ndarray]], list], x: np.ndarray, f0: np.ndarray,
                     h: float | np.ndarray, lower: np.ndarray, upper: np.ndarray,
                     central: bool = False) -> np.ndarray:
    """Finite-difference Jacobian (eq. 22): forward differences, or central
    ones (``central``: twice the evaluations, error O(h²) instead of O(h));
    a step that would leave the box is taken backwards (one-sided) instead.
    ``fun_many`` evaluates a list of points (in parallel, if it can)."""
    n = x.size
    hs = np.broadcast_to(np.asarray(h, float), (n,)).copy()
    points, pairs = [], []
    for j in range(n):
        up_ok, down_ok = x[j] + hs[j] <= upper[j], x[j] - hs[j] >= lower[j]
        if central and up_ok and down_ok:
            a, b = x.copy(), x.copy()
            a[j] += hs[j]
            b[j] -= hs[j]
            pairs.append((len(points), len(points) + 1, 2 * hs[j]))
            points += [a, b]
        else:
            step = hs[j] if up_ok else -hs[j]
            a = x.copy()
            a[j] += step
            pairs.append((len(points), None, step))
            points.append(a)
    cols = fun_many(points)
    return np.stack([(cols[i] - (f0 if k is None else cols[k])) / w for i, k, w in pairs], axis=1)


def broyden_update(A: np.ndarray, dx: np.ndarray, df: np.ndarray) -> np.ndarray:
    """Broyden's rank-one secant update: the Jacobian closest to ``A``
    (Frobenius) with ``A' Δx = Δf`` (C. G. Broyden, "A class of methods for
    solving nonlinear simultaneous equations", Math. Comp. 19, 1965).

    >>> A = broyden_update(np.zeros((2, 2)), np.array([1.0, 0.0]), np.array([2.0, 3.0]))
    >>> A @ np.array([1.0, 0.0])
    array([2., 3.])
    """
    nn = float(dx @ dx)
    if nn <= 0.0:
        return A
    return A + np.outer(df - A @ dx, dx) / nn


def _damped_step(jtj: np.ndarray, g: np.ndarray, idx: np.ndarray, eps: np.ndarray,
                 delta: float | None, room: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Eq. 21 on the free parameters ``idx``; with a radius ``delta`` the
    damping is raised (× 2 at a time) until ``‖ΔP‖ ≤ delta``.

    ``room``: ``(lower − x, upper − x)``, the box around the current point.
    Then the step is the damped quadratic's minimiser *inside* the box,
    ``min ½ΔPᵀ(AᵀA + D)ΔP + gᵀΔP`` subject to the bounds (bounded-variable
    least squares on the Cholesky factor, :func:`scipy.optimize.lsq_linear`,
    "bvls": exact for these few parameters), rather than the unconstrained
    step clipped to the box, which leaves the other parameters where the
    clipped one's motion had sent them."""
    dx = np.zeros(g.size)
    if not idx.size:
        return dx
    sub = jtj[np.ix_(idx, idx)]
    for _ in range(60):
        h = sub + np.diag(eps[idx])
        if room is None:
            dx[idx] = -np.linalg.solve(h, g[idx])
        else:
            from scipy.optimize import lsq_linear

            c = np.linalg.cholesky(h)                            # h = c cᵀ: ½ΔPᵀhΔP + gᵀΔP = ½‖cᵀΔP + c⁻¹g‖² + const
            lo, hi = room[0][idx], room[1][idx]
            r = lsq_linear(c.T, -np.linalg.solve(c, g[idx]), bounds=(np.minimum(lo, 0.0), np.maximum(hi, 0.0)),
                           method="bvls", tol=1e-12)
            dx[idx] = r.x
        if delta is None or np.linalg.norm(dx) <= delta:
            break
        eps = eps * 2.0
    return dx


def _unit(phi: float, m: int, n: int) -> float:
    """One unit of χ² at the scale of the parameters' uncertainty: 1, or
    φ/(M − N) where the model's own error leaves more than 1 per degree of
    freedom (the covariance is scaled the same way)."""
    return max(1.0, phi / max(m - n, 1))


def _gain_left(a: np.ndarray, f: np.ndarray) -> float:
    """``‖f‖² − min_δ ‖f + a δ‖²``: what the Gauss–Newton model of the
    residuals ``f`` with Jacobian ``a`` can still remove (≥ 0)."""
    if a.shape[1] == 0:
        return 0.0
    delta = np.linalg.lstsq(a, -f, rcond=None)[0]
    return float(f @ f - np.sum((f + a @ delta) ** 2))


_JACOBIANS = ("auto", "forward", "central")
_SCALINGS = ("levenberg", "marquardt")
_BOUNDS = ("clip", "box")


@dataclass(frozen=True)
class DLSSettings:
    """How :func:`damped_least_squares` steps and stops (module docstring).
    Checked at construction (:class:`isp.errors.ConfigError` naming the
    field and value).

    Parameters
    ----------
    h : float or tuple of float
        Finite-difference step, parameter units (tolerances in a proxy
        fit), > 0; one per parameter or one for all.
    lam0 : float
        Initial λ (dimensionless with ``scaling="levenberg"``), > 0.
    max_iter : int
        Iterations at most, ≥ 1 (one finite-difference Jacobian each with
        ``refresh = 1``, fewer with secant updates).
    gtol, ftol : float
        Stopping tolerances, ≥ 0: projected gradient ∞-norm (residual ×
        residual per parameter unit); relative fall of φ over two accepted
        steps. With ``refresh`` > 1 the gradient test uses a fresh Jacobian.
    target_chi2 : float, optional
        The noise floor, χ² per residual, > 0: stop once φ/M ≤ this and the
        linearised model offers less than one unit of χ² to gain (module
        notes); ``inf``: on the gain left alone; None: no such test.
    radius : float or None
        Initial trust radius Δ (2-norm of a step, parameter units), > 0;
        None: no radius (plain LM).
    trials : int
        Dampings tried at once per step, ≥ 1 (use the number of workers).
    jacobian : {"auto", "forward", "central"}
        Finite differences; "auto" starts forward and switches to central
        for good once the merit stalls or two steps in a row fall short of
        the linear model (ρ < 0.25).
    scaling : {"levenberg", "marquardt"}
        The damping's scale ``d``: the mean of diag(AᵀA), or each
        parameter's own (module docstring).
    refresh : int
        A finite-difference Jacobian every ``refresh`` accepted steps at
        most, ≥ 1, Broyden updates in between (module docstring); 1
        (default): every step.
    bracket : bool
        With ``trials`` ≥ 2, try dampings on both sides of the current one
        rather than only more damped ones (module docstring; off by default,
        as measured there).
    bounds : {"clip", "box"}
        How a step meets the box: "clip" cuts the damped step at the box;
        "box" takes the damped model's minimiser inside the box (module
        docstring).

    Examples
    --------
    >>> DLSSettings(max_iter=10, h=1e-6).trials
    1
    >>> DLSSettings(refresh=0)
    Traceback (most recent call last):
    ...
    isp.errors.ConfigError: DLSSettings.refresh: must be an integer ≥ 1, got 0
    """

    h: float | tuple[float, ...] = 0.1
    lam0: float = 1e-2
    max_iter: int = 25
    gtol: float = 1e-6
    ftol: float = 1e-4
    target_chi2: float | None = None
    radius: float | None = 1.0
    trials: int = 1
    jacobian: str = "auto"
    scaling: str = "levenberg"
    refresh: int = 1
    bracket: bool = False
    bounds: str = "clip"

    def __post_init__(self):
        def bad(name, why):
            return ConfigError(f"DLSSettings.{name}: {why}")

        def integer(name, least):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < least:
                raise bad(name, f"must be an integer ≥ {least}, got {v!r}")
            object.__setattr__(self, name, int(v))

        def number(name, positive, optional=False):
            v = getattr(self, name)
            if v is None and optional:
                return
            try:
                x = float(v)
            except (TypeError, ValueError):
                x = float("nan")
            if not (x > 0 if positive else x >= 0):
                raise bad(name, f"must be a number {'>' if positive else '≥'} 0, got {v!r}")
            object.__setattr__(self, name, x)

        h = np.asarray(self.h, dtype=float) if not isinstance(self.h, str) else np.array(np.nan)
        if h.ndim > 1 or h.size == 0 or not np.all(h > 0) or not np.all(np.isfinite(h)):
            raise bad("h", f"must be a positive step or one per parameter, got {self.h!r}")
        object.__setattr__(self, "h", float(h) if h.ndim == 0 else tuple(h.tolist()))
        number("lam0", True)
        integer("max_iter", 1)
        number("gtol", False)
        number("ftol", False)
        number("target_chi2", True, optional=True)
        number("radius", True, optional=True)
        integer("trials", 1)
        integer("refresh", 1)
        for name, valid in (("jacobian", _JACOBIANS), ("scaling", _SCALINGS), ("bounds", _BOUNDS)):
            if getattr(self, name) not in valid:
                raise bad(name, f"unknown {getattr(self, name)!r}; valid: {', '.join(map(repr, valid))}")
        object.__setattr__(self, "bracket", bool(self.bracket))


def damped_least_squares(fun: Callable[[np.ndarray], np.ndarray], x0, *, lower, upper,
                         settings: DLSSettings | None = None,
                         fun_many: Callable[[Sequence[np.ndarray]], list] | None = None,
                         jac_many: Callable[[Sequence[np.ndarray]], list] | None = None,
                         jac0: np.ndarray | None = None, callback: Callable[[dict], None] | None = None,
                         executor=None) -> DlsResult:
    """Minimise ``‖fun(x)‖²`` within ``[lower, upper]`` (module docstring).

    Parameters
    ----------
    fun : callable
        (N,) → (M,) residuals (divided by their uncertainties).
    x0 : (N,) array_like
    lower, upper : (N,) array_like
    settings : DLSSettings, optional
        Steps, damping and stopping (default ``DLSSettings()``).
    fun_many : callable, optional
        Evaluates a list of points (the caller's map, e.g. over worker
        processes holding the model); default ``executor.map(fun, points)``.
    jac_many : callable, optional
        Evaluates a list of points for the Jacobian only — a cheaper model
        (fewer wavelengths, pupil samples): the step is then damped
        Gauss–Newton on an approximate Jacobian, still accepted only on the
        exact merit.
    jac0 : (M, N) array, optional
        A Jacobian at ``x0`` to start from instead of a finite-difference
        one (e.g. the screening's wider secants,
        :func:`calibration.fit.proxy.screen_parameters`). It is treated as a
        secant Jacobian: a failed step or a small gradient re-linearises by
        finite differences before anything is concluded from it.
    callback : callable, optional
        Called with each iteration's record (a dict: iteration, merit,
        lambda, accepted, step, evaluations, ...).
    executor : isp.runtime.executor.Executor, optional
        Maps ``fun`` over points where ``fun_many`` is not given ("serial":
        a loop, the default; "processes" needs a picklable ``fun``).

    Returns
    -------
    DlsResult
    """
    cfg = DLSSettings() if settings is None else settings
    if not isinstance(cfg, DLSSettings):
        raise ConfigError(f"settings must be a DLSSettings, got {type(cfg).__name__}")
    h, lam0, max_iter, gtol, ftol = cfg.h, cfg.lam0, cfg.max_iter, cfg.gtol, cfg.ftol
    target_chi2, radius, trials, jacobian, scaling = cfg.target_chi2, cfg.radius, cfg.trials, cfg.jacobian, cfg.scaling
    refresh, bracket, bounds, progress = cfg.refresh, cfg.bracket, cfg.bounds, callback
    h = np.asarray(h, float) if isinstance(h, tuple) else h
    if fun_many is None and executor is not None and executor.parallel:
        fun_many = functools.partial(executor.map, fun)
    t0 = time.perf_counter()
    lower = np.asarray(lower, float)
    upper = np.asarray(upper, float)
    x = np.clip(np.asarray(x0, float), lower, upper)
    n = x.size
    evals = 0

    def many(points):
        nonlocal evals
        evals += len(points)
        if fun_many is not None:
            return [np.asarray(v, float) for v in fun_many(points)]
        return [np.asarray(fun(p), float) for p in points]

    def jacobian_at(x, f):
        if jac_many is None:
            return forward_jacobian(many, x, f, h, lower, upper, central)

        def cheap(points):   # the base point is evaluated by the same (cheap) model
            nonlocal evals
            evals += len(points)
            return [np.asarray(v, float) for v in jac_many(points)]

        f_cheap = cheap([x])[0]
        return forward_jacobian(cheap, x, f_cheap, h, lower, upper, central)

    f = many([x])[0]
    phi = float(f @ f)
    m = f.size
    central = jacobian == "central"
    if jac0 is not None:
        A = np.asarray(jac0, float)
        if A.shape != (m, n):
            raise ValueError(f"jac0 has shape {A.shape}; the problem's Jacobian is {(m, n)}")
    else:
        A = jacobian_at(x, f)
    lam = float(lam0)
    delta = None if radius is None else float(radius)
    k0 = max(1, trials) // 2 if bracket else 0   # trials bolder than (λ, Δ): see the module docstring
    s = np.ones(n)
    # A is a finite-difference Jacobian at x (or jac0, a secant one); accepted steps on secants
    fresh, since_fd, A_fd = jac0 is None, 0, (A if jac0 is None else None)
    history = [{"iteration": 0, "merit": phi, "lambda": lam, "accepted": True, "step": 0.0, "evaluations": evals}]
    if progress:
        progress(history[-1])
    reason = "max_iter"
    last_phis = [phi]
    for it in range(1, max_iter + 1):
        g = A.T @ f
        free = ~(((x <= lower) & (g > 0)) | ((x >= upper) & (g < 0)))
        if np.max(np.abs(g[free]), initial=0.0) < gtol:
            if fresh:
                reason = "gradient"
                break
            A = A_fd = jacobian_at(x, f)   # a secant Jacobian's gradient is not proof of a minimum
            fresh, since_fd = True, 0
            continue
        if target_chi2 is not None and phi / m <= target_chi2 and _gain_left(A[:, free], f) < _unit(phi, m, n):
            reason = "noise floor"
            break
        jtj = A.T @ A
        d = np.maximum(np.diag(jtj), 1e-12 * max(np.max(np.diag(jtj)), 1e-300))
        if scaling == "levenberg":
            d = np.full(n, np.mean(d))
        accepted = False
        idx = np.flatnonzero(free)
        room = (lower - x, upper - x) if bounds == "box" else None
        secants = []   # (Δx, f(x + Δx)) of every trial: Broyden's data when A is not refreshed
        for _ in range(12):  # rounds of retries with more damping
            steps = []
            for k in range(max(1, trials)):
                e = k - k0
                dx = _damped_step(jtj, g, idx, lam * 4.0 ** e * d * s, None if delta is None else delta / 2.0 ** e,
                                  room)
                steps.append(np.clip(x + dx, lower, upper) - x)
            f_trials = many([x + dx for dx in steps])
            phis = [float(v @ v) for v in f_trials]
            secants += list(zip(steps, f_trials))
            best = int(np.argmin(phis))
            dx, f_new, phi_new = steps[best], f_trials[best], phis[best]
            lam *= 4.0 ** (best - k0)
            if delta is not None:
                delta /= 2.0 ** (best - k0)
            pred = phi - float(np.sum((f + A @ dx) ** 2))
            rho = (phi - phi_new) / pred if pred > 0 else -1.0
            if phi_new < phi:
                accepted = True
                lam = lam / 3.0 if rho > 0.75 else (lam * 2.0 if rho < 0.25 else lam)
                if delta is not None:
                    norm = float(np.linalg.norm(dx))
                    if rho > 0.75 and norm >= 0.5 * delta:
                        delta *= 2.0
                    elif rho < 0.25:
                        delta = max(0.5 * delta, 1e-3 * (radius or 1.0))
                break
            # the next round's boldest trial is 4× more damped than this round's most damped
            lam *= 4.0 ** max(1, trials - best + k0)
            if delta is not None:
                delta = max(delta / 2.0 ** max(1, trials - best + k0), 1e-6 * (radius or 1.0))
        history.append({"iteration": it, "merit": phi_new if accepted else phi, "lambda": lam, "radius": delta,
                        "central": central, "secant": not fresh, "s_max": float(np.max(s)),
                        "accepted": accepted, "step": float(np.linalg.norm(dx)), "evaluations": evals,
                        "rho": float(rho)})
        if progress:
            progress(history[-1])
        if not accepted:
            if not fresh:   # the secant Jacobian, not the damping, failed: re-linearise first
                A = A_fd = jacobian_at(x, f)
                fresh, since_fd = True, 0
                lam = float(lam0)
                delta = None if radius is None else float(radius)
                continue
            if jacobian == "auto" and not central:
                central = True   # a biased gradient can point uphill: retry with central differences
                A = jacobian_at(x, f)
                lam = float(lam0)
                delta = None if radius is None else float(radius)
                continue
            reason = "no descent (damping exhausted)"
            break
        f_old = f
        x, f = np.clip(x + dx, lower, upper), f_new
        last_phis.append(phi_new)
        phi = phi_new
        stalled = len(last_phis) >= 3 and (last_phis[-3] - phi) <= ftol * last_phis[-3]
        poor = rho < 0.25 and len(history) >= 2 and history[-2].get("rho", 1.0) < 0.25
        switch = jacobian == "auto" and not central and (stalled or poor)
        if switch:
            # forward differences' O(h) bias, not the problem, is what the poor linear model shows
            central = True
            last_phis = [phi]
            stalled = False
        secant = refresh > 1 and since_fd + 1 < refresh and rho >= 0.25 and not switch
        if stalled and not fresh:   # judge convergence on a finite-difference Jacobian
            stalled, secant, last_phis = False, False, [phi]
        if secant:
            # the accepted trial last, so that its secant holds exactly
            order = sorted(range(len(secants)), key=lambda k: secants[k][0] is dx)
            for k in order:
                A = broyden_update(A, secants[k][0], secants[k][1] - f_old)
            fresh, since_fd = False, since_fd + 1
        else:
            A_new = jacobian_at(x, f)
            if not switch and A_fd is not None:   # a change of scheme is not the problem's non-linearity
                col = np.linalg.norm(A_fd, axis=0)
                nu = np.linalg.norm(A_new - A_fd, axis=0) / np.maximum(col, 1e-12)
                s = np.maximum(np.maximum(1.0, s / 2.0), (nu / NONLINEARITY_TAU) ** 2)
            A = A_fd = A_new
            fresh, since_fd = True, 0
        if stalled:
            reason = "merit converged"
            break
    jtj = A.T @ A
    try:
        cov = np.linalg.pinv(jtj)
    except np.linalg.LinAlgError:
        cov = np.full((n, n), np.nan)
    chi2 = phi / max(m - n, 1)
    if chi2 > 1:
        cov = cov * chi2
    return DlsResult(x, f, A, cov, history, evals, reason, time.perf_counter() - t0)

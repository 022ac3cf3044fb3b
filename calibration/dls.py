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

``ε_j = λ · d_j · s_j``

* ``d_j = (AᵀA)_jj`` (Marquardt's scaling): damping proportional to each
  parameter's own curvature makes the step invariant to how parameters are
  scaled, so a barely-sensitive parameter is not thrown across its range by
  the same ε that holds back a sensitive one.
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

Bounds: a step is clipped to the box; a parameter at a bound whose gradient
points outward is held fixed for the step (projected Gauss–Newton).

Stopping (Algorithm 1's ``‖Aᵀf + εΔP‖ ≫ 0`` made concrete): the projected
gradient's largest component below ``gtol``, or φ falling by less than
``ftol`` relatively over two accepted steps, or φ/M below ``target_chi2``
(the residual reached the noise floor), or ``max_iter`` Jacobians.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

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
                     h: float | np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Forward-difference Jacobian (eq. 22); a step that would leave the box
    is taken backwards instead. ``fun_many`` evaluates a list of points (in
    parallel, if it can)."""
    n = x.size
    hs = np.broadcast_to(np.asarray(h, float), (n,)).copy()
    points = []
    for j in range(n):
        xj = x.copy()
        if x[j] + hs[j] > upper[j]:
            hs[j] = -hs[j]
        xj[j] += hs[j]
        points.append(xj)
    cols = fun_many(points)
    return np.stack([(c - f0) / hj for c, hj in zip(cols, hs)], axis=1)


def damped_least_squares(fun: Callable[[np.ndarray], np.ndarray], x0, *, lower, upper,
                         fun_many: Callable[[Sequence[np.ndarray]], list] | None = None,
                         h: float | np.ndarray = 0.1, lam0: float = 1e-2, max_iter: int = 25,
                         gtol: float = 1e-6, ftol: float = 1e-4, target_chi2: float | None = None,
                         progress: Callable[[dict], None] | None = None) -> DlsResult:
    """Minimise ``‖fun(x)‖²`` within ``[lower, upper]`` (module docstring).

    Parameters
    ----------
    fun : callable
        (N,) → (M,) residuals (divided by their uncertainties).
    x0 : (N,) array_like
    lower, upper : (N,) array_like
    fun_many : callable, optional
        Evaluates a list of points, e.g. on a process pool; default a loop.
    h : float or (N,)
        Finite-difference step.
    lam0 : float
        Initial λ.
    max_iter : int
        Jacobians at most.
    gtol, ftol : float
        Stopping tolerances (projected gradient ∞-norm; relative fall of φ).
    target_chi2 : float, optional
        Stop once φ/M ≤ this (the noise floor).
    progress : callable, optional
        Called with each iteration's record.

    Returns
    -------
    DlsResult
    """
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

    f = many([x])[0]
    phi = float(f @ f)
    m = f.size
    A = forward_jacobian(many, x, f, h, lower, upper)
    lam = float(lam0)
    s = np.ones(n)
    history = [{"iteration": 0, "merit": phi, "lambda": lam, "accepted": True, "step": 0.0, "evaluations": evals}]
    if progress:
        progress(history[-1])
    reason = "max_iter"
    last_phis = [phi]
    for it in range(1, max_iter + 1):
        g = A.T @ f
        free = ~(((x <= lower) & (g > 0)) | ((x >= upper) & (g < 0)))
        if np.max(np.abs(g[free]), initial=0.0) < gtol:
            reason = "gradient"
            break
        if target_chi2 is not None and phi / m <= target_chi2:
            reason = "noise floor"
            break
        jtj = A.T @ A
        d = np.maximum(np.diag(jtj), 1e-12 * max(np.max(np.diag(jtj)), 1e-300))
        accepted = False
        for _ in range(12):  # retries with more damping
            eps = lam * d * s
            dx = np.zeros(n)
            idx = np.flatnonzero(free)
            if idx.size:
                sub = jtj[np.ix_(idx, idx)] + np.diag(eps[idx])
                dx[idx] = -np.linalg.solve(sub, g[idx])
            x_new = np.clip(x + dx, lower, upper)
            dx = x_new - x
            f_new = many([x_new])[0]
            phi_new = float(f_new @ f_new)
            pred = phi - float(np.sum((f + A @ dx) ** 2))
            rho = (phi - phi_new) / pred if pred > 0 else -1.0
            if phi_new < phi:
                accepted = True
                lam = lam / 3.0 if rho > 0.75 else (lam * 2.0 if rho < 0.25 else lam)
                break
            lam *= 4.0
        history.append({"iteration": it, "merit": phi_new if accepted else phi, "lambda": lam,
                        "accepted": accepted, "step": float(np.linalg.norm(dx)), "evaluations": evals,
                        "rho": float(rho)})
        if progress:
            progress(history[-1])
        if not accepted:
            reason = "no descent (damping exhausted)"
            break
        x, f = x_new, f_new
        last_phis.append(phi_new)
        phi = phi_new
        A_new = forward_jacobian(many, x, f, h, lower, upper)
        col = np.linalg.norm(A, axis=0)
        nu = np.linalg.norm(A_new - A, axis=0) / np.maximum(col, 1e-12)
        s = np.maximum(np.maximum(1.0, s / 2.0), (nu / NONLINEARITY_TAU) ** 2)
        A = A_new
        if len(last_phis) >= 3 and (last_phis[-3] - phi) <= ftol * last_phis[-3]:
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

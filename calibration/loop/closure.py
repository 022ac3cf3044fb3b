"""Closing the loop: fit, find what the model lacks, add it, refit.

:func:`close_loop` starts from a base model (:mod:`calibration.loop.base`:
a lens with its perturbations, or a parametric optical MTF) and the
effects of the registry (:mod:`calibration.loop.effects`):

1. Fit the base parameters (damped least squares,
   :func:`calibration.fit.dls.damped_least_squares`). A base with a
   ``start()`` (a lens: :func:`calibration.fit.proxy.fit_proxy`, whose coarse
   stage and restarts find the basin) is fitted from there, for at most
   :data:`START_POLISH` iterations.
2. Estimate the measurement's noise floor from the data: every observation
   is re-rendered through the model with its own measured noise
   (``noise_realisations`` times) and re-measured; the spread of those
   SFRAs is the SFRA noise, σ_i = k·noise_i/step_i fitted over all
   observations (a smooth law: a handful of realisations per edge is too
   few for a per-edge σ). The floor is RMS(σ_i).
3. Residuals per observation: SFRA and the mean SFR in four frequency
   bands (0.02–0.125–0.25–0.375–0.5 cycles/pixel), each divided by its
   own noise, the same law fitted to the renders' spread of that band
   (on e1's device the bands' noise is 1.0, 2.0, 3.6 and 5.2 × SFRA's:
   the SFR's noise rises with frequency). They are
   decomposed by field position (x, y, radius), orientation, channel and
   band for the report.
4. Every registry effect not yet in the model is tried: its parameters are
   fitted (base held, or refitted with it where the base is cheap; from
   ``x0`` and the effect's further ``starts``, the best on the training
   data kept) on the training folds of a K-fold split *by field
   region* and scored on the held-out regions; its gain is the fall of the
   held-out χ², penalised by 2 per parameter per fold (AIC). An effect must
   also be *consistent*: no held-out fold may get worse by more than the
   penalty plus 3σ of that fold's χ² (σ = √(2n) for n terms). A physical
   effect of the registry acts over the whole field, so fitted on some
   regions it helps (or leaves) the others; one that buys a local defect
   (a smudge in one corner) with a large loss elsewhere is mimicking, not
   explaining (measured: sensor tilt fitted to a corner smudge made one
   fold 4.8× worse while helping the other two; the injected tilt helped
   all three folds by > 1000×). The best consistent effect is kept if it
   explains at least ``min_gain`` of the held-out χ²; then all
   parameters are refitted together (:func:`_joint_fit`: for a lens base,
   the Jacobian from the fitter's cheaper model on the executor's workers,
   refreshed every few steps as the fitter's; from a 1,200-edge e1
   capture, 81 parameters, from the nominal lens: 3 iterations to χ² 16.8
   per term in 53 s on two cores, where the serial fit with a full-model
   Jacobian every step took 641 s for 3, to 16.5; the iterations:
   :data:`POOLED_ITER_FACTOR`). Where no candidate reaches ``min_gain``
   with a lens base held (a base fitted first takes up what it can mimic:
   a uniform blur such as crosstalk by defocus and aberrations), the best
   ``confirm`` candidates by held-out gain are each refitted together with
   the base for a few iterations, against the base refitted alone as long
   (:func:`_confirm`); one whose χ² falls by ``confirm_gain`` more is kept
   and everything is refitted as above. Repeat until the SFRA residual is within
   ``stop_ratio`` of the noise floor or nothing helps. Each effect tried
   carries its confidence: ``z``, the fall of the held-out χ² (the
   penalty included) in units of that χ²'s own noise, √(2n) for n held-out
   terms (z ≈ 0 for an effect that is not there, negative where it only
   costs its penalty), and how many folds it improved.
5. What is left is described: remaining χ² per field ring, orientation and
   band; where it exceeds the floor, the report says so ("unexplained
   residual") rather than attributing it. The LSF's asymmetry, which the
   SFR drops and the loop does not fit, is checked against the final
   model (:func:`asymmetry_check`): edges asymmetric beyond their noise in
   a way the model cannot make are named too.

The error metric reported before/after is the SFRA RMS error
(cycles/pixel) on all observations, plus the SFR MSE (0–0.5 cycles/pixel)
and χ² per observation.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from isp.runtime.executor import pool_executor, worker_payload

from calibration.fit.dls import DLSSettings, damped_least_squares
from calibration.loop.effects import create_effect, list_effects
from calibration.fit.forward_model import BANDS, band_means

__all__ = ["LoopReport", "close_loop", "BANDS", "model_sfr", "plot_sfr_curves", "summary", "write_report"]

MODEL_FLOOR = 5e-4      # SFRA error a perfect fit still has (model discretisation), cycles/pixel


@dataclass
class LoopReport:
    base: str
    base_names: tuple
    base_x: np.ndarray
    effects_added: list
    effect_values: dict
    tried: list
    error_before: dict
    error_after: dict
    noise_floor: float
    unexplained: list
    decomposition_before: dict
    decomposition_after: dict
    seconds: float
    sfra_measured: np.ndarray = field(repr=False, default=None)
    sfra_before: np.ndarray = field(repr=False, default=None)
    sfra_after: np.ndarray = field(repr=False, default=None)
    base_x_before: np.ndarray = field(repr=False, default=None)    # the base fit before any effect
    asymmetry: dict | None = None                                   # :func:`asymmetry_check`
    steps_s: dict = field(default_factory=dict)    # wall seconds by step: base, noise, trials, refits
    defocus_um: float | None = None                 # :func:`sensor_defocus_um` of the final model
    sensor_surface: dict | None = None              # :func:`sensor_surface` of the final model

    def kept_effects(self) -> list[dict]:
        """The effects kept, in order, with their fitted values: the
        ``effects`` of a device file (``device/v1``)."""
        return [{"name": n, "params": {k: float(v) for k, v in self.effect_values[n].items()}}
                for n in self.effects_added]

    def confidence(self) -> dict:
        """Each kept effect's confidence when it was added (its held-out
        gain, ``z`` and folds improved; :func:`confidence`)."""
        out = {}
        for k, name in enumerate(self.effects_added, 1):
            t = next((t for t in self.tried if t["effect"] == name and t["round"] == k), None)
            if t is not None:
                out[name] = {"heldout_gain": round(float(t["gain"]), 4),
                             **{x: t[x] for x in ("z", "folds_improved", "folds") if x in t}}
                if "joint_gain" in t:       # kept by the confirmation (:func:`_confirm`)
                    out[name]["joint_gain"] = round(float(t["joint_gain"]), 4)
        return out

    def to_dict(self) -> dict:
        return {"schema": "loop-report/v1", "base": self.base,
                "base_parameters": {n: float(v) for n, v in zip(self.base_names, self.base_x)},
                "effects_added": list(self.effects_added), "effect_values": self.effect_values,
                "confidence": self.confidence(),
                "tried": self.tried, "error_before": self.error_before, "error_after": self.error_after,
                "noise_floor": self.noise_floor, "defocus_um": self.defocus_um,
                "sensor_surface": self.sensor_surface, "unexplained": self.unexplained,
                "decomposition_before": self.decomposition_before,
                "decomposition_after": self.decomposition_after, "asymmetry": self.asymmetry,
                "seconds": round(self.seconds, 1), "seconds_by_step": {k: round(v, 1) for k, v in self.steps_s.items()}}


class _Problem:
    """Parameters [base | effects...] → weighted residuals."""

    def __init__(self, base, obs, bias_a, bias_c, sigma):
        self.base, self.obs = base, obs
        self.bias_a, self.bias_bands = bias_a, band_means(obs.freq, bias_c)
        self.sigma = sigma
        self.meas_bands = band_means(obs.freq, np.asarray(obs.sfr))
        self.effects = []

    def split(self, p):
        out, i = [], len(self.base.names)
        xb = p[:i]
        for e in self.effects:
            out.append(p[i:i + len(e.names)])
            i += len(e.names)
        return xb, out

    def predict(self, p, effects=None, xs=None):
        effects = self.effects if effects is None else effects
        xb, xe = self.split(p) if xs is None else (p, xs)
        return predict_with_effects(self.base, xb, zip(effects, xe))

    def residuals(self, pred, mask=None):
        obs = self.obs
        ra = (obs.sfra - pred.sfra - self.bias_a) / self.sigma[:, 0]
        rb = (self.meas_bands - band_means(obs.freq, pred.sfr) - self.bias_bands) / self.sigma[:, 1:]
        r = np.concatenate([ra[:, None], rb], axis=1)
        r = np.where(np.isfinite(r), r, 0.0)
        if mask is not None:
            r = r[mask]
        return r.ravel()

    def errors(self, pred) -> dict:
        obs = self.obs
        d = obs.sfra - pred.sfra - self.bias_a
        f = np.asarray(obs.freq)
        m = f <= 0.5
        with np.errstate(invalid="ignore"):
            mse = np.nanmean((np.asarray(obs.sfr)[:, m] - pred.sfr[:, m]) ** 2)
        r = self.residuals(pred)
        out = {"sfra_rms": float(np.sqrt(np.mean(d ** 2))), "sfr_mse": float(mse),
               "chi2_per_obs": float(np.mean(r ** 2)),
               "normalised_rms_per_band": np.sqrt(np.mean(r.reshape(len(obs), -1)[:, 1:] ** 2, axis=0)).tolist()}
        for fov in (0.1, 0.5, 0.9):
            sel = np.abs(obs.radius - fov) <= 0.1
            if sel.any():
                out[f"sfra_rms_fov{fov}"] = float(np.sqrt(np.mean(d[sel] ** 2)))
                out[f"sfr_mse_fov{fov}"] = float(np.nanmean((np.asarray(obs.sfr)[sel][:, m] - pred.sfr[sel][:, m]) ** 2))
        return out


def _decompose(obs, d_sfra) -> dict:
    """Mean SFRA residual by field ring, half (x, y), orientation, channel."""
    out = {}
    r = obs.radius
    rings = np.digitize(r, [0.25, 0.5, 0.75])
    out["ring"] = {f"{lo:.2f}-{hi:.2f}": float(np.mean(d_sfra[rings == k])) if np.any(rings == k) else None
                   for k, (lo, hi) in enumerate(((0, .25), (.25, .5), (.5, .75), (.75, 1.0)))}
    cx, cy = obs.center_px
    x, y = np.asarray(obs.x_px) - cx, np.asarray(obs.y_px) - cy
    # a slope needs a spread of positions (observations on one line have none)
    out["x_slope_per_half_width"] = float(np.polyfit(x / cx, d_sfra, 1)[0]) if np.ptp(x) > 1e-6 * cx else 0.0
    out["y_slope_per_half_height"] = float(np.polyfit(y / cy, d_sfra, 1)[0]) if np.ptp(y) > 1e-6 * cy else 0.0
    for key in ("orientation", "channel"):
        v = np.asarray(getattr(obs, key))
        out[key] = {str(k): float(np.mean(d_sfra[v == k])) for k in np.unique(v)}
    # edge direction: sagittal/tangential is blind to an x/y anisotropy at the
    # centre of the field (all four sides of a centred square are "tangential")
    a = np.asarray(obs.normal_deg, float) % 180.0
    vert = (a < 45.0) | (a >= 135.0)
    out["direction"] = {k: float(np.mean(d_sfra[m])) for k, m in (("vertical", vert), ("horizontal", ~vert))
                        if m.any()}
    return out


def _folds(obs, k: int, seed: int = 0) -> np.ndarray:
    """Fold index per observation, whole field regions per fold."""
    reg = obs.region
    keys = reg[:, 0] * 1000 + reg[:, 1]
    uniq = np.unique(keys)
    rng = np.random.default_rng(seed)
    perm = rng.permutation(len(uniq))
    fold_of = {u: perm[i] % k for i, u in enumerate(uniq)}
    return np.array([fold_of[v] for v in keys])


def _fit(prob: _Problem, p0, lower, upper, free, mask=None, max_iter=10, h=None, pool=None, refresh=1, jac0=None):
    """DLS on the ``free`` parameters (bool mask), others held. ``pool``:
    an executor bound by :func:`_bind_problem` (every parameter free, no
    mask): the line search's trial points on its workers, the Jacobian's
    columns by the cheaper model there, a finite-difference Jacobian
    every ``refresh`` accepted steps (Broyden updates between). ``jac0``:
    a first Jacobian of the free parameters, scaled (:func:`_cheap_columns`),
    taken as a secant one (:func:`calibration.fit.dls.damped_least_squares`)."""
    if pool is not None and mask is not None:
        raise ValueError("a pool's workers fit every observation: no mask")
    p0 = np.asarray(p0, float)
    idx = np.nonzero(free)[0]
    scale = prob_scale(prob)[idx]

    def full(q):
        p = p0.copy()
        p[idx] = q * scale
        return p

    def fun(q):
        return prob.residuals(prob.predict(full(q)), mask)

    def on_pool(which):
        return lambda qs: pool.map(functools.partial(_worker_residuals, which), [full(q) for q in qs])

    many, cheap = (None, None) if pool is None else (on_pool("full"), on_pool("cheap"))
    settings = DLSSettings(h=0.5 if h is None else h, max_iter=max_iter, ftol=1e-3, refresh=refresh,
                           trials=1 if pool is None else pool.workers,
                           jacobian="auto" if pool is None else "forward")
    res = damped_least_squares(fun, p0[idx] / scale, lower=lower[idx] / scale, upper=upper[idx] / scale,
                               settings=settings, fun_many=many, jac_many=cheap, jac0=jac0)
    return full(res.x), res


def _bind_problem(prob: _Problem, ex, cheap: bool = True):
    """``ex`` bound to workers that each hold ``prob`` and, with ``cheap``,
    its twin on the fitter's cheaper Jacobian model
    (:data:`calibration.fit.forward_model.FAST_JACOBIAN`); None where ``ex``
    is serial or the base has no cheaper model (a parametric base is cheap
    already, and fast enough in this process)."""
    if not ex.parallel or not hasattr(prob.base, "with_settings"):
        return None
    from calibration.fit.forward_model import FAST_JACOBIAN

    return ex.bind((prob, FAST_JACOBIAN if cheap else None), setup=_problem_pair)


def _problem_pair(payload) -> dict:
    prob, settings = payload
    if settings is None:
        return {"full": prob}
    cheap = copy.copy(prob)
    cheap.base = prob.base.with_settings(settings)
    return {"full": prob, "cheap": cheap}


def _worker_residuals(which: str, p) -> np.ndarray:
    """The residuals at ``p`` of the worker's ``which`` problem ("full" or "cheap")."""
    prob = worker_payload()[which]
    return prob.residuals(prob.predict(p))


#: iterations of the refit on workers per iteration of the serial one: its Jacobian is refreshed
#: every third step, Broyden updates between. On the loop suite's case 0 (e1, 81 parameters, the
#: refit after sharpening was kept; two cores): 12 iterations ended at χ² 1.311 per term in 143 s,
#: 24 at 1.186 in 271 s, where 12 serial ones with a full-model Jacobian at each step had ended at
#: 1.182 in about 35 minutes (12 with a cheap Jacobian at each step: 1.176 in 321 s)
POOLED_ITER_FACTOR = 2


def _joint_fit(prob: _Problem, p, lower, upper, max_iter: int, ex, known=None):
    """Every parameter refitted together (after an effect is kept). A lens
    base's 80–92 parameters make this the loop's longest step: serial,
    full-model Jacobians at every step took ~35 min on a 2-core machine
    (``benchmarks/loop_suite.py`` case 0); here the Jacobian comes from
    the cheaper model on the executor's workers every
    :data:`calibration.fit.proxy.REFRESH` steps, as the fitter's, for
    :data:`POOLED_ITER_FACTOR` × ``max_iter`` iterations, each step still
    accepted on the full model. ``known``: the first Jacobian's leading
    columns, already in hand (:func:`_cheap_columns` at ``p``, or at the
    base's part of it); the rest are computed on the workers and the fit
    starts from them instead of a Jacobian of its own (only where the
    workers are)."""
    from calibration.fit.proxy import REFRESH

    pool = _bind_problem(prob, ex)
    if pool is None:
        return _fit(prob, p, lower, upper, np.ones(len(p), bool), max_iter=max_iter)
    with pool:
        jac0 = None
        if known is not None:
            rest = np.arange(known.shape[1], len(p))
            jac0 = np.hstack([known, _cheap_columns(prob, p, lower, upper, pool, rest)]) if rest.size else known
        return _fit(prob, p, lower, upper, np.ones(len(p), bool), max_iter=POOLED_ITER_FACTOR * max_iter,
                    pool=pool, refresh=REFRESH, jac0=jac0)


def _cheap_columns(prob: _Problem, p, lower, upper, pool, cols) -> np.ndarray:
    """(M, len(cols)) forward-difference columns ``cols`` of the scaled
    Jacobian of ``prob``'s residuals at ``p``, by the cheaper model on
    ``pool`` (:func:`_bind_problem`): the columns :func:`_fit`'s first
    Jacobian has there (its step, 0.5 of each parameter's scale, and its
    bounds)."""
    from calibration.fit.dls import forward_jacobian

    scale = prob_scale(prob)
    q = np.asarray(p, float) / scale
    cols = np.asarray(cols, int)

    def cheap(points):
        full = []
        for sub in points:
            x = q.copy()
            x[cols] = sub
            full.append(x * scale)
        return [np.asarray(v, float) for v in pool.map(functools.partial(_worker_residuals, "cheap"), full)]

    f0 = cheap([q[cols]])[0]
    return forward_jacobian(cheap, q[cols], f0, 0.5, (np.asarray(lower, float) / scale)[cols],
                            (np.asarray(upper, float) / scale)[cols])


def prob_scale(prob: _Problem) -> np.ndarray:
    s = [np.asarray(prob.base.scale, float)] + [np.asarray(e.scale, float) for e in prob.effects]
    return np.concatenate(s)


#: base-fit iterations after a base's own ``start()`` (:meth:`calibration.loop.base.LensBase.start`),
#: which already fits the loop's residuals (SFRA and the SFR bands; the fitter weighs each edge by
#: its measured σ, the loop by its σ law): with every perturbation of a lens free, one more
#: iteration costs as many predictions as the lens has perturbations
START_POLISH = 0

#: candidates a confirmation refits with the base (:func:`_confirm`), the best by held-out gain
CONFIRM_CANDIDATES = 2
#: serial-equivalent iterations of each confirmation refit (× :data:`POOLED_ITER_FACTOR` on workers)
CONFIRM_ITER = 3
#: the fall of χ² against the base refitted alone that confirms a candidate
CONFIRM_GAIN = 0.10
#: the χ² per term a confirmed candidate must leave: in-sample evidence is trusted only where the
#: effect explains the residual nearly to the noise. Where something outside the registry remains,
#: the base refitted with an effect mimics part of it: on the loop suite's case 24 (a bilateral
#: denoiser in e1's chain, χ² 40 per term) sharpening refitted with the base gains 51 %, where held
#: out it gained 11 %
CONFIRM_MAX_CHI2 = 3.0


def close_loop(base, obs, *, effects=None, folds: int = 3, min_gain: float = 0.15, stop_ratio: float = 1.2,
               max_effects: int = 3, base_iter: int = 12, seed: int = 0, fold=None,
               confirm: int = CONFIRM_CANDIDATES, confirm_gain: float = CONFIRM_GAIN,
               executor=None) -> LoopReport:
    """Fit ``base`` to ``obs`` and add effects while they explain held-out
    data (module docstring). ``effects``: registry names to try (default
    all). ``executor`` (an :class:`isp.runtime.executor.Executor`) runs the
    base's start fit and, where it shows progress, the loop's bar and step
    notes; default up to 2 worker processes with progress. ``confirm``,
    ``confirm_gain``: :func:`_confirm` (0 candidates: none)."""
    t0 = time.perf_counter()
    names = list(list_effects()) if effects is None else list(effects)
    ex = pool_executor(None, progress=True) if executor is None else executor
    say = print if ex.progress else (lambda *a, **k: None)
    bar = ex.bar(total=2 + len(names), desc="loop", unit="step")

    def tick(msg):
        bar.set_postfix_str(msg)
        bar.update(1)

    # 1. base fit, noise-free bias first at the start point; a base that can find its own basin
    # (a lens: calibration.fit.proxy's coarse stage and restarts) starts there
    nb = len(base.names)
    started = hasattr(base, "start")
    steps = {"base": 0.0, "noise": 0.0, "trials": 0.0, "refits": 0.0, "confirm": 0.0}

    def timed(step, t):
        steps[step] += time.perf_counter() - t
        return time.perf_counter()

    x_start = base.start(ex) if started else base.x0
    t = timed("base", t0)
    a0, c0, sd0 = base.measurement_bias(x_start)
    t = timed("noise", t)
    sigma = _sigma_law(obs, sd0)
    prob = _Problem(base, obs, a0, c0, sigma)
    # from a fitted start the base moves only to the loop's own weighting (its σ law), if at all
    n_iter = min(base_iter, START_POLISH) if started else base_iter
    p = x_start.copy()
    if n_iter > 0:
        p, _ = _fit(prob, x_start, np.asarray(base.lower, float), np.asarray(base.upper, float), np.ones(nb, bool),
                    max_iter=n_iter)
        a1, c1, sd1 = base.measurement_bias(p[:nb])          # bias at the fitted base
        prob.bias_a, prob.bias_bands = a1, band_means(obs.freq, c1)
        prob.sigma = sigma = _sigma_law(obs, sd1)
    t = timed("base", t)
    noise_floor = float(np.sqrt(np.mean(sigma[:, 0] ** 2)))
    tick("base fitted")
    pred0 = prob.predict(p)
    x_before = p.copy()
    before = prob.errors(pred0)
    dec_before = _decompose(obs, obs.sfra - pred0.sfra - prob.bias_a)
    tried, kept = [], []
    if fold is None:
        fold = _folds(obs, folds, seed)
    else:                       # the caller's split (e.g. by edge segment); K from its labels
        fold = np.unique(np.asarray(fold), return_inverse=True)[1]
        folds = int(fold.max()) + 1
    lower = np.asarray(base.lower, float)
    upper = np.asarray(base.upper, float)
    while len(kept) < max_effects:
        cur = prob.errors(prob.predict(p))
        if cur["chi2_per_obs"] <= stop_ratio ** 2:
            say(f"loop: residual χ² {cur['chi2_per_obs']:.2f} per term, within {stop_ratio}² of the noise: done")
            break
        best, round_ = None, []
        t = time.perf_counter()
        pool = _bind_problem(prob, ex, cheap=False)
        try:
            for name in names:
                if name in [e.name for e in prob.effects]:
                    continue
                e = create_effect(name)
                gain, cv_old, cv_new, xs, per_fold = _cv_gain(prob, p, e, fold, folds, pool)
                consistent = _consistent(per_fold, len(e.names))
                rec = {"effect": name, "round": len(kept) + 1, "heldout_chi2_before": cv_old,
                       "heldout_chi2_after": cv_new, "gain": gain, "values": dict(zip(e.names, map(float, xs))),
                       "fold_chi2": [[round(a, 2), round(b, 2)] for a, b, _ in per_fold], "consistent": consistent,
                       **confidence(per_fold)}
                tried.append(rec)
                if len(kept) == 0:
                    tick(f"{name}: gain {gain:.2f}{'' if consistent else ' (inconsistent across folds)'}")
                if not consistent:
                    continue
                if _visible(e, base):          # one these data cannot see is not confirmed
                    round_.append((rec, e, xs))
                if best is None or gain > best[0]:
                    best = (gain, e, xs)
        finally:
            if pool is not None:
                pool.close()
        t = timed("trials", t)
        if best is None or best[0] < min_gain:
            # an absorbed effect may gain nothing, or lose its penalty, with the base held: ranked all the same
            ranked = sorted(round_, key=lambda c: -c[0]["gain"])[:confirm]
            found = None
            if ranked and not getattr(base, "refit_in_cv", True):
                say(f"loop: no effect explains ≥ {min_gain:.0%} of the held-out residual with the base held; "
                    f"refitting the base with {', '.join(c[1].name for c in ranked)}")
                found, p, joint_gain = _confirm(prob, p, lower, upper, ranked, confirm_gain, ex)
                t = timed("confirm", t)
                for rec, c, _ in ranked:
                    say(f"loop: {c.name} refitted with the base: χ² {-rec['joint_gain']:+.1%} against the base "
                        f"alone, {rec['joint_chi2']:.2f} per term")
            if found is None:
                say("loop: nothing explains the residual; stopping")
                break
            e = found
            say(f"loop: adding {e.name} (χ² −{joint_gain:.0%} refitted with the base)")
            # the confirmation's refit was the first CONFIRM_ITER iterations of this one
            n_refit = max(base_iter - CONFIRM_ITER, 1)
        else:
            gain, e, xs = best
            say(f"loop: adding {e.name} (held-out χ² −{gain:.0%})")
            p = np.concatenate([p, xs])
            n_refit = base_iter
        prob.effects.append(e)
        kept.append(e.name)
        lower = np.concatenate([lower, e.lower])
        upper = np.concatenate([upper, e.upper])
        p, _ = _joint_fit(prob, p, lower, upper, n_refit, ex)
        timed("refits", t)
    if bar is not None:
        bar.close()
    pred1 = prob.predict(p)
    after = prob.errors(pred1)
    d_after = obs.sfra - pred1.sfra - prob.bias_a
    xb, xe = prob.split(p)
    values = {e.name: dict(zip(e.names, map(float, x))) for e, x in zip(prob.effects, xe)}
    unexplained = _unexplained(prob, pred1, obs, d_after, noise_floor, stop_ratio)
    asym = asymmetry_check(base, prob, p, stop_ratio)
    defocus = sensor_defocus_um(base, xb, zip(prob.effects, xe))
    surface = sensor_surface(base, xb, zip(prob.effects, xe))
    if asym is not None and not asym["explained"]:
        unexplained.append(
            f"LSF asymmetry the model does not make: χ² {asym['chi2_per_term']:.1f} per term (noise: 1); measured A "
            "RMS per band " + ", ".join(f"{v:.4f}" for v in asym["measured_rms_per_band"]) + ", model "
            + ", ".join(f"{v:.4f}" for v in asym["model_rms_per_band"]))
    return LoopReport(base.description, tuple(base.names), xb, kept, values, tried, before, after, noise_floor,
                      unexplained, dec_before, _decompose(obs, d_after), time.perf_counter() - t0,
                      np.asarray(obs.sfra), pred0.sfra + prob.bias_a, pred1.sfra + prob.bias_a, x_before,
                      asymmetry=asym, steps_s=steps, defocus_um=defocus, sensor_surface=surface)


def sensor_defocus_um(base, xb, effects) -> float | None:
    """The sensor's defocus on axis, µm (+: away from the lens): the lens
    base's (:meth:`calibration.loop.base.LensBase.defocus_um`) plus what the
    kept ``effects`` ((Effect, parameters) pairs) put at the image centre (a
    focus shift; a tilt or a curvature puts none there; a per-colour one
    its mean). None for a base without a lens."""
    if not hasattr(base, "defocus_um"):
        return None
    centre = dataclasses.replace(base.geometry, x_mm=np.zeros(1), y_mm=np.zeros(1), node_r=np.zeros(1))
    dz = base.defocus_um(xb)
    for e, x in effects:
        d = e.defocus_mm(x, centre)
        if d is not None:
            dz += 1e3 * float(np.mean(d))
    return float(dz)


#: where :func:`sensor_surface` samples the sensor: fractions of the frame's half width and height
SURFACE_GRID = (-0.8, -0.4, 0.0, 0.4, 0.8)


def surface_points(sensor) -> tuple[np.ndarray, float]:
    """(25, 2) image points, mm (+y down the array, as the traces' image
    plane, :func:`calibration.optics.psf.map.sensor_to_image`): the
    :data:`SURFACE_GRID` over the frame of ``sensor``; and the frame's
    half diagonal, mm (where :func:`fit_surface` puts the corner)."""
    half = 0.5e-3 * sensor.pixel_pitch_um * np.array([sensor.width_px, sensor.height_px], float)
    gx, gy = np.meshgrid(SURFACE_GRID, SURFACE_GRID)
    return np.stack([gx.ravel(), gy.ravel()], axis=1) * half, float(np.hypot(*half))


def fit_surface(points_mm, defocus_mm, half_diagonal_mm: float) -> dict:
    """The sensor's defocus over the frame as the registry's three optical
    effects describe it, by least squares: ``d(x, y) = d₀ + y·tan θx + x·tan
    θy + c·(r/r_corner)²`` (:class:`~calibration.loop.effects.FocusShift`,
    :class:`~calibration.loop.effects.SensorTilt`,
    :class:`~calibration.loop.effects.FieldCurvature`).

    Returns ``defocus_um`` (d₀), ``tilt_x_deg``, ``tilt_y_deg``,
    ``curvature_um`` (c, at the corner) and ``rms_left_um`` (what the
    three terms leave).

    >>> pts = np.array([(x, y) for x in (-1.0, 0.0, 1.0) for y in (-1.0, 0.0, 1.0)])
    >>> d = 0.002 + pts[:, 0] * np.tan(np.radians(0.1)) + 0.004 * (pts ** 2).sum(1) / 2.0
    >>> {k: round(v, 3) for k, v in fit_surface(pts, d, 2 ** 0.5).items()}
    {'defocus_um': 2.0, 'tilt_x_deg': 0.0, 'tilt_y_deg': 0.1, 'curvature_um': 4.0, 'rms_left_um': 0.0}
    """
    p = np.asarray(points_mm, float)
    d = 1e3 * np.asarray(defocus_mm, float)
    a = np.stack([np.ones(len(p)), p[:, 1], p[:, 0], (p ** 2).sum(axis=1) / half_diagonal_mm ** 2], axis=1)
    c, *_ = np.linalg.lstsq(a, d, rcond=None)
    return {"defocus_um": float(c[0]), "tilt_x_deg": float(np.degrees(np.arctan(1e-3 * c[1]))),
            "tilt_y_deg": float(np.degrees(np.arctan(1e-3 * c[2]))), "curvature_um": float(c[3]),
            "rms_left_um": float(np.sqrt(np.mean((d - a @ c) ** 2)))}


def sensor_surface(base, xb, effects) -> dict | None:
    """Where the sensor lies against the fitted lens's best focus over the
    frame (:func:`fit_surface` of the lens base's
    :meth:`~calibration.loop.base.LensBase.defocus_map_um` plus what the
    kept ``effects``, (Effect, parameters) pairs, put there), at
    :func:`surface_points`. A lens base can take up a tilted or curved
    sensor by tilting and bending its own image surface (the SFR sees only
    the difference, as it sees only the defocus of a shifted sensor): this
    is the module's tilt and curvature whichever of the two carries them.
    None for a base without a lens."""
    if not hasattr(base, "defocus_map_um"):
        return None
    pts, half = surface_points(base.obs.sensor)
    r = np.hypot(pts[:, 0], pts[:, 1]) / half
    geom = dataclasses.replace(base.geometry, x_mm=pts[:, 0], y_mm=pts[:, 1], node_r=r)
    d = 1e-3 * base.defocus_map_um(xb, pts)
    for e, x in effects:
        dz = e.defocus_mm(x, geom)
        if dz is not None:
            dz = np.asarray(dz, float)
            d = d + (dz.mean(axis=1) if dz.ndim == 2 else dz)
    return fit_surface(pts, d, half)


def surface_text(surface: dict) -> str:
    """One line for a :func:`fit_surface` result.

    >>> surface_text({"defocus_um": 2.0, "tilt_x_deg": 0.0, "tilt_y_deg": 0.1, "curvature_um": 4.0,
    ...               "rms_left_um": 0.5})
    'tilt 0.000° about x, 0.100° about y; curvature +4.0 µm at the corner (0.5 µm RMS beyond these)'
    """
    return (f"tilt {surface['tilt_x_deg']:.3f}° about x, {surface['tilt_y_deg']:.3f}° about y; curvature "
            f"{surface['curvature_um']:+.1f} µm at the corner ({surface['rms_left_um']:.1f} µm RMS beyond these)")


def _visible(e, base) -> bool:
    """Whether effect ``e`` acts on ``base``'s observations at all: a colour
    effect on green edges does not (its hooks return None)."""
    geom = getattr(base, "geometry", None)
    if geom is None:
        return True
    x = np.asarray(e.x0, float) + np.asarray(e.scale, float)
    return any(hook(x, geom) is not None for hook in (e.defocus_mm, e.shifts_px, e.transfer))


def _confirm(prob: _Problem, p, lower, upper, ranked, min_gain: float, ex) -> tuple:
    """A lens base fitted first may have absorbed an effect (a uniform blur
    such as crosstalk taken up by defocus and aberrations), so that the
    effect fitted with the base held explains little held-out data. Refit
    the base together with each of ``ranked`` (``(trial record, effect,
    held-out fit)``, best first) for :data:`CONFIRM_ITER` iterations, and
    the base alone for as many: a candidate whose joint χ² falls by at least
    ``min_gain`` below the base's own, to at most :data:`CONFIRM_MAX_CHI2`
    per term, is kept, the best of them.
    ``(effect, parameters, its gain)`` of that one, or ``(None, p, None)``
    with the base's own refit where it fits better. Each record gains
    ``joint_gain``, ``joint_chi2`` and ``joint_values``.

    Measured on the loop suite's case 6 (e9, 3.4 % crosstalk the base
    absorbed; held-out gains 5.9 % for motion blur, 5.2 % for crosstalk):
    refitted for six iterations, the base alone goes from χ² 1.443 to
    1.406 per term, with crosstalk to 1.201 (leak 0.030 for 0.034 put in),
    with motion blur to 1.217."""
    def chi2(problem, q):
        return float(np.mean(problem.residuals(problem.predict(q)) ** 2))

    # every refit starts at p: the columns of p's parameters in their first Jacobian are computed
    # once for all of them (each candidate's own columns on its refit's workers), not once per refit
    known = _base_columns(prob, p, lower, upper, ex)
    alone, _ = _joint_fit(prob, p, lower, upper, CONFIRM_ITER, ex, known=known)
    chi0, chi_p = chi2(prob, alone), chi2(prob, p)
    if chi0 > chi_p:
        alone, chi0 = p, chi_p
    best = None
    for rec, e, xs in ranked:
        trial = copy.copy(prob)
        trial.effects = prob.effects + [e]
        q, _ = _joint_fit(trial, np.concatenate([p, xs]), np.concatenate([lower, e.lower]),
                          np.concatenate([upper, e.upper]), CONFIRM_ITER, ex, known=known)
        chi = chi2(trial, q)
        rec["joint_gain"], rec["joint_chi2"] = 1.0 - chi / chi0, chi
        rec["joint_values"] = dict(zip(e.names, map(float, q[len(p):])))
        if rec["joint_gain"] >= min_gain and chi <= CONFIRM_MAX_CHI2 and (best is None or rec["joint_gain"] > best[0]):
            best = (rec["joint_gain"], e, q)
    return (None, alone, None) if best is None else (best[1], best[2], best[0])


def _base_columns(prob: _Problem, p, lower, upper, ex) -> np.ndarray | None:
    """The first Jacobian of ``prob`` at ``p``, every column (the base's and
    any kept effect's; :func:`_cheap_columns` on workers bound to it); None
    where :func:`_bind_problem` binds none."""
    pool = _bind_problem(prob, ex)
    if pool is None:
        return None
    with pool:
        return _cheap_columns(prob, p, lower, upper, pool, np.arange(len(p)))


def effect_terms(base, effects) -> tuple:
    """(defocus_mm, shifts_px, transfer) of ``effects`` ((Effect,
    parameters) pairs): defocus and shifts add (a node's defocus, (K,),
    to each of its colours' where another effect's is per colour, (K, C)),
    transfer functions multiply; None where no effect has the term."""
    g = base.geometry
    dz = shifts = transfer = None
    for e, x in effects:
        d = e.defocus_mm(x, g)
        if d is not None:
            d = np.asarray(d, float)
            if dz is not None and dz.ndim != d.ndim:
                dz, d = (dz[:, None], d) if dz.ndim == 1 else (dz, d[:, None])
            dz = d if dz is None else dz + d
        s = e.shifts_px(x, g)
        if s is not None:
            shifts = s if shifts is None else shifts + s
        t = e.transfer(x, g)
        if t is not None:
            transfer = t if transfer is None else transfer * t
    return dz, shifts, transfer


def predict_with_effects(base, xb, effects):
    """The base model's prediction at parameters ``xb`` with ``effects``
    ((Effect, parameters) pairs) applied (:func:`effect_terms`)."""
    dz, shifts, transfer = effect_terms(base, effects)
    return base.predict(np.asarray(xb, float), defocus_mm=dz, shifts_px=shifts, transfer=transfer)


def asymmetry_check(base, prob, p, ratio: float) -> dict | None:
    """The final model against the measured LSF asymmetry
    (:mod:`calibration.sfr.asymmetry`), which the loop does not fit: χ² per
    term of ``(A_measured − A_model − bias) / σ``, σ the measurement's in
    quadrature with the model's own (:func:`calibration.sfr.asymmetry.odd_sigma`). The model's A has its defocus
    effects; a transfer effect (crosstalk, sharpening, glare: real and
    even) scales A by its band mean; with lateral shifts in the model the
    mixed-colour ("L") observations, whose A the shifts change, are left
    out. None when the observations have no asymmetry (or none is left).
    A χ² above ``ratio²`` means the edges are asymmetric in a way the model
    cannot make (coma of a decentred lens the base lacks, asymmetric
    processing)."""
    from calibration.sfr.asymmetry import BANDS as ODD_BANDS
    from calibration.sfr.asymmetry import odd_sigma

    obs = prob.obs
    if obs.odd is None:
        return None
    xb, xe = prob.split(p)
    dz, shifts, transfer = effect_terms(base, zip(prob.effects, xe))
    keep = np.ones(len(obs), bool) if shifts is None else np.asarray(obs.channel) != "L"
    if not keep.any():
        return None
    a = np.asarray(base.odd(xb, dz), float)
    if transfer is not None:
        a *= band_means(obs.freq, transfer, ODD_BANDS)
    r = (np.asarray(obs.odd) - a - np.asarray(base.odd_bias)) / odd_sigma(obs.odd_std)
    r = np.where(np.isfinite(r), r, 0.0)[keep]
    a = a[keep]
    chi2 = float(np.mean(r ** 2))
    return {"chi2_per_term": chi2, "explained": chi2 <= ratio ** 2, "observations": int(keep.sum()),
            "measured_rms_per_band": [float(v) for v in np.sqrt(np.nanmean(np.asarray(obs.odd)[keep] ** 2, axis=0))],
            "model_rms_per_band": [float(v) for v in np.sqrt(np.mean(a ** 2, axis=0))],
            "normalised_residual_rms_per_band": [float(v) for v in np.sqrt(np.mean(r ** 2, axis=0))]}


def _sigma_law(obs, sd) -> np.ndarray:
    """σ_ij = k_j·noise_i/step_i for each column j of the re-rendered
    spreads ``sd`` (N, 1 + K: SFRA, then the SFR bands), in quadrature
    with the model floor. k_j is fitted in variance, k² = Σx²s²/Σx⁴: a
    spread from a few renders is unbiased as a variance, not as a
    standard deviation (from two antithetic pairs its square root reads
    ≈ 0.9 of σ).

    >>> obs = type("O", (), {"noise": np.full(4, 0.01), "step": np.full(4, 0.5)})()
    >>> s = _sigma_law(obs, np.array([[0.004, 0.008]] * 4))
    >>> bool(np.allclose(s, np.sqrt(np.array([0.004, 0.008]) ** 2 + MODEL_FLOOR ** 2)))
    True
    """
    x = np.asarray(obs.noise, float) / np.maximum(np.asarray(obs.step, float), 1e-6)
    sd = np.asarray(sd, float).reshape(len(x), -1)
    out = np.empty_like(sd)
    for j in range(sd.shape[1]):
        s = sd[:, j]
        ok = np.isfinite(s) & (s > 0) & (x > 0)
        k = float(np.sqrt(np.sum(x[ok] ** 2 * s[ok] ** 2) / np.sum(x[ok] ** 4))) if ok.sum() >= 3 else 0.0
        out[:, j] = np.sqrt((k * x) ** 2 + MODEL_FLOOR ** 2)
    return out


def _cv_gain(prob: _Problem, p, e, fold, k, pool=None):
    """Held-out χ² without and with effect ``e`` (its parameters fitted on
    the other folds, the rest held). ``pool`` (:func:`_bind_problem` of
    ``prob``): the folds' fits on its workers."""
    g_old = g_new = 0.0
    xs_all, per_fold = [], []
    trial = copy.copy(prob)
    trial.effects = prob.effects + [e]
    q0 = np.concatenate([p, e.x0])
    free = np.zeros(len(q0), bool)
    free[len(p):] = True
    nb = len(prob.base.names)
    if getattr(prob.base, "refit_in_cv", False):
        free[:nb] = True          # a cheap base re-balances with the new effect (e.g. blur vs sharpening)
    lo = np.concatenate([np.asarray(prob.base.lower, float), np.full(len(p) - nb, -np.inf), e.lower])
    hi = np.concatenate([np.asarray(prob.base.upper, float), np.full(len(p) - nb, np.inf), e.upper])
    pred_old = prob.predict(p)
    r_old = prob.residuals(pred_old).reshape(len(prob.obs), -1)
    starts = [q0] + [np.concatenate([p, np.asarray(x, float)]) for x in getattr(e, "starts", ())]
    tasks = [(e, s, lo, hi, free, fold != j) for j in range(k) for s in starts]
    fitted = pool.map(_cv_fit_task, tasks) if pool is not None else [_cv_fit(trial, *t) for t in tasks]
    for j in range(k):
        q = min(fitted[j * len(starts):(j + 1) * len(starts)], key=lambda f: f[1])[0]
        train = fold != j
        r_new = trial.residuals(trial.predict(q)).reshape(len(prob.obs), -1)
        old_j = float(np.sum(r_old[~train] ** 2))
        new_j = float(np.sum(r_new[~train] ** 2)) + 2.0 * len(e.names)
        per_fold.append((old_j, new_j, int(r_old[~train].size)))
        g_old += old_j
        g_new += new_j
        xs_all.append(q[len(p):])
    gain = 1.0 - g_new / g_old if g_old > 0 else 0.0
    return gain, g_old, g_new, np.median(np.array(xs_all), axis=0), per_fold


def _cv_fit(trial: _Problem, e, start, lo, hi, free, train) -> tuple[np.ndarray, float]:
    """One fold's fit of a candidate effect (``trial``'s last) from
    ``start`` on the ``train`` observations: its parameters and its
    training χ²."""
    q, _ = _fit(trial, start, lo, hi, free, mask=train, max_iter=6)
    return q, float(np.sum(trial.residuals(trial.predict(q), train) ** 2))


def _cv_fit_task(task) -> tuple[np.ndarray, float]:
    prob = worker_payload()["full"]
    e = task[0]
    trial = copy.copy(prob)
    trial.effects = prob.effects + [e]
    return _cv_fit(trial, *task)


def confidence(per_fold) -> dict:
    """How surely a tried effect is there, from its held-out folds
    ``(χ² without, χ² with (penalty included), n terms)``: ``z``, the fall
    of the held-out χ² over √(2 Σn), the χ²'s own noise; ``folds_improved``.

    >>> confidence([(1200.0, 1000.0, 5000), (900.0, 880.0, 5000)])
    {'z': 1.56, 'folds_improved': 2, 'folds': 2}
    """
    old = sum(f[0] for f in per_fold)
    new = sum(f[1] for f in per_fold)
    n = sum(f[2] for f in per_fold)
    return {"z": round(float((old - new) / np.sqrt(2.0 * n)), 2) if n else 0.0,
            "folds_improved": int(sum(f[1] < f[0] for f in per_fold)), "folds": len(per_fold)}


def _consistent(per_fold, n_params: int) -> bool:
    """No held-out fold worse by more than the AIC penalty plus 3σ of its
    χ² (σ = √(2n), n its residual terms): see the module docstring."""
    return all(new - old <= 2.0 * n_params + 3.0 * np.sqrt(2.0 * n) for old, new, n in per_fold)


def _unexplained(prob, pred, obs, d, floor, ratio) -> list:
    """Structure of the final residual that exceeds the floor."""
    out = []
    rms = float(np.sqrt(np.mean(d ** 2)))
    chi2 = float(np.mean(prob.residuals(pred) ** 2))
    if chi2 > ratio ** 2:
        out.append(f"unexplained residual: χ² {chi2:.1f} per term (noise: 1); SFRA residual {rms:.4f} cycles/pixel, "
                   f"noise floor {floor:.4f}")
        r = prob.residuals(pred).reshape(len(obs), -1)
        band = np.sqrt(np.mean(r[:, 1:] ** 2, axis=0))
        out.append("RMS normalised residual per band " + ", ".join(
            f"{lo:g}–{hi:g} cy/px: {b:.1f}" for (lo, hi), b in zip(BANDS, band)))
        dec = _decompose(obs, d)
        rings = {k: v for k, v in dec["ring"].items() if v is not None and abs(v) > 2 * floor}
        if rings:
            out.append(f"field rings with a mean residual beyond 2× the floor: {rings}")
        big = np.argsort(-np.abs(d))[:5]
        out.append("largest residuals at (x, y) px: " + ", ".join(
            f"({obs.x_px[i]:.0f}, {obs.y_px[i]:.0f}) {d[i]:+.4f}" for i in big))
    return out


def write_report(report: LoopReport, obs, directory) -> dict:
    """``report.json``, ``report.md`` and ``residual_maps.png`` in ``directory``."""
    from isp.io.files import write_bytes_atomic

    from calibration.report import write_json

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    paths = {"json": write_json(d / "report.json", report.to_dict())}
    lines = ["# Loop closure report", "", f"Base model: {report.base}", "",
             f"Noise floor (SFRA RMS from the data): {report.noise_floor:.4f} cycles/pixel", ""]
    if report.defocus_um is not None:
        lines += [f"Sensor defocus on axis: {report.defocus_um:+.1f} µm (+: beyond the lens's best focus, "
                  "against the design's own focus)", ""]
    if report.sensor_surface is not None:
        lines += [f"Sensor against the lens's best focus over the frame: {surface_text(report.sensor_surface)} "
                  "(a tilt or curvature of the lens's image surface and of the sensor look the same to the SFR)",
                  ""]
    lines += ["| metric | before | after |", "|---|---|---|"]
    for k, v in report.error_before.items():
        after = report.error_after.get(k, float("nan"))
        if isinstance(v, list):          # one value per SFR band
            lines.append(f"| {k} | {', '.join(f'{x:.3g}' for x in v)} | {', '.join(f'{x:.3g}' for x in after)} |")
        else:
            lines.append(f"| {k} | {v:.5g} | {after:.5g} |")
    lines += ["", "## Effects tried", "",
              "| round | effect | held-out χ² before | after | gain | z | folds improved | consistent across folds "
              "| χ² gain refitted with the base |", "|---|---|---|---|---|---|---|---|---|"]
    for t in report.tried:
        lines.append(f"| {t['round']} | {t['effect']} | {t['heldout_chi2_before']:.1f} | "
                     f"{t['heldout_chi2_after']:.1f} | {t['gain']:+.2f} | {t['z']:+.1f} | "
                     f"{t['folds_improved']}/{t['folds']} | "
                     f"{'yes' if t.get('consistent', True) else 'no'} | "
                     + (f"{t['joint_gain']:+.2f} |" if "joint_gain" in t else "– |"))
    lines += ["", "## Effects kept", ""]
    lines += [f"- **{n}**: " + ", ".join(f"{k} = {v:.4g}" for k, v in report.effect_values[n].items())
              for n in report.effects_added] or ["- none"]
    if report.asymmetry is not None:
        a = report.asymmetry
        lines += ["", "## LSF asymmetry (not fitted; checked against the final model)", "",
                  f"χ² {a['chi2_per_term']:.2f} per term: "
                  + ("within the noise." if a["explained"] else "**beyond the noise**.") + " Measured A RMS per band "
                  + ", ".join(f"{v:.4f}" for v in a["measured_rms_per_band"]) + "; model "
                  + ", ".join(f"{v:.4f}" for v in a["model_rms_per_band"]) + "."]
    lines += ["", "## Left unexplained", ""] + ([f"- {u}" for u in report.unexplained] or
                                                 ["- nothing beyond the noise floor"])
    paths["md"] = write_bytes_atomic(d / "report.md", "\n".join(lines).encode())
    try:
        paths["plot"] = _plot(report, obs, d / "residual_maps.png")
    except Exception as e:       # a plot must not lose the report
        print(f"loop: residual plot skipped ({e})")
    return paths


def _plot(report, obs, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from calibration.report import save_figure

    before = obs.region_map(report.sfra_measured - report.sfra_before)
    after = obs.region_map(report.sfra_measured - report.sfra_after)
    lim = np.nanmax(np.abs(before)) if np.isfinite(before).any() else 1.0
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, m, t in zip(axes, (before, after), ("residual before", "residual after")):
        im = ax.imshow(m, cmap="coolwarm", vmin=-lim, vmax=lim)
        ax.set_title(f"{t} (SFRA, cy/px)")
    fig.colorbar(im, ax=axes, shrink=0.8)
    save_figure(fig, path)
    return path


def model_sfr(base, xb, effects: dict) -> np.ndarray:
    """(N, F) noise-free SFR of ``base`` at ``xb`` with ``effects``
    ({name: {parameter: value}}), as the loop combines them."""
    pairs = []
    for name, vals in effects.items():
        e = create_effect(name)
        pairs.append((e, np.array([vals[n] for n in e.names], float)))
    return predict_with_effects(base, xb, pairs).sfr


def plot_sfr_curves(obs, sfr_before, sfr_after, path, title: str = "") -> Path:
    """Measured SFR (mean over observations per channel, with its spread)
    against the model before and after the loop, saved at ``path``.

    Parameters
    ----------
    obs : Observations
    sfr_before, sfr_after : (N, F) ndarray
        Modelled SFR per observation on ``obs.freq`` (:func:`model_sfr`);
        ``sfr_before`` may be None.
    path : str or Path
        The figure (PNG by default; :func:`calibration.report.save_figure`).
    title : str
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from calibration.report import save_figure

    f = np.asarray(obs.freq)
    m = f <= 0.75
    fig, ax = plt.subplots(figsize=(6.0, 3.8))
    colours = {"R": "tab:red", "G": "tab:green", "B": "tab:blue", "L": "black"}
    ch = np.asarray(obs.channel)
    for c in sorted(set(ch.tolist())):
        sel = ch == c
        meas = np.asarray(obs.sfr)[sel][:, m]
        mu = np.nanmean(meas, axis=0)
        col = colours.get(c, "black")
        ax.fill_between(f[m], np.nanmin(meas, axis=0), np.nanmax(meas, axis=0), color=col, alpha=0.15, lw=0)
        ax.plot(f[m], mu, color=col, lw=1.6, label=f"measured {c}" + (f" ({sel.sum()})" if sel.sum() > 1 else ""))
        if sfr_before is not None:
            ax.plot(f[m], np.mean(sfr_before[sel][:, m], axis=0), color=col, lw=1.0, ls=":")
        ax.plot(f[m], np.mean(sfr_after[sel][:, m], axis=0), color=col, lw=1.0, ls="--")
    ax.plot([], [], color="gray", ls=":", label="base model (before)")
    ax.plot([], [], color="gray", ls="--", label="with effects (after)")
    ax.axvline(0.5, color="gray", lw=0.5)
    ax.set(xlabel="cycles / pixel", ylabel="SFR", xlim=(0, f[m][-1]), title=title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper right")
    save_figure(fig, path)
    return Path(path)


def summary(rep: LoopReport) -> str:
    """A few lines of text on a loop's report: effects added with values,
    error before/after, noise floor, what is left (an anisotropy between
    vertical and horizontal edges beyond twice the floor included)."""
    lines = []
    if rep.effects_added:
        for n in rep.effects_added:
            v = ", ".join(f"{k} = {x:.4g}" for k, x in rep.effect_values[n].items())
            lines.append(f"added {n}: {v}")
    else:
        lines.append("no effect added")
    b, a = rep.error_before, rep.error_after
    lines.append(f"SFRA RMS error {b['sfra_rms']:.4f} -> {a['sfra_rms']:.4f} cy/px "
                 f"(noise floor {rep.noise_floor:.4f}); SFR MSE {b['sfr_mse']:.3g} -> {a['sfr_mse']:.3g}; "
                 f"chi2/term {b['chi2_per_obs']:.2f} -> {a['chi2_per_obs']:.2f}")
    base = ", ".join(f"{k} = {float(v):.4g}" for k, v in zip(rep.base_names, rep.base_x))
    lines.append(f"base: {base}")
    if rep.defocus_um is not None:
        lines.append(f"sensor defocus on axis: {rep.defocus_um:+.1f} µm (+: beyond the lens's best focus)")
    if rep.sensor_surface is not None:
        lines.append(f"sensor against the lens's best focus: {surface_text(rep.sensor_surface)}")
    lines += [f"left: {u}" for u in rep.unexplained[:1]]
    d = rep.decomposition_after.get("direction", {})   # measured − final model, by edge direction
    if len(d) == 2 and abs(d["vertical"] - d["horizontal"]) > 2 * rep.noise_floor:
        lines.append(f"left: vertical and horizontal edges differ: mean SFRA residual {d['vertical']:+.4f} "
                     f"(vertical) vs {d['horizontal']:+.4f} (horizontal) cy/px — an anisotropy no "
                     "effect tried models")
    return "\n".join(lines)

"""Proxy cameras: perturbed lenses fitted to measured slanted-edge SFR
(paper §3.2, Algorithm 1).

``fit_proxy(nominal, observations, ProxyFitSettings(...))`` finds the perturbation of the nominal
lens whose simulated SFRA matches the measured SFRA over the field:
residuals ``f_i = (SFRA*_i − SFRA_i(P) − b_i) / σ_i`` per observation (an
edge at a field position, orientation and colour channel), where
``SFRA_i(P)`` is the noise-free prediction of :class:`calibration.fit.forward_model.SfrModel`,
``b_i`` the rise of SFRA that the observation's own noise causes (eq. 14
simulates the noise; computed once at the nominal lens) and ``σ_i`` the
measurement's uncertainty. The solver is :func:`calibration.fit.dls.damped_least_squares`
(the paper's DLS with per-parameter dynamic damping); ``method="scipy"``
runs ``scipy.optimize.least_squares`` (trust-region reflective) on the same
residuals as a baseline.

Parameters are the perturbation names of :mod:`calibration.optics.perturb`,
scaled by their tolerances: the fit works in tolerance units, bounded to
±``bound_factor`` tolerances. Focus (the last air gap) is fitted too, within
±:data:`FOCUS_BOUND`: a real device's focus is set at assembly, to its own
best focus, and unknown to the model.

The Jacobian's columns are independent lens evaluations and run on an
executor (:mod:`isp.runtime.executor`; default 2 worker processes). By default (``n_params``) the fit
keeps the :data:`N_PARAMS` parameters to which its residuals are most
sensitive (:func:`screen_parameters`); screening and fit share the pool,
and the screening's secants are the fit's first Jacobian, which Broyden
updates refine between finite-difference ones (:data:`REFRESH`). Beyond
SFRA, the residuals can carry the SFR's band means and the LSF's
asymmetry (``residuals``; "auto" takes all three where measured).

From the nominal lens, a local optimiser (DLS or TRF alike) settles on
about a third of perturbed phone lenses in a minimum far above the noise
floor. A fit that ends above :data:`RESTART_CHI2` χ² per residual
therefore tries :data:`RESTARTS` other starts within the tolerance box and
keeps the best (:func:`restart`).

On many regions (the paper's 15 × 20) the screening, the fit and any
restarts run first on a :data:`COARSE_GRID` sub-grid of them, and all the
observations refine that fit (``coarse``): the basin shows on 35 regions
at a tenth of the cost of 300 (an evaluation of e9: 0.17 against 1.74 s
CPU, ``benchmarks/lens_eval.py``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import NamedTuple
from pathlib import Path

import numpy as np

from isp.errors import ConfigError
from isp.runtime.executor import Executor, pool_executor, worker_payload

from calibration.fit.dls import DLSSettings, DlsResult, damped_least_squares
from calibration.optics.lens import Lens
from calibration.optics.perturb import PARAMETER_KINDS, TOLERANCED_KINDS, ParameterSpace, Perturbation, PerturbedLens, apply
from calibration.fit.observations import Observations

#: the focus parameter's tolerance (mm): its unit in a fit (assembly sets focus within a few µm
#: of a device's best focus, but that focus is not the nominal lens's)
FOCUS_TOLERANCE_MM = 0.010

#: the focus parameter's bound, tolerances (±80 µm; the others keep ``bound_factor``): a device's
#: best focus moves with its tolerance stack. Devices drawn within tolerance and refocused
#: (``isp calib simulate --perturb random``, seeds 0–199, 2000 × 1500) moved by up to 50, 47, 56 and
#: 30 µm on e1, e2, e9 and e11 (95th percentile 38, 27, 35 and 23 µm); 29, 19, 24 and 10 % of them
#: beyond ±20 µm, out of reach of a bound of two tolerances (the other parameters'). A module whose focus
#: is beyond ±80 µm is a defocused one (the loop's ``focus_shift`` effect)
FOCUS_BOUND = 8.0

#: DLS finite-difference step (tolerance units): forward differences are
#: biased by O(h); on e9 h = 0.1 stalled the fit where 0.03 did not, and the
#: model is smooth well below that (central differences at 0.0125-tolerance
#: steps matched the linear model to ρ = 1.000)
DLS_STEP = 0.03
#: parameters fitted by default (screened)
N_PARAMS = 24   # 16 leave the pixel-level fit ahead on e9; 24 put ours ahead of it on every lens
#: finite-difference Jacobians every this many accepted steps (Broyden updates between), and
#: iterations at most. Measured on e9, 15 × 20 regions, 600 observations, 16 parameters, SFRA +
#: asymmetry, --fast-jacobian, on one 2-core machine (``benchmarks/proxy.py``): a Jacobian every
#: step, 10 iterations, screened apart: 89.5 s + 38.6 s screening, merit 71.5 k, SFR MSE ×10⁻³
#: 0.23 / 0.74 / 1.60 at FoV 0.1 / 0.5 / 0.9; every 3rd step, 20 iterations, screening inside
#: (its secants the first Jacobian): 91.7 s in all, merit 73.6 k, 0.22 / 0.75 / 1.55; and with
#: 24 parameters and the shape residuals 108.8 s in all, 0.14 / 0.33 / 0.71
REFRESH = 3
MAX_ITER = 20

#: restarts of a fit (DLS or TRF) that ends far above the noise floor (merit per residual above
#: RESTART_CHI2; at the floor it is about 1): that many Latin-hypercube starts within ±1
#: tolerance, each PROBE_ITER iterations, the best continued for the rest of the budget
#: (:func:`restart`). Measured on benchmarks/proxy.py's 24 devices (docs/results/proxy.md).
RESTARTS = 4
RESTART_CHI2 = 4.0
PROBE_ITER = 5
#: the best probe is continued when its merit is below this many times the first fit's: after
#: PROBE_ITER iterations a probe is still falling, where the first fit had the whole budget
CONTINUE_WITHIN = 1.5

#: coarse-to-fine: where a sub-grid of this many regions (rows, cols), spread over the whole field,
#: at least halves the observations, the fit, its screening and any restarts run first on its
#: observations (:func:`coarse_subset`), and all of them refine that fit. Why: a lens evaluation costs about
#: in proportion to the observations (e9: 1.74 s CPU for 600, 0.17 s for the 70 of the sub-grid,
#: ``benchmarks/lens_eval.py``), and which basin a fit ends in shows on a 5 × 7 sub-grid already
#: (docs/results/proxy.md).
COARSE_GRID = (5, 7)

#: what :func:`fit_proxy` can fit to
RESIDUALS = ("sfra", "bands", "odd", "shape")

#: the kinds of perturbation a fit screens by default (:func:`default_names`)
FIT_KINDS = ("decenter", "tilt", "thickness", "focus")
#: every kind a fit can be given (:attr:`ProxyFitSettings.kinds`): a lens's own
#: (:data:`calibration.optics.perturb.PARAMETER_KINDS`) and the focus (the last air gap)
KINDS = (*PARAMETER_KINDS, "focus")
#: every kind a module's tolerances perturb, and focus: ``isp calib fit --kinds all``, the loop's base
ALL_KINDS = (*TOLERANCED_KINDS, "focus")


def default_names(lens: Lens, kinds=FIT_KINDS) -> list[str]:
    """The fitted parameters of ``kinds``: by default each element's decenter
    (x, y) and tilt (about x and y), the air gaps, and focus — the
    perturbations that break the field symmetry or move focus, to which SFRA
    over the field is most sensitive; curvatures, conics and materials
    (``"curvature"``, ``"conic"``, ``"nd"``, ...: :data:`KINDS`) where asked."""
    space = ParameterSpace.default(lens, kinds=[k for k in kinds if k != "focus"])
    names = list(space.names)
    if "focus" in kinds:
        names.append(focus_name(lens))
    return names


def screen_parameters(model, names, n_keep: int, *, bias=None, fun_many=None, h: float = 0.5,
                      return_jacobian: bool = False):
    """The ``n_keep`` parameters to which the fit's residuals (``bias``'s
    kind: SFRA, or with the bands or the asymmetry) are most sensitive
    (norm of the Jacobian column in tolerance units, one forward
    difference of ``h`` tolerances each, at the nominal lens); focus is
    always kept. With more parameters than the data constrain (e9 has 48
    decenters, tilts and gaps), DLS wanders along weak directions; the most
    sensitive ones make an equivalent proxy (paper §3.2 perturbs a chosen
    subset too).

    ``return_jacobian``: also return the kept columns, ``(M, n_kept)``
    residual change per tolerance, in the order of the returned names: a
    secant Jacobian at the nominal lens that :func:`fit_proxy` starts from
    instead of computing a first finite-difference one."""
    names = list(names)
    space = parameter_space(model.nominal, names)
    pts = [np.zeros(len(names))] + [np.eye(len(names))[j] * h for j in range(len(names))]
    b = np.zeros(len(model.obs)) if bias is None else bias
    if fun_many is None:
        rs = [_residuals(model, space, b, u) for u in pts]
    else:
        rs = fun_many(pts)
    sens = np.array([np.linalg.norm(r - rs[0]) for r in rs[1:]])
    fname = focus_name(model.nominal)
    order = [names[j] for j in np.argsort(-sens) if names[j] != fname]
    keep = order[: max(0, n_keep - (fname in names))]
    kept = [n for n in names if n in keep or n == fname]
    if not return_jacobian:
        return kept
    cols = [(np.asarray(rs[1 + names.index(n)]) - rs[0]) / h for n in kept]
    return kept, np.stack(cols, axis=1)


def focus_name(lens: Lens) -> str:
    """Name of the last gap (lens to image plane)."""
    return f"s{len(lens.surfaces)}.thickness"


def parameter_bounds(names, focus: str, bound_factor: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """``(lower, upper)`` of a fit's parameters ``names`` (tolerances):
    ±``bound_factor``, the ``focus`` parameter ±:data:`FOCUS_BOUND` (or
    ``bound_factor`` if wider).

    >>> parameter_bounds(["e1.decenter_x", "s9.thickness"], "s9.thickness")[1].tolist()
    [2.0, 8.0]
    """
    b = np.array([max(bound_factor, FOCUS_BOUND) if n == focus else bound_factor for n in names], float)
    return -b, b


def parameter_space(lens: Lens, names) -> ParameterSpace:
    """The space of ``names`` with the default tolerances (focus: ±10 µm)."""
    names = list(names)
    fname = focus_name(lens)
    overrides = {fname: FOCUS_TOLERANCE_MM} if fname in names else None
    return ParameterSpace.default(lens, names, overrides=overrides)


class FittedLens:
    """The fitted lens of a fit holding ``nominal``, ``space`` and ``u``
    (parameters in tolerance units): shared by every proxy fitter."""

    @property
    def perturbation(self) -> Perturbation:
        return self.space.to_perturbation(self.u * self.space.tolerance)

    @property
    def lens(self) -> PerturbedLens:
        return apply(self.nominal, self.perturbation)


@dataclass
class ProxyFit(FittedLens):
    """A fitted proxy camera and how it was fitted."""

    nominal: Lens
    space: ParameterSpace
    u: np.ndarray                       # parameters in tolerance units
    result: DlsResult | None
    observations: Observations
    predicted_before: np.ndarray        # SFRA (with noise bias) of the nominal lens
    predicted_after: np.ndarray         # SFRA (with noise bias) of the proxy
    noise_bias: np.ndarray
    method: str = "dls"
    evaluations: int = 0
    seconds: float = 0.0
    settings: dict = field(default_factory=dict)
    #: the least share of an observation's light inside the model's PSF window, fitted lens
    #: (:meth:`calibration.fit.forward_model.SfrModel.window_energy`); well below 1, the window is too small
    window_energy: float = 1.0
    #: the restarts tried (:func:`restart`): start, probe merit; for the continued one its final merit
    #: and whether it was kept
    restarts: list = field(default_factory=list)
    #: the coarse stage of a coarse-to-fine fit (``ProxyFitSettings.coarse``): its observations,
    #: evaluations, seconds, merit and residual count; empty where the fit ran on all from the start
    coarse: dict = field(default_factory=dict)

    @property
    def std(self) -> np.ndarray:
        """1-σ uncertainty of each parameter, physical units."""
        if self.result is None:
            return np.full(len(self.u), np.nan)
        return self.result.std * self.space.tolerance

    def errors(self) -> dict:
        """SFRA RMS error (cy/px), χ² per observation and the median |residual|
        in σ (0.67 at the noise floor of Gaussian noise; a handful of failed
        edges, which can dominate χ², move it little) of the nominal and
        fitted models."""
        obs = self.observations
        out = {}
        for label, pred in (("before", self.predicted_before), ("after", self.predicted_after)):
            d = obs.sfra - pred
            out[label] = {"sfra_rms": float(np.sqrt(np.mean(d ** 2))),
                          "chi2_per_obs": float(np.mean((d / obs.sfra_std) ** 2)),
                          "median_abs_z": float(np.median(np.abs(d) / obs.sfra_std))}
        return out

    def to_dict(self) -> dict:
        tol = self.space.tolerance
        return {
            "method": self.method,
            "parameters": [{"name": n, "value": float(v), "std": float(s), "tolerance": float(t)}
                           for n, v, s, t in zip(self.space.names, self.u * tol, self.std, tol)],
            "errors": self.errors(),
            "evaluations": self.evaluations,
            "seconds": round(self.seconds, 2),
            "stop_reason": self.result.reason if self.result is not None else "",
            "merit_history": [h["merit"] for h in (self.result.history if self.result else [])],
            "observations": len(self.observations),
            "settings": self.settings,
            "window_energy_min": round(self.window_energy, 4),
            "restarts": self.restarts,
            "coarse": self.coarse,
        }

    def save(self, directory) -> dict:
        """Write ``proxy.json`` (lens/v1: nominal + fitted perturbation),
        ``fit.json`` and the plots into ``directory``; returns the paths."""
        from calibration.report import write_json

        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        paths = {"proxy": save_proxy(d / "proxy.json", self.nominal, self.perturbation),
                 "fit": write_json(d / "fit.json", self.to_dict())}
        paths.update(plot_fit(self, d))
        return paths


# -- evaluation (picklable: one model per worker process) -----------------------------
def residual_task(u: np.ndarray) -> np.ndarray:
    """The residuals at parameters ``u``, in a worker whose payload
    :func:`worker_models` set up: one column of a parallel Jacobian."""
    w = worker_payload()        # worker_models, built once per worker
    return _residuals(w["model"], w["space"], w["bias"], u)


def _cheap_residual_task(u: np.ndarray) -> np.ndarray:
    w = worker_payload()
    return _residuals(w["cheap"], w["space"], w["bias"], u)


class ResidualBias(NamedTuple):
    """What the measurement adds to the model's noise-free prediction, in
    the parts a kind of residuals uses: SFRA bias (N,); for band residuals
    the band bias (N, 4) and the measured band means (N, 4); for asymmetry
    residuals the asymmetry-band bias (N, K); ``noise`` (N, 1 + 4), the
    spread of one noisy measurement's SFRA and band means from the same
    renders (:class:`calibration.fit.forward_model.MeasurementBias`), whose
    ratios weigh the bands (:func:`band_noise`)."""

    sfra: np.ndarray
    bands: np.ndarray | None = None
    measured_bands: np.ndarray | None = None
    odd: np.ndarray | None = None
    noise: np.ndarray | None = None


def _residuals(model, space: ParameterSpace, bias, u: np.ndarray) -> np.ndarray:
    """Residuals over their σ, (N, parts) flattened: SFRA; with band parts
    in ``bias`` (a :class:`ResidualBias`), the mean SFR in four bands, each
    over σ times its :func:`band_noise` (the SFR's noise rises with frequency:
    on e1's device 1.0, 2.0, 3.6 and 5.2 × SFRA's); with asymmetry parts, the LSF asymmetry bands over their σ
    (:mod:`calibration.sfr.asymmetry`). ``bias`` may be a plain (N,) SFRA bias."""
    lens = space.apply(np.asarray(u) * space.tolerance)
    pred = model.predict(lens)
    obs = model.obs
    if not isinstance(bias, ResidualBias):
        bias = ResidualBias(np.asarray(bias, float))
    parts = [((obs.sfra - pred.sfra - bias.sfra) / obs.sfra_std)[:, None]]
    if bias.bands is not None:
        from calibration.fit.forward_model import band_means

        parts.append((bias.measured_bands - band_means(obs.freq, pred.sfr) - bias.bands)
                     / (np.asarray(band_noise(bias.noise), float) * obs.sfra_std[:, None]))
    if bias.odd is not None:
        from calibration.sfr.asymmetry import odd_sigma

        parts.append((obs.odd - model.predict_odd(lens) - bias.odd) / odd_sigma(obs.odd_std))
    r = np.concatenate(parts, axis=1).ravel()
    return np.where(np.isfinite(r), r, 0.0)


def resolve_residuals(residuals: str, obs: Observations) -> str:
    """``residuals`` checked; "auto" is "shape" (SFRA, SFR bands and LSF
    asymmetry) where the observations carry the asymmetry, else "sfra".

    Why "shape": on 12 synthetic devices (4 phone lenses × 3, 24
    parameters; ``benchmarks/proxy.py``) it ended closer to the measured
    SFR than SFRA + asymmetry alone in 10 of the 12 lens × FoV means, with
    the same edge-image SSIM."""
    if residuals == "auto":
        return "shape" if obs.odd is not None else "sfra"
    if residuals not in RESIDUALS:
        raise ValueError(f"unknown residuals {residuals!r}; valid: 'auto', {', '.join(map(repr, RESIDUALS))}")
    if residuals in ("odd", "shape") and obs.odd is None:
        raise ValueError(f"residuals {residuals!r} need the observations' LSF asymmetry (obs.odd): measure the "
                         "edges again with this version, or use residuals='sfra'")
    return residuals


def residual_bias(model, lens, residuals: str, executor: Executor | None = None) -> ResidualBias:
    """The measurement's bias at ``lens`` with the parts ``residuals``
    uses (:class:`ResidualBias`), measured on ``executor`` (default: in
    this process)."""
    mb = model.measurement_biases(lens, executor=executor)
    obs = model.obs
    out = ResidualBias(np.asarray(mb.sfra, float), noise=mb.noise)
    if residuals in ("bands", "shape"):
        from calibration.fit.forward_model import band_means

        out = out._replace(bands=band_means(obs.freq, mb.sfr), measured_bands=band_means(obs.freq, obs.sfr))
    if residuals in ("odd", "shape"):
        out = out._replace(odd=mb.odd)
    return out


def band_noise(spread) -> np.ndarray | float:
    """(K,) each SFR band's noise over SFRA's: RMS of ``spread``'s band
    columns over RMS of its first (``spread`` (N, 1 + K), the model's noisy
    renders, :class:`calibration.fit.forward_model.MeasurementBias`); 4.0
    where the renders carry no noise.

    >>> band_noise(np.array([[0.01, 0.01, 0.02, 0.036, 0.052]] * 3)).round(2).tolist()
    [1.0, 2.0, 3.6, 5.2]
    """
    if spread is None:
        return 4.0
    s = np.asarray(spread, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(np.nanmean(s ** 2, axis=0))
        r = rms[1:] / rms[0]
    return r if np.all(np.isfinite(r)) and np.all(r > 0) else 4.0


@dataclass(frozen=True)
class ProxyFitSettings:
    """How :func:`fit_proxy` fits (module docstring); the defaults are the
    measured ones. Checked at construction (:class:`isp.errors.ConfigError`
    naming the field and value).

    Parameters
    ----------
    model : calibration.fit.forward_model.ModelSettings, optional
        The forward model (default ``ModelSettings()``).
    method : {"dls", "scipy"}
        :func:`calibration.fit.dls.damped_least_squares`, or scipy's TRF
        on the same residuals.
    max_iter : int
        Iterations (DLS) at most, ≥ 1; for scipy its ``max_nfev``, which TRF
        counts without its finite differences (about ``max_iter``
        iterations).
    bound_factor : float
        Bounds, tolerances (> 0): the fit keeps every parameter within
        ±``bound_factor``, focus within ±:data:`FOCUS_BOUND` (:func:`parameter_bounds`).
    n_params : int, optional
        Without ``names``: fit the ``n_params`` (≥ 1) most sensitive of
        :func:`default_names` (:func:`screen_parameters`); None: all.
    residuals : {"auto", "sfra", "bands", "odd", "shape"}
        "auto" (default): "shape" where the observations have the
        asymmetry, else "sfra". "sfra": the paper's SFRA per observation;
        "bands": SFRA plus the mean SFR in four frequency bands
        (:data:`calibration.fit.forward_model.BANDS`), which pins the
        curve's shape; "odd": SFRA plus the LSF's asymmetry in four bands
        (:mod:`calibration.sfr.asymmetry`; needs ``obs.odd``), which the
        SFR's modulus drops: the direction of coma from a decentered
        element; "shape": SFRA, bands and asymmetry (see
        ``benchmarks/proxy.py``).
    jacobian_model : calibration.fit.forward_model.ModelSettings, optional
        A cheaper forward model for the Jacobian only (DLS), e.g. one
        wavelength and fewer pupil samples; steps are still accepted on the
        full model's merit (``benchmarks/proxy.py --fast-jacobian`` measures
        what it costs).
    refresh : int
        DLS: a finite-difference Jacobian every ``refresh`` (≥ 1) accepted
        steps at most, Broyden secant updates in between
        (:mod:`calibration.fit.dls`; ``benchmarks/proxy.py --refresh``
        measures what it costs).
    bounds : {"clip", "box"}
        DLS: how a step meets the ±``bound_factor`` box
        (:class:`calibration.fit.dls.DLSSettings`; ``benchmarks/proxy.py``'s
        method ``ours_box`` measures it).
    prior : float, optional
        A Gaussian prior on every fitted perturbation, its standard
        deviation in tolerances (> 0; ``1/√3``: a perturbation uniform
        within its tolerance): the residuals gain ``u_j / prior``, a maximum
        a posteriori fit that holds directions the measurement cannot see
        near the nominal design instead of letting them drift to the
        bounds. None (default): no prior. At ``1/√3`` on the 12 devices of
        ``benchmarks/proxy.py`` (method ``ours_prior``) the data outweighed
        it: SFR error tied with no prior (1.05× / 1.03× / 1.01×).
    restarts : int
        When the fit ends with a merit above :data:`RESTART_CHI2` per
        residual (far above the noise floor: a local minimum, or a model
        that cannot fit), try this many (≥ 0) other starts
        (:func:`restart`, seeded by ``seed``); 0: none. A fit that reaches
        the floor from the nominal lens costs nothing more.
    seed : int
        Seed of the restarts' starting points.
    coarse : (int, int), optional
        Fit first on the observations of a sub-grid of this many regions
        (:func:`coarse_subset`; screening and restarts included), then
        refine on all of them from there (no restarts); only where that
        cuts the observations at least twofold and ``x0`` is not given.
        None: fit on all observations from the start.
    fine_iter : int, optional
        Iterations at most of a coarse-to-fine fit's stage on all
        observations (≥ 0); None: ``max_iter``; 0: stop after the coarse
        stage (the fit and its errors are then the sub-grid's: what a device
        calibration on the descriptor's own 5 × 7 regions needs). Each costs as much as the
        whole coarse stage's per observation: on e1's clean device (41
        perturbations, 1,200 edges, 24 s an iteration) the merit after 12
        stood within 1.3 % of where 20 left it.
    floor_chi2 : float
        DLS stops at the noise floor: χ² per residual at most this (> 0),
        with less than one unit of χ² left to gain in the linearised model
        (:class:`calibration.fit.dls.DLSSettings`'s ``target_chi2``).
        ``inf``: on the gain left alone, as the fine stage of a
        coarse-to-fine fit does.
    stage_params : int, optional
        A coarse stage given more parameters than this also fits first the
        ``stage_params`` most sensitive of its assembly perturbations (those
        of :func:`default_names`: decenters, tilts, gaps and focus; screened
        on the sub-grid, restarts included), then all of them from there
        (no restarts), and keeps the better of that and the fit of all at
        once (recorded among ``restarts``), which then runs without restarts.
        None: all at once only, restarts included. Why:
        from the nominal lens, all of a lens's perturbations at once can
        settle where their directions drift together, far from the device,
        and the staged fit can too, on other devices
        (:data:`calibration.loop.base.LOOP_STAGE_PARAMS`). Why no restarts of
        the fit of all at once: in 92 dimensions their starts land far from
        any device (on the loop suite's case 14 their probes ended at 107–139 k
        where the fit itself reached 70.9 k and the staged one 26.4 k; without
        them the case ends where it did, at 1.07 × its noise floor, its base
        fit in 318 s instead of 400);
        on an e2 module fitted over all 92 (the coarse stage alone, the full
        model's Jacobian) they cost 207 of 481 s and the staged fit won
        either way, at the same χ².
    widen : bool
        Where the fitted lens throws more than a tenth of some
        observation's light outside the model's PSF window
        (:data:`calibration.optics.psf.map.WINDOW_ENERGY_WARN`), fit again
        from the start with a window :data:`WIDEN_FACTOR` times wider, up to
        :data:`MAX_WINDOW_UM`, and again while each widening recovers at
        least :data:`WIDEN_RECOVERS` of the light the window missed
        (:func:`fit_proxy`). A blurry module's corner
        light falls outside a narrow window and its model's SFR there is
        too high at low frequencies: on 6 modules of e2, whose corners
        spread wider than e9's, five quick fits widened to 48 µm and the
        conditioned correction's gain at FoV 0.9 went from +1.19 to
        +1.35 dB (docs/results/device.md). False (default): one fit, the window as
        given (``isp calib fit --widen`` turns it on).
    kinds : tuple of str
        The kinds of perturbation screened to ``n_params`` when the fit is
        given no names (:data:`KINDS`; default :data:`FIT_KINDS`: decenters,
        tilts, air gaps and focus).

    Examples
    --------
    >>> ProxyFitSettings(max_iter=6, restarts=0).coarse
    (5, 7)
    >>> ProxyFitSettings(method="lm")
    Traceback (most recent call last):
    ...
    isp.errors.ConfigError: ProxyFitSettings.method: unknown 'lm'; valid: 'dls', 'scipy'
    """

    model: object = None
    method: str = "dls"
    max_iter: int = MAX_ITER
    bound_factor: float = 2.0
    n_params: int | None = N_PARAMS
    residuals: str = "auto"
    jacobian_model: object = None
    refresh: int = REFRESH
    bounds: str = "clip"
    prior: float | None = None
    restarts: int = RESTARTS
    seed: int = 0
    coarse: tuple[int, int] | None = COARSE_GRID
    fine_iter: int | None = None
    floor_chi2: float = 1.0
    stage_params: int | None = None
    widen: bool = False
    kinds: tuple = FIT_KINDS

    def __post_init__(self):
        from calibration.fit.forward_model import ModelSettings

        def bad(name, why):
            return ConfigError(f"ProxyFitSettings.{name}: {why}")

        def integer(name, least, optional=False):
            v = getattr(self, name)
            if v is None and optional:
                return
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < least:
                raise bad(name, f"must be an integer ≥ {least}, got {v!r}")
            object.__setattr__(self, name, int(v))

        def positive(name, optional=False):
            v = getattr(self, name)
            if v is None and optional:
                return
            try:
                x = float(v)
            except (TypeError, ValueError):
                x = float("nan")
            if not x > 0:
                raise bad(name, f"must be a number > 0, got {v!r}")
            object.__setattr__(self, name, x)

        for name in ("model", "jacobian_model"):
            v = getattr(self, name)
            if v is not None and not isinstance(v, ModelSettings):
                raise bad(name, f"must be a ModelSettings, got {type(v).__name__}")
        for name, valid in (("method", ("dls", "scipy")), ("residuals", ("auto", *RESIDUALS)),
                            ("bounds", ("clip", "box"))):
            if getattr(self, name) not in valid:
                raise bad(name, f"unknown {getattr(self, name)!r}; valid: {', '.join(map(repr, valid))}")
        integer("max_iter", 1)
        integer("fine_iter", 0, optional=True)
        integer("n_params", 1, optional=True)
        integer("stage_params", 1, optional=True)
        integer("refresh", 1)
        integer("restarts", 0)
        integer("seed", 0)
        if not isinstance(self.widen, bool):
            raise bad("widen", f"must be True or False, got {self.widen!r}")
        kinds = (self.kinds,) if isinstance(self.kinds, str) else tuple(self.kinds)
        unknown = [k for k in kinds if k not in KINDS]
        if unknown or not kinds:
            raise bad("kinds", f"unknown {', '.join(map(repr, unknown)) or 'none given'}; valid: {', '.join(KINDS)}")
        object.__setattr__(self, "kinds", kinds)
        positive("bound_factor")
        positive("prior", optional=True)
        positive("floor_chi2")
        if self.coarse is not None:
            try:
                rows, cols = self.coarse
                ok = all(not isinstance(v, bool) and int(v) == v and v >= 1 for v in (rows, cols))
            except (TypeError, ValueError):
                ok = False
            if not ok:
                raise bad("coarse", f"must be (rows, cols) of integers ≥ 1 or None, got {self.coarse!r}")
            object.__setattr__(self, "coarse", (int(rows), int(cols)))


def worker_models(payload) -> dict:
    """What a fit's worker holds (the executor's setup, once per worker):
    the model, the Jacobian's cheaper model, the parameter space, the bias."""
    from calibration.fit.forward_model import SfrModel

    nominal, obs, settings, names, bias, *rest = payload
    model = SfrModel(nominal, obs, settings)
    jac_settings = rest[0] if rest else None
    return {"model": model, "cheap": SfrModel(nominal, obs, jac_settings) if jac_settings is not None else model,
            "space": parameter_space(nominal, names), "bias": bias}


def fit_proxy(nominal: Lens, obs: Observations, settings: ProxyFitSettings | None = None, *, names=None,
              x0=None, executor: Executor | None = None) -> ProxyFit:
    """Fit a proxy camera to SFR observations (module docstring).

    Parameters
    ----------
    nominal : Lens
    obs : Observations
    settings : ProxyFitSettings, optional
        How to fit (default ``ProxyFitSettings()``: the measured defaults).
    names : sequence of str, optional
        Fitted parameters (default :func:`default_names`, screened to
        ``settings.n_params``).
    x0 : (N,) array_like, optional
        Start (tolerance units); default the nominal lens (0).
    executor : isp.runtime.executor.Executor, optional
        Runs the Jacobian's lens evaluations (each worker holds the models,
        built once from the executor's payload) and the measurement bias;
        its progress bar counts iterations. Default: up to 2 worker
        processes with a progress bar (:func:`isp.runtime.executor.pool_executor`).
        DLS tries as many dampings per step as it has workers.
    """
    cfg = ProxyFitSettings() if settings is None else settings
    if not isinstance(cfg, ProxyFitSettings):
        raise ConfigError(f"settings must be a ProxyFitSettings, got {type(cfg).__name__}")
    fit = _fit_proxy(nominal, obs, cfg, names, x0, executor)
    if not cfg.widen:
        return fit
    from dataclasses import replace

    from calibration.fit.forward_model import ModelSettings
    from calibration.optics.psf.map import WINDOW_ENERGY_WARN

    model, tried, seconds = cfg.model or ModelSettings(), [], fit.seconds
    while fit.window_energy < WINDOW_ENERGY_WARN and model.window_um < MAX_WINDOW_UM:
        missing = 1.0 - fit.window_energy
        missed_before = 1.0 - tried[-1]["window_energy_min"] if tried else None
        if missed_before is not None and missed_before - missing < WIDEN_RECOVERS * missed_before:
            break           # the last widening recovered too little: another would cost a whole fit for less
        tried.append({"window_um": model.window_um, "window_energy_min": round(fit.window_energy, 4),
                      "seconds": round(fit.seconds, 2)})
        model = model.with_window(min(MAX_WINDOW_UM, WIDEN_FACTOR * model.window_um))
        fit = _fit_proxy(nominal, obs, replace(cfg, model=model), names, x0, executor)
        seconds += fit.seconds
    if tried:
        fit.settings["widened"] = tried
        fit.seconds = seconds
    return fit


#: :attr:`ProxyFitSettings.widen`: each refit's window is this many times the last one's
WIDEN_FACTOR = 1.5
#: :attr:`ProxyFitSettings.widen`: the widest window it tries, µm
MAX_WINDOW_UM = 128.0
#: :attr:`ProxyFitSettings.widen`: it widens again only where the last widening recovered at least this share of
#: the light the narrower window missed. On a module of e2 the fitted lens kept 78 % of a corner region's light
#: in 32 µm, 81 % in 48, 82 % in 72 and 83 % in 108: after 48 µm each refit cost as much as the first fit and
#: moved nothing
WIDEN_RECOVERS = 0.25


def _fitted_count(nominal: Lens, names, cfg: ProxyFitSettings) -> int:
    """How many perturbations a fit given ``names`` (None: screened from
    ``cfg.kinds`` to ``cfg.n_params``) asks for, the size its coarse
    sub-grid is chosen by."""
    if names is not None:
        return len(names)
    return cfg.n_params or len(default_names(nominal, cfg.kinds))


def _fit_proxy(nominal: Lens, obs: Observations, cfg: ProxyFitSettings, names, x0,
               executor: Executor | None) -> ProxyFit:
    """:func:`fit_proxy` with one window."""
    n_fit = _fitted_count(nominal, names, cfg)
    mask = coarse_subset(obs, cfg.coarse, min_obs=2 * n_fit) if cfg.coarse is not None and x0 is None else None
    own = executor is None
    ex = pool_executor(None, progress=True) if own else executor
    try:
        if mask is not None:
            return _coarse_to_fine(nominal, obs, mask, names, cfg, ex)
        return _fit(nominal, obs, cfg, names, x0, ex)
    finally:
        if own:
            ex.close()


def _fit(nominal, obs, cfg: ProxyFitSettings, names, x0, ex: Executor, screen: bool = False) -> ProxyFit:
    """:func:`fit_proxy` on all of ``obs`` (no coarse stage); ``screen``:
    the given ``names`` are screened to ``cfg.n_params`` as the default
    ones are."""
    from calibration.fit.forward_model import ModelSettings, SfrModel

    method, max_iter, bound_factor, n_params = cfg.method, cfg.max_iter, cfg.bound_factor, cfg.n_params
    jacobian_settings, refresh, bounds, prior = cfg.jacobian_model, cfg.refresh, cfg.bounds, cfg.prior
    restarts, seed, floor_chi2 = cfg.restarts, cfg.seed, cfg.floor_chi2
    settings = cfg.model or ModelSettings()
    t0 = time.perf_counter()
    model = SfrModel(nominal, obs, settings)
    residuals = resolve_residuals(cfg.residuals, obs)
    bias = residual_bias(model, nominal, residuals, ex)
    screen = (screen or names is None) and n_params is not None
    names = list(names) if names is not None else default_names(nominal, cfg.kinds)
    cheap_model = None   # in this process, where there is no pool
    pool = None
    if ex.parallel:
        # one pool for screening and fit, its workers' models built once over every candidate
        # parameter; the fit's points are embedded in that space (zeros elsewhere: the same lens)
        pool = ex.bind((nominal, obs, settings, names, bias, jacobian_settings), setup=worker_models)
    elif jacobian_settings is not None:
        cheap_model = SfrModel(nominal, obs, jacobian_settings)
    all_names, where = names, None

    def on_pool(task, points):
        if where is not None:
            full = np.zeros((len(points), len(all_names)))
            full[:, where] = points
            points = list(full)
        return pool.map(task, points)

    bar = None
    tried: list = []
    try:
        jac0 = None
        if screen and len(names) > n_params:
            # screened on the residuals the fit will use (the asymmetry makes decenters visible
            # that SFRA hides), by the Jacobian's model: a ranking, and the fit's first Jacobian
            task = residual_task if jacobian_settings is None else _cheap_residual_task
            screen_model = model if cheap_model is None else cheap_model
            names, jac0 = screen_parameters(screen_model, names, n_params, bias=bias,
                                            return_jacobian=True,
                                            fun_many=None if pool is None else (lambda pts: on_pool(task, pts)))
        space = parameter_space(nominal, names)
        n = len(space.names)
        if names != all_names:
            where = np.array([all_names.index(k) for k in names])
        lower, upper = parameter_bounds(space.names, focus_name(nominal), bound_factor)
        u0 = np.zeros(n) if x0 is None else np.asarray(x0, float)
        if x0 is not None:
            jac0 = None   # screened at the nominal lens, not at x0

        def with_prior(points, values):
            if prior is None:
                return values
            return [np.concatenate([v, np.asarray(p, float) / prior]) for p, v in zip(points, values)]

        def fun(u):
            return with_prior([u], [_residuals(model, space, bias, u)])[0]

        def fun_many(points):
            if pool is None or len(points) == 1:
                return [fun(p) for p in points]
            return with_prior(points, on_pool(residual_task, points))

        def cheap_many(points):
            if pool is None:
                return with_prior(points, [_residuals(cheap_model, space, bias, p) for p in points])
            return with_prior(points, on_pool(_cheap_residual_task, points))

        jac_many = cheap_many if jacobian_settings is not None else None

        if prior is not None and jac0 is not None:
            jac0 = np.vstack([jac0, np.eye(n) / prior])

        bar = ex.bar(total=max_iter, unit="iter", desc=f"proxy fit ({n} parameters, {len(obs)} edges)")

        def report(rec):
            if bar is not None and rec["iteration"] > 0:
                bar.update(1)
                bar.set_postfix(merit=f"{rec['merit']:.4g}", evals=rec["evaluations"])

        bias_sfra = bias.sfra
        before = model.predict(nominal).sfra + bias_sfra
        if method == "dls":
            # central differences cure forward ones' O(h) bias, not a cheaper model's error: at a
            # fitted e9 device (15 × 20 regions; a one-off check, not a benchmark) the
            # cheap model's Jacobian is 7.9 % off the full
            # model's central one forward, 7.5 % central (the full model forward: 2.8 %), and the
            # two central iterations that ended the fit bought 0.1 χ² for 42 s
            scheme = "auto" if jacobian_settings is None else "forward"

            def local(start, iters, first_jacobian=None):
                dls = DLSSettings(h=DLS_STEP, max_iter=iters, target_chi2=floor_chi2, trials=ex.workers,
                                  refresh=refresh, bounds=bounds, jacobian=scheme)
                return damped_least_squares(fun, start, lower=lower, upper=upper, settings=dls, fun_many=fun_many,
                                            jac_many=jac_many, callback=report, jac0=first_jacobian)
        elif method == "scipy":
            from scipy.optimize import least_squares

            def local(start, iters, first_jacobian=None):
                calls = {"n": 0}

                def counted(u):
                    calls["n"] += 1
                    return fun(u)

                # TRF counts in max_nfev neither its finite differences nor the Jacobians, so
                # max_iter here is about max_iter iterations: the same budget as DLS's Jacobians
                ls = least_squares(counted, start, bounds=(lower, upper), method="trf", diff_step=DLS_STEP,
                                   x_scale=1.0, max_nfev=iters)
                jtj = ls.jac.T @ ls.jac
                cov = np.linalg.pinv(jtj) * max(1.0, 2 * ls.cost / max(len(ls.fun) - n, 1))
                return DlsResult(ls.x, ls.fun, ls.jac, cov, [], calls["n"], ls.message)
        else:
            raise ValueError(f"unknown method {method!r}; valid: 'dls', 'scipy'")
        res = local(u0, max_iter, jac0)
        if restarts > 0 and res.merit > RESTART_CHI2 * res.residuals.size:
            if bar is not None:
                bar.total += restarts * min(PROBE_ITER, max_iter) + max(max_iter - PROBE_ITER, 0)
                bar.set_description(f"proxy fit ({n} parameters, {len(obs)} edges, {restarts} restarts)")
            res, tried = restart(local, res, restarts, max_iter, seed)
        u, evals = res.x, res.evaluations
    finally:
        if pool is not None:
            pool.close()
        if bar is not None:
            bar.close()
    fitted = space.apply(u * space.tolerance)
    after = model.predict(fitted).sfra + bias_sfra
    return ProxyFit(nominal, space, np.asarray(u), res, obs, before, after, bias_sfra, method, evals,
                    time.perf_counter() - t0, settings=_settings_dict(settings),
                    window_energy=float(np.min(model.window_energy(fitted))), restarts=tried)


def coarse_subset(obs: Observations, grid=COARSE_GRID, min_obs: int = 1) -> np.ndarray | None:
    """Mask of the observations in a ``grid`` sub-grid of ``obs``'s regions:
    rows and columns evenly spread from edge to edge, so the corners stay
    in. Where ``grid`` holds fewer than ``min_obs`` observations, the
    sub-grid grows (rows and columns in proportion) until it holds them:
    a fit needs at least about two observations per parameter it fits,
    and a fit of many parameters still gains from choosing its basin on
    a sub-grid. None where the sub-grid would not at least halve the
    observations.

    Examples
    --------
    A 15 × 20 grid keeps rows 0, 4, 7, 10, 14 and columns 0, 3, 6, 10, 13,
    16, 19: 35 of its 300 regions; asked for 36 observations or more (one
    per region), it keeps 6 × 8 regions.
    """
    rows, cols = obs.grid
    region = obs.region
    g0, g1 = int(grid[0]), int(grid[1])
    grow = 0
    while True:
        gr, gc = min(g0 + grow, rows), min(round(g1 * (g0 + grow) / g0), cols)
        keep_r = np.unique(np.round(np.linspace(0, rows - 1, gr)).astype(int))
        keep_c = np.unique(np.round(np.linspace(0, cols - 1, gc)).astype(int))
        mask = np.isin(region[:, 0], keep_r) & np.isin(region[:, 1], keep_c)
        if 2 * mask.sum() > len(obs):
            return None
        if mask.sum() >= min_obs:
            return mask
        if gr == rows and gc == cols:
            return None
        grow += 1


def _coarse_to_fine(nominal, obs, mask, names, cfg: ProxyFitSettings, ex: Executor) -> ProxyFit:
    """:func:`fit_proxy` on ``obs.subset(mask)`` (screening, restarts), then on
    all of ``obs`` from its result, with its parameters."""
    import dataclasses

    t0 = time.perf_counter()
    sub = obs.subset(mask)
    n_fit = _fitted_count(nominal, names, cfg)
    staging = cfg.stage_params is not None and n_fit > cfg.stage_params
    first = _fit(nominal, sub, dataclasses.replace(cfg, restarts=0) if staging else cfg, names, None, ex)
    names = list(first.space.names)   # the screened ones where none were given
    if staging and len(names) > cfg.stage_params:
        # also: the most sensitive assembly parameters find a basin (screening and restarts among
        # them), then all of them from there; the better of the two coarse fits is kept
        assembly = [k for k in default_names(nominal) if k in names]
        lead = _fit(nominal, sub, dataclasses.replace(cfg, n_params=cfg.stage_params),
                    assembly if len(assembly) > cfg.stage_params else names, None, ex, screen=True)
        got = dict(zip(lead.space.names, lead.u))
        staged = _fit(nominal, sub, dataclasses.replace(cfg, restarts=0), names,
                      np.array([got.get(k, 0.0) for k in names]), ex)
        kept = staged.result.merit < first.result.merit
        tried = first.restarts + [{"start": f"{len(lead.space.names)} first", "probe_merit": round(lead.result.merit, 3),
                                   "final_merit": round(staged.result.merit, 3), "kept": bool(kept)}]
        first = dataclasses.replace(staged if kept else first, seconds=time.perf_counter() - t0, restarts=tried,
                                    evaluations=first.evaluations + lead.evaluations + staged.evaluations)
    # the sub-grid chose the basin; on all observations the fit only has to move within it, by
    # about the coarse fit's uncertainty: it stops once the linear model leaves less than one
    # unit of χ² to gain, whatever χ² per residual the model's own error leaves (on e9 device 1 at
    # 15 × 20 the merit stood within 0.01 % for its last 12 of 20 iterations, each rejected step
    # costing up to 24 evaluations of all 600 observations)
    stage = {"observations": int(mask.sum()), "evaluations": first.evaluations, "seconds": round(first.seconds, 2),
             "merit": None if first.result is None else round(first.result.merit, 3),
             "residuals": None if first.result is None else int(first.result.residuals.size)}
    if cfg.fine_iter == 0:
        return dataclasses.replace(first, coarse={**stage, "refined": False})
    fine_iter = cfg.max_iter if cfg.fine_iter is None else cfg.fine_iter
    fine_cfg = dataclasses.replace(cfg, restarts=0, floor_chi2=np.inf, max_iter=fine_iter)
    fine = _fit(nominal, obs, fine_cfg, list(first.space.names), first.u, ex)
    return dataclasses.replace(fine, evaluations=first.evaluations + fine.evaluations,
                               seconds=time.perf_counter() - t0, restarts=first.restarts, coarse=stage)


def restart(local, first, count: int, max_iter: int, seed: int = 0):
    """Multistart for a fit ``first`` that ended far above the noise floor.

    ``local(start, iterations)`` runs the local fit (a :class:`DlsResult`).
    ``count`` starts spread over the ±1-tolerance box, where a device's
    perturbations lie (a Latin hypercube, seeded), each fitted for
    :data:`PROBE_ITER` iterations (at most ``max_iter``); the probe with the lowest merit,
    if below :data:`CONTINUE_WITHIN` times ``first``'s, is continued for the rest of
    ``max_iter``, and kept if it ends below ``first``. Why: DLS and TRF alike settle, from the nominal lens, in
    minima of 15–84 χ² per residual, far above the noise floor, on 9 of the 24 devices of
    ``benchmarks/proxy.py`` (the truth lens, within the fitted parameters,
    sits at the floor); a few iterations tell the basins apart (the merit
    falls 10–100× within five iterations into the truth's basin,
    docs/results/proxy.md). Returns the best result (its ``evaluations`` counting
    every run) and one record per start.
    """
    import dataclasses

    from scipy.stats import qmc

    probe_iter = min(PROBE_ITER, max_iter)
    starts = 2.0 * qmc.LatinHypercube(d=first.x.size, seed=seed).random(count) - 1.0
    probes = [local(x, probe_iter) for x in starts]
    tried = [{"start": k, "probe_merit": round(r.merit, 3)} for k, r in enumerate(probes)]
    evals = first.evaluations + sum(r.evaluations for r in probes)
    best = first
    j = int(np.argmin([r.merit for r in probes]))
    if probes[j].merit < CONTINUE_WITHIN * first.merit:
        go_on = probes[j]
        if max_iter > probe_iter:
            go_on = local(probes[j].x, max_iter - probe_iter)
            evals += go_on.evaluations
        tried[j]["final_merit"] = round(go_on.merit, 3)
        tried[j]["kept"] = bool(go_on.merit < first.merit)
        if go_on.merit < first.merit:
            best = dataclasses.replace(go_on, history=first.history + probes[j].history + go_on.history)
    return dataclasses.replace(best, evaluations=evals), tried


def _settings_dict(settings) -> dict:
    import dataclasses

    return dataclasses.asdict(settings) if dataclasses.is_dataclass(settings) else dict(settings)


def plot_fit(fit: ProxyFit, directory) -> dict:
    """merit.png (merit per iteration), sfra_maps.png (measured, nominal,
    fitted SFRA over the field) and parameters.png (values ± 1σ in
    tolerances)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from calibration.report import save_figure

    d = Path(directory)
    out = {}
    hist = fit.result.history if fit.result is not None else []
    if hist:
        fig, ax = plt.subplots(figsize=(5, 3.4))
        ax.semilogy([h["evaluations"] for h in hist], [h["merit"] for h in hist], "o-")
        ax.set(xlabel="lens evaluations", ylabel="merit Σ f² (χ²)", title=f"proxy fit ({fit.method})")
        ax.axhline(len(fit.observations), color="gray", ls=":", label="noise floor (χ² = N)")
        ax.legend()
        ax.grid(alpha=0.3)
        save_figure(fig, d / "merit.png")
        out["merit_plot"] = d / "merit.png"
    obs = fit.observations
    maps = [obs.region_map(), obs.region_map(fit.predicted_before), obs.region_map(fit.predicted_after)]
    vmin = np.nanmin([np.nanmin(m) for m in maps])
    vmax = np.nanmax([np.nanmax(m) for m in maps])
    fig, axes = plt.subplots(1, 4, figsize=(17, 3.6))
    for ax, m, title in zip(axes, maps, ("measured SFRA", "nominal lens", "proxy camera")):
        im = ax.imshow(m, vmin=vmin, vmax=vmax, cmap="viridis")
        ax.set_title(title)
    fig.colorbar(im, ax=axes[:3], shrink=0.8, label="SFRA (cy/px)")
    r = maps[0] - maps[2]
    lim = np.nanmax(np.abs(r)) if np.isfinite(r).any() else 1.0
    im = axes[3].imshow(r, cmap="coolwarm", vmin=-lim, vmax=lim)
    axes[3].set_title("measured − proxy")
    fig.colorbar(im, ax=axes[3], shrink=0.8)
    save_figure(fig, d / "sfra_maps.png")
    out["sfra_plot"] = d / "sfra_maps.png"
    fig, ax = plt.subplots(figsize=(max(6, 0.22 * len(fit.u)), 3.4))
    std_u = fit.result.std if fit.result is not None else np.zeros_like(fit.u)
    ax.bar(range(len(fit.u)), fit.u, yerr=std_u, capsize=2)
    ax.set_xticks(range(len(fit.u)))
    ax.set_xticklabels(fit.space.names, rotation=90, fontsize=7)
    ax.set_ylabel("fitted value / tolerance")
    ax.axhline(0, color="k", lw=0.5)
    fig.tight_layout()
    save_figure(fig, d / "parameters.png")
    out["parameters_plot"] = d / "parameters.png"
    return out


def save_proxy(path, nominal, perturbation: Perturbation | None = None) -> Path:
    """Write ``nominal`` with ``perturbation`` as a proxy lens file (lens/v1
    plus a ``perturbation`` object of {name: value}), atomically; what
    :func:`load_proxy` reads back. A fitted proxy camera, or the true lens of
    a simulated device (``isp calib simulate --save-lens``)."""
    from calibration.optics.io.lens_json import lens_to_dict
    from calibration.report import write_json

    doc = lens_to_dict(nominal)
    doc["perturbation"] = {n: float(v) for n, v in (perturbation.as_dict() if perturbation else {}).items()}
    return write_json(path, doc)


def load_proxy(path) -> PerturbedLens:
    """A proxy lens file (lens/v1 with a ``perturbation`` object) as a
    PerturbedLens; a plain lens/v1 file gives the nominal lens."""
    from calibration.optics.io import read_lens

    lens = read_lens(path)
    pert = lens.metadata.get("perturbation") or {}
    return apply(lens, Perturbation.from_dict(pert))


__all__ = ["FittedLens", "ProxyFit", "default_names", "screen_parameters", "fit_proxy", "focus_name", "load_proxy", "parameter_space", "save_proxy",
           "plot_fit", "FOCUS_TOLERANCE_MM"]

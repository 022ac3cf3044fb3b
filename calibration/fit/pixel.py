"""The pixel-level competitor of the proxy fit: lens perturbations fitted
to the measured edge *images* by their mean squared error (paper §4.2,
the "pixel MSE" baseline of Table 1).

:func:`fit_pixel_mse` renders every observation's slanted edge through the
candidate lens — its PSF from :meth:`calibration.fit.forward_model.SfrModel.observation_psfs`,
the edge at the measured ROI's geometry (centre, size, angle, levels;
:class:`calibration.fit.synthetic_devices.SyntheticEdge`) by
:func:`calibration.simulate.capture.render_slanted_edge` — and minimises
``Σ (simulated − measured)²`` over all pixels of all ROIs with
``scipy.optimize.least_squares`` (trust-region reflective, forward
differences of 0.1 tolerance) over the same parameters, in tolerance units
and bounds (±2 tolerances, focus ±8), as :func:`calibration.fit.proxy.fit_proxy`.

Unlike the SFRA fit it has no noise model: the measured noise is simply
part of the residual (its MSE floor is σ²), and the pixels also weigh the
sub-pixel position and the exposure of each edge, which a real capture
does not share with the simulation (``benchmarks/sfr_noise.py``).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from isp.runtime.executor import Executor, create_executor, worker_payload

from calibration.optics.lens import Lens
from calibration.optics.perturb import ParameterSpace
from calibration.fit.proxy import FittedLens, default_names, focus_name, parameter_bounds, parameter_space
from calibration.fit.observations import Observations

__all__ = ["PixelFit", "edge_offset", "fit_pixel_mse", "pixel_residuals", "register_edge", "render_edges"]


@dataclass
class PixelFit(FittedLens):
    """A lens fitted to edge images (the fields :class:`calibration.fit.proxy.ProxyFit` shares)."""

    nominal: Lens
    space: ParameterSpace
    u: np.ndarray                       # parameters in tolerance units
    observations: Observations
    mse_before: float                   # pixel MSE of the nominal lens
    mse_after: float                    # pixel MSE of the fitted lens
    method: str = "pixel-mse"
    evaluations: int = 0
    seconds: float = 0.0
    message: str = ""
    iterations: int = 0
    settings: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        tol = self.space.tolerance
        return {"method": self.method,
                "parameters": [{"name": n, "value": float(v), "tolerance": float(t)}
                               for n, v, t in zip(self.space.names, self.u * tol, tol)],
                "mse_before": self.mse_before, "mse_after": self.mse_after,
                "evaluations": self.evaluations, "iterations": self.iterations,
                "seconds": round(self.seconds, 2), "stop_reason": self.message,
                "observations": len(self.observations), "settings": self.settings}


def render_edges(model, lens, edges) -> list[np.ndarray]:
    """Each edge's ROI (noise-free) through ``lens``'s PSF for that
    observation (``model``: an :class:`~calibration.fit.forward_model.SfrModel` on
    the same observations, in the same order as ``edges``)."""
    psfs = model.observation_psfs(lens)
    if len(psfs) != len(edges):
        raise ValueError(f"{len(edges)} edge images for {len(psfs)} observations")
    return [e.render(psfs[i], model.pitch_um) for i, e in enumerate(edges)]


def edge_offset(simulated, measured) -> tuple[float, int]:
    """Where the ``measured`` edge lies relative to the ``simulated`` one,
    pixels along the edge normal, and the axis that normal runs along (1:
    columns, a near-vertical edge; 0: rows, a near-horizontal one).

    Both ROIs are located as ISO 12233 locates an edge (windowed
    derivative centroids per line, a straight-line fit;
    :func:`calibration.sfr.esfr.measure_sfr`), and the offset is the difference
    of the two lines at the ROI's middle line. A chart capture fixes an
    edge's position only to the chart's registration, not to the
    0.1-pixel level at which a PSF's centroid moves with the lens, so a
    comparison of edge images that is meant to judge the blur, not the
    position, aligns them first (:func:`register_edge`).

    Examples
    --------
    >>> from calibration.sfr.synthetic import render_slanted_edge
    >>> a = render_slanted_edge((48, 64), 5.0, 1.2)
    >>> b = render_slanted_edge((48, 64), 5.0, 1.2, center=(31.5 + 0.3, 23.5))
    >>> off, axis = edge_offset(a, b)
    >>> round(off, 2), axis
    (0.3, 1)
    """
    from calibration.sfr.esfr import measure_sfr

    a = np.asarray(simulated, dtype=np.float64)
    b = np.asarray(measured, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2:
        raise ValueError(f"edge_offset needs two ROIs of one 2-D shape; got {a.shape} and {b.shape}")
    fa, fb = measure_sfr(a), measure_sfr(b)
    if fa.orientation != fb.orientation:
        raise ValueError(f"the edges differ in orientation ({fa.orientation} against {fb.orientation})")
    axis = 1 if fa.orientation == "vertical" else 0
    mid = (a.shape[0 if axis == 1 else 1] - 1) / 2.0   # the middle line, across the normal
    line = np.polynomial.polynomial.polyval
    return float(line(mid, fb.edge_fit_linear) - line(mid, fa.edge_fit_linear)), axis


def register_edge(simulated, measured) -> tuple[np.ndarray, float]:
    """``simulated`` moved along the edge normal onto ``measured``'s edge
    (:func:`edge_offset`; cubic spline, edge values repeated at the
    border), and the offset applied, pixels."""
    from scipy.ndimage import shift

    off, axis = edge_offset(simulated, measured)
    step = [0.0, 0.0]
    step[axis] = off
    return shift(np.asarray(simulated, dtype=np.float64), step, order=3, mode="nearest"), off


def pixel_residuals(model, space: ParameterSpace, edges, u) -> np.ndarray:
    """Simulated − measured pixels of every edge, concatenated."""
    lens = space.apply(np.asarray(u, dtype=np.float64) * space.tolerance)
    sims = render_edges(model, lens, edges)
    r = np.concatenate([(s - np.asarray(e.image, dtype=np.float64)).ravel() for s, e in zip(sims, edges)])
    return np.where(np.isfinite(r), r, 0.0)


def _worker_state(payload) -> dict:
    """What a fit's worker holds (the executor's setup, once per worker)."""
    from calibration.fit.forward_model import SfrModel

    nominal, obs, settings, names, edges = payload
    return {"model": SfrModel(nominal, obs, settings), "space": parameter_space(nominal, names), "edges": edges}


def _residual_task(u):
    w = worker_payload()
    return pixel_residuals(w["model"], w["space"], w["edges"], u)


def _steps(u: np.ndarray, lower: np.ndarray, upper: np.ndarray, rel: float) -> np.ndarray:
    """Forward-difference steps as scipy's '2-point' with ``diff_step=rel``
    takes them (``rel·sign(u)·max(1, |u|)``), turned back where a step
    would leave the bounds."""
    h = rel * np.where(u >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(u))
    out = (u + h > upper) | (u + h < lower)
    return np.where(out, -h, h)


def fit_pixel_mse(nominal: Lens, obs: Observations, edges, *, names=None, settings=None, max_iter: int = 15,
                  bound_factor: float = 2.0, diff_step: float = 0.1, x0=None,
                  executor: Executor | None = None) -> PixelFit:
    """Fit lens perturbations to measured edge images by pixel MSE.

    Parameters
    ----------
    nominal : Lens
    obs : Observations
        The observations the edges were measured as (their positions,
        orientations and colours give the model's PSFs).
    edges : sequence of SyntheticEdge
        The measured ROIs, one per observation in ``obs``'s order
        (``synthetic_observations(..., return_edges=True)``); anything with
        ``image`` and ``render(psf, pitch_um)`` will do.
    names : sequence of str, optional
        Fitted parameters (default :func:`calibration.fit.proxy.default_names`;
        pass the SFR fit's to compare the two).
    settings : calibration.fit.forward_model.ModelSettings, optional
    max_iter : int
        Iterations (Jacobians) at most: ``max_nfev`` of the solver, which
        counts neither the Jacobian's evaluations nor, on one worker, those
        of its finite differences.
    bound_factor : float
        Bounds in tolerances.
    diff_step : float
        Forward-difference step, tolerances (relative beyond 1).
    x0 : (P,) array_like, optional
        Start, tolerance units (default the nominal lens).
    executor : isp.runtime.executor.Executor, optional
        One worker (default: "serial", in this process): scipy's own finite
        differences (as ``fit_proxy`` with method "scipy"); more: the
        Jacobian's columns on its workers (same steps), each holding the
        model and edges from the payload. Its progress bar counts lens
        evaluations.
    """
    from scipy.optimize import least_squares

    from calibration.fit.forward_model import ModelSettings, SfrModel

    settings = settings or ModelSettings()
    edges = list(edges)
    if len(edges) != len(obs):
        raise ValueError(f"{len(edges)} edge images for {len(obs)} observations")
    t0 = time.perf_counter()
    names = list(names) if names is not None else default_names(nominal)
    model = SfrModel(nominal, obs, settings)
    space = parameter_space(nominal, names)
    n = len(space.names)
    lower, upper = parameter_bounds(space.names, focus_name(nominal), float(bound_factor))
    u0 = np.zeros(n) if x0 is None else np.clip(np.asarray(x0, dtype=np.float64), lower, upper)
    ex = create_executor("serial") if executor is None else executor
    workers = ex.workers
    calls = {"n": 0}
    bar = ex.bar(unit="eval", desc=f"pixel-MSE fit ({n} parameters)")

    def tick(k=1):
        calls["n"] += k
        bar.update(k)

    last, first = {}, {}

    def fun(u):
        tick()
        r = pixel_residuals(model, space, edges, u)
        last["u"], last["r"] = np.array(u, dtype=np.float64), r
        first.setdefault("r", r)
        return r

    pool = None
    if ex.parallel:
        pool = ex.bind((nominal, obs, settings, names, edges), setup=_worker_state)

    def jac(u):
        u = np.asarray(u, dtype=np.float64)
        f0 = last["r"] if "u" in last and np.array_equal(last["u"], u) else fun(u)
        h = _steps(u, lower, upper, diff_step)
        pts = [u + h[j] * np.eye(n)[j] for j in range(n)]
        cols = pool.map(_residual_task, pts)
        tick(n)
        return np.stack([(c - f0) / h[j] for j, c in enumerate(cols)], axis=1)

    try:
        ls = least_squares(fun, u0, jac=jac if pool is not None else "2-point", bounds=(lower, upper),
                           method="trf", diff_step=diff_step, x_scale=1.0, max_nfev=max(1, int(max_iter)))
    finally:
        if pool is not None:
            pool.close()
        bar.close()
    r_nominal = first["r"] if x0 is None else pixel_residuals(model, space, edges, np.zeros(n))
    return PixelFit(nominal, space, np.asarray(ls.x, dtype=np.float64), obs, float(np.mean(r_nominal ** 2)),
                    float(np.mean(ls.fun ** 2)), "pixel-mse", calls["n"], time.perf_counter() - t0,
                    str(ls.message), int(ls.njev or 0),
                    {**dataclasses.asdict(settings), "max_iter": int(max_iter), "diff_step": diff_step,
                     "bound_factor": bound_factor, "workers": workers})

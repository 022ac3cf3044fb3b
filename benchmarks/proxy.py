"""Proxy cameras fitted to synthetic devices (the paper's Table 1).

For each phone lens (``../shared/data/lenses/phone/*.zmx``) and each of
``--devices`` devices:

* **truth**: the lens with every :func:`calibration.fit.proxy.default_names`
  parameter (element decenters and tilts, air gaps, focus) perturbed
  uniformly within ±1 tolerance (seeded); its PSF map
  (``psf_map(grid=GRID, channels=("G",), n=96, pupil_samples=64,
  n_wavelengths=3)``: a 48 µm window, which holds ≥ 98 % of every corner
  PSF, ``benchmarks/psf_window.py``; a 24 µm window cuts up to 13 % off
  and makes the truth itself unreachable for the model) is the device;
* **measurement**: :func:`calibration.fit.synthetic_devices.synthetic_observations`
  — a vertical and a horizontal 5° edge at every region centre, rendered
  exactly through the truth PSFs, noise σ = ``noise``·(1 + r²) (r the
  normalised field radius), measured with ISO 12233;
* **fits**, all from the nominal lens over the same parameters (the
  ``--n-params`` to which SFRA and the LSF asymmetry are most sensitive,
  :func:`calibration.fit.proxy.screen_parameters`, screened once per
  measurement; its time is reported apart):

  - ``nominal``: no fit;
  - ``truth``: no fit either — the device's own lens through the same
    forward model, what a perfect fit would score: the floor the model
    (its PSF window, sampling, wavelengths) leaves;
  - ``pixel``: :func:`calibration.fit.pixel.fit_pixel_mse` — MSE
    between simulated and measured edge images (scipy TRF);
  - ``scipy``: ``fit_proxy(method="scipy")`` — SFRA residuals, scipy TRF
    with the same finite-difference step; ``max_nfev = --max-iter``, which
    TRF counts without its finite differences: about ``--max-iter``
    iterations, as the others;
  - ``scipy_shape``: the same on the shape residuals (below), those of
    ``ours_shape``, the default: the optimiser compared on the same
    residuals and data;
  - ``ours``: ``fit_proxy(method="dls")`` — SFRA residuals, damped least
    squares with dynamic damping (paper Algorithm 1); ``--fast-jacobian``
    takes its Jacobian from a cheaper model (pupil 32 samples), ``--refresh
    K`` re-computes it every K accepted steps only (Broyden updates in
    between), ``--screen-in-fit`` lets ``fit_proxy`` screen (its time then
    includes the screening, whose secants are the fit's first Jacobian);
  - ``ours_bands``: the same with ``residuals="bands"`` (SFRA plus the mean
    SFR in four frequency bands);
  - ``ours_odd``: the same with ``residuals="odd"`` (SFRA plus the LSF's
    asymmetry in four bands, :mod:`calibration.sfr.asymmetry`);
  - ``ours_shape``: SFRA, the four SFR bands and the four asymmetry bands;
    every ``ours`` fit that ends above ``RESTART_CHI2`` χ² per residual
    tries ``--restarts`` other starts (``fit_proxy(restarts=...)``, seeded
    by the device; logged as ``restarts``); the baselines run as their
    libraries give them, from the nominal lens only, except
  - ``scipy_restart``: ``scipy_shape`` with the same restarts as ours (the
    multistart is not tied to the optimiser: this compares the two local
    optimisers on equal terms);
  - ``ours_box``: ``ours_shape`` whose steps are the damped model's
    minimiser inside the ±2-tolerance box (``bounds="box"``,
    :func:`calibration.fit.dls.damped_least_squares`) instead of the clipped
    step;
  - ``ours_prior``: ``ours_shape`` with a Gaussian prior of σ = 1/√3
    tolerance on each perturbation (``fit_proxy(prior=...)``, a maximum a
    posteriori fit).

Per method, at FoV 0.1 / 0.5 / 0.9 (the observations whose normalised
radius is within ±0.1 of it; the nearest radius where none is):

* **SFR MSE ×10⁻³**: mean over those observations of the mean squared
  difference on 0..0.5 cycles/pixel between the fitted lens's noise-free
  SFR (:class:`calibration.fit.forward_model.SfrModel`) and the measured SFR;
  ``SFR MSE truth`` is the same against the truth lens's noise-free SFR
  through the same model (the part of the error the measurement's noise
  does not hide);
* **SSIM** (``skimage.metrics.structural_similarity``, data range 1, the
  0..1 signal scale) between the edge ROI simulated through the fitted
  lens and the measured (noisy) one;
* **registered SSIM**: the same after moving each simulated edge along its
  normal onto the measured one, by the offset of the two edges as ISO
  12233 locates them (:func:`calibration.fit.pixel.register_edge`;
  ``|offset| px`` the mean size of that move). The plain SSIM also scores
  each edge's sub-pixel position, which a chart capture does not fix and
  which the forward model's own approximations (its PSF window and pupil
  sampling against the truth's) shift by up to ~0.2 px in the corners:
  the truth lens itself is that far off there. A fit that moves its edges
  there by bending the lens scores higher on the plain SSIM than the truth
  does; the registered SSIM judges the blur alone;
* **SSIM as device** (``ssim_device``): the fitted lens's edges rendered
  the way the devices were (:func:`render_as_device`: its PSF map at
  :data:`DEVICE_MAP`'s settings), not through the fits' forward model. A
  proxy camera is used through its PSF map (``isp synth``), so this is the
  SSIM of what it will simulate; the truth lens scores its own noise-free
  edges here exactly;
* fit time (s) and lens evaluations (``ours`` evaluates its Jacobian on
  ``--workers`` processes; ``scipy`` and ``pixel`` — ``--pixel-workers`` 1 —
  run scipy's own finite differences in one process).

``--from-json`` and ``--rescore`` read earlier runs: a log whose last line
is the run's JSON, or the ``benchmarks/results/proxy.json`` a run wrote.

``--rescore LOG...`` fits nothing: it measures every logged fit again (the
devices drawn again from the logged seeds, each method's lens from its
logged parameters) with today's figures, e.g. the registered SSIM on logs
that predate it, after checking that the logged SFR MSE and SSIM come back.
It needs the original run's ``--lenses`` (a device's seed holds its
lens's place in that list), ``--grid`` and ``--noise-growth``.

``--noise`` takes several levels for a noise sweep: each device is measured
at each level and fitted again; a summary table shows how the errors of
``ours`` and ``pixel`` grow with the noise.

Prints a table per device, the summaries (over all devices and, with
several lenses, per lens: the figures of the results pages' tables), and one JSON
object as the LAST line. Usage::

    python -m benchmarks.proxy [--lenses e9 e2] [--devices 2] [--grid 5 7]
                               [--noise 0.004] [--methods nominal pixel scipy ours]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # one BLAS thread per fit worker, before numpy loads; not when a test imports it
    _harness.pin_threads(2, blas=1)

import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = _harness.ROOT

from calibration.optics.io import read_lens  # noqa: E402
from calibration.fit.proxy import (COARSE_GRID, N_PARAMS, RESTART_CHI2, RESTARTS, ProxyFitSettings,  # noqa: E402
                                   default_names, fit_proxy, parameter_space, residual_bias, screen_parameters)
from calibration.fit.pixel import fit_pixel_mse, register_edge, render_edges  # noqa: E402
from calibration.fit.synthetic_devices import synthetic_observations  # noqa: E402
from calibration.optics.psf.map import PSFMapSettings, psf_map  # noqa: E402
from calibration.fit.forward_model import FAST_JACOBIAN, ModelSettings, SfrModel  # noqa: E402
from isp.runtime.executor import pool_executor  # noqa: E402

LENS_DIR = ROOT.parent / "shared" / "data" / "lenses" / "phone"
GRID = (5, 7)
FOVS = (0.1, 0.5, 0.9)
FOV_WINDOW = 0.1
METHODS = ("nominal", "truth", "pixel", "scipy", "scipy_shape", "scipy_restart", "ours", "ours_bands", "ours_odd",
           "ours_shape", "ours_box", "ours_prior")
NYQUIST = 0.5
#: residuals of the methods whose name does not end in them
RESIDUALS = {"ours_box": "shape", "ours_prior": "shape", "scipy_restart": "shape"}
#: ours_prior's Gaussian prior on each perturbation, tolerances: the spread of one uniform within ±1
PRIOR_SIGMA = 1.0 / np.sqrt(3.0)
#: every fit's box, in tolerances (fit_proxy's and fit_pixel_mse's ``bound_factor``)
BOUND = 2.0
#: the figures of :func:`metrics`, each per FoV and "all"
FIGURES = ("sfr_mse", "sfr_mse_truth", "ssim", "ssim_registered", "edge_offset_px", "ssim_device")


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _names_lens(token: str, stem: str) -> bool:
    """A lens token (``e9``, or the file's whole stem) names exactly this lens."""
    return stem.split("-")[-1].lower() == token.lower() or stem == token


def _is_case(token: str, lens_name: str, device: int) -> bool:
    """``--only`` token ``LENS:DEVICE`` (LENS as in ``--lenses``) names this case."""
    lens, _, dev = token.rpartition(":")
    return dev == str(device) and _names_lens(lens, lens_name)


def pick_lenses(tokens) -> list[Path]:
    files = sorted(LENS_DIR.glob("*.zmx"))
    if not tokens:
        return files
    out = []
    for t in tokens:
        exact = [f for f in files if _names_lens(t, f.stem)]
        hits = exact or [f for f in files if t.lower() in f.name.lower()]
        if not hits:
            print(f"lens {t!r}: no .zmx in {LENS_DIR} matches; skipped")
        out += [h for h in hits if h not in out]
    return out


def fov_sets(radius: np.ndarray) -> dict[float, np.ndarray]:
    """Observation indices per FoV: radius within ±FOV_WINDOW, else the nearest radius."""
    out = {}
    for f in FOVS:
        d = np.abs(radius - f)
        sel = np.flatnonzero(d <= FOV_WINDOW + 1e-9)
        if sel.size == 0:
            sel = np.flatnonzero(d <= d.min() + 1e-9)
        out[f] = sel
    return out


def metrics(model: SfrModel, lens, obs, edges, truth_sfr, sets, grid) -> dict:
    """SFR MSE (vs measured and vs truth) and SSIM per FoV for ``lens``,
    and the SSIM of its edges rendered as the devices on ``grid`` are
    (:func:`render_as_device`)."""
    from skimage.metrics import structural_similarity

    band = obs.freq <= NYQUIST + 1e-12
    pred = model.predict(lens).sfr[:, band]
    meas = np.asarray(obs.sfr)[:, band]
    mse_meas = np.nanmean((pred - meas) ** 2, axis=1)
    mse_truth = np.nanmean((pred - truth_sfr[:, band]) ** 2, axis=1)
    sims = render_edges(model, lens, edges)
    images = [np.asarray(e.image, dtype=np.float64) for e in edges]
    ssim = np.array([structural_similarity(s, m, data_range=1.0) for s, m in zip(sims, images)])
    moved = [register_edge(s, m) for s, m in zip(sims, images)]
    ssim_reg = np.array([structural_similarity(s, m, data_range=1.0) for (s, _), m in zip(moved, images)])
    offset = np.abs([o for _, o in moved])
    ssim_dev = np.array([structural_similarity(s, m, data_range=1.0)
                         for s, m in zip(render_as_device(lens, edges, grid), images)])
    out = {key: {} for key in FIGURES}
    for k, sel in [(f"{f:g}", sel) for f, sel in sets.items()] + [("all", slice(None))]:
        out["sfr_mse"][k] = float(np.nanmean(mse_meas[sel]))
        out["sfr_mse_truth"][k] = float(np.nanmean(mse_truth[sel]))
        out["ssim"][k] = float(np.mean(ssim[sel]))
        out["ssim_registered"][k] = float(np.mean(ssim_reg[sel]))
        out["edge_offset_px"][k] = float(np.mean(offset[sel]))
        out["ssim_device"][k] = float(np.mean(ssim_dev[sel]))
    return out


def screen(model, names, n_params, bias, workers) -> list[str]:
    """screen_parameters with the Jacobian's evaluations on fit_proxy's pool."""
    if n_params is None or len(names) <= n_params:
        return list(names)
    if workers <= 1:
        return screen_parameters(model, names, n_params, bias=bias)
    from calibration.fit import proxy as _proxy   # fit_proxy's own worker set-up and task

    payload = (model.nominal, model.obs, model.settings, names, bias)
    with pool_executor(workers).bind(payload, setup=_proxy.worker_models) as pool:
        return screen_parameters(model, names, n_params, bias=bias,
                                 fun_many=lambda pts: pool.map(_proxy.residual_task, list(pts)))


#: how a device's edges are rendered: its PSF map, wider and finer than the fits' forward model
DEVICE_MAP = dict(channels=("G",), n=96, pupil_samples=64, n_wavelengths=3)


def device_map(lens, grid):
    """``lens``'s PSF map as the benchmark renders a device (:data:`DEVICE_MAP`)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pool_executor(None) as ex:
            pm = psf_map(lens, PSFMapSettings(grid=tuple(grid), **DEVICE_MAP), executor=ex)
    for w in caught:
        log(f"  warning: {w.message}")
    return pm


def draw_device(space, seed: int, lens_index: int, device: int, grid):
    """Device ``device`` of the lens at ``lens_index`` of ``--lenses``: its
    perturbations (tolerance units, uniform in ±1, seeded by ``seed``, the
    lens's place and the device's index), its lens and its truth PSF map."""
    u_true = np.random.default_rng([seed, lens_index, device]).uniform(-1.0, 1.0, len(space.names))
    truth = space.apply(u_true * space.tolerance)
    return u_true, truth, device_map(truth, grid)


def render_as_device(lens, edges, grid) -> list[np.ndarray]:
    """Each edge's noise-free ROI through ``lens`` rendered as the devices
    are (:func:`device_map`, the PSF of the edge's region), not through the
    fits' forward model: what a proxy camera is used for downstream
    (``isp synth`` renders through its PSF map)."""
    from calibration.fit.synthetic_devices import edge_sites

    pm = device_map(lens, grid)
    region = {(round(x, 6), round(y, 6)): (r, k) for r, k, x, y in edge_sites(pm.sensor, grid)}
    out = []
    for e in edges:
        r, k = region[(round(e.center_px[0], 6), round(e.center_px[1], 6))]
        out.append(e.render(pm.psf(r, k, e.channel).data, pm.pitch_um))
    return out


def observe(pm, noise: float, seed: int, lens_index: int, device: int, noise_index: int, noise_growth: float):
    """The device's edges measured at ``noise`` (seeded as the fits saw them): observations and edges."""
    return synthetic_observations(pm, noise=noise, noise_growth=noise_growth,
                                  rng=[seed, lens_index, device, noise_index], return_edges=True)


def rescore(cases: list[dict], args, settings) -> list[dict]:
    """Every logged fit of ``cases`` measured again with today's
    :func:`metrics` (module docstring, ``--rescore``). The devices are drawn
    again from the seeds; a device whose perturbations differ from the
    logged ones (another ``--lenses`` order or ``--seed``) stops the run."""
    paths = {p.stem: (i, p) for i, p in enumerate(pick_lenses(args.lenses))}
    grid = (int(args.grid[0]), int(args.grid[1]))
    worst = {"sfr_mse_rel": 0.0, "ssim_abs": 0.0}
    for case in cases:
        name, d = case["lens"], case["device"]
        if name not in paths:
            raise SystemExit(f"{name}: not among --lenses {args.lenses}; give the original run's --lenses")
        li, path = paths[name]
        lens = read_lens(path)
        space = parameter_space(lens, default_names(lens))
        log(f"{name} device {d}: drawn again, noise {case['noise']:g}")
        u_true, truth, pm = draw_device(space, args.seed, li, d, grid)
        if not np.allclose(u_true, case["u_true"], atol=1e-4):
            raise SystemExit(f"{name} device {d}: the seeds draw other perturbations than the log's; "
                             "give the original run's --lenses and --seed")
        noise_index = args.noise.index(case["noise"]) if case["noise"] in args.noise else 0
        obs, edges = observe(pm, case["noise"], args.seed, li, d, noise_index, args.noise_growth)
        model = SfrModel(lens, obs, settings)
        sets = fov_sets(np.asarray(obs.radius))
        truth_sfr = model.predict(truth).sfr
        for m, rec in case["methods"].items():
            if m == "nominal":
                fitted = lens
            elif m == "truth":
                fitted = truth
            else:
                sub = parameter_space(lens, rec.get("names", case["names"]))
                fitted = sub.apply(np.asarray(rec["u"]) * sub.tolerance)
            new = metrics(model, fitted, obs, edges, truth_sfr, sets, grid)
            # the log's parameters are rounded to 1e-4 tolerance: the figures come back close, not exact
            for k, v in rec["sfr_mse"].items():
                worst["sfr_mse_rel"] = max(worst["sfr_mse_rel"], abs(new["sfr_mse"][k] / v - 1.0))
            for k, v in rec["ssim"].items():
                worst["ssim_abs"] = max(worst["ssim_abs"], abs(new["ssim"][k] - v))
            rec.update(new)
    log(f"rescored {len(cases)} case(s): logged figures came back within {worst['sfr_mse_rel']:.2%} (SFR MSE) "
        f"and {worst['ssim_abs']:.1e} (SSIM)")
    return cases


def run_case(lens, pm, truth_lens, noise, seed, args, settings) -> dict:
    """One measurement of one device at one noise level, all methods."""
    t0 = time.perf_counter()
    obs, edges = observe(pm, noise, *seed, args.noise_growth)
    t_obs = time.perf_counter() - t0
    model = SfrModel(lens, obs, settings)
    sets = fov_sets(np.asarray(obs.radius))
    truth_sfr = model.predict(truth_lens).sfr
    t0 = time.perf_counter()
    # screened once for every method, on all the measurement holds (SFRA and the LSF's asymmetry)
    with pool_executor(args.workers) as ex:
        bias = residual_bias(model, lens, "odd", ex)
    names = screen(model, default_names(lens), args.n_params, bias, args.workers)
    t_screen = time.perf_counter() - t0
    case = {"observations": len(obs), "noise": noise, "names": names, "seconds_observe": round(t_obs, 2),
            "seconds_screen": round(t_screen, 2), "fov_radius": {f"{f:g}": [float(np.min(obs.radius[s])),
                                                                             float(np.max(obs.radius[s]))]
                                                                  for f, s in sets.items()},
            "methods": {}}
    for m in args.methods:
        log(f"    {m} ...")
        t0 = time.perf_counter()
        stop, extra = "", {}
        if m == "nominal":
            fitted, evals, secs, u = lens, 0, 0.0, np.zeros(len(names))
        elif m == "truth":
            fitted, evals, secs, u = truth_lens, 0, 0.0, np.zeros(len(names))
        elif m == "pixel":
            with pool_executor(args.pixel_workers) as ex:
                fit = fit_pixel_mse(lens, obs, edges, names=names, settings=settings, max_iter=args.max_iter,
                                    executor=ex)
            fitted, evals, secs, u, stop = fit.lens, fit.evaluations, fit.seconds, fit.u, fit.message
            extra = {"pixel_mse_before": fit.mse_before, "pixel_mse_after": fit.mse_after}
        elif m.startswith(("scipy", "ours")):
            iters = args.max_iter
            if m.startswith("scipy"):
                # fit_proxy's scipy max_iter is scipy's max_nfev, which TRF counts without its
                # finite differences: about max_iter iterations, as the others
                iters = args.scipy_max_iter or args.max_iter
                extra = {"scipy_max_nfev": iters}
            ours = m.startswith("ours")
            fast = FAST_JACOBIAN if (ours and args.fast_jacobian) else None
            own = ours and args.screen_in_fit   # fit_proxy screens itself: its time counts it
            cfg = ProxyFitSettings(
                model=settings, method="dls" if ours else "scipy", max_iter=iters, n_params=args.n_params,
                residuals=residuals_of(m), jacobian_model=fast, refresh=args.refresh if ours else 1,
                bounds="box" if m == "ours_box" else "clip", prior=PRIOR_SIGMA if m == "ours_prior" else None,
                restarts=args.restarts if (ours or m == "scipy_restart") else 0,
                coarse=(tuple(args.coarse) if (ours or m == "scipy_restart") and args.coarse[0] > 0 else None),
                seed=int(np.random.SeedSequence(seed).generate_state(1)[0]))
            with pool_executor(args.workers if ours else 1) as ex:
                fit = fit_proxy(lens, obs, cfg, names=None if own else names, executor=ex)
            fitted, evals, secs, u = fit.lens, fit.evaluations, fit.seconds, fit.u
            if fit.restarts:
                extra["restarts"] = fit.restarts
            if fit.coarse:
                extra["coarse"] = fit.coarse
            stop = fit.result.reason if fit.result is not None else ""
            if fit.result is not None:
                extra["merit"] = round(fit.result.merit, 3)   # the fit's own objective, on its residuals
            if fit.result is not None and fit.result.history:
                extra["merit_history"] = [round(float(h["merit"]), 3) for h in fit.result.history]
            if own:
                extra["names"] = list(fit.space.names)
            e = fit.errors()
            extra = {**extra, "sfra_rms_before": e["before"]["sfra_rms"], "sfra_rms_after": e["after"]["sfra_rms"],
                     "chi2_before": e["before"]["chi2_per_obs"], "chi2_after": e["after"]["chi2_per_obs"]}
        else:
            raise ValueError(f"unknown method {m!r}; valid: {', '.join(METHODS)}")
        rec = metrics(model, fitted, obs, edges, truth_sfr, sets, (int(args.grid[0]), int(args.grid[1])))
        rec.update({"seconds": round(float(secs), 2), "evaluations": int(evals), "stop": str(stop),
                    "u": [round(float(v), 4) for v in u], "wall_s": round(time.perf_counter() - t0, 2), **extra})
        case["methods"][m] = rec
        log(f"    {m}: {secs:.1f} s, {evals} evaluations, SFR MSE ×1e-3 "
            f"{rec['sfr_mse']['all'] * 1e3:.3f}, SSIM {rec['ssim']['all']:.4f} {stop}")
    return case


def table(case: dict, title: str) -> str:
    fk = [f"{f:g}" for f in FOVS]
    head = (f"{'method':<11} | " + " ".join(f"{'MSE@' + k:>8}" for k in fk) + " | "
            + " ".join(f"{'truth@' + k:>9}" for k in fk) + " | " + " ".join(f"{'SSIM@' + k:>9}" for k in fk)
            + f" | {'time s':>7} {'evals':>6}")
    lines = [title, "SFR MSE ×10⁻³ vs measured (MSE) and vs the truth lens's noise-free SFR (truth); SSIM of edge images",
             head, "-" * len(head)]
    for m, r in case["methods"].items():
        lines.append(f"{m:<11} | " + " ".join(f"{r['sfr_mse'][k] * 1e3:8.3f}" for k in fk) + " | "
                     + " ".join(f"{r['sfr_mse_truth'][k] * 1e3:9.3f}" for k in fk) + " | "
                     + " ".join(f"{r['ssim'][k]:9.4f}" for k in fk) + f" | {r['seconds']:7.1f} {r['evaluations']:6d}")
    rad = ", ".join(f"{k}: r {lo:.2f}–{hi:.2f}" for k, (lo, hi) in case["fov_radius"].items())
    lines.append(f"({case['observations']} observations; FoV sets {rad}; screening {case['seconds_screen']} s; "
                 f"{len(case['names'])} parameters)")
    return "\n".join(lines)


def summarise(cases: list[dict], methods) -> dict:
    """Mean of every figure over the cases, per noise level and method."""
    out = {}
    for noise in sorted({c["noise"] for c in cases}):
        sel = [c for c in cases if c["noise"] == noise]
        per = {}
        for m in methods:
            rs = [c["methods"][m] for c in sel if m in c["methods"]]
            if not rs:
                continue
            # the registered SSIM and edge offsets only where every case has them (older logs do not)
            keys = [key for key in FIGURES if all(key in r for r in rs)]
            per[m] = {key: {k: float(np.mean([r[key][k] for r in rs])) for k in rs[0][key]} for key in keys}
            per[m]["seconds"] = float(np.mean([r["seconds"] for r in rs]))
            per[m]["evaluations"] = float(np.mean([r["evaluations"] for r in rs]))
            per[m]["cases"] = len(rs)
            # fitted parameters left on the box (u is stored to 1e-4): fewest and most over the cases
            on_box = [int(np.sum(np.abs(r["u"]) >= BOUND - 1e-3)) for r in rs]
            per[m]["at_bounds"] = [min(on_box), max(on_box)]
        out[f"{noise:g}"] = per
    return out


def _run_of(path) -> dict:
    """The results of one earlier run: a results file (``proxy.json``) or a
    log whose last JSON line is the run's record (or, from runs before the
    harness, its results alone)."""
    text = Path(path).read_text()
    try:
        rec = json.loads(text)
    except json.JSONDecodeError:
        lines = [ln for ln in text.splitlines() if ln.startswith("{")]
        if not lines:
            raise SystemExit(f"{path}: no JSON line (not a benchmarks/proxy.py log?)") from None
        rec = json.loads(lines[-1])
    rec = rec.get("results", rec) if isinstance(rec, dict) else {}
    if "cases" not in rec:
        raise SystemExit(f"{path}: no cases (not a benchmarks/proxy.py log or result?)")
    return rec


def load_cases(paths) -> tuple[list[dict], list[str]]:
    """The cases of earlier runs (:func:`_run_of`; one device measured at
    one noise in several runs, with other methods, is one case) and the
    union of their methods, in :data:`METHODS` order. The runs must have
    drawn the same devices (same ``--lenses`` and ``--seed``)."""
    merged: dict[tuple, dict] = {}
    for p in paths:
        for c in _run_of(p)["cases"]:
            # the same seeded device in two runs (other methods): one case
            key = (c["lens"], c["device"], c["noise"])
            if key in merged:
                merged[key]["methods"].update(c["methods"])
            else:
                merged[key] = c
    cases = list(merged.values())
    seen = {m for c in cases for m in c["methods"]}
    return cases, [m for m in METHODS if m in seen]


#: non-inferiority margins of :func:`paired`: ``ref`` may trail another method by
#: at most 10 % in SFR MSE or 0.005 in edge-image SSIM (at the 95 % bound)
MARGINS = {"sfr_mse": float(np.log(1.10)), "ssim": 0.005, "ssim_registered": 0.005, "ssim_device": 0.005}


def paired(cases: list[dict], ref: str, methods, level: float = 0.95, margins=None) -> dict:
    """``ref`` against every other method, device by device, per lens and FoV
    (and over all lenses): is it better, worse, or not distinguishable?

    A mean over a few devices is the worst device's figure, so the
    comparison is paired: for SFR MSE the per-device log ratio ``ln(other /
    ref)`` (> 0: ``ref`` closer), for SSIM the difference ``ref − other``;
    their mean with a Student-t interval at ``level`` over the devices.
    ``verdict``: ``better`` / ``worse`` when the interval excludes 0, else
    ``tied`` (the devices do not tell the two apart). ``noninferior``: the
    interval's lower end is above ``−margin`` (:data:`MARGINS`), i.e.
    ``ref`` is shown to be at most a margin behind; over few devices that
    fails for most cells even where ``verdict`` is ``tied``. Also the
    geometric-mean ratio and how many devices ``ref`` wins. Returns ``{key:
    {lens or "all": {fov: {method: {...}}}}}``.
    """
    from scipy.stats import t as student_t

    margins = MARGINS if margins is None else margins
    out = {}
    groups = {name: [c for c in cases if c["lens"] == name] for name in sorted({c["lens"] for c in cases})}
    if len(groups) > 1:
        groups["all"] = list(cases)
    for key in MARGINS:
        if not all(key in r for c in cases for r in c["methods"].values()):
            continue   # a figure older logs lack
        out[key] = {}
        for name, sel in groups.items():
            per_fov = {}
            for k in [f"{f:g}" for f in FOVS]:
                cells = {}
                for m in methods:
                    if m in (ref, "nominal", "truth"):
                        continue
                    pairs = [(c["methods"][m][key][k], c["methods"][ref][key][k]) for c in sel
                             if m in c["methods"] and ref in c["methods"]]
                    if not pairs:
                        continue
                    o, r = np.array(pairs, dtype=float).T
                    d = np.log(o / r) if key == "sfr_mse" else r - o
                    n = d.size
                    half = (float(student_t.ppf(0.5 + level / 2, n - 1) * d.std(ddof=1) / np.sqrt(n))
                            if n > 1 else float("inf"))
                    mean = float(d.mean())
                    verdict = "better" if mean - half > 0 else "worse" if mean + half < 0 else "tied"
                    cells[m] = {"n": n, "mean": mean, "half_width": half, "verdict": verdict,
                                "noninferior": bool(mean - half > -margins[key]), "wins": int(np.sum(d > 0))}
                    if key == "sfr_mse":
                        cells[m]["ratio"] = float(np.exp(mean))   # geometric mean of other / ref
                per_fov[k] = cells
            out[key][name] = per_fov
    return out


def residuals_of(method: str) -> str:
    """The residuals a fitting method minimises ("pixel" for the pixel fit)."""
    if method == "pixel":
        return "pixel"
    return RESIDUALS.get(method, method.partition("_")[2] or "sfra")


def merit_comparison(cases: list[dict], ref: str, methods) -> dict:
    """The fits' own objective, where it is the same one: for each method
    that minimises ``ref``'s residuals without a prior (``ours_prior``'s
    merit holds its prior's terms), the devices on which ``ref`` ends at the
    lower merit and the geometric-mean merit ratio other / ref. A fit can
    end lower on its merit and still further from the measurement at one
    FoV: the merit weighs every observation by its uncertainty."""
    out = {}
    for m in methods:
        if m == ref or m == "ours_prior" or residuals_of(m) != residuals_of(ref):
            continue
        pairs = [(c["methods"][m]["merit"], c["methods"][ref]["merit"]) for c in cases
                 if "merit" in c["methods"].get(m, {}) and "merit" in c["methods"].get(ref, {})]
        if pairs:
            o, r = np.array(pairs, dtype=float).T
            out[m] = {"n": len(pairs), "ref_lower": int(np.sum(r < o)), "ratio": float(np.exp(np.mean(np.log(o / r))))}
    return out


def print_paired(comp: dict, ref: str) -> None:
    """:func:`paired` as lines: ratio (other / ref), interval, wins, verdict."""
    print(f"\nPaired, {ref} against each method (SFR MSE: geometric-mean ratio other/{ref}, 95 % interval "
          f"over devices; SSIM: mean {ref} − other; INFERIOR: {ref} trails by more than the margin, "
          f"{np.exp(MARGINS['sfr_mse']) - 1:.0%} in SFR MSE, {MARGINS['ssim']} in SSIM; ssim_registered: "
          f"the SSIM with each simulated edge moved onto the measured one; ssim_device: the edges rendered "
          f"as the devices are)")
    for key, per in comp.items():
        for name, per_fov in per.items():
            for k, cells in per_fov.items():
                parts = []
                for m, c in cells.items():
                    if key == "sfr_mse":
                        lo, hi = np.exp(c["mean"] - c["half_width"]), np.exp(c["mean"] + c["half_width"])
                        size = f"{c['ratio']:.2f}× [{lo:.2f}, {hi:.2f}]"
                    else:
                        size = f"{c['mean']:+.4f} ±{c['half_width']:.4f}"
                    parts.append(f"{m} {size} {c['wins']}/{c['n']} {c['verdict']}"
                                 + ("" if c["noninferior"] else " INFERIOR"))
                print(f"  {key:<7} {name[-4:]:>5} FoV {k}: " + "; ".join(parts))


def print_summary(summary: dict, title: str) -> None:
    """The means of :func:`summarise`, a line per noise level and method."""
    fk = [f"{f:g}" for f in FOVS]
    print(f"\nSummary: {title}")
    for noise, per in summary.items():
        print(f"noise {noise}")
        for m, r in per.items():
            print(f"  {m:<11} SFR MSE×1e-3 " + " ".join(f"{r['sfr_mse'][k] * 1e3:7.3f}" for k in fk)
                  + "   truth " + " ".join(f"{r['sfr_mse_truth'][k] * 1e3:7.3f}" for k in fk)
                  + "   SSIM " + " ".join(f"{r['ssim'][k]:.4f}" for k in fk)
                  + ("   registered " + " ".join(f"{r['ssim_registered'][k]:.4f}" for k in fk)
                     + "   |offset| px " + " ".join(f"{r['edge_offset_px'][k]:.3f}" for k in fk)
                     if "ssim_registered" in r else "")
                  + ("   as device " + " ".join(f"{r['ssim_device'][k]:.4f}" for k in fk)
                     if "ssim_device" in r else "")
                  + f"   {r['seconds']:6.1f} s {r['evaluations']:6.0f} evals"
                  + f"   on the bounds {r['at_bounds'][0]}–{r['at_bounds'][1]}")


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--lenses", nargs="*", default=None,
                    help="lens tokens (e9, e2, e1, e11) or name parts; default all in ../shared/data/lenses/phone")
    ap.add_argument("--devices", type=int, default=2, help="perturbed devices per lens")
    ap.add_argument("--first-device", type=int, default=0,
                    help="index of the first device (seeded by lens, index): devices 3..5 of a lens are "
                         "`--first-device 3 --devices 3`, the same devices a `--devices 6` run draws")
    ap.add_argument("--only", nargs="+", default=None, metavar="LENS:DEVICE",
                    help="fit only these devices of the run the other options describe, seeded as in it "
                         "(a device's seed is its lens's place in --lenses and its index), e.g. "
                         "`--lenses e1 e2 e9 e11 --devices 6 --only e11:0 e1:4` re-runs two of its 24 devices")
    ap.add_argument("--from-json", nargs="+", type=Path, default=None, metavar="LOG",
                    help="no fits: summarise the cases of earlier runs (the JSON on each LOG's last line), "
                         "e.g. two shards of devices")
    ap.add_argument("--rescore", nargs="+", type=Path, default=None, metavar="LOG",
                    help="no fits: measure the logged fits of earlier runs again with today's figures (the "
                         "devices drawn again from the seeds: give the runs' own --lenses, --grid, --noise)")
    ap.add_argument("--ref", default="ours_shape", choices=METHODS,
                    help="the method the paired comparison holds against the others (default ours_shape)")
    ap.add_argument("--grid", type=int, nargs=2, default=list(GRID), metavar=("R", "C"),
                    help="field grid of the truth PSF map and the edges (paper: 15 20)")
    ap.add_argument("--noise", type=float, nargs="+", default=[0.004],
                    help="noise σ at the centre (0..1); several for a noise sweep")
    ap.add_argument("--noise-growth", type=float, default=1.0)
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--n-params", type=int, default=N_PARAMS,
                    help=f"fitted parameters (screened; default {N_PARAMS}); 0: all")
    ap.add_argument("--max-iter", type=int, default=15, help="iterations per fit (one Jacobian each with --refresh 1)")
    ap.add_argument("--scipy-max-iter", type=int, default=None,
                    help="fit_proxy max_iter for scipy (its max_nfev: about this many TRF iterations); "
                         "default --max-iter, as the others")
    ap.add_argument("--restarts", type=int, default=RESTARTS,
                    help=f"ours and scipy_restart: starts tried when a fit ends above {RESTART_CHI2:g} χ² per "
                         f"residual (fit_proxy's restarts; default {RESTARTS}, 0: none; the other baselines "
                         f"run without)")
    ap.add_argument("--coarse", type=int, nargs=2, default=list(COARSE_GRID), metavar=("R", "C"),
                    help=f"ours and scipy_restart: fit first on an R × C sub-grid of the regions, then refine on "
                         f"all (fit_proxy's coarse; default {COARSE_GRID[0]} {COARSE_GRID[1]}, only where it at "
                         f"least halves the observations: not at 5 × 7; 0 0: off)")
    ap.add_argument("--workers", type=int, default=2, help="processes for ours' Jacobian and the screening")
    ap.add_argument("--pixel-workers", type=int, default=1,
                    help="processes for the pixel fit's Jacobian (1: scipy's own, as the scipy baseline)")
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--fast-jacobian", action="store_true",
                    help="ours: Jacobian from a cheaper model (pupil 32 samples; steps still judged on the full model)")
    ap.add_argument("--refresh", type=int, default=1,
                    help="ours: a finite-difference Jacobian every REFRESH accepted steps, Broyden updates "
                         "in between (default 1, every step: the methods compared at equal iterations; "
                         "fit_proxy's own default is calibration.fit.proxy.REFRESH with more iterations)")
    ap.add_argument("--screen-in-fit", action="store_true",
                    help="ours: fit_proxy screens the parameters itself (with the Jacobian's model, its "
                         "secants the fit's first Jacobian), so the reported fit time includes the screening, "
                         "as `isp calib fit` runs it")
    args = ap.parse_args(argv)
    args.n_params = None if args.n_params <= 0 else args.n_params
    grid = (int(args.grid[0]), int(args.grid[1]))
    settings = ModelSettings()
    result = {"fast_jacobian": bool(args.fast_jacobian), "refresh": args.refresh, "grid": list(grid), "noise": args.noise, "devices": args.devices, "methods": args.methods,
              "max_iter": args.max_iter, "n_params": args.n_params, "seed": args.seed, "cases": [], "skipped": []}
    if not LENS_DIR.is_dir() and not args.from_json:
        raise SystemExit(f"proxy: {LENS_DIR} not found (the shared data folder is needed)")
    cases = []
    t_all = time.perf_counter()
    if args.from_json or args.rescore:
        cases, methods = load_cases(args.from_json or args.rescore)
        args.methods = result["methods"] = methods
        if args.rescore:
            cases = rescore(cases, args, settings)
    for li, path in enumerate([] if (args.from_json or args.rescore) else pick_lenses(args.lenses)):
        name = path.stem
        try:
            lens = read_lens(path)
            all_names = default_names(lens)
            space = parameter_space(lens, all_names)
        except Exception as exc:   # noqa: BLE001 — a lens the toolkit cannot read or perturb: report, go on
            print(f"{name}: skipped ({type(exc).__name__}: {exc})")
            result["skipped"].append({"lens": name, "reason": f"{type(exc).__name__}: {exc}"})
            continue
        for d in range(args.first_device, args.first_device + args.devices):
            if args.only and not any(_is_case(t, name, d) for t in args.only):
                continue
            try:
                log(f"{name} device {d}: truth PSF map {grid[0]}×{grid[1]}")
                u_true, truth, pm = draw_device(space, args.seed, li, d, grid)
                for ni, noise in enumerate(args.noise):
                    log(f"  noise {noise:g}")
                    case = run_case(lens, pm, truth, noise, [args.seed, li, d, ni], args, settings)
                    case.update({"lens": name, "device": d, "u_true": [round(float(v), 4) for v in u_true],
                                 "all_names": all_names})
                    cases.append(case)
                    print(table(case, f"\n{name}  device {d}  noise {noise:g}  grid {grid[0]}×{grid[1]}"), flush=True)
            except Exception as exc:   # noqa: BLE001
                traceback.print_exc(file=sys.stderr)
                print(f"{name} device {d}: failed ({type(exc).__name__}: {exc})")
                result["skipped"].append({"lens": name, "device": d, "reason": f"{type(exc).__name__}: {exc}"})
    summary = summarise(cases, args.methods)
    print_summary(summary, f"mean over {len({(c['lens'], c['device']) for c in cases})} device(s)")
    lenses = sorted({c["lens"] for c in cases})
    by_lens = {}
    if len(lenses) > 1:   # the paper's table is per lens: the mean over each lens's devices
        for name in lenses:
            sel = [c for c in cases if c["lens"] == name]
            by_lens[name] = summarise(sel, args.methods)
            print_summary(by_lens[name], f"{name}, mean over {len(sel)} case(s)")
    comparison = None
    if args.ref in args.methods and len(args.methods) > 1 and cases:
        comparison = paired(cases, args.ref, args.methods)
        print_paired(comparison, args.ref)
        comparison["merit"] = merit_comparison(cases, args.ref, args.methods)
        for m, c in comparison["merit"].items():
            print(f"  merit   {args.ref} lower than {m} on {c['ref_lower']}/{c['n']} devices "
                  f"(geometric-mean ratio {m}/{args.ref} {c['ratio']:.3f})")
    if len(summary) > 1:
        # --ref (ours_shape by default; the sweep once printed a method "ours" that no run had)
        print("\nNoise sweep: SFR MSE ×10⁻³ vs the measurement and vs truth (all FoV), SSIM (all FoV)")
        print(f"{'noise':>7} " + " ".join(f"{m + ' meas':>18} {m + ' truth':>18} {m + ' SSIM':>17}"
                                        for m in (args.ref, "pixel")))
        for noise, per in summary.items():
            cells = []
            for m in (args.ref, "pixel"):
                r = per.get(m)
                cells.append(f"{r['sfr_mse']['all'] * 1e3:18.3f} {r['sfr_mse_truth']['all'] * 1e3:18.3f} "
                             f"{r['ssim']['all']:17.4f}" if r else f"{'-':>18} {'-':>18} {'-':>17}")
            print(f"{noise:>7} " + " ".join(cells))
    result["cases"] = cases
    result["summary"] = summary
    if by_lens:
        result["summary_by_lens"] = by_lens
    if comparison:
        result["paired"] = comparison
    result["seconds"] = round(time.perf_counter() - t_all, 1)
    return _harness.publish("proxy", result, args, argv)


if __name__ == "__main__":
    main()

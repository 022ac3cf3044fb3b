"""``isp calib fit``: a proxy camera fitted to a measurement (paper §3.2,
Algorithm 1) — the lens file plus the perturbation that makes its simulated
slanted-edge SFR match the measured one.

Reads the measurement as ``isp calib loop`` does (a chart capture, the JSON
of ``isp calib sfr`` or an ``sfr-observations/v1`` file), fits with
:func:`calibration.fit.proxy.fit_proxy` and writes, into one folder (built in a
temporary folder and renamed, so a failed fit leaves nothing):

* ``proxy.json``: lens/v1 with the fitted ``perturbation`` (nominal +
  perturbations; :func:`calibration.fit.proxy.load_proxy` reads it back, and
  ``isp synth --lens proxy.json`` makes training data from it);
* ``fit.json``: parameters with 1σ uncertainty, errors before/after, merit
  per iteration, lens evaluations, time, restarts, the coarse stage;
* ``merit.png``, ``sfra_maps.png``, ``parameters.png``;
* ``device.json``, the device's calibration (``device/v1``,
  :mod:`calibration.fit.device`): the proxy's descriptor on the design's
  basis, the fit's errors and the measurement's SHA-256, what one shared
  correction model reads; on ``--basis FILE``, else on the basis a lens
  profile ships for the design (the packaged e9's); none for a design
  without one, or with ``--basis none``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from calibration.cli.arguments import coarse_grid
from isp.errors import ConfigError
from isp.runtime.executor import add_executor_argument

#: bootstrap replicas per edge of a capture (``--bootstrap``); off by default: on simulated device 3 the
#: edges' own σ brought the fitted lens closer to the true one from a 1 µm capture (RMS SFR error 0.0130 →
#: 0.0092) and farther from a 2.8 µm one (0.0099 → 0.0116)
BOOTSTRAP = 0

EPILOG = """examples:
  isp calib fit --lens e9.zmx --measured capture.dng -o dev3/   # + device.json on the packaged e9 basis
  isp calib fit --lens e9.zmx --measured chart_sfr.json --method scipy --max-iter 20
  isp calib fit --lens e9.zmx --measured obs.json --residuals bands --no-fast-jacobian
  isp calib fit --lens e9.zmx --measured capture.dng --bootstrap 20 -o e9_proxy/   # each edge its own σ
  isp calib fit --lens e9.zmx --measured capture.dng --fine-iter 0 -o dev3/   # the line's quick fit
  isp calib fit --lens phone.zmx --measured capture.dng --basis phone_basis.npz -o dev3/   # another design's basis
"""


def run(args: argparse.Namespace) -> int:
    """Fit the proxy camera and write its folder (built aside and renamed into place)."""
    from calibration.fit.device import resolve_basis
    from calibration.fit.measurements import load_measured, match_sensor
    from calibration.optics.io import read_lens
    from calibration.report import check_output_folder, staged_folder
    from isp.runtime.executor import create_executor, pool_executor

    from calibration.fit.proxy import ProxyFitSettings, fit_proxy
    from calibration.optics.psf.map import WINDOW_ENERGY_WARN
    from calibration.fit.forward_model import FAST_JACOBIAN, ModelSettings

    t0 = time.perf_counter()
    _check_fitting_options(args)
    for option, least in (("--bootstrap", 0), ("--components", 1), ("--fine-iter", 0)):
        _at_least(args, option, least)
    if args.fine_iter == 0 and args.coarse[0] == 0:
        raise ConfigError("--fine-iter 0 stops after the coarse stage; it needs --coarse R C")
    coarse = coarse_grid(args.coarse)
    variants = [("(as given)", args)] + [(text, _try_options(args, text)) for text in args.tries or ()]
    out = Path(args.output)
    check_output_folder(out)
    nominal = read_lens(args.lens)              # a bad lens file fails before any measurement
    basis = resolve_basis(args.basis, nominal)
    obs, notes = load_measured(args.measured, channel=args.channel, encoding=args.encoding,
                               pixel_um=args.pixel_um, bootstrap=args.bootstrap,
                               executor=create_executor("serial", progress=True))
    for n in notes:
        print(f"note: {n}")
    nominal, obs = match_sensor(nominal, obs, pixel_um=args.pixel_um)
    print(f"{args.measured}: {len(obs)} observations; fitting {args.n_params} parameters "
          f"({args.method}, {args.residuals} residuals)", flush=True)
    fits = []
    with pool_executor(args.workers, progress=True, executor=args.executor) as ex:
        for text, a in variants:
            if len(variants) > 1:
                print(f"fit {len(fits) + 1} of {len(variants)}: {text}", flush=True)
            settings = None if a.window_um is None else ModelSettings().with_window(a.window_um)
            fits.append(fit_proxy(nominal, obs, ProxyFitSettings(
                model=settings, method=a.method, max_iter=a.max_iter, n_params=a.n_params, residuals=a.residuals,
                jacobian_model=FAST_JACOBIAN if args.fast_jacobian else None, refresh=args.refresh,
                restarts=a.restarts, coarse=coarse, fine_iter=args.fine_iter, widen=a.widen, kinds=a.kinds,
                stage_params=a.stage),
                executor=ex))
    fit = min(fits, key=lambda f: f.errors()["after"]["chi2_per_obs"])
    if len(fits) > 1:
        fit.settings["tries"] = [{"options": text, "chi2_per_obs": round(f.errors()["after"]["chi2_per_obs"], 3),
                                  "seconds": round(f.seconds, 1), "kept": f is fit}
                                 for (text, _), f in zip(variants, fits)]
        for t in fit.settings["tries"]:
            print(f"{t['options']}: χ²/obs {t['chi2_per_obs']:.2f} ({t['seconds']:.0f} s)"
                  + ("  ← kept: the lowest" if t["kept"] else ""))
    with staged_folder(out) as tmp:
        fit.save(tmp)
        if basis is not None:
            cal = _device_file(fit, basis, args, tmp / "device.json")
    e = fit.errors()
    if fit.coarse and fit.coarse.get("refined", True):
        print(f"coarse to fine: fitted first on {fit.coarse['observations']} of {len(obs)} observations "
              f"(a sub-grid of the regions, {fit.coarse['seconds']:.0f} s), then refined on all")
    elif fit.coarse:
        print(f"fitted on {fit.coarse['observations']} of {len(obs)} observations (a sub-grid of the regions, "
              "--fine-iter 0: not refined on all); the errors below are the sub-grid's")
    if fit.restarts:
        won = [t for t in fit.restarts if t.get("kept")]
        print(f"the fit ended far above the noise floor; {len(fit.restarts)} other starts tried: "
              + (f"start {won[0]['start']} reached a lower merit and was kept" if won else "none did better"))
    print(f"SFRA RMS {e['before']['sfra_rms']:.4f} → {e['after']['sfra_rms']:.4f} cycles/pixel, "
          f"χ²/obs {e['before']['chi2_per_obs']:.1f} → {e['after']['chi2_per_obs']:.2f}, median |residual| "
          f"{e['before']['median_abs_z']:.2f} → {e['after']['median_abs_z']:.2f} σ (0.67 at the noise floor); "
          f"{fit.evaluations} lens evaluations, {fit.seconds:.0f} s")
    for w in fit.settings.get("widened", []):
        print(f"note: the lens fitted with a {w['window_um']:g} µm PSF window threw "
              f"{1 - w['window_energy_min']:.0%} of some region's light outside it: fitted again with a wider one "
              f"({fit.settings.get('window_um'):g} µm at the end; --window-um sets it)")
    if fit.window_energy < WINDOW_ENERGY_WARN and fit.settings.get("widened"):
        print(f"note: the fitted lens still throws {1 - fit.window_energy:.0%} of some region's light outside the "
              f"{fit.settings.get('window_um'):g} µm PSF window; widening further recovered too little of it to "
              "pay for another fit (benchmarks/psf_window.py)")
    elif fit.window_energy < WINDOW_ENERGY_WARN:
        print(f"note: the fitted lens throws {1 - fit.window_energy:.0%} of some region's light outside the model's "
              f"{fit.settings.get('window_um')} µm PSF window; its SFR there is too high at low frequencies "
              "(a wider window: --widen or --window-um, benchmarks/psf_window.py)")
    if basis is not None:
        print(f"device calibration: {cal.grid[0]} × {cal.grid[1]} regions × {cal.descriptor.shape[2]} components "
              f"on basis {basis.key[:12]} (max |d| {abs(cal.descriptor).max():.2f} spreads)")
    print(f"wrote {out}/proxy.json, fit.json, merit.png, sfra_maps.png, parameters.png"
          f"{', device.json' if basis is not None else ''} ({time.perf_counter() - t0:.0f} s)")
    return 0


#: ``--method`` and ``--residuals`` choices (the command line's and a ``--try``'s)
METHODS = ("dls", "scipy")
RESIDUALS = ("auto", "sfra", "bands", "odd", "shape")
#: what ``--try`` may change: the options that decide which basin a fit ends in
TRY_OPTIONS = ("--n-params", "--restarts", "--max-iter", "--window-um", "--widen", "--no-widen", "--method",
               "--residuals", "--kinds", "--stage")


def kind_list(text: str) -> tuple[str, ...]:
    """``--kinds``'s comma-separated list, e.g. ``"curvature,conic,focus"``;
    ``"all"``: every kind a module's tolerances perturb, and focus."""
    from calibration.fit.proxy import ALL_KINDS

    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    return ALL_KINDS if kinds == ("all",) else kinds


def _at_least(a: argparse.Namespace, option: str, least: int, where: str = "") -> None:
    """ConfigError (one line, prefixed by ``where``) where integer ``option``
    of ``a`` is given and below ``least``."""
    value = getattr(a, option[2:].replace("-", "_"))
    if value is not None and value < least:
        raise ConfigError(f"{where}{option} {value}: " + ("0 or more" if least == 0 else f"at least {least}"))


def _check_fitting_options(a: argparse.Namespace, where: str = "") -> None:
    """ConfigError (one line, prefixed by ``where``) for a fitting option
    out of its range: the command line's, or a ``--try``'s."""
    from calibration.fit.proxy import KINDS

    for option, least in (("--max-iter", 1), ("--n-params", 1), ("--restarts", 0), ("--stage", 1)):
        _at_least(a, option, least, where)
    if a.widen and a.window_um is not None and a.window_um >= 128.0:
        raise ConfigError(f"{where}--widen with --window-um {a.window_um:g}: the window to start from must be "
                          "below 128 µm, the widest --widen tries")
    if a.window_um is not None and not 8.0 <= a.window_um <= 256.0:
        raise ConfigError(f"{where}--window-um {a.window_um:g}: between 8 and 256 µm")
    unknown = [k for k in a.kinds if k not in KINDS]
    if unknown or not a.kinds:
        raise ConfigError(f"{where}--kinds {','.join(a.kinds)}: {', '.join(unknown) or 'none given'} is not a kind "
                          f"of perturbation ({', '.join(KINDS)})")


def _try_options(args: argparse.Namespace, text: str) -> argparse.Namespace:
    """``args`` with the fitting options of one ``--try`` string replaced
    (:data:`TRY_OPTIONS`); ConfigError (one line) for anything else."""
    import shlex

    p = argparse.ArgumentParser(prog="--try", add_help=False, exit_on_error=False)
    for name in ("--n-params", "--restarts", "--max-iter", "--stage"):
        p.add_argument(name, type=int, default=getattr(args, name[2:].replace("-", "_")))
    p.add_argument("--window-um", type=float, default=args.window_um)
    p.add_argument("--widen", action=argparse.BooleanOptionalAction, default=args.widen)
    p.add_argument("--method", choices=METHODS, default=args.method)
    p.add_argument("--residuals", choices=RESIDUALS, default=args.residuals)
    p.add_argument("--kinds", type=kind_list, default=args.kinds)
    where = f"--try {text!r}: "
    try:
        got, rest = p.parse_known_args(shlex.split(text))
    except (argparse.ArgumentError, ValueError) as e:
        raise ConfigError(f"{where}{e}") from None
    if rest:
        raise ConfigError(f"{where}{' '.join(rest)} is not one of {', '.join(TRY_OPTIONS)}")
    merged = argparse.Namespace(**{**vars(args), **vars(got)})
    _check_fitting_options(merged, where)
    return merged


def _device_file(fit, basis, args, path):
    """Write the device's ``device/v1`` calibration of the fitted proxy."""
    from calibration.fit.device import device_calibration, measurement_source

    e = fit.errors()
    summary = {"sfra_rms_before": e["before"]["sfra_rms"], "sfra_rms_after": e["after"]["sfra_rms"],
               "chi2_per_obs": e["after"]["chi2_per_obs"], "parameters": len(fit.space.names)}
    cal = device_calibration(fit.lens, basis, min(args.components, basis.size), fit=summary,
                             source=measurement_source(args.measured))
    cal.save(path)
    return cal


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp calib fit``."""
    from calibration.fit.device import DEFAULT_COMPONENTS
    from calibration.fit.proxy import COARSE_GRID, FIT_KINDS, MAX_ITER, N_PARAMS, REFRESH, RESTART_CHI2, RESTARTS

    p.description = __doc__.split("\n\n")[0].replace("``", "`")
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("--lens", required=True, metavar="LENS", help="lens file (lens/v1 .json, Zemax .zmx, ...)")
    p.add_argument("--measured", required=True, metavar="MEAS",
                   help="chart capture (DNG/raw or image), SFR JSON of `isp calib sfr`, or sfr-observations/v1")
    p.add_argument("-o", "--output", default="proxy_fit", metavar="DIR", help="output folder (default proxy_fit/)")
    p.add_argument("--method", choices=METHODS, default="dls",
                   help="dls: damped least squares, dynamic damping (default); scipy: least_squares TRF")
    p.add_argument("--residuals", choices=RESIDUALS, default="auto",
                   help="auto (default): shape where the measurement has the LSF asymmetry, else sfra; "
                        "sfra: SFRA per edge (the paper); bands: plus the mean SFR in four frequency bands; "
                        "odd: plus the LSF's asymmetry in four bands (coma's direction, which SFR drops); "
                        "shape: SFRA, bands and asymmetry")
    p.add_argument("--n-params", type=int, default=N_PARAMS,
                   help=f"perturbations fitted, the most sensitive (default {N_PARAMS})")
    p.add_argument("--kinds", type=kind_list, default=FIT_KINDS, metavar="K,K,...",
                   help=f"the kinds of perturbation screened to --n-params (default {','.join(FIT_KINDS)}; also "
                        "curvature, conic, nd, vd, asphere, tilt_xy: a module's power and form errors, which "
                        "decenters, tilts and gaps can only mimic)")
    p.add_argument("--stage", type=int, metavar="N",
                   help="with more than N perturbations fitted: fit first the N most sensitive decenters, tilts, "
                        "gaps and focus (restarts among them), then all from there, and keep the better of that "
                        "and all at once (default: all at once). With --kinds all --n-params 92 --stage 24 an e2 "
                        "module's quick fit ended at χ²/obs 19.0 against 36.0 over 48 assembly perturbations, its "
                        "device file 0.26 spreads from the module's against 0.92")
    p.add_argument("--max-iter", type=int, default=MAX_ITER, help=f"iterations at most (default {MAX_ITER})")
    p.add_argument("--refresh", type=int, default=REFRESH,
                   help="a finite-difference Jacobian every REFRESH accepted steps, Broyden secant updates "
                        f"in between (default {REFRESH}; 1: every step)")
    p.add_argument("--restarts", type=int, default=RESTARTS,
                   help=f"when the fit ends above {RESTART_CHI2:g} χ² per residual (a local minimum far above "
                        f"the noise floor), this many other starts within ±1 tolerance, the best continued "
                        f"(default {RESTARTS}; 0: none)")
    p.add_argument("--coarse", type=int, nargs=2, default=list(COARSE_GRID), metavar=("R", "C"),
                   help="fit first (screening and restarts included) on the edges of an R × C sub-grid of the "
                        "regions, spread edge to edge, then refine on all; only where that at least halves the "
                        f"edges (default {COARSE_GRID[0]} {COARSE_GRID[1]}: on the paper's 15 × 20 regions, "
                        "35 of 300; 0 0: off)")
    p.add_argument("--fine-iter", type=int, default=None, metavar="N",
                   help="iterations at most of the refinement on all edges (default: --max-iter); 0: none, the "
                        "coarse sub-grid's fit is the result: enough for a device calibration (--basis), whose "
                        "descriptor is read on 5 × 7 regions, in under a third of the time (64 s against 229 s on an "
                        "e9 module, 2 cores; benchmarks/device_workflow.py)")
    p.add_argument("--workers", type=int, default=None, help="processes for the Jacobian (default 2)")
    add_executor_argument(p)
    p.add_argument("--basis", metavar="BASIS.npz", default="auto",
                   help="the design's descriptor basis (`isp calib basis`) to write device.json on, the device's "
                        "calibration for the shared correction model; 'auto' (default): the basis a lens profile "
                        "ships for this design (the packaged e9's), none for other designs; 'none': no device.json")
    p.add_argument("--components", type=int, default=DEFAULT_COMPONENTS,
                   help=f"descriptor components in device.json (default {DEFAULT_COMPONENTS}, at most the basis's)")
    p.add_argument("--fast-jacobian", action=argparse.BooleanOptionalAction, default=True,
                   help="Jacobian from a cheaper model (32 pupil samples, a 24 µm PSF window), steps judged on the full model "
                        "(default on: on e9 at 15 × 20 regions with a 16 µm model window it ended at a lower "
                        "merit in 109 s against 181 s with the full model's Jacobian, and in 152 s with the "
                        "32 µm window)")
    p.add_argument("--window-um", type=float, metavar="UM",
                   help="the forward model's PSF window, µm (default 32; wider for blurry devices, whose "
                        "corner light a narrow window drops: the fit says when)")
    p.add_argument("--widen", action=argparse.BooleanOptionalAction, default=False,
                   help="where the fitted lens throws over a tenth of some region's light outside the PSF "
                        "window, fit again 1.5× wider, and again while widening recovers that light (each "
                        "refit costs a fit; default off: on e9's modules, which lose 8–23 %% at 32 µm, it "
                        "would double the quick fit's time for a gain not measured)")
    p.add_argument("--try", dest="tries", action="append", metavar="OPTIONS",
                   help=f"fit again with these fitting options changed (repeatable; {', '.join(TRY_OPTIONS)}) "
                        "and keep the fit of the lowest "
                        "χ² per observation, the first included: a fit stops in a local minimum, and how near the "
                        "device file comes to the module follows that χ² (on e2's quick fits the lowest of "
                        "'', '--widen', '--n-params 48', '--n-params 48 --restarts 12' and '--kinds all --n-params "
                        "92 --stage 24' gained +1.67 dB at FoV 0.9, as the true descriptors do, where the first "
                        "alone gained +1.19; docs/results/device.md); fit.json lists them "
                        "under settings.tries. One option alone goes with '=': --try=--widen")
    p.add_argument("--channel", help="R, G, B, L or all (default G; grey images: L)")
    p.add_argument("--encoding", choices=("linear", "srgb"), default="linear", help="image codes (default linear)")
    p.add_argument("--pixel-um", type=float, metavar="UM", help="pixel pitch, µm (default: the capture's)")
    p.add_argument("--bootstrap", type=int, default=BOOTSTRAP, metavar="N",
                   help="a capture's edges: N residual-bootstrap replicas each (20 is plenty), whose spread is "
                        "that edge's σ in the fit, so an edge whose measurement is unstable weighs little "
                        f"(default {BOOTSTRAP}: 0.002 cycles/pixel for every edge). On one simulated device it "
                        "brought the fit closer to the true lens from a 1 µm capture and farther from a 2.8 µm "
                        "one")

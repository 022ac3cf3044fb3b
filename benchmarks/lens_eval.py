"""Cost of one lens evaluation of the proxy-camera forward model.

A proxy fit (:mod:`calibration.fit.proxy`, :mod:`calibration.fit.dls`) evaluates
:meth:`calibration.fit.forward_model.SfrModel.predict` about 200 times, each for a
new perturbed lens. This script times one such evaluation on the paper's
setup: lens US-12210142-B2-e9, its sensor split into 15 × 20 regions, a
vertical (normal −5°) and a horizontal (normal 95°) edge at every region
centre (600 observations, green channel), a lens perturbed uniformly within
±1 tolerance in every :func:`calibration.fit.proxy.default_names` parameter —
a fresh one per timed call (the model caches the last lens's rays; nothing
is reused across lenses).

Timed, median of ``--repeats`` calls (process CPU seconds, which a busy
machine does not inflate, and wall seconds):

* ``predict`` at the default :class:`ModelSettings` (48 pupil samples);
* ``predict`` at the fast-Jacobian settings of ``benchmarks/proxy.py``
  (``FAST_JACOBIAN``: 32 pupil samples, a 24 µm window);
* ``node_psfs(lens, defocus_mm=dz)`` with a per-node defocus (±5 µm, the
  loop's focus/tilt/curvature effects), on the lens whose rays are already
  traced (the loop's case: the trace is reused, the PSFs recomputed);
* ``predict`` at both settings on the coarse stage's observations only
  (:func:`calibration.fit.proxy.coarse_subset`: the 70 edges of a 5 × 7
  sub-grid), what a coarse-to-fine fit's first stage pays per evaluation.

Accuracy: with ``--reference FILE`` the predicted SFR of every timed lens is
compared with the one saved by an earlier run (``--save-reference FILE``,
e.g. from the code before an optimisation): RMS and largest absolute
difference of SFRA, and largest of SFR, over the 600 observations
(cycles/pixel, resp. SFR units).

Each timing is the median of the ``--repeats`` calls with the fastest and
slowest (``{"median", "min", "max", "n"}``). A call on a machine whose
other core is free runs the tracer's two threads in parallel: less wall
time than CPU time (two threads sharing caches); with the cores busy (a
fit's worker processes) CPU ≈ wall. Model set-up includes importing
colour (~3 s).

Prints a line per timing and one JSON object as the LAST line. Usage::

    python -m benchmarks.lens_eval [--repeats 3] [--save-reference F.npz] [--reference F.npz]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # one BLAS thread, as in a fit's worker processes; before numpy loads
    _harness.pin_threads(2, blas=1)

import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

ROOT = _harness.ROOT

from calibration.optics.io import read_lens  # noqa: E402
from calibration.fit.proxy import COARSE_GRID, coarse_subset, default_names, parameter_space  # noqa: E402
from calibration.fit.observations import FREQ, Observations  # noqa: E402
from calibration.fit.synthetic_devices import edge_sites  # noqa: E402
from calibration.sfr.chart import classify_orientation  # noqa: E402
from calibration.fit.forward_model import FAST_JACOBIAN, ModelSettings, SfrModel  # noqa: E402

LENS = ROOT.parent / "shared" / "data" / "lenses" / "phone" / "US-12210142-B2-e9.zmx"
GRID = (15, 20)
EDGE_DEG = 5.0
DEFOCUS_UM = 5.0


def observations(sensor, grid=GRID) -> Observations:
    """A vertical and a horizontal edge at every region centre (dummy SFR values:
    the model reads only the geometry, channel and frequencies)."""
    cx, cy = (sensor.width_px - 1) / 2.0, (sensor.height_px - 1) / 2.0
    half = 0.5 * math.hypot(sensor.width_px, sensor.height_px)
    xs, ys, normals, orients = [], [], [], []
    t = math.radians(EDGE_DEG)
    for _, _, x, y in edge_sites(sensor, grid):
        rad = math.hypot(x - cx, y - cy) / half
        fa = math.degrees(math.atan2(cy - y, x - cx))
        for horizontal in (False, True):
            edge_dir = (math.cos(t), math.sin(t)) if horizontal else (math.sin(t), math.cos(t))
            xs.append(x)
            ys.append(y)
            normals.append(90.0 + EDGE_DEG if horizontal else -EDGE_DEG)
            orients.append(classify_orientation(edge_dir[0], edge_dir[1], rad, fa))
    n = len(xs)
    sfr = np.tile(np.exp(-4.0 * FREQ), (n, 1))
    return Observations(x_px=np.array(xs), y_px=np.array(ys), normal_deg=np.array(normals),
                        channel=np.array(["G"] * n), orientation=np.array(orients), sfra=np.full(n, 0.3),
                        sfra_std=np.full(n, 0.01), noise=np.full(n, 0.004), step=np.full(n, 0.6), freq=FREQ,
                        sfr=sfr, sensor=sensor, grid=grid, source="benchmark", meta={"measure": "image"})


def perturbed(space, seed: int, i: int):
    """Lens ``i``: every parameter uniform within ±1 tolerance (seeded)."""
    u = np.random.default_rng([seed, i]).uniform(-1.0, 1.0, len(space.names))
    return space.apply(u * space.tolerance)


def timed(fn):
    """(result, CPU s, wall s) of one call."""
    c0, w0 = time.process_time(), time.perf_counter()
    out = fn()
    return out, time.process_time() - c0, time.perf_counter() - w0


def summary(cpu, wall) -> dict:
    """CPU and wall seconds of the timed calls: median, fastest, slowest."""
    return {"cpu_s": _harness.spread(cpu).as_dict(3), "wall_s": _harness.spread(wall).as_dict(3)}


def run_predict(model, space, seed, offset, repeats, log):
    """CPU/wall of predict() over fresh lenses; their SFRs."""
    cpu, wall, sfrs = [], [], []
    for r in range(repeats):
        lens = perturbed(space, seed, offset + r)
        pred, c, w = timed(lambda lens=lens: model.predict(lens))
        cpu.append(c)
        wall.append(w)
        sfrs.append(pred.sfr)
        log(f"  lens {offset + r}: {c:.2f} s CPU, {w:.2f} s wall")
    return summary(cpu, wall), sfrs


def run_defocus(model, space, seed, offset, repeats, log):
    """CPU/wall of node_psfs(defocus per node) on already traced lenses."""
    cpu, wall, psfs = [], [], []
    rng = np.random.default_rng([seed, 999])
    for r in range(repeats):
        lens = perturbed(space, seed, offset + r)
        model.node_psfs(lens)                            # trace (the loop has it already)
        dz = rng.uniform(-DEFOCUS_UM, DEFOCUS_UM, len(model.regions)) * 1e-3
        p, c, w = timed(lambda lens=lens, dz=dz: model.node_psfs(lens, defocus_mm=dz))
        cpu.append(c)
        wall.append(w)
        psfs.append(p)
        log(f"  lens {offset + r}: {c:.2f} s CPU, {w:.2f} s wall")
    return summary(cpu, wall), psfs


def sfr_diff(model, a, b) -> dict:
    """RMS/max |ΔSFRA| (cycles/pixel) and max |ΔSFR| over all observations and lenses."""
    from calibration.fit.forward_model import sfra_of

    da = np.concatenate([sfra_of(model.obs.freq, x) - sfra_of(model.obs.freq, y) for x, y in zip(a, b)])
    ds = max(float(np.max(np.abs(x - y))) for x, y in zip(a, b))
    return {"sfra_rms": float(np.sqrt(np.mean(da ** 2))), "sfra_max": float(np.max(np.abs(da))), "sfr_max": ds}


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--save-reference", metavar="NPZ", help="save the timed lenses' SFRs and PSFs")
    ap.add_argument("--reference", metavar="NPZ", help="compare with SFRs and PSFs saved by an earlier run")
    ap.add_argument("--profile", choices=("default", "fast", "defocus"), help="cProfile one call, print top 30")
    ap.add_argument("--psf-n", type=int, default=ModelSettings.psf_n,
                    help=f"the default model's PSF window, samples (default: {ModelSettings.window_um:g} µm, 64 "
                         "samples on these 1 µm pixels; "
                         "benchmarks/psf_window.py measures what it costs in accuracy)")
    args = ap.parse_args(argv)

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    lens = read_lens(LENS)
    space = parameter_space(lens, default_names(lens))
    obs = observations(lens.sensor)
    out = {"lens": LENS.stem, "grid": list(GRID), "observations": len(obs), "repeats": args.repeats,
           "psf_n": args.psf_n}
    t0 = time.process_time()
    default = SfrModel(lens, obs, ModelSettings(psf_n=args.psf_n))
    fast = SfrModel(lens, obs, FAST_JACOBIAN)
    out["model_setup_cpu_s"] = round(time.process_time() - t0, 2)
    if args.profile:
        import cProfile
        import pstats

        model = fast if args.profile == "fast" else default
        lens_p = perturbed(space, args.seed, 0)
        if args.profile == "defocus":
            model.node_psfs(lens_p)
            dz = np.linspace(-DEFOCUS_UM, DEFOCUS_UM, len(model.regions)) * 1e-3
            call = lambda: model.node_psfs(lens_p, defocus_mm=dz)   # noqa: E731
        else:
            call = lambda: model.predict(lens_p)                    # noqa: E731
        prof = cProfile.Profile(time.process_time)
        prof.runcall(call)
        pstats.Stats(prof).sort_stats("tottime").print_stats(30)
        return out
    log("predict, default settings")
    out["predict_default"], sfr_d = run_predict(default, space, args.seed, 0, args.repeats, log)
    log("predict, fast-Jacobian settings (pupil 32)")
    out["predict_fast"], sfr_f = run_predict(fast, space, args.seed, 100, args.repeats, log)
    log("node_psfs with a per-node defocus (traced lens)")
    out["node_psfs_defocus"], psf_z = run_defocus(default, space, args.seed, 200, args.repeats, log)
    sub = obs.subset(coarse_subset(obs, COARSE_GRID))
    log(f"predict on the coarse sub-grid ({len(sub)} observations), default and fast settings")
    out["coarse_observations"] = len(sub)
    out["predict_default_coarse"], _ = run_predict(SfrModel(lens, sub, ModelSettings(psf_n=args.psf_n)), space,
                                                   args.seed, 300, args.repeats, log)
    out["predict_fast_coarse"], _ = run_predict(SfrModel(lens, sub, FAST_JACOBIAN), space, args.seed, 400,
                                                args.repeats, log)
    sfr_z = [default.predict(perturbed(space, args.seed, 200 + r),
                             defocus_mm=np.random.default_rng([args.seed, 999]).uniform(-1, 1, len(default.regions))
                             * DEFOCUS_UM * 1e-3).sfr for r in range(args.repeats)]
    if args.save_reference:
        np.savez_compressed(args.save_reference, default=np.array(sfr_d), fast=np.array(sfr_f),
                            defocus=np.array(sfr_z), psf_defocus=np.array(psf_z))
    if args.reference:
        ref = np.load(args.reference)
        out["accuracy_vs_reference"] = {
            "default": sfr_diff(default, sfr_d, ref["default"]),
            "fast": sfr_diff(fast, sfr_f, ref["fast"]),
            "defocus": sfr_diff(default, sfr_z, ref["defocus"]),
            "psf_defocus_max_rel": float(max(np.max(np.abs(a - b)) / np.max(np.abs(b))
                                             for a, b in zip(psf_z, ref["psf_defocus"]))),
        }
    for k in ("predict_default", "predict_fast", "node_psfs_defocus", "predict_default_coarse",
              "predict_fast_coarse"):
        c, w = out[k]["cpu_s"], out[k]["wall_s"]
        print(f"{k:<22} {c['median']:7.2f} s CPU ({c['min']:.2f}–{c['max']:.2f}) {w['median']:7.2f} s wall")
    if "accuracy_vs_reference" in out:
        for k, v in out["accuracy_vs_reference"].items():
            print(f"accuracy {k}: {v}")
    return _harness.publish("lens_eval", out, args, argv)


if __name__ == "__main__":
    main()

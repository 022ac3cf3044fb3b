"""Detection limits of the loop: the smallest magnitude of each registry
effect that the loop names, and nothing else, on the stand-in device.

The device is :class:`calibration.loop.stand_ins.StandInDevice`: closed-form
optics (diffraction at f/2 × a Gaussian blur of 0.6 µm on 1 µm pixels),
edges at the region centres of a grid (one vertical and one horizontal
each), rendered, noised and measured with the default SFR method; the loop
runs on :class:`calibration.loop.base.ParametricBase`, which models those
optics exactly, with every registry effect a candidate. Each effect is put
in alone at magnitudes up a ladder (its own units; the defocus effects in
the device's optics, the chain's in the ROIs' pixels, as the loop's tests
do), each magnitude with two noise draws. A magnitude is *detected* where
both draws end with that effect alone added; the limit is the smallest
magnitude of the unbroken run of detections down from the highest one (a
larger magnitude missed above it is noted: taken for another effect). What
the loop named when it missed is kept.

Three settings: noise σ 0.3 % of the range (SNR 200) on the 5 × 7 grid (70
edges; 210 on R, G and B planes for longitudinal colour), the same at
1 % (SNR 60), and 0.3 % on a 9 × 13 grid (234 edges). The base fits these
optics exactly, so the limits are those of the measurement and the loop's
statistics alone: a lower bound for a device with every tolerance drawn,
whose base leaves its own residual (``benchmarks/loop_suite.py``).

Results: ``benchmarks/results/detection_limits.json``. Prints a line per
effect and one JSON object as the last line. Usage::

    python -m benchmarks.detection_limits [--effects focus_shift sharpening ...] [--settings base noisy dense]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # one BLAS thread per worker, set before numpy loads
    _harness.pin_threads(2, blas=1)

import sys  # noqa: E402
import time  # noqa: E402

from calibration.loop import stand_ins as S  # noqa: E402

#: effect → (unit, magnitude ladder, device and pixels for magnitude m: (device kwargs, image ops, channels))
LADDERS = {
    "focus_shift": ("µm", (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0),
                    lambda m: ({"dz": lambda x, y, m=m: 1e-3 * m}, (), ("G",))),
    "sensor_tilt": ("degree about y", (0.02, 0.03, 0.05, 0.07, 0.1, 0.15, 0.2, 0.4),
                    lambda m: ({"dz": S.tilt_about_y(m)}, (), ("G",))),
    "field_curvature": ("µm at the corner", (1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0),
                        lambda m: ({"dz": S.curvature(1e-3 * m)}, (), ("G",))),
    "lateral_ca": ("R px at the corner (B −⅔ of it)", (0.1, 0.15, 0.2, 0.3, 0.4, 0.6, 0.8, 1.2, 1.6, 2.0),
                   lambda m: ({"ca": (m, -2.0 * m / 3.0)}, (), ("L",))),
    "longitudinal_ca": ("R µm from G (B −4⁄3 of it)", (0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0),
                        lambda m: ({"loca": {"R": 1e-3 * m, "B": -4e-3 * m / 3.0}}, (), ("R", "G", "B"))),
    "pixel_crosstalk": ("leak to each neighbour", (0.005, 0.01, 0.015, 0.02, 0.03, 0.04, 0.06, 0.08),
                        lambda m: ({}, (S.crosstalk(m),), ("G",))),
    "sharpening": ("unsharp-mask gain (σ 1.2 px)", (0.02, 0.03, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.6, 0.8),
                   lambda m: ({}, (S.sharpen(m, 1.2),), ("G",))),
    "motion_blur": ("px along x", (0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 2.5),
                    lambda m: ({}, (S.motion(m, 0.0),), ("G",))),
    "veiling_glare": ("share of the light (halo σ 12 px)", (0.002, 0.003, 0.005, 0.01, 0.015, 0.02, 0.03, 0.04, 0.06, 0.08),
                      lambda m: ({}, (S.glare(m, 12.0),), ("G",))),
}
#: name → (noise σ, grid)
SETTINGS = {"base": (0.003, (5, 7)), "noisy": (0.01, (5, 7)), "dense": (0.003, (9, 13))}
SETTING_TITLES = {"base": "SNR 200, 70 edges", "noisy": "SNR 60, 70 edges", "dense": "SNR 200, 234 edges"}
SEEDS = (1, 2)


def run_one(effect: str, m: float, noise: float, grid, seed: int, executor) -> dict:
    """The loop on the stand-in with ``effect`` at magnitude ``m``."""
    from calibration.fit.synthetic_devices import synthetic_observations
    from calibration.loop.base import ParametricBase
    from calibration.loop.closure import close_loop

    kw, ops, channels = LADDERS[effect][2](m)
    obs = synthetic_observations(S.StandInDevice(grid=grid, **kw), noise=noise, image_ops=ops, rng=seed,
                                 channels=channels)
    rep = close_loop(ParametricBase(obs, f_number=2.0), obs, executor=executor)
    return {"added": list(rep.effects_added), "after_over_floor": round(rep.error_after["sfra_rms"] / rep.noise_floor, 3),
            "edges": len(obs)}


def ladder(effect: str, noise: float, grid, executor, log) -> dict:
    """Every rung of ``effect``'s ladder, from the top down, until two in a
    row below the highest detection are missed (the limit is above them).
    The limit is the lowest rung of the unbroken run of detections down
    from the highest detected one; rungs above it that were missed are
    listed (``missed_above``: a larger effect taken for another)."""
    unit, rungs, _ = LADDERS[effect]
    rows, misses = [], 0
    for m in sorted(rungs, reverse=True):
        runs = [run_one(effect, m, noise, grid, s, executor) for s in SEEDS]
        ok = all(r["added"] == [effect] for r in runs)
        rows.append({"magnitude": m, "detected": ok, "named": [r["added"] for r in runs],
                     "after_over_floor": [r["after_over_floor"] for r in runs], "edges": runs[0]["edges"]})
        log(f"  {effect} {m:g}: {'detected' if ok else 'not'} ({'; '.join(', '.join(r['added']) or '-' for r in runs)})")
        misses = 0 if ok else misses + (1 if any(r["detected"] for r in rows) else 0)
        if misses == 2:
            break
    rows.reverse()
    limit, top = None, None
    for r in reversed(rows):          # from the top: the run of detections below the highest one
        if r["detected"]:
            limit = r["magnitude"]
            top = limit if top is None else top
        elif top is not None:
            break
    missed_above = [r["magnitude"] for r in rows if top is not None and r["magnitude"] > top]
    instead = sorted({n for r in rows if not r["detected"] for draw in r["named"] for n in draw if n != effect})
    return {"unit": unit, "limit": limit, "missed_above": missed_above, "rungs": rows, "named_instead": instead}


def limit_text(res: dict) -> str:
    """A ladder's limit as the table gives it: the magnitude, "≤ m" where
    the lowest rung tried was detected, "> m" where none was, and the rungs
    above it that were missed in brackets."""
    rungs = res["rungs"]
    if res["limit"] is None:
        return f"> {rungs[-1]['magnitude']:g}"
    text = f"{'≤ ' if rungs[0]['detected'] else ''}{res['limit']:g}"
    missed = res.get("missed_above") or []
    return text + (f" (missed at {', '.join(f'{m:g}' for m in missed)})" if missed else "")


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--effects", nargs="+", choices=list(LADDERS), default=list(LADDERS))
    ap.add_argument("--settings", nargs="+", choices=list(SETTINGS), default=list(SETTINGS))
    args = ap.parse_args(argv)
    from isp.runtime.executor import pool_executor

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    ex = pool_executor(None)
    t0 = time.perf_counter()
    out: dict = {}
    for name in args.settings:
        noise, grid = SETTINGS[name]
        log(f"{name}: noise {noise:g}, grid {grid}")
        out[name] = {e: ladder(e, noise, grid, ex, log) for e in args.effects}
    table = {e: {"unit": LADDERS[e][0], **{SETTING_TITLES[s]: limit_text(out[s][e]) for s in out},
                 "named when missed": ", ".join(sorted({n for s in out for n in out[s][e]["named_instead"]}))
                 or "nothing"}
             for e in args.effects}
    for e, row in table.items():
        print(f"{e:<16} " + "  ".join(f"{k}: {v}" for k, v in row.items() if k != "unit"))
    return _harness.publish("detection_limits", {"settings": {k: {"noise": SETTINGS[k][0], "grid": list(SETTINGS[k][1])}
                                                              for k in out},
                                                 "seeds": list(SEEDS), "table": table, "runs": out,
                                                 "elapsed_s": round(time.perf_counter() - t0, 1)}, args, argv)


if __name__ == "__main__":
    main()

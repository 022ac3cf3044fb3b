"""Attribution that holds: the loop on devices with every tolerance drawn
and zero to two effects put into their captures.

Case ``k`` of the suite (``k`` = 0, 1, ...):

* the lens cycles through e1, e2, e9, e11 (``k mod 4``);
* the device is ``isp calib simulate LENS --perturb random --seed 100 + k
  --size 2000,1500`` (every tolerance drawn, refocused);
* a generator seeded with ``k`` draws how many effects (0, 1 or 2, equally
  likely), which ones (without replacement, from :data:`RANGES`) and each
  magnitude (uniform in its range); the effects go into the capture
  (:mod:`calibration.simulate.injected`): a focus shift, a tilted or a
  curved sensor through the optics (the PSF map computed on that surface:
  the lens's own defocus), the others into the mosaic, before the sensor
  noise, or after it for processing such as sharpening;
* the capture (noise seed = the device's) is measured as ``isp calib loop``
  measures one and the loop runs as a user runs it (``make_base`` of the
  lens, ``close_loop`` with every registry effect tried).

Recorded per case: what went in, what the loop added, which of those are
right (added and put in), missed (put in, not added) and false (added,
not put in), the errors before and after against the loop's noise floor,
what it left unexplained, and the wall seconds. The magnitude ranges are
what a line meets and what the loop's tests use; they are not yet
multiples of measured detection limits.

A focus shift is what the loop base's lens fits anyway (its focus range is
±80 µm, :data:`calibration.fit.proxy.FOCUS_BOUND`), so it is judged by the
sensor defocus the loop reports (:func:`calibration.loop.closure.sensor_defocus_um`:
on axis, against the lens's RMS best focus, the criterion by which the
device was refocused): named where it lies within 30 % of the shift (or
1.5 µm) of the device's true defocus, the shift included. The focus
parameter itself (the last gap) is no judge: it trades against every other
tolerance that moves focus (on cases 1 and 6, no shift put in, it lies 30
and 17 µm from the device's, the defocus 0.6 and 4.8 µm). A device without
a shift whose reported defocus is off by more than the smallest shift put in
(:data:`FALSE_DEFOCUS_UM`) counts as a false focus shift. Both figures are
recorded.

A tilted or curved sensor is taken up the same way, by a lens base that
tilts and bends its own image surface: a device drawn within tolerance
has tilts of 0.1–0.6° and corner curvatures of −13 to +27 µm of its own
(cases 1, 6, 11, 14, 24, 26), as large as those put in. They are judged by
the sensor surface the loop reports
(:func:`calibration.loop.closure.sensor_surface`: the defocus over the
frame, fitted by a plane and a term in r²) against the device's
(:func:`true_surface`, the same fit of its lens's surface plus the sensor
put in): named within 30 % of the tilt or curvature put in (or of the
smallest put in), false where none was put in and the report is further
from the truth than the smallest put in (:data:`FALSE_TILT_DEG`,
:data:`FALSE_CURVATURE_UM`). :func:`rejudge` judges every record by the
rule as it is; a record without the surface is judged without it.

Lateral colour is left out: the loop measures a capture's edges on the
mosaic's green plane, which a shift of the red and blue planes does not
reach.

Cases from :data:`REGISTRY_CASES` on put in one effect each from outside
the registry (:data:`OUTSIDE_RANGES`: a denoiser or JPEG in the chain, a
smudge on the lens), in turn: right when the loop adds nothing (what is
left it reports unexplained, or it is within the noise).

Each case is written to ``benchmarks/results/loop_suite_parts/case_KKK.json``
as it ends, and a recorded case is not run again (``--redo``), so the
suite runs in parts; the summary over the cases recorded so far
(per effect: put in, named; false additions; clean devices given an
effect) is ``loop_suite.json``. Prints one JSON object as the last line.
Usage::

    python -m benchmarks.loop_suite [--cases 24] [--only K [K ...]] [--max-seconds S]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # one BLAS thread per worker, set before numpy loads
    _harness.pin_threads(2, blas=1)

import math  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.forward_fidelity import LENSES, PHONE  # noqa: E402
from benchmarks.loop_clean import run_loop  # noqa: E402

#: the effects put in and their magnitude ranges (each parameter uniform between the two values;
#: defocus in µm and degrees on the sensor, other lengths on a Bayer plane:
#: :mod:`calibration.simulate.injected`)
RANGES = {
    "focus_shift": {"dz_um": (4.0, 12.0)},
    "sensor_tilt": {"tilt_x_deg": (0.0, 0.0), "tilt_y_deg": (0.06, 0.3)},
    "field_curvature": {"dz_corner_um": (4.0, 20.0)},
    "pixel_crosstalk": {"leak": (0.02, 0.06)},
    "veiling_glare": {"share": (0.03, 0.12), "halo_sigma_px": (5.0, 15.0)},
    "sharpening": {"gain": (0.4, 1.2), "sigma_px": (1.0, 1.0)},
}
#: effects outside the loop's registry (:data:`calibration.simulate.injected.OUTSIDE`), one per case
#: after the :data:`REGISTRY_CASES`: the loop must add nothing for them
OUTSIDE_RANGES = {
    "denoise": {"sigma_range": (0.02, 0.04), "sigma_px": (1.0, 2.0)},
    "jpeg": {"quality": (40.0, 80.0)},
    "haze": {"share": (0.1, 0.3), "halo_sigma_px": (8.0, 15.0), "x": (-0.6, 0.6), "y": (-0.4, 0.4),
             "radius": (0.2, 0.4)},
}
#: a reported defocus further than this from the truth, where no shift was put in, is a false
#: focus shift (µm): the smallest shift :data:`RANGES` puts in
FALSE_DEFOCUS_UM = RANGES["focus_shift"]["dz_um"][0]
#: cases 0 … REGISTRY_CASES − 1 draw registry effects; the next ones an effect outside it each
REGISTRY_CASES = 24
#: every effect a case can put in, and its ranges
ALL_RANGES = {**RANGES, **OUTSIDE_RANGES}
SIZE = (2000, 1500)
SEED0 = 100
EXPOSURE = 0.8


def draw_case(k: int) -> dict:
    """Case ``k``: lens, device seed and the effects with their magnitudes."""
    rng = np.random.default_rng(k)
    if k < REGISTRY_CASES:
        names = list(RANGES)
        n = int(rng.integers(0, 3))
        picked = [names[i] for i in sorted(rng.choice(len(names), n, replace=False))]
    else:
        picked = [list(OUTSIDE_RANGES)[(k - REGISTRY_CASES) % len(OUTSIDE_RANGES)]]
    effects = {e: {p: round(float(rng.uniform(lo, hi)), 4) for p, (lo, hi) in ALL_RANGES[e].items()} for e in picked}
    lens = list(LENSES)[k % len(LENSES)]
    return {"case": k, "lens": lens, "seed": SEED0 + k, "effects": effects}


def capture(case: dict, log):
    """The case's device captured with its effects put in, measured as the
    loop measures a capture: ``(observations, device description)``."""
    from calibration.fit.measurements import load_measured, match_sensor
    from calibration.optics.io import read_lens
    from calibration.optics.lens import Sensor
    from calibration.sfr.esfr import DEFAULT_METHOD
    from calibration.simulate.capture import simulate_capture, write_capture
    from calibration.simulate.chart import slanted_square_chart
    from calibration.simulate.device import device_lens
    from calibration.simulate.injected import make_injection

    lens_path = PHONE / f"{LENSES[case['lens']]}.zmx"
    lens = read_lens(lens_path)
    w, h = SIZE
    lens = lens.replace(sensor=Sensor(pixel_pitch_um=lens.sensor.pixel_pitch_um * lens.sensor.width_px / w,
                                      width_px=w, height_px=h))
    device, what = device_lens(lens, "random", seed=case["seed"])
    injections = [make_injection(e, **p) for e, p in case["effects"].items()]
    with tempfile.TemporaryDirectory() as tmp:
        log(f"case {case['case']}: capturing {case['lens']} device {case['seed']} with "
            f"{', '.join(case['effects']) or 'no effect'} ...")
        dng = write_capture(Path(tmp) / "capture.dng",
                            capture=simulate_capture(device, slanted_square_chart(h, w), exposure=EXPOSURE,
                                                     rng=case["seed"], injections=injections))
        obs, _ = load_measured(str(dng), method=DEFAULT_METHOD)
        _, obs = match_sensor(read_lens(lens_path), obs)
    return lens_path, obs, what, true_defocus_um(device, case["effects"]), true_surface(device, obs.sensor,
                                                                                       case["effects"])


def true_defocus_um(device, effects: dict) -> float:
    """The device's sensor defocus on axis with the effects put in, µm (+:
    away from the lens), as :meth:`calibration.loop.base.LensBase.defocus_um`
    measures a fitted lens: its own (≈ 0, the device was refocused) plus a
    focus shift's Δz (a tilt or a curvature is zero on axis)."""
    from calibration.optics.spot import defocus

    return 1e3 * defocus(device) + float(effects.get("focus_shift", {}).get("dz_um", 0.0))


def true_surface(device, sensor, effects: dict) -> dict:
    """The device's sensor against its lens's best focus over the frame
    with the effects put in, as :func:`calibration.loop.closure.sensor_surface`
    measures a fitted lens: the lens's own
    (:func:`calibration.optics.spot.defocus_map`: a device drawn within
    tolerance tilts and bends its image surface by itself) plus the Δz of
    each optical effect put in (:data:`calibration.simulate.injected.INJECTIONS`)."""
    from calibration.loop.closure import fit_surface, surface_points
    from calibration.optics.spot import defocus_map
    from calibration.simulate.injected import INJECTIONS

    pts, half = surface_points(sensor)
    d = defocus_map(device, pts)
    for name, params in effects.items():
        make, where, _ = INJECTIONS.get(name, (None, "", None))
        if where == "optics":
            d = d + make(**params)(pts[:, 0], pts[:, 1], half)
    return fit_surface(pts, d, half)


#: how far a reported quantity may lie from the truth and still name the effect that moves it: this
#: share of the magnitude put in, or of the smallest magnitude :data:`RANGES` puts in
NAMED_SHARE = 0.3
#: a tilt (degree) and a curvature (µm at the corner) reported further than this from the truth,
#: where none was put in, are false: the smallest :data:`RANGES` puts in
FALSE_TILT_DEG = RANGES["sensor_tilt"]["tilt_y_deg"][0]
FALSE_CURVATURE_UM = RANGES["field_curvature"]["dz_corner_um"][0]


def judged(put: dict, added: list, defocus_um: float | None, true_um: float,
           surface: dict | None = None, true_surf: dict | None = None) -> tuple[set, set]:
    """(named, false) of a case: the effects put in that the loop named and
    those it got wrong without their being put in.

    An effect is named when the loop added it, or when what the loop
    reports of the module carries it: a focus shift, a reported defocus
    within 30 % of the shift or 1.5 µm of the truth; a sensor tilt and a
    field curvature, a reported sensor surface (``surface``,
    :func:`calibration.loop.closure.sensor_surface`, against ``true_surf``,
    :func:`true_surface`) whose tilt (both axes) or corner curvature lies
    within :data:`NAMED_SHARE` of the magnitude put in (or of the smallest
    one :data:`RANGES` puts in) of the truth. The lens base takes these up
    by moving its own image surface; what the SFR fixes is where the sensor
    lies against it. False: added, or a defocus, tilt or curvature
    reported further from the truth than :data:`FALSE_DEFOCUS_UM`,
    :data:`FALSE_TILT_DEG` or :data:`FALSE_CURVATURE_UM` where none was put in.

    >>> surf = {"defocus_um": 0.0, "tilt_x_deg": 0.01, "tilt_y_deg": 0.21, "curvature_um": 1.0}
    >>> true = {"defocus_um": 0.0, "tilt_x_deg": 0.0, "tilt_y_deg": 0.2, "curvature_um": 6.0}
    >>> judged({"sensor_tilt": {"tilt_x_deg": 0.0, "tilt_y_deg": 0.1}}, [], 0.0, 0.0, surf, true)
    ({'sensor_tilt'}, {'field_curvature'})
    """
    named = set(put) & set(added)
    false = set(added) - set(put)
    off = None if defocus_um is None else abs(defocus_um - true_um)
    dz = put.get("focus_shift", {}).get("dz_um")
    if dz is not None and off is not None and off <= max(0.3 * abs(dz), 1.5):
        named.add("focus_shift")
    if dz is None and off is not None and off > FALSE_DEFOCUS_UM:
        false.add("focus_shift")
    if surface is None or true_surf is None:
        return named, false
    tilt_off = math.hypot(surface["tilt_x_deg"] - true_surf["tilt_x_deg"], surface["tilt_y_deg"] - true_surf["tilt_y_deg"])
    curv_off = abs(surface["curvature_um"] - true_surf["curvature_um"])
    for name, off, put_mag, false_at in (
            ("sensor_tilt", tilt_off, lambda p: math.hypot(p["tilt_x_deg"], p["tilt_y_deg"]), FALSE_TILT_DEG),
            ("field_curvature", curv_off, lambda p: abs(p["dz_corner_um"]), FALSE_CURVATURE_UM)):
        if name in put and off <= NAMED_SHARE * max(put_mag(put[name]), false_at):
            named.add(name)
        if name not in put and off > false_at:
            false.add(name)
    return named, false


def rejudge(c: dict) -> dict:
    """A case judged by :func:`judged` from what it records: ``right``,
    ``missed`` and ``false`` set. A record without the sensor surface is
    judged without it; one without the true defocus (its focus shifts
    judged by the fitted last gap) keeps its own verdict."""
    if "true_defocus_um" not in c:
        return c
    put = {e: p for e, p in c["effects"].items() if e not in OUTSIDE_RANGES}
    right, false = judged(c["effects"], c["effects_added"], c.get("defocus_um"), c["true_defocus_um"],
                          c.get("sensor_surface"), c.get("true_surface"))
    return {**c, "right": sorted(right), "missed": sorted(set(put) - right), "false": sorted(false)}


def run_case(case: dict, log) -> dict:
    lens_path, obs, what, truth, surface = capture(case, log)
    rep, wall = run_loop(lens_path, obs)
    return rejudge({**case, "device": what, "edges": len(obs), "effects_added": list(rep.effects_added),
            "defocus_um": None if rep.defocus_um is None else round(rep.defocus_um, 2),
            "true_defocus_um": round(truth, 2),
            "sensor_surface": None if rep.sensor_surface is None else
            {k: round(v, 4) for k, v in rep.sensor_surface.items()},
            "true_surface": {k: round(v, 4) for k, v in surface.items()},
            "effect_values": rep.effect_values, "error_before": rep.error_before["sfra_rms"],
            "error_after": rep.error_after["sfra_rms"], "noise_floor": rep.noise_floor,
            "after_over_floor": rep.error_after["sfra_rms"] / rep.noise_floor,
            "chi2_after": rep.error_after["chi2_per_obs"], "unexplained": rep.unexplained,
            "wall_s": round(wall, 1), "seconds_by_step": {k: round(v, 1) for k, v in rep.steps_s.items()},
            "confidence": rep.confidence(),
            # every candidate tried in every round, so that a missed effect's fit can be read
            "trials": [{"effect": t["effect"], "round": t["round"], "gain": round(float(t["gain"]), 4),
                        **{k: t[k] for k in ("z", "folds_improved") if k in t},
                        "values": {k: round(float(v), 4) for k, v in t["values"].items()},
                        "consistent": bool(t["consistent"]),
                        **({"joint_gain": round(float(t["joint_gain"]), 4), "joint_chi2": round(float(t["joint_chi2"]), 3)}
                           if "joint_gain" in t else {})} for t in rep.tried]})


def summarise(cases: list[dict]) -> dict:
    """Per effect: put in and named; false additions per effect; clean
    devices given an effect; the effects the loop kept, and how many of
    them were put in (the precision its confidence must be calibrated
    against: every kept effect, and those kept at ``z`` ≥ 3, where the
    record holds it); the after/floor ratios and wall seconds."""
    per = {e: {"put_in": 0, "named": 0} for e in RANGES}
    outside = {e: {"put_in": 0, "nothing_added": 0} for e in OUTSIDE_RANGES}
    false = {}
    for c in cases:
        for e in c["effects"]:
            if e in outside:
                outside[e]["put_in"] += 1
                outside[e]["nothing_added"] += not c["effects_added"]
                continue
            per[e]["put_in"] += 1
            per[e]["named"] += e in c["right"]
        for e in c["false"]:
            false[e] = false.get(e, 0) + 1
    kept = [(e in c["effects"], c.get("confidence", {}).get(e, {}).get("z")) for c in cases for e in c["effects_added"]]
    sure = [right for right, z in kept if z is not None and z >= 3.0]
    clean = [c for c in cases if not c["effects"]]
    ratio = [c["after_over_floor"] for c in cases]
    return {"cases": len(cases), "per_effect": per, "outside_registry": outside, "false_additions": false,
            "clean_cases": len(clean), "clean_given_an_effect": sum(bool(c["effects_added"]) for c in clean),
            "all_right": sum(not c["missed"] and not c["false"] for c in cases),
            "kept": {"effects": len(kept), "put_in": sum(right for right, _ in kept),
                     "at_z3": len(sure), "at_z3_put_in": sum(sure)},
            "with_sensor_surface": sum(c.get("sensor_surface") is not None for c in cases),
            "after_over_floor_median": round(float(np.median(ratio)), 3) if ratio else None,
            "after_over_floor_max": round(float(np.max(ratio)), 3) if ratio else None,
            "wall_s_median": round(float(np.median([c["wall_s"] for c in cases])), 1) if cases else None,
            "wall_s_max": max((c["wall_s"] for c in cases), default=None)}


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--cases", type=int, default=REGISTRY_CASES + len(OUTSIDE_RANGES),
                    help=f"cases 0 … N − 1 (default {REGISTRY_CASES + len(OUTSIDE_RANGES)}: {REGISTRY_CASES} with "
                         "registry effects, then one per effect outside it)")
    ap.add_argument("--only", type=int, nargs="+", metavar="K", help="run these cases only")
    ap.add_argument("--redo", action="store_true", help="run recorded cases again")
    ap.add_argument("--max-seconds", type=float, default=0.0,
                    help="start no case after this many seconds (0: no limit); the rest runs next time")
    args = ap.parse_args(argv)

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    parts = _harness.results_dir(args) / "loop_suite_parts"
    parts.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    todo = args.only if args.only is not None else range(args.cases)
    for k in todo:
        part = parts / f"case_{k:03d}.json"
        if part.is_file() and not args.redo:
            continue
        if args.max_seconds and time.perf_counter() - t0 > args.max_seconds:
            log(f"--max-seconds {args.max_seconds:g} reached: case {k} and after left for the next run")
            break
        rec = run_case(draw_case(k), log)
        _harness.write_record(part, rec)
        log(f"case {k} ({rec['lens']}): put in {', '.join(rec['effects']) or 'nothing'}; added "
            f"{', '.join(rec['effects_added']) or 'nothing'}; after/floor {rec['after_over_floor']:.2f}; "
            f"{rec['wall_s']} s")
    cases = [rejudge(json.loads(p.read_text())) for p in sorted(parts.glob("case_*.json"))]
    summary = summarise(cases)
    log(json.dumps(summary["per_effect"]))
    # the record is the parts', whichever run wrote them: its command is the plain one, which resumes
    return _harness.publish("loop_suite", {"size": list(SIZE), "seed0": SEED0, "ranges": RANGES,
                                           "outside_ranges": OUTSIDE_RANGES, "summary": summary,
                                           "cases": [row(c) for c in cases]}, args, [])


def _against(c: dict, key: str, fmt: str) -> str:
    """A reported sensor-surface term with the truth in brackets, or "-"."""
    s, t = c.get("sensor_surface"), c.get("true_surface")
    return "-" if not s or not t else f"{fmt.format(s[key] + 0.0)} ({fmt.format(t[key] + 0.0)})"


def row(c: dict) -> dict:
    """A case as one flat table row."""
    def put(e, p):
        return f"{e} ({', '.join(f'{k} {v:g}' for k, v in p.items() if ALL_RANGES[e].get(k) != (0.0, 0.0))})"

    return {"case": c["case"], "lens": c["lens"], "device seed": c["seed"],
            "put in": "; ".join(put(e, p) for e, p in c["effects"].items()) or "nothing",
            "added": ", ".join(c["effects_added"]) or "nothing", "missed": ", ".join(c["missed"]) or "-",
            "false": ", ".join(c["false"]) or "-",
            "defocus µm (true)": "-" if c.get("defocus_um") is None else
            f"{round(c['defocus_um'], 1) + 0.0:+.1f} ({round(c['true_defocus_um'], 1) + 0.0:+.1f})",
            "tilt about y ° (true)": _against(c, "tilt_y_deg", "{:+.3f}"),
            "curvature µm (true)": _against(c, "curvature_um", "{:+.1f}"),
            "SFRA RMS before": round(c["error_before"], 4),
            "after": round(c["error_after"], 4), "floor": round(c["noise_floor"], 4),
            "after / floor": round(c["after_over_floor"], 2), "wall s": c["wall_s"],
            **{f"{k} s": c.get("seconds_by_step", {}).get(k, "-") for k in ("base", "noise", "trials", "confirm", "refits")}}


if __name__ == "__main__":
    main()

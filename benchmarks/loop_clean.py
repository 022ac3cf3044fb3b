"""The loop on clean devices: does its base reach the noise floor?

For each phone lens (e1, e2, e9, e11) the device of ``isp calib simulate
LENS --perturb random --seed 5 --size 2000,1500`` (every tolerance drawn) is
captured twice, and the first capture goes through ``isp calib loop`` as a
user runs it (``make_base`` of the lens, ``close_loop`` with its defaults:
every registry effect tried). Nothing was added to the device, so the right
answer is no effect and a base at the noise floor. Recorded per lens:

* the base's SFRA RMS error and the loop's noise floor (its own estimate
  from the model's noisy renders), their ratio (target ≤ 1.3) and the
  χ² per term (SFRA and the four SFR bands, each over its noise);
* the noise measured independently, as the two captures' SFRA difference
  over √2, and the loop's floor over it (1.0 for a right noise model);
* the normalised residual per SFR band and the LSF asymmetry χ² per term;
* the effects added (target: none) and the run's wall seconds (target
  ≤ 600 s on two cores; the loop's workers are two processes).

The base fits every toleranced kind of perturbation and focus
(:data:`calibration.loop.base.BASE_KINDS`); ``--kinds`` with ``--label``
runs another base and keeps its results apart (``results.variants``), so
that bases can be compared on the same devices.

Results are kept per lens in ``benchmarks/results/loop_clean.json``; a lens
recorded is not run again (``--redo`` runs the lenses named again). Prints
one JSON object as the last line. Usage::

    python -m benchmarks.loop_clean [--lenses e1 e2 e9 e11] [--n-params N]
    python -m benchmarks.loop_clean --label gaps_decenters_tilts --kinds decenter tilt thickness
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # one BLAS thread per worker, set before numpy loads
    _harness.pin_threads(2, blas=1)

import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

from benchmarks.capture_roundtrip import capture_pair, two_capture_noise  # noqa: E402
from benchmarks.forward_fidelity import LENSES, PHONE  # noqa: E402
from calibration.sfr.esfr import DEFAULT_METHOD  # noqa: E402


def run_loop(lens_path, obs, n_params: int | None = None, kinds=None) -> tuple:
    """``isp calib loop --lens LENS --measured CAPTURE`` on measured ``obs``,
    its base over the perturbations of ``kinds`` (default
    :data:`~calibration.loop.base.BASE_KINDS`): (LoopReport, wall s)."""
    from calibration.loop.base import BASE_KINDS, make_base
    from calibration.loop.closure import close_loop

    t0 = time.perf_counter()
    base = make_base(str(lens_path), obs, n_params=n_params, kinds=kinds or BASE_KINDS)
    rep = close_loop(base, obs)
    return rep, time.perf_counter() - t0


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--lenses", nargs="+", default=list(LENSES), choices=list(LENSES))
    ap.add_argument("--seed", type=int, default=5, help="the device of each lens (isp calib simulate --seed)")
    ap.add_argument("--size", type=int, nargs=2, default=[2000, 1500], metavar=("W", "H"))
    ap.add_argument("--n-params", type=int, default=None,
                    help="the lens base's most sensitive perturbations (default all, as isp calib loop)")
    ap.add_argument("--redo", action="store_true", help="run the lenses again even where recorded")
    ap.add_argument("--kinds", nargs="+", metavar="KIND",
                    help="the base's kinds of perturbation (default calibration.loop.base.BASE_KINDS); with "
                         "--label, to compare bases")
    ap.add_argument("--label", help="keep these results apart, under results.variants[LABEL]")
    args = ap.parse_args(argv)

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    from calibration.loop.base import BASE_KINDS

    kinds = tuple(args.kinds) if args.kinds else BASE_KINDS
    settings = {"seed": args.seed, "size": list(args.size), "n_params": args.n_params, "method": DEFAULT_METHOD,
                "base_kinds": list(kinds)}
    path = _harness.results_dir(args) / "loop_clean.json"
    record = json.loads(path.read_text()).get("results", {}) if path.is_file() else {}
    variants = record.pop("variants", {})
    mine = record if args.label is None else variants.get(args.label, {})
    done = mine.get("lenses", {}) if mine.get("settings") == settings else {}

    def save():
        if args.label is None:
            return _harness.publish("loop_clean", {"settings": settings, "lenses": done, "variants": variants},
                                    args, argv)
        variants[args.label] = {"settings": settings, "lenses": done}
        return _harness.publish("loop_clean", {**record, "variants": variants}, args, argv)

    for name in args.lenses:
        if name in done and not args.redo:
            log(f"{name}: recorded, skipped (--redo to run again)")
            continue
        lens_path = PHONE / f"{LENSES[name]}.zmx"
        log(f"{name}: capturing the device twice ...")
        device, what, nominal, obs = capture_pair(lens_path, args.seed, args.size, 0.8, [DEFAULT_METHOD], log)
        first, second = obs[DEFAULT_METHOD]
        repeat = two_capture_noise(first, second)
        rep, wall = run_loop(lens_path, first, args.n_params, kinds)
        before = rep.error_before
        rec = {"lens": LENSES[name], "device": what, "edges": len(first),
               "base_sfra_rms": before["sfra_rms"], "noise_floor": rep.noise_floor,
               "ratio": before["sfra_rms"] / rep.noise_floor, "chi2_per_term": before["chi2_per_obs"],
               "two_capture_noise": repeat, "floor_over_two_capture_noise": rep.noise_floor / repeat,
               "bands": before["normalised_rms_per_band"], "asymmetry_chi2_per_term": (rep.asymmetry or {}).get("chi2_per_term"),
               "effects_added": list(rep.effects_added), "effects": ", ".join(rep.effects_added) or "none",
               "wall_s": round(wall, 1)}
        done[name] = rec
        log(f"{name}: base SFRA {rec['base_sfra_rms']:.4f}, floor {rec['noise_floor']:.4f} ({rec['ratio']:.2f}×; "
            f"two captures {repeat:.4f}), χ² {rec['chi2_per_term']:.2f}, effects {rec['effects_added'] or 'none'}, "
            f"{rec['wall_s']} s")
        save()
    return save()


if __name__ == "__main__":
    main()

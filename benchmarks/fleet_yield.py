"""A production line's fleet of e9 modules through ``isp calib fleet``:
what the yield check sees, and what it costs per device.

The modules: ``--within`` lenses drawn within the design's tolerances
(the same draws as ``benchmarks/device_eval.py``: ``eval_lenses(e9, N,
seed)``) and, for each ``SCALE:SEED`` of ``--beyond``, one lens drawn at
that multiple of the tolerances. Each is simulated as a 2000 × 1500 chart
capture (``isp calib simulate``), then the fleet runs on the folder
(:func:`calibration.fleet.run_fleet`, the line's quick fit, ``--effects``
as given; default no loop, the loop's cost is measured apart) on
``--executor`` with ``--workers``.

Reported per module: its group (within, or the scale), the measured SFRA
over the nominal design's per field ring, the fit's SFRA RMS error before
and after, how many of the fitted parameters lie past one tolerance, the
device's descriptor RMS, the seconds. Then per group the range of the
worst ring's ratio, and the fleet's throughput.

Second part (``--descriptor-draws``): the device descriptor's RMS, in
spreads of the basis's draws, of lenses drawn at 0.5, 1, 2 and 3 times
the tolerances (the production basis ``--basis``): does it grow with how
far out a lens is?

Prints one JSON object as its last line. Usage::

    python -m benchmarks.fleet_yield --basis out/e9_basis.npz [--work out/fleet_yield]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = _harness.ROOT
E9 = ROOT.parent / "shared" / "data" / "lenses" / "phone" / "US-12210142-B2-e9.zmx"


def _beyond(text: str) -> list[tuple[float, int]]:
    out = []
    for item in text.split(","):
        if item.strip():
            scale, seed = item.split(":")
            out.append((float(scale), int(seed)))
    return out


def modules(lens, within: int, seed: int, beyond) -> list[tuple[str, str, object]]:
    """``(name, group, lens)`` of the fleet's modules."""
    from calibration.optics.perturb import nominal
    from restoration.evaluate.rings import eval_lenses
    from restoration.synth.optics import draw_lenses

    out = [(f"within_{d}", "within", pl) for d, pl in enumerate(eval_lenses(lens, within, seed))]
    for scale, s in beyond:
        pl = draw_lenses(nominal(lens), 2, np.random.default_rng(s), tolerance_scale=scale)[1]
        out.append((f"x{scale:g}_{s}", f"{scale:g}x tolerance", pl))
    return out


def simulate(mods, folder: Path) -> None:
    """Each module's chart capture, ``folder/NAME.dng`` (kept between runs)."""
    from calibration.fit.proxy import save_proxy
    from isp.cli.main import main as isp

    folder.mkdir(parents=True, exist_ok=True)
    lenses = folder.parent / "lenses"
    lenses.mkdir(exist_ok=True)
    for name, _, pl in mods:
        cap = folder / f"{name}.dng"
        if cap.is_file():
            continue
        lens_file = lenses / f"{name}.json"
        save_proxy(lens_file, pl.nominal, pl.perturbation)
        if isp(["calib", "simulate", str(lens_file), "-o", str(cap), "--size", "2000,1500"]) != 0:
            raise RuntimeError(f"{cap}: the simulation failed")


def descriptor_study(lens, basis_file: str, draws: int) -> dict:
    """Descriptor RMS (spreads) of lenses drawn at several tolerance scales."""
    from calibration.fit.device import describe, load_basis
    from calibration.optics.perturb import nominal
    from isp.runtime.executor import pool_executor
    from restoration.synth.optics import draw_lenses

    basis = load_basis(basis_file, lens)
    out = {}
    with pool_executor(2) as ex:
        for scale in (0.5, 1.0, 2.0, 3.0):
            rms = []
            for s in range(draws):
                pl = draw_lenses(nominal(lens), 2, np.random.default_rng(9000 + s), tolerance_scale=scale)[1]
                d = describe(pl, basis, basis.size, executor=ex)
                rms.append(float(np.sqrt(np.mean(d ** 2))))
            out[f"{scale:g}"] = {"rms": [round(v, 3) for v in rms], "median": round(float(np.median(rms)), 3)}
            print(f"descriptor RMS at {scale:g}x tolerance: {out[f'{scale:g}']['rms']}", flush=True)
    return {"basis_components": basis.size, "grid": list(basis.grid), "draws_per_scale": draws, "by_scale": out}


def projection(rep: dict, workers: int, captures: Path, basis: Path) -> dict:
    """Devices per hour for N nodes, from this run's seconds of worker
    time per device (wall time × workers / devices fitted) and what each
    node and each device must receive."""
    per_device = rep["wall_s"] * workers / max(1, rep["fitted_now"])
    caps = sorted(captures.glob("*.dng"))
    mb = float(np.median([c.stat().st_size for c in caps])) / 2 ** 20 if caps else 0.0
    rows = []
    for nodes in (1, 8, 32, 128):
        for cores in (2, 16):
            per_hour = nodes * cores * 3600 / per_device
            rows.append({"nodes": nodes, "cores per node": cores, "devices per hour": round(per_hour),
                         "capture MB/s in": round(per_hour * mb / 3600, 2)})
    return {"worker_s_per_device": round(per_device, 1), "capture_mb": round(mb, 2),
            "basis_mb": round(basis.stat().st_size / 2 ** 20, 2), "table": rows}


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--basis", required=True, help="the e9 descriptor basis (isp calib basis)")
    ap.add_argument("--work", default="out/fleet_yield", help="captures, lenses and devices (default out/fleet_yield)")
    ap.add_argument("--within", type=int, default=6, help="modules drawn within tolerance (default 6)")
    ap.add_argument("--seed", type=int, default=0, help="of the within-tolerance draws (default 0)")
    ap.add_argument("--beyond", type=_beyond, default=_beyond("2:201,3:301"), metavar="SCALE:SEED,...",
                    help="modules drawn at SCALE times the tolerances (default 2:201,3:301)")
    ap.add_argument("--effects", default="none", help="the fleet's --effects (default none)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--executor", default="processes", help="processes (default) or ray")
    ap.add_argument("--descriptor-draws", type=int, default=4, help="lenses per scale in part two (0: skip)")
    args = ap.parse_args(argv)
    from calibration.fleet import FleetSettings, parse_effects, run_fleet
    from isp.runtime.executor import pool_executor
    from restoration.synth.optics import load_lens

    lens = load_lens(E9)            # as benchmarks/device_eval.py reads it: the same draws
    work = Path(args.work)
    mods = modules(lens, args.within, args.seed, args.beyond)
    t0 = time.perf_counter()
    simulate(mods, work / "captures")
    sim_s = time.perf_counter() - t0
    settings = FleetSettings(effects=parse_effects(args.effects))
    ex = pool_executor(args.workers, progress=True, executor=args.executor, imports=("rawpy", "calibration.fleet"))
    devices = work / f"devices_{args.executor}"
    with ex:
        rep = run_fleet(work / "captures", E9, args.basis, devices, settings, executor=ex)
    group = {f"{n}.dng": g for n, g, _ in mods}
    rows = [{"module": r["capture"], "group": group.get(r["capture"], "?"),
             "sfra_ratio_centre": r["sfra_ratio_rings"][0], "sfra_ratio_middle": r["sfra_ratio_rings"][1],
             "sfra_ratio_corner": r["sfra_ratio_rings"][2], "sfra_rms_nominal": round(r["sfra_rms_before"], 4),
             "sfra_rms_fitted": round(r["sfra_rms_after"], 4),
             "parameters_past_one_tolerance": r["parameters_past_one_tolerance"],
             "descriptor_rms": r["descriptor_rms"], "below_spec": r["below_spec"], "seconds": r["seconds"]}
            for r in rep["rows"]]
    by_group = {}
    for r in rep["rows"]:
        by_group.setdefault(group.get(r["capture"], "?"), []).append(r)
    groups = {}
    for name, members in by_group.items():
        worst = [r["sfra_ratio_min"] for r in members]
        past = [r["parameters_past_one_tolerance"] for r in members]
        groups[name] = {"modules": len(members), "worst_ring_min": min(worst), "worst_ring_max": max(worst),
                        "past_one_tolerance": f"{min(past)}–{max(past)}"}
    out = {"modules": rows, "groups": groups, "simulate_s": round(sim_s, 1),
           "fleet": {k: rep[k] for k in ("devices", "failed", "fitted_now", "wall_s", "device_seconds_median",
                                         "devices_per_hour", "executor", "yield")},
           "settings": rep["settings"]}
    for name, g in groups.items():
        print(f"{name}: {g['modules']} modules, worst-ring SFRA ratio {g['worst_ring_min']:.2f}–"
              f"{g['worst_ring_max']:.2f}, parameters past one tolerance {g['past_one_tolerance']}")
    out["projection"] = projection(rep, ex.workers, work / "captures", Path(args.basis))
    if args.descriptor_draws:
        out["descriptor"] = descriptor_study(lens, args.basis, args.descriptor_draws)
    return _harness.publish("fleet_yield", out, args, argv)


if __name__ == "__main__":
    main()

"""A module's calibration to corrected output, as a production line runs it.

For each of ``--devices`` modules of a lens design (drawn within tolerance
by ``isp calib simulate --perturb random --seed S``), untimed: its chart
capture (``--size``, default 2000 × 1500 at the design's 2.8 µm binned
pitch) and a 12 MP photo it took (``--photo-size``; a chart scene: the
content does not change the time). Timed, each as its own process,
start-up included, 2 cores:

1. ``isp calib fit --basis`` on the chart capture: the module's
   ``device.json``. Both ways: the quick fit a line would run
   (``--fine-iter 0``, the coarse 5 × 7 sub-grid's fit: the descriptor's own
   regions) and the full coarse-to-fine fit;
2. ``isp process photo.dng --correction MODEL --device device.json``: the
   photo corrected by the shared model with that file.

No training anywhere: the peer in the same run is the full fit, and the
target is a module's calibration to its corrected output in ≤ 3 minutes.

``--speed`` first times the conditioned model itself as
``benchmarks/correction.py`` times the packaged one: its INT8 file against
its FP32 export (``--model``'s name without ``.int8``, else its dequantized
twin) on a 12 MP frame, 2
threads, each at its best of ``--tile-sizes``; ``--also NAME=M.int8.onnx``
adds other models (a narrower network) in the same run. Targets: INT8 ≥ 2×
its float twin, ≤ 1.2 s.
What each descriptor is worth is ``benchmarks/device_eval.py``'s to say
(its ``--quick`` arm).

Run::

    python -m benchmarks.device_workflow --model out/e9_device48/e9_device.int8.onnx --basis out/e9_basis.npz
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":
    _harness.pin_threads(2, blas=1)

import json  # noqa: E402
import shutil  # noqa: E402
import statistics  # noqa: E402
from pathlib import Path  # noqa: E402

from benchmarks.device_eval import line_arguments  # noqa: E402
from benchmarks.forward_fidelity import LENSES, PHONE  # noqa: E402

TARGET_S = 180.0


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    line_arguments(ap, devices=1, seed=100)
    ap.add_argument("--photo-size", default="4000,3000", help="the photo's W,H (default 4000,3000)")
    ap.add_argument("--no-full", action="store_true", help="time the quick fit only")
    ap.add_argument("--work", default="out/device_workflow", help="captures and fits (default out/device_workflow)")
    ap.add_argument("--speed", action="store_true", help="time the model's INT8 file against its FP32 export first")
    ap.add_argument("--also", nargs="+", default=[], metavar="NAME=M.int8.onnx",
                    help="other conditioned models to time with --speed")
    ap.add_argument("--tile-sizes", type=int, nargs="+",
                    help="tile sizes for --speed (default benchmarks/correction.py's, from 448 px: float "
                         "can run fastest on small tiles)")
    ap.add_argument("--runs", type=int, default=3, help="warm runs per model and tile for --speed (default 3)")
    ap.add_argument("--no-workflow", action="store_true", help="--speed alone")
    ap.add_argument("--fp32", help="--model's FP32 twin for --speed (default: its name without .int8; another "
                                   "export of the same network where the model ships without one)")
    ap.add_argument("--label", help="publish as device_workflow_LABEL.json (another model's run beside the "
                                    "recorded one)")
    args = ap.parse_args(argv)
    res = {"lens": LENSES[args.lens], "target_s": TARGET_S}
    if args.speed:
        res["speed"] = speed({"model": args.model, **dict(a.split("=", 1) for a in args.also)}, args,
                             {"model": args.fp32} if args.fp32 else {})
    if not args.no_workflow:
        res.update(workflow(args))
    return _harness.publish("device_workflow", res, args, argv, label=args.label)


def speed(models: dict, args, twins: dict | None = None) -> dict:
    """``benchmarks/correction.py`` on each INT8 file and its FP32 export
    (``twins[name]`` where given, else the file beside it without
    ``.int8``), or where there is none its dequantized twin (``peer``
    says which)."""
    import tempfile

    from benchmarks import correction

    out = {}
    for name, int8 in models.items():
        fp32 = Path((twins or {}).get(name) or str(int8).replace(".int8.onnx", ".onnx"))
        if name in (twins or {}) and not fp32.is_file():
            raise SystemExit(f"device_workflow: {fp32}: no such FP32 export of {int8}")
        peer = ["--fp32", str(fp32)] if fp32.is_file() and fp32 != Path(int8) else []
        with tempfile.TemporaryDirectory() as tmp:
            tiles = ["--tile-sizes", *map(str, args.tile_sizes)] if args.tile_sizes else []
            r = correction.main([*peer, "--int8", str(int8), "--runs", str(args.runs), *tiles,
                                 "--profile", "--results", tmp])
        out[name] = {k: r[k] for k in ("int8_model", "fp32_s", "int8_s", "speedup", "tile_fp32", "tile_int8",
                                       "ms_per_mp_int8", "peak_rss_mb", "speedup_same_tile", "window_speedup",
                                       "conv_speedup", "rest_speedup")}
        out[name]["peer"] = "FP32 export" if peer else "dequantized twin"
        out[name]["meets_targets"] = bool(r["speedup"] >= 2.0 and r["int8_s"] <= 1.2)
    return out


def workflow(args) -> dict:
    """The timed line, per module."""
    from isp.cli.main import main as isp

    lens = PHONE / f"{LENSES[args.lens]}.zmx"
    isp_cmd, env = _harness.isp_command(), _harness.child_env()
    rows = []
    for i in range(args.devices):
        seed = args.seed + i
        work = Path(args.work) / f"{args.lens}_{seed}"
        work.mkdir(parents=True, exist_ok=True)
        chart, photo = work / "chart.dng", work / "photo.dng"
        for path, size in ((chart, args.size), (photo, args.photo_size)):
            if not path.is_file() and isp(["calib", "simulate", str(lens), "-o", str(path), "--size", size,
                                           "--perturb", "random", "--seed", str(seed)]) != 0:
                raise SystemExit(f"device_workflow: {path}: the simulation failed")
        row = {"module_seed": seed}
        for name, extra in (("quick", ["--fine-iter", "0"]), ("full", [])):
            if name == "full" and args.no_full:
                continue
            fit = work / f"fit_{name}"
            if fit.exists():
                shutil.rmtree(fit)
            c = _harness.run_child([*isp_cmd, "calib", "fit", "--lens", str(lens), "--measured", str(chart),
                                    "--basis", args.basis, "-o", str(fit), "--workers", "2",
                                    *extra], env)
            out = work / f"photo_{name}.jpg"
            p = _harness.run_child([*isp_cmd, "process", str(photo), "-o", str(out), "--correction", args.model,
                                    "--device", str(fit / "device.json")], env)
            f = json.loads((fit / "fit.json").read_text())
            row[name] = {"fit_s": round(c.wall_s, 1), "fit_peak_mb": round(c.peak_mb), "process_s": round(p.wall_s, 2),
                         "process_peak_mb": round(p.peak_mb), "total_s": round(c.wall_s + p.wall_s, 1),
                         "lens_evaluations": f.get("evaluations"),
                         "sfra_rms_after": round(f["errors"]["after"]["sfra_rms"], 4)}
            print(f"module {seed}, {name} fit: {c.wall_s:.0f} s, process {p.wall_s:.1f} s, "
                  f"total {c.wall_s + p.wall_s:.0f} s (target {TARGET_S:.0f} s)", flush=True)
        rows.append(row)
    totals = {n: statistics.median(r[n]["total_s"] for r in rows) for n in ("quick", "full") if n in rows[0]}
    return {"modules": rows, "median_total_s": totals,
            "quick_meets_target": all(r["quick"]["total_s"] <= TARGET_S for r in rows)}


if __name__ == "__main__":
    main()

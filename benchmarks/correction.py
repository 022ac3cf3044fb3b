"""FP32 vs INT8 correction on a 12 MP frame, 2 threads.

Runs the ``correction`` stage (onnxruntime, its tiling, two intra-op
threads, sequential) with an exported model and its INT8 copy on a
4000 × 3000 camera-RGB frame: one cold run (memory: the process's peak
resident set over the run, ``VmHWM`` reset through ``/proc/self/clear_refs``
where allowed), then ``--runs`` warm runs whose median is reported, with
the fastest and slowest (``min_s``, ``max_s``). The peer in the same run
is the FP32 model itself: ``speedup`` = FP32 / INT8.

**Each model at its own best tile size.** The tile size moves the two
models in opposite directions: FP32's activations are 4× larger and fall
out of cache first, so FP32 is fastest on 448–640 px tiles and INT8 on
1,024–1,536 px (the speed table of the results pages). Timing both at
the INT8 model's tile flatters INT8 (by a third on a depthwise model:
1.85× against 1.40×). So every model is timed at each of ``--tile-sizes`` (default
:data:`SWEEP`, plus the model's own ``tile_size``) and ``fp32_s``,
``int8_s`` and ``speedup`` are each model's best; ``speedup_same_tile``
is the ratio at the INT8 model's own tile, and ``sweep`` holds every
median. ``--tile-size T`` times both at ``T`` only. The runs alternate
between the two models and are spread over two passes of the tile sizes,
the second reversed (:func:`sweep_models`), so that the machine's drift
falls on both models alike. Then the INT8 model at its best tile once
more, as the stage runs a frame of several tiles (two side by side, one
intra-op thread each) against one tile at a time on both threads,
alternated run by run (``tiles_at_once``).

Models: by default the packaged INT8 model and its FP32 twin
(:func:`export.quantize.dequantize_qdq`: the same graph with the weights
folded back to float and the activation Q/DQ pairs removed, so a fresh
checkout measures the ratio without a checkpoint; its tile margin measured
anew, :func:`export.onnx_export.remeasure_overlap`, since the INT8 file's
is wider for INT8's sake); ``--fp32 M.onnx --int8
M.int8.onnx`` as written by ``isp export CHECKPOINT -o M.onnx --int8 ...``;
with ``--checkpoint CKPT --calib-data DIR`` they are exported first into a
temporary folder.

Run::

    python -m benchmarks.correction                       # the packaged model and its FP32 twin
    python -m benchmarks.correction --size 1000x750 --runs 1 --tile-size 512   # a quick look
    python -m benchmarks.correction --fp32 out/e9_default/e9.onnx --int8 out/e9_default/e9.int8.onnx

Last line: a JSON object with ``fp32_s``, ``int8_s``, ``speedup`` (each
at its best tile: ``tile_fp32``, ``tile_int8``), ``speedup_same_tile``,
``ms_per_mp_int8``, ``peak_rss_mb``, ``sweep``, ``tiles_at_once``. Targets: INT8 ≤ 2 s per 12 MP frame
(≤ 170 ms/MP) and ≥ 2× faster than FP32.
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: ONNX Runtime's own threads do the work, BLAS one
    _harness.pin_threads(2, blas=1)

import json  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.correction_tiling import measure_stage  # noqa: E402


#: tile sizes (px, context included) every model is timed at by default
SWEEP = (448, 512, 640, 768, 1024, 1536)


def _export(checkpoint: str, calib_data: str, directory: Path) -> tuple[Path, Path]:
    from export.onnx_export import export_onnx
    from export.quantize import SynthCalibration, quantize_int8

    fp32 = directory / "model.onnx"
    int8 = directory / "model.int8.onnx"
    export_onnx(checkpoint, fp32)
    quantize_int8(fp32, int8, SynthCalibration(calib_data, 16))
    return fp32, int8


def _stage(path: Path, frame, threads: int, tile_size: int | None):
    from modules.correction import Correction

    stage = Correction(model=path, threads=threads, progress=False, tile_size=tile_size)
    stage.check(frame.domain)
    return stage


def _run(stage, frame, memory: bool = False) -> dict:
    r = measure_stage(stage, frame, memory=memory)
    # each output is dropped before the next run, as a pipeline drops a frame it has passed on:
    # kept alive, every run's 144 MB output is fresh memory from the kernel (page faults measured
    # at 0.05-0.3 s per 12 MP frame on top of the stage's own 0.1 s)
    del r["out"]
    return r


def _summary(tiling: tuple, frame, cold: dict, warm: list[dict]) -> dict:
    from modules.common.tiling import plan_tiles

    secs = [r["seconds"] for r in warm]
    run = _harness.spread(secs)
    model = statistics.median(r["model_seconds"] for r in warm)
    tiles = plan_tiles(frame.data.shape[:2], *tiling)
    computed = sum(t.window_shape[0] * t.window_shape[1] for t in tiles)  # overlap included
    return {"median_s": round(run.median, 3), "min_s": round(run.min, 3), "max_s": round(run.max, 3),
            "runs_s": secs, "cold_s": cold["seconds"],
            "peak_rss_delta_mib": cold["peak_rss_delta_mib"], "tiles": tiling,
            # inside the model, per megapixel it computed (the network's own rate), and outside it
            "model_s": round(model, 3), "model_ms_per_computed_mp": round(1e9 * model / computed, 1),
            "computed_over_frame": round(computed / frame.data.shape[0] / frame.data.shape[1], 3),
            "outside_model_s": round(run.median - model, 3)}


def tiles_at_once(path: Path, frame, threads: int, tile: int, runs: int) -> dict:
    """The INT8 model at ``tile`` as the stage runs it (``threads`` tiles
    side by side, one intra-op thread each) and one tile at a time on
    ``threads`` intra-op threads, alternated run by run: median seconds."""
    from modules.correction import Correction

    class OneTileAtATime(Correction):
        def workers(self, tiles: int) -> int:
            return 1

    one = OneTileAtATime(model=path, threads=threads, progress=False, tile_size=tile)
    stages = {"side_by_side_s": _stage(path, frame, threads, tile), "one_at_a_time_s": one}
    secs = {k: [] for k in stages}
    for st in stages.values():   # each session built and warm before anything is timed
        _run(st, frame)
    for _ in range(runs):
        for k, st in stages.items():
            secs[k].append(_run(st, frame)["seconds"])
    return {"tile": tile, **{k: round(statistics.median(v), 3) for k, v in secs.items()}}


def sweep_models(paths: dict, frame, threads: int, runs: int, sizes: list[int], log=print) -> dict:
    """``{tile: {name: timing}}`` for every model of ``paths`` (name → .onnx)
    at every tile size, ``runs`` warm runs each (median).

    The runs alternate between the models at each tile and are spread over
    two passes of the sizes, the second in reverse order: this shared
    machine's speed drifts by ±10 % within minutes (one INT8 file measured
    1.73× and 1.47× within 20 minutes when each sweep ran its sizes once,
    in order), and a drift now falls on every model and size alike instead
    of on whichever was timed last. The first visit of a (model, tile)
    makes the cold run that measures memory; a later visit makes one
    untimed run first.
    """
    cold, warm, tiling = {}, {(n, t): [] for n in paths for t in sizes}, {}
    first = -(-runs // 2)
    for order, k in ((sizes, first), (sizes[::-1], runs - first)):
        for t in order if k else ():
            stages = {n: _stage(p, frame, threads, t) for n, p in paths.items()}
            for n, stage in stages.items():
                r = _run(stage, frame, memory=(n, t) not in cold)
                cold.setdefault((n, t), r)
                tiling[(n, t)] = stage.tiling()
            for _ in range(k):
                for n, stage in stages.items():
                    warm[(n, t)].append(_run(stage, frame))
            del stages
    out = {t: {n: _summary(tiling[(n, t)], frame, cold[(n, t)], warm[(n, t)]) for n in paths} for t in sizes}
    for t in sizes:
        log(f"  tile {t} px: " + ", ".join(f"{n.upper()} {out[t][n]['median_s']:.2f} s" for n in paths))
    return out


def _peak_mb(*timings: dict) -> float:
    """The largest peak-RSS growth of :func:`sweep_models` timings, in MB (10⁶ bytes)."""
    return round(max(t["peak_rss_delta_mib"] for t in timings) * 1.048576, 1)


def op_shares(path: Path, threads: int, side: int, runs: int = 5) -> dict:
    """Share of the model's kernel time per operator type (ONNX Runtime's
    profiler, the stage's session options) on one window of ``side``²
    pixels, the size of a 1,024-px tile with its context: ``{op: percent}``,
    largest first, ``top_nodes`` (the eight slowest nodes, same unit) and
    ``ms`` per run, ``conv_ms`` the convolutions' share of it; ``node_ms``:
    every node's ms per run."""
    import onnxruntime as ort

    from modules.correction import model_info, pack_input, session_options

    opts = session_options(threads)
    opts.enable_profiling = True
    with tempfile.TemporaryDirectory() as d:
        opts.profile_file_prefix = str(Path(d) / "ort")
        sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        info = model_info(sess)
        rng = np.random.default_rng(0)
        x = (0.2 + 0.3 * rng.random((1, info.in_channels - 3 * info.packing ** 2 + 3, side, side))).astype(np.float32)
        feed = {info.input_name: pack_input(x, info.packing)}
        sess.run(None, feed)   # warm-up; ORT profiles it too, hence runs + 1 below
        for _ in range(runs):
            sess.run(None, feed)
        events = json.loads(Path(sess.end_profiling()).read_text())
    per_op: dict[str, float] = {}
    per_node: dict[str, float] = {}
    for e in events:
        if e.get("cat") == "Node" and e["name"].endswith("_kernel_time"):
            per_op[e["args"]["op_name"]] = per_op.get(e["args"]["op_name"], 0.0) + e["dur"]
            node = f"{e['name'][:-len('_kernel_time')]} ({e['args']['op_name']})"
            per_node[node] = per_node.get(node, 0.0) + e["dur"]
    total = sum(per_op.values())
    shares = {k: round(100 * v / total, 1) for k, v in sorted(per_op.items(), key=lambda kv: -kv[1])}
    # the slowest nodes: one conv of an odd shape can cost more than all the others of its type
    # (the packed head at 12 output channels, see restoration.nn.network.HEAD_CHANNEL_MULTIPLE)
    top = {k: round(100 * v / total, 1) for k, v in sorted(per_node.items(), key=lambda kv: -kv[1])[:8]}
    conv = sum(v for k, v in per_op.items() if k.endswith("Conv"))   # Conv, QLinearConv, FusedConv
    return {"ms": round(total / 1000 / (runs + 1), 1), "conv_ms": round(conv / 1000 / (runs + 1), 1),
            "percent": shares, "top_nodes": top,
            "node_ms": {k: v / 1000 / (runs + 1) for k, v in per_node.items()}}


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--fp32", help="exported FP32 model (.onnx)")
    ap.add_argument("--int8", help="its INT8 copy (.onnx); alone: the FP32 peer is its dequantized twin "
                    "(default: the packaged model)")
    ap.add_argument("--checkpoint", help="or: a checkpoint to export first (needs --calib-data)")
    ap.add_argument("--calib-data", help="synth folder for the INT8 calibration")
    ap.add_argument("--size", default="4000x3000", help="W×H (default 4000x3000, 12 MP)")
    ap.add_argument("--runs", type=int, default=3, help="warm runs per model (median; default 3)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--tile-size", type=int, help="time both models at this tile size only (px)")
    ap.add_argument("--tile-sizes", type=int, nargs="+", default=list(SWEEP),
                    help="tile sizes to time each model at, its best reported (px; default "
                         f"{' '.join(map(str, SWEEP))}, plus the model's own)")
    ap.add_argument("--profile", action="store_true",
                    help="also the share of each operator type in each model's time, on one window of "
                         "float's best tile on one thread, and INT8's speed-up on its convolutions and on "
                         "the rest")
    args = ap.parse_args(argv)
    _harness.pin_threads(args.threads, blas=1)
    w, h = (int(v) for v in args.size.lower().split("x"))

    import onnx

    from export.onnx_export import remeasure_overlap
    from export.quantize import dequantize_qdq
    from isp import CFA, CameraMeta, Domain, Frame
    from modules.correction import model_info, onnx_session, resolve_model

    with tempfile.TemporaryDirectory() as tmp:
        if args.checkpoint:
            fp32, int8 = _export(args.checkpoint, args.calib_data, Path(tmp))
        elif args.fp32 and args.int8:
            fp32, int8 = Path(args.fp32), Path(args.int8)
        elif args.fp32:
            ap.error("--fp32 needs its --int8 copy")
        else:
            int8 = Path(args.int8) if args.int8 else resolve_model("default")
            fp32 = Path(tmp) / "fp32_twin.onnx"
            onnx.save(dequantize_qdq(onnx.load(str(int8))), str(fp32))
            # the twin's own tile margin: the INT8 file's is wider (its rounding needs it, see
            # export.onnx_export), and timing float at it would be unfair to float
            remeasure_overlap(fp32)
        meta = CameraMeta(cfa=CFA.RGGB, raw_size=(h, w), active_area=(0, 0, h, w))
        rng = np.random.default_rng(0)
        # a smooth scene with texture: the same work as a photograph for a conv net
        img = np.clip(0.25 + 0.1 * rng.standard_normal((h, w, 3)).astype(np.float32), 0, 1)
        frame = Frame(img, Domain.CAMERA_RGB, meta)
        own = model_info(onnx_session(int8, args.threads)).tile_size
        sizes = [args.tile_size] if args.tile_size else sorted(set(args.tile_sizes) | {own})
        # the first stage built in a process ran up to 1.6x slower (allocator and page-cache warm-up):
        # one throwaway run of each model before anything is timed
        for path in (fp32, int8):
            _run(_stage(path, frame, args.threads, sizes[0]), frame)
        sweep = sweep_models({"fp32": fp32, "int8": int8}, frame, args.threads, args.runs, sizes,
                             log=lambda m: print(m, flush=True))
        t32 = min(sizes, key=lambda t: sweep[t]["fp32"]["median_s"])
        t8 = min(sizes, key=lambda t: sweep[t]["int8"]["median_s"])
        r32, r8 = sweep[t32]["fp32"], sweep[t8]["int8"]
        same_tile = own if own in sweep else sizes[0]   # --tile-size: the one tile timed
        at_once = tiles_at_once(int8, frame, args.threads, t8, args.runs)
        same = sweep[same_tile]
        # every node's time stays out of the JSON (benchmarks/int8_form.py reads it). The window is
        # float's best tile on one thread, as the stage runs tiles side by side: the kernels' ratio
        # where float runs fastest, which bounds the stage's
        profile = ({k: {f: v for f, v in op_shares(p, 1, t32).items() if f != "node_ms"}
                    for k, p in (("fp32", fp32), ("int8", int8))} if args.profile else None)
    mp = w * h / 1e6
    result = {"size": f"{w}x{h}", "threads": args.threads, "runs": args.runs,
              "fp32_s": r32["median_s"], "int8_s": r8["median_s"],
              "speedup": round(r32["median_s"] / r8["median_s"], 3), "tile_fp32": t32, "tile_int8": t8,
              "speedup_same_tile": round(same["fp32"]["median_s"] / same["int8"]["median_s"], 3),
              "sweep": {str(t): {"fp32_s": v["fp32"]["median_s"], "int8_s": v["int8"]["median_s"],
                                 "fp32_range_s": [v["fp32"]["min_s"], v["fp32"]["max_s"]],
                                 "int8_range_s": [v["int8"]["min_s"], v["int8"]["max_s"]],
                                 "peak_rss_mb": _peak_mb(v["fp32"], v["int8"])} for t, v in sweep.items()},
              "ms_per_mp_fp32": round(1000 * r32["median_s"] / mp, 1),
              "ms_per_mp_int8": round(1000 * r8["median_s"] / mp, 1),
              "peak_rss_mb": _peak_mb(r32, r8),
              "fp32": r32, "int8": r8, "model": str(fp32) if args.fp32 or args.checkpoint else f"dequantized {int8}",
              "int8_model": str(int8), "tiles_at_once": at_once}
    if profile is not None:
        result["op_profile"] = profile
        # what INT8 buys on the convolutions and on everything else: the whole can gain no more than
        # the convolutions unless the rest runs faster in INT8 than in float
        f, i = profile["fp32"], profile["int8"]
        result["window_speedup"] = round(f["ms"] / i["ms"], 3)
        result["conv_speedup"] = round(f["conv_ms"] / i["conv_ms"], 3)
        result["rest_speedup"] = round((f["ms"] - f["conv_ms"]) / (i["ms"] - i["conv_ms"]), 3)
    print(f"{w}×{h}, {args.threads} threads, median of {args.runs}, each at its best tile: FP32 "
          f"{result['fp32_s']:.2f} s ({t32} px), INT8 {result['int8_s']:.2f} s ({t8} px, "
          f"{result['ms_per_mp_int8']:.0f} ms/MP), speedup {result['speedup']:.2f}× "
          f"({result['speedup_same_tile']:.2f}× both at {same_tile} px), "
          f"peak RSS +{result['peak_rss_mb']} MB")
    print(f"  INT8 at {t8} px: tiles side by side {at_once['side_by_side_s']:.2f} s, one at a time on "
          f"{args.threads} threads {at_once['one_at_a_time_s']:.2f} s")
    for name, r in (("FP32", r32), ("INT8", r8)):
        print(f"  {name}: {r['model_s']:.2f} s in the model ({r['model_ms_per_computed_mp']:.0f} ms per MP computed, "
              f"{r['computed_over_frame']}× the frame with the overlap), {r['outside_model_s']:.2f} s outside it")
    if profile is not None:
        for name, p in profile.items():
            top = ", ".join(f"{k} {v} %" for k, v in list(p["percent"].items())[:5])
            print(f"  {name} operators on one {t32}² window, one thread ({p['ms']} ms): {top}")
            nodes = ", ".join(f"{k} {v} %" for k, v in list(p["top_nodes"].items())[:4])
            print(f"    slowest nodes: {nodes}")
        print(f"  on the window INT8 runs {result['window_speedup']:.2f}× float: the convolutions "
              f"{result['conv_speedup']:.2f}× ({profile['fp32']['conv_ms']} → {profile['int8']['conv_ms']} ms), "
              f"everything else {result['rest_speedup']:.2f}×")
    return _harness.publish("correction", result, args, argv)


if __name__ == "__main__":
    main()

"""Memory and time of the tiled correction stage on a 12 MP frame.

A tiny stand-in model (SpaceToDepth 2, three 3×3 convolutions at ½
resolution, DepthToSpace 2; 5 → 3 channels, dynamic H/W) built with the
``onnx`` helper API, run by :class:`modules.correction.Correction` on a
random 4000 × 3000 camera-RGB frame with two intra-op threads. Not the
shipped model: it measures what the *stage* adds (the output frame, one
tile, the field channels, ORT's arena for one tile) and the tiling
overhead (pixels computed twice in the margins, gathering and stitching).

A cold run (ORT's arena and the output's pages fresh) for memory, then
``--runs`` warm runs (as inside a pipeline whose earlier stages have
warmed the allocator) for time: their median, fastest and slowest. Times: wall seconds in all, wall seconds
inside the model's runs, and the CPU seconds of the stage's thread outside
them (gathering tiles, field channels, stitching: the tiling's own cost,
which a loaded machine does not inflate).

Peak memory is the process's peak resident set (``VmHWM``) during the run,
reset just before it through ``/proc/self/clear_refs`` where the kernel
allows, minus the resident set before it; tracemalloc's peak counts the
numpy allocations alone (ORT's arena is not traced).

Run::

    python -m benchmarks.correction_tiling                  # 4000×3000, tile 512
    python -m benchmarks.correction_tiling --tile 256 --overlap 16

Last line: a JSON object.
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: ONNX Runtime's own threads do the work, BLAS one
    _harness.pin_threads(2, blas=1)

import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


def tiny_model(path: Path, *, width: int = 16, tile: int = 512, overlap: int | None = None,
               seed: int = 0) -> Path:
    """Write the stand-in model (module docstring) with stage metadata."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(seed)
    nodes = [helper.make_node("SpaceToDepth", ["x"], ["h"], blocksize=2)]
    inits, cur, c = [], "h", 20
    dil = (1, 2, 1)
    for i, (d, co) in enumerate(zip(dil, (width, width, 12))):
        w = rng.normal(0, 1 / np.sqrt(9 * c), (co, c, 3, 3)).astype(np.float32)
        inits += [numpy_helper.from_array(w, f"w{i}"), numpy_helper.from_array(np.zeros(co, np.float32), f"b{i}")]
        nodes.append(helper.make_node("Conv", [cur, f"w{i}", f"b{i}"], [f"c{i}"], kernel_shape=[3, 3],
                                      pads=[d] * 4, dilations=[d, d]))
        cur, c = f"c{i}", co
        if i < len(dil) - 1:
            nodes.append(helper.make_node("Relu", [cur], [f"r{i}"]))
            cur = f"r{i}"
    nodes.append(helper.make_node("DepthToSpace", [cur], ["y"], blocksize=2, mode="DCR"))
    graph = helper.make_graph(
        nodes, "tiny", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 5, "h", "w"])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 3, "h", "w"])], initializer=inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    meta = {"domain": "camera_rgb", "placement": "after demosaic", "lens": "bench", "fov_encoding": "xy",
            "tile_size": str(tile), "receptive_radius": str(2 * sum(dil)), "input_multiple": "4"}
    if overlap is not None:
        meta["tile_overlap"] = str(overlap)
    for k, v in meta.items():
        e = m.metadata_props.add()
        e.key, e.value = k, v
    onnx.save(m, str(path))
    return path


def _status_kb(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    return -1


def _reset_peak() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def measure_stage(stage, frame, memory: bool = False) -> dict:
    """One run of the stage: wall seconds, seconds inside the model (each
    worker's share: the summed model calls over the tiles run at once),
    CPU seconds spent outside the model by the threads that tile (the
    tiling's own cost, which load does not inflate), and (``memory``)
    peak memory."""
    workers = stage.workers(stage.tile_count(frame.data.shape[:2]))
    sess, t_model, cpu_model = stage.tile_session(workers), [0.0], [0.0]
    run = sess.run
    lock = threading.Lock()

    def timed(*a, **k):
        t0, c0 = time.perf_counter(), time.thread_time()
        try:
            return run(*a, **k)
        finally:
            with lock:
                t_model[0] += time.perf_counter() - t0
                cpu_model[0] += time.thread_time() - c0

    rss0 = _status_kb("VmRSS")
    reset = memory and _reset_peak()
    hwm0 = _status_kb("VmHWM")
    if memory:
        tracemalloc.start()
    sess.run = timed  # count inference apart from tiling
    # one worker: the tiling is this thread's, the model's intra-op pool others'; several: every
    # thread of the process tiles or runs the model (one intra-op thread each, on its caller)
    cpu = time.thread_time if workers == 1 else time.process_time
    t0, c0 = time.perf_counter(), cpu()
    try:
        out = stage(frame).data
    finally:
        del sess.run
    r = {"out": out, "seconds": round(time.perf_counter() - t0, 3),
         "model_seconds": round(t_model[0] / workers, 3), "workers": workers,
         "tiling_cpu_seconds": round(cpu() - c0 - cpu_model[0], 3)}
    if memory:
        r["tracemalloc_peak_mib"] = round(tracemalloc.get_traced_memory()[1] / 2 ** 20, 1)
        tracemalloc.stop()
        r["peak_rss_delta_mib"] = round((_status_kb("VmHWM") - (rss0 if reset else max(rss0, hwm0))) / 1024, 1)
        r["peak_reset"] = reset
    return r


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--size", default="4000x3000", help="W×H of the frame (default 4000x3000, 12 MP)")
    ap.add_argument("--tile", type=int, default=512, help="tile side incl. margins (0: whole frame)")
    ap.add_argument("--overlap", type=int, default=None, help="margin per side (default: the model's radius)")
    ap.add_argument("--width", type=int, default=16, help="channels of the stand-in model")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--runs", type=int, default=3, help="warm runs timed (median; default 3)")
    args = ap.parse_args(argv)
    _harness.pin_threads(args.threads, blas=1)
    w, h = (int(v) for v in args.size.lower().split("x"))

    from isp import CFA, CameraMeta, Domain, Frame
    from modules.correction import Correction
    from modules.common.tiling import plan_tiles

    with tempfile.TemporaryDirectory() as tmp:
        path = tiny_model(Path(tmp) / "tiny.onnx", width=args.width, tile=args.tile, overlap=args.overlap)
        meta = CameraMeta(cfa=CFA.RGGB, raw_size=(h, w), active_area=(0, 0, h, w))
        frame = Frame(np.random.default_rng(0).random((h, w, 3), dtype=np.float32), Domain.CAMERA_RGB, meta)
        stage = Correction(model=path, threads=args.threads, progress=False)
        stage.check(Domain.CAMERA_RGB)
        tile, margin, mult, border = stage.tiling()
        tiles = plan_tiles((h, w), tile, margin, mult, border)
        computed = sum(t.window_shape[0] * t.window_shape[1] for t in tiles)

        cold = measure_stage(stage, frame, memory=True)  # first run: ORT arena and output pages fresh
        del cold["out"]
        warm = []
        for _ in range(args.runs):   # as inside a pipeline, whose earlier stages warmed the allocator
            warm.append(measure_stage(stage, frame))
            out_mib = round(warm[-1].pop("out").nbytes / 2 ** 20, 1)

        def spread(key):
            return _harness.spread(r[key] for r in warm).as_dict(3)

        result = {
            "size": f"{w}x{h}", "megapixels": round(w * h / 1e6, 2), "tile": tile, "overlap": margin,
            "multiple": mult, "tiles": len(tiles), "computed_over_frame": round(computed / (w * h), 3),
            "threads": args.threads, "width": args.width,
            "runs": args.runs, "seconds": spread("seconds"), "model_seconds": spread("model_seconds"),
            "tiling_cpu_seconds": spread("tiling_cpu_seconds"),
            "cold_seconds": cold["seconds"], "cold_tiling_cpu_seconds": cold["tiling_cpu_seconds"],
            "peak_rss_delta_mib": cold["peak_rss_delta_mib"], "peak_reset": cold["peak_reset"],
            "tracemalloc_peak_mib": cold["tracemalloc_peak_mib"],
            "output_frame_mib": out_mib,
        }
    r = result
    print(f"{r['tiles']} tiles of {tile} px (overlap {margin}); {r['computed_over_frame']}× the frame's "
          f"pixels computed; {r['seconds']['median']:.2f} s, median of {args.runs} "
          f"({r['model_seconds']['median']:.2f} s in the model, tiling {r['tiling_cpu_seconds']['median']:.2f} s "
          f"CPU; first run {r['cold_seconds']:.2f} s); peak RSS +{r['peak_rss_delta_mib']} MiB "
          f"(output frame {r['output_frame_mib']} MiB)")
    return _harness.publish("correction_tiling", result, args, argv)


if __name__ == "__main__":
    main()

"""What the INT8 graph forms buy (``export/int8_form.py``), on the real model.

From an INT8 file (default: the packaged one) this takes its FP32 twin
(:func:`export.quantize.dequantize_qdq`, in float's own form), quantises it
again twice, with the forms and without (``quantize_int8(...,
graph_forms=False)``), and writes the twin in the INT8 form too (float,
the one-hot copies left in). Calibration uses the export's sample frames
(:func:`export.onnx_export.sample_frame`): enough for timing, not for
quality. Then, with the stage's session options on 2 threads:

* the wall time of one window per file, all files interleaved run by run,
  the median of ``--runs`` with the fastest and slowest run
  (``window_ms``): INT8 on a 1,072² window (a 1,024-px tile with
  its context), float on a 704² one (its fast tile size);
* ONNX Runtime's profiler on the two INT8 files (1,072²): the time of
  every ``QLinearMul`` together, of the ones fed by the kernel attention
  (broadcast or spread), and of the convs on the field features.

Run::

    python -m benchmarks.int8_form                      # the packaged model
    python -m benchmarks.int8_form --int8 M.int8.onnx --runs 20

Last line: a JSON object.
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: ONNX Runtime's own threads do the work, BLAS one
    _harness.pin_threads(2, blas=1)

import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


def sample_reader(n: int = 8, size: int = 128):
    """A calibration reader over ``n`` sample-frame feeds ``{"input": (1, 5,
    size, size)}`` (:class:`export.quantize.ReplayReader`, so it rewinds)."""
    from functools import partial
    from types import SimpleNamespace

    from export.onnx_export import model_input, sample_frame
    from export.quantize import ReplayReader

    feeds = iter([{"input": model_input(sample_frame((size, size), True, k), True)} for k in range(n)])
    return ReplayReader(SimpleNamespace(get_next=partial(next, feeds, None)))


def _feed(path: Path, side: int) -> tuple[object, dict]:
    import onnxruntime as ort

    from modules.correction import model_info, pack_input, session_options

    sess = ort.InferenceSession(str(path), session_options(2), providers=["CPUExecutionProvider"])
    info = model_info(sess)
    x = (0.2 + 0.3 * np.random.default_rng(0).random((1, 5, side, side))).astype(np.float32)
    return sess, {info.input_name: pack_input(x, info.packing)}


def window_times(files: dict[str, tuple[Path, int]], runs: int) -> dict[str, _harness.Spread]:
    """Wall ms of one window per file (name → (path, side)), the files
    interleaved run by run so that the machine's drift falls on all."""
    loaded = {k: _feed(p, side) for k, (p, side) in files.items()}
    times = _harness.interleaved({k: (lambda sess=sess, feed=feed: sess.run(None, feed))
                                  for k, (sess, feed) in loaded.items()}, runs=runs, warmup=1, log=False)
    return {k: t.map(lambda s: 1e3 * s) for k, t in times.items()}


def node_groups(path: Path, side: int = 1072) -> dict[str, float]:
    """Profiled ms per run of the INT8 file's products and field convs."""
    from benchmarks.correction import op_shares

    nodes = op_shares(path, 2, side)["node_ms"]
    mul = {k: v for k, v in nodes.items() if k.endswith("(QLinearMul)")}
    # the kernel attention's products are Mul_1..Mul_4 of each DOConv (Mul: channel, Mul_5: filter)
    kernel = {k: v for k, v in mul.items() if "/conv/Mul_" in k and k.split("/conv/Mul_")[1][:1] in "1234"}
    field = {k: v for k, v in nodes.items() if k.endswith("(QLinearConv)") and "field" in k}
    return {"total_ms": round(sum(nodes.values()), 1), "qlinearmul_ms": round(sum(mul.values()), 2),
            "kernel_attention_mul_ms": round(sum(kernel.values()), 2),
            "kernel_attention_muls": len(kernel), "field_conv_ms": round(sum(field.values()), 2),
            "field_convs": len(field)}


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--int8", help="an INT8 file (default: the packaged model)")
    ap.add_argument("--runs", type=int, default=15, help="timed runs per file (median; default 15)")
    args = ap.parse_args(argv)

    import onnx

    from export.int8_form import int8_form
    from export.quantize import dequantize_qdq, quantize_int8
    from modules.correction import resolve_model

    src = Path(args.int8) if args.int8 else resolve_model("default")
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        twin = dequantize_qdq(onnx.load(str(src)))
        onnx.save(twin, str(d / "float.onnx"))
        spread = onnx.load(str(d / "float.onnx"))
        int8_form(spread)
        onnx.save(spread, str(d / "float_int8_form.onnx"))
        for name, forms in (("int8.onnx", True), ("int8_plain.onnx", False)):
            quantize_int8(d / "float.onnx", d / name, sample_reader(), graph_forms=forms)
        timing = window_times({"int8_forms": (d / "int8.onnx", 1072), "int8_plain": (d / "int8_plain.onnx", 1072),
                              "float": (d / "float.onnx", 704), "float_int8_form": (d / "float_int8_form.onnx", 704)},
                             args.runs)
        groups = {"int8_forms": node_groups(d / "int8.onnx"), "int8_plain": node_groups(d / "int8_plain.onnx")}
    times = {k: round(t.median, 1) for k, t in timing.items()}
    result = {"model": str(src), "runs": args.runs, "window_ms": {k: t.as_dict(1) for k, t in timing.items()},
              "profile_1072": groups,
              "int8_gain": round(1 - times["int8_forms"] / times["int8_plain"], 3),
              "float_cost_of_int8_form": round(times["float_int8_form"] / times["float"] - 1, 3)}
    p, f = groups["int8_plain"], groups["int8_forms"]
    print(f"INT8, 1,072² window: {times['int8_plain']} ms without the forms, {times['int8_forms']} ms with them "
          f"({-100 * result['int8_gain']:+.1f} %)")
    print(f"  kernel-attention products ({p['kernel_attention_muls']}): {p['kernel_attention_mul_ms']} ms broadcast, "
          f"{f['kernel_attention_mul_ms']} ms spread; field convs ({p['field_convs']}): {p['field_conv_ms']} ms on 3 "
          f"channels, {f['field_conv_ms']} ms on 4 (profiler)")
    print(f"float, 704² window: {times['float']} ms in its own form, {times['float_int8_form']} ms in INT8's "
          f"({100 * result['float_cost_of_int8_form']:+.1f} %)")
    return _harness.publish("int8_form", result, args, argv)


if __name__ == "__main__":
    main()

"""ONNX Runtime speed of the restoration-network variants on 2 threads.

For each variant: export (opset 17, dynamic H/W, TorchScript exporter),
optionally a static INT8 QDQ copy (per-channel int8 weights, uint8
activations, calibrated on random inputs — enough for timing, not for
quality), then time all sessions *interleaved* on a 512 × 512 input: one
warm-up round, then the median of ``--rounds`` (with the fastest and
slowest; a shared machine's load moves every number, interleaving keeps the
ratios honest). Also times one dense 3×3 conv 64→64
as a yardstick of what the machine sustains. Reports ms per megapixel
(one 512² run × 1/0.262144) and the MAC rate achieved.

Run::

    python -m benchmarks.doconv_speed doconv static 'doconv:{"scale": 4, "widths": [64, 128]}'
    python -m benchmarks.doconv_speed --no-int8 doconv_spatial_tap
    python -m benchmarks.doconv_speed --yardsticks                 # what INT8 buys per conv kind here

A variant is ``name`` or ``name:{json overrides}``. This is a design aid for
the network; the shipped model's export and benchmark belong to ``export/``.
Last line: a JSON object, ``{"ms": {label: {median, min, max, n}},
"int8_speedup": {variant: FP32 / INT8 of the medians}}``.
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import json  # noqa: E402
import tempfile  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

from restoration.nn.macs import macs_per_pixel  # noqa: E402
from restoration.nn.network import build_model  # noqa: E402

SIZE = 512


def parse(spec: str):
    name, _, kw = spec.partition(":")
    kw = json.loads(kw) if kw else {}
    return name, {k: tuple(v) if isinstance(v, list) else v for k, v in kw.items()}


def export(model, path: Path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(model.eval(), (torch.rand(1, model.in_channels, 64, 96),), str(path), dynamo=False,
                          opset_version=17, input_names=["input"], output_names=["output"],
                          dynamic_axes={"input": {2: "h", 3: "w"}, "output": {2: "h", 3: "w"}})


def quantize(src: Path, dst: Path, channels: int) -> None:
    from onnxruntime.quantization import (
        CalibrationDataReader,
        QuantFormat,
        QuantType,
        quantize_static,
    )
    from onnxruntime.quantization.shape_inference import quant_pre_process

    class Reader(CalibrationDataReader):
        def __init__(self):
            rng = np.random.default_rng(0)
            self.it = iter([{"input": rng.random((1, channels, 128, 128), dtype=np.float32)} for _ in range(4)])

        def get_next(self):
            return next(self.it, None)

    pre = dst.with_suffix(".pre.onnx")
    quant_pre_process(str(src), str(pre), skip_symbolic_shape=True)
    quantize_static(str(pre), str(dst), Reader(), quant_format=QuantFormat.QDQ, per_channel=True,
                    activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8)


def session(path: Path, threads: int):
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


#: single-layer yardsticks of what INT8 buys on this CPU: (label, module, channels)
def _yardsticks(c: int = 64):
    nn = torch.nn
    return [(f"dense 3×3 {c}→{c} ×2", nn.Sequential(nn.Conv2d(c, c, 3, padding=1), nn.ReLU(),
                                                  nn.Conv2d(c, c, 3, padding=1), nn.ReLU()), c),
            (f"1×1 {c}→{2 * c}→{c}", nn.Sequential(nn.Conv2d(c, 2 * c, 1), nn.ReLU(), nn.Conv2d(2 * c, c, 1)), c),
            (f"depthwise 3×3 {c} ×2", nn.Sequential(nn.Conv2d(c, c, 3, padding=1, groups=c), nn.ReLU(),
                                                   nn.Conv2d(c, c, 3, padding=1, groups=c)), c)]


def yardsticks(args, tmp: Path, rng) -> list:
    """Runs of the single-layer yardsticks, FP32 and INT8 (at ½ of SIZE)."""
    runs = []
    for k, (label, module, c) in enumerate(_yardsticks()):
        f32 = tmp / f"y{k}.onnx"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(module.eval(), (torch.rand(1, c, 32, 32),), str(f32), dynamo=False, opset_version=17,
                              input_names=["input"], dynamic_axes={"input": {2: "h", 3: "w"}})
        q8 = tmp / f"y{k}.int8.onnx"
        quantize(f32, q8, c)
        x = rng.random((1, c, SIZE // 2, SIZE // 2), dtype=np.float32)
        runs.append((f"yardstick {label} FP32", session(f32, args.threads), x, 0))
        runs.append((f"yardstick {label} INT8", session(q8, args.threads), x, 0))
    return runs


def main(argv=None):
    ap = _harness.parser(__doc__)
    ap.add_argument("variants", nargs="*")
    ap.add_argument("--yardsticks", action="store_true",
                    help="also time single conv layers (dense 3×3, 1×1, depthwise) in FP32 and INT8: "
                         "what INT8 can buy on this CPU at best")
    ap.add_argument("--no-int8", action="store_true")
    ap.add_argument("--rounds", type=int, default=5, help="timed rounds (median; default 5)")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    _harness.pin_threads(args.threads)
    tmp = Path(tempfile.mkdtemp())
    runs = []  # (label, session, input, MACs per run)
    ref = torch.nn.Conv2d(64, 64, 3, padding=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(ref, (torch.rand(1, 64, 32, 32),), str(tmp / "ref.onnx"), dynamo=False, opset_version=17,
                          input_names=["input"], dynamic_axes={"input": {2: "h", 3: "w"}})
    rng = np.random.default_rng(0)
    runs.append(("dense conv 3×3 64→64 (yardstick)", session(tmp / "ref.onnx", args.threads),
                 rng.random((1, 64, SIZE // 2, SIZE // 2), dtype=np.float32), 64 * 64 * 9 * (SIZE // 2) ** 2))
    for k, spec in enumerate(args.variants):
        name, kw = parse(spec)
        model = build_model(name, **kw)
        macs = macs_per_pixel(model) * SIZE * SIZE
        x = rng.random((1, model.in_channels, SIZE, SIZE), dtype=np.float32)
        f32 = tmp / f"m{k}.onnx"
        export(model, f32)
        runs.append((f"{spec} FP32", session(f32, args.threads), x, macs))
        if not args.no_int8:
            q8 = tmp / f"m{k}.int8.onnx"
            quantize(f32, q8, model.in_channels)
            runs.append((f"{spec} INT8", session(q8, args.threads), x, macs))
    if args.yardsticks:
        runs += yardsticks(args, tmp, rng)
    times = _harness.interleaved({label: (lambda sess=sess, x=x: sess.run(None, {sess.get_inputs()[0].name: x}))
                                  for label, sess, x, _macs in runs}, runs=args.rounds, warmup=1, log=False)
    med = [times[label].median for label, *_ in runs]
    mp = SIZE * SIZE / 1e6
    for (label, _, _, macs), t in zip(runs, med):
        per_mp = t * 1e3 / mp if "yardstick" not in label else float("nan")
        print(f"{label:56s} {t * 1e3:7.1f} ms  {per_mp:6.0f} ms/MP  {macs / t / 1e9:6.1f} GMAC/s", flush=True)
    ratios = {runs[i][0][:-5]: round(med[i] / med[i + 1], 2) for i in range(len(runs) - 1)
              if runs[i][0].endswith(" FP32") and runs[i + 1][0].endswith(" INT8")}
    for label, r in ratios.items():
        print(f"INT8 speed-up, {label}: {r:.2f}×")
    result = {"size": SIZE, "rounds": args.rounds, "threads": args.threads,
              "ms": {label: times[label].map(lambda t: 1e3 * t).as_dict(2) for label, *_ in runs},
              "int8_speedup": ratios}
    return _harness.publish("doconv_speed", result, args, argv)


if __name__ == "__main__":
    main()

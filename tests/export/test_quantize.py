"""``export/quantize.py``: ONNX FP32 → static INT8. Property tests on a tiny
untrained model: every conv quantised, the input encoding and output
decoding kept in float, the dequantised twin is the FP32 graph with
rounded weights, the residual high-pass shares the residual's range; and
the INT8 PSNR check on smooth random pairs (see :func:`test_int8_psnr_drop`)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxruntime.quantization")

from isp import Domain
from restoration.nn.checkpoint import save_checkpoint
from restoration.nn.network import build_model
from tests.helpers import EXPORT_KW as KW
from tests.helpers import EXPORT_META as META
from tests.helpers import onnx_calibration_reader as _reader

pytestmark = [pytest.mark.property, pytest.mark.filterwarnings("ignore:Please consider to run pre-processing"),
              pytest.mark.filterwarnings("ignore::DeprecationWarning")]


def test_int8_every_conv_quantized(exported, quantized):
    """After ORT_ENABLE_ALL every Conv of the FP32 model is a QLinearConv;
    the metadata carries over with precision int8; the stage runs it."""
    from modules.correction import Correction

    q = quantized
    # the graph quantised: the export's convs and the kernel attention's copies (export.int8_form)
    assert q["fp32_conv"] == exported[2]["convs"] + q["int8_form"]["spread_muls"]
    assert q["int8_quantized_conv"] == q["fp32_conv"] and q["int8_float_conv"] == 0
    assert q["ops"].get("QuantizeLinear", 0) > 0  # QDQ form
    stage = Correction(model=exported[0] / "tiny.int8.onnx")
    stage.check(Domain.CAMERA_RGB)
    assert stage.model_meta["precision"] == "int8" and stage.model_meta["lens"] == "test-lens"


def test_int8_psnr_drop(exported, quantized):
    """INT8 vs FP32 PSNR drop ≤ 0.2 dB (``PSNR_DROP_LIMIT``), here on 4 smooth
    random pairs (target = a random-ish frame, input = its Gaussian blur),
    PSNR in linear RGB of the whole output, and with the tiny *untrained*
    model (close to the identity), not the restoration test set: the CLI
    measures that one (``isp export --int8 --calib-data``)."""
    import cv2

    from export.onnx_export import model_input, sample_frame
    from modules.correction import run_model

    d = exported[0]
    s32, s8 = (ort.InferenceSession(str(d / f), providers=["CPUExecutionProvider"])
               for f in ("tiny.onnx", "tiny.int8.onnx"))
    p32, p8 = [], []
    for k in range(4):
        target = np.clip(sample_frame((96, 128), True, 100 + k), 0, 1)
        x = model_input(cv2.GaussianBlur(target, (0, 0), 1.5), True)
        for s, acc in ((s32, p32), (s8, p8)):
            y = run_model(s, x)[0].transpose(1, 2, 0)
            acc.append(10 * np.log10(1 / np.mean((y - target) ** 2)))
    drop = np.mean(p32) - np.mean(p8)
    assert drop <= 0.2, (np.mean(p32), np.mean(p8))


def test_int8_keeps_the_input_encoding_and_output_decoding_in_float(tmp_path):
    """A model with encoding="sqrt": every conv is quantised, while the nodes
    outside the conv network stay float (the square root's input is never
    rounded, nor the decoded output), and the INT8 output follows the FP32
    one closely."""
    import onnx
    import onnxruntime as ort

    from export.onnx_export import export_onnx
    from export.quantize import quantize_int8

    torch.manual_seed(0)
    kw = {**KW, "encoding": "sqrt"}
    ckpt = save_checkpoint(tmp_path / "sq.pt", build_model("doconv", **kw), variant="doconv", model_kwargs=kw,
                           step=1, metadata=META)
    export_onnx(ckpt, tmp_path / "sq.onnx", tile_size=256)
    rep = quantize_int8(tmp_path / "sq.onnx", tmp_path / "sq.int8.onnx", _reader())
    assert rep["int8_quantized_conv"] == rep["fp32_conv"] and rep["int8_float_conv"] == 0
    m = onnx.load(str(tmp_path / "sq.int8.onnx"))
    prod = {o: n for n in m.graph.node for o in n.output}
    sqrt = next(n for n in m.graph.node if n.op_type == "Sqrt")
    assert prod[sqrt.input[0]].op_type != "DequantizeLinear"          # encoded from unrounded RGB
    out = m.graph.output[0].name
    assert prod[out].op_type == "Sub" and all(prod[i].op_type != "DequantizeLinear"
                                              for i in prod[out].input if i in prod)
    from modules.correction import run_model

    x = next(iter(_reader(1, 64, 7).it))["input"]
    a = run_model(ort.InferenceSession(str(tmp_path / "sq.onnx")), x)
    b = run_model(ort.InferenceSession(str(tmp_path / "sq.int8.onnx")), x)
    assert np.abs(a - b).mean() < 0.01


def test_dequantized_twin_is_the_fp32_graph(exported, quantized):
    """``dequantize_qdq`` folds the INT8 model back to float: no Q/DQ node
    left, the same convs, and its output is the FP32 model's with the INT8
    model's rounded weights (7-bit per channel: ≥ 38 dB from the FP32 model
    here), which the INT8 model, its activations rounded too, is not."""
    import onnx as onnx_

    from export.onnx_export import model_input, sample_frame
    from export.quantize import dequantize_qdq
    from modules.correction import run_model

    d = exported[0]
    twin = dequantize_qdq(onnx_.load(str(d / "tiny.int8.onnx")))
    onnx_.checker.check_model(twin)
    ops = [n.op_type for n in twin.graph.node]
    assert "QuantizeLinear" not in ops and "DequantizeLinear" not in ops
    assert ops.count("Conv") == exported[2]["convs"]
    assert {p.key: p.value for p in twin.metadata_props}["precision"] == "fp32-dequantized"
    onnx_.save(twin, str(d / "tiny.twin.onnx"))
    s32, s8, stw = (ort.InferenceSession(str(d / f), providers=["CPUExecutionProvider"])
                    for f in ("tiny.onnx", "tiny.int8.onnx", "tiny.twin.onnx"))
    x = model_input(np.clip(sample_frame((96, 128), True, 7), 0, 1), True)
    y32, y8, ytw = (run_model(s, x) for s in (s32, s8, stw))
    psnr = lambda a, b: 10 * np.log10(1 / np.mean((a - b) ** 2))  # noqa: E731
    assert psnr(ytw, y32) >= 38, psnr(ytw, y32)   # 41.0 dB measured
    # oracle: the FP32 file with each quantised initializer replaced by hand,
    # q → (q − zero point)·scale per output channel, computes the twin exactly
    q8 = {i.name: onnx_.numpy_helper.to_array(i) for i in onnx_.load(str(d / "tiny.int8.onnx")).graph.initializer}
    ref = onnx_.load(str(d / "tiny.onnx"))

    def rounded(name, dims):
        q = q8[name + "_quantized"]
        scale = q8.get(name + "_scale", q8.get(name + "_quantized_scale"))
        zero = q8.get(name + "_zero_point", q8.get(name + "_quantized_zero_point"))
        shape = (-1,) + (1,) * (q.ndim - 1)
        w = (q.astype(np.float64) - np.reshape(zero, shape)) * np.reshape(scale, shape)
        # the INT8 file's field convs have a zero input column more (export.int8_form)
        w = w[tuple(slice(0, d) for d in dims)]
        return onnx_.numpy_helper.from_array(w.astype(np.float32), name)

    swapped = 0
    for init in ref.graph.initializer:          # weights and biases
        if init.name + "_quantized" in q8:
            init.CopyFrom(rounded(init.name, init.dims))
            swapped += 1
    for node in ref.graph.node:                 # the attention's box-mean kernels are Constant nodes
        if node.op_type == "Constant" and node.output[0] + "_quantized" in q8:
            node.attribute[0].t.CopyFrom(rounded(node.output[0], node.attribute[0].t.dims))
            swapped += 1
    assert swapped >= exported[2]["convs"]
    s_ref = ort.InferenceSession(ref.SerializeToString(), providers=["CPUExecutionProvider"])
    assert np.abs(run_model(s_ref, x) - ytw).max() <= 1e-5
    assert np.abs(y8 - ytw).max() > 1e-3   # and the INT8 model, its activations rounded, is not it


@pytest.mark.parametrize("kw, gain", [({"highpass": 9}, 30),
                                     ({"highpass": 9, "encoding": "sqrt", "highpass_domain": "linear"}, 3)])
def test_int8_highpass_shares_the_residual_range_and_keeps_flat_fields(tmp_path, kw, gain):
    """The residual high-pass (restoration.nn.network.ResidualHighPass) exports
    as Pad + dilated 3×3 box convs + Sub, every conv quantised, and its box
    means get the residual's own quantisation range. Calibrated on their
    own they get the narrow range natural crops give a local mean, and clip
    on a flat field (8.7 % too bright at grey 0.7 on an e9 model).
    Checked: the scales are shared (and differ without the
    overrides, so the check can fail), and a flat field brighter than any
    calibration crop keeps the FP32 model's level in INT8. The high-pass of
    the linear residual (``highpass_domain="linear"``) filters ``r (r + 2u)``,
    made in the graph; its ``2u`` is a 1×1 conv, quantised like the rest.
    (Its head is scaled less: a flat field's residual varies with the field
    position, and squared the variation outgrows what a 9 × 9 box removes.)"""
    import onnx
    import onnxruntime as ort

    from export import quantize as q
    from export.onnx_export import export_onnx
    from modules.correction import run_model

    torch.manual_seed(0)
    kw = {**KW, "field": True, **kw}
    model = build_model("doconv", **kw)
    with torch.no_grad():
        model.head[0].weight.mul_(gain)   # a large residual, which on a flat field is near constant
    ckpt = save_checkpoint(tmp_path / "hp.pt", model, variant="doconv", model_kwargs=kw, step=1, metadata=META)
    export_onnx(ckpt, tmp_path / "hp.onnx", tile_size=256, measure_overlap=False)
    chains = q.highpass_chains(onnx.load(str(tmp_path / "hp.onnx")))
    assert len(chains) == 1 and len(chains[0][1]) == 3   # Pad and two box convs (9 = 3²)
    r, chain = chains[0].residual, chains[0].chain

    def scales(path):
        m = onnx.load(str(path))
        inits = {i.name: onnx.numpy_helper.to_array(i) for i in m.graph.initializer}
        return {n.input[0]: float(inits[n.input[1]]) for n in m.graph.node if n.op_type == "QuantizeLinear"}

    rep = q.quantize_int8(tmp_path / "hp.onnx", tmp_path / "hp.int8.onnx", _reader())
    assert rep["int8_quantized_conv"] == rep["fp32_conv"] and rep["int8_float_conv"] == 0
    s = scales(tmp_path / "hp.int8.onnx")
    box = [t for t in chain if t in s]
    assert box and all(np.isclose(s[t], s[r]) for t in box)
    original = q.shared_range_overrides
    try:
        q.shared_range_overrides = lambda *a, **k: {}
        q.quantize_int8(tmp_path / "hp.onnx", tmp_path / "hp_own.int8.onnx", _reader())
    finally:
        q.shared_range_overrides = original
    own = scales(tmp_path / "hp_own.int8.onnx")
    assert not all(np.isclose(own[t], own[r]) for t in box)

    # the edge Pad runs on the uint8 residual (quantized_pads), and the FP32 twin undoes it
    m = onnx.load(str(tmp_path / "hp.int8.onnx"))
    prod = {o: n for n in m.graph.node for o in n.output}
    pad = next(n for n in m.graph.node if n.op_type == "Pad")
    assert prod[pad.input[0]].op_type == "QuantizeLinear"
    twin = q.dequantize_qdq(m)
    assert not any(n.op_type in ("QuantizeLinear", "DequantizeLinear") for n in twin.graph.node)
    # the linear residual, made by a float Mul, reaches the output's Sub unrounded (highpass_reads_float)
    if "highpass_domain" in kw:
        assert prod[r].op_type == "Mul"
        assert any(n.op_type == "Sub" and n.input[0] == r for n in m.graph.node)

    x = next(iter(_reader(1, 96, 3).it))["input"]
    x[:, :-2] = 1.5        # a flat field (the packed RGB; field kept), brighter than any calibration crop
    c = (slice(None), slice(None), slice(16, -16), slice(16, -16))
    fp32, int8 = (run_model(ort.InferenceSession(str(p)), x)[c].mean()
                  for p in (tmp_path / "hp.onnx", tmp_path / "hp.int8.onnx"))
    assert abs(fp32 - 1.5) < 0.01 and abs(int8 - fp32) < 0.005

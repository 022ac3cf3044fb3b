"""``export.int8_form``: the graph forms INT8 runs faster and their float
inverses. Property tests: every rewrite is the same function (ONNX
Runtime, float, to 1e-6), its inverse gives back the exported graph's ops,
and the INT8 file a real export writes has no one-channel product left
nor a conv on three channels."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

from export.int8_form import (float_form, int8_form, pad_thin_convs, spread_broadcast_muls,  # noqa: E402
                              unpad_thin_convs, unspread_broadcast_muls)
from export.onnx_export import op_counts  # noqa: E402

pytestmark = [pytest.mark.property, pytest.mark.filterwarnings("ignore:Please consider to run pre-processing"),
              pytest.mark.filterwarnings("ignore::DeprecationWarning")]

KW = {"widths": [8, 16], "depths": [1, 1, 1], "window": 1}


@pytest.fixture(scope="module")
def fp32(tmp_path_factory):
    """A tiny DOConv UNet (three blocks of four kernels) exported to ONNX."""
    from export.onnx_export import export_onnx
    from restoration.nn.checkpoint import save_checkpoint
    from restoration.nn.network import build_model

    d = tmp_path_factory.mktemp("int8_form")
    torch.manual_seed(5)
    model = build_model("doconv", **KW)
    with torch.no_grad():   # away from uniform attention, so a wrong channel would show
        for m in model.modules():
            if isinstance(m, torch.nn.Conv2d) and m.out_channels in (4,):
                m.weight.normal_(0, 1)
        model.head[0].weight.mul_(10)
    meta = {"domain": "camera_rgb", "lens": "t", "fov_encoding": "xy", "input_multiple": 4, "attention": "local"}
    ckpt = save_checkpoint(d / "m.pt", model, variant="doconv", model_kwargs=KW, step=1, metadata=meta)
    export_onnx(ckpt, d / "m.onnx", tile_size=256, measure_overlap=False, overlap=16)
    return d / "m.onnx"


def _run(model, x):
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return sess.run(None, {"input": x})[0]


def _input(seed=0, h=24, w=40):
    rng = np.random.default_rng(seed)
    x = (0.05 + 0.9 * rng.random((1, 14, h, w))).astype(np.float32)
    x[:, 12:] = 2 * x[:, 12:] - 1   # the field channels in [-1, 1]
    return x


def _mul_channels(model) -> list[tuple[int, int]]:
    """(channels of input 0, of input 1) of every Mul, where shape inference knows both."""
    from export.int8_form import _channels

    ch = _channels(model)
    return [(ch[n.input[0]], ch[n.input[1]]) for n in model.graph.node
            if n.op_type == "Mul" and n.input[0] in ch and n.input[1] in ch]


def test_spread_is_the_same_function_and_leaves_no_one_channel_product(fp32):
    m = onnx.load(str(fp32))
    before = _mul_channels(m)
    assert sum(1 in p and p[0] != p[1] for p in before) == 12   # 3 blocks × 4 kernels broadcast
    x = _input()
    ref = _run(m, x)
    assert spread_broadcast_muls(m) == 12
    onnx.checker.check_model(m)
    assert not any(1 in p and p[0] != p[1] for p in _mul_channels(m))
    assert np.abs(_run(m, x) - ref).max() <= 1e-6
    # the copies are 1×1 convs of one-hot weights on the kernel attention
    assert op_counts(m)["Conv"] == op_counts(onnx.load(str(fp32)))["Conv"] + 12
    assert unspread_broadcast_muls(m) == 12

    def ops(model):   # the slices' bounds come back as initializers, not Constant nodes
        return {k: v for k, v in op_counts(model).items() if k != "Constant"}

    assert ops(m) == ops(onnx.load(str(fp32)))
    assert np.abs(_run(m, x) - ref).max() <= 1e-6
    # spread again (an INT8 file's twin quantised anew): its names taken, it still makes a valid graph
    assert spread_broadcast_muls(m) == 12
    onnx.checker.check_model(m)
    assert np.abs(_run(m, x) - ref).max() <= 1e-6


def test_thin_convs_get_four_input_channels_and_the_same_function(fp32):
    from export.int8_form import _channels

    m = onnx.load(str(fp32))
    x = _input(1)
    ref = _run(m, x)
    inits = {i.name: i for i in m.graph.initializer}

    def in_channels():
        return sorted(onnx.numpy_helper.to_array(inits[n.input[1]]).shape[1] for n in m.graph.node
                      if n.op_type == "Conv" and onnx.numpy_helper.to_array(inits[n.input[1]]).shape[1] < 8)

    assert in_channels().count(3) == 4   # the field features: the stem's and three attentions'
    assert pad_thin_convs(m) == 4
    assert 3 not in in_channels() and in_channels().count(4) == 4
    assert np.abs(_run(m, x) - ref).max() <= 1e-6
    assert all(c % 4 == 0 for n, c in _channels(m).items() if n.startswith("/Concat"))
    assert unpad_thin_convs(m) == 4
    assert in_channels().count(3) == 4 and np.abs(_run(m, x) - ref).max() <= 1e-6


def test_forms_leave_other_graphs_alone():
    """A product of two full tensors and a conv on a graph input are not rewritten."""
    from onnx import TensorProto, helper, numpy_helper

    w = numpy_helper.from_array(np.ones((4, 3, 1, 1), np.float32), "w")
    g = helper.make_graph(
        [helper.make_node("Conv", ["x", "w"], ["c"]), helper.make_node("Mul", ["c", "c"], ["y"])], "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3, 4, 4])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 4, 4, 4])], [w])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    assert int8_form(m) == {"spread_muls": 0, "padded_convs": 0}
    assert float_form(m) == {"unspread_muls": 0, "unpadded_convs": 0}
    # a concatenation whose last input's copies never reach a multiple of 4 (1 + 2k) is left alone
    w3 = numpy_helper.from_array(np.ones((4, 3, 1, 1), np.float32), "w3")
    g = helper.make_graph(
        [helper.make_node("Concat", ["a", "b"], ["ab"], axis=1), helper.make_node("Conv", ["ab", "w3"], ["y"])],
        "g", [helper.make_tensor_value_info("a", TensorProto.FLOAT, [1, 1, 4, 4]),
              helper.make_tensor_value_info("b", TensorProto.FLOAT, [1, 2, 4, 4])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 4, 4, 4])], [w3])
    assert pad_thin_convs(helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])) == 0


def test_an_int8_export_runs_the_int8_form_and_its_twin_the_float_form(fp32, tmp_path):
    """End to end: quantize_int8 rewrites before quantising (every conv,
    the copies included, quantised) and dequantize_qdq gives back the float
    form, the same function as the INT8 file's weights in float."""
    from export.quantize import dequantize_qdq, quantize_int8
    from tests.helpers import onnx_calibration_reader as _reader

    q = quantize_int8(fp32, tmp_path / "m.int8.onnx", _reader())
    assert q["int8_form"] == {"spread_muls": 12, "padded_convs": 4}
    assert q["int8_quantized_conv"] == q["fp32_conv"] == op_counts(onnx.load(str(fp32)))["Conv"] + 12
    twin = dequantize_qdq(onnx.load(str(tmp_path / "m.int8.onnx")))
    assert op_counts(twin)["Conv"] == op_counts(onnx.load(str(fp32)))["Conv"]
    x = _input(2)
    # the twin's rounded weights: close to the float file, and its product shapes are float's
    assert np.abs(_run(twin, x) - _run(onnx.load(str(fp32)), x)).max() < 0.05
    assert sum(1 in p and p[0] != p[1] for p in _mul_channels(twin)) == 12
    # benchmarks/int8_form.py finds the products and convs it times by their export names
    from benchmarks.int8_form import node_groups

    groups = node_groups(tmp_path / "m.int8.onnx", side=64)
    assert groups["kernel_attention_muls"] == 12 and groups["field_convs"] == 4

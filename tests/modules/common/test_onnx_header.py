"""The ONNX header reader against onnxruntime's own description of the
same files (the oracle): metadata and inputs, on the packaged model and on
graphs built here with every input form the correction stage meets."""

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

from isp.errors import ConfigError  # noqa: E402
from modules.common.onnx_header import read_header  # noqa: E402

pytestmark = pytest.mark.published   # onnxruntime, a peer's reading of the same files


def _described(path):
    s = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return (dict(s.get_modelmeta().custom_metadata_map),
            [(i.name, i.type, list(i.shape)) for i in s.get_inputs()])


def _header(path):
    h = read_header(path)
    return h.get_modelmeta().custom_metadata_map, [(i.name, i.type, list(i.shape)) for i in h.get_inputs()]


def _model(path, *, dtype=onnx.TensorProto.FLOAT, stats=False, ir=8, initializer_input=False, meta=None):
    from onnx import helper, numpy_helper

    h = onnx.helper
    x = h.make_tensor_value_info("input", dtype, [1, 5, "height", None])
    inputs, nodes, inits = [x], [], []
    w = numpy_helper.from_array(np.ones((3, 5, 1, 1), np.float32 if dtype == 1 else np.float16), "w")
    inits.append(w)
    if initializer_input:    # IR 3 lists initializers among the inputs; onnxruntime hides them
        inputs.append(h.make_tensor_value_info("w", dtype, [3, 5, 1, 1]))
    nodes.append(helper.make_node("Conv", ["input", "w"], ["y"]))
    if stats:
        inputs.append(h.make_tensor_value_info("stats", dtype, [1, 5]))
        nodes.append(helper.make_node("Identity", ["stats"], ["s_out"]))
    outs = [h.make_tensor_value_info("y", dtype, None)]
    if stats:
        outs.append(h.make_tensor_value_info("s_out", dtype, None))
    g = h.make_graph(nodes, "g", inputs, outs, inits)
    m = h.make_model(g, opset_imports=[h.make_opsetid("", 13)])
    m.ir_version = ir
    for k, v in (meta or {"domain": "camera_rgb", "note": "é ✓ long " + "x" * 300}).items():
        e = m.metadata_props.add()
        e.key, e.value = k, v
    onnx.save(m, str(path))
    return path


@pytest.mark.parametrize("kw", [{}, {"dtype": onnx.TensorProto.FLOAT16}, {"stats": True},
                                {"ir": 3, "initializer_input": True}, {"meta": {}}])
def test_header_reads_what_onnxruntime_describes(tmp_path, kw):
    p = _model(tmp_path / "m.onnx", **kw)
    assert _header(p) == _described(p)


def test_header_of_the_packaged_model():
    from modules.correction import resolve_model

    p = resolve_model("default")
    meta, inputs = _header(p)
    assert (meta, inputs) == _described(p)
    assert meta["lens"] == "US-12210142-B2-e9" and inputs == [("input", "tensor(float)", [1, 14, "height", "width"])]


@pytest.mark.parametrize("content", [b"", b"not a model at all \xff\xfe", b"\x0a\xff\xff\xff\xff\xff"])
def test_a_file_that_is_no_model_is_a_config_error(tmp_path, content):
    p = tmp_path / "bad.onnx"
    p.write_bytes(content)
    with pytest.raises(ConfigError, match="bad.onnx: not a loadable ONNX model"):
        read_header(p)


def test_truncated_model_is_a_config_error(tmp_path):
    p = _model(tmp_path / "m.onnx")
    data = p.read_bytes()
    p.write_bytes(data[:len(data) // 2])
    with pytest.raises(ConfigError, match="not a loadable ONNX model"):
        read_header(p)

"""The correction slot: identity without a model; an ONNX model runs where its
metadata says it belongs and is refused elsewhere, with a message saying
where; field-of-view channels come from the full frame (kind: property)."""

from __future__ import annotations

import numpy as np
import pytest

from isp import CFA, CameraMeta, Domain, Frame, Pipeline, PlacementError
from isp.errors import ConfigError
from modules.correction import field_coordinates

onnx = pytest.importorskip("onnx")


def _model(path, domain="camera_rgb", fov="none", scale=2.0, meta=True):
    """out = scale * in[:, :3] (+ the FoV channels copied when fov="xy":
    out = [fov_x, fov_y, fov_x])."""
    from onnx import TensorProto, helper

    cin = 5 if fov == "xy" else 3
    inp = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, cin, "h", "w"])
    out = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 3, "h", "w"])
    if fov == "xy":
        idx = helper.make_tensor("idx", TensorProto.INT64, [3], [3, 4, 3])
        nodes = [helper.make_node("Gather", ["x", "idx"], ["y"], axis=1)]
        inits = [idx]
    else:
        s = helper.make_tensor("s", TensorProto.FLOAT, [], [scale])
        nodes = [helper.make_node("Mul", ["x", "s"], ["y"])]
        inits = [s]
    graph = helper.make_graph(nodes, "t", [inp], [out], initializer=inits)
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    if meta:
        for k, v in {"domain": domain, "placement": "after demosaic, before luminance",
                     "lens": "test-lens", "tile_size": "256", "fov_encoding": fov}.items():
            e = m.metadata_props.add()
            e.key, e.value = k, v
    onnx.save(m, str(path))
    return path


def _frame(h=8, w=10):
    meta = CameraMeta(cfa=CFA.RGGB, raw_size=(h, w), active_area=(0, 0, h, w))
    return Frame(np.full((h, w, 3), 0.25, np.float32), Domain.CAMERA_RGB, meta)


def test_identity_without_model():
    p = Pipeline.from_names(["correction"], start="camera_rgb")
    out = p.run(_frame())
    assert np.array_equal(out.data, _frame().data) and "identity" in out.history[-1].note


def test_model_runs_at_its_placement(tmp_path):
    m = _model(tmp_path / "m.onnx")
    p = Pipeline.from_names(["demosaic", "correction", "luminance"], {"correction": {"model": str(m)}},
                            start="raw_linear")
    mosaic = Frame(np.full((8, 10), 0.25, np.float32), Domain.RAW_LINEAR, CameraMeta(cfa=CFA.RGGB))
    out = p.run(mosaic)
    assert np.allclose(out.data, 0.5) and "m.onnx" in out.history[1].note


def test_model_in_the_wrong_place_is_refused_saying_where(tmp_path):
    m = _model(tmp_path / "m.onnx", domain="camera_rgb")
    with pytest.raises(PlacementError) as e:
        Pipeline.from_names(["black_level", "white_balance", "demosaic", "ccm", "correction", "gamma"],
                            {"correction": {"model": str(m)}})
    msg = str(e.value)
    assert "'correction'" in msg and "camera_rgb" in msg and "linear_rgb" in msg
    assert "after demosaic, before luminance" in msg


def test_model_without_metadata_or_file_is_refused(tmp_path):
    m = _model(tmp_path / "bare.onnx", meta=False)
    with pytest.raises(PlacementError, match="no 'domain' metadata"):
        Pipeline.from_names(["correction"], {"correction": {"model": str(m)}}, start="camera_rgb")
    with pytest.raises(ConfigError, match="not found"):
        Pipeline.from_names(["correction"], {"correction": {"model": str(tmp_path / "x.onnx")}},
                            start="camera_rgb")


def test_fov_channels_come_from_the_full_frame(tmp_path):
    m = _model(tmp_path / "fov.onnx", fov="xy")
    meta = CameraMeta(cfa=CFA.RGGB, raw_size=(40, 60), active_area=(0, 0, 40, 60), origin=(10, 20))
    crop = Frame(np.zeros((8, 10, 3), np.float32), Domain.CAMERA_RGB, meta)
    out = Pipeline.from_names(["correction"], {"correction": {"model": str(m)}}, start="camera_rgb").run(crop)
    expect = field_coordinates((8, 10), (10, 20), (40, 60))
    assert np.allclose(out.data[..., 0], expect[0]) and np.allclose(out.data[..., 1], expect[1])
    # the crop sits left of and above the centre: x and y negative there
    assert out.data[..., 0].max() < 0.05 and out.data[..., 1].max() < 0.0


def test_field_coordinates_symmetric_on_full_frame():
    c = field_coordinates((6, 8), (0, 0), (6, 8))
    assert np.allclose(c[0], -c[0][:, ::-1]) and np.allclose(c[1], -c[1][::-1])
    assert c.min() > -1 and c.max() < 1

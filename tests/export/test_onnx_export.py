"""``export/onnx_export.py``: checkpoint → ONNX FP32, and the checks the
export makes. Property tests on a tiny untrained model: ONNX ↔ torch
parity (packed and planar forms), constant conv weights, metadata round
trip through the correction stage, the INT8 copy's own tile overlap, the
stage's packed tiles, dead nodes pruned."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxruntime.quantization")

from isp import CFA, CameraMeta, Domain, Frame
from isp.errors import ConfigError

pytestmark = [pytest.mark.property, pytest.mark.filterwarnings("ignore:Please consider to run pre-processing"),
              pytest.mark.filterwarnings("ignore::DeprecationWarning")]


def test_fp32_parity_and_constant_weights(exported):
    """Property (ONNX ↔ torch): max abs error ≤ 1e-4 at two sizes (dynamic
    H, W); every Conv weight and bias an initializer; opset ≥ 17."""
    from export.onnx_export import check_constant_weights

    d, model, report = exported
    assert report["parity_max_abs"] <= 1e-4
    proto = onnx.load(str(d / "tiny.onnx"))
    assert max(o.version for o in proto.opset_import if o.domain in ("", "ai.onnx")) >= 17
    assert check_constant_weights(proto) == report["convs"] == report["ops"]["Conv"] > 0
    inp = proto.graph.input[0].type.tensor_type.shape.dim
    assert [x.dim_param for x in inp[2:]] == ["height", "width"]
    # independent check of the file on disk at a third size
    from export.onnx_export import model_input, sample_frame

    x = model_input(sample_frame((48, 80), True, 9), True)
    sess = ort.InferenceSession(str(d / "tiny.onnx"), providers=["CPUExecutionProvider"])
    with torch.no_grad():
        ref = model(torch.from_numpy(x)).numpy()
    # the file takes its input packed 2×2 to depth: built here by hand, pixel by pixel of a block
    assert report["metadata"]["space_to_depth"] == "2"
    rgb = [x[:, c, dy::2, dx::2] for dy in range(2) for dx in range(2) for c in range(3)]
    field = [(x[:, c, 0::2, 0::2] + x[:, c, 1::2, 1::2]) / 2 for c in (3, 4)]   # linear: block centre
    got = sess.run(None, {"input": np.stack(rgb + field, axis=1)})[0]
    assert got.shape == (1, 12, 24, 40)
    for k, (dy, dx, c) in enumerate((dy, dx, c) for dy in range(2) for dx in range(2) for c in range(3)):
        assert np.abs(got[:, k] - ref[:, c, dy::2, dx::2]).max() <= 1e-4
    # the packed head's 12 output channels are padded with zero filters to 16
    # (which the INT8 kernel needs to run fast) and sliced off again
    inits = {i.name: i for i in proto.graph.initializer}
    head = [n for n in proto.graph.node if n.op_type == "Conv" and n.name.startswith("/head/")]
    assert len(head) == 1 and onnx.numpy_helper.to_array(inits[head[0].input[1]]).shape[0] == 16


def test_planar_export_is_the_same_function(exported, tmp_path):
    from export.onnx_export import model_input, export_onnx, sample_frame

    d, model, _ = exported
    report = export_onnx(d / "tiny.pt", tmp_path / "planar.onnx", tile_size=256, packed=False,
                         measure_overlap=False)
    assert "space_to_depth" not in report["metadata"] and report["parity_max_abs"] <= 1e-4
    x = model_input(sample_frame((48, 80), True, 9), True)
    sess = ort.InferenceSession(str(tmp_path / "planar.onnx"), providers=["CPUExecutionProvider"])
    with torch.no_grad():
        ref = model(torch.from_numpy(x)).numpy()
    assert np.abs(sess.run(None, {"input": x})[0] - ref).max() <= 1e-4
    # the packed form drops the full-resolution DepthToSpace of the head
    assert report["ops"].get("DepthToSpace", 0) == 2


def test_metadata_accepted_by_the_correction_stage(exported):
    from export.onnx_export import METADATA_KEYS
    from modules.correction import Correction

    d, _, report = exported
    meta = report["metadata"]
    assert set(METADATA_KEYS) <= set(meta)
    assert meta["domain"] == "camera_rgb" and meta["lens"] == "test-lens" and meta["training_data"] == "abc123"
    assert meta["fov_encoding"] == "xy" and meta["precision"] == "fp32" and meta["tile_size"] == "256"
    # the overlap was measured and is at most the receptive radius
    assert report["overlap"]["overlap"] is not None and int(meta["tile_overlap"]) == report["overlap"]["overlap"]
    stage = Correction(model=d / "tiny.onnx")
    stage.check(Domain.CAMERA_RGB)
    assert stage.info.overlap == int(meta["tile_overlap"]) and stage.info.tile_size == 256
    with pytest.raises(ConfigError, match="camera_rgb"):
        stage.check(Domain.LINEAR_RGB)
    h, w = 300, 200
    meta_cam = CameraMeta(cfa=CFA.RGGB, raw_size=(h, w), active_area=(0, 0, h, w))
    frame = Frame(np.random.default_rng(0).random((h, w, 3), dtype=np.float32), Domain.CAMERA_RGB, meta_cam)
    out = stage.process(frame)
    assert out.data.shape == (h, w, 3) and np.isfinite(out.data).all()


def test_non_constant_conv_weight_is_refused():
    from onnx import TensorProto, helper

    from export.onnx_export import ExportError, check_constant_weights

    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 1, 4, 4])
    wt = helper.make_tensor_value_info("w", TensorProto.FLOAT, [1, 1, 3, 3])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, None)
    g = helper.make_graph([helper.make_node("Conv", ["x", "w"], ["y"], name="dyn")], "g", [x, wt], [y])
    with pytest.raises(ExportError, match="dyn"):
        check_constant_weights(helper.make_model(g))


def test_int8_copy_gets_its_own_tile_overlap(exported, quantized, tmp_path):
    """The INT8 file's margin is measured on the INT8 file and is at least its
    receptive radius (its rounding needs more context than the float model:
    one context change that flips a rounding moves the output by a whole
    step): its tiles then reproduce the whole frame bit for bit, and the
    metadata says so; the border context stays the float model's."""
    import shutil

    from export.onnx_export import OVERLAP_TOLERANCE, remeasure_overlap, sample_frame
    from modules.correction import Correction

    q8 = tmp_path / "q.int8.onnx"
    shutil.copy(exported[0] / "tiny.int8.onnx", q8)
    r = remeasure_overlap(q8)
    m = r["overlap"]
    assert m is not None and r["errors"][m] <= OVERLAP_TOLERANCE
    assert all(e > OVERLAP_TOLERANCE for k, e in r["errors"].items() if k < m)
    stage = Correction(model=q8)
    assert stage.info.overlap == r["overlap_int8"] == max(m, 64)   # the radius, 63, on the 4-px grid
    assert stage.info.border == int(exported[2]["metadata"]["tile_overlap"])
    h, w = 512, 704
    frame = Frame(sample_frame((h, w), True, 0), Domain.CAMERA_RGB,
                  CameraMeta(cfa=CFA.RGGB, raw_size=(h, w), active_area=(0, 0, h, w)))
    tiled = Correction(model=q8, tile_size=2 * stage.info.overlap + 96).process(frame).data
    whole = Correction(model=q8, tile_size=0).process(frame).data
    assert np.array_equal(tiled, whole)
    # ... which the float model's margin does not give the INT8 file
    b = stage.info.border
    short = Correction(model=q8, tile_size=2 * stage.info.overlap + 96, overlap=b).process(frame).data
    assert not np.array_equal(short, Correction(model=q8, tile_size=0, overlap=b).process(frame).data)


@pytest.mark.parametrize("shape", [(150, 203), (96, 128)])
def test_stage_packs_tiles_as_the_planar_model_sees_them(exported, tmp_path, shape):
    """The stage with the packed export, in tiles on a frame whose sides are
    not multiples of the packing, equals the planar export run on the whole
    frame (field channels, reflection at the borders and the cut last tiles
    included)."""
    from export.onnx_export import export_onnx, sample_frame
    from isp import CFA, CameraMeta, Frame
    from modules.correction import Correction

    d = exported[0]
    export_onnx(d / "tiny.pt", tmp_path / "planar.onnx", tile_size=256, packed=False, overlap=16)
    img = sample_frame(shape, True, 5)
    meta = CameraMeta(cfa=CFA.RGGB, raw_size=(400, 500), active_area=(0, 0, 400, 500))
    frame = Frame(img, Domain.CAMERA_RGB, meta)
    for tile in (0, 64):   # whole frame, then tiles (the same tiles for both)
        planar = Correction(model=tmp_path / "planar.onnx", tile_size=tile, overlap=16).process(frame).data
        packed = Correction(model=d / "tiny.onnx", tile_size=tile, overlap=16).process(frame).data
        assert not np.allclose(planar, img, atol=1e-3)   # the model does something
        assert np.abs(packed - planar).max() <= 2e-5


def test_dead_nodes_are_pruned_and_live_ones_kept():
    """prune_dead_nodes removes chains nobody reads (a Q → DQ pair left by
    bypass_input_qdq) and keeps everything on the way to an output."""
    from onnx import TensorProto, helper

    from export.quantize import prune_dead_nodes

    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 4])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 4])
    nodes = [helper.make_node("Relu", ["x"], ["a"], name="live1"),
             helper.make_node("Neg", ["a"], ["y"], name="live2"),
             helper.make_node("Abs", ["a"], ["d1"], name="dead1"),     # read only by dead2
             helper.make_node("Sqrt", ["d1"], ["d2"], name="dead2")]   # read by nobody
    model = helper.make_model(helper.make_graph(nodes, "g", [x], [y]))
    assert prune_dead_nodes(model) == 2
    assert [n.name for n in model.graph.node] == ["live1", "live2"]
    onnx.checker.check_model(model)
    assert prune_dead_nodes(model) == 0

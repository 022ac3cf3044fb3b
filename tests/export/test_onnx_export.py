"""``export/``: checkpoint → ONNX FP32 → static INT8, and the checks the
export makes. Property tests (ONNX ↔ torch parity, metadata round trip through
the correction stage, constant conv weights, every conv quantised) on a
tiny untrained model; the INT8 PSNR check on smooth random pairs (see
:func:`test_int8_psnr_drop`)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxruntime.quantization")

from isp import CFA, CameraMeta, Domain, Frame
from isp.errors import ConfigError, InputError
from restoration.nn.checkpoint import save_checkpoint
from restoration.nn.network import build_model

pytestmark = [pytest.mark.property, pytest.mark.filterwarnings("ignore:Please consider to run pre-processing"),
              pytest.mark.filterwarnings("ignore::DeprecationWarning")]

KW = {"widths": [8, 16], "depths": [1, 1, 1]}
META = {"domain": "camera_rgb", "placement": "camera_rgb after demosaic", "lens": "test-lens",
        "fov_encoding": "xy", "training_data": "abc123", "input_multiple": 4, "receptive_radius": 63,
        "attention": "local", "process": {"tone": "none", "white": 4.0}}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    from export.onnx_export import export_onnx

    d = tmp_path_factory.mktemp("export")
    torch.manual_seed(3)
    model = build_model("doconv", **KW)
    with torch.no_grad():  # away from the identity, so parity and quantisation see a real correction
        model.head[0].weight.mul_(10)
    ckpt = save_checkpoint(d / "tiny.pt", model, variant="doconv", model_kwargs=KW, step=5, metadata=META)
    report = export_onnx(ckpt, d / "tiny.onnx", tile_size=256)
    return d, model.eval(), report


def _reader(n=6, size=64, seed=0):
    """Calibration crops (1, 5, size, size): smooth random RGB + field."""
    from export.onnx_export import model_input, sample_frame

    class Reader:
        def __init__(self):
            self.it = iter([{"input": model_input(sample_frame((size, size), True, seed + k), True)}
                            for k in range(n)])

        def get_next(self):
            return next(self.it, None)

        def __len__(self):
            return n

    return Reader()


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


@pytest.fixture(scope="module")
def quantized(exported):
    from export.quantize import quantize_int8

    d = exported[0]
    return quantize_int8(d / "tiny.onnx", d / "tiny.int8.onnx", _reader())


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


def test_bad_input_is_one_line_exit_2(tmp_path, capsys):
    from isp.cli.main import main

    assert main(["export", str(tmp_path / "none.pt"), "-o", str(tmp_path / "m.onnx")]) == 2
    assert "no such checkpoint" in capsys.readouterr().err
    assert main(["export", "x.pt", "-o", str(tmp_path / "m.onnx"), "--int8"]) == 2
    assert "--calib-data" in capsys.readouterr().err
    with pytest.raises(InputError, match="manifest"):
        from export.quantize import SynthCalibration

        SynthCalibration(tmp_path, 4)


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

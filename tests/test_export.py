"""``export/``: checkpoint → ONNX FP32 → static INT8, and the checks issue 7
asks for. Property tests (ONNX ↔ torch parity, metadata round trip through
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
from restoration.checkpoint import save_checkpoint
from restoration.network import build_model

pytestmark = [pytest.mark.filterwarnings("ignore:Please consider to run pre-processing"),
              pytest.mark.filterwarnings("ignore::DeprecationWarning")]

KW = {"widths": [8, 16], "depths": [1, 1, 1]}
META = {"domain": "camera_rgb", "placement": "camera_rgb after demosaic", "lens": "test-lens",
        "fov_encoding": "xy", "training_data": "abc123", "input_multiple": 4, "receptive_radius": 60,
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
    from export.onnx_export import _model_input, sample_frame

    class Reader:
        def __init__(self):
            self.it = iter([{"input": _model_input(sample_frame((size, size), True, seed + k), True)}
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
    from export.onnx_export import _model_input, sample_frame

    x = _model_input(sample_frame((48, 80), True, 9), True)
    sess = ort.InferenceSession(str(d / "tiny.onnx"), providers=["CPUExecutionProvider"])
    with torch.no_grad():
        ref = model(torch.from_numpy(x)).numpy()
    assert np.abs(sess.run(None, {"input": x})[0] - ref).max() <= 1e-4


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
    assert q["fp32_conv"] == exported[2]["convs"]
    assert q["int8_quantized_conv"] == q["fp32_conv"] and q["int8_float_conv"] == 0
    assert q["ops"].get("QuantizeLinear", 0) > 0  # QDQ form
    stage = Correction(model=exported[0] / "tiny.int8.onnx")
    stage.check(Domain.CAMERA_RGB)
    assert stage.model_meta["precision"] == "int8" and stage.model_meta["lens"] == "test-lens"


def test_int8_psnr_drop(exported, quantized):
    """INT8 vs FP32 PSNR drop ≤ 0.2 dB (issue 7's limit), here on 4 smooth
    random pairs (target = a random-ish frame, input = its Gaussian blur),
    PSNR in linear RGB of the whole output, and with the tiny *untrained*
    model (close to the identity), not the restoration test set: the CLI
    measures that one (``isp export --int8 --calib-data``)."""
    import cv2

    from export.onnx_export import _model_input, sample_frame

    d = exported[0]
    s32, s8 = (ort.InferenceSession(str(d / f), providers=["CPUExecutionProvider"])
               for f in ("tiny.onnx", "tiny.int8.onnx"))
    p32, p8 = [], []
    for k in range(4):
        target = np.clip(sample_frame((96, 128), True, 100 + k), 0, 1)
        x = _model_input(cv2.GaussianBlur(target, (0, 0), 1.5), True)
        for s, acc in ((s32, p32), (s8, p8)):
            y = s.run(None, {"input": x})[0][0].transpose(1, 2, 0)
            acc.append(10 * np.log10(1 / np.mean((y - target) ** 2)))
    drop = np.mean(p32) - np.mean(p8)
    assert drop <= 0.2, (np.mean(p32), np.mean(p8))


def test_bad_input_is_one_line_exit_2(tmp_path, capsys):
    from isp.cli import main

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
    x = next(iter(_reader(1, 64, 7).it))["input"]
    a = ort.InferenceSession(str(tmp_path / "sq.onnx")).run(None, {"input": x})[0]
    b = ort.InferenceSession(str(tmp_path / "sq.int8.onnx")).run(None, {"input": x})[0]
    assert np.abs(a - b).mean() < 0.01

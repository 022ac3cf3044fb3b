"""The correction slot: identity without a model; an ONNX model runs where its
metadata says it belongs and is refused elsewhere, with a message saying
where; field-of-view channels come from the full frame (kind: property)."""

from __future__ import annotations

import numpy as np
import pytest

from isp import CFA, CameraMeta, Domain, Frame, Pipeline, PlacementError
from isp.errors import ConfigError
from modules.correction import field_coordinates

pytestmark = pytest.mark.property

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
    p = Pipeline.from_names(["correction"], {"correction": {"model": "none"}}, start="camera_rgb")
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


# ------------------------------------------------------------ tiled inference

def _conv_model(path, *, fov="xy", dilations=(1, 2, 4), s2d=False, meta=None, stats=False, seed=0):
    """A small local network, dynamic H/W: 3×3 convolutions with
    ``dilations`` and ReLUs between, zero-padded like a trained model's.
    Receptive-field radius Σ dilations (× 2 with ``s2d``: the convs then run
    at ½ resolution between SpaceToDepth and DepthToSpace, so the model is
    equivariant to even shifts only). Input 5 channels (RGB + field) with
    ``fov="xy"``, else 3; output 3. ``stats``: a second input (1, 3, 1, 1)
    added to the output."""
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(seed)
    cin = 5 if fov == "xy" else 3
    inputs = [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, cin, "h", "w"])]
    nodes, inits, cur, c = [], [], "x", cin
    if s2d:
        nodes.append(helper.make_node("SpaceToDepth", [cur], ["s2d"], blocksize=2))
        cur, c = "s2d", 4 * cin
    widths = [8] * (len(dilations) - 1) + [12 if s2d else 3]
    for i, (d, co) in enumerate(zip(dilations, widths)):
        w = rng.normal(0, 1.5 / np.sqrt(9 * c), (co, c, 3, 3)).astype(np.float32)
        inits += [numpy_helper.from_array(w, f"w{i}"),
                  numpy_helper.from_array(rng.normal(0, 0.1, co).astype(np.float32), f"b{i}")]
        nodes.append(helper.make_node("Conv", [cur, f"w{i}", f"b{i}"], [f"c{i}"], kernel_shape=[3, 3],
                                      pads=[d] * 4, dilations=[d, d]))
        cur, c = f"c{i}", co
        if i < len(dilations) - 1:
            nodes.append(helper.make_node("Relu", [cur], [f"r{i}"]))
            cur = f"r{i}"
    if s2d:
        nodes.append(helper.make_node("DepthToSpace", [cur], ["d2s"], blocksize=2, mode="DCR"))
        cur = "d2s"
    if stats:
        inputs.append(helper.make_tensor_value_info("stats", TensorProto.FLOAT, [1, 3, 1, 1]))
        nodes.append(helper.make_node("Add", [cur, "stats"], ["withstats"]))
        cur = "withstats"
    nodes.append(helper.make_node("Identity", [cur], ["y"]))
    out = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 3, "h", "w"])
    m = helper.make_model(helper.make_graph(nodes, "t", inputs, [out], initializer=inits),
                          opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    radius = sum(dilations) * (2 if s2d else 1)
    md = {"domain": "camera_rgb", "placement": "after demosaic", "lens": "test-lens",
          "fov_encoding": fov, "tile_size": "256", "receptive_radius": str(radius),
          "input_multiple": "2" if s2d else "1", **(meta or {})}
    for k, v in md.items():
        e = m.metadata_props.add()
        e.key, e.value = k, v
    onnx.save(m, str(path))
    return path


def _rgb_frame(rng, h, w, origin=(0, 0), full=None):
    full = full or (h, w)
    meta = CameraMeta(cfa=CFA.RGGB, raw_size=full, active_area=(0, 0, *full), origin=origin)
    return Frame(rng.random((h, w, 3), dtype=np.float32), Domain.CAMERA_RGB, meta)


def _run(model, frame, **kw):
    from modules.correction import Correction

    return Correction(model=model, **kw)(frame).data


def test_tiled_equals_untiled_700x900(tmp_path, rng):
    """Max seam error ≤ 1 DN at 8 bits against an untiled run
    (measured: ~1e-6, float rounding); the field channels depend on the
    tile's position, so a wrong origin would show."""
    from modules.correction import Correction

    m = _conv_model(tmp_path / "c.onnx")
    f = _rgb_frame(rng, 700, 900)
    stage = Correction(model=m)
    tiled = stage(f)
    assert "tiles of 256 px, overlap 7 px" in tiled.history[-1].note
    untiled = _run(m, f, tile_size=0)
    assert np.abs(tiled.data - untiled).max() < 1e-5
    # the untiled run is the model on the reflect-padded frame (image and field)
    x = np.concatenate([f.data.transpose(2, 0, 1), field_coordinates((700, 900), (0, 0), (700, 900))])
    x = np.pad(x, ((0, 0), (7, 7), (7, 7)), mode="reflect")[None]
    ref = stage.session.run(None, {"x": x})[0][0, :, 7:-7, 7:-7].transpose(1, 2, 0)
    assert np.abs(untiled - ref).max() < 1e-5


def test_two_threads_run_tiles_side_by_side_with_the_same_result(tmp_path, rng):
    """threads = 2 on a frame of several tiles: two tiles at once, each on a
    one-thread session (module Notes), bit for bit one thread's frame."""
    from modules.correction import Correction

    m = _conv_model(tmp_path / "c.onnx")
    f = _rgb_frame(rng, 700, 900)
    two, one = Correction(model=m, threads=2), Correction(model=m, threads=1)
    assert two.workers(two.tile_count((700, 900))) == 2 and one.workers(one.tile_count((700, 900))) == 1
    assert two.workers(two.tile_count((100, 100))) == 1   # one tile: two intra-op threads instead
    assert two.tile_session(2) is one.session and two.tile_session(1) is two.session
    assert np.array_equal(two(f).data, one(f).data)


def test_prepare_loads_the_session_in_the_background(tmp_path, rng):
    import time

    from modules.correction import Correction, _cached_session

    m = _conv_model(tmp_path / "c.onnx")
    stage = Correction(model=m, threads=2)
    _cached_session.cache_clear()
    stage.prepare(_rgb_frame(rng, 700, 900))
    deadline = time.monotonic() + 30
    while _cached_session.cache_info().currsize < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert _cached_session.cache_info().currsize == 1     # the one-thread session the tiles run on
    Correction(model="none").prepare(_rgb_frame(rng, 10, 10))   # nothing to load: no error


def test_tiled_equals_untiled_with_downsampling_and_odd_size(tmp_path, rng):
    """A stride-2 model on a 301×403 frame: windows of even size at even
    origins (input_multiple), padding to the multiple by reflection."""
    m = _conv_model(tmp_path / "s.onnx", s2d=True, dilations=(1, 2), meta={"input_multiple": "4"})
    f = _rgb_frame(rng, 301, 403)
    tiled = _run(m, f, tile_size=96)
    assert tiled.shape == (301, 403, 3)
    assert np.abs(tiled - _run(m, f, tile_size=0)).max() < 1e-5


def test_seam_error_grows_when_overlap_below_receptive_field(tmp_path, rng):
    """Proves the test above can fail: radius 7, overlap 7 / 4 / 1."""
    m = _conv_model(tmp_path / "c.onnx")
    f = _rgb_frame(rng, 200, 260)
    untiled = _run(m, f, tile_size=0)
    err = [np.abs(_run(m, f, tile_size=64, overlap=o) - untiled).max() for o in (7, 4, 1)]
    assert err[0] < 1e-5 and 1 / 255 < err[1] < err[2]


def test_field_channels_per_tile_on_a_crop(tmp_path):
    """The field model (output = field x, y, x) on a crop of a larger frame,
    in 24 tiles: each pixel gets its position on the full frame."""
    m = _model(tmp_path / "fov.onnx", fov="xy")
    meta = CameraMeta(cfa=CFA.RGGB, raw_size=(300, 400), active_area=(0, 0, 300, 400), origin=(37, 51))
    crop = Frame(np.zeros((130, 190, 3), np.float32), Domain.CAMERA_RGB, meta)
    out = _run(m, crop, tile_size=40, overlap=3)
    expect = field_coordinates((130, 190), (37, 51), (300, 400))
    assert np.array_equal(out[..., 0], expect[0]) and np.array_equal(out[..., 1], expect[1])


def test_stats_input_is_the_frame_mean_in_every_tile(tmp_path, rng):
    m = _conv_model(tmp_path / "g.onnx", stats=True, meta={"attention": "global"})
    f = _rgb_frame(rng, 150, 170)
    f = f.evolve(f.data * np.array([1.0, 2.0, 3.0], np.float32))
    tiled, untiled = _run(m, f, tile_size=48), _run(m, f, tile_size=0)
    assert np.abs(tiled - untiled).max() < 1e-5
    # the stats term is the mean of the frame, not of a tile: remove it and compare
    m0 = _conv_model(tmp_path / "l.onnx")
    diff = tiled - _run(m0, f, tile_size=48)
    assert np.allclose(diff, f.data.mean(axis=(0, 1)), atol=1e-5)


def test_global_attention_without_stats_runs_untiled_only(tmp_path):
    m = _conv_model(tmp_path / "g.onnx", meta={"attention": "global"})
    with pytest.raises(ConfigError, match="attention='global'.*tile_size = 0"):
        Pipeline.from_names(["correction"], {"correction": {"model": str(m)}}, start="camera_rgb")
    Pipeline.from_names(["correction"], {"correction": {"model": str(m), "tile_size": 0}}, start="camera_rgb")


@pytest.mark.parametrize("key,value,match", [
    ("tile_overlap", "a lot", "tile_overlap='a lot'"),
    ("attention", "tiled", "'local', 'global'"),
    ("fov_encoding", "polar", "'none', 'xy'"),
    ("tile_size", "14", "at least 15 px"),
])
def test_bad_metadata_is_named(tmp_path, key, value, match):
    m = _conv_model(tmp_path / "b.onnx", meta={key: value})
    with pytest.raises(ConfigError, match=match):
        Pipeline.from_names(["correction"], {"correction": {"model": str(m)}}, start="camera_rgb")


def test_session_options_and_sharing(tmp_path):
    import onnxruntime as ort

    from modules.correction import Correction

    m = _conv_model(tmp_path / "c.onnx")
    a, b = Correction(model=m), Correction(model=str(m))
    assert a.session is b.session
    o = a.session.get_session_options()
    assert o.intra_op_num_threads == 2 and o.inter_op_num_threads == 1
    assert o.execution_mode == ort.ExecutionMode.ORT_SEQUENTIAL
    assert o.graph_optimization_level == ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    assert o.get_session_config_entry("session.intra_op.allow_spinning") == "0"


def test_int8_model_goes_through_the_same_tiling(tmp_path, rng):
    """A static QDQ INT8 model: tiles agree with the untiled run (fixed
    scales), and the output stays near the float model's."""
    from onnxruntime.quantization import (
        CalibrationDataReader,
        QuantFormat,
        quantize_static,
    )

    fp = _conv_model(tmp_path / "fp.onnx")

    class Reader(CalibrationDataReader):
        def __init__(self):
            self.it = iter([{"x": np.concatenate([rng.random((1, 3, 32, 32), dtype=np.float32),
                                                  rng.uniform(-1, 1, (1, 2, 32, 32)).astype(np.float32)], 1)}
                            for _ in range(4)])

        def get_next(self):
            return next(self.it, None)

    q = tmp_path / "int8.onnx"
    quantize_static(str(fp), str(q), Reader(), quant_format=QuantFormat.QDQ)
    md = onnx.load(str(q))
    assert any(n.op_type == "QuantizeLinear" for n in md.graph.node)
    assert {p.key for p in md.metadata_props} >= {"domain", "receptive_radius"}
    f = _rgb_frame(rng, 150, 170)
    tiled, untiled = _run(q, f, tile_size=64), _run(q, f, tile_size=0)
    assert np.abs(tiled - untiled).max() < 1e-5  # measured: 0
    assert np.abs(tiled - _run(fp, f)).mean() < 0.02


def test_frame_statistics_rgb_and_field(rng):
    from modules.correction import frame_statistics

    d = rng.random((30, 40, 3), dtype=np.float32)
    assert np.allclose(frame_statistics(d, 3), d.mean(axis=(0, 1)), atol=1e-6)
    s = frame_statistics(d, 5, origin=(0, 0), full_size=(60, 40))  # the top half of the frame
    assert np.allclose(s[3:], field_coordinates((30, 40), (0, 0), (60, 40)).mean(axis=(1, 2)), atol=1e-6)
    assert abs(s[3]) < 1e-6 and np.isclose(s[4], -0.5)


def test_auto_runs_the_model_of_the_frame_s_lens_profile_only(tmp_path):
    """``model = "auto"`` (the default): the model of the profile matching
    ``frame.meta``, per frame, the identity for another lens; a profile
    model at a position its domain does not fit is refused when it runs."""
    from isp.profiles import PROFILES, Profile, register_profile

    m = _model(tmp_path / "m.onnx")                       # out = 2 · in, camera_rgb
    register_profile(Profile("test-auto", {"LensModel": "TEST auto lens"}, m))
    try:
        stage = Pipeline.from_names(["correction"], start="camera_rgb").stages[0]
        assert stage.model == "auto" and stage.summary()["model"] == "auto"
        mine = _frame()
        mine = Frame(mine.data, mine.domain, mine.meta.replace(lens="TEST auto lens"))
        out = stage(mine)
        assert np.allclose(out.data, 0.5)
        assert out.history[-1].note.startswith("profile 'test-auto' (LensModel 'TEST auto lens'): m.onnx")
        other = stage(_frame())
        assert np.array_equal(other.data, _frame().data)
        assert other.history[-1].note.startswith("identity: no profile for ")
        assert stage.summary(mine.meta)["profile"] == "test-auto"
        assert stage.summary(_frame().meta)["model"] is None
        late = Pipeline.from_names(["correction"], start="linear_rgb")      # builds: no model known yet
        with pytest.raises(PlacementError, match="profile 'test-auto'.*trained for camera_rgb"):
            late.run(Frame(mine.data, Domain.LINEAR_RGB, mine.meta))
    finally:
        PROFILES.remove("test-auto")

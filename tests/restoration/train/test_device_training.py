"""A correction network conditioned on the device, from pairs to the stage
(kind: property).

A tiny set is synthesised through two lenses (a mild and a strong blur
widening over the field), each carrying its own device descriptor in the
manifest, as ``isp synth --basis`` writes it. Checked: every pair's batch
carries its own lens's descriptor at each pixel (the stage's function),
with the configured noise; a tiny ``device`` network trains on it and its
checkpoint and ONNX export name the design and basis; the correction stage
reads a ``device/v1`` file, its tiles equal its whole frame, a file of
another design is refused in one line, and a run without one says so; a
blind model says it ignores one; a conditioned model cannot be trained on
a set without descriptors.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from tests.helpers import TINY_UNET_KW as TINY
from tests.helpers import data_file, kernel_psf_map, latent_pngs, make_frame, widening_gaussian_map, write_toml

pytestmark = pytest.mark.property

torch = pytest.importorskip("torch")

from isp.cli.main import main
from isp.errors import ConfigError
from isp.io.device import DeviceCalibration, descriptor_map
from isp.runtime.executor import create_executor

DESIGN, BASIS = "d" * 64, "b" * 64
K = 3
#: each lens's descriptor on a 2 × 2 grid, K numbers per region
DESCRIPTORS = np.array([np.full((2, 2, K), -0.5), np.arange(2 * 2 * K, dtype=float).reshape(2, 2, K) / 6])


def _strong_map():
    def kernel(r, c, ch, xx, yy):
        s = 1.4 + 0.5 * (r + c)
        return np.exp(-(xx ** 2 + yy ** 2) / (2 * s * s))

    return kernel_psf_map(kernel, height=96, width=128, grid=(3, 4), n=16)


@pytest.fixture(scope="module")
def device_pairs(tmp_path_factory):
    from restoration.synth.colour import colour_table, read_camera
    from restoration.synth.pairs import SynthPlan, SynthSettings, find_latents, generate

    tmp = tmp_path_factory.mktemp("device_pairs")
    cams = (read_camera(data_file("raw", "SYNTHETIC_phone_S6meta_512x384.dng")),)
    st = SynthSettings(size=64, cct_steps=4)
    lat = tuple(str(p) for p in find_latents(latent_pngs(tmp / "latent")))
    info = {"device": {"lens": "test-lens", "design": DESIGN, "basis": BASIS, "basis_file": "b.npz",
                       "grid": [2, 2], "components": K, "descriptors": DESCRIPTORS.tolist()}}
    plan = SynthPlan((widening_gaussian_map(), _strong_map()), cams, colour_table(list(cams), st.cct_k, st.cct_steps),
                     lat, (96, 128), 0, st, (4e-4, 1e-6), info)
    generate(plan, tmp / "pairs", 16, shard_size=8, executor=create_executor("serial"))
    return tmp / "pairs"


def test_each_pair_carries_its_lens_descriptor(device_pairs):
    from restoration.train.trainer import PairBank

    bank = PairBank.load([device_pairs], [(0, i) for i in range(16)])
    assert bank.device == {"lens": "test-lens", "design": DESIGN, "basis": BASIS, "components": K}
    assert bank.channels == 5 + K
    lens = np.arange(16) % 2                                     # pair i went through lens i mod 2
    assert np.array_equal(bank.descriptor, DESCRIPTORS[lens].astype(np.float32))
    x, _, _ = bank.batch([3, 4], [(4, 8), (0, 0)], 32)
    for n, (i, (r, c)) in enumerate(zip([3, 4], [(4, 8), (0, 0)])):
        o = bank.origin[i] + (r, c)
        want = descriptor_map(DESCRIPTORS[lens[i]], np.arange(32) + o[0], np.arange(32) + o[1], (96, 128))
        assert np.allclose(x[n, 5:], want, atol=1e-6)
    noisy, _, _ = bank.batch([3], [(4, 8)], 32, 0.3, np.random.default_rng(0))
    assert 0.01 < np.std(noisy[0, 5:] - x[0, 5:]) < 0.3         # per-region noise, interpolated
    # a swapped descriptor is another pair's lens's, exactly (no noise), and the image is the pair's own
    o = bank.origin[3] + (4, 8)
    others = {lens[j] for j in range(len(bank)) if lens[j] != lens[3]}
    rng = np.random.default_rng(1)
    swapped = [bank.batch([3], [(4, 8)], 32, 0.0, rng, descriptor_swap=0.999)[0] for _ in range(12)]
    assert all(np.array_equal(s[0, :5], x[0, :5]) for s in swapped)
    seen = {next((k for k in others | {lens[3]} if np.allclose(s[0, 5:], descriptor_map(
        DESCRIPTORS[k], np.arange(32) + o[0], np.arange(32) + o[1], (96, 128)), atol=1e-6)), None) for s in swapped}
    assert None not in seen and seen & others


@pytest.fixture(scope="module")
def device_model(device_pairs, tmp_path_factory):
    """A tiny ``device`` network trained 4 steps, exported (its margin: the receptive radius)."""
    from export.onnx_export import export_onnx

    tmp = tmp_path_factory.mktemp("device_model")
    cfg = {"data": {"dirs": [str(device_pairs)], "crop": 32, "batch": 4, "val_latents": 1, "val_pairs": 2,
                    "descriptor_noise": 0.1},
           "model": {"variant": "device", "kwargs": {**TINY, "device": K}},
           "optim": {"lr": 3e-3}, "run": {"steps": 4, "seed": 0, "device": "cpu", "threads": 1,
                                          "checkpoint_every": 4, "out": str(tmp / "out")}}
    assert main(["train", "--config", str(write_toml(tmp / "cfg.toml", cfg)), "-q"]) == 0
    report = export_onnx(tmp / "out" / "model.pt", tmp / "device.onnx", tile_size=0, measure_overlap=False)
    return tmp, report


def test_the_checkpoint_and_export_name_the_design_and_basis(device_model):
    from restoration.nn.checkpoint import load_model

    tmp, report = device_model
    model, info = load_model(tmp / "out" / "model.pt")
    md = info["metadata"]
    assert model.in_channels == 5 + K and md["device_components"] == K
    assert md["device_design"] == DESIGN and md["device_basis"] == BASIS
    meta = report["metadata"]
    assert meta["device_components"] == str(K) and meta["device_design"] == DESIGN
    assert meta["device_basis"] == BASIS and report["parity_max_abs"] < 1e-4


def test_the_stage_reads_the_device_file_and_its_tiles_are_the_whole_frame(device_model, tmp_path):
    from isp import Domain
    from modules.correction import Correction

    tmp, report = device_model
    radius = int(report["metadata"]["receptive_radius"])
    tile = 2 * radius + 32
    rng = np.random.default_rng(5)
    frame = make_frame(rng.random((96, 3 * tile, 3)), Domain.CAMERA_RGB)
    dev = DeviceCalibration("test-lens", DESIGN, BASIS, DESCRIPTORS[1]).save(tmp_path / "dev.json")
    model = tmp / "device.onnx"
    whole = Correction(model=model, device=dev, tile_size=0).process(frame)
    tiled = Correction(model=model, device=dev, tile_size=tile).process(frame)
    assert "device dev.json" in tiled.history[-1].note and "tiles" in tiled.history[-1].note
    assert np.abs(whole.data - tiled.data).max() < 1e-5
    mean = Correction(model=model, tile_size=0).process(frame)
    assert "descriptor 0" in mean.history[-1].note
    assert np.abs(mean.data - whole.data).max() > 1e-6            # the descriptor reaches the output
    other = DeviceCalibration("other-lens", "e" * 64, BASIS, DESCRIPTORS[1]).save(tmp_path / "other.json")
    with pytest.raises(ConfigError) as e:
        Correction(model=model, device=other, tile_size=0).process(frame)
    assert "other.json" in str(e.value) and "lens design" in str(e.value) and "\n" not in str(e.value)


def test_a_blind_model_says_it_ignores_a_device_file(exported_blind, tmp_path):
    from isp import Domain
    from modules.correction import Correction

    dev = DeviceCalibration("test-lens", DESIGN, BASIS, DESCRIPTORS[0]).save(tmp_path / "dev.json")
    out = Correction(model=exported_blind, device=dev, tile_size=0).process(
        make_frame(np.random.default_rng(1).random((32, 48, 3)), Domain.CAMERA_RGB))
    assert "dev.json ignored" in out.history[-1].note


@pytest.fixture(scope="module")
def exported_blind(tmp_path_factory):
    from export.onnx_export import export_onnx
    from restoration.nn.checkpoint import save_checkpoint
    from restoration.nn.network import build_model
    from tests.helpers import EXPORT_META

    d = tmp_path_factory.mktemp("blind")
    ckpt = save_checkpoint(d / "b.pt", build_model("doconv", **TINY), variant="doconv", model_kwargs=TINY, step=1,
                           metadata=EXPORT_META)
    export_onnx(ckpt, d / "b.onnx", tile_size=0, measure_overlap=False)
    return d / "b.onnx"


def test_a_conditioned_model_needs_pairs_with_descriptors(pairs, tmp_path):
    cfg = {"data": {"dirs": [str(pairs)], "crop": 32, "batch": 4, "val_latents": 1, "val_pairs": 2},
           "model": {"variant": "device", "kwargs": {**TINY, "device": K}},
           "run": {"steps": 1, "seed": 0, "device": "cpu", "threads": 1, "out": str(tmp_path / "out")}}
    code = main(["train", "--config", str(write_toml(tmp_path / "cfg.toml", cfg)), "-q"])
    assert code == 2
    assert not (tmp_path / "out" / "model.pt").exists()


def test_the_manifest_carries_each_lens_descriptor(device_pairs):
    m = json.loads((device_pairs / "manifest.json").read_text())
    assert np.array_equal(np.array(m["device"]["descriptors"]), DESCRIPTORS)
    assert m["device"]["design"] == DESIGN and m["device"]["components"] == K


def test_the_evaluation_runs_a_conditioned_model_with_the_device(device_model):
    """The checkpoint and its export, given the same device calibration,
    correct a crop alike (the evaluation's two runners), and the descriptor
    reaches the output."""
    from restoration.evaluate.runner import load_runner

    tmp, _ = device_model
    cal = DeviceCalibration("test-lens", DESIGN, BASIS, DESCRIPTORS[1], source={"measured": "dev.dng"})
    rgb = np.random.default_rng(3).random((96, 128, 3)).astype(np.float32)
    outs = [load_runner(p, device=cal)(rgb, (0, 0), (96, 128)) for p in (tmp / "out" / "model.pt", tmp / "device.onnx")]
    assert np.abs(outs[0] - outs[1]).max() < 1e-4
    blind = load_runner(tmp / "out" / "model.pt")(rgb, (0, 0), (96, 128))
    assert np.abs(blind - outs[0]).max() > 1e-6
    with pytest.raises(ConfigError, match="another lens design"):
        load_runner(tmp / "out" / "model.pt", device=DeviceCalibration("x", "e" * 64, BASIS, DESCRIPTORS[1]))


def test_isp_eval_refuses_a_bad_device_file_in_one_line(device_model, tmp_path, capsys):
    tmp, _ = device_model
    bad = tmp_path / "dev.json"
    bad.write_text("{}")
    code = main(["eval", str(tmp / "device.onnx"), "--images", str(tmp_path), "--lens",
                 str(data_file("lenses", "phone", "US-12210142-B2-e9.zmx")), "--json", str(tmp_path / "r.json"),
                 "--device", str(bad)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "dev.json" in err and "device/v1" in err and "\n" not in err


def test_a_frame_carrying_its_calibration_is_corrected_with_it(device_model, tmp_path):
    """A DNG's own calibration (DNGPrivateData, read into the frame's
    metadata) is used where the stage is given none, and gives what the
    same file given with --device gives; an explicit file wins."""
    from isp import Domain
    from modules.correction import Correction

    tmp, _ = device_model
    cal = DeviceCalibration("test-lens", DESIGN, BASIS, DESCRIPTORS[1])
    rgb = np.random.default_rng(6).random((96, 128, 3))
    carried = make_frame(rgb, Domain.CAMERA_RGB, device_calibration=cal.to_text(), path="module.dng")
    model = tmp / "device.onnx"
    own = Correction(model=model, tile_size=0).process(carried)
    assert "module.dng's own (DNGPrivateData)" in own.history[-1].note
    given = Correction(model=model, tile_size=0, device=cal.save(tmp_path / "dev.json")).process(
        make_frame(rgb, Domain.CAMERA_RGB))
    assert np.abs(own.data - given.data).max() < 1e-6
    other = DeviceCalibration("test-lens", DESIGN, BASIS, DESCRIPTORS[0]).save(tmp_path / "other.json")
    wins = Correction(model=model, tile_size=0, device=other).process(carried)
    assert "device other.json" in wins.history[-1].note and np.abs(wins.data - own.data).max() > 1e-6


def test_another_modules_calibration_is_refused_where_both_name_their_module(device_model, tmp_path):
    """Given the wrong module's file the model corrects worse than not at all
    (docs/results/device.md): where the file names its module's serial (from
    its chart capture) and the capture names its own, another module's file
    is refused in one line naming the capture; the same module's, or a file
    or capture naming none, is used."""
    from isp import Domain
    from isp.errors import InputError
    from modules.correction import Correction

    tmp, _ = device_model
    model = tmp / "device.onnx"
    rgb = np.random.default_rng(7).random((96, 128, 3))

    def cal(serial):
        src = {"measured": "chart.dng", **({"serial": serial} if serial else {})}
        return DeviceCalibration("test-lens", DESIGN, BASIS, DESCRIPTORS[1], source=src).save(
            tmp_path / f"dev_{serial or 'none'}.json")

    def run(serial, device):
        return Correction(model=model, tile_size=0, device=device).process(
            make_frame(rgb, Domain.CAMERA_RGB, serial=serial, path="module.dng"))

    with pytest.raises(InputError) as e:
        run("SN-2", cal("SN-1"))
    msg = str(e.value)
    assert msg.startswith("module.dng: dev_SN-1.json is the calibration of module SN-1") and "SN-2" in msg
    assert "\n" not in msg
    same = run("SN-1", cal("SN-1"))
    assert "device dev_SN-1.json" in same.history[-1].note
    assert np.abs(run("", cal("SN-1")).data - same.data).max() < 1e-6         # the capture names no module
    assert np.abs(run("SN-2", cal("")).data - same.data).max() < 1e-6         # the file names none


def test_a_conditioned_model_quantises_every_conv_and_reads_its_device_in_int8(device_model, tmp_path):
    """Static INT8 of the conditioned export (calibration crops carrying
    descriptor channels): every conv quantised; the INT8 model reads the
    device calibration as the float one does."""
    from isp import Domain
    from export.quantize import quantize_int8
    from modules.correction import Correction
    from tests.helpers import onnx_calibration_reader

    tmp, _ = device_model
    q8 = tmp_path / "device.int8.onnx"
    r = quantize_int8(tmp / "device.onnx", q8, onnx_calibration_reader(device=K))
    assert r["int8_quantized_conv"] == r["fp32_conv"] and r["int8_float_conv"] == 0
    cal = DeviceCalibration("test-lens", DESIGN, BASIS, DESCRIPTORS[1]).save(tmp_path / "dev.json")
    frame = make_frame(np.random.default_rng(2).random((64, 96, 3)), Domain.CAMERA_RGB)
    f32, i8 = (Correction(model=m, device=cal, tile_size=0).process(frame).data for m in (tmp / "device.onnx", q8))
    assert Correction(model=q8).model_meta["device_design"] == DESIGN
    assert np.abs(f32 - i8).mean() < 0.02


def test_a_profile_carries_a_modules_calibration(device_model, tmp_path, user_folder):
    """A profile with ``device = FILE`` gives the matching frames that
    calibration; a capture's own calibration and --device win over it."""
    from isp import Domain
    from modules.correction import Correction

    tmp, _ = device_model
    DeviceCalibration("test-lens", DESIGN, BASIS, DESCRIPTORS[1]).save(user_folder / "module7.json")
    (user_folder / "m7.toml").write_text(f'schema = "profile/v1"\nmodel = "{tmp / "device.onnx"}"\n'
                                         f'device = "module7.json"\n[match]\nLensModel = "test-lens"\n')
    rgb = np.random.default_rng(8).random((64, 96, 3))
    out = Correction(tile_size=0).process(make_frame(rgb, Domain.CAMERA_RGB, lens="test-lens"))
    assert "device module7.json" in out.history[-1].note
    own = DeviceCalibration("test-lens", DESIGN, BASIS, DESCRIPTORS[0])
    carried = make_frame(rgb, Domain.CAMERA_RGB, lens="test-lens", device_calibration=own.to_text())
    assert "DNGPrivateData" in Correction(tile_size=0).process(carried).history[-1].note
    given = own.save(tmp_path / "given.json")
    assert "device given.json" in Correction(tile_size=0, device=given).process(carried).history[-1].note


def test_a_profile_runs_its_conditioned_model_where_a_calibration_is_known(device_model, exported_blind,
                                                                         tmp_path, user_folder):
    """A profile with a blind ``model`` and a ``device_model``: a matching
    capture without a calibration gets the blind model; one with
    ``--device`` or its own calibration gets the conditioned model, which
    reads it."""
    from isp import Domain
    from modules.correction import Correction

    tmp, _ = device_model
    (user_folder / "lens.toml").write_text(f'schema = "profile/v1"\nmodel = "{exported_blind}"\n'
                                           f'device_model = "{tmp / "device.onnx"}"\n[match]\nLensModel = "test-lens"\n')
    rgb = np.random.default_rng(9).random((64, 96, 3))
    blind = Correction(tile_size=0).process(make_frame(rgb, Domain.CAMERA_RGB, lens="test-lens"))
    assert "b.onnx" in blind.history[-1].note and "device" not in blind.history[-1].note
    cal = DeviceCalibration("test-lens", DESIGN, BASIS, DESCRIPTORS[1])
    given = Correction(tile_size=0, device=cal.save(tmp_path / "dev.json")).process(
        make_frame(rgb, Domain.CAMERA_RGB, lens="test-lens"))
    assert "device.onnx" in given.history[-1].note and "device dev.json" in given.history[-1].note
    direct = Correction(model=tmp / "device.onnx", device=tmp_path / "dev.json", tile_size=0).process(
        make_frame(rgb, Domain.CAMERA_RGB))
    assert np.array_equal(given.data, direct.data) and np.abs(given.data - blind.data).max() > 1e-6
    carried = make_frame(rgb, Domain.CAMERA_RGB, lens="test-lens", device_calibration=cal.to_text())
    own = Correction(tile_size=0).process(carried)
    assert "device.onnx" in own.history[-1].note and np.abs(own.data - given.data).max() < 1e-6


def test_field_driven_attention_exports_and_tiles_as_the_whole_frame(tmp_path):
    """``device_attention`` (attention from field and descriptor alone,
    metadata ``attention = "field"``): the stage runs it, and its tiles equal
    the whole frame, as the stage's ``local`` models' do."""
    from export.onnx_export import export_onnx
    from restoration.nn.checkpoint import save_checkpoint
    from restoration.nn.network import build_model
    from tests.helpers import EXPORT_META

    kw = {**TINY, "device": K}
    meta = {**{k: v for k, v in EXPORT_META.items() if k != "attention"},   # the export reads it off the model
            "device_components": K, "device_design": DESIGN, "device_basis": BASIS}
    torch.manual_seed(0)
    ckpt = save_checkpoint(tmp_path / "m.pt", build_model("device_attention", **kw), variant="device_attention",
                           model_kwargs=kw, step=1, metadata=meta)
    report = export_onnx(ckpt, tmp_path / "att.onnx", tile_size=0, measure_overlap=False)
    assert report["metadata"]["attention"] == "field"
    # every pool a network can have is an attention mode the stage knows (training and export write the pool)
    from modules.correction import ATTENTION_MODES
    from restoration.nn.doconv import POOL_MODES

    assert set(POOL_MODES) <= set(ATTENTION_MODES)
    frame, dev, whole, tiled = _whole_and_tiled(tmp_path / "att.onnx", report, tmp_path)
    assert np.abs(whole.data - tiled.data).max() < 1e-5
    assert np.abs(whole.data - frame.data).max() > 1e-4          # the network did something


def _whole_and_tiled(model, report, tmp_path):
    """A frame three tiles wide (each tile twice the export's receptive
    radius and more), a device file, and the stage's output on the frame
    whole and tiled."""
    from isp import Domain
    from modules.correction import Correction

    tile = 2 * int(report["metadata"]["receptive_radius"]) + 32
    frame = make_frame(np.random.default_rng(6).random((96, 3 * tile, 3)), Domain.CAMERA_RGB)
    dev = DeviceCalibration("test-lens", DESIGN, BASIS, DESCRIPTORS[0]).save(tmp_path / "dev.json")
    whole = Correction(model=model, device=dev, tile_size=0).process(frame)
    tiled = Correction(model=model, device=dev, tile_size=tile).process(frame)
    return frame, dev, whole, tiled


def test_film_modulation_exports_quantises_every_conv_and_tiles_as_the_whole_frame(tmp_path):
    """``device_film`` (the descriptor scaling and shifting the stem's and the
    blocks' channels): it starts as the ``device`` network of the same weights
    (the modulation at the identity); with the modulation trained away from
    it, the descriptor changes the output through it alone, the export runs
    in the stage with tiles equal to the whole frame, and static INT8
    quantises every conv and stays near the float model."""
    import onnx

    from export.onnx_export import export_onnx
    from export.quantize import quantize_int8
    from modules.correction import Correction
    from restoration.nn.checkpoint import save_checkpoint
    from restoration.nn.network import build_model
    from tests.helpers import EXPORT_META, onnx_calibration_reader

    kw = {**TINY, "device": K}
    torch.manual_seed(0)
    film, plain = build_model("device_film", **kw).eval(), build_model("device", **kw).eval()
    missing = film.load_state_dict(plain.state_dict(), strict=False).missing_keys
    assert missing and all("film" in k for k in missing)
    x = torch.rand(1, 5 + K, 32, 48)
    with torch.no_grad():
        assert torch.equal(film(x), plain(x))
        for name, p in film.named_parameters():
            if "film" in name:
                p.normal_(0.0, 0.3)
        # the stem's bias and the attention read the descriptor too: take them out, FiLM still moves the output
        film.stem_field.weight[:, 3:] = 0.0
        other = torch.cat([x[:, :5], -x[:, 5:]], 1)
        assert (film(x) - film(other)).abs().max() > 1e-3
    meta = {**{k: v for k, v in EXPORT_META.items() if k != "attention"},
            "device_components": K, "device_design": DESIGN, "device_basis": BASIS}
    ckpt = save_checkpoint(tmp_path / "m.pt", film, variant="device_film", model_kwargs=kw, step=1, metadata=meta)
    report = export_onnx(ckpt, tmp_path / "film.onnx", tile_size=0, measure_overlap=False)
    # the modulation exports as two convs (restoration.nn.network.film): no conv's output is sliced
    # but the head's (its channels padded to HEAD_CHANNEL_MULTIPLE)
    graph = onnx.load(tmp_path / "film.onnx").graph
    convs = {o for n in graph.node if n.op_type == "Conv" and "head" not in n.name for o in n.output}
    assert not [n.name for n in graph.node if n.op_type in ("Slice", "Split") and n.input[0] in convs]
    q8 = tmp_path / "film.int8.onnx"
    r = quantize_int8(tmp_path / "film.onnx", q8, onnx_calibration_reader(device=K))
    assert r["int8_quantized_conv"] == r["fp32_conv"] and r["int8_float_conv"] == 0
    frame, dev, whole, tiled = _whole_and_tiled(tmp_path / "film.onnx", report, tmp_path)
    assert np.abs(whole.data - tiled.data).max() < 1e-5
    i8 = Correction(model=q8, device=dev, tile_size=0).process(frame)
    assert np.abs(i8.data - whole.data).mean() < 0.02

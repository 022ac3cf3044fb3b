"""The command line: process with --save-stages and --set, info, stages,
batch in parallel, demo, and a --help that teaches (kind: property)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from isp.cli.main import make_parser
from isp.pipeline import DEFAULT_STAGES

pytestmark = pytest.mark.property


def test_process_save_stages(cli, tmp_path, raw_file):
    stages = tmp_path / "stages"
    out = tmp_path / "o.jpg"
    code, stdout, stderr = cli("process", str(raw_file("SYNTHETIC_phone_S6meta_512x384.dng")),
                               "-o", str(out), "--save-stages", str(stages), "-v")
    assert code == 0, stderr
    names = sorted(p.name for p in stages.iterdir())
    assert "00_input.npy" in names and "00_input.png" in names
    for i, name in enumerate(DEFAULT_STAGES[:-1], start=1):
        assert f"{i:02d}_{name}.npy" in names and f"{i:02d}_{name}.png" in names
    assert f"{len(DEFAULT_STAGES):02d}_jpeg.jpg" in names
    def saved(name):
        return np.load(stages / f"{DEFAULT_STAGES.index(name) + 1:02d}_{name}.npy")

    assert saved("demosaic").shape == (384, 512, 3)
    assert saved("black_level").dtype == np.float32
    assert (stages / f"{len(DEFAULT_STAGES):02d}_jpeg.jpg").read_bytes() == out.read_bytes()
    assert "lens_shading" in stdout and "GainMap" in stdout


def test_process_set_overrides_and_png_output(cli, tmp_path, raw_file):
    cfg = tmp_path / "p.toml"
    cfg.write_text('[[stage]]\nname = "black_level"\n[[stage]]\nname = "white_balance"\n'
                   '[[stage]]\nname = "demosaic"\n[[stage]]\nname = "ccm"\n[[stage]]\nname = "gamma"\n')
    out = tmp_path / "o.png"
    code, stdout, stderr = cli("process", str(raw_file("tinydng_colorchart.dng")), "-o", str(out),
                               "--config", str(cfg), "--set", "white_balance.mode=grey_world",
                               "--set", "demosaic.method=bilinear", "--set", "png.bits=16", "-v")
    assert code == 0, stderr
    assert "grey world" in stdout and "bilinear" in stdout
    import cv2

    img = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint16 and img.shape == (1156, 1734, 3)
    code, _, stderr = cli("process", str(raw_file("tinydng_colorchart.dng")), "-o", str(out),
                          "--set", "sharpen.amount=1")
    assert code == 2 and "no stage 'sharpen'" in stderr


def test_info_json(cli, raw_file, tmp_path):
    code, stdout, _ = cli("info", str(raw_file("imageio_Blackmagic.dng")),
                          "--json", str(tmp_path / "i.json"))
    assert code == 0
    info = json.loads(stdout)
    assert info == json.loads((tmp_path / "i.json").read_text())
    assert info["cfa"] == "RGGB" and info["data"]["shape"] == [2160, 4096]
    assert info["baseline_exposure"] == pytest.approx(2.65412)
    assert info["calibration_illuminant_1_name"] == "Standard light A"
    assert info["calibration_illuminant_2_name"] == "D65"
    assert info["default_crop"] == [16, 8, 4096, 2160]
    assert info["applied_by_decoder"] == ["LinearizationTable"]
    code, stdout, _ = cli("info", str(raw_file("SYNTHETIC_phone_S6meta_512x384.dng")))
    info = json.loads(stdout)
    assert [p["action"] for p in info["opcode_plan"]] == ["lens_shading"] * 4
    assert info["opcodes"]["OpcodeList2"][0]["name"] == "GainMap"


def test_stages_lists_and_describes(cli):
    code, stdout, _ = cli("stages")
    assert code == 0
    for name in DEFAULT_STAGES:
        assert name in stdout
    code, stdout, _ = cli("stages", "demosaic")
    assert code == 0 and "method" in stdout and "malvar2004" in stdout
    code, _, stderr = cli("stages", "nope")
    assert code == 2 and "unknown stage 'nope'" in stderr


def test_batch_two_workers(cli, tmp_path, raw_file):
    src = tmp_path / "in"
    src.mkdir()
    for n in ("a", "b", "c"):
        shutil.copy(raw_file("SYNTHETIC_phone_S6meta_512x384.dng"), src / f"{n}.dng")
    code, stdout, _ = cli("batch", str(src), "-o", str(tmp_path / "out"), "--workers", "2")
    assert code == 0 and "processed 3 of 3" in stdout
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a.jpg", "b.jpg", "c.jpg"]


def test_demo_small(cli, tmp_path):
    code, stdout, stderr = cli("demo", "-o", str(tmp_path), "--width", "400", "--height", "300")
    assert code == 0, stderr
    for name in ("demo.dng", "demo.jpg", "demo_no_correction.jpg", "demo_before_after.png"):
        assert (tmp_path / name).exists(), name
    # the packaged model brings the lens-blurred capture closer to the blur-free one
    line = stdout.split("around the slanted squares: ")[1].splitlines()[0]
    for zone in line.split(", "):
        before, after = (float(v) for v in zone.split()[-4:-1:2])
        assert after > before, line
    de = float(stdout.split("mean ΔE00 ")[1].split(",")[0])
    de_nc = float(stdout.split("without the correction: mean ")[1].split(",")[0])
    ratio = float(stdout.split("background ")[1].split(" ")[0])
    assert de_nc < 1.0                   # the demo camera's colour is recovered
    assert de < 1.5                      # and the correction model leaves flat patches nearly alone
    assert abs(ratio - 1.0) < 0.03       # and its lens shading corrected


@pytest.mark.parametrize("command", ["process", "info", "stages", "batch", "demo", "profiles"])
def test_help_teaches_with_an_example(command):
    parser = make_parser(command)
    sub = parser._subparsers._group_actions[0].choices[command]
    text = sub.format_help()
    assert "example" in text and len(text) > 300


def test_process_never_imports_torch(tmp_path, raw_file):
    """`isp process` runs on numpy/OpenCV/onnxruntime only (torch is an extra)."""
    import subprocess
    import sys

    code = ("import sys; from isp.cli.main import main; "
            f"main(['process', {str(raw_file('SYNTHETIC_phone_S6meta_512x384.dng'))!r}, '-o', "
            f"{str(tmp_path / 'o.jpg')!r}]); print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "False"


# -- the shipped correction model ---------------------------------------------

def test_shipped_model_is_packaged_int8_and_small():
    """The default pipeline's correction stage runs the packaged model of the
    default phone lens: a file of the package, ≤ 5 MB, INT8 (every conv a
    quantised conv once loaded), exported for camera RGB after demosaic."""
    import onnx

    from modules.correction import MODELS_DIR, SHIPPED_MODELS, Correction

    path = MODELS_DIR / SHIPPED_MODELS["default"]
    assert path.is_file() and path.stat().st_size <= 5 * 2 ** 20
    st = Correction(model="default")
    assert st.model == path
    meta = st.model_meta
    assert meta["domain"] == "camera_rgb" and meta["precision"] == "int8"
    assert meta["lens"] == "US-12210142-B2-e9" and meta["fov_encoding"] == "xy"
    m = onnx.load(str(path))
    convs = [n for n in m.graph.node if n.op_type == "Conv"]
    # QDQ: every conv's weight comes through a DequantizeLinear of an int8 initializer
    producers = {o: n for n in m.graph.node for o in n.output}
    assert convs and all(producers[c.input[1]].op_type == "DequantizeLinear" for c in convs)


@pytest.mark.parametrize("level", [0.005, 0.05, 0.4, 0.9])
def test_shipped_model_keeps_flat_fields(level):
    """Physics: optical blur moves no light further than the PSF reaches, so
    its correction leaves a flat field's level alone. A network without the
    residual high-pass learns a tone curve: one darkened a flat 0.01 by
    7.6 % and brightened 0.7 by 6.3 % (``benchmarks/flat_fields.py``; the
    demo's ColorChecker moved 0.85 ΔE00). Grey and a saturated colour,
    centre of a 384 × 512 frame, each channel's mean within 1 %, or 0.0006
    in the darks: the packaged model quantises its residual in linear RGB
    (``highpass_domain="linear"``), in steps of 0.0011, and a noise-free
    flat field has no noise to dither the rounding (worst 0.0005 over
    ``benchmarks/flat_fields.py``'s 48 fields; noisy ones move ≤ 0.08 σ)."""
    from isp import CFA, CameraMeta, Domain, Frame
    from modules.correction import Correction

    h, w = 384, 512
    meta = CameraMeta(cfa=CFA.RGGB, raw_size=(h, w), active_area=(0, 0, h, w))
    st = Correction(model="default")
    for colour in ((1.0, 1.0, 1.0), (1.0, 0.3, 0.2)):
        img = np.full((h, w, 3), level, np.float32) * np.asarray(colour, np.float32)
        out = st.process(Frame(img, Domain.CAMERA_RGB, meta)).data
        got = out[h // 2 - 40:h // 2 + 40, w // 2 - 40:w // 2 + 40].reshape(-1, 3).mean(0)
        assert np.all(np.abs(got - img[0, 0]) < np.maximum(0.01 * img[0, 0], 0.0006)), (colour, got / img[0, 0])


def test_shipped_model_keeps_the_means_of_noise_and_texture():
    """Physics: the means an optical correction keeps are linear. A model
    that filters its residual in the √x domain, whose encoding clips
    negatives, does not: a noisy black (mean 0, σ 0.002) came out 0.40 σ
    bright, and a fine texture around grey 0.3 0.46 % bright
    (``benchmarks/flat_fields.py``). Within 0.1 σ and 0.2 %."""
    from benchmarks.flat_fields import noisy_field_changes, texture_mean_change

    noisy = noisy_field_changes("default", levels=(0.0, 0.005), size=(192, 256))
    assert noisy["worst_sigma"] < 0.1, noisy
    texture = texture_mean_change("default", size=(192, 256))
    assert texture["worst_percent"] < 0.2, texture


def test_process_forced_model_corrects_and_no_correction_turns_it_off(cli, tmp_path, raw_file):
    """The S6-metadata capture names no lens a profile matches (tests/isp/cli/
    test_profiles.py), so the packaged model is forced here."""
    dng = str(raw_file("SYNTHETIC_phone_S6meta_512x384.dng"))
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    cfg = tmp_path / "to_display.toml"  # stop before JPEG so the outputs compare exactly
    cfg.write_text("".join(f'[[stage]]\nname = "{n}"\n' for n in DEFAULT_STAGES[:-1]))
    code, out_on, err = cli("process", dng, "-o", str(a), "--config", str(cfg), "-v", "--correction", "default")
    assert code == 0, err
    code, out_off, err = cli("process", dng, "-o", str(b), "--config", str(cfg), "-v",
                             "--no-correction")
    assert code == 0, err
    assert "e9_default.int8.onnx" in out_on and "identity (no model)" in out_off
    import cv2

    on, off = cv2.imread(str(a)), cv2.imread(str(b))
    diff = np.abs(on.astype(int) - off.astype(int))
    assert on.shape == off.shape and diff.mean() > 0.05  # the model changed the frame...
    # ... locally (it sharpens; noise with it) and kept its exposure and colour (±3 DN of ~100)
    assert np.median(diff) <= 8
    assert np.all(np.abs(on.astype(float).mean((0, 1)) - off.astype(float).mean((0, 1))) < 3.0)


def test_info_names_the_correction_model(cli, raw_file):
    dng = str(raw_file("SYNTHETIC_phone_S6meta_512x384.dng"))
    code, stdout, err = cli("info", dng, "--correction", "default")
    assert code == 0, err
    c = json.loads(stdout)["correction"]
    assert c["model"] == "e9_default.int8.onnx" and c["source"] == "packaged default"
    assert c["lens"] == "US-12210142-B2-e9" and c["size_kb"] <= 5 * 1024
    code, stdout, err = cli("info", dng, "--no-correction")
    assert json.loads(stdout)["correction"]["model"] is None

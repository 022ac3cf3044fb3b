"""The command line: process with --save-stages and --set, info, stages,
batch in parallel, demo, and a --help that teaches (kind: property)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from isp.cli import main, make_parser
from isp.pipeline import DEFAULT_STAGES


def _run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_process_save_stages(capsys, tmp_path, raw_file):
    stages = tmp_path / "stages"
    out = tmp_path / "o.jpg"
    code, stdout, stderr = _run(capsys, "process", str(raw_file("SYNTHETIC_phone_S6meta_512x384.dng")),
                                "-o", str(out), "--save-stages", str(stages), "-v")
    assert code == 0, stderr
    names = sorted(p.name for p in stages.iterdir())
    assert "00_input.npy" in names and "00_input.png" in names
    for i, name in enumerate(DEFAULT_STAGES[:-1], start=1):
        assert f"{i:02d}_{name}.npy" in names and f"{i:02d}_{name}.png" in names
    assert f"{len(DEFAULT_STAGES):02d}_jpeg.jpg" in names
    assert np.load(stages / "04_demosaic.npy").shape == (384, 512, 3)
    assert np.load(stages / "01_black_level.npy").dtype == np.float32
    assert (stages / f"{len(DEFAULT_STAGES):02d}_jpeg.jpg").read_bytes() == out.read_bytes()
    assert "lens_shading" in stdout and "GainMap" in stdout


def test_process_set_overrides_and_png_output(capsys, tmp_path, raw_file):
    cfg = tmp_path / "p.toml"
    cfg.write_text('[[stage]]\nname = "black_level"\n[[stage]]\nname = "white_balance"\n'
                   '[[stage]]\nname = "demosaic"\n[[stage]]\nname = "ccm"\n[[stage]]\nname = "gamma"\n')
    out = tmp_path / "o.png"
    code, stdout, stderr = _run(capsys, "process", str(raw_file("tinydng_colorchart.dng")), "-o", str(out),
                                "--config", str(cfg), "--set", "white_balance.mode=grey_world",
                                "--set", "demosaic.method=bilinear", "-v")
    assert code == 0, stderr
    assert "grey world" in stdout and "bilinear" in stdout
    import cv2

    img = cv2.imread(str(out), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint16 and img.shape == (1156, 1734, 3)
    code, _, stderr = _run(capsys, "process", str(raw_file("tinydng_colorchart.dng")), "-o", str(out),
                           "--set", "sharpen.amount=1")
    assert code == 2 and "no stage 'sharpen'" in stderr


def test_info_json(capsys, raw_file, tmp_path):
    code, stdout, _ = _run(capsys, "info", str(raw_file("imageio_Blackmagic.dng")),
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
    code, stdout, _ = _run(capsys, "info", str(raw_file("SYNTHETIC_phone_S6meta_512x384.dng")))
    info = json.loads(stdout)
    assert [p["action"] for p in info["opcode_plan"]] == ["lens_shading"] * 4
    assert info["opcodes"]["OpcodeList2"][0]["name"] == "GainMap"


def test_stages_lists_and_describes(capsys):
    code, stdout, _ = _run(capsys, "stages")
    assert code == 0
    for name in DEFAULT_STAGES:
        assert name in stdout
    code, stdout, _ = _run(capsys, "stages", "demosaic")
    assert code == 0 and "method" in stdout and "malvar2004" in stdout
    code, _, stderr = _run(capsys, "stages", "nope")
    assert code == 2 and "unknown stage 'nope'" in stderr


def test_batch_two_workers(capsys, tmp_path, raw_file):
    src = tmp_path / "in"
    src.mkdir()
    for n in ("a", "b", "c"):
        shutil.copy(raw_file("SYNTHETIC_phone_S6meta_512x384.dng"), src / f"{n}.dng")
    code, stdout, _ = _run(capsys, "batch", str(src), "-o", str(tmp_path / "out"), "--workers", "2")
    assert code == 0 and "processed 3 of 3" in stdout
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a.jpg", "b.jpg", "c.jpg"]


def test_demo_small(capsys, tmp_path):
    code, stdout, stderr = _run(capsys, "demo", "-o", str(tmp_path), "--width", "400", "--height", "300")
    assert code == 0, stderr
    assert (tmp_path / "demo.dng").exists() and (tmp_path / "demo.jpg").exists()
    de = float(stdout.split("mean ΔE00 ")[1].split(",")[0])
    ratio = float(stdout.split("background ")[1].split(" ")[0])
    assert de < 1.0                      # the demo camera's colour is recovered
    assert abs(ratio - 1.0) < 0.03       # and its lens shading corrected


@pytest.mark.parametrize("command", ["process", "info", "stages", "batch", "demo"])
def test_help_teaches_with_an_example(command):
    parser = make_parser()
    sub = parser._subparsers._group_actions[0].choices[command]
    text = sub.format_help()
    assert "example" in text and len(text) > 300


def test_process_never_imports_torch(tmp_path, raw_file):
    """`isp process` runs on numpy/OpenCV/onnxruntime only (torch is an extra)."""
    import subprocess
    import sys

    code = ("import sys; from isp.cli import main; "
            f"main(['process', {str(raw_file('SYNTHETIC_phone_S6meta_512x384.dng'))!r}, '-o', "
            f"{str(tmp_path / 'o.jpg')!r}]); print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "False"

"""Bad input: one line naming the file and the reason, exit code 2, no
traceback, no partial output (kind: property). Files that can be processed
correctly are (KDC, headerless dump with geometry, the 0/0 BaselineExposure
DNG)."""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest

pytestmark = pytest.mark.property


def _assert_refused(cli, tmp_path, src, reason):
    out = tmp_path / "out.jpg"
    code, stdout, stderr = cli("process", str(src), "-o", str(out))
    assert code == 2
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert str(src) in lines[0] and reason in lines[0]
    assert "Traceback" not in stderr
    assert not out.exists() and list(tmp_path.glob("*.jpg*")) == []


def test_nef_returned_as_rgb_is_refused(cli, tmp_path, raw_file):
    _assert_refused(cli, tmp_path, raw_file("imageio_Nikon_uncompressed.nef"), "not a Bayer mosaic")


def test_headerless_raw_refused_without_geometry(cli, tmp_path, raw_file):
    _assert_refused(cli, tmp_path, raw_file("fastopenisp_test.RAW"), "--width")


def test_headerless_raw_processed_with_geometry(cli, tmp_path, raw_file):
    out = tmp_path / "dump.jpg"
    code, stdout, stderr = cli("process", str(raw_file("fastopenisp_test.RAW")), "-o", str(out),
                               "--width", "1920", "--height", "1080", "--bits", "10", "--pattern", "RGGB")
    assert code == 0, stderr
    assert out.stat().st_size > 10_000


def test_headerless_wrong_size_is_refused(cli, tmp_path, raw_file):
    src = raw_file("fastopenisp_test.RAW")
    code, _, stderr = cli("process", str(src), "-o", str(tmp_path / "x.jpg"),
                          "--width", "1000", "--height", "1000", "--bits", "10", "--pattern", "RGGB")
    assert code == 2 and "needs 2000000 bytes" in stderr and str(src) in stderr


def test_mat_file_is_refused(cli, tmp_path, raw_file):
    _assert_refused(cli, tmp_path, raw_file("sidd_0001_METADATA_RAW_010.MAT"), "MATLAB")


def test_empty_file_is_refused(cli, tmp_path):
    src = tmp_path / "empty.dng"
    src.write_bytes(b"")
    _assert_refused(cli, tmp_path, src, "empty file")


def test_text_file_named_dng_is_refused(cli, tmp_path):
    src = tmp_path / "notes.dng"
    src.write_text("this is not a DNG\n")
    _assert_refused(cli, tmp_path, src, "no TIFF header")


def test_truncated_dng_is_refused(cli, tmp_path, raw_file):
    data = raw_file("SYNTHETIC_phone_S6meta_512x384.dng").read_bytes()
    src = tmp_path / "truncated.dng"
    src.write_bytes(data[: len(data) * 2 // 3])
    _assert_refused(cli, tmp_path, src, "truncated")


def test_missing_file_is_refused(cli, tmp_path):
    _assert_refused(cli, tmp_path, tmp_path / "nope.dng", "no such file")


def test_kdc_is_processed(cli, tmp_path, raw_file):
    out = tmp_path / "kdc.jpg"
    code, _, stderr = cli("process", str(raw_file("rawpy_RAW_KODAK_DC50.KDC")), "-o", str(out))
    assert code == 0, stderr and out.exists()


def test_nan_baseline_exposure_dng_is_processed(cli, tmp_path, raw_file):
    """tinydng stores BaselineExposure as 0/0: treated as absent (0 EV), noted,
    processed normally."""
    out = tmp_path / "tiny.jpg"
    code, stdout, stderr = cli("process", str(raw_file("tinydng_colorchart.dng")), "-o", str(out), "-v")
    assert code == 0, stderr
    assert "+0.00 EV" in stdout and "0/0" in stdout
    assert out.exists()


def test_bad_config_is_a_one_line_error(cli, tmp_path, raw_file):
    cfg = tmp_path / "p.toml"
    cfg.write_text('[[stage]]\nname = "black_level"\n[[stage]]\nname = "gamma"\n')
    code, _, stderr = cli("process", str(raw_file("tinydng_colorchart.dng")), "-o",
                          str(tmp_path / "o.jpg"), "--config", str(cfg))
    assert code == 2 and str(cfg) in stderr and "'gamma'" in stderr
    assert len(stderr.strip().splitlines()) == 1


def test_exit_code_and_stderr_from_a_real_process(tmp_path):
    src = tmp_path / "bad.dng"
    src.write_text("nope")
    out = subprocess.run([sys.executable, "-m", "isp", "process", str(src), "-o", str(tmp_path / "o.jpg")],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and "Traceback" not in out.stderr


def test_batch_continues_past_bad_files(cli, tmp_path, raw_file):
    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(raw_file("SYNTHETIC_phone_S6meta_512x384.dng"), src / "good.dng")
    (src / "empty.dng").write_bytes(b"")
    (src / "text.dng").write_text("hello")
    (src / "readme.txt").write_text("not a raw, not even tried")
    code, stdout, stderr = cli("batch", str(src), "-o", str(tmp_path / "out"), "--workers", "1")
    assert code == 1
    assert "processed 1 of 3" in stdout and "2 failed" in stdout
    assert "empty.dng: empty file" in stdout and "text.dng: not a DNG" in stdout
    assert (tmp_path / "out" / "good.jpg").exists()
    assert not (tmp_path / "out" / "empty.jpg").exists()

"""``isp batch``: the summary lists every file not processed with the reason
(a failure, or an entry not taken), the exit code says whether any failed,
and ``--format`` chooses the encoder (kind: property)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

pytestmark = pytest.mark.property


def _folder(tmp_path, raw_file, *, gpr=True):
    src = tmp_path / "in"
    src.mkdir()
    shutil.copy(raw_file("SYNTHETIC_phone_S6meta_512x384.dng"), src / "good.dng")
    if gpr:
        (src / "clip.GPR").symlink_to(raw_file("gopro_HERO6_GOPR0024_vc5.GPR"))
    (src / "notes.txt").write_text("not a raw file")
    (src / "sub").mkdir()
    return src


def test_summary_lists_failed_and_not_taken(cli, tmp_path, raw_file):
    src = _folder(tmp_path, raw_file)
    out = tmp_path / "out"
    code, stdout, stderr = cli("batch", src, "-o", out, "--workers", "1")
    assert code == 1, stderr
    lines = stdout.splitlines()
    assert f"processed 1 of 2 file(s) into {out}" in lines
    assert "1 failed:" in lines and "2 not taken:" in lines
    failed = lines[lines.index("1 failed:") + 1]
    assert failed.startswith(f"  {src / 'clip.GPR'}: VC-5 (GoPro) compression (Compression = 9) is not "
                             "supported by LibRaw")
    not_taken = lines[lines.index("2 not taken:") + 1:]
    assert not_taken == [f"  {src / 'notes.txt'}: not a raw file by its name (extension '.txt')",
                         f"  {src / 'sub'}: a folder (isp batch does not descend into folders)"]
    assert sorted(p.name for p in out.iterdir()) == ["good.jpg"]


def test_nothing_failed_is_exit_0_and_still_lists_what_was_not_taken(cli, tmp_path, raw_file):
    src = _folder(tmp_path, raw_file, gpr=False)
    code, stdout, _ = cli("batch", src, "-o", tmp_path / "out", "--workers", "1")
    assert code == 0
    assert "processed 1 of 1 file(s)" in stdout and " failed:" not in stdout
    assert "2 not taken:" in stdout and "notes.txt" in stdout


def test_no_raw_files_names_what_is_there(cli, tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    (src / "a.txt").write_text("x")
    code, _, stderr = cli("batch", src, "-o", tmp_path / "out")
    assert code == 2 and "no raw files" in stderr and "a.txt" in stderr
    assert len(stderr.strip().splitlines()) == 1


def test_format_chooses_the_encoder(cli, tmp_path, raw_file):
    import cv2

    src = _folder(tmp_path, raw_file, gpr=False)
    out = tmp_path / "out"
    code, _, stderr = cli("batch", src, "-o", out, "--workers", "1", "--format", "png", "--set", "png.bits=16")
    assert code == 0, stderr
    img = cv2.imread(str(out / "good.png"), cv2.IMREAD_UNCHANGED)
    assert img.dtype == np.uint16 and img.shape == (384, 512, 3)
    code, _, stderr = cli("batch", src, "-o", tmp_path / "out2", "--format", ".bmp")
    assert code == 2 and "unknown output format" in stderr and ".png (PNG)" in stderr
    assert not (tmp_path / "out2").exists()

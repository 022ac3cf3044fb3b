"""``--look`` of ``isp process`` and ``isp batch`` (kind: property): the
look names the stages that run, a pipeline file and a look together are
refused with one line, an unknown look is argparse's usage error."""

from __future__ import annotations

import pytest

from isp.pipeline import LOOKS

pytestmark = pytest.mark.property


def test_process_look_chooses_the_stages(cli, tmp_path, raw_file):
    dng = raw_file("skia_sample_1mp.dng")
    runs = {}
    for look in ("adobe", "linear"):
        out = tmp_path / f"{look}.png"
        code, stdout, stderr = cli("process", dng, "-o", out, "--look", look, "-v")
        assert code == 0, stderr
        ran = [line.split()[0] for line in stdout.splitlines() if line.startswith("  ") and " ms " in line]
        assert ran == [n for n in LOOKS[look] if n != "jpeg"] + ["png"]
        runs[look] = out.read_bytes()
    code, stdout, stderr = cli("process", dng, "-o", tmp_path / "default.png")
    assert code == 0, stderr
    assert (tmp_path / "default.png").read_bytes() == runs["adobe"] != runs["linear"]


def test_look_and_a_pipeline_file_are_refused_together(cli, tmp_path, raw_file):
    cfg = tmp_path / "p.toml"
    cfg.write_text('[[stage]]\nname = "black_level"\n')
    code, _, stderr = cli("process", raw_file("skia_sample_1mp.dng"), "-o", tmp_path / "o.jpg",
                          "--config", cfg, "--look", "linear")
    assert code == 2 and "give either a look or a pipeline file" in stderr
    assert len(stderr.strip().splitlines()) == 1 and not (tmp_path / "o.jpg").exists()


def test_unknown_look_is_a_usage_error(cli, tmp_path, raw_file):
    with pytest.raises(SystemExit) as e:
        cli("process", raw_file("skia_sample_1mp.dng"), "-o", tmp_path / "o.jpg", "--look", "film")
    assert e.value.code == 2


def test_batch_takes_a_look(cli, tmp_path, raw_file):
    src = tmp_path / "in"
    src.mkdir()
    (src / "a.dng").write_bytes(raw_file("skia_sample_1mp.dng").read_bytes())
    code, _, stderr = cli("batch", src, "-o", tmp_path / "out", "--look", "linear", "--workers", "1")
    assert code == 0, stderr
    assert (tmp_path / "out" / "a.jpg").exists()

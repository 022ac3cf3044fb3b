"""The `isp train` command (restoration/cli/train.py): errors are one line
and exit 2; ``--lens`` trains for one device and ``--pixel-um`` sets the
pairs' pitch.

Kind: property.
"""

from __future__ import annotations

import pytest
from tests.helpers import ROOT, write_toml

pytestmark = pytest.mark.property

torch = pytest.importorskip("torch")

from isp.cli.main import main


def test_cli_errors_are_one_line_exit_2(tmp_path, capsys, pairs):
    bad = write_toml(tmp_path / "bad.toml", {"data": {"dirs": [str(pairs)]}, "optim": {"lrate": 1.0}})
    nodata = write_toml(tmp_path / "nodata.toml", {"data": {"dirs": [str(tmp_path / "none")]},
                                                   "run": {"out": str(tmp_path / "o")}})
    for argv, msg in ((["--config", str(tmp_path / "missing.toml")], "no such config file"),
                      (["--config", str(bad)], "unknown key(s) 'lrate'"),
                      (["--config", str(nodata)], "no manifest"),
                      ([], "give --config")):
        assert main(["train", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("isp: error:") and msg in err and "\n" not in err


def test_isp_train_lens_trains_for_one_device(tmp_path, monkeypatch, capsys):
    """`--lens PROXY`: the pairs from that lens alone, into OUT/pairs; the
    rest as the config says. A missing file is one line, exit 2.
    `--pixel-um`: the pairs' pixel pitch."""
    from pathlib import Path

    import restoration.train.trainer as tr
    from restoration.train.config import load_config

    seen = {}
    monkeypatch.setattr(tr, "train", lambda config, **kw: seen.setdefault("config", config))
    proxy = tmp_path / "proxy.json"
    proxy.write_text("{}")
    cfg = ROOT / "configs" / "e9_default.toml"
    argv = ["train", "--config", str(cfg), "--out", str(tmp_path / "dev"), "-q", "--lens"]
    assert main(argv + [str(proxy)]) == 0
    c, base = seen["config"], load_config(cfg)
    assert c.synth.samples == 1 and Path(c.synth.lens) == proxy.resolve()
    assert Path(c.synth.out) == tmp_path / "dev" / "pairs" and c.data_dirs() == [c.synth.out]
    assert c.model == base.model and c.optim == base.optim and c.synth.pairs == base.synth.pairs
    assert main(argv + [str(tmp_path / "nope.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert "nope.json" in err and "\n" not in err
    # --pixel-um: the pairs' pitch, passed on to isp synth and checked against an existing set
    seen.clear()
    assert main(argv + [str(proxy), "--pixel-um", "1"]) == 0
    c = seen["config"]
    assert c.synth.pixel_um == 1.0 and tr.synth_argv(c)[-2:] == ["--pixel-um", "1.0"]
    assert "--pixel-um" not in tr.synth_argv(base)
    assert tr._synth_mismatch({"psf_map": {"sensor": {"pixel_pitch_um": 2.807}}}, c)[-1] == "pixel_um 2.807 ≠ 1.0"
    assert main(argv + [str(proxy), "--pixel-um", "0.01"]) == 2
    assert "pixel_um" in capsys.readouterr().err

"""The `isp export` command (export/cli.py): bad input is one line and
exit 2. Property test."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnxruntime.quantization")

from isp.errors import InputError

pytestmark = [pytest.mark.property, pytest.mark.filterwarnings("ignore:Please consider to run pre-processing"),
              pytest.mark.filterwarnings("ignore::DeprecationWarning")]


def test_bad_input_is_one_line_exit_2(tmp_path, capsys):
    from isp.cli.main import main

    assert main(["export", str(tmp_path / "none.pt"), "-o", str(tmp_path / "m.onnx")]) == 2
    assert "no such checkpoint" in capsys.readouterr().err
    assert main(["export", "x.pt", "-o", str(tmp_path / "m.onnx"), "--int8"]) == 2
    assert "--calib-data" in capsys.readouterr().err
    with pytest.raises(InputError, match="manifest"):
        from export.quantize import SynthCalibration

        SynthCalibration(tmp_path, 4)

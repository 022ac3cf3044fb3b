"""The production line's workflow end to end through the command line
(kind: property; slow: a 2000 × 1500 chart capture is simulated and fitted).

``isp calib simulate --perturb random`` (a module) → ``isp calib basis``
(once per design; here a small one) → ``isp calib fit --basis`` (the
module's ``device.json``) → ``isp process capture.dng --correction MODEL
--device device.json``, with a tiny network conditioned on the device whose
export names that design and basis; then the same capture carrying its
calibration (``isp calib simulate --device``) corrects alike without
``--device``. No training anywhere.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from isp.cli.main import main

pytestmark = [pytest.mark.property, pytest.mark.slow]

torch = pytest.importorskip("torch")


def test_chart_capture_to_corrected_output(tmp_path, e9_zmx, capsys):
    from export.onnx_export import export_onnx
    from isp.io.device import DeviceCalibration
    from restoration.nn.checkpoint import save_checkpoint
    from restoration.nn.network import build_model
    from tests.helpers import EXPORT_META, TINY_UNET_KW

    cap = tmp_path / "module.dng"
    assert main(["calib", "simulate", str(e9_zmx), "-o", str(cap), "--size", "2000,1500", "--perturb", "random",
                 "--seed", "3"]) == 0
    basis = tmp_path / "e9_basis.npz"
    assert main(["calib", "basis", str(e9_zmx), "-o", str(basis), "--draws", "5", "--grid", "2", "3",
                 "--components", "4", "--workers", "2"]) == 0
    fit = tmp_path / "module"
    assert main(["calib", "fit", "--lens", str(e9_zmx), "--measured", str(cap), "--basis", str(basis),
                 "--components", "4", "--n-params", "4", "--max-iter", "3", "--restarts", "0", "-o", str(fit)]) == 0
    cal = DeviceCalibration.load(fit / "device.json")
    assert cal.lens == e9_zmx.stem and cal.grid == (2, 3) and cal.components == 4
    capsys.readouterr()

    kw = {**TINY_UNET_KW, "device": 4}
    meta = {**EXPORT_META, "lens": e9_zmx.stem, "device_components": 4, "device_design": cal.design,
            "device_basis": cal.basis}
    ckpt = save_checkpoint(tmp_path / "m.pt", build_model("device", **kw), variant="device", model_kwargs=kw,
                           step=1, metadata=meta)
    model = tmp_path / "device.onnx"
    export_onnx(ckpt, model, tile_size=1024, measure_overlap=False)
    out = tmp_path / "out.tif"
    assert main(["process", str(cap), "-o", str(out), "--correction", str(model), "--device",
                 str(fit / "device.json"), "--look", "linear", "--set", "tiff.bits=32", "-v"]) == 0
    printed = capsys.readouterr()
    assert "device device.json" in printed.out + printed.err and out.is_file()

    carrying = tmp_path / "carrying.dng"
    assert main(["calib", "simulate", str(e9_zmx), "-o", str(carrying), "--size", "2000,1500", "--perturb",
                 "random", "--seed", "3", "--device", str(fit / "device.json")]) == 0
    out2 = tmp_path / "out2.tif"
    assert main(["process", str(carrying), "-o", str(out2), "--correction", str(model), "--look", "linear",
                 "--set", "tiff.bits=32", "-v"]) == 0
    printed = capsys.readouterr()
    assert "DNGPrivateData" in printed.out + printed.err
    import tifffile

    assert np.array_equal(tifffile.imread(out), tifffile.imread(out2))
    fit_json = json.loads((fit / "fit.json").read_text())
    assert fit_json["errors"]["after"]["sfra_rms"] < fit_json["errors"]["before"]["sfra_rms"]

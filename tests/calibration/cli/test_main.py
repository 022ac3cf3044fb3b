"""`isp calib`: lens reports, spots, PSFs, simulated captures and SFR from
the command line (kind: property; figures checked against the lens README
and the SFR reference JSONs)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.helpers import data_file
from isp.cli.main import main


@pytest.mark.property
def test_calib_help_is_reachable(capsys):
    with pytest.raises(SystemExit) as e:
        main(["calib", "--help"])
    assert e.value.code == 0
    assert "isp calib sfr" in capsys.readouterr().out


@pytest.mark.property
def test_lens_report_and_conversion(cli, tmp_path, e9_zmx):
    zmx = e9_zmx
    out = tmp_path / "e9.json"
    code, stdout, stderr = cli("calib", "lens", str(zmx), "--save", str(out), "--json")
    assert code == 0, stderr
    rep = json.loads(stdout[stdout.index("{"):])
    assert rep["efl_mm"] == pytest.approx(4.6704, rel=1e-3)        # lenses/README.md
    assert rep["f_number"] == pytest.approx(1.95, rel=1e-3)
    assert [f["field"] for f in rep["fields"]] == [0.0, 0.5, 0.7, 1.0]
    assert rep["fields"][2]["transmitted"] == pytest.approx(0.77, abs=0.02)
    # the converted file reads back to the same lens
    code, stdout2, _ = cli("calib", "lens", str(out), "--json")
    assert json.loads(stdout2)["efl_mm"] == pytest.approx(rep["efl_mm"], rel=1e-12)


@pytest.mark.property
def test_bad_lens_file_is_one_line(cli, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"schema": "lens/v1", "surfaces": [{"curvature": "x"}]}')
    code, _, stderr = cli("calib", "lens", str(bad))
    assert code == 2 and "bad.json" in stderr and len(stderr.strip().splitlines()) == 1


@pytest.mark.property
def test_spot_and_psf_plots(cli, tmp_path, e9_zmx):
    zmx = e9_zmx
    code, stdout, stderr = cli("calib", "spot", str(zmx), "--fields", "0,1", "--rays", "2000",
                               "--plot", str(tmp_path / "s.png"))
    assert code == 0, stderr and (tmp_path / "s.png").stat().st_size > 1000
    code, stdout, stderr = cli("calib", "psf", str(zmx), "--field", "0,20", "--n", "32",
                               "--pupil-samples", "32", "--plot", str(tmp_path / "p.png"))
    assert code == 0, stderr
    assert "centroid" in stdout and (tmp_path / "p.png").stat().st_size > 1000


@pytest.mark.published
def test_sfr_roi_matches_the_reference_tool(cli, tmp_path):
    img = data_file("edges", "sfrmat3_v_edge_mono.tif")
    ref = json.loads(data_file("edges", "reference", "sfrmat3_v_edge_mono.json").read_text())
    out = tmp_path / "v.json"
    code, stdout, stderr = cli("calib", "sfr", str(img), "--json", str(out), "--plot",
                               str(tmp_path / "v.png"))
    assert code == 0, stderr
    edge = json.loads(out.read_text())["edges"][0]
    assert set(edge) >= {"freq", "sfr", "mtf50", "sfra", "angle_deg", "roi", "field", "orientation", "warnings"}
    assert edge["mtf50"] == pytest.approx(ref["sfrmat5"]["mtf50"], rel=0.02)


@pytest.mark.property
def test_sfr_chart_mode(cli, tmp_path):
    img = data_file("edges", "sfrmat3_ISO_DSC_300a.jpg")
    out = tmp_path / "c.json"
    code, stdout, stderr = cli("calib", "sfr", str(img), "--chart", "--encoding", "srgb",
                               "--json", str(out))
    assert code == 0, stderr
    res = json.loads(out.read_text())
    assert len(res["edges"]) == 4          # the tilted dark square's four sides
    assert len(res["maps"]["sfra"]["all"]) == 15 and len(res["maps"]["sfra"]["all"][0]) == 20
    for e in res["edges"]:
        assert 0.2 < e["mtf50"] < 0.5 and 2 < abs(e["angle_deg"]) < 12


@pytest.mark.property
def test_sfr_bad_roi_is_one_line(cli, tmp_path):
    img = data_file("edges", "sfrmat3_v_edge_mono.tif")
    code, _, stderr = cli("calib", "sfr", str(img), "--roi", "5000,0,40,40")
    assert code == 2 and "outside" in stderr and len(stderr.strip().splitlines()) == 1


@pytest.mark.property
@pytest.mark.slow
def test_simulate_writes_a_capture_the_isp_reads(cli, tmp_path, e9_zmx):
    zmx = e9_zmx
    dng = tmp_path / "sim.dng"
    code, stdout, stderr = cli("calib", "simulate", str(zmx), "-o", str(dng), "--size", "640,480",
                               "--cache", str(tmp_path / "cache"))
    assert code == 0, stderr
    from isp.io.read import read_raw

    f = read_raw(dng)
    assert f.shape == (480, 640) and len(f.meta.opcodes[2]) == 4
    assert np.isfinite(f.data).all()
    code, _, stderr = cli("process", str(dng), "-o", str(tmp_path / "sim.jpg"))
    assert code == 0, stderr


@pytest.mark.property
@pytest.mark.slow
def test_simulate_saves_the_devices_true_lens(cli, tmp_path, e9_zmx):
    """`--save-lens`: the prescription (its own sensor, not the capture's
    --size) with exactly the device's drawn and refocused perturbation."""
    from calibration.fit.proxy import load_proxy
    from calibration.optics.io import read_lens
    from calibration.simulate.device import device_lens

    zmx = e9_zmx
    saved = tmp_path / "dev3.json"
    code, stdout, stderr = cli("calib", "simulate", str(zmx), "-o", str(tmp_path / "dev3.dng"),
                               "--size", "640,480", "--perturb", "random", "--seed", "3",
                               "--save-lens", str(saved), "--cache", str(tmp_path / "cache"))
    assert code == 0, stderr
    assert "true lens" in stdout
    lens = read_lens(str(zmx))
    device, _ = device_lens(lens, "random", seed=3)
    back = load_proxy(saved)
    want, got = device.perturbation.as_dict(), back.perturbation.as_dict()
    assert set(got) == set(want) and any(abs(v) > 0 for v in want.values())
    assert all(got[k] == pytest.approx(v, rel=1e-12, abs=1e-15) for k, v in want.items())
    assert back.nominal.sensor == lens.sensor and lens.sensor.width_px != 640


@pytest.mark.property
def test_sfr_chart_on_a_raw_capture(cli, tmp_path):
    """The demo capture (a DNG from the project's writer) has six slanted dark
    squares: chart mode on the raw mosaic finds their sides and measures the
    green channel per CFA plane."""
    from calibration.demo import make_capture
    from isp.io.dng_write import write_dng

    dn, meta, _ = make_capture(600, 800, seed=1, optics="gaussian")
    dng = write_dng(tmp_path / "demo.dng", dn, meta)
    out = tmp_path / "c.json"
    code, stdout, stderr = cli("calib", "sfr", str(dng), "--chart", "--channel", "G", "--json", str(out))
    assert code == 0, stderr
    res = json.loads(out.read_text())
    assert res["kind"] == "raw" and len(res["edges"]) >= 16
    # the demo blurs with a Gaussian of 0.7 px: MTF50 well below Nyquist, far above a blur of 2 px
    assert all(0.15 < e["mtf50"] < 0.5 for e in res["edges"])


@pytest.mark.property
def test_simulate_refuses_a_bad_sensor_tilt(cli, tmp_path, e9_zmx):
    dng = tmp_path / "t.dng"
    code, _, stderr = cli("calib", "simulate", str(e9_zmx), "-o", str(dng), "--sensor-tilt", "0.2")
    assert code == 2 and "expected 2 numbers" in stderr and len(stderr.strip().splitlines()) == 1
    assert not dng.exists()

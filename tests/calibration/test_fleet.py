"""calibration/fleet.py and ``isp calib fleet``: a small production line of
e9 modules, each measured on a coarse grid, calibrated on the local pool
and on a local Ray instance.

Kind: property. References: the nominal design (a module that is the
design measures as sharp as the design predicts, ring by ring), a module
perturbed far past its tolerances (softer, and flagged), the pool's
device files (Ray's are the same but for the timing), and the capture
files' hashes (a finished device is kept on a second run).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from isp.runtime.executor import create_executor

pytestmark = pytest.mark.property

#: the modules' perturbations, tolerance units: far past the tolerances, the design itself, within
NAMES = ["e1.decenter_x", "e1.decenter_y", "s17.thickness"]
MODULES = {"module_a": [4.0, 4.0, 3.0], "module_b": [0.0, 0.0, 0.0], "module_c": [-0.5, 0.3, 0.5]}
SETTINGS = dict(n_params=6, max_iter=4, restarts=0, coarse=None, fine_iter=None, components=3,
                effects=("sharpening",), max_effects=1, folds=2, loop_iter=2, min_sfra_ratio=0.6)


@pytest.fixture(scope="module")
def line(tmp_path_factory, make_e9_device, e9_zmx, e9_lens):
    """Three modules' measurements (sfr-observations/v1 files), a bad
    capture, and the design's basis (4 draws on a 2 × 3 grid)."""
    from calibration.fit.device import learn_basis

    tmp = tmp_path_factory.mktemp("fleet")
    caps = tmp / "captures"
    caps.mkdir()
    for i, (name, u) in enumerate(MODULES.items()):
        _, obs = make_e9_device(NAMES, u, grid=(3, 4), noise=0.003, rng=10 + i)
        obs.save(caps / f"{name}.json")
    (caps / "module_x.dng").write_bytes(b"not a capture")
    (caps / "readme.txt").write_text("notes")
    basis = learn_basis(e9_lens, draws=4, grid=(2, 3), components=3, executor=create_executor("processes", 2),
                        name=e9_zmx.stem).save(tmp / "basis.npz")
    return tmp, caps, basis


@pytest.fixture(scope="module")
def pool_fleet(line, e9_zmx):
    """The line calibrated on a 2-process pool: (report, devices folder)."""
    from calibration.fleet import FleetSettings, run_fleet

    tmp, caps, basis = line
    out = tmp / "devices_pool"
    with create_executor("processes", 2) as ex:
        rep = run_fleet(caps, e9_zmx, basis, out, FleetSettings(**SETTINGS), executor=ex, log=lambda *a: None)
    return rep, out


def test_fleet_on_the_pool_flags_the_soft_module(line, pool_fleet, e9_zmx):
    from calibration.fleet import FleetSettings, run_fleet
    from isp.io.device import DeviceCalibration

    tmp, caps, basis = line
    rep, out = pool_fleet
    assert rep["devices"] == 3 and rep["failed"] == 1 and "module_x.dng" in rep["failures"]
    assert "no TIFF header" in rep["failures"]["module_x.dng"] and "readme.txt" in rep["not_taken"]
    rows = {r["capture"]: r for r in rep["rows"]}
    # the design measures as the design predicts; the far module is softer in some ring, and flagged
    assert rows["module_b.json"]["sfra_ratio_rings"] == pytest.approx([1, 1, 1], abs=0.03)
    assert rows["module_a.json"]["sfra_ratio_min"] < 0.6 < rows["module_c.json"]["sfra_ratio_min"] < 0.95
    assert rep["below_spec"] == ["module_a.json"] and rep["yield"] == pytest.approx(2 / 3)
    for r in rows.values():
        assert r["sfra_rms_after"] < r["sfra_rms_before"] or r["capture"] == "module_b.json"
        assert r["noise_floor"] > 0
        cal = DeviceCalibration.load(out / r["device_file"])
        assert cal.components == 3 and cal.grid == (2, 3) and cal.fit["record"]["capture"] == r["capture"]
    assert {p.name for p in out.iterdir()} == {"fleet.json", "fleet.md", "fleet.png",
                                                *(f"{m}.device.json" for m in MODULES)}
    assert "| module_a.json |" in (out / "fleet.md").read_text()

    # resumable: a second run keeps every finished device and fits only what failed
    rep2 = run_fleet(caps, e9_zmx, basis, out, FleetSettings(**SETTINGS), executor=create_executor("serial"),
                     log=lambda *a: None)
    assert rep2["fitted_now"] == 0 and all(r.get("resumed") for r in rep2["rows"])


def test_fleet_on_ray_writes_the_pools_devices(line, pool_fleet, e9_zmx, tmp_path):
    ray = pytest.importorskip("ray", reason="ray is not installed (pip install 'phone-isp[cluster]')")
    from calibration.fleet import FleetSettings, run_fleet
    from isp.runtime.executor import executor_from_spec

    _, caps, basis = line
    if ray.is_initialized():
        ray.shutdown()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="warning")
    try:
        rep_ray = run_fleet(caps, e9_zmx, basis, tmp_path / "ray", FleetSettings(**SETTINGS),
                            executor=executor_from_spec("ray", 2), log=lambda *a: None)
    finally:
        ray.shutdown()
    rep_pool, pool_dir = pool_fleet
    assert rep_ray["executor"] == "ray × 2" and rep_ray["devices"] == 3
    assert rep_ray["failures"] == rep_pool["failures"] and rep_ray["below_spec"] == rep_pool["below_spec"]
    for name in MODULES:
        a, b = (json.loads(p.read_text()) for p in (tmp_path / "ray" / f"{name}.device.json",
                                                      pool_dir / f"{name}.device.json"))
        for d in (a, b):
            d["fit"]["record"].pop("seconds")
        assert a == b
        assert np.isfinite(np.asarray(a["descriptor"], float)).all()


def test_fleet_command_line(line, e9_zmx, tmp_path, capsys):
    from isp.cli.main import main

    _, caps, basis = line
    code = main(["calib", "fleet", str(caps), "--lens", str(e9_zmx), "--basis", str(basis), "-o",
                 str(tmp_path / "dev"), "--n-params", "2", "--max-iter", "2", "--coarse", "0", "0",
                 "--components", "3", "--effects", "none", "--workers", "2"])
    out = capsys.readouterr().out
    assert code == 1 and "3 device(s)" in out and "1 failed" in out and "not taken: readme.txt" in out
    with pytest.raises(SystemExit):
        main(["calib", "fleet", "--help"])
    assert "isp calib fleet captures/" in capsys.readouterr().out
    assert main(["calib", "fleet", str(caps), "--lens", str(e9_zmx), "--basis", str(basis), "-o",
                 str(tmp_path / "d2"), "--effects", "unicorn"]) == 2
    assert "unicorn" in capsys.readouterr().err


def test_unlike_the_fleet_needs_a_fleet():
    from calibration.fleet import unlike_the_fleet

    rows = [{"capture": f"m{i}", "sfra_rms_after": e} for i, e in enumerate([0.0088, 0.0101, 0.0109, 0.0101, 0.0092,
                                                                             0.0111, 0.0237, 0.0188])]
    # the fleet_yield modules: the two drawn beyond tolerance, none of the six within
    assert unlike_the_fleet(rows) == ["m6", "m7"]
    assert unlike_the_fleet(rows[:4]) == []              # four modules: no median to trust

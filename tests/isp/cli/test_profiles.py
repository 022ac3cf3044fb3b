"""The correction only for its lens, through the command line: `isp
profiles`, the demo and a simulated e9 capture corrected by the packaged
profile's model, the real GoPro and Canon files not corrected (their output
byte for byte that of ``--correction none``), a forced model, and a broken
user profile reported without stopping a render (kind: property)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from isp.profiles import reload_profiles

pytestmark = pytest.mark.property

#: the real files of other lenses (../shared/data/raw): no profile matches them
OTHER_LENSES = {"gopro_HERO6_GOPR0024.dng": "GoPro HERO6 Black", "gopro_FUSION_GPFR7066.dng": "GoPro FUSION",
                "tinydng_colorchart.dng": "Canon EOS Kiss X4"}


def correction_note(stdout: str) -> str:
    """The correction stage's line of ``isp process -v``."""
    return next(line for line in stdout.splitlines() if line.strip().startswith("correction "))


def test_profiles_lists_the_packaged_profile_and_a_broken_user_file(cli, user_folder):
    code, out, err = cli("profiles")
    assert code == 0, err
    first = out.splitlines()[0].split()
    assert first[:3] == ["e9", "packaged", "LensModel"] and "e9_default.int8.onnx" in out
    assert str(user_folder) in out and "unreadable" not in out
    (user_folder / "bad.toml").write_text("model = [\n")
    reload_profiles()
    code, out, err = cli("profiles")
    assert code == 0, err
    lines = [line for line in out.splitlines() if line.startswith("unreadable profile")]
    assert lines == [f"unreadable profile {user_folder / 'bad.toml'}: not a TOML profile: "
                     + lines[0].split("not a TOML profile: ")[1]]
    code, out, err = cli("profiles", "--json")
    doc = json.loads(out)
    e9 = next(p for p in doc["profiles"] if p["name"] == "e9")
    assert e9["origin"] == "packaged" and e9["match"] == {"LensModel": ["US-12210142-B2-e9",
                                                                        "US-12210142-B2-e9 (*)"]}
    assert list(doc["broken"]) == [str(user_folder / "bad.toml")]


def test_the_demo_capture_is_corrected(cli, tmp_path, user_folder):
    """The demo writes its lens's identity, so the default pipeline runs the
    packaged model on it (and `isp info` says which profile and why)."""
    from calibration.demo import DEMO_LENS, make_capture
    from isp.io.dng_write import write_dng

    dn, meta, _ = make_capture(300, 400, seed=0)
    dng = write_dng(tmp_path / "demo.dng", dn, meta)
    code, out, err = cli("process", dng, "-o", tmp_path / "on.jpg", "-v")
    assert code == 0, err
    note = correction_note(out)
    assert f"profile 'e9' (LensModel '{DEMO_LENS}'): e9_default.int8.onnx" in note
    # the correction sees the demosaic its model was trained after, not the look's bilinear
    assert re.search(r"demosaic +\d+ ms +malvar2004 \(auto: lens profile 'e9'\)", out), out
    code, _, err = cli("process", dng, "-o", tmp_path / "off.jpg", "--correction", "none")
    assert code == 0, err
    assert (tmp_path / "on.jpg").read_bytes() != (tmp_path / "off.jpg").read_bytes()
    code, out, err = cli("info", dng)
    c = json.loads(out)["correction"]
    assert c["profile"] == "e9" and c["model"] == "e9_default.int8.onnx" and c["lens"] == DEMO_LENS


def test_a_simulated_e9_capture_is_corrected(cli, tmp_path, user_folder, e9_lens):
    """The simulator names the lens it simulates (the prescription file's
    stem, "(perturbed)" appended for a perturbed sample), and both find the
    e9 profile."""
    from calibration.optics.lens import Sensor
    from calibration.optics.perturb import apply
    from calibration.simulate.capture import SensorModel, capture_meta, simulate_capture, write_capture
    from isp.profiles import match_profile
    from tests.helpers import gaussian_psf_map, smooth_ri

    sensor = Sensor(1.4, 320, 240)
    sm = SensorModel.from_sensor(sensor, cfa="RGGB")
    pm = gaussian_psf_map(sensor, (3, 4), lambda r, c, k: 1.4, pitch_um=0.7, n=33)
    scene = np.broadcast_to(np.array([0.5, 0.4, 0.3]), (240, 320, 3))
    raw, meta = simulate_capture(e9_lens, scene, psfmap=pm, sensor=sm, relative_illumination=smooth_ri(sensor),
                                 noise=False)
    assert meta.lens == "US-12210142-B2-e9" and meta.unique_camera_model == "phone-isp simulated phone"
    dng = write_capture(tmp_path / "sim.dng", capture=(raw, meta))
    code, out, err = cli("process", dng, "-o", tmp_path / "sim.jpg", "-v")
    assert code == 0, err
    assert "profile 'e9' (LensModel 'US-12210142-B2-e9'): e9_default.int8.onnx" in correction_note(out)
    perturbed = capture_meta(sm, lens=apply(e9_lens, {"s2.thickness": 0.002}))
    assert perturbed.lens == "US-12210142-B2-e9 (perturbed)"
    assert match_profile(perturbed).profile.name == "e9"
    # each simulated module names itself (CameraSerialNumber): one module, one serial; two, two
    from isp.io.read import read_raw

    assert read_raw(dng).meta.serial == meta.serial and meta.serial.startswith("SIM-")
    again = capture_meta(sm, lens=apply(e9_lens, {"s2.thickness": 0.002}))
    other = capture_meta(sm, lens=apply(e9_lens, {"s2.thickness": 0.003}))
    assert again.serial == perturbed.serial and len({meta.serial, perturbed.serial, other.serial}) == 3


@pytest.mark.parametrize("name", list(OTHER_LENSES))
def test_other_lenses_are_not_corrected_and_info_says_why(cli, raw_file, user_folder, name):
    code, out, err = cli("info", raw_file(name))
    assert code == 0, err
    c = json.loads(out)["correction"]
    assert c["model"] is None and c["profile"] is None
    assert c["note"].startswith(f"rendered without correction: no profile for UniqueCameraModel "
                                f"{OTHER_LENSES[name]!r}")
    assert "no LensModel; profiles: e9 (LensModel 'US-12210142-B2-e9' | " in c["note"]


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n.startswith("gopro") else n
                                  for n in OTHER_LENSES])
def test_other_lenses_render_byte_identical_to_no_correction(cli, raw_file, tmp_path, user_folder, name):
    """The output file of the default render is, byte for byte, that of
    ``--correction none`` and of ``--no-correction`` (the GoPro files, 12 and
    9 MP, in the slow run)."""
    src = raw_file(name)
    outs = {}
    for mode in ((), ("--correction", "none"), ("--no-correction",)):
        out = tmp_path / f"{'_'.join(mode) or 'default'}.jpg"
        code, stdout, err = cli("process", src, "-o", out, "-v", *mode)
        assert code == 0, err
        outs[mode] = out.read_bytes()
        if not mode:
            assert "identity: no profile for UniqueCameraModel" in correction_note(stdout)
    assert len(set(outs.values())) == 1


def test_no_model_is_loaded_for_a_lens_without_profile(raw_file, tmp_path, user_folder):
    """The time a file of another lens saves: onnxruntime is not even imported."""
    import subprocess
    import sys

    code = ("import sys; from isp.cli.main import main; "
            f"main(['process', {str(raw_file('tinydng_colorchart.dng'))!r}, '-o', {str(tmp_path / 'c.jpg')!r}]); "
            "print('onnxruntime' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "False"


def test_a_forced_model_runs_whatever_the_lens(cli, raw_file, tmp_path, user_folder):
    from tests.helpers import onnx_select_rgb

    src = raw_file("tinydng_colorchart.dng")
    code, out, err = cli("process", src, "-o", tmp_path / "forced.jpg", "-v", "--correction", "default")
    assert code == 0, err
    assert "e9_default.int8.onnx (lens US-12210142-B2-e9" in correction_note(out)
    model = onnx_select_rgb(tmp_path / "mine.onnx")
    code, out, err = cli("process", src, "-o", tmp_path / "mine.jpg", "-v", "--correction", model)
    assert code == 0, err
    assert "mine.onnx (lens toy" in correction_note(out)
    code, out, err = cli("process", src, "-o", tmp_path / "x.jpg", "--correction", tmp_path / "absent.onnx")
    assert code == 2 and "absent.onnx' not found" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.jpg").exists()
    cfg = tmp_path / "short.toml"
    cfg.write_text('[[stage]]\nname = "black_level"\n')
    code, out, err = cli("process", src, "-o", tmp_path / "x.png", "--config", cfg, "--correction", model)
    assert code == 2 and "the pipeline has no correction stage" in err


def test_a_user_profile_corrects_its_lens_and_a_broken_one_stops_nothing(cli, raw_file, tmp_path,
                                                                       user_folder):
    """A user profile for the Canon body (its model a channel selector) runs
    on the Canon file; an unreadable profile beside it is named in the
    stage's note and stops no render."""
    from tests.helpers import onnx_select_rgb

    onnx_select_rgb(user_folder / "canon.onnx")
    (user_folder / "canon.toml").write_text('model = "canon.onnx"\n[match]\nMake = "Canon"\n'
                                            'Model = "Canon EOS *"\n')
    (user_folder / "broken.toml").write_text('model = "canon.onnx"\n[match]\nLens = "x"\n')
    reload_profiles()
    code, out, err = cli("process", raw_file("tinydng_colorchart.dng"), "-o", tmp_path / "c.jpg", "-v")
    assert code == 0, err
    note = correction_note(out)
    assert "profile 'canon' (Make 'Canon', Model 'Canon EOS Kiss X4')" in note and "canon.onnx" in note
    assert "1 profile(s) unreadable (see `isp profiles`)" in note

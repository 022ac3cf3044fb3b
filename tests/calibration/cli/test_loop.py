"""`isp calib loop` end to end (kind: property): a synthetic chart the test
renders itself, with sharpening applied to its pixels (an effect of the
measurement chain the parametric base lacks), from the image, from the SFR
JSON of `isp calib sfr`, and from a single slanted edge; bad input gives one
line, exit code 2 and no report folder."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from isp.cli.main import main

pytestmark = pytest.mark.property

KEYS = ("effects_added", "error_before", "error_after", "noise_floor")


def _sharpen(img, gain=0.8, sigma=1.2):
    return img + gain * (img - gaussian_filter(img, sigma, mode="nearest"))


def _chart(h=360, w=480, rows=2, cols=3, angle=5.0, sigma=1.0, ss=4, noise=0.003, seed=0):
    """Slanted dark squares blurred by a Gaussian of ``sigma`` px, integrated
    over square pixels (supersampled ×ss), sharpened, noisy: 16-bit codes."""
    import cv2

    big = np.full((h * ss, w * ss), 0.8, np.float32)
    side = 0.5 * min(h / rows, w / cols) * ss
    for r in range(rows):
        for c in range(cols):
            cy, cx = (r + 0.5) * h / rows * ss, (c + 0.5) * w / cols * ss
            box = cv2.boxPoints(((cx, cy), (side, side), angle))
            cv2.fillConvexPoly(big, np.round(box * 16).astype(np.int32), 0.2, lineType=cv2.LINE_AA, shift=4)
    big = cv2.GaussianBlur(big, (0, 0), sigma * ss)
    img = _sharpen(cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA).astype(np.float64))
    img = img + np.random.default_rng(seed).normal(0.0, noise, img.shape)
    return np.clip(np.round(img * 65535), 0, 65535).astype(np.uint16)


def _write_png(path, img):
    import cv2

    assert cv2.imwrite(str(path), img)
    return path


@pytest.fixture(scope="module")
def chart_png(tmp_path_factory):
    return _write_png(tmp_path_factory.mktemp("chart") / "chart.png", _chart())


def _check_report(out_dir):
    doc = json.loads((out_dir / "report.json").read_text())
    for k in KEYS:
        assert k in doc
    assert doc["error_after"]["sfra_rms"] <= doc["error_before"]["sfra_rms"]
    assert doc["error_after"]["sfr_mse"] <= doc["error_before"]["sfr_mse"]
    assert doc["noise_floor"] > 0
    for name in ("report.md", "residual_maps.png", "sfr_curves.png"):
        assert (out_dir / name).stat().st_size > 100
    # nothing but the report folder itself was left beside it (no temporary folders)
    assert [p.name for p in out_dir.parent.iterdir() if p.name.startswith(".")] == []
    return doc


def test_loop_on_a_chart_image_finds_the_sharpening(cli, tmp_path, chart_png):
    out = tmp_path / "rep"
    code, stdout, stderr = cli("calib", "loop", "--lens", "parametric", "--measured", chart_png, "-o", out)
    assert code == 0, stderr
    doc = _check_report(out)
    assert doc["effects_added"][:1] == ["sharpening"]
    assert doc["effect_values"]["sharpening"]["gain"] == pytest.approx(0.8, abs=0.3)
    assert doc["error_after"]["sfra_rms"] < 0.5 * doc["error_before"]["sfra_rms"]
    assert "added sharpening" in stdout and "noise floor" in stdout
    assert "loop" in stderr                      # the progress bar


def test_loop_on_the_sfr_json_of_isp_calib_sfr(cli, capsys, tmp_path, chart_png):
    js = tmp_path / "chart.json"
    assert main(["calib", "sfr", str(chart_png), "--chart", "--json", str(js)]) == 0
    capsys.readouterr()
    out = tmp_path / "rep"
    code, _, stderr = cli("calib", "loop", "--lens", "parametric", "--measured", js, "-o", out,
                          "--effects", "sharpening,focus_shift", "--max-effects", "1")
    assert code == 0, stderr
    doc = _check_report(out)
    assert doc["effects_added"] == ["sharpening"]
    assert {t["effect"] for t in doc["tried"]} == {"sharpening", "focus_shift"}


def test_single_edge_image_is_split_into_segments(cli, tmp_path):
    """An ISO 12233 ROI file (one edge filling the frame): one field region,
    so the edge is cut into segments that the loop cross-validates over."""
    from calibration.sfr.synthetic import render_slanted_edge

    img = _sharpen(render_slanted_edge((300, 120), 5.0, sigma_px=1.0, low=0.2, high=0.8))
    img = img + np.random.default_rng(1).normal(0.0, 0.003, img.shape)
    png = _write_png(tmp_path / "edge.png", np.clip(np.round(img * 65535), 0, 65535).astype(np.uint16))
    out = tmp_path / "rep"
    code, stdout, stderr = cli("calib", "loop", "--lens", "parametric", "--measured", png, "-o", out, "--f-number", "4")
    assert code == 0, stderr
    assert "segments" in stdout and "4 observations in 4 field region" in stdout
    doc = _check_report(out)
    assert doc["base_parameters"].keys() == {"sigma_px"}       # F-number held at 4
    assert "sharpening" in doc["effects_added"]


def test_raw_capture_is_measured_on_the_mosaic(cli, tmp_path):
    """The demo DNG (six slanted squares, Gaussian blur 0.7 px): edges found
    on the 2×2 average, measured on the green CFA plane."""
    from calibration.demo import make_capture
    from isp.io.dng_write import write_dng

    dn, meta, _ = make_capture(600, 800, seed=1)
    dng = write_dng(tmp_path / "demo.dng", dn, meta)
    out = tmp_path / "rep"
    code, stdout, stderr = cli("calib", "loop", "--lens", "parametric", "--measured", dng, "-o", out,
                               "--effects", "sharpening", "--pixel-um", "1.4")
    assert code == 0, stderr
    assert "pixel pitch unknown" not in stdout
    doc = _check_report(out)
    assert doc["base_parameters"]["sigma_px"] < 1.5


def test_observations_json_and_an_existing_report_folder(cli, tmp_path, chart_png):
    from calibration.fit.measurements import load_measured

    obs, _ = load_measured(str(chart_png))
    js = obs.save(tmp_path / "obs.json")
    out = tmp_path / "rep"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    code, _, stderr = cli("calib", "loop", "--lens", "parametric", "--measured", js, "-o", out, "--max-effects", "0")
    assert code == 0, stderr
    doc = _check_report(out)
    assert doc["effects_added"] == [] and doc["error_after"] == doc["error_before"]
    assert (out / "keep.txt").read_text() == "mine"


def _bad_inputs(tmp):
    corrupt = tmp / "corrupt.png"
    corrupt.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    wrong = tmp / "lens.json"
    wrong.write_text(json.dumps({"schema": "lens/v1", "surfaces": []}))
    notjson = tmp / "broken.json"
    notjson.write_text("{ not json")
    bad_obs = tmp / "obs.json"
    bad_obs.write_text(json.dumps({"schema": "sfr-observations/v1", "sensor": {}, "observations": []}))
    flat = tmp / "flat.png"
    _write_png(flat, np.full((64, 64), 30000, np.uint16))
    return {
        "missing": (["--measured", tmp / "nope.png"], "nope.png"),
        "corrupt image": (["--measured", corrupt], "corrupt.png"),
        "JSON of the wrong schema": (["--measured", wrong], "lens.json"),
        "not JSON": (["--measured", notjson], "broken.json"),
        "empty observations": (["--measured", bad_obs], "obs.json"),
        "no edge": (["--measured", flat], "flat.png"),
    }


@pytest.mark.parametrize("case", ["missing", "corrupt image", "JSON of the wrong schema", "not JSON",
                                  "empty observations", "no edge"])
def test_bad_measurement_is_one_line_and_leaves_nothing(cli, tmp_path, case):
    argv, name = _bad_inputs(tmp_path)[case]
    out = tmp_path / "rep"
    code, stdout, stderr = cli("calib", "loop", "--lens", "parametric", *argv, "-o", out)
    assert code == 2, (stdout, stderr)
    assert len(stderr.strip().splitlines()) == 1 and name in stderr and "Traceback" not in stderr
    assert not out.exists()
    assert [p for p in tmp_path.iterdir() if p.name.startswith(".")] == []


@pytest.mark.parametrize("argv,what", [
    (["--lens", "nope.zmx"], "nope.zmx"),
    (["--lens", "parametric", "--effects", "sharpening,unicorn"], "unicorn"),
    (["--lens", "parametric", "--f-number", "fast"], "--f-number"),
    (["--lens", "parametric", "--folds", "1"], "--folds"),
])
def test_bad_options_are_one_line(cli, tmp_path, chart_png, argv, what):
    out = tmp_path / "rep"
    code, _, stderr = cli("calib", "loop", *argv, "--measured", chart_png, "-o", out)
    assert code == 2 and len(stderr.strip().splitlines()) == 1 and what in stderr
    assert not out.exists()


def test_help_teaches(capsys):
    with pytest.raises(SystemExit) as e:
        main(["calib", "loop", "--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    assert "examples:" in text and "isp calib loop --lens parametric" in text and "--measured" in text


def test_bootstrap_gives_each_edge_its_own_sigma(tmp_path, chart_png):
    """property: with ``bootstrap`` every edge's σ is its own residual-
    bootstrap spread, which grows with the noise (4× the noise: σ 2.5–6×,
    as σ_SFRA ∝ noise for small noise) and repeats on a second measurement
    (seeded); without, every edge has the 0.002 cycles/pixel default."""
    from calibration.fit.measurements import load_measured

    plain, _ = load_measured(str(chart_png))
    assert np.all(plain.sfra_std == 2e-3)
    quiet, _ = load_measured(str(chart_png), bootstrap=20)
    again, _ = load_measured(str(chart_png), bootstrap=20)
    noisy, _ = load_measured(str(_write_png(tmp_path / "noisy.png", _chart(noise=0.012))), bootstrap=20)
    assert np.all(np.isfinite(quiet.sfra_std)) and np.all(quiet.sfra_std > 0)
    np.testing.assert_array_equal(quiet.sfra_std, again.sfra_std)
    np.testing.assert_allclose(quiet.sfra, plain.sfra)            # the measurement itself is unchanged
    ratio = np.median(noisy.sfra_std) / np.median(quiet.sfra_std)
    assert 2.5 < ratio < 6.0, ratio

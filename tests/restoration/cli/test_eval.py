"""The `isp eval` command (restoration/cli/eval.py), end to end.

Kind: property. The JSON report's keys per ring (the PSF maps replaced by
a small synthetic one: no optics computed); the test set's light from
``--exposure`` and ``--noise-scale``; a missing input or a bad range is
one line and exit 2; the help.
"""

from __future__ import annotations

import json

import pytest

from tests.helpers import onnx_select_rgb
from tests.helpers import ring_psf_map as psf_map

pytestmark = pytest.mark.property


KEYS = ("psnr_uncorrected", "psnr_corrected", "ssim_uncorrected", "ssim_corrected")


def test_isp_eval_writes_the_report(make, latent_dir, tmp_path, monkeypatch, capsys):
    """`isp eval MODEL --images DIR --lens LENS --json OUT`: the JSON has the
    report's keys per ring, plus overall, per-image, per-lens, timing
    (the PSF maps are replaced by the synthetic one: no optics here)."""
    import restoration.evaluate.rings as ev
    from isp.cli.main import main

    plan, _ = make([psf_map(), psf_map()])
    seen = {}

    def fake_plan(lens, images_dir, **kw):
        seen.update(kw, lens=str(lens))
        return plan

    monkeypatch.setattr(ev, "eval_plan", fake_plan)
    lens = tmp_path / "lens.json"
    lens.write_text("{}")
    model = onnx_select_rgb(tmp_path / "sel.onnx")
    out = tmp_path / "report.json"
    rc = main(["eval", str(model), "--images", str(latent_dir), "--lens", str(lens), "--json", str(out),
               "--samples", "2", "--size", "32", "--border", "8", "--seed", "3", "-q"])
    assert rc == 0
    rep = json.loads(out.read_text())
    assert set(rep["rings"]) == {"0.1", "0.5", "0.9"}
    for ring in rep["rings"].values():
        assert all(isinstance(ring[k], float) for k in KEYS + ("psnr_baseline", "ssim_baseline"))
        assert ring["crops"] == 4                                # 2 images × 2 lenses, one place each
    assert rep["settings"]["seed"] == 3 and seen["settings"].samples == 2 and seen["settings"].seed == 3
    assert rep["model"]["kind"] == "onnx" and len(rep["per_lens"]) == 2 and len(rep["per_image"]) == 2
    assert rep["overall"]["crops"] == 12 and len(rep["crops"]) == 12
    assert rep["timing"]["model"] > 0 and rep["timing"]["per_crop"] > 0
    assert "wrote" in capsys.readouterr().out


def test_isp_eval_sets_the_light_of_the_test_set(make, latent_dir, tmp_path, monkeypatch, capsys):
    """`--exposure` and `--noise-scale` reach the test set's synthesis (the
    rest of it as training's), and a bad range is one line, exit 2, no
    report."""
    import restoration.evaluate.rings as ev
    from isp.cli.main import main

    plan, _ = make([psf_map()])
    seen = {}

    def fake_plan(lens, images_dir, **kw):
        seen.update(kw)
        return plan

    monkeypatch.setattr(ev, "eval_plan", fake_plan)
    lens = tmp_path / "lens.json"
    lens.write_text("{}")
    model = onnx_select_rgb(tmp_path / "sel.onnx")
    args = ["eval", str(model), "--images", str(latent_dir), "--lens", str(lens), "--size", "32", "--border", "8",
            "-q", "--json"]
    assert main(args + [str(tmp_path / "a.json"), "--exposure", "0,0.5", "--noise-scale", "0.25,0.5"]) == 0
    st = seen["synth"]
    assert st.exposure_ev == (0.0, 0.5) and st.noise_scale == (0.25, 0.5)
    assert st.noise and st.cct_k == (2850.0, 7500.0)                    # the others as training's
    seen.clear()
    assert main(args + [str(tmp_path / "b.json"), "--no-noise", "--exposure", "1,1"]) == 0
    assert seen["synth"].exposure_ev == (1.0, 1.0) and not seen["synth"].noise
    capsys.readouterr()
    rc = main(args + [str(tmp_path / "c.json"), "--noise-scale", "0,1"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.count("\n") == 0 and "noise_scale" in err
    assert not (tmp_path / "c.json").exists()


@pytest.mark.parametrize("missing", ["model", "images", "lens"])
def test_isp_eval_missing_input_is_one_line(missing, latent_dir, tmp_path, capsys):
    from isp.cli.main import main

    paths = {"model": tmp_path / "m.onnx", "images": latent_dir, "lens": tmp_path / "lens.json"}
    paths["model"].write_bytes(b"x")
    paths["lens"].write_text("{}")
    paths[missing] = tmp_path / f"no_{missing}"
    rc = main(["eval", str(paths["model"]), "--images", str(paths["images"]), "--lens", str(paths["lens"]),
               "--json", str(tmp_path / "o.json")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.count("\n") == 0 and f"no_{missing}" in err
    assert not (tmp_path / "o.json").exists()


def test_isp_eval_help(capsys):
    from isp.cli.main import main

    with pytest.raises(SystemExit) as e:
        main(["eval", "--help"])
    assert e.value.code == 0
    text = capsys.readouterr().out
    assert "examples:" in text and "--baseline" in text and "spawn_key=(2,)" in text

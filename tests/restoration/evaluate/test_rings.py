"""Evaluation of a correction model (restoration.evaluate.rings, .runner, .baseline,
`isp eval`).

Kind: property. Controlled cases whose answer is known: an identity model
scores as the uncorrected pipeline; a model that undoes a pure shift (a PSF
that is a displaced delta, no noise) scores as an ideal lens does; the
Wiener deconvolution with the true PSF beats the uncorrected image where
the blur is strong (a physics check); a checkpoint and its ONNX export score
alike. PSF maps are small synthetic ones (no optics computed); the frame is
384 × 512 with 48-px crops, so all three field rings can be reached.
"""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
from tests.helpers import data_file, kernel_psf_map

from calibration.optics.psf.map import PSFMap
from isp.runtime.executor import create_executor

pytestmark = pytest.mark.property

S6 = ("raw", "SYNTHETIC_phone_S6meta_512x384.dng")
FRAME = (384, 512)
QUIET = create_executor("serial")          # the crops in this process, no progress bar
KEYS = ("psnr_uncorrected", "psnr_corrected", "ssim_uncorrected", "ssim_corrected")


# -- fixtures --------------------------------------------------------------------------

def psf_map(kind="gauss", shift=(0, 0), grid=(3, 4), n=32, pitch_um=0.5) -> PSFMap:
    """Gaussians widening with the field radius (σ 0.3 px at the centre to
    ≈ 1.8 px in the corners, per channel a little wider), or deltas
    displaced by ``shift`` PSF samples (``pitch_um`` µm on 1-µm pixels)."""
    rows, cols = grid

    def kernel(r, c, ch, xx, yy):
        if kind == "delta":
            k = np.zeros_like(xx)
            k[n // 2 + shift[0], n // 2 + shift[1]] = 1.0
            return k
        rho = math.hypot((r + 0.5) / rows - 0.5, (c + 0.5) / cols - 0.5) / math.hypot(0.5, 0.5)
        s = 0.3 + 1.5 * rho + 0.1 * ch
        return np.exp(-(xx ** 2 + yy ** 2) / (2 * s * s))

    h, w = FRAME
    return kernel_psf_map(kernel, height=h, width=w, grid=grid, n=n, pitch_um=pitch_um)


@pytest.fixture(scope="module")
def latent_dir(tmp_path_factory):
    """Two 8-bit latent images with texture and edges."""
    d = tmp_path_factory.mktemp("latent")
    for seed in range(2):
        rng = np.random.default_rng(seed)
        y, x = np.mgrid[0:128, 0:128]
        img = np.stack([0.5 + 0.35 * np.sin(x / 3.0 + k + seed) * np.cos(y / 4.0 - k) for k in range(3)], -1)
        for _ in range(12):
            r, c = rng.integers(0, 108, 2)
            img[r:r + rng.integers(5, 20), c:c + rng.integers(5, 20)] = rng.uniform(0.05, 0.95, 3)
        cv2.imwrite(str(d / f"img{seed}.png"), np.clip(np.rint(img * 255), 0, 255).astype(np.uint8)[:, :, ::-1])
    return d


@pytest.fixture(scope="module")
def cameras():
    from restoration.synth.colour import read_camera

    return (read_camera(data_file(*S6)),)


@pytest.fixture(scope="module")
def make(latent_dir, cameras):
    """``make(maps, baseline=..., **synth settings)`` → (plan, settings)."""
    from restoration.evaluate.rings import EvalSettings
    from restoration.synth.pairs import SynthPlan, SynthSettings, find_latents
    from restoration.synth.colour import colour_table

    def build(maps, baseline="wiener", **kw):
        es = EvalSettings(size=32, border=8, baseline=baseline, min_ring_pixels=64)
        st = SynthSettings(**{"size": es.work, "cct_steps": 4, "augment": False, **kw})
        lat = tuple(str(p) for p in find_latents(latent_dir))
        info = {"lens": {"lenses": [{"psf_map_key": f"k{i}", "proxy": False} for i in range(len(maps))]}}
        return SynthPlan(tuple(maps), cameras, colour_table(list(cameras), st.cct_k, st.cct_steps), lat, FRAME,
                         0, st, (4e-4, 1e-6), info), es

    return build


def identity(J, origin, full_size):
    return J


def onnx_select_rgb(path, meta=None):
    """An ONNX model whose output is its input's RGB (a 1×1 conv selecting
    channels 0–2 of RGB + field), with the correction stage's metadata."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    w = np.zeros((3, 5, 1, 1), np.float32)
    w[[0, 1, 2], [0, 1, 2]] = 1.0
    inp = helper.make_tensor_value_info("input", TensorProto.FLOAT, [1, 5, "h", "w"])
    out = helper.make_tensor_value_info("output", TensorProto.FLOAT, [1, 3, "h", "w"])
    graph = helper.make_graph([helper.make_node("Conv", ["input", "w"], ["output"])], "sel", [inp], [out],
                              initializer=[helper.make_tensor("w", TensorProto.FLOAT, w.shape, w.ravel())])
    m = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    for k, v in {"domain": "camera_rgb", "fov_encoding": "xy", "input_multiple": "4", "lens": "toy",
                 **(meta or {})}.items():
        e = m.metadata_props.add()
        e.key, e.value = k, v
    onnx.save(m, str(path))
    return path


# -- geometry ------------------------------------------------------------------------------

def test_field_radius_and_ring_placement():
    """Property: r = 0 at the centre, 1 at the corners; crops placed for a
    ring lie on the sensor with their centre inside the ring."""
    from restoration.evaluate.rings import RINGS, field_radius, ring_origin

    h, w = 4211, 5614
    r = field_radius(np.array([0, h // 2, h - 1]), np.array([0, w // 2, w - 1]), (h, w))
    assert r[0, 0] == pytest.approx(1.0, abs=1e-3) and r[2, 2] == pytest.approx(1.0, abs=1e-3)
    assert r[1, 1] == pytest.approx(0.0, abs=1e-3)
    rng = np.random.default_rng(0)
    for _ in range(20):
        for lo, hi in RINGS.values():
            r0, c0 = ring_origin((h, w), 320, 0.5 * (lo + hi), (lo, hi), rng)
            assert 0 <= r0 <= h - 320 and 0 <= c0 <= w - 320
            rr = field_radius(np.arange(r0, r0 + 320), np.arange(c0, c0 + 320), (h, w))
            assert lo <= rr[160, 160] <= hi and lo <= rr.min() and rr.max() <= hi


def test_unseen_lenses_are_not_the_training_draws(e9_zmx):
    """The evaluation's lenses come from another random stream than the
    training's (spawn key 2 vs 0), so none equals a training lens for the
    same seed, and the proxy is left out unless asked for."""
    from restoration.evaluate.rings import eval_lenses
    from restoration.synth.pairs import seeded_rng
    from restoration.synth.optics import draw_lenses, load_lens

    lens = load_lens(e9_zmx)
    train = draw_lenses(lens, 4, seeded_rng(0, 0))
    test = eval_lenses(lens, 3, 0)
    assert len(test) == 3
    key = lambda pl: tuple(sorted(pl.perturbation.as_dict().items()))
    assert not {key(t) for t in test} & {key(t) for t in train}
    assert key(eval_lenses(lens, 1, 0, with_proxy=True)[0]) == key(lens)
    assert [key(t) for t in eval_lenses(lens, 3, 0)] == [key(t) for t in test]   # deterministic


# -- controlled cases ------------------------------------------------------------------------

def test_identity_model_scores_as_uncorrected(make):
    """Property: corrected == uncorrected, ring by ring, for an identity model."""
    from restoration.evaluate.rings import evaluate_plan

    plan, es = make([psf_map()])
    res = evaluate_plan(plan, identity, es, executor=QUIET)
    assert set(res["rings"]) == {"0.1", "0.5", "0.9"}
    for ring in res["rings"].values():
        assert ring["crops"] == 2
        assert ring["psnr_corrected"] == ring["psnr_uncorrected"]
        assert ring["ssim_corrected"] == ring["ssim_uncorrected"]
    # the blur grows with the field: the uncorrected image gets worse outwards
    psnr = [res["rings"][k]["psnr_uncorrected"] for k in ("0.1", "0.5", "0.9")]
    assert psnr[0] > psnr[1] > psnr[2]


def test_exact_inverse_scores_as_an_ideal_lens(make):
    """Property: the blur is a shift by 2 px (a displaced delta: the CFA
    phase is kept), no noise, no quantisation; a model that shifts back
    gives exactly the input of an ideal lens, so its scores equal the ideal
    lens's uncorrected ones, far above the shifted image's."""
    from restoration.evaluate.rings import evaluate_plan

    def unshift(J, origin, full_size):
        return np.roll(J, -2, axis=1)          # the border it wraps is not scored

    kw = {"noise": False, "quantise": False, "baseline": "none"}
    shifted, es = make([psf_map("delta", shift=(0, 4))], **kw)
    ideal, _ = make([None], **kw)
    got = evaluate_plan(shifted, unshift, es, executor=QUIET)
    ref = evaluate_plan(ideal, identity, es, executor=QUIET)
    for k in ("0.1", "0.5", "0.9"):
        g, r = got["rings"][k], ref["rings"][k]
        assert g["psnr_corrected"] == pytest.approx(r["psnr_uncorrected"], abs=0.01)
        assert g["ssim_corrected"] == pytest.approx(r["ssim_uncorrected"], abs=1e-4)
        assert g["psnr_corrected"] > g["psnr_uncorrected"] + 5.0
        assert g["psnr_baseline"] is None and g["ssim_baseline"] is None


@pytest.mark.parametrize("method", ["wiener", "rl"])
def test_deconvolution_with_the_true_psf_helps_where_the_blur_is(make, method):
    """Physics: with the true (field-varying) PSF and little noise, the
    classical deconvolution raises PSNR and SSIM at FoV 0.9, where the
    blur is widest."""
    from restoration.evaluate.rings import evaluate_plan

    plan, es = make([psf_map()], baseline=method, noise_scale=(0.02, 0.02))
    r = evaluate_plan(plan, identity, es, executor=QUIET)["rings"]["0.9"]
    assert r["psnr_baseline"] > r["psnr_uncorrected"] + 1.0
    assert r["ssim_baseline"] > r["ssim_uncorrected"]


def test_wiener_inverts_a_shift():
    """The baseline's kernel convention is the blur's: Wiener with a
    displaced-delta PSF undoes the displacement (interior, no noise)."""
    from calibration.simulate.optical_image import KernelBank
    from restoration.evaluate.baseline import deconvolve
    from restoration.synth.optics import CropBlur

    m = psf_map("delta", shift=(2, -4))       # 1 px down, 2 px left
    rng = np.random.default_rng(1)
    img = cv2.GaussianBlur(rng.uniform(0, 1, (64, 80, 3)).astype(np.float32), (0, 0), 1.0)
    blurred = CropBlur(m)(img, (100, 200))
    out, rec = deconvolve(blurred, KernelBank.from_psf(m), (100, 200), FRAME, sigma2=np.zeros(3))
    assert rec.regions >= 1 and rec.balance == pytest.approx(0.003 + 1e-12, rel=1e-3)
    inner = (slice(12, -12), slice(12, -12))
    assert np.abs(blurred[inner] - img[inner]).max() > 0.1
    assert np.abs(out[inner] - img[inner]).max() < 0.05


# -- runners -------------------------------------------------------------------------------

def test_onnx_identity_through_the_correction_stage(make, tmp_path):
    """An ONNX model run by the correction stage (tiles, field channels):
    a channel-selecting model scores exactly as the uncorrected pipeline."""
    from restoration.evaluate.rings import evaluate_plan
    from restoration.evaluate.runner import OnnxRunner, load_runner

    runner = load_runner(onnx_select_rgb(tmp_path / "sel.onnx"))
    assert isinstance(runner, OnnxRunner) and runner.meta["fov_encoding"] == "xy"
    plan, es = make([psf_map()], baseline="none")
    res = evaluate_plan(plan, runner, es, executor=QUIET)
    for ring in res["rings"].values():
        assert ring["psnr_corrected"] == pytest.approx(ring["psnr_uncorrected"], abs=1e-6)


@pytest.mark.parametrize("domain", ["display_rgb", "linear_rgb"])
def test_identity_at_the_other_placements_scores_as_uncorrected(make, tmp_path, domain):
    """The placement ablation's models run where they were trained: at the
    end of the pipeline (fed the processed input, scored as they return it)
    or between the colour matrix and the gamma (fed linear sRGB, their
    output encoded by the gamma): an identity model scores as the
    uncorrected pipeline at either."""
    from restoration.evaluate.rings import evaluate_plan
    from restoration.evaluate.runner import load_runner

    runner = load_runner(onnx_select_rgb(tmp_path / "sel.onnx", {"domain": domain}))
    plan, es = make([psf_map()], baseline="none")
    res = evaluate_plan(plan, runner, es, executor=QUIET)
    for ring in res["rings"].values():
        assert ring["psnr_corrected"] == pytest.approx(ring["psnr_uncorrected"], abs=1e-4)


def test_onnx_for_another_domain_is_refused(tmp_path):
    from isp.errors import PlacementError
    from restoration.evaluate.runner import load_runner

    # camera_rgb (the slot), linear_rgb and display_rgb (the placement ablation) run; not others
    with pytest.raises(PlacementError, match="raw_linear"):
        load_runner(onnx_select_rgb(tmp_path / "d.onnx", {"domain": "raw_linear"}))


@pytest.mark.filterwarnings("ignore::DeprecationWarning")     # the TorchScript exporter (no onnxscript here)
def test_checkpoint_and_onnx_score_alike(make, tmp_path):
    """Property (torch ↔ ONNX): a small DOConv UNet saved as a checkpoint
    and exported to ONNX gives the same metrics (±0.01 dB, ±1e-4 SSIM)."""
    torch = pytest.importorskip("torch")
    onnx = pytest.importorskip("onnx")
    from restoration.nn.checkpoint import save_checkpoint
    from restoration.evaluate.rings import evaluate_plan
    from restoration.nn.network import build_model
    from restoration.evaluate.runner import TorchRunner, load_runner

    torch.manual_seed(0)
    kwargs = {"widths": [8, 8], "depths": [1, 0, 1]}
    model = build_model("doconv", **kwargs).eval()
    with torch.no_grad():                      # a visible correction, not the near-identity of an untrained head
        model.head[0].weight.mul_(20.0)
    meta = {"domain": "camera_rgb", "fov_encoding": "xy", "input_multiple": 4, "receptive_radius": 24,
            "lens": "toy"}
    ckpt = save_checkpoint(tmp_path / "m.pt", model, variant="doconv", model_kwargs=kwargs, metadata=meta)
    x = torch.rand(1, 5, 64, 64)
    path = tmp_path / "m.onnx"
    torch.onnx.export(model, (x,), str(path), dynamo=False, opset_version=17, input_names=["input"],
                      output_names=["output"], dynamic_axes={"input": {2: "h", 3: "w"}, "output": {2: "h", 3: "w"}})
    m = onnx.load(str(path))
    for k, v in meta.items():
        e = m.metadata_props.add()
        e.key, e.value = k, str(v)
    onnx.save(m, str(path))

    t_run, o_run = load_runner(ckpt), load_runner(path)
    assert isinstance(t_run, TorchRunner) and t_run.margin == 24 and t_run.meta["lens"] == "toy"
    plan, es = make([psf_map()], baseline="none")
    a = evaluate_plan(plan, t_run, es, executor=QUIET)
    b = evaluate_plan(plan, o_run, es, executor=QUIET)
    for k in ("0.1", "0.5", "0.9"):
        ra, rb = a["rings"][k], b["rings"][k]
        assert ra["psnr_corrected"] == pytest.approx(rb["psnr_corrected"], abs=0.01)
        assert ra["ssim_corrected"] == pytest.approx(rb["ssim_corrected"], abs=1e-4)
        assert abs(ra["psnr_corrected"] - ra["psnr_uncorrected"]) > 0.05     # the model does something


def test_a_checkpoint_whose_reach_exceeds_the_tile_runs_on_larger_tiles():
    """A receptive radius of 300 px with the default 512 px tile left no
    core (`isp eval` of a wide-attention model failed); the runner raises
    the tile instead, and the result is the whole-frame run's (tile 0)."""
    torch = pytest.importorskip("torch")
    from restoration.nn.network import build_model
    from restoration.evaluate.runner import MIN_CORE, TorchRunner

    torch.manual_seed(0)
    model = build_model("doconv", widths=(8, 8), depths=(0, 1, 0)).eval()
    run = TorchRunner(model, {"receptive_radius": 300, "tile_size": 512})
    assert run.tile >= 2 * 300 + MIN_CORE and run.tile % run.multiple == 0
    rgb = np.random.default_rng(0).random((40, 48, 3), dtype=np.float32)
    got = run(rgb, (0, 0), (40, 48))
    want = TorchRunner(model, {"receptive_radius": 300, "tile_size": 0})(rgb, (0, 0), (40, 48))
    assert np.abs(got - want).max() < 1e-5 and np.abs(got - rgb).max() > 1e-3


# -- the command line -------------------------------------------------------------------------

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


def test_a_model_trained_at_another_pixel_pitch_is_flagged(make, latent_dir, tmp_path, monkeypatch):
    """A model corrects blur in pixels: one whose training pairs were made
    at 2.807 µm pixels, scored on lenses whose sensor has 1 µm pixels,
    gets a warning naming both pitches and the option that makes pairs at
    the test's pitch; trained at the test's pitch, none."""
    import warnings

    import restoration.evaluate.rings as ev
    from restoration.evaluate.runner import load_runner

    plan, _ = make([psf_map()], baseline="none")
    plan.info["psf_map"] = {"sensor": {"pixel_pitch_um": 1.0, "width_px": 128, "height_px": 96}}
    monkeypatch.setattr(ev, "eval_plan", lambda lens, images_dir, **kw: plan)
    runner = load_runner(onnx_select_rgb(tmp_path / "sel.onnx"))
    kw = dict(images_dir=latent_dir, lens="lens.json",
              settings=ev.EvalSettings(samples=1, size=32, border=8, baseline="none"), executor=QUIET)
    for pitch, flagged in ((2.807, True), (1.0, False)):
        runner.info = {"metadata": {"training_sets": [{"psf_map": {"sensor": {"pixel_pitch_um": pitch}}}]}}
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            ev.evaluate(runner, **kw)
        hits = [str(w.message) for w in seen if "µm pixels" in str(w.message)]
        assert bool(hits) is flagged
        if flagged:
            assert "2.807 µm" in hits[0] and "1 µm" in hits[0] and "--pixel-um 1" in hits[0]


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

"""Training of the correction network (restoration/train/trainer.py, train_config.py,
checkpoint.py, `isp train`).

Kind: property. A tiny set is synthesised with the project's own synthesis
(a Gaussian PSF map that widens over the field, two latent images, the
phone DNGs' colour metadata) and a tiny DOConv network is trained on it
for a few dozen steps through the command line. Checked: the loss falls;
the loss is the L2 of the pipeline's own stage functions applied to the
model's output (recomputed by hand at step 0, and changed when the gamma
stage's function is patched); a resumed run repeats the uninterrupted
run's losses; a checkpoint reloads to the same outputs; config errors are
one line and exit 2.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from tests.helpers import ROOT, data_file, kernel_psf_map

pytestmark = pytest.mark.property

torch = pytest.importorskip("torch")

from calibration.optics.psf.map import PSFMap
from isp.cli.main import main
from isp.errors import ConfigError
from isp.runtime.executor import create_executor

S6 = ("raw", "SYNTHETIC_phone_S6meta_512x384.dng")
LG = ("raw", "skia_sample_1mp.dng")
TINY = {"widths": [8, 16], "depths": [1, 1, 1], "expansion": 2}
STEPS = 24


def gaussian_map(height=96, width=128, grid=(3, 4), n=16, pitch_um=0.5) -> PSFMap:
    """Gaussian PSFs whose width grows over the field (a known blur)."""
    def kernel(r, c, ch, xx, yy):
        s = 0.6 + 0.4 * (r + c) + 0.15 * ch
        return np.exp(-(xx ** 2 + yy ** 2) / (2 * s * s))

    return kernel_psf_map(kernel, height=height, width=width, grid=grid, n=n, pitch_um=pitch_um)


def latent_pngs(d, size=144, count=3):
    """Latent sRGB images with edges and texture (8-bit PNG)."""
    d.mkdir(parents=True, exist_ok=True)
    for seed in range(count):
        rng = np.random.default_rng(seed)
        y, x = np.mgrid[0:size, 0:size]
        img = np.stack([0.5 + 0.4 * np.sin(x / (3.0 + seed) + k) * np.cos(y / 5.0 - k) for k in range(3)], -1)
        for _ in range(6):
            r, c, h, w = rng.integers(0, size - 20, 4) // 1
            img[r:r + 8 + h % 24, c:c + 8 + w % 24] = rng.uniform(0.05, 0.95, 3)
        u8 = np.clip(np.rint(img * 255), 0, 255).astype(np.uint8)
        cv2.imwrite(str(d / f"img{seed}.png"), u8[:, :, ::-1])
    return d


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    """A synthesised set: 24 pairs of 64², 3 latent images, one blurred lens."""
    from restoration.synth.pairs import SynthPlan, SynthSettings, find_latents, generate
    from restoration.synth.colour import colour_table, read_camera

    tmp = tmp_path_factory.mktemp("train")
    cams = (read_camera(data_file(*S6)), read_camera(data_file(*LG)))
    st = SynthSettings(size=64, cct_steps=4)
    lat = tuple(str(p) for p in find_latents(latent_pngs(tmp / "latent")))
    plan = SynthPlan((gaussian_map(),), cams, colour_table(list(cams), st.cct_k, st.cct_steps), lat, (96, 128),
                     0, st, (4e-4, 1e-6))
    generate(plan, tmp / "pairs", 24, shard_size=10, executor=create_executor("serial"))
    return tmp / "pairs"


def config_dict(data_dir, out, **run) -> dict:
    return {"data": {"dirs": [str(data_dir)], "crop": 32, "batch": 4, "val_latents": 1, "val_pairs": 2},
            "model": {"variant": "doconv", "kwargs": TINY},
            "optim": {"lr": 3e-3, "step_epochs": 4.0},
            "temperature": {"epochs": 2.0},
            "run": {"steps": STEPS, "seed": 0, "device": "cpu", "threads": 1, "checkpoint_every": 8,
                    "out": str(out), **run}}


def write_toml(path, d: dict):
    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, dict):
            return "{" + ", ".join(f"{k} = {val(x)}" for k, x in v.items()) + "}"
        if isinstance(v, list):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return repr(v)

    path.write_text("".join(f"[{s}]\n" + "".join(f"{k} = {val(v)}\n" for k, v in t.items()) + "\n"
                            for s, t in d.items()))
    return path


@pytest.fixture(scope="module")
def run_a(pairs, tmp_path_factory):
    """The uninterrupted run, through `isp train`."""
    tmp = tmp_path_factory.mktemp("run_a")
    cfg = write_toml(tmp / "cfg.toml", config_dict(pairs, tmp / "never"))
    assert main(["train", "--config", str(cfg), "--out", str(tmp / "out"), "-q"]) == 0
    return tmp / "out", cfg


# -- the run ---------------------------------------------------------------------------

def test_training_lowers_the_loss_and_writes_its_outputs(run_a):
    out, _ = run_a
    log = json.loads((out / "train_log.json").read_text())
    loss = np.asarray(log["history"]["loss"])
    assert log["history"]["step"] == list(range(STEPS))
    assert loss[-8:].mean() < 0.8 * loss[:4].mean()
    for f in ("model.pt", "last.pt", "loss.png", "checkpoints/step_0000008.pt", "checkpoints/step_0000024.pt"):
        assert (out / f).is_file(), f
    assert [v["step"] for v in log["val"]] == [0, 8, 16, 24]
    assert log["val"][-1]["psnr_db"] > log["val"][0]["psnr_db"]
    assert log["data"]["train_pairs"] + log["data"]["val_pairs"] <= 24
    assert log["device"] == "cpu" and log["seconds_per_step"] > 0


def test_checkpoint_metadata_and_reload(run_a, pairs):
    """model.pt rebuilds the model; its validation PSNR is the logged one."""
    from restoration.nn.checkpoint import load_model
    from restoration.train.dataset import read_manifest
    from restoration.train.trainer import PairBank, split_pairs, validate

    out, _ = run_a
    model, info = load_model(out / "model.pt")
    assert not model.training and info["step"] == STEPS and info["variant"] == "doconv"
    md = info["metadata"]
    assert md["domain"] == "camera_rgb" and md["placement"] == "camera_rgb after demosaic"
    assert md["fov_encoding"] == "xy" and md["input_multiple"] == 4 and md["receptive_radius"] > 0
    assert md["training_data"] == read_manifest(pairs)["data_sha256"]
    _, val, _ = split_pairs([pairs], 1, 2, 0)
    v = validate(model, PairBank.load([pairs], val), torch.device("cpu"), 4)
    log = json.loads((out / "train_log.json").read_text())
    assert v["psnr_db"] == pytest.approx(log["val"][-1]["psnr_db"], abs=1e-4)


def test_resume_repeats_the_uninterrupted_run(run_a, tmp_path):
    """From the step-16 checkpoint into a new folder: steps 16..23 give the same losses."""
    out, cfg = run_a
    assert main(["train", "--config", str(cfg), "--out", str(tmp_path / "b"), "-q",
                 "--resume", str(out / "checkpoints" / "step_0000016.pt")]) == 0
    a = json.loads((out / "train_log.json").read_text())["history"]
    b = json.loads((tmp_path / "b" / "train_log.json").read_text())["history"]
    assert b["step"] == list(range(STEPS))                 # 0..15 carried over from the checkpoint's log
    np.testing.assert_allclose(b["loss"][16:], a["loss"][16:], rtol=1e-5)
    np.testing.assert_allclose(b["lr"], a["lr"])


def test_save_load_round_trip_gives_identical_outputs(tmp_path):
    from restoration.nn.checkpoint import load_checkpoint, load_model, save_checkpoint
    from restoration.nn.network import build_model

    torch.manual_seed(3)
    m = build_model("doconv", **TINY)
    with torch.no_grad():
        for p in m.parameters():
            p.add_(0.05 * torch.randn_like(p))
    m.eval()
    opt = torch.optim.Adam(m.parameters())
    save_checkpoint(tmp_path / "c.pt", m, variant="doconv", model_kwargs=TINY, optimizer=opt, step=7, epoch=1,
                    config={"a": np.float32(1.5)}, metadata={"lens": "x", "t": (1, 2)})
    m2, info = load_model(tmp_path / "c.pt")
    x = torch.rand(2, 5, 32, 48)
    with torch.no_grad():
        assert torch.equal(m(x), m2(x))
    assert info["step"] == 7 and info["config"] == {"a": 1.5} and info["metadata"]["t"] == [1, 2]
    assert "state_dict" not in info and load_checkpoint(tmp_path / "c.pt")["optimizer"] is not None
    assert not list(tmp_path.glob(".*.tmp"))            # atomic write leaves no temporary file


# -- the loss is the pipeline's Process --------------------------------------------------

def test_process_is_the_stages_own_functions():
    """The loss's Process calls the modules' stage functions (not copies),
    and its values and gradients equal the chain written out with them."""
    import modules.ccm
    import modules.gamma
    import modules.luminance
    import restoration.synth.colour as sc
    from restoration.train.trainer import process_batch

    assert sc.srgb_oetf is modules.gamma.srgb_oetf
    assert sc.apply_ccm is modules.ccm.apply_ccm
    assert sc.adjust_luminance is modules.luminance.adjust_luminance
    rng = np.random.default_rng(0)
    meta = [{"ccm": np.eye(3) + 0.2 * rng.standard_normal((3, 3)), "exposure_ev": float(e),
             "luma_weights": np.array([0.3, 0.5, 0.2]), "tone": t, "white": 4.0}
            for e, t in ((0.5, "none"), (1.5, "reinhard"))]
    x = torch.rand(2, 3, 8, 8, dtype=torch.float64) * 0.4
    x1 = x.clone().requires_grad_(True)
    x2 = x.clone().requires_grad_(True)
    p1 = process_batch(x1, meta)
    p2 = torch.cat([modules.gamma.srgb_oetf(modules.ccm.apply_ccm(
        modules.luminance.adjust_luminance(x2[n:n + 1], 2.0 ** m["exposure_ev"], m["luma_weights"], m["tone"],
                                           m["white"], channel_axis=-3), m["ccm"], channel_axis=-3))
        for n, m in enumerate(meta)])
    torch.testing.assert_close(p1, p2, rtol=0, atol=0)
    (p1 ** 2).sum().backward()
    (p2 ** 2).sum().backward()
    torch.testing.assert_close(x1.grad, x2.grad, rtol=0, atol=0)


def test_training_loss_is_l2_of_process_of_model(pairs, run_a):
    """Step 0's logged loss = mean((gamma∘ccm∘luminance)(Model(J)) − L)²,
    recomputed by hand from the seeded model and the step's batch."""
    import modules.ccm
    import modules.gamma
    import modules.luminance
    from restoration.nn.network import build_model
    from restoration.train.trainer import PairBank, batch_plan, crop_plan, split_pairs

    out, _ = run_a
    log = json.loads((out / "train_log.json").read_text())
    train_ids, _, _ = split_pairs([pairs], 1, 2, 0)
    bank = PairBank.load([pairs], train_ids)
    torch.manual_seed(0)
    model = build_model("doconv", **TINY)
    from restoration.nn.doconv import set_temperature

    set_temperature(model, 30.0)
    idx = batch_plan(0, len(bank), 4, 0)
    offs = crop_plan(0, bank, idx, 32, 4, 0)
    for i, (r, c) in zip(idx, offs):     # crop origins on the full frame on the 4-px grid
        assert (bank.origin[i, 0] + r) % 4 == 0 and (bank.origin[i, 1] + c) % 4 == 0
    x, y, meta = bank.batch(idx, offs, 32)
    with torch.no_grad():
        pred = model(torch.from_numpy(x))
        srgb = torch.cat([modules.gamma.srgb_oetf(modules.ccm.apply_ccm(modules.luminance.adjust_luminance(
            pred[n:n + 1], 2.0 ** m["exposure_ev"], m["luma_weights"], m["tone"], m["white"], channel_axis=-3),
            m["ccm"], channel_axis=-3)) for n, m in enumerate(meta)])
        by_hand = float(((srgb - torch.from_numpy(y)) ** 2).mean())
    assert log["history"]["loss"][0] == pytest.approx(by_hand, rel=1e-6)


def test_patching_the_gamma_function_changes_the_loss(pairs, run_a, tmp_path, monkeypatch):
    """The same first step with the gamma stage's function replaced by a
    linear clip: another loss, so the training loss is computed through it."""
    import restoration.synth.colour as sc
    from restoration.train.trainer import train
    from restoration.train.config import TrainConfig

    out, _ = run_a
    base = json.loads((out / "train_log.json").read_text())["history"]["loss"][0]
    monkeypatch.setattr(sc, "srgb_oetf", lambda v: v.clamp(0.0, 1.0))
    cfg = TrainConfig.from_dict(config_dict(pairs, tmp_path, steps=1)).replace("data", val_pairs=0)
    patched = train(cfg, executor=create_executor("serial"), log=lambda *_: None)["history"]["loss"][0]
    assert abs(patched - base) > 1e-3 * base


# -- data split, config, command line ----------------------------------------------------

def test_split_holds_out_whole_latent_images(pairs):
    from restoration.train.trainer import split_pairs

    train, val, held = split_pairs([pairs], 1, 100, 0)
    lat = np.concatenate([np.load(p)["latent"] for p in sorted(pairs.glob("shard-*.npz"))])
    names = json.loads((pairs / "manifest.json").read_text())["latent"]["files"]
    held_idx = {k for k, f in enumerate(names) if f["path"] in held}
    assert len(held) == 1 and val and train
    assert all(lat[i] in held_idx for _, i in val) and not any(lat[i] in held_idx for _, i in train)
    assert len(train) + len(val) == 24


def test_every_config_key_is_documented():
    import restoration.train.trainer as t
    from restoration.train.config import SECTIONS

    for section, cls in SECTIONS.items():
        for f in cls.__dataclass_fields__:
            assert f"``{section}.{f}``" in t.__doc__, f"{section}.{f} missing from restoration/train/trainer.py's table"


def test_config_errors_name_the_key(tmp_path):
    from restoration.train.config import TrainConfig, load_config

    with pytest.raises(ConfigError, match=r"unknown key\(s\) 'lrate'; valid: loss, lr"):
        TrainConfig.from_dict({"data": {"dirs": ["x"]}, "optim": {"lrate": 1}})
    with pytest.raises(ConfigError, match="unknown section"):
        TrainConfig.from_dict({"data": {"dirs": ["x"]}, "optimizer": {}})
    with pytest.raises(ConfigError, match="optim.lr must be float"):
        TrainConfig.from_dict({"data": {"dirs": ["x"]}, "optim": {"lr": "fast"}})
    with pytest.raises(ConfigError, match="multiple of 4"):
        TrainConfig.from_dict({"data": {"dirs": ["x"], "crop": 30}})
    with pytest.raises(ConfigError, match="no training data"):
        TrainConfig.from_dict({})
    (tmp_path / "c.json").write_text(json.dumps({"data": {"dirs": ["x"]}, "run": {"steps": 5}}))
    assert load_config(tmp_path / "c.json").run.steps == 5


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


@pytest.mark.parametrize("name, samples", [("e9_default.toml", 3), ("e9_lenses9.toml", 9), ("e9_gpu.toml", 9),
                                           ("e9_bright.toml", 3), ("e9_nonoise.toml", 3)])
def test_default_config_is_valid(name, samples):
    """configs/e9_default.toml (and its twins: nine cameras, the GPU budget,
    bright light, no noise) parses, trains the default variant with the
    linear high-pass and its penalty, and synthesises from the e9 lens."""
    from pathlib import Path

    from restoration.train.config import load_config, resolve_path

    cfg = load_config(ROOT / "configs" / name)
    assert cfg.synth is not None and resolve_path(cfg.synth.lens).name == "US-12210142-B2-e9.zmx"
    assert cfg.synth.samples == samples
    assert cfg.model.variant == "doconv" and cfg.optim.betas == [0.9, 0.999] and cfg.optim.eps == 1e-8
    assert cfg.model.kwargs["highpass_domain"] == "linear" and cfg.optim.highpass_penalty == 1.0
    light = {"e9_bright.toml": ([0.0, 0.5], [0.25, 0.5], True), "e9_nonoise.toml": ([0.0, 2.0], [0.5, 2.0], False)}
    ev, scale, noise = light.get(name, ([0.0, 2.0], [0.5, 2.0], True))
    assert list(cfg.synth.exposure_ev) == ev and list(cfg.synth.noise_scale) == scale and cfg.synth.noise is noise
    assert Path(cfg.synth.out).name == name.removesuffix(".toml")   # each its own pairs


@pytest.mark.parametrize("placement", ["raw", "srgb", "linear"])
def test_placement_ablation_losses(pairs, tmp_path, placement):
    """The placement ablation's other models. "raw": the loss is on
    Model(J) against the target taken back to camera RGB (which round-trips
    through Process where nothing clipped); "srgb": on Model(Process(J)), the
    field channels passed through, against the sRGB target; "linear": on
    gamma(Model(Lum+CCM(J))), the sRGB curve written out here (IEC
    61966-2-1). Step 0's logged loss is recomputed by hand from the seeded
    model and the step's batch."""
    from restoration.nn.doconv import set_temperature
    from restoration.nn.network import build_model
    from restoration.synth.colour import process_after_slot, unprocess_after_slot
    from restoration.train.trainer import PairBank, batch_plan, crop_plan, split_pairs

    def proc(t, meta, inverse=False, **kw):
        f = unprocess_after_slot if inverse else process_after_slot
        return torch.cat([f(t[n:n + 1], m["ccm"], m["exposure_ev"], luma_weights=m["luma_weights"],
                            tone=m["tone"], white=m["white"], channel_axis=-3, **kw) for n, m in enumerate(meta)])

    def srgb(v):  # IEC 61966-2-1 encoding, clipped to [0, 1]
        v = v.clamp(0, 1)
        return torch.where(v <= 0.0031308, 12.92 * v, 1.055 * v.clamp(min=0.0031308) ** (1 / 2.4) - 0.055)

    assert unprocess_after_slot(np.full((1, 1, 3), 0.5), np.eye(3), 0.0)[0, 0, 0] == pytest.approx(0.21404, abs=1e-5)
    d = config_dict(pairs, tmp_path / "out")
    d["model"]["placement"] = placement
    assert main(["train", "--config", str(write_toml(tmp_path / "cfg.toml", d)), "-q"]) == 0
    log = json.loads((tmp_path / "out" / "train_log.json").read_text())

    train_ids, _, _ = split_pairs([pairs], 1, 2, 0)
    bank = PairBank.load([pairs], train_ids)
    idx = batch_plan(0, len(bank), 4, 0)
    x, y, meta = bank.batch(idx, crop_plan(0, bank, idx, 32, 4, 0), 32)
    x, y = torch.from_numpy(x), torch.from_numpy(y)
    torch.manual_seed(0)
    model = build_model("doconv", **TINY)
    set_temperature(model, 30.0)
    with torch.no_grad():
        if placement == "raw":
            target = proc(y, meta, inverse=True)
            inside = (y > 0.01) & (y < 0.99)
            assert torch.allclose(proc(target, meta)[inside], y[inside], atol=1e-4)
            by_hand = float(((model(x) - target) ** 2).mean())
        elif placement == "linear":
            lin = proc(x[:, :3], meta, gamma=False)
            by_hand = float((((srgb(model(torch.cat([lin, x[:, 3:]], 1)))) - y) ** 2).mean())
        else:
            by_hand = float(((model(torch.cat([proc(x[:, :3], meta), x[:, 3:]], 1)) - y) ** 2).mean())
    assert log["history"]["loss"][0] == pytest.approx(by_hand, rel=1e-5)
    ck = torch.load(tmp_path / "out" / "model.pt", weights_only=False)
    assert ck["metadata"]["domain"] == {"srgb": "display_rgb", "linear": "linear_rgb"}.get(placement, "camera_rgb")
    assert ck["metadata"]["training_placement"] == placement


def test_a_model_without_field_encoding_trains(pairs, tmp_path):
    """The no-field ablation takes RGB only: training feeds it the first
    three channels of the pairs (which carry the field too)."""
    d = config_dict(pairs, tmp_path / "out", steps=4, checkpoint_every=4)
    d["model"] = {"variant": "no_field", "kwargs": TINY}
    assert main(["train", "--config", str(write_toml(tmp_path / "cfg.toml", d)), "-q"]) == 0
    log = json.loads((tmp_path / "out" / "train_log.json").read_text())
    assert log["model"]["variant"] == "no_field" and np.isfinite(log["val"][-1]["psnr_db"])


def test_a_set_blurred_through_another_psf_window_is_refused(tmp_path):
    """ensure_data does not reuse a set whose PSF maps had another window
    (the synthesis's default went from 32 to 64 samples)."""
    from restoration.train.trainer import ensure_data
    from restoration.train.config import load_config

    cfg = load_config(write_toml(tmp_path / "c.toml", {
        "synth": {"out": str(tmp_path / "set"), "lens": "x.zmx", "pairs": 10},
        "run": {"out": str(tmp_path / "o")}}))
    (tmp_path / "set").mkdir()
    manifest = {"schema": "isp-synth/v1", "pairs": 10, "size": cfg.synth.size, "seed": 0,
                "lens": {"samples": 1, "tolerance_scale": 1.0, "path": "x.zmx"},
                "settings": {"tone": "none", "demosaic": "malvar2004", "blend": "bilinear", "noise": True,
                             "exposure_ev": [0.0, 2.0], "cct_k": [2850.0, 7500.0], "noise_scale": [0.5, 2.0]},
                "psf_map": {"n": 32, "pitch_um": 0.5, "grid": [15, 20]}, "shards": []}
    (tmp_path / "set" / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ConfigError, match="psf_n 32 ≠ 64"):
        ensure_data(cfg, executor=create_executor("serial"), log=lambda *a: None)


def test_split_seed_is_fixed_or_follows_the_run_seed(pairs, tmp_path):
    """data.split_seed fixes the seed of the held-out draw while run.seed
    changes; -1 (the default) follows run.seed as before."""
    from restoration.train.trainer import split_seed
    from restoration.train.config import load_config

    def cfg(run_seed, split=None):
        data = {"dirs": [str(pairs)], "val_latents": 1}
        if split is not None:
            data["split_seed"] = split
        return load_config(write_toml(tmp_path / f"c{run_seed}{split}.toml",
                                      {"data": data, "run": {"seed": run_seed}}))

    assert split_seed(cfg(3)) == 3 and split_seed(cfg(3, 0)) == 0 and split_seed(cfg(5, 0)) == 0


def test_highpass_penalty_shrinks_what_the_highpass_removes(pairs, tmp_path):
    """``optim.highpass_penalty`` adds the mean square of what the residual
    high-pass removes to the loss: trained with it (same seed, same
    batches), the model's residual carries far less of what the high-pass
    takes out again than without it. A negative weight is refused."""
    import torch

    from restoration.nn.checkpoint import load_model
    from restoration.nn.network import highpass_removed_power

    kw = {**TINY, "encoding": "sqrt", "highpass": 3, "highpass_domain": "linear"}
    power = {}
    for weight in (0.0, 100.0):
        d = config_dict(pairs, tmp_path / f"out{weight:g}", steps=12, checkpoint_every=12)
        d["model"] = {"variant": "doconv", "kwargs": kw}
        d["optim"]["highpass_penalty"] = weight
        assert main(["train", "--config", str(write_toml(tmp_path / f"c{weight:g}.toml", d)), "-q"]) == 0
        model = load_model(tmp_path / f"out{weight:g}" / "model.pt")
        model = (model[0] if isinstance(model, tuple) else model).train()
        torch.manual_seed(0)
        x = torch.rand(2, 5, 32, 32) * 0.5
        model(x)
        power[weight] = float(highpass_removed_power(model).detach())
    assert power[100.0] < power[0.0] / 3, power
    from restoration.train.config import TrainConfig

    with pytest.raises(ConfigError, match="highpass_penalty"):
        TrainConfig.from_dict({"data": {"dirs": ["x"]}, "optim": {"highpass_penalty": -1.0}})

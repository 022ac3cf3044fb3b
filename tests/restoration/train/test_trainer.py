"""Training of the correction network (restoration/train/trainer.py).

Kind: property. A tiny set is synthesised with the project's own synthesis
(a Gaussian PSF map that widens over the field, latent images, the phone
DNGs' colour metadata) and a tiny DOConv network is trained on it for a
few dozen steps through the command line. Checked: the loss falls; the
loss is the L2 of the pipeline's own stage functions applied to the
model's output (recomputed by hand at step 0, and changed when the gamma
stage's function is patched), also at the placement ablation's other
places; a resumed run repeats the uninterrupted run's losses; the saved
model reloads to the logged validation; the held-out split; every config
key documented; a set made with another PSF window is refused; the
high-pass penalty.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from tests.helpers import TINY_UNET_KW as TINY
from tests.helpers import write_toml

pytestmark = pytest.mark.property

torch = pytest.importorskip("torch")

from isp.cli.main import main
from isp.errors import ConfigError
from isp.runtime.executor import create_executor


STEPS = 24


def config_dict(data_dir, out, **run) -> dict:
    return {"data": {"dirs": [str(data_dir)], "crop": 32, "batch": 4, "val_latents": 1, "val_pairs": 2},
            "model": {"variant": "doconv", "kwargs": TINY},
            "optim": {"lr": 3e-3, "step_epochs": 4.0},
            "temperature": {"epochs": 2.0},
            "run": {"steps": STEPS, "seed": 0, "device": "cpu", "threads": 1, "checkpoint_every": 8,
                    "out": str(out), **run}}


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


# -- data split, config ------------------------------------------------------------------

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


def test_budget_steps_is_the_steps_that_fit_the_time_left():
    from restoration.train.trainer import budget_steps

    # 99 s (one checkpoint kept back) at 0.05 s per step plus 1 s per 1,000 steps' checkpoint
    assert budget_steps(55, 10_000, 100.0, 0.05, 1.0, 1000) == 55 + int(99.0 / 0.051)
    assert budget_steps(55, 500, 100.0, 0.05, 1.0, 1000) == 500          # run.steps stays the most
    assert budget_steps(55, 500, 0.5, 0.05, 1.0, 1000) == 56             # no time left: one more step


def test_a_time_budget_caps_the_steps_and_the_schedule(pairs, tmp_path):
    """``run.seconds``: a budget spent before the first step ends the run
    after it (the model is written); an ample one leaves ``run.steps`` as
    it is and logs the measured step time; a negative one is refused."""
    d = config_dict(pairs, tmp_path / "spent", steps=80, checkpoint_every=40)
    assert main(["train", "--config", str(write_toml(tmp_path / "a.toml", d)), "--seconds", "1e-6", "-q"]) == 0
    log = json.loads((tmp_path / "spent" / "train_log.json").read_text())
    assert len(log["history"]["step"]) == 1 and (tmp_path / "spent" / "model.pt").is_file()

    d = config_dict(pairs, tmp_path / "ample", steps=80, checkpoint_every=40, seconds=3600.0)
    assert main(["train", "--config", str(write_toml(tmp_path / "b.toml", d)), "-q"]) == 0
    log = json.loads((tmp_path / "ample" / "train_log.json").read_text())
    assert len(log["history"]["step"]) == 80
    assert log["time_budget"]["steps"] == 80 and 0 < log["time_budget"]["step_s"] < 10
    # the cosine schedule's horizon is the capped count
    from restoration.train.config import TrainConfig
    from restoration.train.trainer import learning_rate

    c = TrainConfig.from_dict({**d, "optim": {"lr": 1.0, "schedule": "cosine"}})
    assert learning_rate(c, 40, 1.0) == pytest.approx(0.5)

    d["run"]["seconds"] = -1.0
    assert main(["train", "--config", str(write_toml(tmp_path / "c.toml", d)), "-q"]) == 2

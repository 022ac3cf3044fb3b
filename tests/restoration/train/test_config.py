"""The training configuration (restoration/train/config.py).

Kind: property. Config errors name the key (and the valid ones); the
shipped configs (configs/e9_*.toml) parse and say what they train on.
"""

from __future__ import annotations

import json

import pytest
from tests.helpers import ROOT

from isp.errors import ConfigError

pytestmark = pytest.mark.property


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

"""Checkpoints (restoration/nn/checkpoint.py): a saved model reloads to
identical outputs, with its step, config and metadata, written atomically.

Kind: property.
"""

from __future__ import annotations

import numpy as np
import pytest
from tests.helpers import TINY_UNET_KW as TINY

pytestmark = pytest.mark.property

torch = pytest.importorskip("torch")


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

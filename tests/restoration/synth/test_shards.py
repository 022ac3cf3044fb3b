"""The shards of synthesised pairs (restoration/synth/shards.py).

Kind: property. Shards are deterministic (the workers don't matter, the
seed does) and traceable (hashes, manifest, provenance), load back as the
pairs written, and a changed shard is caught. PSF maps are small synthetic
ones, so no optics is computed.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from isp.runtime.executor import create_executor
from tests.helpers import data_file
from tests.helpers import field_gaussian_map as gaussian_map
from tests.helpers import make_synth_plan as make_plan

pytestmark = pytest.mark.property

S6 = ("raw", "SYNTHETIC_phone_S6meta_512x384.dng")


def test_shards_are_deterministic_and_traceable(tmp_path, cameras):
    from restoration.train.dataset import SynthPairs, verify
    from restoration.synth.pairs import generate
    from restoration.synth.shards import file_sha256

    m = gaussian_map()
    plan = make_plan(tmp_path, cameras, [m, gaussian_map(sigmas=np.full((3, 4, 3), 1.2))], seed=5)
    serial = create_executor("serial")
    a = generate(plan, tmp_path / "a", 6, shard_size=4, executor=serial)
    b = generate(plan, tmp_path / "b", 6, shard_size=4, executor=create_executor("processes", 2))
    c = generate(dataclasses.replace(plan, seed=6), tmp_path / "c", 6, shard_size=4, executor=serial)
    assert [s["sha256"] for s in a["shards"]] == [s["sha256"] for s in b["shards"]]   # workers don't matter
    assert a["data_sha256"] == b["data_sha256"] != c["data_sha256"]                   # the seed does
    assert (tmp_path / "a" / "manifest.json").read_bytes() == (tmp_path / "b" / "manifest.json").read_bytes()
    assert verify(tmp_path / "a") == []
    man = json.loads((tmp_path / "a" / "manifest.json").read_text())
    assert man["schema"] == "isp-synth/v1" and man["seed"] == 5 and man["pairs"] == 6
    assert man["cameras"][0]["sha256"] == file_sha256(data_file(*S6))
    assert man["process"]["stages"] == ["luminance", "ccm", "gamma"]

    pairs = SynthPairs(tmp_path / "a")
    assert len(pairs) == 6
    lens_used = set()
    for i in range(6):
        p = pairs[i]
        assert p["input"].shape == (32, 32, 3) and p["target"].dtype == np.float32
        assert p["index"] == i
        lens_used.add(int(p["lens"]))
        # field coordinates: pixel (i, j) of the pair is sensor pixel origin + (i, j)
        r0, c0 = (int(v) for v in p["origin"])
        assert 0 <= r0 <= 96 - 32 and 0 <= c0 <= 128 - 32
        np.testing.assert_allclose(p["fov"][0, 5, 7], (c0 + 7 + 0.5) / 128 * 2 - 1, atol=1e-6)
        np.testing.assert_allclose(p["fov"][1, 5, 7], (r0 + 5 + 0.5) / 96 * 2 - 1, atol=1e-6)
        out = pairs.process(p["input"], p)
        assert -10 * np.log10(np.mean((out - p["target"]) ** 2)) > 15     # blurred, noisy, but the same picture
    assert lens_used == {0, 1}                                            # both lenses ("multiple samples")

    # a changed shard is caught
    shard = tmp_path / "a" / man["shards"][0]["file"]
    raw = bytearray(shard.read_bytes())
    raw[-100] ^= 0xFF
    shard.write_bytes(bytes(raw))
    assert len(verify(tmp_path / "a")) == 1
    with pytest.raises(Exception, match="previous set"):
        generate(plan, tmp_path / "a", 2, executor=create_executor("serial"))

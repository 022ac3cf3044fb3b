"""Reading synthesised pairs (``isp synth`` output) for training: numpy
only, so a data loader can run without torch.

>>> pairs = SynthPairs("pairs/")                       # doctest: +SKIP
>>> p = pairs[0]                                       # doctest: +SKIP
>>> p["input"].shape, p["fov"].shape, p["target"].dtype  # doctest: +SKIP
((256, 256, 3), (2, 256, 256), dtype('float32'))

The loss of the paper (eq. 24) compares ``Process(Model(J))`` with the
target, where ``Process`` is :func:`restoration.synth.colour.process_after_slot`
with the pair's ``ccm`` and ``exposure_ev`` (and the manifest's luminance
``tone``/``white``); the same stage functions run on torch tensors.

Field coordinates: ``fov`` channel 0 = x, 1 = y, in [-1, 1] over the full
frame (:func:`modules.correction.field_coordinates`), as the correction
stage computes them at inference. Flipping or rotating a pair for
augmentation must move them with the pixels (DESIGN.md).
"""

from __future__ import annotations

import json
from collections import OrderedDict
from pathlib import Path

import numpy as np

from isp.errors import InputError

from restoration.synth.shards import SCHEMA, file_sha256

__all__ = ["SynthPairs", "load_shard", "read_manifest", "verify"]


def read_manifest(directory) -> dict:
    """The ``manifest.json`` of a synthesised set.

    Raises
    ------
    InputError
        No manifest, not JSON, or another schema.
    """
    path = Path(directory) / "manifest.json"
    try:
        m = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(path, "no manifest: not an `isp synth` output folder") from None
    except (OSError, ValueError) as e:
        raise InputError(path, f"unreadable manifest: {e}") from None
    if not isinstance(m, dict) or m.get("schema") != SCHEMA:
        raise InputError(path, f"schema {m.get('schema') if isinstance(m, dict) else None!r}, expected {SCHEMA!r}")
    return m


def load_shard(path) -> dict[str, np.ndarray]:
    """All arrays of one shard (see :mod:`restoration.synth.shards`)."""
    with np.load(Path(path), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def verify(directory) -> list[str]:
    """Problems with a set: missing shards or shards whose SHA-256 differs
    from the manifest's (empty list: the data is what the manifest says)."""
    d = Path(directory)
    m = read_manifest(d)
    out = []
    for s in m["shards"]:
        p = d / s["file"]
        if not p.is_file():
            out.append(f"{p}: missing")
        elif file_sha256(p) != s["sha256"]:
            out.append(f"{p}: SHA-256 differs from the manifest")
    return out


class SynthPairs:
    """Random access to the pairs of a synthesised set.

    Each item is a dict: ``input`` (H, W, 3) float32 camera RGB (the slot's
    input), ``target`` (H, W, 3) float32 sRGB in [0, 1], ``fov`` (2, H, W)
    float32, ``ccm`` (3, 3), ``exposure_ev``, ``luma_weights`` (3,),
    ``neutral`` (3,), ``origin`` (2,), ``index``, ``lens``, ``camera``,
    ``noise_profile`` (2,); for a set synthesised with a descriptor basis,
    ``descriptor`` (K, H, W) float32, the pair's lens descriptor at each
    pixel (:func:`isp.io.device.descriptor_map`).

    Parameters
    ----------
    directory : path
        An ``isp synth`` output folder.
    cache_shards : int
        Shards kept in memory (a shard of 100 pairs of 256² is ~60 MB);
        read shard by shard (shuffle within and across shards) to avoid
        reloading.
    """

    def __init__(self, directory, cache_shards: int = 2):
        self.directory = Path(directory)
        self.manifest = read_manifest(self.directory)
        self._starts = np.cumsum([0] + [s["pairs"] for s in self.manifest["shards"]])
        self._cache: OrderedDict = OrderedDict()
        self._keep = max(1, int(cache_shards))
        self.full_size = tuple(self.manifest["full_size"])
        lum = self.manifest["process"]["luminance"]
        self.tone, self.white = lum["tone"], float(lum["white"])
        dev = self.manifest.get("device")
        self.descriptors = None if dev is None else np.asarray(dev["descriptors"], np.float32)

    def __len__(self) -> int:
        return int(self._starts[-1])

    def _shard(self, k: int) -> dict:
        if k in self._cache:
            self._cache.move_to_end(k)
            return self._cache[k]
        data = load_shard(self.directory / self.manifest["shards"][k]["file"])
        self._cache[k] = data
        while len(self._cache) > self._keep:
            self._cache.popitem(last=False)
        return data

    def shard_of(self, i: int) -> tuple[int, int]:
        """(shard, position in it) of pair ``i``."""
        if not 0 <= i < len(self):
            raise IndexError(f"pair {i} out of range (0..{len(self) - 1})")
        k = int(np.searchsorted(self._starts, i, side="right") - 1)
        return k, int(i - self._starts[k])

    def __getitem__(self, i: int) -> dict:
        from modules.correction import field_coordinates

        k, j = self.shard_of(int(i))
        s = self._shard(k)
        x = s["input"][j].astype(np.float32)
        out = {"input": x, "target": s["target"][j].astype(np.float32) / np.float32(s["target_max"]),
               "fov": field_coordinates(x.shape[:2], tuple(int(v) for v in s["origin"][j]), self.full_size)}
        for key in ("ccm", "exposure_ev", "luma_weights", "neutral", "origin", "index", "lens", "camera",
                    "noise_profile", "cct"):
            out[key] = s[key][j]
        if self.descriptors is not None:
            from isp.io.device import descriptor_map

            o = [int(v) for v in s["origin"][j]]
            h, w = x.shape[:2]
            out["descriptor"] = descriptor_map(self.descriptors[int(s["lens"][j])], np.arange(h) + o[0],
                                               np.arange(w) + o[1], self.full_size)
        return out

    def process(self, x, item: dict, channel_axis: int = -1):
        """``Process`` of the loss for one pair's metadata (numpy or torch)."""
        from restoration.synth.colour import process_after_slot

        return process_after_slot(x, item["ccm"], float(item["exposure_ev"]), luma_weights=item["luma_weights"],
                                  tone=self.tone, white=self.white, channel_axis=channel_axis)

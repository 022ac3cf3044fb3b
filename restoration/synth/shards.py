"""Shards of synthesised pairs on disk, and the manifest that makes a
training set traceable to its inputs.

Layout of an output folder::

    DIR/manifest.json         schema "isp-synth/v1": seed, settings, lenses
                              (perturbations, PSF-map keys), cameras, latent
                              files (SHA-256), shards (SHA-256), data hash
    DIR/shard-00000.npz       pairs 0 .. shard_size−1
    DIR/shard-00001.npz       ...

Arrays of a shard (``K`` pairs of ``H × W``; written uncompressed by
:func:`numpy.savez`, whose zip entries carry a fixed date, so the same
pairs give the same bytes):

================  ==============  =============================================
key               shape, dtype    meaning
================  ==============  =============================================
``input``         (K,H,W,3) f16   camera RGB after demosaic (the slot's input
                                  ``J``), white-balanced, linear, 0..≈1/g
``target``        (K,H,W,3) u8    latent sRGB (u16 when a latent was 16-bit;
                                  ``target_max`` says which)
``target_max``    () f32          255 or 65535
``index``         (K,) i64        global pair index
``origin``        (K,2) i32       (row, col) of the crop's first pixel on the
                                  full frame (``full_size`` in the manifest);
                                  field coordinates follow from it
                                  (:func:`modules.correction.field_coordinates`)
``lens``          (K,) i16        index into ``manifest["lens"]["lenses"]``
``camera``        (K,) i16        index into ``manifest["cameras"]``
``cct``           (K,) f32        scene white, kelvin
``neutral``       (K,3) f32       camera neutral (G = 1); WB gains = 1/neutral
``ccm``           (K,3,3) f32     balanced camera RGB → linear sRGB
``exposure_ev``   (K,) f32        luminance stage's total exposure (gain 2^EV)
``luma_weights``  (K,3) f32       luminance weights (for a tone curve)
``noise_profile`` (K,2) f64       (S, O) used: variance S·x + O
``latent``        (K,) i32        index into ``manifest["latent"]["files"]``
``latent_box``    (K,4) i32       (row, col) of the crop in the latent image
                                  (before augmentation), rot90 count, flip
================  ==============  =============================================
"""

from __future__ import annotations

import hashlib
import io
import json
from pathlib import Path

import numpy as np

from isp.io.files import file_sha256

__all__ = ["SCHEMA", "SHARD_KEYS", "file_sha256", "shard_name", "write_manifest", "write_shard"]

SCHEMA = "isp-synth/v1"

#: per-pair arrays of a shard and their dtypes
SHARD_KEYS = {
    "input": np.float16, "index": np.int64, "origin": np.int32, "lens": np.int16, "camera": np.int16,
    "cct": np.float32, "neutral": np.float32, "ccm": np.float32, "exposure_ev": np.float32,
    "luma_weights": np.float32, "noise_profile": np.float64, "latent": np.int32, "latent_box": np.int32,
}


def shard_name(k: int) -> str:
    """File name of shard ``k``.

    >>> shard_name(3)
    'shard-00003.npz'
    """
    return f"shard-{int(k):05d}.npz"


def write_shard(path, pairs: list[dict], target_dtype=np.uint8) -> dict:
    """Write pairs (dicts of :func:`restoration.synth.pairs.make_pair`) as one
    ``.npz`` shard, atomically. Returns its manifest entry (file, pairs,
    first index, SHA-256)."""
    from isp.io.files import write_bytes_atomic

    arrays = {k: np.stack([np.asarray(p[k]) for p in pairs]).astype(t, copy=False) for k, t in SHARD_KEYS.items()}
    tmax = np.iinfo(target_dtype).max
    targets = []
    for p in pairs:
        t = np.asarray(p["target"])
        if t.dtype != target_dtype:  # an 8-bit latent in a 16-bit set: exact ×257
            t = t.astype(np.float64) * (tmax / np.iinfo(t.dtype).max)
            t = np.rint(t).astype(target_dtype)
        targets.append(t)
    arrays["target"] = np.stack(targets)
    arrays["target_max"] = np.float32(tmax)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    data = buf.getvalue()
    path = Path(path)
    write_bytes_atomic(path, data)
    return {"file": path.name, "pairs": len(pairs), "first_index": int(arrays["index"][0]),
            "sha256": hashlib.sha256(data).hexdigest()}


def data_sha256(shards: list[dict]) -> str:
    """One hash for the whole set: SHA-256 of the shards' hashes in order."""
    h = hashlib.sha256()
    for s in shards:
        h.update(bytes.fromhex(s["sha256"]))
    return h.hexdigest()


def write_manifest(directory, manifest: dict) -> Path:
    """Write ``manifest.json`` atomically (sorted keys, indented)."""
    from isp.io.files import write_bytes_atomic

    text = json.dumps(manifest, indent=2, sort_keys=True, default=_json_default) + "\n"
    return write_bytes_atomic(Path(directory) / "manifest.json", text.encode())


def _json_default(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, Path):
        return str(v)
    raise TypeError(f"not JSON-serialisable: {type(v).__name__}")

"""Fixtures the restoration tests share between folders: the evaluation's
small test set (``evaluate/`` and ``cli/test_eval.py``) and the training's
synthesised pairs (``train/`` and ``cli/test_train.py``).

Fixtures
--------
latent_dir
    Two 8-bit latent images with texture and edges.
eval_cameras
    The S6 phone DNG's colour metadata (a skip without ``../shared/data``).
make
    ``make(maps, baseline=..., **synth settings)`` → (plan, settings): an
    evaluation of 32-px crops of ``latent_dir`` through the PSF maps ``maps``
    (``None``: an ideal lens) on the :data:`tests.helpers.EVAL_FRAME` sensor.
pairs
    A synthesised training set: 24 pairs of 64², 3 latent images, one
    blurred lens.

All are module-wide.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from isp.runtime.executor import create_executor
from tests.helpers import EVAL_FRAME as FRAME
from tests.helpers import data_file, latent_pngs, widening_gaussian_map

S6 = ("raw", "SYNTHETIC_phone_S6meta_512x384.dng")
LG = ("raw", "skia_sample_1mp.dng")


# -- evaluation ------------------------------------------------------------------------

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
def eval_cameras():
    """The S6 phone DNG's colour metadata, the evaluation's one camera."""
    from restoration.synth.colour import read_camera

    return (read_camera(data_file(*S6)),)


@pytest.fixture(scope="module")
def make(latent_dir, eval_cameras):
    """``make(maps, baseline=..., **synth settings)`` → (plan, settings)."""
    from restoration.evaluate.rings import EvalSettings
    from restoration.synth.pairs import SynthPlan, SynthSettings, find_latents
    from restoration.synth.colour import colour_table

    def build(maps, baseline="wiener", **kw):
        es = EvalSettings(size=32, border=8, baseline=baseline, min_ring_pixels=64)
        st = SynthSettings(**{"size": es.work, "cct_steps": 4, "augment": False, **kw})
        lat = tuple(str(p) for p in find_latents(latent_dir))
        info = {"lens": {"lenses": [{"psf_map_key": f"k{i}", "proxy": False} for i in range(len(maps))]}}
        return SynthPlan(tuple(maps), eval_cameras, colour_table(list(eval_cameras), st.cct_k, st.cct_steps), lat,
                         FRAME, 0, st, (4e-4, 1e-6), info), es

    return build


# -- training ----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    """A synthesised set: 24 pairs of 64², 3 latent images, one blurred lens."""
    from restoration.synth.pairs import SynthPlan, SynthSettings, find_latents, generate
    from restoration.synth.colour import colour_table, read_camera

    tmp = tmp_path_factory.mktemp("train")
    cams = (read_camera(data_file(*S6)), read_camera(data_file(*LG)))
    st = SynthSettings(size=64, cct_steps=4)
    lat = tuple(str(p) for p in find_latents(latent_pngs(tmp / "latent")))
    plan = SynthPlan((widening_gaussian_map(),), cams, colour_table(list(cams), st.cct_k, st.cct_steps), lat, (96, 128),
                     0, st, (4e-4, 1e-6))
    generate(plan, tmp / "pairs", 24, shard_size=10, executor=create_executor("serial"))
    return tmp / "pairs"

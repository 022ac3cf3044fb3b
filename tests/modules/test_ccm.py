"""The ``ccm`` stage (modules.ccm), kind: property: a white-balanced
neutral leaves the stage neutral (on the profile colour-hdri documents and
on real files), no clipping, notes and registry, a user matrix, refusals
naming the domain, the source or the missing tags, identity without a
colour matrix, and the same result on torch as on numpy.

Files come from ``<repo>/../shared/data/raw``; tests that need them skip with
the reason when the folder is absent.
"""

from __future__ import annotations

import numpy as np
import pytest

from isp import ConfigError, Domain, Frame, InputError, create_stage
from isp.meta import CameraMeta
from modules.ccm import ColorCorrection, apply_ccm
from modules.common.dng_colour import camera_to_linear_srgb, camera_to_xyz_d50
from tests.helpers import DUAL_ILLUMINANT_DNGS, canon_meta, dng_colour_meta, reference

pytestmark = pytest.mark.property

CANON_NEUTRAL = tuple(reference("colour_hdri_canon_eos_5d_mark_ii.json")["as_shot_neutral"])


# --------------------------------------------------------------------------
# properties: the stage

def _balanced_frame(meta: CameraMeta, data: np.ndarray) -> Frame:
    return Frame(data.astype(np.float32), Domain.CAMERA_RGB, meta,
                 neutral=tuple(meta.as_shot_neutral))


def _stage_neutral_check(meta: CameraMeta, source: str):
    n = np.asarray(meta.as_shot_neutral, dtype=np.float64)
    raw = np.broadcast_to(n * 0.4, (4, 5, 3))       # a grey patch, unbalanced
    balanced = raw / n                               # the white-balance stage
    out = ColorCorrection(source=source)(_balanced_frame(meta, balanced))
    assert out.domain is Domain.LINEAR_RGB
    rgb = out.data.astype(np.float64)
    np.testing.assert_allclose(rgb - rgb.mean(axis=-1, keepdims=True), 0.0, atol=1e-5)
    return rgb


@pytest.mark.parametrize("source", ["auto", "color_matrix", "color_matrix_1",
                                    "color_matrix_2", "forward_matrix"])
def test_property_stage_keeps_neutral_neutral(source):
    """property: the as-shot neutral, white-balanced, leaves the stage with
    R = G = B (1e-5), at the level it came in (balanced 0.4 → 0.4)."""
    rgb = _stage_neutral_check(canon_meta(), source)
    np.testing.assert_allclose(rgb, 0.4, atol=1e-5)


@pytest.mark.parametrize("name, sources", [
    *[(f, ("auto", "color_matrix", "color_matrix_1", "color_matrix_2")) for f in DUAL_ILLUMINANT_DNGS],
    ("tinydng_colorchart.dng", ("auto", "color_matrix_1")),
])
def test_property_stage_keeps_neutral_neutral_on_files(name, sources):
    """property: the same on the sample files."""
    meta = dng_colour_meta(name)
    for source in sources:
        _stage_neutral_check(meta, source)


def test_property_stage_does_not_clip():
    """property: no clipping; values above 1 and below 0 pass through
    linearly."""
    meta = canon_meta()
    stage = ColorCorrection()
    bright = stage(_balanced_frame(meta, np.full((2, 2, 3), 4.0))).data
    assert np.all(bright > 1.0)
    np.testing.assert_allclose(bright, 4.0, atol=1e-4)
    rng = np.random.default_rng(0)
    x = rng.uniform(-0.5, 3.0, size=(3, 4, 3))
    m, _ = camera_to_linear_srgb(meta, applied_neutral=CANON_NEUTRAL)
    got = stage(_balanced_frame(meta, x)).data
    np.testing.assert_allclose(got, np.einsum("ij,hwj->hwi", m, x.astype(np.float32)), atol=1e-5)
    assert got.dtype == np.float32


def test_property_stage_notes_and_registry():
    """property: the history note names the source and the temperature; the
    entry point gives the stage by name, and parameters validate."""
    out = ColorCorrection()(_balanced_frame(canon_meta(), np.ones((2, 2, 3))))
    note = out.history[-1].note
    assert out.history[-1].stage == "ccm"
    assert "source auto" in note and "ForwardMatrix" in note and " K" in note
    stage = create_stage("ccm", source="color_matrix")
    assert isinstance(stage, ColorCorrection) and stage.source == "color_matrix"
    with pytest.raises(ConfigError):
        create_stage("ccm", source="bogus")


def test_property_stage_user_matrix():
    m = (1.0, 0.1, 0.0, 0.0, 1.0, 0.0, 0.0, 0.2, 1.0)
    out = ColorCorrection(matrix=m)(_balanced_frame(canon_meta(), np.ones((1, 1, 3))))
    np.testing.assert_allclose(out.data[0, 0], [1.1, 1.0, 1.2], atol=1e-6)
    assert out.history[-1].note == "user matrix"
    with pytest.raises(ValueError, match="9 numbers"):
        ColorCorrection(matrix=(1.0, 0.0, 0.0))


def test_property_stage_refuses_other_domains():
    frame = Frame(np.ones((2, 2), np.float32), Domain.RAW_LINEAR, canon_meta())
    with pytest.raises(ConfigError, match="camera_rgb"):
        ColorCorrection()(frame)


def test_property_unknown_source_lists_valid_names():
    for call in (lambda: camera_to_xyz_d50(canon_meta(), source="bogus"),
                 lambda: camera_to_linear_srgb(canon_meta(), source="bogus"),
                 lambda: ColorCorrection(source="bogus")):
        with pytest.raises(ValueError, match="valid: auto, color_matrix, color_matrix_1, "
                                             "color_matrix_2, forward_matrix"):
            call()


def test_property_missing_tags_for_source():
    meta = canon_meta(forward_matrix_1=None, forward_matrix_2=None)
    with pytest.raises(InputError, match="no ForwardMatrix"):
        camera_to_xyz_d50(meta, source="forward_matrix")
    with pytest.raises(InputError, match="no ColorMatrix2"):
        camera_to_xyz_d50(canon_meta(color_matrix_2=None), source="color_matrix_2")
    with pytest.raises(ValueError, match="not both"):
        camera_to_xyz_d50(canon_meta(), neutral=CANON_NEUTRAL, xy=(0.31, 0.33))
    with pytest.raises(ValueError, match="positive"):
        camera_to_xyz_d50(canon_meta(), neutral=(0.5, 0.0, 0.5))


def test_property_no_colour_matrix_is_identity():
    """property: without any ColorMatrix the stage treats camera RGB as
    linear sRGB and says so."""
    meta = CameraMeta(as_shot_neutral=(0.5, 1.0, 0.7))
    m, notes = camera_to_linear_srgb(meta, applied_neutral=(0.5, 1.0, 0.7))
    np.testing.assert_array_equal(m, np.eye(3))
    assert notes == ("no colour matrix: camera RGB treated as linear sRGB",)
    out = ColorCorrection()(Frame(np.ones((1, 1, 3), np.float32), Domain.CAMERA_RGB, meta))
    assert "no colour matrix" in out.history[-1].note


def test_property_torch_matches_numpy():
    """property: apply_ccm runs on torch (N, 3, H, W) and matches numpy."""
    torch = pytest.importorskip("torch")
    m, _ = camera_to_linear_srgb(canon_meta(), applied_neutral=CANON_NEUTRAL)
    x = np.random.default_rng(1).uniform(0, 2, size=(2, 5, 6, 3)).astype(np.float32)
    expected = np.stack([apply_ccm(img, m) for img in x])
    t = torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2)))
    got = apply_ccm(t, m, channel_axis=-3)
    assert got.shape == t.shape and got.dtype == torch.float32
    np.testing.assert_allclose(got.numpy().transpose(0, 2, 3, 1), expected, atol=1e-6)

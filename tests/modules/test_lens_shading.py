"""The lens-shading stage (modules.lens_shading), kind: property: the
vignette and gain-map opcodes applied where the file says, against the
opcodes' own evaluation (on the real three-plane GainMap blob too), and
cell-centred sampling."""

from __future__ import annotations

import numpy as np
import pytest

from isp import CFA, Domain, create_stage
from isp.opcodes import AreaSpec, FixVignetteRadial, GainMap, parse_opcode_list
from tests.helpers import data_file, make_frame

pytestmark = pytest.mark.property


def test_fix_vignette_radial_applied():
    op = FixVignetteRadial(k=(0.5, 0.0, 0.0, 0.0, 0.0), center_x=0.5, center_y=0.5)
    f = make_frame(np.ones((20, 30, 3)), Domain.RAW_LINEAR, opcodes={2: (op,)}, raw_size=(20, 30))
    out = create_stage("lens_shading")(f).data
    assert np.allclose(out[..., 0], op.evaluate(20, 30), atol=1e-6)
    assert out[10, 15, 0] == pytest.approx(1.0, abs=0.01) and out[0, 0, 0] > 1.4


def test_three_plane_gain_map_on_linear_rgb():
    """The real 3-plane GainMap blob (4056x3040 sensor): each colour plane of a
    3-channel frame takes its own map plane (reference: GainMap.evaluate)."""
    gm = parse_opcode_list(_blob())[0]
    h, w = 3040, 4056
    f = make_frame(np.ones((h // 8, w // 8, 3)), Domain.RAW_LINEAR, opcodes={2: (gm,)},
               active_area=(0, 0, h, w), default_crop=(0, 0, w // 8, h // 8))
    out = create_stage("lens_shading")(f).data
    rows, cols = np.arange(h // 8), np.arange(w // 8)
    for p in range(3):
        assert np.allclose(out[..., p], gm.evaluate(rows, cols, h, w, map_plane=p), atol=1e-6)
    assert not np.allclose(out[..., 0], out[..., 2])   # colour shading differs per plane


def _blob():
    return data_file("raw", "opcodes", "DngOpcodesEditor_GainMap.bin").read_bytes()


def test_opcodelist3_gain_map_applied_per_cfa_colour():
    """A 3-plane map in OpcodeList3 (after demosaic) applied before demosaic:
    every mosaic site takes the plane of its own colour."""
    gains = np.stack([np.full((2, 2), 2.0), np.full((2, 2), 3.0), np.full((2, 2), 5.0)], axis=2)
    gm = GainMap.spanning_image(gains.astype(np.float32), area=AreaSpec(0, 0, 4, 4, 0, 3, 1, 1))
    f = make_frame(np.ones((4, 4)), Domain.RAW_LINEAR, cfa=CFA.GRBG, opcodes={3: (gm,)})
    out = create_stage("lens_shading")(f).data
    assert np.allclose(out, np.tile([[3.0, 2.0], [5.0, 3.0]], (2, 2)))


def test_cell_centred_sampling_moves_map_points():
    # a map that is 1 at its first point and 3 at its last
    g = np.array([[1.0, 3.0]], np.float32)[:, :, None].repeat(2, axis=0)
    gm = GainMap.spanning_image(g, area=AreaSpec(0, 0, 1, 4, 0, 1, 1, 1))
    f = make_frame(np.ones((1, 4)), Domain.RAW_LINEAR, cfa=CFA.RGGB, opcodes={2: (gm,)})
    dng = create_stage("lens_shading")(f).data[0]
    cc = create_stage("lens_shading", sampling="cell_centred")(f).data[0]
    # pixel centres at 1/8, 3/8, 5/8, 7/8 of the width
    assert np.allclose(dng, 1 + 2 * np.array([1, 3, 5, 7]) / 8)
    assert np.allclose(cc, [1.0, 1.5, 2.5, 3.0])   # points at 1/4 and 3/4


@pytest.mark.parametrize("shape, strength", [((61, 83), 1.0), ((40, 30), 0.6)])
def test_four_phase_maps_equal_each_maps_own_evaluation(shape, strength):
    """Four per-CFA-phase GainMaps (the DngCreator layout, taken in one banded
    pass) give each site its own map's gain (GainMap.evaluate, the dense
    interpolation) to float32 rounding, odd sizes included; the notes
    report each map's gain range."""
    h, w = shape
    rng = np.random.default_rng(7)
    maps = tuple(GainMap.spanning_image(rng.uniform(1.0, 2.5, (5, 7)).astype(np.float32),
                                        area=AreaSpec(r, c, h, w, 0, 1, 2, 2))
                 for r in (0, 1) for c in (0, 1))
    data = rng.uniform(0.0, 1.0, shape).astype(np.float32)
    f = make_frame(data, Domain.RAW_LINEAR, cfa=CFA.RGGB, opcodes={2: maps}, raw_size=shape)
    out = create_stage("lens_shading", strength=strength)(f)
    notes = []
    for op in maps:
        r, c = op.area.top, op.area.left
        g = op.evaluate(np.arange(r, h, 2), np.arange(c, w, 2), h, w) ** np.float32(strength)
        np.testing.assert_allclose(out.data[r::2, c::2], data[r::2, c::2] * g, rtol=2e-6)
        notes.append(f"gains {g.min():.3f}-{g.max():.3f}")
    assert [n.split("GainMap ")[1] for n in out.history[-1].note.split("; ")] == notes

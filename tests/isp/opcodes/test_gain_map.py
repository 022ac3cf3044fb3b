"""The GainMap opcode (isp/opcodes/gain_map.py; DNG 1.7.1.0, chapter 7).

Each test is marked with its kind:

* published: facts published with the sample blob (the data README) or
  taken from the Adobe DNG SDK's code (re-implemented here as an
  independent scalar oracle of its interpolator);
* golden: facts of the project's own synthetic DNG (made by the project's
  DNG writer; regenerate it with that writer, the values are its inputs);
* property: evaluation over a full frame's CFA phase, describe().
"""

from __future__ import annotations

import json
import math
import struct

import numpy as np
import pytest

from isp.opcodes import (
    AreaSpec,
    GainMap,
    OpcodeError,
    parse_opcode_list,
    serialize_opcode_list,
)
from tests.helpers import gain_map_params as _gain_map_params
from tests.helpers import opcode_blob as _blob
from tests.helpers import opcode_header as _header
from tests.helpers import opcode_list as _list
from tests.helpers import raw_data_file as _data_file
from tests.helpers import tiff_tag as _tag


# ---------------------------------------------------------------------------
# published: the real sample blobs (facts from shared/data/README.md)

@pytest.mark.published
def test_published_gain_map_blob():
    """published: DngOpcodesEditor GainMap, 32x32x3, gains 0.994-2.81, for
    a 4056x3040 sensor."""
    blob = _blob("DngOpcodesEditor_GainMap.bin")
    (op,) = parse_opcode_list(blob)
    assert isinstance(op, GainMap) and op.name == "GainMap" and op.id == 9
    assert op.gains.shape == (32, 32, 3) and op.gains.dtype == np.float32
    assert (op.points_v, op.points_h, op.map_planes) == (32, 32, 3)
    assert (op.area.top, op.area.left, op.area.bottom, op.area.right) == (0, 0, 3040, 4056)
    assert (op.area.plane, op.area.planes) == (0, 3)
    assert round(float(op.gains.min()), 3) == 0.994
    assert round(float(op.gains.max()), 2) == 2.81
    assert op.version == (1, 3, 0, 0) and op.preview_skippable and not op.optional
    assert serialize_opcode_list([op]) == blob


@pytest.mark.golden
def test_golden_synthetic_s6_gain_maps():
    """golden: the synthetic S6 DNG's OpcodeList2 (written by the project):
    4 GainMaps, one per CFA phase, 32x32, pitch 2."""
    blob = _tag(_data_file("SYNTHETIC_phone_S6meta_512x384.dng"), subifd=False)
    ops = parse_opcode_list(blob)
    assert [type(op) for op in ops] == [GainMap] * 4
    assert [(op.area.top, op.area.left) for op in ops] == [(0, 0), (0, 1), (1, 0), (1, 1)]
    for op in ops:
        assert (op.area.row_pitch, op.area.col_pitch) == (2, 2)
        assert op.gains.shape == (32, 32, 1)
        assert (op.area.bottom, op.area.right) == (384, 512)
        rows, cols = op.pixels(384, 512)
        np.testing.assert_array_equal(rows, np.arange(op.area.top, 384, 2))
        np.testing.assert_array_equal(cols, np.arange(op.area.left, 512, 2))
        assert op.evaluate(rows, cols, 384, 512).shape == (192, 256)
    assert serialize_opcode_list(ops) == blob


# ---------------------------------------------------------------------------
# reference: GainMap interpolation against a scalar re-implementation of the
# SDK's dng_gain_map_interpolator (dng_gain_map.cpp), written from its code

def sdk_gain(gains, sv, sh, ov, oh, row, col, height, width, plane):
    """One pixel, as dng_gain_map::Interpolate does (bounds = the image):
    row interpolation in float32, column in float64 on float32 entries."""
    f32 = np.float32
    pv, ph = gains.shape[:2]
    if pv == 1:                                   # dng_gain_map::GetStream
        sv, ov = 1.0, 0.0
    if ph == 1:
        sh, oh = 1.0, 0.0
    row_f = ((1.0 / height) * (row + 0.5) - ov) / sv
    if row_f <= 0.0:
        r1 = r2 = 0
        fr = f32(0.0)
    elif row_f >= pv - 1:
        r1 = r2 = pv - 1
        fr = f32(0.0)
    else:
        r1 = int(row_f)
        r2 = r1 + 1
        fr = f32(row_f - r1)

    def entry(c):
        return f32(gains[r1, c, plane] * (f32(1.0) - fr) + gains[r2, c, plane] * fr)

    col_f = ((1.0 / width) * (col + 0.5) - oh) / sh
    if col_f <= 0.0:
        return entry(0)
    if col_f >= ph - 1:
        return entry(ph - 1)
    c = int(col_f)
    base = float(entry(c))
    delta = float(entry(c + 1)) - base
    return f32(base + delta * (col_f - c))


def sdk_row_incremental(gains, sv, sh, ov, oh, row, col0, cols, pitch, height, width, plane):
    """One row as dng_opcode_GainMap::ProcessArea walks it: the column
    interpolation is stepped incrementally in float32 (Increment /
    ResetColumn)."""
    f32 = np.float32
    pv, ph = gains.shape[:2]
    if pv == 1:
        sv, ov = 1.0, 0.0
    if ph == 1:
        sh, oh = 1.0, 0.0
    scale_h, offset_h = 1.0 / width, 0.5
    row_f = ((1.0 / height) * (row + 0.5) - ov) / sv
    if row_f <= 0.0:
        r1 = r2 = 0
        fr = f32(0.0)
    elif row_f >= pv - 1:
        r1 = r2 = pv - 1
        fr = f32(0.0)
    else:
        r1, fr = int(row_f), f32(row_f - int(row_f))
        r2 = r1 + 1

    def entry(c):
        return f32(gains[r1, c, plane] * (f32(1.0) - fr) + gains[r2, c, plane] * fr)

    state = {}

    def reset(column):
        col_f = (scale_h * (column + offset_h) - oh) / sh
        if col_f <= 0.0:
            state.update(base=entry(0), step=f32(0.0),
                         reset=math.ceil(oh / scale_h - offset_h))
        elif col_f >= ph - 1:
            state.update(base=entry(ph - 1), step=f32(0.0), reset=0x7FFFFFFF)
        else:
            c = int(col_f)
            base = float(entry(c))
            delta = float(entry(c + 1)) - base
            state.update(base=f32(base + delta * (col_f - c)),
                         step=f32(delta * scale_h / sh),
                         reset=math.ceil(((c + 1) * sh + oh) / scale_h - offset_h))
        state["index"] = f32(0.0)
        state["column"] = column

    reset(col0)
    out = []
    for _ in range(0, cols, pitch):
        out.append(f32(state["base"] + state["step"] * state["index"]))
        for _ in range(pitch):
            state["column"] += 1
            if state["column"] >= state["reset"]:
                reset(state["column"])
            else:
                state["index"] = f32(state["index"] + f32(1.0))
    return np.array(out, dtype=np.float32)


def _random_map(rng, pv, ph, planes, height, width):
    gains = rng.uniform(0.8, 3.0, size=(pv, ph, planes)).astype(np.float32)
    # a map that does not reach the image edges on either side, so both
    # clamps are exercised; origins differ from 0 and per axis
    ov, oh = rng.uniform(0.02, 0.15), rng.uniform(-0.1, 0.12)
    sv = rng.uniform(0.6, 0.95) / max(pv - 1, 1)
    sh = rng.uniform(0.6, 1.2) / max(ph - 1, 1)
    area = AreaSpec(0, 0, height, width, 0, planes)
    return GainMap(area, gains, sv, sh, ov, oh)


@pytest.mark.published
@pytest.mark.parametrize("seed, pv, ph, planes", [
    (0, 7, 11, 1), (1, 13, 5, 3), (2, 2, 2, 1), (3, 1, 9, 2), (4, 17, 1, 1), (5, 32, 32, 4)])
def test_reference_gain_map_matches_sdk_interpolator(seed, pv, ph, planes):
    """reference: GainMap.evaluate == the SDK's per-pixel interpolator
    (odd, non-square maps, origins != 0, one-point axes), |err| <= 1e-6."""
    rng = np.random.default_rng(seed)
    height, width = 97, 131
    op = _random_map(rng, pv, ph, planes, height, width)
    rows = np.sort(rng.choice(height, 23, replace=False))
    cols = np.sort(rng.choice(width, 29, replace=False))
    rows[0], cols[-1] = 0, width - 1                    # include the edges
    for plane in range(planes):
        got = op.evaluate(rows, cols, height, width, map_plane=plane)
        want = np.array([[sdk_gain(op.gains, op.spacing_v, op.spacing_h, op.origin_v,
                                   op.origin_h, r, c, height, width, plane)
                          for c in cols] for r in rows], dtype=np.float32)
        assert got.dtype == np.float32 and got.shape == (rows.size, cols.size)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)


@pytest.mark.published
@pytest.mark.parametrize("pitch, col0", [(1, 0), (2, 1)])
def test_reference_gain_map_matches_sdk_incremental_walk(pitch, col0):
    """reference: the SDK applies the map stepping the column interpolation
    incrementally in float32; evaluate agrees with that walk to 2e-6."""
    rng = np.random.default_rng(7)
    height, width = 61, 700
    op = _random_map(rng, 9, 13, 1, height, width)
    cols = np.arange(col0, width, pitch)
    for row in (0, 17, 60):
        want = sdk_row_incremental(op.gains, op.spacing_v, op.spacing_h, op.origin_v,
                                   op.origin_h, row, col0, width - col0, pitch, height,
                                   width, 0)
        got = op.evaluate([row], cols, height, width)[0]
        np.testing.assert_allclose(got, want, rtol=0, atol=2e-6)


@pytest.mark.published
def test_reference_gain_map_linear_field_is_exact():
    """reference (analytic): gains linear in the map position are
    reproduced exactly by bilinear interpolation inside the map."""
    pv, ph = 6, 9
    ov, oh, sv, sh = 0.1, 0.05, 0.15, 0.1
    pos_v = ov + sv * np.arange(pv)
    pos_h = oh + sh * np.arange(ph)
    a, b, c = 1.25, 0.75, -0.5
    gains = (a + b * pos_v[:, None] + c * pos_h[None, :])[:, :, None]
    op = GainMap(AreaSpec(0, 0, 0, 0), gains, sv, sh, ov, oh)
    height, width = 200, 300
    rows = np.arange(height)
    cols = np.arange(width)
    v = (rows + 0.5) / height
    h = (cols + 0.5) / width
    inside_v = (v >= pos_v[0]) & (v <= pos_v[-1])
    inside_h = (h >= pos_h[0]) & (h <= pos_h[-1])
    got = op.evaluate(rows[inside_v], cols[inside_h], height, width)
    want = a + b * v[inside_v][:, None] + c * h[inside_h][None, :]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
    # outside the map the edge values hold (no extrapolation)
    top = op.evaluate([0], cols[inside_h], height, width)[0]
    np.testing.assert_allclose(top, a + b * pos_v[0] + c * h[inside_h], atol=1e-6)


@pytest.mark.property
def test_gain_map_evaluate_full_frame_phase():
    """A 32x32 map evaluated for one CFA phase of a 16 MP frame: float32 of
    the phase's shape, equal to the map evaluated point by point. (Its speed
    is measured by benchmarks/pipeline.py, not here: a timed test fails on a
    loaded machine.)"""
    rng = np.random.default_rng(1)
    op = _random_map(rng, 32, 32, 1, 3000, 5328)
    rows, cols = np.arange(0, 3000, 2), np.arange(0, 5328, 2)
    g = op.evaluate(rows, cols, 3000, 5328)
    assert g.shape == (1500, 2664) and g.dtype == np.float32
    for r, c in ((0, 0), (711, 1999), (1499, 2663)):
        one = op.evaluate(rows[r:r + 1], cols[c:c + 1], 3000, 5328)
        assert one[0, 0] == pytest.approx(float(g[r, c]), abs=1e-6)


@pytest.mark.published
def test_gain_map_pixels_and_planes():
    """reference: area lattice clipped to the image; an empty area is the
    whole image (SDK dng_area_spec::Overlap); plane p uses map plane
    min(p, MapPlanes - 1)."""
    g = np.ones((2, 2, 2), np.float32)
    op = GainMap(AreaSpec(1, 2, 100, 7, 0, 3, 2, 3), g, 1.0, 1.0)
    rows, cols = op.pixels(10, 20)
    np.testing.assert_array_equal(rows, [1, 3, 5, 7, 9])
    np.testing.assert_array_equal(cols, [2, 5])
    assert [op.map_plane_for(p) for p in range(3)] == [0, 1, 1]
    whole = GainMap(AreaSpec(0, 0, 0, 0), g, 1.0, 1.0)
    rows, cols = whole.pixels(4, 3)
    np.testing.assert_array_equal(rows, np.arange(4))
    np.testing.assert_array_equal(cols, np.arange(3))
    outside = GainMap(AreaSpec(50, 50, 60, 60), g, 1.0, 1.0)
    assert [a.size for a in outside.pixels(10, 10)] == [0, 0]


@pytest.mark.published
def test_gain_map_one_point_axis_forces_spacing():
    """reference: with MapPointsV == 1 the SDK forces spacing 1 and origin
    0 on that axis, so a stored spacing of 0 is accepted and kept."""
    params = _gain_map_params(np.full((1, 3, 1), 2.0), 0.0, 0.5, 7.0, 0.0)
    blob = _list(_header(9, params))
    (op,) = parse_opcode_list(blob)
    assert (op.spacing_v, op.origin_v) == (0.0, 7.0)
    assert op.map_spacing == (1.0, 0.5) and op.map_origin == (0.0, 0.0)
    np.testing.assert_allclose(op.evaluate([0, 9], [0, 9], 10, 10), 2.0)
    assert serialize_opcode_list([op]) == blob


# ---------------------------------------------------------------------------
# errors and summaries

@pytest.mark.published
@pytest.mark.parametrize("gains, sv, points, match", [
    (np.array([[[1.0], [np.nan]]]), 0.5, None, "non-finite gain"),
    (np.ones((2, 2, 1)), 0.0, None, "spacing V is 0.0, must be > 0"),
    (np.ones((2, 2, 1)), -1.0, None, "spacing V is -1.0"),
    (np.ones((2, 2, 1)), math.inf, None, "spacing V is inf"),
    (np.ones((2, 2, 1)), 0.5, (0, 2, 1), "map has 0x2 points"),
])
def test_invalid_gain_maps_rejected(gains, sv, points, match):
    """reference: the SDK's ThrowBadFormat cases (and non-finite gains)."""
    params = _gain_map_params(gains, sv, 0.5, 0.0, 0.0)
    if points is not None:
        params = params[:32] + struct.pack(">II", *points[:2]) + params[40:72] \
            + struct.pack(">I", points[2]) + b""
    with pytest.raises(OpcodeError, match=match):
        parse_opcode_list(_list(_header(9, params)))


@pytest.mark.property
def test_describe_is_short_and_json_ready():
    """property: describe() summarises (gain range, never the array)."""
    g = np.linspace(0.5, 2.5, 64 * 64).reshape(64, 64, 1)
    d = GainMap.spanning_image(g, flags=3).describe()
    text = json.dumps(d)
    assert len(text) < 600
    assert d["name"] == "GainMap" and d["points"] == [64, 64] and d["map_planes"] == 1
    assert d["gain_min"] == 0.5 and d["gain_max"] == 2.5
    assert d["optional"] and d["preview_skippable"] and d["version"] == "1.3.0.0"


@pytest.mark.property
def test_gain_map_apply_multiplies_its_lattice_and_planes():
    """kind: property. A GainMap on one CFA phase (pitch 2) of a window at
    (1, 0) multiplies exactly those pixels by :meth:`GainMap.evaluate` at
    their image coordinates; image plane p of a 3-plane image takes map
    plane min(p, planes - 1)."""
    from isp.opcodes import OpcodeContext

    gm = GainMap(AreaSpec(1, 1, 20, 30, 0, 1, 2, 2), np.array([[[1.0], [2.0]], [[3.0], [4.0]]]),
                 0.5, 0.5, 0.25, 0.25)
    out = gm.apply(np.ones((9, 30), np.float32), OpcodeContext(2, (1, 0), (20, 30)))
    rows, cols = np.arange(1, 10, 2), np.arange(1, 30, 2)
    assert np.allclose(out[0::2, 1::2], gm.evaluate(rows, cols, 20, 30), atol=1e-6)
    assert np.all(out[1::2] == 1.0) and np.all(out[:, 0::2] == 1.0)
    two = GainMap(AreaSpec(0, 0, 0, 0, 0, 3), np.stack([np.full((2, 2), 2.0), np.full((2, 2), 3.0)], -1))
    rgb = two.apply(np.ones((4, 4, 3), np.float32), OpcodeContext(3))
    assert rgb[0, 0].tolist() == [2.0, 3.0, 3.0]

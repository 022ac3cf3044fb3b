"""Tests of isp.opcodes: DNG opcode lists (DNG 1.7.1.0, chapter 7).

Each test is marked with its kind:

* published: facts published with the sample blobs (the data
  README) or taken from the Adobe DNG SDK's code (re-implemented here as an
  independent scalar oracle);
* golden: facts of the project's own synthetic DNG (made by the project's
  DNG writer; regenerate it with that writer, the values are its inputs);
* property: round trips, robustness against corrupt input, invariants.
"""

from __future__ import annotations

import json
import math
import random
import struct
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from isp.errors import IspError
from isp.opcodes import (
    OPCODE_NAMES, AreaSpec, DeltaPerColumn, DeltaPerRow, FixBadPixelsConstant,
    FixBadPixelsList, FixVignetteRadial, GainMap, MapPolynomial, MapTable, Opcode,
    OpcodeError, ScalePerColumn, ScalePerRow, TrimBounds, UnknownOpcode, WarpFisheye,
    WarpRectilinear, WarpRectilinear2, parse_opcode_list, serialize_opcode_list,
)

CLASSES = {1: WarpRectilinear, 2: WarpFisheye, 3: FixVignetteRadial, 4: FixBadPixelsConstant,
           5: FixBadPixelsList, 6: TrimBounds, 7: MapTable, 8: MapPolynomial, 9: GainMap,
           10: DeltaPerRow, 11: DeltaPerColumn, 12: ScalePerRow, 13: ScalePerColumn,
           14: WarpRectilinear2}

from tests.helpers import DATA  # noqa: E402
RAW = DATA / "raw"
BLOBS = ("DngOpcodesEditor_GainMap.bin", "DngOpcodesEditor_FixVignetteRadial.bin",
         "DngOpcodesEditor_WarpRectilinear.bin")


def _data_file(*parts) -> Path:
    path = RAW.joinpath(*parts)
    if not path.exists():
        pytest.skip(f"shared test data absent: {path} (see shared/data/README.md)")
    return path


def _blob(name: str) -> bytes:
    return _data_file("opcodes", name).read_bytes()


def _tag(path: Path, subifd: bool, name: str = "OpcodeList2") -> bytes:
    tifffile = pytest.importorskip("tifffile")
    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0].pages[0] if subifd else tif.pages[0]
        return page.tags[name].value


def _header(opcode_id: int, params: bytes, version=(1, 3, 0, 0), flags=0) -> bytes:
    return struct.pack(">I4BII", opcode_id, *version, flags, len(params)) + params


def _list(*opcodes: bytes) -> bytes:
    return struct.pack(">I", len(opcodes)) + b"".join(opcodes)


def _area(t=0, l=0, b=8, r=8, plane=0, planes=1, rp=1, cp=1) -> bytes:
    return struct.pack(">8I", t, l, b, r, plane, planes, rp, cp)


def _gain_map_params(gains, sv, sh, ov, oh, area=None) -> bytes:
    g = np.asarray(gains, dtype=np.float32)
    pv, ph, planes = g.shape
    return ((area or _area()) + struct.pack(">II4dI", pv, ph, sv, sh, ov, oh, planes)
            + g.astype(">f4").tobytes())


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


@pytest.mark.published
def test_published_vignette_blob():
    """published: DngOpcodesEditor FixVignetteRadial (k0 = 1, centred)."""
    blob = _blob("DngOpcodesEditor_FixVignetteRadial.bin")
    (op,) = parse_opcode_list(blob)
    assert isinstance(op, FixVignetteRadial)
    assert op.k == (1.0, 0.0, 0.0, 0.0, 0.0) and (op.center_x, op.center_y) == (0.5, 0.5)
    # the editor writes the version bytes reversed (00 00 01 03): kept as stored
    assert op.version == (0, 0, 1, 3)
    assert serialize_opcode_list([op]) == blob
    g = op.evaluate(300, 400)
    # centred, k0 = 1: g = 1 + r^2, r = 1 at the corners (pixel edges)
    assert g.shape == (300, 400) and g.dtype == np.float32
    assert g.min() == pytest.approx(1.0, abs=1e-4) and g.max() == pytest.approx(2.0, abs=1e-2)


@pytest.mark.published
def test_published_warp_blob():
    """published: DngOpcodesEditor WarpRectilinear, one plane."""
    blob = _blob("DngOpcodesEditor_WarpRectilinear.bin")
    (op,) = parse_opcode_list(blob)
    assert isinstance(op, WarpRectilinear) and op.planes == 1
    assert op.radial == ((0.75, 0.25, 0.0, 0.0),) and op.tangential == ((0.0, 0.0),)
    assert (op.center_x, op.center_y) == (0.5, 0.5)
    assert serialize_opcode_list([op]) == blob


@pytest.mark.published
def test_published_skia_map_polynomials():
    """published: the LG G4 lossy linear DNG's OpcodeList2 holds 3
    MapPolynomial (degree 3) on planes 0, 1, 2."""
    blob = _tag(_data_file("skia_sample_1mp.dng"), subifd=True)
    ops = parse_opcode_list(blob)
    assert [type(op) for op in ops] == [MapPolynomial] * 3
    assert [op.degree for op in ops] == [3, 3, 3]
    assert [op.area.plane for op in ops] == [0, 1, 2]
    assert serialize_opcode_list(ops) == blob
    for op in ops:   # a linearisation curve: increasing on 0..1
        y = op.evaluate(np.linspace(0, 1, 101))
        assert np.all(np.diff(y) > 0)


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
# reference: vignette, polynomial, table


@pytest.mark.published
def test_reference_vignette_formula():
    """reference: FixVignetteRadial.evaluate against the SDK's Prepare
    (centre Lerp over the image, radius to the farthest corner, pixel
    centres) evaluated pixel by pixel."""
    k = (0.3, -0.1, 0.05, 0.02, -0.01)
    op = FixVignetteRadial(k, center_x=0.3, center_y=0.6)
    height, width, par = 40, 70, 1.25
    got = op.evaluate(height, width, pixel_aspect_ratio=par)
    s = 1.0 / par
    cy, cx = 0.6 * height, 0.3 * width
    radius = math.hypot(max(cy, height - cy) * s, max(cx, width - cx))
    for i, j in [(0, 0), (39, 69), (24, 21), (5, 60), (39, 0)]:
        r2 = min(1.0, (((i + 0.5 - cy) * s) ** 2 + (j + 0.5 - cx) ** 2) / radius ** 2)
        want = 1.0 + sum(kk * r2 ** (n + 1) for n, kk in enumerate(k))
        assert got[i, j] == pytest.approx(want, abs=2e-6)


@pytest.mark.published
def test_reference_map_polynomial_and_table():
    """reference: MapPolynomial is sum c_i x^i (np.polynomial); MapTable
    looks up the nearest 16-bit code and repeats its last entry."""
    area = AreaSpec(0, 0, 0, 0)
    c = (0.01, 0.9, -0.2, 0.3)
    poly = MapPolynomial(area, c)
    x = np.linspace(-0.1, 1.1, 57).reshape(3, 19)
    np.testing.assert_allclose(poly.evaluate(x), np.polynomial.polynomial.polyval(x, c),
                               rtol=1e-6)
    table = MapTable(area, np.arange(0, 2000, 2, dtype=np.uint16))     # 1000 entries
    np.testing.assert_array_equal(table.lookup([0, 5, 999, 1000, 65535]),
                                  [0, 10, 1998, 1998, 1998])
    np.testing.assert_allclose(table.evaluate([0.0, 5 / 65535, 1.0, 2.0]),
                               np.array([0, 10, 1998, 1998]) / 65535, rtol=1e-6)


# ---------------------------------------------------------------------------
# errors: clear one-line messages naming the opcode


@pytest.mark.property
def test_error_names_opcode_and_byte_counts():
    """property: a parameter byte count that disagrees with the content is
    an error naming index, opcode and both counts."""
    ok = _header(6, struct.pack(">4I", 0, 0, 2, 2))
    gm = _gain_map_params(np.ones((32, 32, 1)), 0.03, 0.03, 0.0, 0.0)
    bad = struct.pack(">I4BII", 9, 1, 3, 0, 0, 0, len(gm) - 4) + gm[:-4]
    with pytest.raises(OpcodeError) as info:
        parse_opcode_list(_list(ok, ok, bad))
    msg = str(info.value)
    assert msg == ("opcode #2 GainMap: declares 4168 parameter bytes but needs 4172 "
                   "for 32x32x1 gains")
    assert info.value.index == 2 and info.value.name == "GainMap"
    assert isinstance(info.value, ValueError) and isinstance(info.value, IspError)


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
def test_list_level_errors():
    """property: truncated, oversized and trailing lists; huge counts fail
    fast, before any allocation."""
    with pytest.raises(OpcodeError, match="needs at least 4"):
        parse_opcode_list(b"\x00\x00")
    with pytest.raises(OpcodeError, match="declares 4294967295 opcodes"):
        parse_opcode_list(b"\xff\xff\xff\xff" + bytes(64))
    with pytest.raises(OpcodeError, match="max_opcodes=2"):
        parse_opcode_list(_list(*[_header(6, struct.pack(">4I", 0, 0, 1, 1))] * 3),
                          max_opcodes=2)
    with pytest.raises(OpcodeError, match="3 bytes left after the last of 0 opcodes"):
        parse_opcode_list(bytes(7))
    huge = struct.pack(">I4BII", 9, 1, 3, 0, 0, 0, 0xFFFFFFFF) + bytes(80)
    with pytest.raises(OpcodeError, match=r"opcode #0 GainMap: declares 4294967295"):
        parse_opcode_list(_list(huge))
    with pytest.raises(OpcodeError, match="expected bytes"):
        parse_opcode_list(12)
    assert parse_opcode_list(bytes(4)) == ()
    assert parse_opcode_list(np.frombuffer(bytes(4), np.uint8)) == ()


@pytest.mark.property
def test_unknown_opcodes_are_listed_and_round_trip():
    """property: vendor/unknown IDs are kept with their bytes, never dropped."""
    blob = _list(_header(0x8000_0001, b"vendor data", flags=1),
                 _header(6, struct.pack(">4I", 1, 2, 3, 4)),
                 _header(0, b""))
    ops = parse_opcode_list(blob)
    assert [op.name for op in ops] == ["Unknown(2147483649)", "TrimBounds", "Unknown(0)"]
    assert ops[0].data == b"vendor data" and ops[0].optional
    assert serialize_opcode_list(ops) == blob
    assert ops[0].describe()["parameter_bytes"] == 11


@pytest.mark.property
def test_construction_validates():
    """property: invalid opcodes cannot be built either (same messages)."""
    with pytest.raises(OpcodeError, match=r"^GainMap: 1 non-finite gain\(s\)"):
        GainMap(AreaSpec(0, 0, 4, 4), [[[1.0], [math.inf]]], 0.5, 0.5)
    with pytest.raises(OpcodeError, match="area planes is 0"):
        AreaSpec(0, 0, 4, 4, planes=0)
    with pytest.raises(OpcodeError, match="is empty .* pitch is 2x2"):
        AreaSpec(0, 0, 0, 0, row_pitch=2, col_pitch=2)
    with pytest.raises(OpcodeError, match="optical centre"):
        FixVignetteRadial((0, 0, 0, 0, 0), center_x=1.5)
    with pytest.raises(OpcodeError, match="degree 0..8"):
        MapPolynomial(AreaSpec(0, 0, 1, 1), [0.0] * 10)
    with pytest.raises(OpcodeError, match="3 values but the area needs 2"):
        DeltaPerRow(AreaSpec(0, 0, 4, 4, row_pitch=2), [0.0, 0.0, 0.0])
    with pytest.raises(OpcodeError, match="bounds .* are empty"):
        TrimBounds(5, 0, 5, 10)


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


# ---------------------------------------------------------------------------
# property: independently encoded lists of every opcode type round-trip

raw64 = st.binary(min_size=8, max_size=8)          # any float64 bit pattern
raw32 = st.binary(min_size=4, max_size=4)          # any float32 bit pattern
u32 = st.integers(0, 0xFFFFFFFF)
unit = st.floats(0.0, 1.0).map(lambda x: struct.pack(">d", x))


@st.composite
def area_specs(draw):
    top, left = draw(st.integers(0, 9)), draw(st.integers(0, 9))
    h, w = draw(st.integers(0, 20)), draw(st.integers(0, 20))
    empty = h == 0 or w == 0
    rp = 1 if empty else draw(st.integers(1, 4))
    cp = 1 if empty else draw(st.integers(1, 4))
    plane, planes = draw(st.integers(0, 3)), draw(st.integers(1, 4))
    return (top, left, top + h, left + w, plane, planes, rp, cp)


def _area_bytes(a) -> bytes:
    return struct.pack(">8I", *a)


@st.composite
def opcode_params(draw):
    """(opcode ID, parameter bytes) for a valid opcode, encoded here from
    the layouts in DNG 1.7.1.0 ch. 7 (independently of isp.opcodes)."""
    oid = draw(st.sampled_from(sorted(OPCODE_NAMES) + [0, 15, 0xDEADBEEF]))
    if oid in (1, 2, 14):
        n = draw(st.integers(1, 4))
        per = {1: 6, 2: 4, 14: 15 + 2}[oid]
        out = struct.pack(">I", n)
        for _ in range(n):
            out += b"".join(draw(st.lists(raw64, min_size=per, max_size=per)))
            if oid == 14:
                lo, hi = draw(st.floats(0.0, 0.4)), draw(st.floats(0.5, 1.0))
                out += struct.pack(">2d", lo, hi)
        out += draw(unit) + draw(unit)
        if oid == 14:
            out += struct.pack(">I", draw(u32))
        return oid, out
    if oid == 3:
        return oid, b"".join(draw(st.lists(raw64, min_size=5, max_size=5))) \
            + draw(unit) + draw(unit)
    if oid == 4:
        return oid, struct.pack(">II", draw(u32), draw(u32))
    if oid == 5:
        p, r = draw(st.integers(0, 5)), draw(st.integers(0, 3))
        vals = draw(st.lists(u32, min_size=2 * p + 4 * r, max_size=2 * p + 4 * r))
        return oid, struct.pack(f">III{len(vals)}I", draw(u32), p, r, *vals)
    if oid == 6:
        t, l = draw(st.integers(0, 100)), draw(st.integers(0, 100))
        return oid, struct.pack(">4I", t, l, t + draw(st.integers(1, 50)),
                                l + draw(st.integers(1, 50)))
    if oid == 7:
        n = draw(st.integers(1, 40))
        table = draw(st.lists(st.integers(0, 0xFFFF), min_size=n, max_size=n))
        return oid, _area_bytes(draw(area_specs())) + struct.pack(f">I{n}H", n, *table)
    if oid == 8:
        d = draw(st.integers(0, 8))
        return oid, _area_bytes(draw(area_specs())) + struct.pack(">I", d) \
            + b"".join(draw(st.lists(raw64, min_size=d + 1, max_size=d + 1)))
    if oid == 9:
        pv, ph, planes = draw(st.integers(1, 5)), draw(st.integers(1, 5)), draw(st.integers(1, 3))
        gains = draw(st.lists(st.floats(width=32, allow_nan=False, allow_infinity=False),
                              min_size=pv * ph * planes, max_size=pv * ph * planes))
        sv, sh = draw(st.floats(1e-6, 10.0)), draw(st.floats(1e-6, 10.0))
        ov, oh = draw(st.floats(-10.0, 10.0)), draw(st.floats(-10.0, 10.0))
        return oid, _area_bytes(draw(area_specs())) \
            + struct.pack(f">II4dI{len(gains)}f", pv, ph, sv, sh, ov, oh, planes, *gains)
    if oid in (10, 11, 12, 13):
        a = draw(area_specs())
        span, pitch = (a[2] - a[0], a[6]) if oid in (10, 12) else (a[3] - a[1], a[7])
        if a[2] <= a[0] or a[3] <= a[1]:
            span = 0
        n = -(-span // pitch)
        return oid, _area_bytes(a) + struct.pack(">I", n) \
            + b"".join(draw(st.lists(raw32, min_size=n, max_size=n)))
    return oid, draw(st.binary(max_size=40))


@st.composite
def opcode_lists(draw):
    items = draw(st.lists(opcode_params(), max_size=4))
    parts = [_header(oid, params, version=tuple(draw(st.lists(st.integers(0, 255),
                                                              min_size=4, max_size=4))),
                     flags=draw(u32))
             for oid, params in items]
    return items, _list(*parts)


@pytest.mark.property
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(opcode_lists())
def test_property_round_trip_every_opcode_type(case):
    """property: serialize(parse(x)) == x, byte for byte (NaN payloads,
    -0.0, reversed version bytes included), for lists of every type."""
    items, blob = case
    ops = parse_opcode_list(blob)
    assert [op.id for op in ops] == [oid for oid, _ in items]
    for op, (oid, params) in zip(ops, items):
        assert isinstance(op, Opcode)
        assert type(op) is CLASSES.get(oid, UnknownOpcode)
        assert op.to_bytes()[16:] == params
        json.dumps(op.describe())
    assert serialize_opcode_list(ops) == blob
    assert serialize_opcode_list(parse_opcode_list(serialize_opcode_list(ops))) == blob


# ---------------------------------------------------------------------------
# property: corrupt input raises OpcodeError and nothing else


def _sample_blobs() -> list[bytes]:
    """The real blobs where present, else synthetic ones of each kind."""
    out = [(RAW / "opcodes" / n).read_bytes() for n in BLOBS if (RAW / "opcodes" / n).exists()]
    out.append(_list(_header(9, _gain_map_params(np.ones((3, 4, 2)), 0.5, 0.3, 0.0, 0.1)),
                     _header(10, _area(0, 0, 4, 4, rp=2) + struct.pack(">I2f", 2, 0.1, 0.2)),
                     _header(7, _area() + struct.pack(">I3H", 3, 1, 2, 3)),
                     _header(5, struct.pack(">III2I4I", 1, 1, 1, 5, 6, 0, 0, 2, 2)),
                     _header(14, struct.pack(">I19d2dI", 1, *([0.0] * 17), 0.0, 1.0,
                                             0.5, 0.5, 0))))
    return out


def _parse_only_opcode_error(data: bytes) -> None:
    try:
        ops = parse_opcode_list(data)
    except OpcodeError as err:
        assert "\n" not in str(err)
        return
    for op in ops:      # whatever parsed must describe and re-encode
        json.dumps(op.describe())
        op.to_bytes()


@pytest.mark.property
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(
    st.binary(max_size=200),
    st.tuples(st.sampled_from(range(8)), st.integers(0, 2**31), st.integers(0, 255),
              st.sampled_from(["flip", "set", "truncate", "u32"]), u32),
))
def test_property_corrupt_input_raises_only_opcode_error(case):
    """property: random bytes and mutated real blobs parse or raise
    OpcodeError, nothing else."""
    if isinstance(case, bytes):
        _parse_only_opcode_error(case)
        return
    which, pos, byte, kind, value = case
    blobs = _sample_blobs()
    data = bytearray(blobs[which % len(blobs)])
    i = pos % len(data)
    if kind == "flip":
        data[i] ^= 1 << (byte % 8)
    elif kind == "set":
        data[i] = byte
    elif kind == "truncate":
        del data[i:]
    else:
        j = (i // 4) * 4
        data[j:j + 4] = struct.pack(">I", value)
    _parse_only_opcode_error(bytes(data))


def _mutate(rng: random.Random, data: bytes) -> bytes:
    d = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        if not d:
            break
        kind = rng.random()
        i = rng.randrange(len(d))
        if kind < 0.35:
            d[i] ^= 1 << rng.randrange(8)
        elif kind < 0.5:
            del d[i:]
        elif kind < 0.8:               # a count/size field set to a huge value
            j = (i // 4) * 4
            d[j:j + 4] = struct.pack(">I", rng.choice(
                [0xFFFFFFFF, 0x7FFFFFFF, 0x80000000, 0x10000, rng.randrange(2**32), 0]))
        elif kind < 0.9:
            d[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
        else:
            j = (i // 8) * 8           # a float64 field set to NaN/inf/0/-0
            d[j:j + 8] = struct.pack(">d", rng.choice([math.nan, math.inf, -math.inf,
                                                       0.0, -0.0, 1e308]))
    return bytes(d)


@pytest.mark.property
@pytest.mark.slow
def test_slow_fuzz_10000_mutations():
    """property: 10,000 mutations of the real blobs (bit flips, truncations,
    huge counts, insertions, NaN/inf floats) raise only OpcodeError, each
    parse under 0.5 s."""
    rng = random.Random(20240611)
    blobs = _sample_blobs()
    worst = 0.0
    for n in range(10_000):
        data = _mutate(rng, rng.choice(blobs))
        t0 = time.perf_counter()
        _parse_only_opcode_error(data)
        dt = time.perf_counter() - t0
        worst = max(worst, dt)
        assert dt < 0.5, f"mutation {n} took {dt:.2f} s"

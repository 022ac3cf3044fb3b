"""Opcode lists (isp/opcodes/lists.py; DNG 1.7.1.0, chapter 7): parsing
and serialising.

Kind: property (each test marked): independently encoded lists of every
opcode type round-trip byte for byte; list-level and per-opcode errors are
one line naming the opcode; corrupt input (random bytes, mutated real
blobs) raises OpcodeError and nothing else.
"""

from __future__ import annotations

import json
import math
import random
import struct
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from isp.errors import IspError
from isp.opcodes import (
    OPCODE_NAMES,
    DeltaPerColumn,
    DeltaPerRow,
    FixBadPixelsConstant,
    FixBadPixelsList,
    FixVignetteRadial,
    GainMap,
    MapPolynomial,
    MapTable,
    Opcode,
    OpcodeError,
    ScalePerColumn,
    ScalePerRow,
    TrimBounds,
    UnknownOpcode,
    WarpFisheye,
    WarpRectilinear,
    WarpRectilinear2,
    parse_opcode_list,
    serialize_opcode_list,
)
from tests.helpers import DATA
from tests.helpers import gain_map_params as _gain_map_params
from tests.helpers import opcode_area as _area
from tests.helpers import opcode_header as _header
from tests.helpers import opcode_list as _list


RAW = DATA / "raw"
BLOBS = ("DngOpcodesEditor_GainMap.bin", "DngOpcodesEditor_FixVignetteRadial.bin",
         "DngOpcodesEditor_WarpRectilinear.bin")


CLASSES = {1: WarpRectilinear, 2: WarpFisheye, 3: FixVignetteRadial, 4: FixBadPixelsConstant,
           5: FixBadPixelsList, 6: TrimBounds, 7: MapTable, 8: MapPolynomial, 9: GainMap,
           10: DeltaPerRow, 11: DeltaPerColumn, 12: ScalePerRow, 13: ScalePerColumn,
           14: WarpRectilinear2}


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

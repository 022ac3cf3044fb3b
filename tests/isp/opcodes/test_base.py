"""The opcode base classes (isp/opcodes/base.py): area specs and opcodes
validate on construction with the parser's messages; unknown (vendor)
opcodes keep their bytes.

Kind: property (each test marked).
"""

from __future__ import annotations

import math
import struct

import pytest

from isp.opcodes import (
    AreaSpec,
    DeltaPerRow,
    FixVignetteRadial,
    GainMap,
    MapPolynomial,
    OpcodeError,
    TrimBounds,
    parse_opcode_list,
    serialize_opcode_list,
)
from tests.helpers import opcode_header as _header
from tests.helpers import opcode_list as _list


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
def test_area_window_follows_the_lattice_from_the_area_origin():
    """The SDK's dng_area_spec::Overlap: a window starting inside the area
    starts at the first lattice row/column at or after its first pixel."""
    from isp.opcodes import OpcodeContext

    area = AreaSpec(1, 2, 20, 20, row_pitch=3, col_pitch=2)
    assert area.window(OpcodeContext(2, origin=(5, 5)), (10, 10)) == (slice(2, 10, 3),
                                                                     slice(1, 10, 2))
    assert area.window(OpcodeContext(2, origin=(30, 0)), (4, 4)) is None
    assert AreaSpec(0, 0, 0, 0).window(OpcodeContext(2, origin=(7, 7)), (3, 4)) == (
        slice(0, 3, 1), slice(0, 4, 1))
    assert list(AreaSpec(0, 0, 0, 0, plane=1, planes=5).plane_range(3)) == [1, 2]


@pytest.mark.property
def test_opcode_context_checks_and_sizes():
    from isp.opcodes import OpcodeContext

    assert OpcodeContext.for_stage(1).code_max == 65535.0
    assert OpcodeContext.for_stage(3).code_max == 1.0
    assert OpcodeContext(2, (2, 3)).size((4, 5)) == (6, 8)
    assert OpcodeContext(2, (2, 3), (10, 10)).size((4, 5)) == (10, 10)
    for bad in (dict(stage=4), dict(stage=2, origin=(-1, 0)), dict(stage=2, code_max=0.0),
                dict(stage=2, image_size=(0, 3))):
        with pytest.raises(ValueError):
            OpcodeContext(**bad)

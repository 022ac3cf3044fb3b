"""The MapPolynomial and MapTable opcodes (isp/opcodes/value_maps.py;
DNG 1.7.1.0, chapter 7).

Kind: published (each test marked): the LG G4 sample DNG's OpcodeList2
(the data README) and the Adobe DNG SDK's definitions.
"""

from __future__ import annotations


import numpy as np
import pytest

from isp.opcodes import (
    AreaSpec,
    MapPolynomial,
    MapTable,
    parse_opcode_list,
    serialize_opcode_list,
)
from tests.helpers import raw_data_file as _data_file
from tests.helpers import tiff_tag as _tag


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


# -- applying (kind: property) -------------------------------------------------------

from isp.opcodes import OpcodeContext  # noqa: E402


@pytest.mark.property
def test_map_polynomial_applies_in_dn_in_stage_1_and_unclipped_later():
    """Stage 1 evaluates in stored DN (the SDK rescales the coefficients of
    a 16-bit image), rounds and clips to 0..65535; stage 2 on 0..1,
    unclipped; only the area's lattice and planes change."""
    op = MapPolynomial(AreaSpec(0, 0, 2, 4, col_pitch=2), (10.0, 2.0))
    out = op.apply(np.array([[100.0, 100.0, 40000.0, 1.0]] * 2, np.float32),
                   OpcodeContext.for_stage(1))
    assert out.tolist() == [[210.0, 100.0, 65535.0, 1.0]] * 2
    lin = MapPolynomial(AreaSpec(0, 0, 0, 0, plane=1, planes=2), (0.0, 0.0, 2.0))
    x = np.full((2, 2, 3), 0.9, np.float32)
    out = lin.apply(x, OpcodeContext(3))
    assert np.allclose(out[0, 0], [0.9, 1.62, 1.62])


@pytest.mark.property
def test_map_table_looks_up_16_bit_codes():
    """Stage 2 values are read as round(65535 x); stage 1 values are codes."""
    table = MapTable(AreaSpec(0, 0, 0, 0), np.arange(0, 2000, 2, dtype=np.uint16))
    out = table.apply(np.array([[5 / 65535, 0.5]], np.float32), OpcodeContext(2))
    assert np.allclose(out * 65535, [[10, 1998]], atol=1e-3)
    out = table.apply(np.array([[5.0, 999.0]], np.float32), OpcodeContext.for_stage(1))
    assert out.tolist() == [[10.0, 1998.0]]

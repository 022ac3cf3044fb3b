"""The per-row and per-column opcodes (isp/opcodes/per_line.py; DNG 1.7.1.0
chapter 7, DeltaPerRow/Column and ScalePerRow/Column as the Adobe DNG SDK's
dng_misc_opcodes.cpp applies them).

Kind: property (each test marked): results written out by hand for small
areas, pitches and windows.
"""

from __future__ import annotations

import numpy as np
import pytest

from isp.opcodes import (
    AreaSpec, DeltaPerColumn, DeltaPerRow, OpcodeContext, ScalePerColumn, ScalePerRow,
)


@pytest.mark.property
def test_delta_per_row_on_its_lattice_in_16_bit_codes():
    """Rows 1, 3, 5 of columns 2..5, plane 0; deltas are 16-bit codes: in
    stage 2 (white = 1) a delta of 6553.5 adds 0.1."""
    op = DeltaPerRow(AreaSpec(1, 2, 6, 6, row_pitch=2), np.array([6553.5, 0.0, -13107.0], np.float32))
    out = op.apply(np.zeros((8, 8), np.float32), OpcodeContext(2))
    expect = np.zeros((8, 8))
    expect[1, 2:6], expect[5, 2:6] = 0.1, -0.2
    assert np.allclose(out, expect, atol=1e-7)


@pytest.mark.property
def test_delta_in_stored_dn_rounded_and_clipped():
    """Stage 1: deltas in DN, results rounded and kept in 0..65535 as the
    SDK stores its integer stage-1 image."""
    op = DeltaPerColumn(AreaSpec(0, 0, 2, 3), np.array([10.4, -500.0, 70000.0], np.float32))
    out = op.apply(np.full((2, 3), 100.0, np.float32), OpcodeContext.for_stage(1))
    assert out.tolist() == [[110.0, 0.0, 65535.0]] * 2


@pytest.mark.property
def test_scale_per_column_with_pitch_and_planes():
    """Columns 1, 4 of planes 1..2 of a 3-plane image."""
    op = ScalePerColumn(AreaSpec(0, 1, 4, 6, plane=1, planes=2, col_pitch=3),
                        np.array([2.0, 0.5], np.float32))
    out = op.apply(np.ones((4, 6, 3), np.float32), OpcodeContext(3))
    expect = np.ones((4, 6, 3))
    expect[:, 1, 1:] = 2.0
    expect[:, 4, 1:] = 0.5
    assert np.array_equal(out, expect)


@pytest.mark.property
def test_scale_per_row_on_a_window_indexes_from_the_area():
    """The data is a window starting at image row 5: its row 0 is lattice
    row 2 of an area starting at row 1 with pitch 2 (image rows 1, 3, 5)."""
    op = ScalePerRow(AreaSpec(1, 0, 11, 4, row_pitch=2), np.arange(1, 6, dtype=np.float32))
    out = op.apply(np.ones((6, 4), np.float32), OpcodeContext(2, origin=(5, 0)))
    assert out[:, 0].tolist() == [3.0, 1.0, 4.0, 1.0, 5.0, 1.0]


@pytest.mark.property
def test_area_missing_the_data_changes_nothing():
    op = DeltaPerRow(AreaSpec(20, 0, 22, 4), np.array([1.0, 1.0], np.float32))
    data = np.zeros((4, 4), np.float32)
    assert not op.apply(data, OpcodeContext(2)).any()

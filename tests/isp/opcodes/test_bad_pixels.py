"""Bad-pixel repair (isp/opcodes/bad_pixels.py; DNG 1.7.1.0 chapter 7,
FixBadPixelsConstant and FixBadPixelsList as the Adobe DNG SDK's
dng_bad_pixels.cpp does them).

Kind: property (each test marked): on fields whose repaired values are
known in closed form (a plane a row + b col + c, which every symmetric
same-colour average reproduces; a flat field of three colours, which shows
which neighbours were used). Comparison with Adobe's own output is in
tests/modules/test_opcode_lists.py (dng_validate).
"""

from __future__ import annotations

import numpy as np
import pytest

from isp.opcodes import FixBadPixelsConstant, FixBadPixelsList, OpcodeContext, OpcodeError

S1 = OpcodeContext.for_stage(1)          # stored DN, integer arithmetic
S2 = OpcodeContext.for_stage(2)          # linear, black 0, white 1


def _plane(h=40, w=48, a=3.0, b=5.0, c=1000.0):
    rows, cols = np.mgrid[:h, :w]
    return (a * rows + b * cols + c).astype(np.float32)


def _colours(phase, h=12, w=12, r=300.0, g=100.0, b=500.0):
    """A flat field of one red, green and blue value on the Bayer layout of
    BayerPhase ``phase`` (0 GRBG, 1 RGGB, 2 BGGR, 3 GBRG)."""
    layout = {0: "GRBG", 1: "RGGB", 2: "BGGR", 3: "GBRG"}[phase]
    value = {"R": r, "G": g, "B": b}
    tile = np.array([[value[layout[0]], value[layout[1]]], [value[layout[2]], value[layout[3]]]])
    return np.tile(tile, (h // 2, w // 2)).astype(np.float32)


@pytest.mark.property
@pytest.mark.parametrize("phase", [0, 1, 2, 3])
def test_constant_uses_same_colour_neighbours_of_the_bayer_phase(phase):
    """A red or blue pixel takes the four at two pixels (its own colour), a
    green one its four diagonals: on a three-colour field every repaired
    pixel gets its own colour back, whatever the phase."""
    truth = _colours(phase)
    data = truth.copy()
    marks = [(4, 4), (4, 5), (5, 4), (5, 5), (0, 0), (11, 11)]
    for y, x in marks:
        data[y, x] = 7.0
    out = FixBadPixelsConstant(7, phase).apply(data, S1)
    assert np.array_equal(out, truth)


@pytest.mark.property
def test_constant_on_linear_data_and_unrepairable_pixels():
    """Stage 2: the constant is a 16-bit code (x 65535); bad neighbours are
    left out of the mean; a pixel whose four neighbours are all bad stays
    as it is."""
    truth = _plane() / 65535.0 * 10
    data = truth.copy()
    data[10, 10] = 0.0
    data[20, 21] = 0.0
    for dy, dx in ((-1, -1), (-1, 1), (1, -1), (1, 1)):    # (20, 21) is green in RGGB
        data[20 + dy, 21 + dx] = 0.0
    out = FixBadPixelsConstant(0, 1).apply(data.copy(), S2)
    assert out[10, 10] == pytest.approx(truth[10, 10], rel=1e-6)
    assert out[20, 21] == 0.0
    # (19, 20): diagonal (20, 21) is bad, the mean of the other three is
    # the plane at (-1/3, -1/3) from it
    assert out[19, 20] == pytest.approx(truth[19, 20] - 8 / 3 / 65535 * 10, rel=1e-6)


@pytest.mark.property
def test_constant_needs_a_mosaic():
    op = FixBadPixelsConstant(0, 1)
    with pytest.raises(OpcodeError, match="needs a one-plane CFA image"):
        op.apply(np.zeros((4, 4, 3), np.float32), S2)


@pytest.mark.property
def test_isolated_points_and_single_column_reproduce_a_plane():
    """Isolated points (the directional estimate over 5 x 5) and an isolated
    one-pixel column (seven directions over 9 x 9, green split zero on a
    plane) give the plane's value back exactly, in integer DN."""
    truth = _plane()
    data = truth.copy()
    points = [(10, 10), (10, 20), (25, 33), (30, 11)]
    for y, x in points:
        data[y, x] = 0.0
    data[5:35, 40] = 60000.0
    out = FixBadPixelsList(1, points, [[5, 40, 35, 41]]).apply(data, S1)
    assert np.array_equal(out, truth)


@pytest.mark.property
def test_single_row_reproduces_a_plane():
    """A one-pixel row is repaired as a transposed column (the SDK's own
    row repair writes four rows above the row; the specification asks for
    the row)."""
    truth = _plane()
    data = truth.copy()
    data[20, 6:30] = 0.0
    out = FixBadPixelsList(1, np.zeros((0, 2)), [[20, 6, 21, 30]]).apply(data, S1)
    assert np.array_equal(out, truth)


@pytest.mark.property
def test_clustered_points_and_rectangles_use_the_first_set_with_good_pixels():
    """A pair of adjacent bad points: each takes its diagonals (green) or
    the pixels at two (red/blue) that are not bad; a 3 x 3 bad block at
    (20, 30) in RGGB: its centre (green) has no good diagonal, so takes the
    four at two pixels (exact on a plane); its top-left corner (red) skips
    the diagonals and has two good pixels at two, (18, 30) and (20, 28):
    the plane minus (a + b); its top middle (green) has two good diagonals
    in row 19: the plane minus a."""
    a, b = 3.0, 5.0
    truth = _plane(a=a, b=b)
    data = truth.copy()
    data[10, 10] = data[10, 11] = 0.0
    data[20:23, 30:33] = 0.0
    out = FixBadPixelsList(1, [[10, 10], [10, 11]], [[20, 30, 23, 33]]).apply(data.copy(), S2)
    # (10, 10) is red in RGGB: (8, 10), (12, 10), (10, 8), (10, 12), all good
    assert out[10, 10] == pytest.approx(truth[10, 10])
    # (10, 11) is green: its diagonals are good
    assert out[10, 11] == pytest.approx(truth[10, 11])
    assert out[21, 31] == pytest.approx(truth[21, 31])
    assert out[20, 30] == pytest.approx(truth[20, 30] - (a + b))
    assert out[20, 31] == pytest.approx(truth[20, 31] - a)
    assert np.allclose(out[:18], truth[:18])


@pytest.mark.property
def test_points_addressed_in_the_image_outside_the_window_ignored():
    """Coordinates are the list's image's: with the data a window at
    (4, 6), the point at image (14, 16) is data (10, 10); a point outside
    the window changes nothing."""
    truth = _plane()
    data = truth.copy()
    data[10, 10] = 0.0
    ctx = OpcodeContext(1, origin=(4, 6), image_size=(60, 60), code_max=65535.0)
    out = FixBadPixelsList(1, [[14, 16], [2, 2], [59, 59]]).apply(data, ctx)
    assert np.array_equal(out, truth)

"""TrimBounds (isp/opcodes/trim.py; DNG 1.7.1.0 chapter 7; the Adobe DNG
SDK re-bases the trimmed image at its own origin).

Kind: property (each test marked).
"""

from __future__ import annotations

import numpy as np
import pytest

from isp.opcodes import OpcodeContext, OpcodeError, TrimBounds


@pytest.mark.property
def test_trim_crops_and_rebases():
    data = np.arange(48, dtype=np.float32).reshape(6, 8)
    op = TrimBounds(1, 2, 5, 7)
    out = op.apply(data, OpcodeContext(3))
    assert np.array_equal(out, data[1:5, 2:7])
    (rows, cols), ctx = op.window(data.shape, OpcodeContext(3))
    assert (rows, cols) == (slice(1, 5), slice(2, 7))
    assert ctx.origin == (0, 0) and ctx.image_size == (4, 5)


@pytest.mark.property
def test_trim_of_a_window():
    """Data at (2, 3) of a 10 x 12 image; trimming to (1, 1)-(9, 9) keeps
    data rows 0..6, columns 0..5, now at (1, 2) of an 8 x 8 image."""
    op = TrimBounds(1, 1, 9, 9)
    (rows, cols), ctx = op.window((8, 9), OpcodeContext(2, origin=(2, 3), image_size=(10, 12)))
    assert (rows, cols) == (slice(0, 7), slice(0, 6))
    assert ctx.origin == (1, 2) and ctx.image_size == (8, 8)


@pytest.mark.property
def test_trim_outside_the_image_or_in_list1():
    with pytest.raises(OpcodeError, match=r"do not lie inside the 8x6 image"):
        TrimBounds(0, 0, 7, 8).apply(np.zeros((6, 8), np.float32), OpcodeContext(2))
    assert "ActiveArea" in TrimBounds(0, 0, 2, 2).unsupported(1, 1)

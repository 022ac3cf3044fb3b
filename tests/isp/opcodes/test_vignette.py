"""The FixVignetteRadial opcode (isp/opcodes/vignette.py; DNG 1.7.1.0,
chapter 7).

Kind: published (each test marked): the DngOpcodesEditor sample blob (the
data README) and the Adobe DNG SDK's formula, re-implemented here pixel by
pixel.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from isp.opcodes import (
    FixVignetteRadial,
    parse_opcode_list,
    serialize_opcode_list,
)
from tests.helpers import opcode_blob as _blob


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


@pytest.mark.property
def test_vignette_applied_to_a_window_of_the_image():
    """kind: property. A window of the image at (3, 5) is multiplied by the
    image's own gain field, cut to the window; in stage 1 rounded to DN."""
    from isp.opcodes import OpcodeContext

    op = FixVignetteRadial((0.3, 0.1, 0.0, 0.0, 0.0), 0.4, 0.6)
    gain = op.evaluate(20, 30)
    out = op.apply(np.ones((10, 12, 3), np.float32), OpcodeContext(3, (3, 5), (20, 30)))
    assert np.allclose(out, gain[3:13, 5:17, None], atol=1e-7)
    dn = op.apply(np.full((20, 30), 1000.0, np.float32), OpcodeContext.for_stage(1))
    assert np.array_equal(dn, np.rint(1000.0 * gain))

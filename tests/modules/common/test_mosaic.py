"""CFA helpers (modules.common.mosaic), kind: property: the per-site affine
map equals its strided reference."""

from __future__ import annotations

import numpy as np

from modules.common.mosaic import cfa_affine

import pytest

pytestmark = pytest.mark.property


def test_cfa_affine_matches_strided_reference(rng):
    for h, w in ((6, 8), (7, 9), (1, 5)):
        x = rng.normal(size=(h, w)).astype(np.float32)
        s, o = rng.uniform(0.5, 2, (2, 2)), rng.normal(size=(2, 2))
        ref = np.empty_like(x)
        for i in range(2):
            for j in range(2):
                ref[i::2, j::2] = x[i::2, j::2] * s[i, j] + o[i, j]
        assert np.allclose(cfa_affine(x, s, o), ref, atol=1e-6)

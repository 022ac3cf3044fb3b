"""The sRGB encoding (modules.gamma): the IEC 61966-2-1 values (kind:
published) and the fast table against the formula, on numpy and torch (kind:
property)."""

from __future__ import annotations

import numpy as np
import pytest

from modules.gamma import encode, srgb_eotf, srgb_oetf
from tests.helpers import reference

SRGB = reference("srgb_iec_61966_2_1.json")


@pytest.mark.published
@pytest.mark.parametrize("row", SRGB["encode"], ids=lambda r: r["what"])
def test_srgb_published_encoding(row):
    """published: IEC 61966-2-1 — the breakpoint and 8-bit anchors."""
    assert float(srgb_oetf(np.array(row["linear"]))) == pytest.approx(row["encoded"], abs=row["abs_tol"])


@pytest.mark.published
@pytest.mark.parametrize("row", SRGB["decode"], ids=lambda r: r["what"])
def test_srgb_published_decoding(row):
    """published: IEC 61966-2-1 — the inverse at mid-scale."""
    assert float(srgb_eotf(np.array(row["encoded"]))) == pytest.approx(row["linear"], abs=row["abs_tol"])


@pytest.mark.property
def test_gamma_table_matches_formula_and_clips(rng):
    x = rng.uniform(-0.1, 1.3, (300, 400, 3)).astype(np.float32)
    fast = encode(x)
    exact = srgb_oetf(x.astype(np.float64))
    assert np.abs(fast - exact).max() < 1e-4
    assert fast.min() >= 0 and fast.max() <= 1 and fast.dtype == np.float32


@pytest.mark.property
def test_gamma_on_torch_matches_numpy():
    torch = pytest.importorskip("torch")
    x = np.linspace(-0.1, 1.2, 101, dtype=np.float32)
    t = torch.tensor(x, requires_grad=True)
    y = srgb_oetf(t)
    assert np.allclose(y.detach().numpy(), srgb_oetf(x.astype(np.float64)), atol=1e-6)
    y.sum().backward()
    assert torch.isfinite(t.grad).all()

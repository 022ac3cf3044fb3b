"""The one-thread products (calibration/optics/psf/linalg.py): both GEMM
paths give a @ bᵀ, and the masked row medians are np.median's
(kind: property).
"""

from __future__ import annotations

import numpy as np
import pytest

from calibration.optics.psf import linalg

pytestmark = pytest.mark.property


@pytest.mark.parametrize("one_thread", [True, False])
@pytest.mark.parametrize("dtype", [np.complex128, np.complex64])
def test_property_gemm_paths_agree(monkeypatch, one_thread, dtype):
    """property: _a_bt (one complex GEMM, or real GEMMs in blocks that
    OpenBLAS keeps on one thread) is a @ bᵀ."""
    monkeypatch.setattr(linalg, "blas_on_one_thread", lambda: one_thread)
    rng = np.random.default_rng(1)
    a, b = ((rng.standard_normal((3, n, 301)) + 1j * rng.standard_normal((3, n, 301))).astype(dtype) for n in (5, 7))
    ref = np.einsum("kim,kjm->kij", a.astype(complex), b.astype(complex))
    tol = 1e-12 if dtype == np.complex128 else 2e-5
    np.testing.assert_allclose(linalg.a_bt(a, b), ref, rtol=0, atol=tol * np.abs(ref).max())


def test_property_row_medians():
    """property: the masked row medians equal np.median of each row's kept
    values (odd, even and empty rows)."""
    rng = np.random.default_rng(3)
    a = rng.standard_normal((5, 9))
    mask = rng.random((5, 9)) < 0.6
    mask[0] = True
    mask[1] = False
    mask[2, :] = False
    mask[2, [1, 4]] = True
    got = linalg.masked_row_medians(a, mask)
    assert np.isnan(got[1])
    for i in (0, 2, 3, 4):
        assert got[i] == np.median(a[i][mask[i]])

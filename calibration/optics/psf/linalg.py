"""Small dense products of the PSF code, kept on one BLAS thread.

The pupil fits (:mod:`calibration.optics.psf.pupil`) and the Debye sums
(:mod:`calibration.optics.psf.debye`) multiply tall, thin arrays: thousands
of rays by a few dozen monomials or image-plane samples. OpenBLAS threads
such products over every core, and where the cores are shared (a busy
machine, a process pool) its spin-waiting threads cost far more than the
product itself (:data:`BLAS_ONE_THREAD`). The functions here cut them into
real GEMMs that OpenBLAS runs on the calling thread.

Imports numpy only.
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["BLAS_ONE_THREAD", "a_bt", "at_b", "blas_on_one_thread", "lstsq", "masked_row_medians"]

BLAS_ONE_THREAD = 1 << 18
"""OpenBLAS runs a real GEMM of more than 2^18 multiply-adds (a complex one
of almost any size) on all cores. When the cores are shared (a busy machine,
a process pool) its spin-waiting threads add ~30 ms to every such call —
measured 75 ms instead of 3.5 ms for the 3.2k-ray pupil fit, 20 ms instead of
50 µs for a 33×239×33 complex product. The small products here are
therefore done as real GEMMs chunked below that size, on one thread."""


def at_b(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a.T @ b`` for tall arrays, on one BLAS thread.

    Parameters
    ----------
    a : (K, m) ndarray, real or complex
    b : (K, n) ndarray, real or complex

    Returns
    -------
    (m, n) ndarray
        Real GEMMs in chunks of K that stay on one BLAS thread (see
        :data:`BLAS_ONE_THREAD`), complex operands as real and imaginary
        parts side by side; one plain product when even 32 rows of K would
        not stay below that size.

    >>> at_b(np.arange(6.0).reshape(3, 2), np.ones((3, 1))).ravel().tolist()
    [6.0, 9.0]
    """
    if np.iscomplexobj(a) or np.iscomplexobj(b):
        ac, bc = np.asarray(a, np.complex128), np.asarray(b, np.complex128)
        m, n = ac.shape[1], bc.shape[1]
        r = at_b(np.concatenate([ac.real, ac.imag], axis=1), np.concatenate([bc.real, bc.imag], axis=1))
        return (r[:m, :n] - r[m:, n:]) + 1j * (r[:m, n:] + r[m:, :n])
    k = a.shape[0]
    step = BLAS_ONE_THREAD // max(a.shape[1] * b.shape[1], 1) - 1
    if step < 32:
        return a.T @ b
    out = a[:step].T @ b[:step]
    for s in range(step, k, step):
        out += a[s:s + step].T @ b[s:s + step]
    return out


def lstsq(v: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares coefficients ``c`` minimising ``|v c − y|``, by the
    normal equations.

    Parameters
    ----------
    v : (K, m) ndarray
        Design matrix; columns are scaled to unit norm before solving (the
        pupil monomials it is used with are well conditioned on the unit
        disc).
    y : (K, n) ndarray

    Returns
    -------
    (m, n) ndarray
    """
    scale = np.sqrt(np.einsum("ij,ij->j", v, v))
    scale[scale == 0] = 1.0
    vs = v / scale
    return np.linalg.solve(at_b(vs, vs), at_b(vs, y)) / scale[:, None]


def blas_on_one_thread() -> bool:
    """Whether BLAS was told to use one thread (``OPENBLAS_NUM_THREADS`` or,
    which OpenBLAS also reads, ``OMP_NUM_THREADS`` = 1, as the benchmarks
    and the worker pools set them) or there is one core: then any GEMM may
    be one call (see :data:`BLAS_ONE_THREAD`)."""
    env = os.environ.get("OPENBLAS_NUM_THREADS") or os.environ.get("OMP_NUM_THREADS")
    return env == "1" or (os.cpu_count() or 1) == 1


def a_bt(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a[k] @ b[k].T`` for a batch of complex matrices.

    Parameters
    ----------
    a : (B, na, M) ndarray, complex64 or complex128
    b : (B, nb, M) ndarray, same dtype

    Returns
    -------
    (B, na, nb) ndarray
        One complex GEMM per k where BLAS runs on one thread
        (:func:`blas_on_one_thread`); else real GEMMs of the float views
        (re, im interleaved along M): ``Re = a·conj(b)`` and
        ``Im = a·(i conj(b))`` summed over the 2M floats, the sum cut into
        blocks that OpenBLAS keeps on one thread (:data:`BLAS_ONE_THREAD`;
        it threads a complex GEMM of almost any size).
    """
    if blas_on_one_thread():
        return np.matmul(a, b.transpose(0, 2, 1))
    nbatch, na, m = a.shape
    nb = b.shape[1]
    real = np.float32 if a.dtype == np.complex64 else np.float64
    s = np.empty((nbatch, 2 * nb, m), dtype=a.dtype)
    np.conjugate(b, out=s[:, :nb])
    np.multiply(s[:, :nb], 1j, out=s[:, nb:])
    av = np.ascontiguousarray(a).view(real)                       # (B, na, 2M)
    sv = s.view(real)                                             # (B, 2nb, 2M)
    step = max(2, BLAS_ONE_THREAD // (na * 2 * nb) - 1)
    r = np.zeros((nbatch, na, 2 * nb), dtype=real)
    for j in range(0, 2 * m, step):
        r += np.matmul(av[:, :, j:j + step], sv[:, :, j:j + step].transpose(0, 2, 1))
    return r[:, :, :nb] + 1j * r[:, :, nb:]


def masked_row_medians(a: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The median of each row's kept values.

    Parameters
    ----------
    a : (K, M) ndarray, float
    mask : (K, M) ndarray, bool
        The values to keep.

    Returns
    -------
    (K,) ndarray
        ``np.median(a[k][mask[k]])`` of every row, NaN for a row with none
        kept; by one sort (a per-row ``np.nanmedian`` loops in Python).

    >>> masked_row_medians(np.array([[1.0, 5.0, 2.0]]), np.array([[True, False, True]])).tolist()
    [1.5]
    """
    n = np.count_nonzero(mask, axis=1)
    srt = np.sort(np.where(mask, a, np.inf), axis=1)
    lo = np.take_along_axis(srt, np.maximum((n - 1) // 2, 0)[:, None], axis=1)[:, 0]
    hi = np.take_along_axis(srt, np.maximum(n // 2, 0)[:, None], axis=1)[:, 0]
    with np.errstate(invalid="ignore"):
        return np.where(n > 0, (lo + hi) / 2.0, np.nan)

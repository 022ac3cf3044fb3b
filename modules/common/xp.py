"""Array helpers so that a stage's math is written once and runs on numpy
arrays (the pipeline) and torch tensors (training through the stages after
the correction slot).

Functions take the array namespace from their input (array-API style, via
``array-api-compat``) and a ``channel_axis``: numpy images are ``(H, W, 3)``
(``channel_axis=-1``), torch batches ``(N, 3, H, W)`` (``channel_axis=-3``).
Where numpy alone is slow on a 16 MP frame, the numpy path calls an
OpenCV primitive that computes the same thing; tests hold the two to the
plain formula.
"""

from __future__ import annotations

import numpy as np
from array_api_compat import array_namespace, is_numpy_array

__all__ = ["array_namespace", "is_numpy_array", "apply_matrix", "as_like"]


def as_like(value, x):
    """``value`` (array-like, float64) as an array of ``x``'s namespace, dtype
    and device: constants enter a torch graph on the right device."""
    if is_numpy_array(x):
        return np.asarray(value, dtype=x.dtype)
    xp = array_namespace(x)
    return xp.asarray(np.asarray(value, dtype=np.float64), dtype=x.dtype, device=x.device)


def apply_matrix(x, matrix, channel_axis: int = -1):
    """Apply a 3×3 matrix to the colour channels: ``y_i = Σ_j M_ij x_j``.

    Parameters
    ----------
    x : array, float
        Image(s) with 3 channels on ``channel_axis``: numpy ``(H, W, 3)`` or
        torch ``(N, 3, H, W)``. Not clipped.
    matrix : (3, 3) array_like
    channel_axis : int

    Returns
    -------
    array of x's shape, namespace and dtype.

    Examples
    --------
    >>> x = np.ones((2, 2, 3), np.float32)
    >>> apply_matrix(x, np.diag([1.0, 2.0, 3.0]))[0, 0]
    array([1., 2., 3.], dtype=float32)
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (3, 3):
        raise ValueError(f"matrix must be 3x3, got shape {m.shape}")
    if is_numpy_array(x) and x.dtype == np.float32 and x.ndim == 3 and channel_axis in (-1, 2):
        import cv2  # OpenCV's transform is a multithreaded fused 3x3 multiply

        return cv2.transform(np.ascontiguousarray(x), m)
    xp = array_namespace(x)
    xm = xp.moveaxis(x, channel_axis, -1)
    y = xp.matmul(xm, as_like(m.T, x))
    return xp.moveaxis(y, -1, channel_axis)

"""Colour correction: camera RGB to linear sRGB by the DNG colour model.

The stage maps white-balanced camera RGB to linear sRGB (D65) in two steps:

1. camera RGB → CIE XYZ (D50), the *profile connection space* (PCS) of the
   DNG specification, from the file's ColorMatrix / ForwardMatrix tags
   interpolated between the two calibration illuminants by the scene's
   correlated colour temperature;
2. XYZ (D50) → linear sRGB (D65): Bradford chromatic adaptation D50 → D65,
   then the sRGB primaries.

The colour model itself (the matrices, their interpolation and
normalisations, white xy ↔ camera neutral, the domains and the references)
lives in :mod:`modules.common.dng_colour`, after *Adobe DNG Specification*
1.7.1.0, chapter 6, "Mapping Camera Color Space to CIE XYZ Space"; its
public names are re-exported here. This module holds the stage,
:class:`ColorCorrection`, and :func:`apply_ccm`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from isp.frame import Domain, Frame
from isp.meta import CameraMeta  # noqa: F401  (the doctests use it)
from isp.stage import StageBase

from modules.common.dng_colour import DEFAULT_WHITE_XY as DEFAULT_WHITE_XY
from modules.common.dng_colour import (
    ILLUMINANT_CCT,
    PCS_WHITE_XY,
    SOURCES,
    SourceName,
    bradford_matrix,
    camera_neutral_to_xy,
    camera_to_linear_srgb,
    camera_to_xyz_d50,
    check_source,
    illuminant_to_cct,
    interpolation_weight,
    matrix_xyz_d50_to_linear_srgb,
    normalize_color_matrix,
    normalize_forward_matrix,
    xy_to_camera_neutral,
    xy_to_cct,
)
from modules.common.xp import apply_matrix

__all__ = [
    "ColorCorrection",
    "ILLUMINANT_CCT",
    "PCS_WHITE_XY",
    "SOURCES",
    "apply_ccm",
    "bradford_matrix",
    "camera_neutral_to_xy",
    "camera_to_linear_srgb",
    "camera_to_xyz_d50",
    "illuminant_to_cct",
    "interpolation_weight",
    "matrix_xyz_d50_to_linear_srgb",
    "normalize_color_matrix",
    "normalize_forward_matrix",
    "xy_to_camera_neutral",
    "xy_to_cct",
]


def apply_ccm(x, matrix, channel_axis: int = -1):
    """Apply a colour matrix to an image: ``y_i = Σ_j M_ij x_j``.

    Parameters
    ----------
    x : array
        numpy ``(H, W, 3)`` (``channel_axis=-1``) or torch ``(N, 3, H, W)``
        (``channel_axis=-3``), float. Not clipped.
    matrix : (3, 3) array_like
    channel_axis : int

    Returns
    -------
    array of ``x``'s shape, namespace, dtype and device.

    Examples
    --------
    >>> y = apply_ccm(np.full((1, 1, 3), 2.0, np.float32), np.eye(3))
    >>> y.dtype.name, y[0, 0].tolist()
    ('float32', [2.0, 2.0, 2.0])
    """
    return apply_matrix(x, matrix, channel_axis=channel_axis)


# --------------------------------------------------------------------------
# the stage

@dataclass(frozen=True)
class ColorCorrection(StageBase):
    """Colour correction: balanced camera RGB → linear sRGB (D65).

    Parameters
    ----------
    source : str
        Where the camera → XYZ matrix comes from (:data:`SOURCES`): ``auto``
        (ForwardMatrix if present, else ColorMatrix, interpolated by the
        scene CCT), ``color_matrix``, ``color_matrix_1``, ``color_matrix_2``
        (one matrix, no interpolation, as LibRaw does) or ``forward_matrix``.
    matrix : tuple of 9 float, optional
        A user matrix, balanced camera RGB → linear sRGB, row-major; replaces
        the file's colour model.

    Notes
    -----
    The matrix is :func:`camera_to_linear_srgb` with the frame's ``neutral``
    as both the applied and the scene neutral (the file's AsShotNeutral when
    the frame carries none, i.e. unbalanced data). No clipping.

    Examples
    --------
    >>> from isp import Frame
    >>> meta = CameraMeta(color_matrix_1=np.eye(3), as_shot_neutral=(0.5, 1.0, 0.7))
    >>> frame = Frame(np.ones((2, 2, 3), np.float32), Domain.CAMERA_RGB, meta,
    ...               neutral=(0.5, 1.0, 0.7))
    >>> out = ColorCorrection()(frame)
    >>> out.domain.value, np.round(out.data[0, 0], 5).tolist()
    ('linear_rgb', [1.0, 1.0, 1.0])
    """

    name: ClassVar[str] = "ccm"
    consumes: ClassVar[tuple] = (Domain.CAMERA_RGB,)
    produces: ClassVar[Domain] = Domain.LINEAR_RGB

    source: SourceName = "auto"
    matrix: tuple[float, ...] | None = None

    def __post_init__(self):
        check_source(self.source)
        if self.matrix is not None:
            values = tuple(self.matrix) if not isinstance(self.matrix, np.ndarray) \
                else tuple(self.matrix.ravel())
            if len(values) != 9:
                raise ValueError(f"matrix must have 9 numbers (3x3, row-major), got {len(values)}")
            try:
                values = tuple(float(v) for v in values)
            except (TypeError, ValueError):
                raise ValueError(f"matrix must be 9 numbers, got {self.matrix!r}") from None
            if not all(math.isfinite(v) for v in values):
                raise ValueError(f"matrix has non-finite values: {values}")
            object.__setattr__(self, "matrix", values)

    def process(self, frame: Frame) -> Frame:
        if self.matrix is not None:
            m = np.asarray(self.matrix, dtype=np.float64).reshape(3, 3)
            note = "user matrix"
        else:
            m, notes = camera_to_linear_srgb(frame.meta, applied_neutral=frame.neutral,
                                             scene_neutral=frame.neutral, source=self.source)
            note = f"source {self.source}: " + "; ".join(notes)
        out = apply_ccm(frame.data, m)
        return frame.evolve(out, domain=Domain.LINEAR_RGB, stage=self.name, note=note)

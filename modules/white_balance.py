"""White balance in camera space: divide each colour by the camera neutral.

Reference: Adobe, *DNG Specification* 1.7.1.0, chapter 6: AsShotNeutral is
"the selected white balance at time of capture, encoded as the coordinates
of a perfectly neutral color in linear reference space values"; balancing
divides by it, so that neutral becomes R = G = B. The neutral used is
stored on the frame (``Frame.neutral``) for the colour stage, which needs it
to map balanced camera RGB to XYZ.

Modes
-----
``as_shot``
    AsShotNeutral, or AsShotWhiteXY converted to a neutral through the
    camera's colour matrices; falls back to grey world (noted) if the file
    has neither.
``grey_world``
    The neutral is the mean of each channel over unclipped, non-dark pixels
    (Buchsbaum, "A spatial processor model for object colour perception",
    J. Franklin Inst. 310(1), 1980).
``manual``
    ``gains`` = (R, G, B) multipliers given by the user.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from isp.errors import InputError
from isp.frame import Domain, Frame
from isp.stage import StageBase

from modules.common.mosaic import cfa_affine, channel_pattern


def channel_means(data: np.ndarray, cfa_pattern: np.ndarray | None, low: float = 0.002,
                  high: float = 0.95) -> np.ndarray:
    """Mean of each colour (R, G, B) over pixels in (low, high).

    Parameters
    ----------
    data : (H, W) mosaic or (H, W, 3) ndarray, linear 0..1
    cfa_pattern : (2, 2) int array or None
        Channel per CFA phase of a mosaic.

    Returns
    -------
    (3,) float64 means; NaN for a colour with no usable pixel.
    """
    sums = np.zeros(3)
    counts = np.zeros(3)
    step = max(1, int(np.sqrt(data.shape[0] * data.shape[1] / 1e6)))  # ~1 MP sample
    if data.ndim == 2:
        for i in range(2):
            for j in range(2):
                c = int(cfa_pattern[i, j])
                v = data[i::2 * step, j::2 * step]
                m = (v > low) & (v < high)
                sums[c] += float(v[m].sum())
                counts[c] += int(m.sum())
    else:
        v = data[::step, ::step]
        m = np.all((v > low) & (v < high), axis=2)
        sums = v[m].sum(axis=0).astype(np.float64)
        counts[:] = m.sum()
    with np.errstate(invalid="ignore", divide="ignore"):
        return sums / counts


def apply_white_balance(data: np.ndarray, gains, cfa_pattern: np.ndarray | None = None) -> np.ndarray:
    """Multiply each colour by its gain (a new float32 array; not clipped).

    Parameters
    ----------
    data : (H, W) mosaic or (H, W, 3) ndarray, float32
    gains : (3,) array_like
        Multipliers for R, G, B (= 1 / neutral).
    cfa_pattern : (2, 2) int array
        Channel per CFA phase, for a mosaic.

    Examples
    --------
    >>> apply_white_balance(np.ones((2, 2), np.float32), (2, 1, 3), np.array([[0, 1], [1, 2]]))
    array([[2., 1.],
           [1., 3.]], dtype=float32)
    """
    g = np.asarray(gains, dtype=np.float32)
    if data.ndim == 3:
        return data * g
    return cfa_affine(data, channel_pattern(cfa_pattern, g))


@dataclass(frozen=True)
class WhiteBalance(StageBase):
    """Balance colours in camera space (as-shot, grey-world or manual).

    Parameters
    ----------
    mode : {"as_shot", "grey_world", "manual"}
    gains : (float, float, float), optional
        R, G, B multipliers for ``mode="manual"``.
    """

    name = "white_balance"
    consumes = (Domain.RAW_LINEAR,)

    mode: Literal["as_shot", "grey_world", "manual"] = "as_shot"
    gains: tuple[float, float, float] | None = None

    def __post_init__(self):
        if self.mode == "manual":
            if self.gains is None:
                raise ValueError("mode 'manual' needs gains = [R, G, B]")
            if not all(np.isfinite(g) and g > 0 for g in self.gains):
                raise ValueError(f"gains must be positive and finite, got {self.gains}")
        elif self.gains is not None:
            raise ValueError(f"gains are only used with mode 'manual', not {self.mode!r}")

    def neutral(self, frame: Frame) -> tuple[np.ndarray, str]:
        """The camera neutral (R, G, B; G = 1) this stage will divide by, and
        a note saying where it came from."""
        meta = frame.meta
        pattern = meta.cfa.pattern if meta.cfa is not None else None
        if self.mode == "manual":
            n = 1.0 / np.asarray(self.gains, dtype=np.float64)
            how = "manual gains"
        elif self.mode == "as_shot" and meta.as_shot_neutral is not None:
            n = np.asarray(meta.as_shot_neutral, dtype=np.float64)
            how = "as-shot neutral"
        elif self.mode == "as_shot" and meta.as_shot_white_xy is not None:
            from modules.common.dng_colour import xy_to_camera_neutral

            n = np.asarray(xy_to_camera_neutral(meta, meta.as_shot_white_xy), dtype=np.float64)
            how = f"as-shot white xy {tuple(round(v, 4) for v in meta.as_shot_white_xy)}"
        else:
            means = channel_means(frame.data, pattern)
            if not np.all(np.isfinite(means) & (means > 0)):
                raise InputError(meta.path, "grey-world white balance: no usable pixels "
                                            "(image black or clipped)")
            n = means
            how = "grey world" if self.mode == "grey_world" else "grey world (no as-shot white in the file)"
        n = n / n[1]
        return n, how

    def process(self, frame: Frame) -> Frame:
        n, how = self.neutral(frame)
        pattern = frame.meta.cfa.pattern if frame.meta.cfa is not None else None
        out = apply_white_balance(frame.data, 1.0 / n, pattern)
        note = f"{how} ({n[0]:.4f}, {n[1]:.4f}, {n[2]:.4f})"
        return frame.evolve(out, stage=self.name, note=note, neutral=tuple(float(v) for v in n))

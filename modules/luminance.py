"""Exposure and global tone: one gain per pixel, computed from luminance.

``out = x · k · T(k·Y) / (k·Y)`` where ``k = 2^(BaselineExposure + EV)``,
``Y`` the pixel's luminance and ``T`` a global tone curve (identity by
default). Because the per-pixel factor is a scalar, it preserves
chromaticity and commutes with the 3×3 colour matrix that follows, so this
stage can stand before or after the CCM with the same result; that is why it
may sit, as in the paper's pipeline, between the correction slot and the
colour stage.

References
----------
* Adobe, *DNG Specification* 1.7.1.0, BaselineExposure: "the amount by
  which to move the zero point of the exposure scale", in EV; the DNG
  renderer multiplies linear data by 2^BaselineExposure.
* Reinhard, Stark, Shirley, Ferwerda, "Photographic tone reproduction for
  digital images", SIGGRAPH 2002, eq. 4 (extended operator with white
  point ``L_w``).
* Narkowicz, "ACES filmic tone mapping curve" (2016): the rational fit
  ``x(2.51x + 0.03) / (x(2.43x + 0.59) + 0.14)``.

Runs on numpy ``(H, W, 3)`` and torch ``(N, 3, H, W)`` (``channel_axis``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from isp.errors import InputError
from isp.frame import Domain, Frame
from isp.stage import StageBase

from modules.common.xp import array_namespace, as_like, is_numpy_array

#: luminance weights of linear sRGB / BT.709 primaries (ITU-R BT.709-6, 3.2)
BT709_Y = (0.2126, 0.7152, 0.0722)


def tone_reinhard(y, white: float = 4.0):
    """Extended Reinhard operator (Reinhard et al. 2002, eq. 4): maps
    ``white`` to 1; slope 1 at 0."""
    return y * (1.0 + y / (white * white)) / (1.0 + y)


def tone_aces(y):
    """Narkowicz's ACES filmic fit (2016); maps ~10 to 1."""
    return (y * (2.51 * y + 0.03)) / (y * (2.43 * y + 0.59) + 0.14)


TONE_CURVES = {"none": None, "reinhard": tone_reinhard, "aces": tone_aces}


def tone_reinhard_inverse(t, white: float = 4.0):
    """Inverse of :func:`tone_reinhard` on [0, ∞): the root ``y ≥ 0`` of
    ``y²/white² + (1 − t)·y − t = 0``, in the cancellation-free form
    ``2t / ((1 − t) + sqrt((1 − t)² + 4t/white²))``.

    >>> round(float(tone_reinhard_inverse(tone_reinhard(np.float64(2.5)))), 12)
    2.5
    """
    xp = array_namespace(t)
    b = 1.0 - t
    return 2.0 * t / (b + xp.sqrt(b * b + 4.0 * t / (white * white)))


def tone_aces_inverse(t):
    """Inverse of :func:`tone_aces` for ``0 ≤ t < 2.51/2.43`` (its limit at
    infinity): the root ``y ≥ 0`` of
    ``(2.51 − 2.43t)·y² + (0.03 − 0.59t)·y − 0.14t = 0``, cancellation-free.

    >>> round(float(tone_aces_inverse(tone_aces(np.float64(0.7)))), 12)
    0.7
    """
    xp = array_namespace(t)
    a = 2.51 - 2.43 * t
    b = 0.03 - 0.59 * t
    return 0.28 * t / (b + xp.sqrt(b * b + 0.56 * a * t))


TONE_INVERSES = {"none": None, "reinhard": tone_reinhard_inverse, "aces": tone_aces_inverse}


def luminance_weights(frame: Frame) -> np.ndarray:
    """Weights w (sum 1) with ``Y = w · rgb`` for the frame's data.

    For balanced camera RGB, the second row of the DNG camera→XYZ matrix
    (undoing the balance), scaled so that neutral (1, 1, 1) has Y = 1; for
    linear sRGB, the BT.709 weights.
    """
    if frame.domain is Domain.CAMERA_RGB:
        from modules.common.dng_colour import camera_to_xyz_d50

        meta = frame.meta
        neutral = frame.neutral
        try:
            m, _ = camera_to_xyz_d50(meta, neutral=neutral)
        except Exception:  # no usable matrix: treat camera RGB as sRGB-like
            return np.asarray(BT709_Y)
        row = m[1] * (np.asarray(neutral) if neutral is not None else 1.0)
        if not np.all(np.isfinite(row)) or row.sum() <= 0:
            return np.asarray(BT709_Y)
        return row / row.sum()
    return np.asarray(BT709_Y)


def adjust_luminance(x, gain: float, weights=BT709_Y, tone: str = "none",
                     white: float = 4.0, channel_axis: int = -1):
    """Scale by ``gain`` and apply a global tone curve on luminance.

    Parameters
    ----------
    x : array, linear RGB (numpy or torch), 3 channels on ``channel_axis``
    gain : float
        Linear exposure factor (2^EV).
    weights : (3,) array_like
        Luminance weights of x's RGB.
    tone : {"none", "reinhard", "aces"}
    white : float
        Reinhard white point (linear, after gain).
    channel_axis : int

    Returns
    -------
    array like x; not clipped.

    >>> adjust_luminance(np.full((1, 1, 3), 0.25, np.float32), 2.0)[0, 0]
    array([0.5, 0.5, 0.5], dtype=float32)
    """
    if tone not in TONE_CURVES:
        raise ValueError(f"unknown tone curve {tone!r}; valid: {', '.join(TONE_CURVES)}")
    if TONE_CURVES[tone] is None:
        if gain == 1.0:
            return x
        return x * (np.float32(gain) if is_numpy_array(x) else gain)
    xp = array_namespace(x)
    w = as_like(np.asarray(weights, dtype=np.float64), x)
    shape = [1] * x.ndim
    shape[channel_axis] = 3
    y = xp.sum(x * xp.reshape(w, tuple(shape)), axis=channel_axis, keepdims=True) * gain
    y = xp.clip(y, 1e-8, None)  # keeps the ratio finite; dark pixels keep gain ≈ T'(0) = 1
    curve = TONE_CURVES[tone]
    t = curve(y, white) if tone == "reinhard" else curve(y)
    return x * (gain * t / y)


def invert_luminance(y, gain: float, weights=BT709_Y, tone: str = "none", white: float = 4.0,
                     channel_axis: int = -1):
    """The inverse of :func:`adjust_luminance`: the data that the stage maps
    to ``y`` (used to synthesise training data from display images).

    Parameters
    ----------
    y : array, linear RGB (numpy or torch), 3 channels on ``channel_axis``
        Output of :func:`adjust_luminance` (with ``"aces"``, luminance below
        2.51/2.43, the curve's limit).
    gain, weights, tone, white, channel_axis
        As :func:`adjust_luminance`.

    Returns
    -------
    array like y; not clipped.

    Notes
    -----
    The stage multiplies each pixel by ``g·T(gY)/(gY)``, so the output's
    luminance is ``Y' = w·y = T(gY)``; hence ``gY = T⁻¹(Y')`` and
    ``x = y · T⁻¹(Y') / (g·Y')``.

    >>> x = np.array([[[0.2, 0.5, 0.1]]], np.float32)
    >>> y = adjust_luminance(x, 2.0, tone="reinhard")
    >>> bool(np.allclose(invert_luminance(y, 2.0, tone="reinhard"), x, rtol=1e-5))
    True
    """
    if tone not in TONE_CURVES:
        raise ValueError(f"unknown tone curve {tone!r}; valid: {', '.join(TONE_CURVES)}")
    if TONE_CURVES[tone] is None:
        if gain == 1.0:
            return y
        return y * (np.float32(1.0 / gain) if is_numpy_array(y) else 1.0 / gain)
    xp = array_namespace(y)
    w = as_like(np.asarray(weights, dtype=np.float64), y)
    shape = [1] * y.ndim
    shape[channel_axis] = 3
    yl = xp.clip(xp.sum(y * xp.reshape(w, tuple(shape)), axis=channel_axis, keepdims=True), 1e-8, None)
    inv = TONE_INVERSES[tone]
    t = inv(yl, white) if tone == "reinhard" else inv(yl)
    return y * (t / (gain * yl))


@dataclass(frozen=True)
class Luminance(StageBase):
    """Exposure (BaselineExposure + EV) and a global tone curve on luminance.

    Parameters
    ----------
    exposure : float
        Extra exposure in EV (stops), added to the file's BaselineExposure.
    baseline : bool
        Honour the DNG BaselineExposure tag.
    tone : {"none", "reinhard", "aces"}
        Global tone curve on luminance (chromaticity preserved).
    white : float
        White point of the Reinhard curve (linear, after exposure).
    """

    name = "luminance"
    consumes = (Domain.CAMERA_RGB, Domain.LINEAR_RGB)

    exposure: float = 0.0
    baseline: bool = True
    tone: Literal["none", "reinhard", "aces"] = "none"
    white: float = 4.0

    def __post_init__(self):
        if not -16 <= self.exposure <= 16:
            raise ValueError(f"exposure must be within ±16 EV, got {self.exposure}")
        if self.white <= 0:
            raise ValueError(f"white must be positive, got {self.white}")

    def process(self, frame: Frame) -> Frame:
        be = frame.meta.baseline_exposure if self.baseline else None
        ev = (be or 0.0) + self.exposure
        if not -32 <= ev <= 32:
            raise InputError(frame.meta.path, f"exposure {ev:+.3g} EV is out of range")
        gain = float(2.0 ** ev)
        w = luminance_weights(frame) if self.tone != "none" else BT709_Y
        out = adjust_luminance(frame.data, gain, w, self.tone, self.white)
        note = f"{ev:+.2f} EV" + (f" (baseline {be:+.2f})" if be else "") + \
            (f", tone {self.tone}" if self.tone != "none" else "")
        return frame.evolve(out, stage=self.name, note=note)

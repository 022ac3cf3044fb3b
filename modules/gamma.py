"""Encoding linear RGB for display: the sRGB (or BT.709, or pure power) OETF.

References
----------
* IEC 61966-2-1:1999, *Colour management — Default RGB colour space — sRGB*,
  clause 5.2: ``V = 12.92 L`` for ``L ≤ 0.0031308``, else
  ``V = 1.055 L^(1/2.4) − 0.055``.
* ITU-R BT.709-6 (2015), item 1.2: ``V = 4.5 L`` for ``L < 0.018``, else
  ``V = 1.099 L^0.45 − 0.099``.

This is the encoding stage: the first place values are clipped, to [0, 1].
The same functions run on numpy arrays and torch tensors (training applies
them differentiably after the correction slot). On numpy float32 the
pipeline uses a 65,536-entry table of the same function (max error 1e-4,
far below an 8-bit step of 3.9e-3), because a per-pixel ``power`` over a
16 MP frame costs ~1 s.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np

from isp.frame import Domain, Frame
from isp.stage import StageBase

from modules.common.xp import array_namespace, is_numpy_array

_LUT_SIZE = 65536


def srgb_oetf(x):
    """sRGB encoding (IEC 61966-2-1:1999, 5.2) of linear values, clipped to
    [0, 1].

    Parameters
    ----------
    x : array (numpy or torch), linear, any shape

    Returns
    -------
    array of x's shape and type, in [0, 1].

    >>> float(srgb_oetf(np.array(0.18)))  # mid grey
    0.4613561295004...
    """
    xp = array_namespace(x)
    x = xp.clip(x, 0.0, 1.0)
    # the power of a tiny positive number keeps the torch gradient finite
    return xp.where(x <= 0.0031308, 12.92 * x,
                    1.055 * xp.pow(xp.clip(x, 0.0031308, 1.0), 1.0 / 2.4) - 0.055)


def srgb_eotf(v):
    """Inverse of :func:`srgb_oetf` (IEC 61966-2-1:1999, 5.2): encoded → linear.

    >>> float(srgb_eotf(srgb_oetf(np.array(0.5))))
    0.5
    """
    xp = array_namespace(v)
    v = xp.clip(v, 0.0, 1.0)
    return xp.where(v <= 0.04045, v / 12.92, xp.pow((xp.clip(v, 0.04045, 1.0) + 0.055) / 1.055, 2.4))


def bt709_oetf(x):
    """ITU-R BT.709-6 OETF, clipped to [0, 1]."""
    xp = array_namespace(x)
    x = xp.clip(x, 0.0, 1.0)
    return xp.where(x < 0.018, 4.5 * x, 1.099 * xp.pow(xp.clip(x, 0.018, 1.0), 0.45) - 0.099)


def power_oetf(x, exponent: float = 2.2):
    """Pure power encoding ``V = L^(1/exponent)``, clipped to [0, 1]."""
    xp = array_namespace(x)
    return xp.pow(xp.clip(x, 0.0, 1.0), 1.0 / exponent)


CURVES = {"srgb": srgb_oetf, "bt709": bt709_oetf, "power": power_oetf}


@lru_cache(maxsize=8)
def _lut(curve: str, exponent: float) -> np.ndarray:
    x = np.linspace(0.0, 1.0, _LUT_SIZE, dtype=np.float64)
    f = CURVES[curve]
    y = f(x, exponent) if curve == "power" else f(x)
    return y.astype(np.float32)


def encode(x, curve: str = "srgb", exponent: float = 2.2):
    """Encode linear RGB with the named curve (numpy: table lookup of the
    same function; torch: the function itself).

    Parameters
    ----------
    x : array, linear
    curve : {"srgb", "bt709", "power"}
    exponent : float
        For ``curve="power"``.
    """
    if curve not in CURVES:
        raise ValueError(f"unknown curve {curve!r}; valid: {', '.join(CURVES)}")
    if is_numpy_array(x) and x.dtype == np.float32 and x.ndim >= 2:
        import cv2

        # one multithreaded pass: scale, round, saturate to 0..65535 (NaN → 0)
        idx = cv2.multiply(np.ascontiguousarray(x).reshape(x.shape[0], -1), float(_LUT_SIZE - 1),
                           dtype=cv2.CV_16U)
        table = _lut(curve, float(exponent))
        try:  # OpenCV >= 5 looks up 16-bit indices, multithreaded
            return cv2.LUT(idx, table).reshape(x.shape)
        except cv2.error:  # older OpenCV: numpy's (single-threaded) gather
            return table[idx].reshape(x.shape)
    f = CURVES[curve]
    return f(x, exponent) if curve == "power" else f(x)


@dataclass(frozen=True)
class Gamma(StageBase):
    """Encode linear RGB for display (sRGB OETF by default); clips to [0, 1].

    Parameters
    ----------
    curve : {"srgb", "bt709", "power"}
    exponent : float
        Display exponent for ``curve="power"`` (V = L^(1/exponent)).
    """

    name = "gamma"
    consumes = (Domain.LINEAR_RGB,)
    produces = Domain.DISPLAY_RGB

    curve: Literal["srgb", "bt709", "power"] = "srgb"
    exponent: float = 2.2

    def __post_init__(self):
        if not 0.1 <= self.exponent <= 10:
            raise ValueError(f"exponent must be in [0.1, 10], got {self.exponent}")

    def process(self, frame: Frame) -> Frame:
        out = encode(frame.data, self.curve, self.exponent)
        note = self.curve if self.curve != "power" else f"power 1/{self.exponent:g}"
        return frame.evolve(out, domain=Domain.DISPLAY_RGB, stage=self.name, note=note)

"""Bad-pixel opcodes: FixBadPixelsConstant (ID 4) and FixBadPixelsList
(ID 5), stored and validated, not applied (DNG 1.7.1.0, chapter 7; SDK
``dng_bad_pixels.cpp``)."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from isp.opcodes.base import Opcode
from isp.opcodes.binary import U32_MAX, OpcodeError, as_u32, expect_size, frozen_array, set_field

# --------------------------------------------------------------------------
# bad pixels

@dataclass(frozen=True, repr=False)
class FixBadPixelsConstant(Opcode):
    """Pixels equal to a constant are bad and interpolated (ID 4).

    Parameters: uint32 Constant (the marker value, DN), uint32 BayerPhase
    (0..3: position of the top-left pixel's colour in the 2x2 pattern).
    """

    ID = 4
    constant: int
    bayer_phase: int

    def _validate(self):
        set_field(self, "constant", as_u32(self.constant, "constant"))
        set_field(self, "bayer_phase", as_u32(self.bayer_phase, "Bayer phase"))

    def _params(self):
        return struct.pack(">II", self.constant, self.bayer_phase)

    @classmethod
    def _parse(cls, r, size, **header):
        expect_size(size, 8, "constant and Bayer phase")
        return cls(*r.u32s(2, "parameters"), **header)

    def _describe(self):
        return {"constant": self.constant, "bayer_phase": self.bayer_phase}


@dataclass(frozen=True, eq=False, repr=False)
class FixBadPixelsList(Opcode):
    """Listed bad pixels and rectangles are interpolated (ID 5).

    Parameters: uint32 BayerPhase, BadPointCount, BadRectCount; then per
    point uint32 row, col; then per rectangle uint32 top, left, bottom,
    right. The order is kept as stored (the SDK sorts after reading).

    Attributes
    ----------
    bayer_phase : int
    points : (P, 2) ndarray of uint32
        (row, col) of each bad pixel.
    rects : (R, 4) ndarray of uint32
        (top, left, bottom, right) of each bad rectangle, bottom/right
        exclusive.
    """

    ID = 5
    bayer_phase: int
    points: Any = ()
    rects: Any = ()

    def _validate(self):
        set_field(self, "bayer_phase", as_u32(self.bayer_phase, "Bayer phase"))
        for name, width in (("points", 2), ("rects", 4)):
            raw = np.asarray(getattr(self, name))
            a = raw.reshape(-1, width) if raw.size == 0 else raw
            if a.ndim != 2 or a.shape[1] != width:
                raise OpcodeError(f"{name} must have shape (n, {width}), got {raw.shape}")
            if a.size and (np.any(a < 0) or np.any(a > U32_MAX) or np.any(a != np.round(a))):
                raise OpcodeError(f"{name} must hold integers in 0..{U32_MAX}")
            set_field(self, name, frozen_array(a, np.uint32, 2, name))

    def _params(self):
        return (struct.pack(">III", self.bayer_phase, len(self.points), len(self.rects))
                + self.points.astype(">u4").tobytes() + self.rects.astype(">u4").tobytes())

    @classmethod
    def _parse(cls, r, size, **header):
        phase, n_points, n_rects = r.u32s(3, "counts")
        expect_size(size, 12 + 8 * n_points + 16 * n_rects,
                     f"{n_points} bad points and {n_rects} bad rectangles")
        points = r.array(">u4", 2 * n_points, "bad points").reshape(n_points, 2)
        rects = r.array(">u4", 4 * n_rects, "bad rectangles").reshape(n_rects, 4)
        return cls(phase, points, rects, **header)

    def _describe(self):
        return {"bayer_phase": self.bayer_phase, "bad_points": int(len(self.points)),
                "bad_rects": int(len(self.rects))}

"""TrimBounds (ID 6): crop the image to a rectangle (DNG 1.7.1.0,
chapter 7; SDK ``dng_misc_opcodes.cpp``)."""

from __future__ import annotations

import struct
from dataclasses import dataclass

from isp.opcodes.base import Opcode
from isp.opcodes.binary import OpcodeError, as_u32, expect_size, set_field

# --------------------------------------------------------------------------
# trim

@dataclass(frozen=True, repr=False)
class TrimBounds(Opcode):
    """Crop the image to a rectangle (ID 6).

    Parameters: uint32 top, left, bottom, right (pixels, bottom/right
    exclusive); the rectangle must not be empty.
    """

    ID = 6
    top: int
    left: int
    bottom: int
    right: int

    def _validate(self):
        for name in ("top", "left", "bottom", "right"):
            set_field(self, name, as_u32(getattr(self, name), name))
        if self.top >= self.bottom or self.left >= self.right:
            raise OpcodeError(f"bounds ({self.top}, {self.left}, {self.bottom}, "
                              f"{self.right}) are empty")

    def _params(self):
        return struct.pack(">4I", self.top, self.left, self.bottom, self.right)

    @classmethod
    def _parse(cls, r, size, **header):
        expect_size(size, 16, "the bounds")
        return cls(*r.u32s(4, "bounds"), **header)

    def _describe(self):
        return {"bounds": [self.top, self.left, self.bottom, self.right]}

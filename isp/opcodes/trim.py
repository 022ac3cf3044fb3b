"""TrimBounds (ID 6): crop the image to a rectangle (DNG 1.7.1.0,
chapter 7; SDK ``dng_misc_opcodes.cpp``)."""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from isp.opcodes.base import Opcode, OpcodeContext
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

    def unsupported(self, stage, planes):
        if stage == 1:
            return ("trimming the stored image moves the origin the ActiveArea is measured "
                    "from; not supported in OpcodeList1")
        return None

    def window(self, shape, ctx: OpcodeContext) -> tuple[tuple[slice, slice], OpcodeContext]:
        """What trimming does to data of ``shape`` placed by ``ctx``.

        Returns
        -------
        (rows, cols), context
            The slices of the data inside the bounds, and the context of the
            trimmed image: its top-left pixel is the bounds' (Top, Left), its
            size theirs (SDK ``dng_simple_image::Trim`` re-bases the image
            at the origin), so later opcodes of the list address it anew.

        Raises
        ------
        OpcodeError
            Where the bounds do not lie inside the image (the SDK's
            ``ThrowBadFormat``) or miss the data.
        """
        h, w = ctx.size(shape)
        if self.bottom > h or self.right > w:
            raise OpcodeError(f"bounds ({self.top}, {self.left}, {self.bottom}, {self.right}) "
                              f"do not lie inside the {w}x{h} image", name=self.name)
        oy, ox = ctx.origin
        r0, r1 = max(self.top - oy, 0), min(self.bottom - oy, int(shape[0]))
        c0, c1 = max(self.left - ox, 0), min(self.right - ox, int(shape[1]))
        if r0 >= r1 or c0 >= c1:
            raise OpcodeError(f"bounds ({self.top}, {self.left}, {self.bottom}, {self.right}) "
                              f"miss the {shape[1]}x{shape[0]} data at {ctx.origin}",
                              name=self.name)
        return ((slice(r0, r1), slice(c0, c1)),
                ctx.moved(self.top, self.left, (self.bottom - self.top, self.right - self.left)))

    def apply(self, data: np.ndarray, ctx: OpcodeContext) -> np.ndarray:
        """The data inside the bounds (a view), DNG 1.7.1.0 ch. 7
        TrimBounds. Later opcodes need the context :meth:`window` returns."""
        self._check_apply(data, ctx)
        (rows, cols), _ = self.window(data.shape, ctx)
        return data[rows, cols]

    def _describe(self):
        return {"bounds": [self.top, self.left, self.bottom, self.right]}

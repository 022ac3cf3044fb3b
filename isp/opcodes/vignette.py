"""FixVignetteRadial (ID 3): radial vignetting correction and its gain
field as the SDK computes it (DNG 1.7.1.0, chapter 7; SDK
``dng_lens_correction.cpp``)."""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from isp.opcodes.base import Opcode, OpcodeContext
from isp.opcodes.binary import OpcodeError, as_floats, check_center, expect_size, set_field

# --------------------------------------------------------------------------
# vignette

@dataclass(frozen=True, repr=False)
class FixVignetteRadial(Opcode):
    """Radial vignetting correction (ID 3).

    Parameters: float64 k0..k4, then float64 cx, cy, the optical centre
    relative to the image (0..1).

    Attributes
    ----------
    k : tuple of 5 float
        Coefficients of r^2, r^4, r^6, r^8, r^10.
    center_x, center_y : float
        Optical centre, fractions of the image width and height.
    """

    ID = 3
    k: tuple
    center_x: float = 0.5
    center_y: float = 0.5

    def _validate(self):
        set_field(self, "k", as_floats(self.k, 5, "k"))
        set_field(self, "center_x", float(self.center_x))
        set_field(self, "center_y", float(self.center_y))
        check_center(self.center_x, self.center_y)

    def _params(self):
        return struct.pack(">7d", *self.k, self.center_x, self.center_y)

    @classmethod
    def _parse(cls, r, size, **header):
        expect_size(size, 56, "5 coefficients and the optical centre")
        values = r.f64s(7, "coefficients")
        return cls(values[:5], values[5], values[6], **header)

    def evaluate(self, height: int, width: int, *, pixel_aspect_ratio: float = 1.0
                 ) -> np.ndarray:
        """The gain field of an image of ``height`` x ``width`` pixels.

        Parameters
        ----------
        height, width : int
            Size in pixels of the image the opcode applies to.
        pixel_aspect_ratio : float, optional
            DNG ``DefaultScale`` H/V ratio (PixelAspectRatio); 1 for square
            pixels.

        Returns
        -------
        gain : (height, width) ndarray of float32
            Multiplicative gain, dimensionless (>= 1 for a correction).

        Notes
        -----
        As the SDK (``dng_opcode_FixVignetteRadial::Prepare``,
        ``RefVignetteMask16``) computes it, at pixel centres:

        .. math::

            c_y = c_y^{rel} H,\\quad c_x = c_x^{rel} W,\\quad
            R = \\operatorname{hypot}(s\\max(c_y, H - c_y),\\ \\max(c_x, W - c_x))

            r^2 = \\min\\left(1, \\frac{(s(i + 0.5 - c_y))^2 + (j + 0.5 - c_x)^2}{R^2}\\right)

            g = 1 + k_0 r^2 + k_1 r^4 + k_2 r^6 + k_3 r^8 + k_4 r^{10}

        with :math:`s = 1/\\text{pixel aspect ratio}`: R is the distance from
        the optical centre to the farthest image corner (pixel edges), so
        r <= 1 inside the image. The SDK then quantises g through a 16-bit
        table (about 1e-5 relative); this is the exact formula.
        """
        h, w = int(height), int(width)
        if h < 1 or w < 1:
            raise ValueError(f"image size must be positive, got {height}x{width}")
        if not (math.isfinite(pixel_aspect_ratio) and pixel_aspect_ratio > 0):
            raise ValueError(f"pixel_aspect_ratio must be finite and > 0, "
                             f"got {pixel_aspect_ratio!r}")
        s = 1.0 / float(pixel_aspect_ratio)
        cy, cx = self.center_y * h, self.center_x * w
        radius = math.hypot(max(cy, h - cy) * s, max(cx, w - cx))
        dv = ((np.arange(h) + 0.5 - cy) * (s / radius)).astype(np.float32)
        dh = ((np.arange(w) + 0.5 - cx) / radius).astype(np.float32)
        r2 = np.minimum(dv[:, None] ** 2 + dh[None, :] ** 2, np.float32(1.0))
        gain = np.full_like(r2, self.k[4])
        for coeff in self.k[3::-1]:           # Horner in r^2
            gain *= r2
            gain += np.float32(coeff)
        gain *= r2
        gain += np.float32(1.0)
        return gain

    def apply(self, data: np.ndarray, ctx: OpcodeContext) -> np.ndarray:
        """Multiply every plane by the gain field of the list's image
        (:meth:`evaluate` at its size, cut to the window ``data`` is), in
        place (SDK ``dng_opcode_FixVignetteRadial::ProcessArea``). Stage-1
        results are rounded and clipped to 0..``code_max``. Returns
        ``data``."""
        self._check_apply(data, ctx)
        if not all(math.isfinite(k) for k in self.k):
            raise OpcodeError(f"non-finite coefficients {self.k}", name=self.name)
        h, w = ctx.size(data.shape)
        oy, ox = ctx.origin
        g = self.evaluate(h, w, pixel_aspect_ratio=ctx.pixel_aspect_ratio)[
            oy:oy + data.shape[0], ox:ox + data.shape[1]]
        if data.ndim == 3:
            g = g[:, :, None]
        np.multiply(data, g, out=data, casting="unsafe")
        if ctx.stage == 1:
            np.clip(np.rint(data, out=data), 0.0, ctx.code_max, out=data)
        return data

    def _describe(self):
        return {"k": list(self.k), "center": [self.center_x, self.center_y]}

"""Lens-distortion warps: WarpRectilinear (ID 1), WarpFisheye (ID 2) and
WarpRectilinear2 (ID 14, DNG 1.6), stored and validated, not applied
(DNG 1.7.1.0, chapter 7; SDK ``dng_lens_correction.cpp``)."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import ClassVar

from isp.opcodes.base import MAX_WARP_PLANES, Opcode
from isp.opcodes.binary import OpcodeError, Reader, as_floats, as_u32, check_center, expect_size, set_field

# --------------------------------------------------------------------------
# warps

def _plane_rows(rows, width: int, what: str) -> tuple[tuple[float, ...], ...]:
    out = tuple(as_floats(r, width, what) for r in rows)
    if not 1 <= len(out) <= MAX_WARP_PLANES:
        raise OpcodeError(f"{what}: {len(out)} planes, must be 1..{MAX_WARP_PLANES}")
    return out


def _read_warp_planes(r: Reader, size: int, per_plane: int, tail: int, name: str) -> int:
    planes = r.u32("plane count")
    if not 1 <= planes <= MAX_WARP_PLANES:
        raise OpcodeError(f"plane count is {planes}, must be 1..{MAX_WARP_PLANES}")
    expect_size(size, 4 + 8 * per_plane * planes + tail,
                 f"{planes} plane(s) of {name} coefficients")
    return planes


@dataclass(frozen=True, repr=False)
class WarpRectilinear(Opcode):
    """Radial and tangential distortion of a rectilinear lens (ID 1).

    Parameters: uint32 N planes (1 or the image's colour planes); per plane
    float64 kr0, kr1, kr2, kr3 (radial, r^0..r^6) and kt0, kt1
    (tangential); then float64 cx, cy, the optical centre relative to the
    image (0..1, 0 = left/top edge).

    Attributes
    ----------
    radial : tuple of N (kr0, kr1, kr2, kr3)
    tangential : tuple of N (kt0, kt1)
    center_x, center_y : float
        Optical centre, fractions of the image width and height.
    """

    ID = 1
    radial: tuple
    tangential: tuple
    center_x: float = 0.5
    center_y: float = 0.5

    def _validate(self):
        set_field(self, "radial", _plane_rows(self.radial, 4, "radial coefficients"))
        set_field(self, "tangential", _plane_rows(self.tangential, 2, "tangential coefficients"))
        if len(self.tangential) != len(self.radial):
            raise OpcodeError(f"{len(self.radial)} radial but {len(self.tangential)} "
                              "tangential planes")
        set_field(self, "center_x", float(self.center_x))
        set_field(self, "center_y", float(self.center_y))
        check_center(self.center_x, self.center_y)

    @property
    def planes(self) -> int:
        return len(self.radial)

    def _params(self):
        values = [v for kr, kt in zip(self.radial, self.tangential) for v in kr + kt]
        values += [self.center_x, self.center_y]
        return struct.pack(f">I{len(values)}d", self.planes, *values)

    @classmethod
    def _parse(cls, r, size, **header):
        n = _read_warp_planes(r, size, 6, 16, "WarpRectilinear")
        coeffs = [r.f64s(6, "plane coefficients") for _ in range(n)]
        cx, cy = r.f64s(2, "optical centre")
        return cls(tuple(c[:4] for c in coeffs), tuple(c[4:] for c in coeffs), cx, cy,
                   **header)

    def _describe(self):
        return {"planes": self.planes, "radial": [list(k) for k in self.radial],
                "tangential": [list(k) for k in self.tangential],
                "center": [self.center_x, self.center_y]}


@dataclass(frozen=True, repr=False)
class WarpFisheye(Opcode):
    """Fisheye-to-rectilinear remapping (ID 2).

    Parameters: uint32 N planes; per plane float64 kr0..kr3; then float64
    cx, cy (optical centre relative to the image, 0..1).

    Attributes
    ----------
    radial : tuple of N (kr0, kr1, kr2, kr3)
    center_x, center_y : float
    """

    ID = 2
    radial: tuple
    center_x: float = 0.5
    center_y: float = 0.5

    def _validate(self):
        set_field(self, "radial", _plane_rows(self.radial, 4, "radial coefficients"))
        set_field(self, "center_x", float(self.center_x))
        set_field(self, "center_y", float(self.center_y))
        check_center(self.center_x, self.center_y)

    @property
    def planes(self) -> int:
        return len(self.radial)

    def _params(self):
        values = [v for kr in self.radial for v in kr] + [self.center_x, self.center_y]
        return struct.pack(f">I{len(values)}d", self.planes, *values)

    @classmethod
    def _parse(cls, r, size, **header):
        n = _read_warp_planes(r, size, 4, 16, "WarpFisheye")
        radial = tuple(r.f64s(4, "plane coefficients") for _ in range(n))
        cx, cy = r.f64s(2, "optical centre")
        return cls(radial, cx, cy, **header)

    def _describe(self):
        return {"planes": self.planes, "radial": [list(k) for k in self.radial],
                "center": [self.center_x, self.center_y]}


@dataclass(frozen=True, repr=False)
class WarpRectilinear2(Opcode):
    """Rectilinear warp with 15 radial terms and a valid radius range
    (ID 14, DNG 1.6).

    Parameters (SDK ``dng_opcode_WarpRectilinear2``): uint32 N planes; per
    plane float64 kr0..kr14 (radial polynomial in r, all powers), kt0, kt1
    (tangential), min and max valid radius (0 <= min < max <= 1); then
    float64 cx, cy; then uint32 reciprocal flag (non-zero: the radial
    polynomial gives the reciprocal of the ratio).

    Attributes
    ----------
    radial : tuple of N tuples of 15 float
    tangential : tuple of N (kt0, kt1)
    valid_range : tuple of N (min_radius, max_radius)
    center_x, center_y : float
    reciprocal : int
        The stored uint32 (kept as is for byte-exact round trips).
    """

    ID = 14
    MIN_VERSION = (1, 6, 0, 0)
    RADIAL_TERMS: ClassVar[int] = 15
    radial: tuple
    tangential: tuple
    valid_range: tuple
    center_x: float = 0.5
    center_y: float = 0.5
    reciprocal: int = 0

    def _validate(self):
        set_field(self, "radial", _plane_rows(self.radial, self.RADIAL_TERMS, "radial coefficients"))
        set_field(self, "tangential", _plane_rows(self.tangential, 2, "tangential coefficients"))
        set_field(self, "valid_range", _plane_rows(self.valid_range, 2, "valid radius range"))
        n = len(self.radial)
        if len(self.tangential) != n or len(self.valid_range) != n:
            raise OpcodeError(f"plane counts differ: radial {n}, tangential "
                              f"{len(self.tangential)}, valid range {len(self.valid_range)}")
        for p, (lo, hi) in enumerate(self.valid_range):
            if not 0.0 <= lo < hi <= 1.0:   # SDK dng_warp_params_radial::IsValid
                raise OpcodeError(f"plane {p}: valid radius range ({lo!r}, {hi!r}) "
                                  "must satisfy 0 <= min < max <= 1")
        set_field(self, "center_x", float(self.center_x))
        set_field(self, "center_y", float(self.center_y))
        check_center(self.center_x, self.center_y)
        set_field(self, "reciprocal", as_u32(self.reciprocal, "reciprocal flag"))

    @property
    def planes(self) -> int:
        return len(self.radial)

    def _params(self):
        values = [v for kr, kt, vr in zip(self.radial, self.tangential, self.valid_range)
                  for v in kr + kt + vr]
        values += [self.center_x, self.center_y]
        return (struct.pack(f">I{len(values)}d", self.planes, *values)
                + struct.pack(">I", self.reciprocal))

    @classmethod
    def _parse(cls, r, size, **header):
        n = _read_warp_planes(r, size, cls.RADIAL_TERMS + 4, 20, "WarpRectilinear2")
        k = cls.RADIAL_TERMS
        coeffs = [r.f64s(k + 4, "plane coefficients") for _ in range(n)]
        cx, cy = r.f64s(2, "optical centre")
        reciprocal = r.u32("reciprocal flag")
        return cls(tuple(c[:k] for c in coeffs), tuple(c[k:k + 2] for c in coeffs),
                   tuple(c[k + 2:] for c in coeffs), cx, cy, reciprocal, **header)

    def _describe(self):
        return {"planes": self.planes, "radial": [list(k) for k in self.radial],
                "tangential": [list(k) for k in self.tangential],
                "valid_range": [list(v) for v in self.valid_range],
                "center": [self.center_x, self.center_y], "reciprocal": self.reciprocal}

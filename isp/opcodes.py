"""DNG opcode lists (OpcodeList1/2/3): parse, serialize, evaluate.

A DNG carries up to three *opcode lists*, processing steps the raw converter
applies at three points of its pipeline: OpcodeList1 to the raw data as
stored, OpcodeList2 after linearisation (black level subtracted, white = 1),
OpcodeList3 after demosaicing. Phone DNGs use them mostly for lens shading
(``GainMap``, one per CFA phase or one 3-plane map), sometimes for lossy-DNG
linearisation (``MapPolynomial``) and lens distortion (``WarpRectilinear``).

This module reads a list into typed, immutable opcode objects, writes them
back byte for byte, and evaluates the ones whose maths the pipeline needs
(gain maps, vignette, polynomial and table maps). It does not apply anything
to an image: which opcode runs where is the pipeline stages' decision.

Binary layout (all big-endian)
------------------------------
==========================  ===============================================
item                        bytes
==========================  ===============================================
list                        uint32 count, then ``count`` opcodes
opcode header               uint32 opcode ID, 4 bytes DNG version
                            (e.g. ``01 03 00 00``), uint32 flags (bit 0
                            optional, bit 1 may be skipped for previews),
                            uint32 parameter byte count N
opcode parameters           N bytes, laid out per opcode (see each class)
area spec                   uint32 Top, Left, Bottom, Right, Plane, Planes,
                            RowPitch, ColPitch (32 bytes)
==========================  ===============================================

Parsing is strict, as the reference implementation is: a parameter byte
count that disagrees with the content, a count that does not fit the bytes
that follow, trailing bytes after the last opcode, or values the SDK
refuses with ``ThrowBadFormat`` (a gain map with no points, a spacing
<= 0, an area with no planes, ...) raise :class:`OpcodeError`, and nothing
else is raised on any input: every count is checked against the remaining
bytes before anything is allocated. Opcodes this module does not know
(vendor or future IDs) are kept as :class:`UnknownOpcode` with their raw
parameter bytes, so they are listed and round-trip; they are never dropped.

Example
-------
>>> import numpy as np
>>> from isp.opcodes import AreaSpec, GainMap, parse_opcode_list, serialize_opcode_list
>>> gains = np.array([[[1.0], [2.0]], [[3.0], [4.0]]])   # 2 x 2 points, 1 plane
>>> gm = GainMap(AreaSpec(0, 0, 4, 6), gains, spacing_v=1.0, spacing_h=1.0)
>>> blob = serialize_opcode_list([gm])
>>> len(blob)                     # 4 + 16 (header) + 32 (area) + 44 + 4 gains
112
>>> (op,) = parse_opcode_list(blob)
>>> op.name, op.gains.shape, serialize_opcode_list([op]) == blob
('GainMap', (2, 2, 1), True)
>>> rows, cols = op.pixels(4, 6)
>>> # gain = 1 + 2 t_v + t_h at pixel centres, t = (i + 0.5) / size
>>> g = op.evaluate(rows[:2], cols[:2], 4, 6)      # float32, (2, 2)
>>> np.round(g.astype(float), 4).tolist()
[[1.3333, 1.5], [1.8333, 2.0]]

References
----------
Adobe Systems, *Digital Negative (DNG) Specification*, version 1.7.1.0
(2023), chapter 7 "Opcode List Processing" (opcode IDs, flags, the area
spec and each opcode's parameters); WarpRectilinear2 from version 1.6.0.0.

Adobe DNG SDK 1.7 (``dng_opcodes.cpp``, ``dng_opcode_list.cpp``,
``dng_misc_opcodes.cpp``, ``dng_gain_map.cpp``, ``dng_lens_correction.cpp``,
``dng_bad_pixels.cpp``): the reference implementation; layouts, validity
checks and the interpolation conventions here were checked against it.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from typing import Any, ClassVar, Iterable

import numpy as np

from .errors import IspError

__all__ = [
    "AreaSpec", "DeltaPerColumn", "DeltaPerRow", "FLAG_OPTIONAL",
    "FLAG_PREVIEW_SKIPPABLE", "FixBadPixelsConstant",
    "FixBadPixelsList", "FixVignetteRadial", "GainMap", "MapPolynomial",
    "MapTable", "OPCODE_NAMES", "Opcode", "OpcodeError", "ScalePerColumn",
    "ScalePerRow", "TrimBounds", "UnknownOpcode", "WarpFisheye",
    "WarpRectilinear", "WarpRectilinear2", "parse_opcode_list",
    "serialize_opcode_list",
]

#: Opcode ID -> name (DNG 1.7.1.0, chapter 7).
OPCODE_NAMES: dict[int, str] = {
    1: "WarpRectilinear",
    2: "WarpFisheye",
    3: "FixVignetteRadial",
    4: "FixBadPixelsConstant",
    5: "FixBadPixelsList",
    6: "TrimBounds",
    7: "MapTable",
    8: "MapPolynomial",
    9: "GainMap",
    10: "DeltaPerRow",
    11: "DeltaPerColumn",
    12: "ScalePerRow",
    13: "ScalePerColumn",
    14: "WarpRectilinear2",
}

#: Flag bit 0: a reader that cannot apply the opcode may skip it.
FLAG_OPTIONAL = 1
#: Flag bit 1: the opcode may be skipped when rendering a preview.
FLAG_PREVIEW_SKIPPABLE = 2

#: Most planes a warp opcode may describe (the SDK's ``kMaxColorPlanes``).
MAX_WARP_PLANES = 4
#: Highest MapPolynomial degree (the SDK's ``kMaxDegree``).
MAX_POLYNOMIAL_DEGREE = 8
#: Most MapTable entries: one per 16-bit input value.
MAX_TABLE_SIZE = 0x10000

_U32_MAX = 0xFFFFFFFF
_HEADER = struct.Struct(">I4BII")       # id, version[4], flags, byte count
_AREA = struct.Struct(">8I")
_GAIN_MAP_HEADER = struct.Struct(">II4dI")


class OpcodeError(IspError, ValueError):
    """An opcode list or an opcode that cannot be read or is invalid.

    The message is one line: which opcode (its 0-based position in the list
    and its name) and what is wrong, with the offending value, e.g.
    ``opcode #2 GainMap: declares 44 parameter bytes but needs 4172 for
    32x32x1 gains``.

    Attributes
    ----------
    reason : str
        What is wrong, without the opcode prefix.
    index : int or None
        0-based position of the opcode in its list, where known.
    name : str or None
        The opcode's name, where known.
    """

    def __init__(self, reason: str, *, index: int | None = None, name: str | None = None):
        self.reason = reason
        self.index = index
        self.name = name
        if index is not None:
            prefix = f"opcode #{index} {name}: " if name else f"opcode #{index}: "
        else:
            prefix = f"{name}: " if name else ""
        super().__init__(prefix + reason)


# --------------------------------------------------------------------------
# small helpers

class _Reader:
    """Bounds-checked big-endian reads from a byte buffer."""

    __slots__ = ("buf", "pos")

    def __init__(self, buf):
        self.buf = buf
        self.pos = 0

    def remaining(self) -> int:
        return len(self.buf) - self.pos

    def _need(self, n: int, what: str) -> None:
        if n > self.remaining():
            raise OpcodeError(f"truncated: {what} needs {n} bytes, only {self.remaining()} left")

    def u32s(self, n: int, what: str) -> tuple[int, ...]:
        self._need(4 * n, what)
        out = struct.unpack_from(f">{n}I", self.buf, self.pos)
        self.pos += 4 * n
        return out

    def u32(self, what: str) -> int:
        return self.u32s(1, what)[0]

    def f64s(self, n: int, what: str) -> tuple[float, ...]:
        self._need(8 * n, what)
        out = struct.unpack_from(f">{n}d", self.buf, self.pos)
        self.pos += 8 * n
        return out

    def array(self, dtype: str, n: int, what: str) -> np.ndarray:
        """``n`` items of big-endian ``dtype`` as a native-order copy."""
        dt = np.dtype(dtype)
        self._need(dt.itemsize * n, what)
        a = np.frombuffer(self.buf, dtype=dt, count=n, offset=self.pos)
        self.pos += dt.itemsize * n
        return a.astype(dt.newbyteorder("="))

    def raw(self, n: int, what: str) -> bytes:
        self._need(n, what)
        out = bytes(self.buf[self.pos:self.pos + n])
        self.pos += n
        return out


def _u32(value, what: str) -> int:
    """``value`` as an int in 0..2**32-1, or OpcodeError naming it."""
    try:
        v = int(value)
    except (TypeError, ValueError):
        raise OpcodeError(f"{what} must be an integer, got {value!r}") from None
    if v != value or not 0 <= v <= _U32_MAX:
        raise OpcodeError(f"{what} must be an integer in 0..{_U32_MAX}, got {value!r}")
    return v


def _floats(values, n: int | None, what: str) -> tuple[float, ...]:
    out = tuple(float(x) for x in values)
    if n is not None and len(out) != n:
        raise OpcodeError(f"{what} needs {n} values, got {len(out)}")
    return out


def _frozen_array(values, dtype, ndim: int, what: str) -> np.ndarray:
    a = np.array(values, dtype=dtype, order="C", copy=True)
    if a.ndim != ndim:
        raise OpcodeError(f"{what} must be {ndim}-D, got shape {a.shape}")
    a.setflags(write=False)
    return a


def _set(obj, name: str, value) -> None:
    object.__setattr__(obj, name, value)


def _expect_size(size: int, need: int, detail: str) -> None:
    if size != need:
        raise OpcodeError(f"declares {size} parameter bytes but needs {need} for {detail}")


def _check_center(cx: float, cy: float) -> None:
    # SDK: dng_warp_params::IsValid / dng_vignette_radial_params::IsValid.
    if not (0.0 <= cx <= 1.0 and 0.0 <= cy <= 1.0):
        raise OpcodeError(f"optical centre ({cx!r}, {cy!r}) must lie in [0, 1] x [0, 1]")


# --------------------------------------------------------------------------
# area spec

@dataclass(frozen=True)
class AreaSpec:
    """The image area, planes and pixel lattice an opcode applies to.

    Rows ``top, top + row_pitch, ...`` below ``bottom`` and columns
    ``left, left + col_pitch, ...`` below ``right`` of planes
    ``plane .. plane + planes - 1``. Coordinates are pixels of the image the
    opcode list applies to (for OpcodeList2: the stage-2 image, i.e. the
    active area). An *empty* rectangle (``top >= bottom`` or
    ``left >= right``) means the whole image, whatever its size (SDK
    ``dng_area_spec::Overlap``); its pitches must then be 1.

    Attributes
    ----------
    top, left, bottom, right : int
        Rectangle in pixels, bottom/right exclusive (uint32).
    plane, planes : int
        First plane and number of planes (``planes >= 1``).
    row_pitch, col_pitch : int
        Lattice steps in pixels (>= 1); 2 selects one CFA phase of a Bayer
        mosaic.
    """

    top: int
    left: int
    bottom: int
    right: int
    plane: int = 0
    planes: int = 1
    row_pitch: int = 1
    col_pitch: int = 1

    SIZE: ClassVar[int] = 32

    def __post_init__(self):
        for name in ("top", "left", "bottom", "right", "plane", "planes",
                     "row_pitch", "col_pitch"):
            _set(self, name, _u32(getattr(self, name), f"area {name}"))
        if self.planes < 1:
            raise OpcodeError(f"area planes is {self.planes}, must be >= 1")
        if self.row_pitch < 1 or self.col_pitch < 1:
            raise OpcodeError(f"area pitch is {self.row_pitch}x{self.col_pitch} "
                              "(rows x cols), must be >= 1")
        if self.is_empty and (self.row_pitch != 1 or self.col_pitch != 1):
            raise OpcodeError(
                f"area ({self.top}, {self.left}, {self.bottom}, {self.right}) is empty "
                f"(whole image) but its pitch is {self.row_pitch}x{self.col_pitch}, must be 1x1")

    @property
    def is_empty(self) -> bool:
        """True where the rectangle is empty, i.e. the area is the whole image."""
        return self.top >= self.bottom or self.left >= self.right

    @property
    def height(self) -> int:
        """Rectangle height in pixels (0 when empty)."""
        return 0 if self.is_empty else self.bottom - self.top

    @property
    def width(self) -> int:
        """Rectangle width in pixels (0 when empty)."""
        return 0 if self.is_empty else self.right - self.left

    def rows(self, image_height: int) -> np.ndarray:
        """Row indices (int64, ascending) of an image of ``image_height`` rows
        that the area covers, clipped to the image."""
        if self.is_empty:
            return np.arange(int(image_height), dtype=np.int64)
        return np.arange(self.top, min(self.bottom, int(image_height)), self.row_pitch,
                         dtype=np.int64)

    def cols(self, image_width: int) -> np.ndarray:
        """Column indices (int64, ascending) of an image of ``image_width``
        columns that the area covers, clipped to the image."""
        if self.is_empty:
            return np.arange(int(image_width), dtype=np.int64)
        return np.arange(self.left, min(self.right, int(image_width)), self.col_pitch,
                         dtype=np.int64)

    def to_bytes(self) -> bytes:
        """The 32-byte big-endian encoding."""
        return _AREA.pack(self.top, self.left, self.bottom, self.right,
                          self.plane, self.planes, self.row_pitch, self.col_pitch)

    def describe(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {"area": [self.top, self.left, self.bottom, self.right],
                "plane": self.plane, "planes": self.planes,
                "row_pitch": self.row_pitch, "col_pitch": self.col_pitch}

    @classmethod
    def _read(cls, r: _Reader) -> "AreaSpec":
        return cls(*r.u32s(8, "area spec"))


# --------------------------------------------------------------------------
# base class

@dataclass(frozen=True, eq=False)
class Opcode:
    """One opcode of a DNG opcode list (base class).

    Attributes
    ----------
    version : tuple of 4 int
        The DNG version the opcode needs, as stored (bytes, e.g.
        ``(1, 3, 0, 0)``). Defaults to the version that introduced it.
    flags : int
        uint32 flag bits; bit 0 = optional, bit 1 = skippable for previews.
        Other bits are kept as read.
    """

    ID: ClassVar[int] = -1
    MIN_VERSION: ClassVar[tuple[int, int, int, int]] = (1, 3, 0, 0)

    version: tuple | None = field(default=None, kw_only=True)
    flags: int = field(default=0, kw_only=True)

    def __post_init__(self):
        try:
            version = self.MIN_VERSION if self.version is None else tuple(self.version)
        except TypeError:
            version = ()
        if len(version) != 4 or not all(isinstance(v, (int, np.integer)) and 0 <= v <= 255
                                        for v in version):
            raise OpcodeError(f"version must be 4 integers 0..255, got {self.version!r}",
                              name=self.name)
        _set(self, "version", tuple(int(v) for v in version))
        try:
            _set(self, "flags", _u32(self.flags, "flags"))
            self._validate()
        except OpcodeError as err:
            if err.name is not None:
                raise
            raise OpcodeError(err.reason, name=self.name) from None

    def _validate(self) -> None:
        """Normalise and check the opcode's own fields (OpcodeError)."""

    # -- identity ---------------------------------------------------------
    @property
    def id(self) -> int:
        """The opcode ID (DNG 1.7.1.0, chapter 7)."""
        return self.ID

    @property
    def name(self) -> str:
        """The opcode's name in the specification, e.g. ``"GainMap"``."""
        return OPCODE_NAMES.get(self.id, f"Unknown({self.id})")

    @property
    def optional(self) -> bool:
        """Flag bit 0: a reader that does not support it may skip it."""
        return bool(self.flags & FLAG_OPTIONAL)

    @property
    def preview_skippable(self) -> bool:
        """Flag bit 1: may be skipped when rendering a preview."""
        return bool(self.flags & FLAG_PREVIEW_SKIPPABLE)

    # -- encoding ---------------------------------------------------------
    def _params(self) -> bytes:
        raise NotImplementedError

    def to_bytes(self) -> bytes:
        """The opcode's encoding: header (ID, version, flags, byte count)
        followed by its parameters."""
        params = self._params()
        return _HEADER.pack(self.id, *self.version, self.flags, len(params)) + params

    @classmethod
    def _parse(cls, r: _Reader, size: int, **header) -> "Opcode":
        raise NotImplementedError

    # -- reporting --------------------------------------------------------
    def _describe(self) -> dict[str, Any]:
        return {}

    def describe(self) -> dict[str, Any]:
        """A short JSON-ready summary: name, ID, version, flags and the key
        parameters (never whole arrays)."""
        out = {"name": self.name, "id": self.id,
               "version": ".".join(str(v) for v in self.version),
               "flags": self.flags, "optional": self.optional,
               "preview_skippable": self.preview_skippable}
        out.update(self._describe())
        return out

    def __repr__(self) -> str:
        d = self.describe()
        keep = {k: v for k, v in d.items() if k not in ("name", "id")}
        return f"{self.name}({keep})"


# --------------------------------------------------------------------------
# warps

def _plane_rows(rows, width: int, what: str) -> tuple[tuple[float, ...], ...]:
    out = tuple(_floats(r, width, what) for r in rows)
    if not 1 <= len(out) <= MAX_WARP_PLANES:
        raise OpcodeError(f"{what}: {len(out)} planes, must be 1..{MAX_WARP_PLANES}")
    return out


def _read_warp_planes(r: _Reader, size: int, per_plane: int, tail: int, name: str) -> int:
    planes = r.u32("plane count")
    if not 1 <= planes <= MAX_WARP_PLANES:
        raise OpcodeError(f"plane count is {planes}, must be 1..{MAX_WARP_PLANES}")
    _expect_size(size, 4 + 8 * per_plane * planes + tail,
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
        _set(self, "radial", _plane_rows(self.radial, 4, "radial coefficients"))
        _set(self, "tangential", _plane_rows(self.tangential, 2, "tangential coefficients"))
        if len(self.tangential) != len(self.radial):
            raise OpcodeError(f"{len(self.radial)} radial but {len(self.tangential)} "
                              "tangential planes")
        _set(self, "center_x", float(self.center_x))
        _set(self, "center_y", float(self.center_y))
        _check_center(self.center_x, self.center_y)

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
        _set(self, "radial", _plane_rows(self.radial, 4, "radial coefficients"))
        _set(self, "center_x", float(self.center_x))
        _set(self, "center_y", float(self.center_y))
        _check_center(self.center_x, self.center_y)

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
        _set(self, "radial", _plane_rows(self.radial, self.RADIAL_TERMS, "radial coefficients"))
        _set(self, "tangential", _plane_rows(self.tangential, 2, "tangential coefficients"))
        _set(self, "valid_range", _plane_rows(self.valid_range, 2, "valid radius range"))
        n = len(self.radial)
        if len(self.tangential) != n or len(self.valid_range) != n:
            raise OpcodeError(f"plane counts differ: radial {n}, tangential "
                              f"{len(self.tangential)}, valid range {len(self.valid_range)}")
        for p, (lo, hi) in enumerate(self.valid_range):
            if not 0.0 <= lo < hi <= 1.0:   # SDK dng_warp_params_radial::IsValid
                raise OpcodeError(f"plane {p}: valid radius range ({lo!r}, {hi!r}) "
                                  "must satisfy 0 <= min < max <= 1")
        _set(self, "center_x", float(self.center_x))
        _set(self, "center_y", float(self.center_y))
        _check_center(self.center_x, self.center_y)
        _set(self, "reciprocal", _u32(self.reciprocal, "reciprocal flag"))

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
        _set(self, "k", _floats(self.k, 5, "k"))
        _set(self, "center_x", float(self.center_x))
        _set(self, "center_y", float(self.center_y))
        _check_center(self.center_x, self.center_y)

    def _params(self):
        return struct.pack(">7d", *self.k, self.center_x, self.center_y)

    @classmethod
    def _parse(cls, r, size, **header):
        _expect_size(size, 56, "5 coefficients and the optical centre")
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

    def _describe(self):
        return {"k": list(self.k), "center": [self.center_x, self.center_y]}


# --------------------------------------------------------------------------
# bad pixels and trim

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
        _set(self, "constant", _u32(self.constant, "constant"))
        _set(self, "bayer_phase", _u32(self.bayer_phase, "Bayer phase"))

    def _params(self):
        return struct.pack(">II", self.constant, self.bayer_phase)

    @classmethod
    def _parse(cls, r, size, **header):
        _expect_size(size, 8, "constant and Bayer phase")
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
        _set(self, "bayer_phase", _u32(self.bayer_phase, "Bayer phase"))
        for name, width in (("points", 2), ("rects", 4)):
            raw = np.asarray(getattr(self, name))
            a = raw.reshape(-1, width) if raw.size == 0 else raw
            if a.ndim != 2 or a.shape[1] != width:
                raise OpcodeError(f"{name} must have shape (n, {width}), got {raw.shape}")
            if a.size and (np.any(a < 0) or np.any(a > _U32_MAX) or np.any(a != np.round(a))):
                raise OpcodeError(f"{name} must hold integers in 0..{_U32_MAX}")
            _set(self, name, _frozen_array(a, np.uint32, 2, name))

    def _params(self):
        return (struct.pack(">III", self.bayer_phase, len(self.points), len(self.rects))
                + self.points.astype(">u4").tobytes() + self.rects.astype(">u4").tobytes())

    @classmethod
    def _parse(cls, r, size, **header):
        phase, n_points, n_rects = r.u32s(3, "counts")
        _expect_size(size, 12 + 8 * n_points + 16 * n_rects,
                     f"{n_points} bad points and {n_rects} bad rectangles")
        points = r.array(">u4", 2 * n_points, "bad points").reshape(n_points, 2)
        rects = r.array(">u4", 4 * n_rects, "bad rectangles").reshape(n_rects, 4)
        return cls(phase, points, rects, **header)

    def _describe(self):
        return {"bayer_phase": self.bayer_phase, "bad_points": int(len(self.points)),
                "bad_rects": int(len(self.rects))}


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
            _set(self, name, _u32(getattr(self, name), name))
        if self.top >= self.bottom or self.left >= self.right:
            raise OpcodeError(f"bounds ({self.top}, {self.left}, {self.bottom}, "
                              f"{self.right}) are empty")

    def _params(self):
        return struct.pack(">4I", self.top, self.left, self.bottom, self.right)

    @classmethod
    def _parse(cls, r, size, **header):
        _expect_size(size, 16, "the bounds")
        return cls(*r.u32s(4, "bounds"), **header)

    def _describe(self):
        return {"bounds": [self.top, self.left, self.bottom, self.right]}


# --------------------------------------------------------------------------
# value maps

@dataclass(frozen=True, eq=False, repr=False)
class MapTable(Opcode):
    """Map 16-bit values through a look-up table (ID 7).

    Parameters: area spec, uint32 TableSize (1..65536), uint16 table
    [TableSize]. Inputs at or beyond TableSize take the last entry.

    Attributes
    ----------
    area : AreaSpec
    table : (TableSize,) ndarray of uint16
    """

    ID = 7
    area: AreaSpec
    table: Any

    def _validate(self):
        table = np.asarray(self.table)
        if table.size and (np.any(table < 0) or np.any(table > 0xFFFF)
                           or np.any(table != np.round(table))):
            raise OpcodeError("table entries must be integers in 0..65535")
        table = _frozen_array(table, np.uint16, 1, "table")
        if not 1 <= table.size <= MAX_TABLE_SIZE:
            raise OpcodeError(f"table size is {table.size}, must be 1..{MAX_TABLE_SIZE}")
        _set(self, "table", table)

    def _params(self):
        return (self.area.to_bytes() + struct.pack(">I", self.table.size)
                + self.table.astype(">u2").tobytes())

    @classmethod
    def _parse(cls, r, size, **header):
        if size < AreaSpec.SIZE + 4:
            raise OpcodeError(f"declares {size} parameter bytes but needs at least "
                              f"{AreaSpec.SIZE + 4} for the area spec and table size")
        area = AreaSpec._read(r)
        n = r.u32("table size")
        if not 1 <= n <= MAX_TABLE_SIZE:
            raise OpcodeError(f"table size is {n}, must be 1..{MAX_TABLE_SIZE}")
        _expect_size(size, AreaSpec.SIZE + 4 + 2 * n, f"{n} table entries")
        return cls(area, r.array(">u2", n, "table"), **header)

    def lookup(self, values) -> np.ndarray:
        """Map 16-bit values (DN, integers 0..65535) as the SDK does.

        Returns
        -------
        ndarray of uint16, the shape of ``values``
            ``table[min(value, TableSize - 1)]``.
        """
        v = np.asarray(values)
        if v.size and (v.min() < 0 or v.max() > 0xFFFF):
            raise ValueError(f"values must lie in 0..65535, got {v.min()}..{v.max()}")
        return self.table[np.minimum(v.astype(np.int64), self.table.size - 1)]

    def evaluate(self, x) -> np.ndarray:
        """Map normalised values ``x`` (0..1, i.e. DN / 65535).

        Parameters
        ----------
        x : array_like of float
            Input values, 0..1; clipped to that range (the table is only
            defined on the 16-bit integers).

        Returns
        -------
        ndarray of float32, the shape of ``x``
            ``table[min(round(65535 x), TableSize - 1)] / 65535``: the SDK's
            lookup of the nearest 16-bit code, no interpolation between
            entries (DNG 1.7.1.0 ch. 7, MapTable; SDK ``RefMapArea16``).
        """
        x = np.asarray(x, dtype=np.float64)
        index = np.rint(np.clip(np.nan_to_num(x), 0.0, 1.0) * 65535.0).astype(np.int64)
        return (self.table[np.minimum(index, self.table.size - 1)]
                / np.float32(65535.0)).astype(np.float32)

    def _describe(self):
        out = self.area.describe()
        out.update(table_size=int(self.table.size), table_min=int(self.table.min()),
                   table_max=int(self.table.max()))
        return out


@dataclass(frozen=True, repr=False)
class MapPolynomial(Opcode):
    """Map values through a polynomial (ID 8).

    Parameters: area spec, uint32 Degree (0..8), float64 coefficients
    c0..c_Degree.

    Attributes
    ----------
    area : AreaSpec
    coefficients : tuple of float
        c0 .. c_Degree, lowest power first.
    """

    ID = 8
    area: AreaSpec
    coefficients: tuple

    def _validate(self):
        c = _floats(self.coefficients, None, "coefficients")
        if not 1 <= len(c) <= MAX_POLYNOMIAL_DEGREE + 1:
            raise OpcodeError(f"{len(c)} coefficients, must be 1..{MAX_POLYNOMIAL_DEGREE + 1} "
                              f"(degree 0..{MAX_POLYNOMIAL_DEGREE})")
        _set(self, "coefficients", c)

    @property
    def degree(self) -> int:
        """The stored degree (not reduced for zero leading coefficients)."""
        return len(self.coefficients) - 1

    def _params(self):
        return (self.area.to_bytes()
                + struct.pack(f">I{len(self.coefficients)}d", self.degree, *self.coefficients))

    @classmethod
    def _parse(cls, r, size, **header):
        if size < AreaSpec.SIZE + 4:
            raise OpcodeError(f"declares {size} parameter bytes but needs at least "
                              f"{AreaSpec.SIZE + 4} for the area spec and degree")
        area = AreaSpec._read(r)
        degree = r.u32("degree")
        if degree > MAX_POLYNOMIAL_DEGREE:
            raise OpcodeError(f"degree is {degree}, must be 0..{MAX_POLYNOMIAL_DEGREE}")
        _expect_size(size, AreaSpec.SIZE + 4 + 8 * (degree + 1),
                     f"{degree + 1} coefficients (degree {degree})")
        return cls(area, r.f64s(degree + 1, "coefficients"), **header)

    def evaluate(self, x) -> np.ndarray:
        """The polynomial at normalised values ``x``.

        Parameters
        ----------
        x : array_like of float
            Input values on the 0..1 scale of the image the list applies to
            (stage 2/3: black = 0, white = 1; stage 1: DN / 65535).

        Returns
        -------
        ndarray of float32, the shape of ``x``
            :math:`y = \\sum_i c_i x^i`, evaluated in float64. Not clipped:
            the SDK pins its output to [-1, 1] (``RefBaselineMapPoly32``)
            and, for 16-bit stage-1 data, to the 16-bit range; do that where
            the data convention needs it.
        """
        x = np.asarray(x, dtype=np.float64)
        y = np.full_like(x, self.coefficients[-1])
        for c in self.coefficients[-2::-1]:
            y *= x
            y += c
        return y.astype(np.float32)

    def _describe(self):
        out = self.area.describe()
        out.update(degree=self.degree, coefficients=list(self.coefficients))
        return out


# --------------------------------------------------------------------------
# gain map

def _interp_weights(pos: np.ndarray, origin: float, spacing: float, points: int) -> np.ndarray:
    """(len(pos), points) linear-interpolation weights of map samples at
    relative positions ``pos``, clamped to the first/last sample outside
    the map (no extrapolation), as ``dng_gain_map_interpolator`` does."""
    index = np.clip((pos - origin) / spacing, 0.0, points - 1)
    i0 = np.floor(index).astype(np.int64)
    frac = index - i0
    i1 = np.minimum(i0 + 1, points - 1)
    w = np.zeros((pos.size, points), dtype=np.float64)
    k = np.arange(pos.size)
    w[k, i0] = 1.0 - frac
    w[k, i1] += frac
    return w


@dataclass(frozen=True, eq=False, repr=False)
class GainMap(Opcode):
    """A 2-D map of gains, bilinearly interpolated over the image (ID 9):
    lens-shading (colour shading and vignetting) correction.

    Parameters: area spec; uint32 MapPointsV, MapPointsH; float64
    MapSpacingV, MapSpacingH, MapOriginV, MapOriginH; uint32 MapPlanes;
    float32 gains in the order [row][col][plane] (MapPointsV x MapPointsH x
    MapPlanes).

    Attributes
    ----------
    area : AreaSpec
        Which pixels and planes the gains multiply.
    gains : (MapPointsV, MapPointsH, MapPlanes) ndarray of float32
        The gains, dimensionless. Must be finite.
    spacing_v, spacing_h : float
        Distance between map points, as a fraction of the image height /
        width (> 0). Ignored, as stored, where that axis has one point.
    origin_v, origin_h : float
        Position of the first map point, as a fraction of the image height /
        width, measured from the image's top-left corner (not the area's).

    Notes
    -----
    Image plane ``p`` of the area uses map plane ``min(p, MapPlanes - 1)``
    (:meth:`map_plane_for`). With one point on an axis the SDK forces that
    axis's spacing to 1 and origin to 0 (:attr:`map_spacing`,
    :attr:`map_origin` give the values used); the stored ones are kept for
    byte-exact round trips.
    """

    ID = 9
    area: AreaSpec
    gains: Any
    spacing_v: float = 1.0
    spacing_h: float = 1.0
    origin_v: float = 0.0
    origin_h: float = 0.0

    HEADER_SIZE: ClassVar[int] = AreaSpec.SIZE + _GAIN_MAP_HEADER.size   # 76

    def _validate(self):
        gains = np.asarray(self.gains)
        if gains.ndim == 2:
            gains = gains[:, :, None]
        gains = _frozen_array(gains, np.float32, 3, "gains")
        if min(gains.shape) < 1:
            raise OpcodeError(f"map has {gains.shape[0]}x{gains.shape[1]} points and "
                              f"{gains.shape[2]} planes, each must be >= 1")
        bad = ~np.isfinite(gains)
        if bad.any():
            first = [int(i) for i in np.argwhere(bad)[0]]
            raise OpcodeError(f"{int(bad.sum())} non-finite gain(s), first "
                              f"{gains[tuple(first)]!r} at [{first[0]}][{first[1]}][{first[2]}]")
        _set(self, "gains", gains)
        for name in ("spacing_v", "spacing_h", "origin_v", "origin_h"):
            _set(self, name, float(getattr(self, name)))
        for axis, (sp, org) in zip("vh", zip(self.map_spacing, self.map_origin)):
            if not (math.isfinite(sp) and sp > 0.0):
                raise OpcodeError(f"map spacing {axis.upper()} is {sp!r}, must be > 0")
            if not math.isfinite(org):
                raise OpcodeError(f"map origin {axis.upper()} is {org!r}, must be finite")

    @classmethod
    def spanning_image(cls, gains, area: AreaSpec | None = None, **kw) -> "GainMap":
        """A map whose first and last points sit on the image's edges
        (origin 0, spacing 1 / (points - 1)), as most phones write them.
        ``area`` defaults to the whole image, every plane of the map."""
        g = np.asarray(gains)
        if g.ndim == 2:
            g = g[:, :, None]
        if g.ndim != 3:
            raise OpcodeError(f"gains must be 2-D or 3-D, got shape {g.shape}", name="GainMap")
        pv, ph = g.shape[:2]
        if area is None:
            area = AreaSpec(0, 0, 0, 0, 0, max(g.shape[2], 1))
        return cls(area, g, 1.0 / max(pv - 1, 1), 1.0 / max(ph - 1, 1), 0.0, 0.0, **kw)

    @property
    def points_v(self) -> int:
        """MapPointsV."""
        return self.gains.shape[0]

    @property
    def points_h(self) -> int:
        """MapPointsH."""
        return self.gains.shape[1]

    @property
    def map_planes(self) -> int:
        """MapPlanes."""
        return self.gains.shape[2]

    @property
    def map_spacing(self) -> tuple[float, float]:
        """(V, H) spacing used for interpolation (1 on a one-point axis)."""
        return (1.0 if self.points_v == 1 else self.spacing_v,
                1.0 if self.points_h == 1 else self.spacing_h)

    @property
    def map_origin(self) -> tuple[float, float]:
        """(V, H) origin used for interpolation (0 on a one-point axis)."""
        return (0.0 if self.points_v == 1 else self.origin_v,
                0.0 if self.points_h == 1 else self.origin_h)

    def map_plane_for(self, plane: int) -> int:
        """The map plane that image plane ``plane`` uses."""
        return min(int(plane), self.map_planes - 1)

    def pixels(self, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
        """Which pixels of a ``height`` x ``width`` image the map multiplies.

        Returns
        -------
        rows, cols : 1-D ndarrays of int64
            Row and column indices (the area's lattice, clipped to the
            image); the pixels are their outer product
            (``image[np.ix_(rows, cols)]``).
        """
        return self.area.rows(height), self.area.cols(width)

    def evaluate(self, rows, cols, image_height: int, image_width: int,
                 map_plane: int = 0) -> np.ndarray:
        """Gains at pixel coordinates, as the DNG SDK interpolates them.

        Parameters
        ----------
        rows, cols : 1-D array_like of int
            Pixel row and column indices in the image the opcode list
            applies to (0 = top/left of that image, not of the area).
        image_height, image_width : int
            Size of that image in pixels: the map's coordinates are
            fractions of it.
        map_plane : int, optional
            Which map plane (see :meth:`map_plane_for`).

        Returns
        -------
        gain : (len(rows), len(cols)) ndarray of float32
            Gain at each (row, col), dimensionless.

        Notes
        -----
        For row i (columns likewise), per ``dng_gain_map_interpolator``:

        .. math::

            v = \\frac{i + 0.5}{H},\\qquad
            t = \\operatorname{clip}\\left(\\frac{v - \\text{MapOriginV}}
                {\\text{MapSpacingV}},\\ 0,\\ \\text{MapPointsV} - 1\\right)

        and the gain is bilinear in (t_v, t_h) between the four surrounding
        map points; outside the map the nearest edge row/column of points
        holds (no extrapolation). The SDK steps the column interpolation
        incrementally in float32; the two agree to about 1e-6.
        Separable: a (rows x PointsV) and a (cols x PointsH) weight matrix,
        two matrix products.
        """
        h, w = int(image_height), int(image_width)
        if h < 1 or w < 1:
            raise ValueError(f"image size must be positive, got {image_height}x{image_width}")
        if not 0 <= int(map_plane) < self.map_planes:
            raise ValueError(f"map_plane {map_plane} out of range 0..{self.map_planes - 1}")
        r = np.asarray(rows, dtype=np.float64)
        c = np.asarray(cols, dtype=np.float64)
        if r.ndim != 1 or c.ndim != 1:
            raise ValueError(f"rows and cols must be 1-D, got shapes {r.shape} and {c.shape}")
        if not (np.isfinite(r).all() and np.isfinite(c).all()):
            raise ValueError("rows and cols must be finite pixel indices")
        (sv, sh), (ov, oh) = self.map_spacing, self.map_origin
        wr = _interp_weights((r + 0.5) / h, ov, sv, self.points_v)
        wc = _interp_weights((c + 0.5) / w, oh, sh, self.points_h)
        partial = (wr @ self.gains[:, :, int(map_plane)].astype(np.float64)).astype(np.float32)
        return partial @ wc.T.astype(np.float32)

    def _params(self):
        return (self.area.to_bytes()
                + _GAIN_MAP_HEADER.pack(self.points_v, self.points_h, self.spacing_v,
                                        self.spacing_h, self.origin_v, self.origin_h,
                                        self.map_planes)
                + self.gains.astype(">f4").tobytes())

    @classmethod
    def _parse(cls, r, size, **header):
        if size < cls.HEADER_SIZE:
            raise OpcodeError(f"declares {size} parameter bytes but needs at least "
                              f"{cls.HEADER_SIZE} for the area spec and map header")
        area = AreaSpec._read(r)
        pv, ph = r.u32s(2, "map points")
        sv, sh, ov, oh = r.f64s(4, "map spacing and origin")
        planes = r.u32("map planes")
        if min(pv, ph, planes) < 1:
            raise OpcodeError(f"map has {pv}x{ph} points and {planes} planes, "
                              "each must be >= 1")
        _expect_size(size, cls.HEADER_SIZE + 4 * pv * ph * planes,
                     f"{pv}x{ph}x{planes} gains")
        gains = r.array(">f4", pv * ph * planes, "gains").reshape(pv, ph, planes)
        return cls(area, gains, sv, sh, ov, oh, **header)

    def _describe(self):
        out = self.area.describe()
        out.update(points=[self.points_v, self.points_h], map_planes=self.map_planes,
                   spacing=[self.spacing_v, self.spacing_h],
                   origin=[self.origin_v, self.origin_h],
                   gain_min=float(self.gains.min()), gain_max=float(self.gains.max()))
        return out


# --------------------------------------------------------------------------
# per-row / per-column deltas and scales

@dataclass(frozen=True, eq=False, repr=False)
class _PerLine(Opcode):
    """Shared layout of Delta/Scale per row/column: area spec, uint32
    Count, float32 values[Count], with Count = ceil(area height / RowPitch)
    (per row) or ceil(area width / ColPitch) (per column), as the SDK
    requires."""

    AXIS: ClassVar[str] = "row"
    area: AreaSpec
    values: Any

    @classmethod
    def expected_count(cls, area: AreaSpec) -> int:
        """Number of values the area needs (0 for an empty area)."""
        if cls.AXIS == "row":
            return -(-area.height // area.row_pitch)
        return -(-area.width // area.col_pitch)

    def _validate(self):
        values = _frozen_array(self.values, np.float32, 1, "values")
        need = self.expected_count(self.area)
        if values.size != need:
            raise OpcodeError(f"{values.size} values but the area needs {need} "
                              f"(one per {self.AXIS} of the lattice)")
        _set(self, "values", values)

    def _params(self):
        return (self.area.to_bytes() + struct.pack(">I", self.values.size)
                + self.values.astype(">f4").tobytes())

    @classmethod
    def _parse(cls, r, size, **header):
        if size < AreaSpec.SIZE + 4:
            raise OpcodeError(f"declares {size} parameter bytes but needs at least "
                              f"{AreaSpec.SIZE + 4} for the area spec and count")
        area = AreaSpec._read(r)
        n = r.u32("count")
        need = cls.expected_count(area)
        if n != need:
            raise OpcodeError(f"count is {n} but the area needs {need} "
                              f"(one per {cls.AXIS} of the lattice)")
        _expect_size(size, AreaSpec.SIZE + 4 + 4 * n, f"{n} values")
        return cls(area, r.array(">f4", n, "values"), **header)

    def _describe(self):
        out = self.area.describe()
        finite = self.values[np.isfinite(self.values)]
        out.update(count=int(self.values.size),
                   value_min=float(finite.min()) if finite.size else None,
                   value_max=float(finite.max()) if finite.size else None,
                   non_finite=int(self.values.size - finite.size))
        return out


@dataclass(frozen=True, eq=False, repr=False)
class DeltaPerRow(_PerLine):
    """Add a value per row (ID 10). ``values`` (float32) are offsets on
    the 0..1 scale of the image (per lattice row of the area)."""

    ID = 10
    AXIS = "row"


@dataclass(frozen=True, eq=False, repr=False)
class DeltaPerColumn(_PerLine):
    """Add a value per column (ID 11). ``values`` (float32) are offsets on
    the 0..1 scale of the image (per lattice column of the area)."""

    ID = 11
    AXIS = "col"


@dataclass(frozen=True, eq=False, repr=False)
class ScalePerRow(_PerLine):
    """Multiply by a value per row (ID 12). ``values`` (float32) are
    dimensionless scales (per lattice row of the area)."""

    ID = 12
    AXIS = "row"


@dataclass(frozen=True, eq=False, repr=False)
class ScalePerColumn(_PerLine):
    """Multiply by a value per column (ID 13). ``values`` (float32) are
    dimensionless scales (per lattice column of the area)."""

    ID = 13
    AXIS = "col"


# --------------------------------------------------------------------------
# unknown

@dataclass(frozen=True, repr=False)
class UnknownOpcode(Opcode):
    """An opcode this module does not interpret (vendor or future ID),
    kept with its raw parameter bytes so that it is listed and written back
    unchanged. The SDK refuses to apply one unless it is optional.

    Attributes
    ----------
    opcode_id : int
        The stored opcode ID (uint32).
    data : bytes
        The parameter bytes, as stored.
    """

    opcode_id: int
    data: bytes = b""
    MIN_VERSION = (1, 3, 0, 0)

    def _validate(self):
        _set(self, "opcode_id", _u32(self.opcode_id, "opcode ID"))
        _set(self, "data", bytes(self.data))
        if len(self.data) > _U32_MAX:
            raise OpcodeError(f"{len(self.data)} parameter bytes do not fit a uint32 count")

    @property
    def id(self) -> int:
        return self.opcode_id

    @property
    def name(self) -> str:
        return f"Unknown({self.opcode_id})"

    def _params(self):
        return self.data

    def _describe(self):
        return {"parameter_bytes": len(self.data)}


_CLASSES: dict[int, type[Opcode]] = {cls.ID: cls for cls in (
    WarpRectilinear, WarpFisheye, FixVignetteRadial, FixBadPixelsConstant,
    FixBadPixelsList, TrimBounds, MapTable, MapPolynomial, GainMap, DeltaPerRow,
    DeltaPerColumn, ScalePerRow, ScalePerColumn, WarpRectilinear2)}
assert set(_CLASSES) == set(OPCODE_NAMES)


# --------------------------------------------------------------------------
# lists

def _as_buffer(data) -> memoryview:
    if isinstance(data, np.ndarray):
        if data.dtype != np.uint8:
            raise OpcodeError(f"opcode list: expected bytes or a uint8 array, got a "
                              f"{data.dtype} array")
        data = np.ascontiguousarray(data).tobytes()
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise OpcodeError(f"opcode list: expected bytes, got {type(data).__name__}")
    view = memoryview(data)
    if view.ndim != 1 or view.itemsize != 1:
        view = memoryview(view.tobytes())
    return view


def parse_opcode_list(data, *, max_opcodes: int = 1024) -> tuple[Opcode, ...]:
    """Parse the value of an OpcodeList1/2/3 tag.

    Parameters
    ----------
    data : bytes, bytearray, memoryview or (N,) uint8 ndarray
        The tag's bytes, big-endian as DNG stores them whatever the file's
        byte order.
    max_opcodes : int, optional
        Refuse lists that declare more opcodes than this (real lists hold a
        handful; the cap bounds work on corrupt input).

    Returns
    -------
    tuple of Opcode
        In list order; unknown IDs as :class:`UnknownOpcode`.

    Raises
    ------
    OpcodeError
        On any malformed or invalid content, naming the opcode (0-based
        index and name) and what is wrong. Nothing else is raised for any
        ``data``.
    """
    buf = _as_buffer(data)
    r = _Reader(buf)
    if len(buf) < 4:
        raise OpcodeError(f"opcode list: {len(buf)} bytes, needs at least 4 for the count")
    count = r.u32("count")
    if count > max_opcodes:
        raise OpcodeError(f"opcode list: declares {count} opcodes, more than "
                          f"max_opcodes={max_opcodes}")
    if 16 * count > r.remaining():
        raise OpcodeError(f"opcode list: declares {count} opcodes but only {r.remaining()} "
                          f"bytes follow (each opcode needs at least 16)")
    out = []
    for index in range(count):
        if r.remaining() < 16:
            raise OpcodeError(f"truncated: header needs 16 bytes, only {r.remaining()} left",
                              index=index)
        opcode_id, v0, v1, v2, v3, flags, size = _HEADER.unpack_from(buf, r.pos)
        r.pos += 16
        cls = _CLASSES.get(opcode_id)
        name = OPCODE_NAMES.get(opcode_id, f"Unknown({opcode_id})")
        if size > r.remaining():
            raise OpcodeError(f"declares {size} parameter bytes but only {r.remaining()} "
                              "remain in the list", index=index, name=name)
        params = buf[r.pos:r.pos + size]
        r.pos += size
        header = {"version": (v0, v1, v2, v3), "flags": flags}
        try:
            if cls is None:
                op = UnknownOpcode(opcode_id, bytes(params), **header)
            else:
                pr = _Reader(params)
                op = cls._parse(pr, size, **header)
                if pr.remaining():   # a layout bug guard: sizes are checked up front
                    raise OpcodeError(f"declares {size} parameter bytes but uses "
                                      f"{size - pr.remaining()}")
        except OpcodeError as err:
            raise OpcodeError(err.reason, index=index, name=name) from None
        out.append(op)
    if r.remaining():
        raise OpcodeError(f"opcode list: {r.remaining()} bytes left after the last of "
                          f"{count} opcodes")
    return tuple(out)


def serialize_opcode_list(opcodes: Iterable[Opcode]) -> bytes:
    """Encode opcodes as the value of an OpcodeList1/2/3 tag.

    Parameters
    ----------
    opcodes : iterable of Opcode

    Returns
    -------
    bytes
        uint32 count followed by each opcode's :meth:`Opcode.to_bytes`,
        big-endian; ``serialize_opcode_list(parse_opcode_list(b)) == b``
        for every list this module parses.
    """
    ops = list(opcodes)
    for i, op in enumerate(ops):
        if not isinstance(op, Opcode):
            raise OpcodeError(f"not an Opcode: {type(op).__name__}", index=i)
    return struct.pack(">I", len(ops)) + b"".join(op.to_bytes() for op in ops)

"""Shared machinery of the opcode classes: the error type, bounds-checked
big-endian reads and field checks, the area spec, the :class:`Opcode` base
class (header, flags, encoding, reporting), :class:`UnknownOpcode` for IDs
this package does not interpret, and the opcode IDs, flag bits and limits
of DNG 1.7.1.0, chapter 7 "Opcode List Processing" (SDK ``dng_opcodes.cpp``,
``dng_area_spec.cpp``)."""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from isp.errors import IspError

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

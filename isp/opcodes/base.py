"""Shared machinery of the opcode classes: the area spec, the :class:`Opcode`
base class (header, flags, encoding, reporting), :class:`UnknownOpcode` for
IDs this package does not interpret, and the opcode IDs, flag bits and
limits of DNG 1.7.1.0, chapter 7 "Opcode List Processing" (SDK
``dng_opcodes.cpp``, ``dng_area_spec.cpp``). The error type, the
bounds-checked big-endian reads and the field checks are in
:mod:`isp.opcodes.binary`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from isp.opcodes.binary import AREA_SPEC, HEADER, U32_MAX, OpcodeError, Reader, as_u32, set_field

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
            set_field(self, name, as_u32(getattr(self, name), f"area {name}"))
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
        return AREA_SPEC.pack(self.top, self.left, self.bottom, self.right,
                          self.plane, self.planes, self.row_pitch, self.col_pitch)

    def describe(self) -> dict[str, Any]:
        """JSON-ready summary."""
        return {"area": [self.top, self.left, self.bottom, self.right],
                "plane": self.plane, "planes": self.planes,
                "row_pitch": self.row_pitch, "col_pitch": self.col_pitch}

    @classmethod
    def _read(cls, r: Reader) -> "AreaSpec":
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
        set_field(self, "version", tuple(int(v) for v in version))
        try:
            set_field(self, "flags", as_u32(self.flags, "flags"))
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
        return HEADER.pack(self.id, *self.version, self.flags, len(params)) + params

    @classmethod
    def _parse(cls, r: Reader, size: int, **header) -> "Opcode":
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
        set_field(self, "opcode_id", as_u32(self.opcode_id, "opcode ID"))
        set_field(self, "data", bytes(self.data))
        if len(self.data) > U32_MAX:
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

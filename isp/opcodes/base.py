"""Shared machinery of the opcode classes: the area spec, the :class:`Opcode`
base class (header, flags, encoding, reporting), :class:`UnknownOpcode` for
IDs this package does not interpret, and the opcode IDs, flag bits and
limits of DNG 1.7.1.0, chapter 7 "Opcode List Processing" (SDK
``dng_opcodes.cpp``, ``dng_area_spec.cpp``). The error type, the
bounds-checked big-endian reads and the field checks are in
:mod:`isp.opcodes.binary`."""

from __future__ import annotations

import math
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
# where the data sits

@dataclass(frozen=True)
class OpcodeContext:
    """The image an opcode list applies to, and where an array of pixels
    sits in it: what :meth:`Opcode.apply` needs besides the pixels.

    DNG 1.7.1.0, chapter 7: OpcodeList1 applies to the stored raw image
    (stage 1: integer values as stored, before linearisation), OpcodeList2
    to the linearised active area (stage 2: black = 0, white = the 16-bit
    code 65535), OpcodeList3 to the demosaiced image (stage 3, same scale).
    Area specs, bad-pixel coordinates and TrimBounds are in pixels of that
    image; the optical centres and map origins of the lens opcodes are
    fractions of its size. A pipeline often holds only a window of it (the
    DefaultCrop), so the context says where ``data[0, 0]`` sits.

    Attributes
    ----------
    stage : {1, 2, 3}
        Which opcode list (and so which image) this is.
    origin : (int, int)
        (row, col) of ``data[0, 0]`` in the list's image, pixels (>= 0).
    image_size : (int, int) or None
        (H, W) of the list's image in pixels; None: the data reaches its
        bottom-right corner (``origin + data shape``).
    code_max : float
        The data value of the 16-bit code 65535, which is the scale the
        SDK's opcodes work on: 65535 for stage-1 data in DN as LibRaw
        delivers it (8–16-bit integer raws), 1.0 for stages 2 and 3
        (black = 0, white = 1).
    pixel_aspect_ratio : float
        DefaultScale H / V (PixelAspectRatio), 1 for square pixels; the
        radial opcodes measure distances in square units.
    """

    stage: int
    origin: tuple[int, int] = (0, 0)
    image_size: tuple[int, int] | None = None
    code_max: float = 1.0
    pixel_aspect_ratio: float = 1.0

    def __post_init__(self):
        if self.stage not in (1, 2, 3):
            raise ValueError(f"stage must be 1, 2 or 3, got {self.stage!r}")
        oy, ox = (int(v) for v in self.origin)
        if oy < 0 or ox < 0:
            raise ValueError(f"origin must be >= 0, got {self.origin!r}")
        object.__setattr__(self, "origin", (oy, ox))
        if self.image_size is not None:
            h, w = (int(v) for v in self.image_size)
            if h < 1 or w < 1:
                raise ValueError(f"image_size must be positive, got {self.image_size!r}")
            object.__setattr__(self, "image_size", (h, w))
        if not (math.isfinite(self.code_max) and self.code_max > 0):
            raise ValueError(f"code_max must be finite and > 0, got {self.code_max!r}")
        if not (math.isfinite(self.pixel_aspect_ratio) and self.pixel_aspect_ratio > 0):
            raise ValueError(f"pixel_aspect_ratio must be finite and > 0, "
                             f"got {self.pixel_aspect_ratio!r}")

    @classmethod
    def for_stage(cls, stage: int, **kw) -> "OpcodeContext":
        """The context of a list's image held whole: stage 1 in 16-bit DN
        (``code_max`` 65535), stages 2 and 3 normalised (``code_max`` 1)."""
        kw.setdefault("code_max", 65535.0 if stage == 1 else 1.0)
        return cls(stage, **kw)

    def size(self, shape) -> tuple[int, int]:
        """(H, W) of the list's image for data of ``shape``: ``image_size``,
        grown to hold the data where it is smaller."""
        oy, ox = self.origin
        h, w = oy + int(shape[0]), ox + int(shape[1])
        if self.image_size is None:
            return (h, w)
        return (max(self.image_size[0], h), max(self.image_size[1], w))

    def moved(self, dy: int, dx: int, image_size: tuple[int, int]) -> "OpcodeContext":
        """The context after the image is cropped so that its new top-left
        pixel was ``(dy, dx)`` (TrimBounds) and the data to the crop."""
        oy, ox = self.origin
        return OpcodeContext(self.stage, (max(oy - dy, 0), max(ox - dx, 0)), image_size,
                             self.code_max, self.pixel_aspect_ratio)


def data_planes(data: np.ndarray) -> int:
    """Planes of an image array: 1 for (H, W), P for (H, W, P)."""
    return 1 if data.ndim == 2 else int(data.shape[2])


def plane_view(data: np.ndarray, plane: int) -> np.ndarray:
    """A writable (H, W) view of plane ``plane`` of ``data``."""
    return data if data.ndim == 2 else data[:, :, plane]


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

    def window(self, ctx: OpcodeContext, shape) -> tuple[slice, slice] | None:
        """Slices of an array of ``shape`` (placed by ``ctx``) that the area
        covers, as the SDK's ``dng_area_spec::Overlap`` clips it.

        The lattice starts at the area's Top/Left whatever the window: a
        window starting inside the area starts at the first lattice row and
        column at or after its own first pixel. An empty rectangle covers
        the whole image. Returns ``(rows, cols)`` slices of the data, or
        None where the area misses it.

        >>> ctx = OpcodeContext(2, origin=(2, 2))
        >>> AreaSpec(1, 0, 10, 10, row_pitch=2, col_pitch=2).window(ctx, (6, 6))
        (slice(1, 6, 2), slice(0, 6, 2))
        """
        return area_slices(self.top, self.left, self.bottom, self.right, self.row_pitch, self.col_pitch,
                           ctx.origin, shape)

    def plane_range(self, planes: int) -> range:
        """The area's planes that an image of ``planes`` planes has."""
        return range(self.plane, min(self.plane + self.planes, int(planes)))

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

    # -- applying ---------------------------------------------------------
    def unsupported(self, stage: int, planes: int) -> str | None:
        """Why this opcode cannot be applied to a stage-``stage`` image of
        ``planes`` planes, or None where it can (:meth:`apply`)."""
        return None

    def apply(self, data: np.ndarray, ctx: OpcodeContext) -> np.ndarray:
        """Apply the opcode to ``data`` as DNG 1.7.1.0 chapter 7 and the
        Adobe DNG SDK do.

        Parameters
        ----------
        data : (H, W) or (H, W, P) ndarray of float32
            The pixels: the list's image, or the window of it that ``ctx``
            places. Stage 1: stored values (DN); stages 2 and 3: black = 0,
            white = 1.
        ctx : OpcodeContext
            Which list, and where ``data`` sits in its image.

        Returns
        -------
        ndarray of float32
            The result. Opcodes that change pixels in place (maps, deltas,
            gains, bad pixels) write into ``data`` and return it, so pass a
            copy to keep the input; the warps return a new array, TrimBounds
            a view.

        Raises
        ------
        OpcodeError
            Where :meth:`unsupported` gives a reason.
        """
        raise OpcodeError("applying it is not implemented", name=self.name)

    def _check_apply(self, data: np.ndarray, ctx: OpcodeContext) -> None:
        if data.ndim not in (2, 3):
            raise OpcodeError(f"data must be (H, W) or (H, W, P), got shape {data.shape}",
                              name=self.name)
        reason = self.unsupported(ctx.stage, data_planes(data))
        if reason is not None:
            raise OpcodeError(reason, name=self.name)

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

    def unsupported(self, stage, planes):
        return "unknown or vendor opcode: its parameters cannot be interpreted"

    def _describe(self):
        return {"parameter_bytes": len(self.data)}


def area_slices(top: int, left: int, bottom: int, right: int, row_pitch: int, col_pitch: int,
                origin: tuple[int, int], shape: tuple[int, ...]) -> tuple[slice, slice] | None:
    """Slices of a frame's data covered by an opcode area.

    Opcode areas (DNG spec 7, "AreaSpec"; :class:`AreaSpec`) are in active-area pixels and
    step by RowPitch/ColPitch from Top/Left; a frame's data starts at
    ``origin`` (its DefaultCrop offset). Returns ``(rows, cols)`` slices into
    the data, or None if the area misses it.

    >>> area_slices(1, 0, 10, 10, 2, 2, (2, 2), (6, 6))
    (slice(1, 6, 2), slice(0, 6, 2))
    >>> area_slices(0, 0, 0, 0, 1, 1, (0, 0), (4, 4))   # empty = whole image
    (slice(0, 4, 1), slice(0, 4, 1))
    """
    oy, ox = origin
    h, w = shape[0], shape[1]
    if bottom <= top or right <= left:  # an empty area means the whole image (DNG SDK)
        top, left, bottom, right, row_pitch, col_pitch = 0, 0, oy + h, ox + w, 1, 1

    def one(start, stop, pitch, off, n):
        pitch = max(1, int(pitch))
        if start < off:
            start += -(-(off - start) // pitch) * pitch
        stop = min(stop, off + n)
        if start >= stop:
            return None
        return slice(start - off, stop - off, pitch)

    rs = one(top, bottom, row_pitch, oy, h)
    cs = one(left, right, col_pitch, ox, w)
    if rs is None or cs is None:
        return None
    return rs, cs

"""The opcode binary reader/writer helpers: the byte layout every opcode shares.

DNG 1.7.1.0, chapter 7 "Opcode List Processing": an opcode list is a
big-endian ``uint32`` count followed by the opcodes; each opcode is a
16-byte header (:data:`HEADER`: ``uint32`` ID, 4 version bytes, ``uint32``
flags, ``uint32`` parameter byte count) and its parameters, most of which
start with a 32-byte area spec (:data:`AREA_SPEC`: eight ``uint32``).

This module holds what the opcode classes of :mod:`isp.opcodes` share to
read and write that layout strictly: :class:`OpcodeError`, the one error
they raise; :class:`Reader`, bounds-checked big-endian reads that check
every count against the bytes left before allocating; and the field checks
a parsed or constructed opcode runs (:func:`as_u32`, :func:`as_floats`,
:func:`frozen_array`, :func:`expect_size`, :func:`check_center`,
:func:`set_field`). Public inside the package: the opcode modules import
these; users import from :mod:`isp.opcodes`.

Example
-------
>>> r = Reader(bytes.fromhex("00000002") + b"ab")
>>> r.u32("count"), r.remaining()
(2, 2)
>>> r.raw(3, "payload")
Traceback (most recent call last):
...
isp.opcodes.binary.OpcodeError: truncated: payload needs 3 bytes, only 2 left
"""

from __future__ import annotations

import struct

import numpy as np

from isp.errors import IspError

#: Largest value of a ``uint32`` field.
U32_MAX = 0xFFFFFFFF
#: An opcode's header: ID, version (4 bytes), flags, parameter byte count (16 bytes).
HEADER = struct.Struct(">I4BII")
#: An area spec: top, left, bottom, right, plane, planes, row pitch, column pitch (32 bytes).
AREA_SPEC = struct.Struct(">8I")


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


class Reader:
    """Bounds-checked big-endian reads from a byte buffer.

    Every read names what it reads (``what``) and raises
    :class:`OpcodeError` when fewer bytes remain than it needs, before
    anything is allocated.

    Parameters
    ----------
    buf : bytes-like
        The bytes to read, from position 0.

    Attributes
    ----------
    buf : bytes-like
        The buffer.
    pos : int
        Bytes read so far (the next read starts here).
    """

    __slots__ = ("buf", "pos")

    def __init__(self, buf):
        self.buf = buf
        self.pos = 0

    def remaining(self) -> int:
        """Bytes left after :attr:`pos`."""
        return len(self.buf) - self.pos

    def _need(self, n: int, what: str) -> None:
        if n > self.remaining():
            raise OpcodeError(f"truncated: {what} needs {n} bytes, only {self.remaining()} left")

    def u32s(self, n: int, what: str) -> tuple[int, ...]:
        """``n`` big-endian ``uint32`` values."""
        self._need(4 * n, what)
        out = struct.unpack_from(f">{n}I", self.buf, self.pos)
        self.pos += 4 * n
        return out

    def u32(self, what: str) -> int:
        """One big-endian ``uint32``."""
        return self.u32s(1, what)[0]

    def f64s(self, n: int, what: str) -> tuple[float, ...]:
        """``n`` big-endian IEEE doubles."""
        self._need(8 * n, what)
        out = struct.unpack_from(f">{n}d", self.buf, self.pos)
        self.pos += 8 * n
        return out

    def array(self, dtype: str, n: int, what: str) -> np.ndarray:
        """``n`` items of big-endian ``dtype`` (e.g. ``">f4"``) as a
        native-order copy, shape (n,)."""
        dt = np.dtype(dtype)
        self._need(dt.itemsize * n, what)
        a = np.frombuffer(self.buf, dtype=dt, count=n, offset=self.pos)
        self.pos += dt.itemsize * n
        return a.astype(dt.newbyteorder("="))

    def raw(self, n: int, what: str) -> bytes:
        """The next ``n`` bytes, as they are."""
        self._need(n, what)
        out = bytes(self.buf[self.pos:self.pos + n])
        self.pos += n
        return out


def as_u32(value, what: str) -> int:
    """``value`` as an int in 0..2**32-1, or :class:`OpcodeError` naming
    ``what`` and the value (a float with a fraction is refused, not
    truncated).

    >>> as_u32(7.0, "plane")
    7
    """
    try:
        v = int(value)
    except (TypeError, ValueError):
        raise OpcodeError(f"{what} must be an integer, got {value!r}") from None
    if v != value or not 0 <= v <= U32_MAX:
        raise OpcodeError(f"{what} must be an integer in 0..{U32_MAX}, got {value!r}")
    return v


def as_floats(values, n: int | None, what: str) -> tuple[float, ...]:
    """``values`` as a tuple of floats; exactly ``n`` of them unless ``n``
    is None (:class:`OpcodeError` naming ``what`` otherwise)."""
    out = tuple(float(x) for x in values)
    if n is not None and len(out) != n:
        raise OpcodeError(f"{what} needs {n} values, got {len(out)}")
    return out


def frozen_array(values, dtype, ndim: int, what: str) -> np.ndarray:
    """A C-ordered, read-only copy of ``values`` as ``dtype`` with ``ndim``
    dimensions (:class:`OpcodeError` naming ``what`` and the shape
    otherwise): an opcode's arrays cannot change after it is checked."""
    a = np.array(values, dtype=dtype, order="C", copy=True)
    if a.ndim != ndim:
        raise OpcodeError(f"{what} must be {ndim}-D, got shape {a.shape}")
    a.setflags(write=False)
    return a


def set_field(obj, name: str, value) -> None:
    """Set field ``name`` of the frozen dataclass ``obj`` (while it
    normalises its own fields in ``__post_init__``)."""
    object.__setattr__(obj, name, value)


def expect_size(size: int, need: int, detail: str) -> None:
    """:class:`OpcodeError` unless an opcode's declared parameter byte
    count ``size`` equals the ``need`` its content takes (``detail`` says
    what, e.g. ``"32x32x1 gains"``)."""
    if size != need:
        raise OpcodeError(f"declares {size} parameter bytes but needs {need} for {detail}")


def check_center(cx: float, cy: float) -> None:
    """:class:`OpcodeError` unless the optical centre (``cx``, ``cy``), in
    relative coordinates, lies in [0, 1] x [0, 1] (the SDK's
    ``dng_warp_params::IsValid``, ``dng_vignette_radial_params::IsValid``)."""
    if not (0.0 <= cx <= 1.0 and 0.0 <= cy <= 1.0):
        raise OpcodeError(f"optical centre ({cx!r}, {cy!r}) must lie in [0, 1] x [0, 1]")

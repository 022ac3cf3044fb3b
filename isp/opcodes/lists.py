"""Opcode lists (the OpcodeList1/2/3 tag values): the ID -> class table,
strict parsing into typed opcodes and byte-exact serialisation
(DNG 1.7.1.0, chapter 7; SDK ``dng_opcode_list.cpp``)."""

from __future__ import annotations

import struct
from typing import Iterable

import numpy as np

from isp.opcodes.bad_pixels import FixBadPixelsConstant, FixBadPixelsList
from isp.opcodes.base import OPCODE_NAMES, Opcode, UnknownOpcode
from isp.opcodes.binary import HEADER, OpcodeError, Reader
from isp.opcodes.gain_map import GainMap
from isp.opcodes.per_line import DeltaPerColumn, DeltaPerRow, ScalePerColumn, ScalePerRow
from isp.opcodes.trim import TrimBounds
from isp.opcodes.value_maps import MapPolynomial, MapTable
from isp.opcodes.vignette import FixVignetteRadial
from isp.opcodes.warp import WarpFisheye, WarpRectilinear, WarpRectilinear2

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
    r = Reader(buf)
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
        opcode_id, v0, v1, v2, v3, flags, size = HEADER.unpack_from(buf, r.pos)
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
                pr = Reader(params)
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

"""DNG opcode lists (OpcodeList1/2/3): parse, serialize, evaluate.

A DNG carries up to three *opcode lists*, processing steps the raw converter
applies at three points of its pipeline: OpcodeList1 to the raw data as
stored, OpcodeList2 after linearisation (black level subtracted, white = 1),
OpcodeList3 after demosaicing. Phone DNGs use them mostly for lens shading
(``GainMap``, one per CFA phase or one 3-plane map), sometimes for lossy-DNG
linearisation (``MapPolynomial``) and lens distortion (``WarpRectilinear``).

This module reads a list into typed, immutable opcode objects, writes them
back byte for byte, and applies each to an image as the specification and
the Adobe DNG SDK do (:meth:`Opcode.apply`, placed in its list's image by an
:class:`OpcodeContext`): warps with lateral colour, bad-pixel repair, gain
and value maps, per-row and per-column corrections, trimming. Which opcode
runs at which pipeline stage is the stages' decision
(:mod:`isp.io.opcode_plan`).
One module per opcode family (``gain_map``, ``warp``, ``vignette``, ...),
the base class and area spec in ``base``, the byte-layout reader and field
checks they share in ``binary``, list parsing in ``lists``. May import:
numpy and :mod:`isp.errors` (OpenCV, lazily, for the warps' resampling).

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

from isp.opcodes.bad_pixels import FixBadPixelsConstant, FixBadPixelsList
from isp.opcodes.base import (
    FLAG_OPTIONAL,
    FLAG_PREVIEW_SKIPPABLE,
    OPCODE_NAMES,
    AreaSpec,
    Opcode,
    OpcodeContext,
    UnknownOpcode,
)
from isp.opcodes.base import MAX_POLYNOMIAL_DEGREE as MAX_POLYNOMIAL_DEGREE
from isp.opcodes.base import MAX_TABLE_SIZE as MAX_TABLE_SIZE
from isp.opcodes.base import MAX_WARP_PLANES as MAX_WARP_PLANES
from isp.opcodes.binary import OpcodeError
from isp.opcodes.gain_map import GainMap
from isp.opcodes.lists import parse_opcode_list, serialize_opcode_list
from isp.opcodes.per_line import DeltaPerColumn, DeltaPerRow, ScalePerColumn, ScalePerRow
from isp.opcodes.trim import TrimBounds
from isp.opcodes.value_maps import MapPolynomial, MapTable
from isp.opcodes.vignette import FixVignetteRadial
from isp.opcodes.warp import WarpFisheye, WarpRectilinear, WarpRectilinear2

__all__ = [
    "AreaSpec", "DeltaPerColumn", "DeltaPerRow", "FLAG_OPTIONAL",
    "FLAG_PREVIEW_SKIPPABLE", "FixBadPixelsConstant",
    "FixBadPixelsList", "FixVignetteRadial", "GainMap", "MapPolynomial",
    "MapTable", "OPCODE_NAMES", "Opcode", "OpcodeContext", "OpcodeError", "ScalePerColumn",
    "ScalePerRow", "TrimBounds", "UnknownOpcode", "WarpFisheye",
    "WarpRectilinear", "WarpRectilinear2", "parse_opcode_list",
    "serialize_opcode_list",
]

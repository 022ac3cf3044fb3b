"""The DNG opcode lists at their stages: ``opcode_list1`` (OpcodeList1, on
the stored raw values, before ``black_level``), ``opcode_list2``
(OpcodeList2 on the linear mosaic, after ``black_level`` and before
``lens_shading``) and ``opcode_list3`` (OpcodeList3 on camera RGB, after
``demosaic``).

Reference: Adobe, *DNG Specification* 1.7.1.0, chapter 7 "Opcode List
Processing"; the Adobe DNG SDK (``dng_negative.cpp``: List1 on the stage-1
image, List2 after linearisation, List3 after demosaicing). Each opcode's
arithmetic is its class's :meth:`~isp.opcodes.Opcode.apply`.

Which opcode runs where is :func:`isp.io.opcode_plan.opcode_plan`'s
decision, shared with ``isp info``: ``black_level`` keeps OpcodeList2's
MapPolynomial/MapTable and ``lens_shading`` the GainMap/FixVignetteRadial
of lists 2 and 3; these stages apply every other opcode their list holds,
in list order, and an opcode none can apply is reported as skipped with its
reason, never dropped.

Notes
-----
* Coordinates. OpcodeList1 addresses the stored image (the ActiveArea's
  top-left is not its origin), lists 2 and 3 the active area; a frame holds
  the DefaultCrop window of the active area, so each stage places its data
  with an :class:`~isp.opcodes.OpcodeContext` (``meta.active_area``,
  ``meta.origin``). Neighbourhood opcodes (bad pixels, warps) see only that
  window; at its edges they read what the SDK reads at the image's edges.
* Values. Stage 1 holds DN (LibRaw's 16-bit values, results rounded and
  clipped as the SDK stores them); stage 2 black = 0, white = 1, not
  clipped. The SDK's stage 3 is camera RGB before white balance, while this
  pipeline balances before demosaicing: value-dependent List3 opcodes
  (MapTable, MapPolynomial, DeltaPerRow/Column) run on the unbalanced
  values (multiplied by the frame's neutral, then divided again); the
  others are linear per plane and do not care.
* TrimBounds crops the frame and moves ``meta.active_area``, ``meta.origin``
  and ``meta.default_crop`` with it, so later opcodes and stages address the
  trimmed image, as in the SDK.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from isp.errors import InputError
from isp.frame import Domain, Frame
from isp.io.opcode_plan import handled_by
from isp.opcodes import OpcodeContext, OpcodeError
from isp.stage import StageBase

#: List3 opcodes whose result depends on the value, not only on a per-plane
#: scale (applied to the unbalanced camera values)
_VALUE_DEPENDENT = frozenset({"MapTable", "MapPolynomial", "DeltaPerRow", "DeltaPerColumn"})


def list_context(frame: Frame, list_no: int) -> OpcodeContext:
    """Where ``frame``'s data sits in the image OpcodeList ``list_no``
    applies to: list 1 the stored image (``meta.raw_size``; data in DN,
    ``code_max`` 65535), lists 2 and 3 the active area (``frame.full_size``;
    black = 0, white = 1)."""
    meta = frame.meta
    oy, ox = meta.origin
    if list_no == 1:
        top, left = (meta.active_area[:2] if meta.active_area is not None else (0, 0))
        raw_h, raw_w = meta.raw_size
        size = (raw_h, raw_w) if raw_h and raw_w else None
        return OpcodeContext(1, (top + oy, left + ox), size, code_max=65535.0)
    return OpcodeContext(list_no, (oy, ox), frame.full_size, code_max=1.0)


def _trimmed_meta(meta, rows: slice, cols: slice, op, new_ctx: OpcodeContext):
    """``meta`` after TrimBounds ``op`` kept ``data[rows, cols]`` and made the
    trimmed image (``new_ctx``) the frame of reference."""
    dy, dx = op.top, op.left
    at, al = meta.active_area[:2] if meta.active_area is not None else (0, 0)
    h, w = new_ctx.image_size
    h_data, w_data = rows.stop - rows.start, cols.stop - cols.start
    changes = {"active_area": (at + dy, al + dx, at + dy + h, al + dx + w),
               "origin": new_ctx.origin,
               "default_crop": (new_ctx.origin[1], new_ctx.origin[0], w_data, h_data)}
    if meta.cfa is not None and (rows.start or cols.start):
        changes["cfa"] = meta.cfa.shifted(rows.start, cols.start)
    return meta.replace(**changes)


def apply_list(frame: Frame, list_no: int, stage: str) -> Frame:
    """Apply the opcodes of OpcodeList ``list_no`` that the plan gives to
    ``stage``, in list order; the frame's history notes each one.

    Raises
    ------
    InputError
        Where an opcode's parameters do not fit the image (e.g. TrimBounds
        outside it), naming the list, the opcode and why.
    """
    meta = frame.meta
    ops = handled_by(meta, stage)
    if not ops:
        return frame.evolve(stage=stage, note=f"no OpcodeList{list_no} opcodes for this stage")
    data = frame.data
    owned = False
    ctx = list_context(frame, list_no)
    neutral = (np.asarray(frame.neutral, dtype=np.float32)
               if list_no == 3 and frame.neutral is not None and data.ndim == 3 else None)
    notes = []
    for n, i, op in ops:
        where = f"OpcodeList{n}[{i}] {op.name}"
        try:
            if op.name == "TrimBounds":
                (rows, cols), new_ctx = op.window(data.shape, ctx)
                meta = _trimmed_meta(meta, rows, cols, op, new_ctx)
                data, ctx = data[rows, cols], new_ctx
                notes.append(f"{where} to {data.shape[1]}x{data.shape[0]}")
                continue
            if not owned and op.name not in ("WarpRectilinear", "WarpRectilinear2",
                                             "WarpFisheye"):
                data = np.array(data, dtype=np.float32)
                owned = True
            if neutral is not None and op.name in _VALUE_DEPENDENT:
                data *= neutral
                data = op.apply(data, ctx)
                data /= neutral
            else:
                data = op.apply(data, ctx)
                owned = owned or op.name.startswith("Warp")
        except OpcodeError as e:
            raise InputError(meta.path, f"{where}: {e.reason}") from None
        notes.append(where)
    data = np.ascontiguousarray(data, dtype=np.float32)
    return frame.evolve(data, stage=stage, note="; ".join(notes),
                        **({"meta": meta} if meta is not frame.meta else {}))


@dataclass(frozen=True)
class OpcodeList1(StageBase):
    """Apply OpcodeList1 to the stored raw values (DN), before
    linearisation and the black level (DNG 1.7.1.0 ch. 7; SDK stage 1)."""

    name = "opcode_list1"
    consumes = (Domain.RAW,)

    def process(self, frame: Frame) -> Frame:
        return apply_list(frame, 1, self.name)


@dataclass(frozen=True)
class OpcodeList2(StageBase):
    """Apply the OpcodeList2 opcodes that ``black_level`` (MapPolynomial,
    MapTable) and ``lens_shading`` (GainMap, FixVignetteRadial) do not,
    to the linear mosaic (black = 0, white = 1): bad pixels, per-row and
    per-column deltas and scales, trimming, warps."""

    name = "opcode_list2"
    consumes = (Domain.RAW_LINEAR,)

    def process(self, frame: Frame) -> Frame:
        return apply_list(frame, 2, self.name)


@dataclass(frozen=True)
class OpcodeList3(StageBase):
    """Apply the OpcodeList3 opcodes that ``lens_shading`` does not
    (GainMap, FixVignetteRadial) to demosaiced camera RGB: the lens
    warps (WarpRectilinear, WarpRectilinear2, WarpFisheye: distortion and
    lateral colour), value maps, per-row and per-column opcodes, trimming."""

    name = "opcode_list3"
    consumes = (Domain.CAMERA_RGB,)

    def process(self, frame: Frame) -> Frame:
        return apply_list(frame, 3, self.name)


__all__ = ["OpcodeList1", "OpcodeList2", "OpcodeList3", "apply_list", "list_context"]

"""Per-row and per-column opcodes: DeltaPerRow (ID 10), DeltaPerColumn
(ID 11), ScalePerRow (ID 12) and ScalePerColumn (ID 13), which share one
layout (DNG 1.7.1.0, chapter 7; SDK ``dng_misc_opcodes.cpp``)."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from isp.opcodes.base import AreaSpec, Opcode, OpcodeContext, data_planes, plane_view
from isp.opcodes.binary import OpcodeError, expect_size, frozen_array, set_field

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
        values = frozen_array(self.values, np.float32, 1, "values")
        need = self.expected_count(self.area)
        if values.size != need:
            raise OpcodeError(f"{values.size} values but the area needs {need} "
                              f"(one per {self.AXIS} of the lattice)")
        set_field(self, "values", values)

    def _params(self):
        return (self.area.to_bytes() + struct.pack(">I", self.values.size)
                + self.values.astype(">f4").tobytes())

    def _combine(self, x: np.ndarray, v: np.ndarray, code_max: float) -> np.ndarray:
        raise NotImplementedError

    def apply(self, data: np.ndarray, ctx: OpcodeContext) -> np.ndarray:
        """Apply one value per lattice row (column) of the area, in place
        (SDK ``dng_opcode_DeltaPerRow`` and its siblings): lattice row k of
        the area (image row ``Top + k RowPitch``) takes ``values[k]``,
        whichever window of the image ``data`` is. An empty area has no
        values and changes nothing. Stage 1 results are rounded and clipped
        to 0..``code_max`` (the SDK stores them back into the integer raw
        image); stages 2 and 3 are not clipped (the SDK pins to [-1, 1]).
        Returns ``data``."""
        self._check_apply(data, ctx)
        if not np.isfinite(self.values).all():
            raise OpcodeError(f"{int((~np.isfinite(self.values)).sum())} non-finite value(s)",
                              name=self.name)
        window = self.area.window(ctx, data.shape)
        if window is None or self.values.size == 0:
            return data
        rows, cols = window
        oy, ox = ctx.origin
        if self.AXIS == "row":
            first = (rows.start + oy - self.area.top) // self.area.row_pitch
            n = len(range(rows.start, rows.stop, rows.step))
            v = self.values[first:first + n][:, None]
        else:
            first = (cols.start + ox - self.area.left) // self.area.col_pitch
            n = len(range(cols.start, cols.stop, cols.step))
            v = self.values[first:first + n][None, :]
        for p in self.area.plane_range(data_planes(data)):
            view = plane_view(data, p)
            y = self._combine(view[window], v, ctx.code_max)
            if ctx.stage == 1:
                y = np.clip(np.rint(y), 0.0, ctx.code_max)
            view[window] = y
        return data

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
        expect_size(size, AreaSpec.SIZE + 4 + 4 * n, f"{n} values")
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
    """Add a value per row (ID 10). ``values`` (float32) are offsets in
    units of the integer image the SDK holds (16-bit codes: DN in stage 1,
    65535 = white in stages 2 and 3), per lattice row of the area."""

    ID = 10
    AXIS = "row"

    def _combine(self, x, v, code_max):
        # the values are in units of the integer image (DN in stage 1,
        # 16-bit codes in stage 2): the SDK scales them with the image
        return x + v * np.float32(code_max / 65535.0)


@dataclass(frozen=True, eq=False, repr=False)
class DeltaPerColumn(_PerLine):
    """Add a value per column (ID 11). ``values`` (float32) are offsets in
    units of the integer image the SDK holds (16-bit codes: DN in stage 1,
    65535 = white in stages 2 and 3), per lattice column of the area."""

    ID = 11
    AXIS = "col"

    def _combine(self, x, v, code_max):
        # the values are in units of the integer image (DN in stage 1,
        # 16-bit codes in stage 2): the SDK scales them with the image
        return x + v * np.float32(code_max / 65535.0)


@dataclass(frozen=True, eq=False, repr=False)
class ScalePerRow(_PerLine):
    """Multiply by a value per row (ID 12). ``values`` (float32) are
    dimensionless scales (per lattice row of the area)."""

    ID = 12
    AXIS = "row"

    def _combine(self, x, v, code_max):
        return x * v


@dataclass(frozen=True, eq=False, repr=False)
class ScalePerColumn(_PerLine):
    """Multiply by a value per column (ID 13). ``values`` (float32) are
    dimensionless scales (per lattice column of the area)."""

    ID = 13
    AXIS = "col"

    def _combine(self, x, v, code_max):
        return x * v

"""Per-row and per-column opcodes: DeltaPerRow (ID 10), DeltaPerColumn
(ID 11), ScalePerRow (ID 12) and ScalePerColumn (ID 13), which share one
layout (DNG 1.7.1.0, chapter 7; SDK ``dng_misc_opcodes.cpp``)."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from isp.opcodes.base import AreaSpec, Opcode
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

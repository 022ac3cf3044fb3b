"""Value maps: MapTable (ID 7, a 16-bit look-up table) and MapPolynomial
(ID 8), with their evaluation as the SDK does it (DNG 1.7.1.0, chapter 7;
SDK ``dng_misc_opcodes.cpp``)."""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from isp.opcodes.base import (
    MAX_POLYNOMIAL_DEGREE, MAX_TABLE_SIZE, AreaSpec, Opcode, OpcodeContext, data_planes,
    plane_view,
)
from isp.opcodes.binary import OpcodeError, as_floats, expect_size, frozen_array, set_field

# --------------------------------------------------------------------------
# value maps

def map_area(op, data: np.ndarray, ctx: OpcodeContext, fn) -> np.ndarray:
    """Replace the values of ``op.area`` (its rectangle, lattice and planes)
    in ``data`` by ``fn(values)``, in place; stage-1 results are rounded
    and clipped to 0..``code_max`` as the SDK stores them back into the
    integer raw image. Returns ``data``."""
    window = op.area.window(ctx, data.shape)
    if window is None:
        return data
    for p in op.area.plane_range(data_planes(data)):
        view = plane_view(data, p)
        y = fn(view[window])
        if ctx.stage == 1:
            y = np.clip(np.rint(y), 0.0, ctx.code_max)
        view[window] = y
    return data


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
        table = frozen_array(table, np.uint16, 1, "table")
        if not 1 <= table.size <= MAX_TABLE_SIZE:
            raise OpcodeError(f"table size is {table.size}, must be 1..{MAX_TABLE_SIZE}")
        set_field(self, "table", table)

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
        expect_size(size, AreaSpec.SIZE + 4 + 2 * n, f"{n} table entries")
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

    def apply(self, data, ctx):
        """Map the area's values through the table (DNG 1.7.1.0 ch. 7,
        MapTable; SDK ``dng_opcode_MapTable``): each value is read as its
        16-bit code ``round(65535 x / code_max)`` (clipped to 0..65535;
        stage 1: the stored DN itself) and replaced by
        ``table[min(code, TableSize - 1)] code_max / 65535``. In place;
        returns ``data``."""
        self._check_apply(data, ctx)
        scale = np.float32(ctx.code_max)
        return map_area(self, data, ctx, lambda v: self.evaluate(v / scale) * scale)

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
        c = as_floats(self.coefficients, None, "coefficients")
        if not 1 <= len(c) <= MAX_POLYNOMIAL_DEGREE + 1:
            raise OpcodeError(f"{len(c)} coefficients, must be 1..{MAX_POLYNOMIAL_DEGREE + 1} "
                              f"(degree 0..{MAX_POLYNOMIAL_DEGREE})")
        set_field(self, "coefficients", c)

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
        expect_size(size, AreaSpec.SIZE + 4 + 8 * (degree + 1),
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

    def apply(self, data, ctx):
        """Replace the area's values x by the polynomial (DNG 1.7.1.0
        ch. 7, MapPolynomial; SDK ``dng_opcode_MapPolynomial``). Stage 1:
        x and y are stored values in DN, as the SDK rescales the
        coefficients of a 16-bit image; the result is rounded and clipped
        to 0..``code_max``. Stages 2 and 3: x on the 0..1 scale, y not
        clipped (the SDK pins it to [-1, 1] and stores it in a 16-bit image;
        here values beyond white stay for the later stages). In place;
        returns ``data``."""
        self._check_apply(data, ctx)
        if not all(math.isfinite(c) for c in self.coefficients):
            raise OpcodeError(f"non-finite coefficients {self.coefficients}", name=self.name)
        return map_area(self, data, ctx, self.evaluate)

    def _describe(self):
        out = self.area.describe()
        out.update(degree=self.degree, coefficients=list(self.coefficients))
        return out

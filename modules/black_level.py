"""Black level, linearisation and normalisation: sensor DN → linear 0..1.

Reference: Adobe, *DNG Specification* 1.7.1.0, chapter 5 "Mapping Raw Values
to Linear Reference Values": linearisation table, then black subtraction
(BlackLevel pattern + BlackLevelDeltaH/V), then scaling so that WhiteLevel
maps to 1; then the value-mapping opcodes of OpcodeList2 (MapPolynomial,
MapTable) that the decoder did not already apply.

Notes
-----
``y = (L(x) − B(r, c) − ΔV(r) − ΔH(c)) / (W − B(r, c))`` with ``L`` the
LinearizationTable (identity when absent or already applied by LibRaw),
``B`` the BlackLevel pattern at the pixel's position in the active area and
``W`` the WhiteLevel. Nothing is clipped: noise below black stays negative,
so averages of dark regions stay unbiased.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from isp.errors import InputError
from isp.frame import Domain, Frame
from isp.io.opcode_plan import handled_by
from isp.opcodes.base import area_slices
from isp.stage import StageBase

from modules.common.mosaic import cfa_affine


def linearize(data: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Map stored values through a DNG LinearizationTable.

    Parameters
    ----------
    data : ndarray, float32
        Stored values (DN); indices beyond the table use its last entry.
    table : (N,) array_like

    Returns
    -------
    float32 ndarray of data's shape.

    >>> linearize(np.array([0, 1, 5], np.float32), np.array([0, 10, 20]))
    array([ 0., 10., 20.], dtype=float32)
    """
    lut = np.asarray(table, dtype=np.float32)
    idx = np.clip(data, 0, lut.size - 1).astype(np.intp)
    return lut[idx]


def subtract_black_level(data: np.ndarray, black: np.ndarray, white, *,
                         delta_v: np.ndarray | None = None,
                         delta_h: np.ndarray | None = None) -> np.ndarray:
    """Remove the black level and scale to white = 1.

    Parameters
    ----------
    data : (H, W) or (H, W, S) ndarray, float32
        Linearised sensor values in DN.
    black : (R, C, S) array_like
        Black-level repeat pattern in DN; element [0, 0] applies to
        ``data[0, 0]``.
    white : float or sequence of S floats
        White level in DN.
    delta_v, delta_h : (H,), (W,) array_like, optional
        Per-row and per-column black offsets in DN.

    Returns
    -------
    float32 ndarray of data's shape: 0 at black, 1 at white, unclipped.

    Examples
    --------
    >>> d = np.array([[64, 1023], [64, 543.5]], np.float32)
    >>> subtract_black_level(d, np.full((1, 1, 1), 64.0), 1023.0).round(6)
    array([[0. , 1. ],
           [0. , 0.5]], dtype=float32)
    """
    black = np.asarray(black, dtype=np.float64)
    if black.ndim != 3:
        black = black.reshape(1, 1, -1)
    rr, rc, rs = black.shape
    mosaic = data.ndim == 2
    samples = 1 if mosaic else data.shape[2]
    white = np.broadcast_to(np.asarray(white, dtype=np.float64).ravel(), (samples,)) \
        if np.size(white) in (1, samples) else np.asarray(white, dtype=np.float64)[:samples]
    out = np.empty(data.shape, dtype=np.float32)
    src = data
    if delta_v is not None or delta_h is not None:
        src = data.astype(np.float32, copy=True)
        if delta_v is not None:
            dv = np.asarray(delta_v, np.float32)[:data.shape[0]]
            src -= dv[:, None] if mosaic else dv[:, None, None]
        if delta_h is not None:
            dh = np.asarray(delta_h, np.float32)[:data.shape[1]]
            src -= dh[None, :] if mosaic else dh[None, :, None]
    if mosaic and rr <= 2 and rc <= 2:
        # one pass over contiguous memory: y = x·s − b·s per CFA position
        b2 = np.resize(black[:, :, 0], (2, 2)) if (rr, rc) != (2, 2) else black[:, :, 0]
        if rr == 1 and rc == 2:
            b2 = np.vstack([black[0, :, 0], black[0, :, 0]])
        elif rr == 2 and rc == 1:
            b2 = np.hstack([black[:, :1, 0], black[:, :1, 0]])
        scale = 1.0 / (white[0] - b2)
        return cfa_affine(src, scale, -b2 * scale, out=out)
    for i in range(rr):
        for j in range(rc):
            if mosaic:
                b = black[i, j, 0]
                scale = 1.0 / (white[0] - b)
                o = out[i::rr, j::rc]
                np.subtract(src[i::rr, j::rc], np.float32(b), out=o)
                np.multiply(o, np.float32(scale), out=o)
            else:
                b = black[i, j, :samples] if rs >= samples else np.repeat(black[i, j, :1], samples)
                scale = 1.0 / (white - b)
                o = out[i::rr, j::rc]
                np.subtract(src[i::rr, j::rc], b.astype(np.float32), out=o)
                np.multiply(o, scale.astype(np.float32), out=o)
    return out


@dataclass(frozen=True)
class BlackLevel(StageBase):
    """Linearise, subtract the black level and normalise to white = 1.

    Parameters
    ----------
    linearize : bool
        Apply the LinearizationTable and OpcodeList2 MapPolynomial/MapTable
        when the decoder has not already applied them.
    black : float, optional
        Override the file's black level (DN), e.g. for a headerless dump.
    white : float, optional
        Override the file's white level (DN).
    """

    name = "black_level"
    consumes = (Domain.RAW,)
    produces = Domain.RAW_LINEAR

    linearize: bool = True
    black: float | None = None
    white: float | None = None

    def process(self, frame: Frame) -> Frame:
        meta = frame.meta
        data = frame.data
        notes = []
        if self.linearize and meta.linearization_table is not None \
                and "LinearizationTable" not in meta.applied_by_decoder:
            data = linearize(data, meta.linearization_table)
            notes.append("LinearizationTable")
        if self.black is not None:
            black = np.full((1, 1, 1), float(self.black))
        else:
            black = meta.black_pattern()
        white = (self.white,) if self.white is not None else meta.white_level
        if np.any(np.asarray(white) <= black.max()):
            raise InputError(meta.path, f"white level {white} is not above black level {black.max():g}")
        dv = dh = None
        if self.black is None:
            oy, ox = meta.origin
            if meta.black_level_delta_v is not None:
                dv = meta.black_level_delta_v[oy:oy + data.shape[0]]
            if meta.black_level_delta_h is not None:
                dh = meta.black_level_delta_h[ox:ox + data.shape[1]]
        out = subtract_black_level(data, black, white, delta_v=dv, delta_h=dh)
        notes.append(f"black {_fmt(black)} white {_fmt(white)}")
        if self.linearize:
            for list_no, i, op in handled_by(meta, self.name):
                out = _apply_value_map(out, op, meta.origin)
                notes.append(f"OpcodeList{list_no}[{i}] {op.name}")
        return frame.evolve(out, domain=Domain.RAW_LINEAR, stage=self.name, note="; ".join(notes))


def _apply_value_map(data: np.ndarray, op, origin) -> np.ndarray:
    """Apply a MapPolynomial/MapTable opcode to the planes and area it names."""
    a = op.area
    out = data
    planes = range(a.plane, a.plane + a.planes)
    sl = area_slices(a.top, a.left, a.bottom, a.right, a.row_pitch, a.col_pitch, origin, data.shape)
    if sl is None:
        return out
    rows, cols = sl
    if data.ndim == 2:
        if 0 in planes:
            out[rows, cols] = op.evaluate(out[rows, cols])
    else:
        for p in planes:
            if p < data.shape[2]:
                out[rows, cols, p] = op.evaluate(out[rows, cols, p])
    return out


def _fmt(v) -> str:
    a = sorted(set(np.round(np.asarray(v, dtype=np.float64), 3).ravel().tolist()))   # np.unique imports numpy.ma
    return f"{a[0]:g}" if len(a) == 1 else "/".join(f"{x:g}" for x in a)

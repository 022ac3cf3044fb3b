"""Lens-shading correction from the DNG GainMap (and FixVignetteRadial)
opcodes.

Reference: Adobe, *DNG Specification* 1.7.1.0, chapter 7, opcodes GainMap
(ID 9) and FixVignetteRadial (ID 3); Adobe DNG SDK ``dng_gain_map.cpp`` for
the interpolation convention (map positions relative to the image bounds,
pixel centres at +0.5, nearest map point outside the map, bilinear inside).

Notes
-----
Phone DNGs usually carry four GainMaps in OpcodeList2, one per CFA phase
(Top/Left = the phase, RowPitch = ColPitch = 2), so colour shading is
corrected together with luminance shading. A GainMap in OpcodeList3 (after
demosaic, often 3-plane) is applied here before demosaic, each CFA site
taking the gain of its colour plane: the gains vary over tens of pixels and
demosaic mixes only neighbours, so the result is the same to well below the
noise. The SDK clips the product at 1.0; this stage does not (values above
white are real scene light that later stages may still use).

Map sampling
------------
The DNG places map point ``k`` at ``MapOrigin + k · MapSpacing`` (relative
to the image), so a map written with origin 0 and spacing 1/(N − 1) has
its first and last points on the image edges, which is what Android's
DngCreator writes and Adobe's SDK reads (``sampling="dng"``, the default).
Maps made by resizing a coarse grid with OpenCV/PIL conventions put point
``k`` at the centre of cell ``k`` of N, i.e. at ``(k + 0.5) / N``, while still
declaring origin 0 and spacing 1/(N − 1). ``sampling="cell_centred"``
reads such maps as they were made (the shared synthetic S6 test file is one:
its shading follows this convention to 0.5 %, the declared one to only
1.5 %).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from isp.frame import Domain, Frame
from isp.io.opcode_plan import handled_by
from isp.opcodes.base import area_slices
from isp.stage import StageBase


def _phase_indices(sl: slice, n: int, phase: int) -> np.ndarray:
    """Data indices selected by ``sl`` whose absolute CFA phase is ``phase``."""
    idx = np.arange(n)[sl]
    return idx[(idx % 2) == phase]


def cell_centred(op):
    """The same GainMap with its points moved to cell centres
    (origin 0.5/N, spacing 1/N; see the module notes)."""
    import dataclasses

    pv, ph = op.gains.shape[:2]
    return dataclasses.replace(op, origin_v=0.5 / pv, origin_h=0.5 / ph,
                               spacing_v=1.0 / pv, spacing_h=1.0 / ph)


def apply_gain_map(data: np.ndarray, op, origin: tuple[int, int], active_size: tuple[int, int],
                   cfa_pattern: np.ndarray | None = None, per_colour: bool = False,
                   strength: float = 1.0, src: np.ndarray | None = None) -> tuple[float, float]:
    """Multiply ``data`` in place by a GainMap opcode's gains.

    Parameters
    ----------
    data : (H, W) or (H, W, 3) ndarray, float32
        Linear data (modified in place); ``data[0, 0]`` sits at ``origin``
        in active-area pixels.
    op : GainMap
    origin : (int, int)
    active_size : (int, int)
        (H, W) of the active area: the image bounds the map is relative to.
    cfa_pattern : (2, 2) int array, optional
        Channel per CFA phase of ``data`` (0 R, 1 G, 2 B); with
        ``per_colour`` each mosaic site takes the map plane of its colour.
    per_colour : bool
        See above (OpcodeList3 maps applied before demosaic).
    strength : float
        Exponent on the gains: 1 = full correction, 0 = none.
    src : ndarray, optional
        Read the pixels from ``src`` instead of ``data`` (same shape), so a
        set of maps that tiles the image needs no copy first (mosaic,
        single-plane maps only).

    Returns
    -------
    (min gain, max gain) applied.
    """
    a = op.area
    sl = area_slices(a.top, a.left, a.bottom, a.right, a.row_pitch, a.col_pitch, origin, data.shape)
    if sl is None:
        return (1.0, 1.0)
    ah, aw = active_size
    oy, ox = origin
    nplanes = op.gains.shape[2]
    lo, hi = np.inf, -np.inf
    planes = range(a.plane, a.plane + a.planes)

    def gains(rows, cols, plane):
        g = op.evaluate(rows + oy, cols + ox, ah, aw, map_plane=min(plane, nplanes - 1))
        if strength != 1.0:
            g = np.power(g, np.float32(strength))
        return g.astype(np.float32, copy=False)

    rows_all = np.arange(data.shape[0])[sl[0]]
    cols_all = np.arange(data.shape[1])[sl[1]]
    if data.ndim == 2 and not per_colour:
        if 0 in planes:
            g = gains(rows_all, cols_all, 0)
            np.multiply(data[sl] if src is None else src[sl], g, out=data[sl])
            lo, hi = float(g.min()), float(g.max())
    elif data.ndim == 2:
        for pi in range(2):
            for pj in range(2):
                c = int(cfa_pattern[pi, pj])
                if c not in planes:
                    continue
                r = _phase_indices(sl[0], data.shape[0], pi)
                cc = _phase_indices(sl[1], data.shape[1], pj)
                if r.size == 0 or cc.size == 0:
                    continue
                g = gains(r, cc, c)
                data[np.ix_(r, cc)] *= g
                lo, hi = min(lo, float(g.min())), max(hi, float(g.max()))
    else:
        for p in planes:
            if p >= data.shape[2]:
                continue
            g = gains(rows_all, cols_all, p)
            view = data[sl[0], sl[1], p]
            view *= g
            lo, hi = min(lo, float(g.min())), max(hi, float(g.max()))
    return (lo, hi) if np.isfinite(lo) else (1.0, 1.0)


def apply_vignette_radial(data: np.ndarray, op, origin: tuple[int, int],
                          active_size: tuple[int, int], strength: float = 1.0) -> tuple[float, float]:
    """Multiply ``data`` in place by a FixVignetteRadial opcode's gain field
    (evaluated over the active area, cropped to the data)."""
    ah, aw = active_size
    oy, ox = origin
    g = op.evaluate(ah, aw)[oy:oy + data.shape[0], ox:ox + data.shape[1]].astype(np.float32)
    if strength != 1.0:
        g = np.power(g, np.float32(strength))
    if data.ndim == 3:
        data *= g[:, :, None]
    else:
        data *= g
    return float(g.min()), float(g.max())


def apply_phase_maps(data: np.ndarray, maps, origin: tuple[int, int], full_size: tuple[int, int],
                     strength: float = 1.0, out: np.ndarray | None = None):
    """Four per-CFA-phase GainMaps (one per phase, each covering the data) in
    one pass per row parity, or None if their point rows differ.

    The two maps of a row parity share their row weights, so their column
    profiles interleave into one (points × W) matrix; each image row's
    gains are then the blend of two of its rows (bilinear interpolation,
    DNG SDK convention, see :meth:`GainMap.evaluate`), computed and
    multiplied into the data a band of rows at a time, so that the gains
    never exist at full size and every access is contiguous.

    Parameters
    ----------
    data : (H, W) ndarray, float32
        Linear mosaic.
    maps : sequence of 4 GainMap
    origin, full_size : (int, int)
        ``data[0, 0]`` in active-area pixels; the active area's (H, W).
    strength : float
        Exponent on the gains.
    out : (H, W) ndarray, float32, optional
        Where to write (may be ``data`` itself); default a new array.

    Returns
    -------
    (out, [(min, max) gain per map]) or None.
    """
    h, w = data.shape
    oy, ox = origin
    fh, fw = full_size
    by_phase = {}
    for op in maps:
        a = op.area
        sl = area_slices(a.top, a.left, a.bottom, a.right, 2, 2, origin, data.shape)
        by_phase[(sl[0].start, sl[1].start)] = op
    if not all(by_phase[(r, 0)].same_rows(by_phase[(r, 1)]) for r in (0, 1)):
        return None
    if out is None:
        out = np.empty_like(data)
    ranges = {}
    band = max(1, _BAND_VALUES // max(w, 1))
    for r in (0, 1):
        src, dst = data[r::2], out[r::2]
        profile = np.empty((by_phase[(r, 0)].points_v, w), np.float32)
        for c in (0, 1):
            profile[:, c::2] = by_phase[(r, c)].column_profile(np.arange(c, w, 2) + ox, fw)
        i0, i1, w0, w1 = _two_point_rows(by_phase[(r, 0)].row_weights(np.arange(r, h, 2) + oy, fh))
        gains = np.empty((min(band, len(i0)), w), np.float32)
        second = np.empty_like(gains)

        def blend(rows, g, g1):
            np.take(profile, i0[rows], axis=0, out=g)
            g *= w0[rows, None]
            np.take(profile, i1[rows], axis=0, out=g1)
            g1 *= w1[rows, None]
            g += g1
            if strength != 1.0:
                np.power(g, np.float32(strength), out=g)
            return g

        for b0 in range(0, len(i0), band):
            b1 = min(b0 + band, len(i0))
            g = blend(slice(b0, b1), gains[:b1 - b0], second[:b1 - b0])
            np.multiply(src[b0:b1], g, out=dst[b0:b1])
        # between two map rows a column's gain moves monotonically from one
        # point to the next: its extremes lie on the first and last image
        # row of each map cell
        ends = np.flatnonzero(np.diff(i0, prepend=-1, append=-1))
        ends = np.array(sorted({*ends[:-1].tolist(), *(ends[1:] - 1).tolist()}), np.intp)  # np.unique imports numpy.ma
        g = blend(ends, np.empty((len(ends), w), np.float32), np.empty((len(ends), w), np.float32))
        for c in (0, 1):
            ranges[id(by_phase[(r, c)])] = (float(g[:, c::2].min()), float(g[:, c::2].max()))
    return out, [ranges[id(op)] for op in maps]


#: values per band of rows in :func:`apply_phase_maps` (256 KiB of float32:
#: the band's gains and their second term stay in cache)
_BAND_VALUES = 1 << 16


def _two_point_rows(weights: np.ndarray):
    """The two nonzero entries of each row of a bilinear weight matrix
    ``(n, points)``: indices ``i0 ≤ i1`` and their float32 weights (``w1 = 0``
    where one point holds the row, at the map's last point or on a point)."""
    n, points = weights.shape
    i0 = np.argmax(weights != 0, axis=1)
    i1 = np.minimum(i0 + 1, points - 1)
    k = np.arange(n)
    w0 = weights[k, i0].astype(np.float32)
    w1 = np.where(i1 != i0, weights[k, i1], 0).astype(np.float32)
    return i0, i1, w0, w1


def _tiles_by_phase(ops, origin, shape) -> bool:
    """True if ``ops`` are exactly four OpcodeList2 mosaic GainMaps, one per
    CFA phase, each covering the whole data."""
    if len(shape) != 2 or len(ops) != 4:
        return False
    phases = set()
    for list_no, _, op in ops:
        a = op.area
        if list_no != 2 or op.name != "GainMap" or a.row_pitch != 2 or a.col_pitch != 2 \
                or not a.plane <= 0 < a.plane + a.planes:
            return False
        sl = area_slices(a.top, a.left, a.bottom, a.right, 2, 2, origin, shape)
        if sl is None:
            return False
        rs, cs = sl
        if len(range(*rs.indices(shape[0]))) != len(range(rs.start, shape[0], 2)) or \
                len(range(*cs.indices(shape[1]))) != len(range(cs.start, shape[1], 2)):
            return False
        phases.add((rs.start, cs.start))
    return phases == {(0, 0), (0, 1), (1, 0), (1, 1)}


@dataclass(frozen=True)
class LensShading(StageBase):
    """Correct lens shading (vignetting and colour shading) with the file's
    GainMap / FixVignetteRadial opcodes.

    Parameters
    ----------
    strength : float
        Exponent applied to the gains (1 = full correction as the DNG asks;
        phones often use less in the corners to limit noise).
    sampling : {"dng", "cell_centred"}
        Where GainMap points sit (see the module notes); "dng" follows the
        specification and Adobe's SDK.
    """

    name = "lens_shading"
    consumes = (Domain.RAW_LINEAR,)

    strength: float = 1.0
    sampling: Literal["dng", "cell_centred"] = "dng"

    def __post_init__(self):
        if not 0.0 <= self.strength <= 2.0:
            raise ValueError(f"strength must be in [0, 2], got {self.strength}")

    def process(self, frame: Frame) -> Frame:
        meta = frame.meta
        ops = handled_by(meta, self.name)
        if not ops:
            return frame.evolve(stage=self.name, note="no lens-shading opcodes in the file")
        notes = []
        if _tiles_by_phase(ops, meta.origin, frame.data.shape):
            maps = [cell_centred(op) if self.sampling == "cell_centred" else op for _, _, op in ops]
            out = apply_phase_maps(frame.data, maps, meta.origin, frame.full_size, self.strength)
            if out is not None:
                for (list_no, i, op), g in zip(ops, out[1]):
                    notes.append(f"OpcodeList{list_no}[{i}] {op.name} gains {g[0]:.3f}-{g[1]:.3f}")
                return frame.evolve(out[0], stage=self.name, note="; ".join(notes))
            # the usual phone layout: each output pixel is written once from
            # the input, no copy needed
            data, src = np.empty_like(frame.data), frame.data
        else:
            data, src = frame.data.copy(), None
        pattern = meta.cfa.pattern if meta.cfa is not None else None
        for list_no, i, op in ops:
            if op.name == "GainMap":
                if self.sampling == "cell_centred":
                    op = cell_centred(op)
                lo, hi = apply_gain_map(data, op, meta.origin, frame.full_size, pattern,
                                        per_colour=(list_no == 3 and data.ndim == 2),
                                        strength=self.strength, src=src)
            else:
                lo, hi = apply_vignette_radial(data, op, meta.origin, frame.full_size, self.strength)
            notes.append(f"OpcodeList{list_no}[{i}] {op.name} gains {lo:.3f}-{hi:.3f}")
        return frame.evolve(data, stage=self.name, note="; ".join(notes))

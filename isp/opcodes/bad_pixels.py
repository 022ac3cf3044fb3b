"""Bad-pixel opcodes: FixBadPixelsConstant (ID 4) and FixBadPixelsList
(ID 5), read, written and applied as DNG 1.7.1.0 chapter 7 and the Adobe
DNG SDK (``dng_bad_pixels.cpp``) do.

Both work on a one-plane CFA image and interpolate a bad pixel from its
neighbours of the same colour; which sites are green follows from the
BayerPhase (0: the top-left pixel is the green of a red row, 1: red,
2: blue, 3: the green of a blue row): a pixel is green where
``row + col + phase + phase // 2`` is even. Pixels outside the image are
read as the SDK's tiles read them, by repeating its last two rows and
columns (the CFA period). The SDK computes on 16-bit codes with integer
rounding; the same arithmetic is used on stage-1 data (integer DN), and
exact means (no rounding) on the floating-point stage-2 data of this
pipeline. The image is the window held: pixels outside a DefaultCrop are
not read.
"""

from __future__ import annotations

import struct
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from isp.opcodes.base import Opcode, OpcodeContext
from isp.opcodes.binary import U32_MAX, OpcodeError, as_u32, expect_size, frozen_array, set_field

#: neighbourhood radius an isolated bad point needs free (SDK kBadPointPadding)
POINT_PADDING = 2
#: neighbourhood radius an isolated bad rectangle needs free (SDK kBadRectPadding)
RECT_PADDING = 4

# sets of same-colour neighbours tried in turn for a clustered bad point
# (SDK FixClusteredPixel), then for the pixels of a bad rectangle
# (FixClusteredRect); a red/blue pixel skips the sets at odd offsets
_POINT_SETS = (((-1, 1), (-1, -1), (1, -1), (1, 1)),
               ((-2, 0), (2, 0), (0, -2), (0, 2)),
               ((-2, -2), (-2, 2), (2, -2), (2, 2)))
_RECT_SETS = _POINT_SETS + (
    ((-1, -3), (-3, -1), (1, -3), (3, -1), (-1, 3), (-3, 1), (1, 3), (3, 1)),
    ((-4, 0), (4, 0), (0, -4), (0, 4)),
    ((-3, -3), (-3, 3), (3, -3), (3, 3)),
    ((-2, -4), (-4, -2), (2, -4), (4, -2), (-2, 4), (-4, 2), (2, 4), (4, 2)),
    ((-4, -4), (-4, 4), (4, -4), (4, 4)))


def _repeat_index(idx: np.ndarray, n: int) -> np.ndarray:
    """Indices outside 0..n-1 moved into the first or last two (period-2
    repetition of the edge, phase kept: the SDK's ``edge_repeat`` 2 x 2)."""
    if n < 2:
        return np.zeros_like(idx)
    out = np.where(idx < 0, idx % 2, idx)
    return np.where(out >= n, n - 2 + (out - (n - 2)) % 2, out)


class _Arith:
    """The SDK's integer averages on integer codes, plain ones otherwise."""

    def __init__(self, integer: bool):
        self.integer = integer

    def mean(self, total, count):
        total = np.asarray(total, dtype=np.float64)
        count = np.maximum(np.asarray(count, dtype=np.float64), 1.0)
        if self.integer:
            return np.floor((total + np.floor(count / 2)) / count)
        return total / count

    def limit(self, grad):
        """(3 min) >> 1: the gradients an estimate may have."""
        return np.floor(grad * 3 / 2) if self.integer else grad * 1.5

    def shift5(self, x):
        """(x + 16) >> 5."""
        return np.floor((x + 16) / 32) if self.integer else x / 32


def _is_green(rows, cols, phase: int) -> np.ndarray:
    return ((np.asarray(rows) + np.asarray(cols) + phase + (phase >> 1)) & 1) == 0


def _reader(data: np.ndarray, ctx: OpcodeContext):
    """``(get, scale, arithmetic)``: ``get(rows, cols)`` reads pixels of the
    plane ``data`` as float64 16-bit codes (indices outside repeated as the
    SDK's tiles repeat them), ``scale`` is codes per data unit, and the
    arithmetic is the SDK's integer one on stage-1 data."""
    h, w = data.shape
    scale = 65535.0 / ctx.code_max

    def get(rows, cols) -> np.ndarray:
        r = _repeat_index(np.asarray(rows), h)
        c = _repeat_index(np.asarray(cols), w)
        return data[r, c].astype(np.float64) * scale

    return get, scale, _Arith(ctx.stage == 1)

# --------------------------------------------------------------------------
# bad pixels

@dataclass(frozen=True, repr=False)
class FixBadPixelsConstant(Opcode):
    """Pixels equal to a constant are bad and interpolated (ID 4).

    Parameters: uint32 Constant (the marker value, DN), uint32 BayerPhase
    (0..3: position of the top-left pixel's colour in the 2x2 pattern).
    """

    ID = 4
    constant: int
    bayer_phase: int

    def _validate(self):
        set_field(self, "constant", as_u32(self.constant, "constant"))
        set_field(self, "bayer_phase", as_u32(self.bayer_phase, "Bayer phase"))

    def _params(self):
        return struct.pack(">II", self.constant, self.bayer_phase)

    @classmethod
    def _parse(cls, r, size, **header):
        expect_size(size, 8, "constant and Bayer phase")
        return cls(*r.u32s(2, "parameters"), **header)

    def unsupported(self, stage, planes):
        if planes != 1:
            return f"needs a one-plane CFA image, this one has {planes} planes (the SDK refuses it)"
        return None

    def apply(self, data: np.ndarray, ctx: OpcodeContext) -> np.ndarray:
        """Replace every pixel whose 16-bit code equals the constant by the
        mean of its same-colour neighbours that are not (SDK
        ``dng_opcode_FixBadPixelsConstant::ProcessArea``): a green pixel
        its four diagonal neighbours, a red or blue one the four at two
        pixels up, down, left and right. Neighbours come from the input
        (a repaired pixel is not reused); a pixel without a good neighbour
        stays. In place; returns ``data``."""
        self._check_apply(data, ctx)
        get, scale, ar = _reader(data, ctx)
        bad = np.rint(data * np.float32(scale)) == self.constant
        if not bad.any():
            return data
        ys, xs = np.nonzero(bad)
        oy, ox = ctx.origin
        green = _is_green(ys + oy, xs + ox, self.bayer_phase)
        total = np.zeros(ys.size)
        count = np.zeros(ys.size)
        for (dg, dn) in zip(((-1, -1), (-1, 1), (1, -1), (1, 1)),
                            ((-2, 0), (2, 0), (0, -2), (0, 2))):
            dy = np.where(green, dg[0], dn[0])
            dx = np.where(green, dg[1], dn[1])
            v = get(ys + dy, xs + dx)
            ok = np.rint(v) != self.constant
            total += np.where(ok, v, 0.0)
            count += ok
        fixed = count > 0
        est = ar.mean(total, count)
        data[ys[fixed], xs[fixed]] = (est[fixed] / scale).astype(data.dtype)
        return data

    def _describe(self):
        return {"constant": self.constant, "bayer_phase": self.bayer_phase}


@dataclass(frozen=True, eq=False, repr=False)
class FixBadPixelsList(Opcode):
    """Listed bad pixels and rectangles are interpolated (ID 5).

    Parameters: uint32 BayerPhase, BadPointCount, BadRectCount; then per
    point uint32 row, col; then per rectangle uint32 top, left, bottom,
    right. The order is kept as stored (the SDK sorts after reading).

    Attributes
    ----------
    bayer_phase : int
    points : (P, 2) ndarray of uint32
        (row, col) of each bad pixel.
    rects : (R, 4) ndarray of uint32
        (top, left, bottom, right) of each bad rectangle, bottom/right
        exclusive.
    """

    ID = 5
    bayer_phase: int
    points: Any = ()
    rects: Any = ()

    def _validate(self):
        set_field(self, "bayer_phase", as_u32(self.bayer_phase, "Bayer phase"))
        for name, width in (("points", 2), ("rects", 4)):
            raw = np.asarray(getattr(self, name))
            a = raw.reshape(-1, width) if raw.size == 0 else raw
            if a.ndim != 2 or a.shape[1] != width:
                raise OpcodeError(f"{name} must have shape (n, {width}), got {raw.shape}")
            if a.size and (np.any(a < 0) or np.any(a > U32_MAX) or np.any(a != np.round(a))):
                raise OpcodeError(f"{name} must hold integers in 0..{U32_MAX}")
            set_field(self, name, frozen_array(a, np.uint32, 2, name))

    def _params(self):
        return (struct.pack(">III", self.bayer_phase, len(self.points), len(self.rects))
                + self.points.astype(">u4").tobytes() + self.rects.astype(">u4").tobytes())

    @classmethod
    def _parse(cls, r, size, **header):
        phase, n_points, n_rects = r.u32s(3, "counts")
        expect_size(size, 12 + 8 * n_points + 16 * n_rects,
                     f"{n_points} bad points and {n_rects} bad rectangles")
        points = r.array(">u4", 2 * n_points, "bad points").reshape(n_points, 2)
        rects = r.array(">u4", 4 * n_rects, "bad rectangles").reshape(n_rects, 4)
        return cls(phase, points, rects, **header)

    def unsupported(self, stage, planes):
        if planes != 1:
            return f"needs a one-plane CFA image, this one has {planes} planes (the SDK refuses it)"
        return None

    def apply(self, data: np.ndarray, ctx: OpcodeContext) -> np.ndarray:
        """Repair the listed points, then the rectangles, as the SDK does
        (``dng_opcode_FixBadPixelsList::ProcessArea``), in place:

        * a point with no other bad point or rectangle within
          :data:`POINT_PADDING` pixels and at least that far inside the
          image: the mean of the one to four same-colour pairs (vertical,
          horizontal, the two diagonals) whose gradient, summed over the
          5 x 5 neighbourhood, is within 1.5 x the smallest
          (``FixIsolatedPixel``);
        * any other point: the mean of the first set of same-colour
          neighbours (diagonal, then at two pixels, then two diagonally)
          with a good pixel in the image (``FixClusteredPixel``);
        * a one-pixel-wide column (row) rectangle with no other rectangle
          within :data:`RECT_PADDING` and two pixels inside the image:
          per pixel the mean of the best of seven directional pairs over a
          9 x 9 neighbourhood, greens corrected for the split between
          their two kinds, limited to the range of the nearest same-colour
          pixels (``FixSingleColumn`` / ``FixSingleRow``);
        * any other rectangle: per pixel as a clustered point, over eight
          sets up to four pixels away (``FixClusteredRect``).

        Points and rectangles are in the list's image coordinates; those
        outside the window held are not repaired. Returns ``data``."""
        self._check_apply(data, ctx)
        if not len(self.points) and not len(self.rects):
            return data
        get, scale, ar = _reader(data, ctx)
        h, w = data.shape
        oy, ox = ctx.origin
        listed = [(int(r) - oy, int(c) - ox) for r, c in self.points]
        pts = sorted(set(listed))
        repeated = {p for p, n in Counter(listed).items() if n > 1}   # never isolated
        rects = sorted({(int(t) - oy, int(l) - ox, int(b) - oy, int(r) - ox)
                        for t, l, b, r in self.rects})
        point_set = set(pts)

        def green_at(r, c):
            return _is_green(np.asarray(r) + oy, np.asarray(c) + ox, self.bayer_phase)

        def put(r, c, codes):
            data[r, c] = np.asarray(codes) / scale

        def valid(r, c) -> np.ndarray:
            r, c = np.asarray(r), np.asarray(c)
            ok = (r >= 0) & (r < h) & (c >= 0) & (c < w)
            for t, l, b, rr in rects:
                ok &= ~((r >= t) & (r < b) & (c >= l) & (c < rr))
            return ok

        # -- points ---------------------------------------------------------
        inside = [(r, c) for r, c in pts if 0 <= r < h and 0 <= c < w]
        isolated, clustered = [], []
        pad = POINT_PADDING
        for r, c in inside:
            alone = (r, c) not in repeated and not any(
                (r + dy, c + dx) in point_set
                for dy in range(-pad, pad + 1) for dx in range(-pad, pad + 1) if dy or dx)
            alone = alone and not any(t < r + pad + 1 and r - pad < b and l < c + pad + 1
                                      and c - pad < rr for t, l, b, rr in rects)
            if alone and pad <= r < h - pad and pad <= c < w - pad:
                isolated.append((r, c))
            else:
                clustered.append((r, c))
        if isolated:
            r, c = np.array(isolated).T
            d = np.arange(-2, 3)
            win = get(r[:, None, None] + d[None, :, None], c[:, None, None] + d[None, None, :])
            put(r, c, _isolated(win, green_at(r, c), ar))      # (N, 5, 5) neighbourhoods
        for r, c in clustered:
            green = bool(green_at(r, c))
            for offsets in _POINT_SETS:
                if not green and offsets[0][0] & 1:
                    continue
                rr = np.array([r + dy for dy, _ in offsets])
                cc = np.array([c + dx for _, dx in offsets])
                ok = valid(rr, cc) & np.array([(a, b) not in point_set for a, b in zip(rr, cc)])
                if ok.any():
                    put(r, c, ar.mean(get(rr[ok], cc[ok]).sum(), ok.sum()))
                    break
        # -- rectangles (reading the repaired points) -------------------------
        for index, (t, l, b, rr) in enumerate(rects):
            t0, l0, b0, r0 = max(t, 0), max(l, 0), min(b, h), min(rr, w)
            if t0 >= b0 or l0 >= r0:
                continue
            alone = not any(tt < b + RECT_PADDING and t - RECT_PADDING < bb
                            and ll < rr + RECT_PADDING and l - RECT_PADDING < rrr
                            for j, (tt, ll, bb, rrr) in enumerate(rects) if j != index)
            if alone and rr == l + 1 and l >= 2 and rr <= w - 2:
                rows = np.arange(t0, b0)
                put(rows, l, _single_line(lambda i, j: get(rows + i - 4, l + j - 4),
                                          green_at(rows, l), ar))
            elif alone and b == t + 1 and t >= 2 and b <= h - 2:
                cols = np.arange(l0, r0)
                put(t, cols, _single_line(lambda i, j: get(t + j - 4, cols + i - 4),
                                          green_at(t, cols), ar))
            else:
                rows, cols = np.mgrid[t0:b0, l0:r0]
                rows, cols = rows.ravel(), cols.ravel()
                green = green_at(rows, cols)
                todo = np.ones(rows.size, dtype=bool)
                for offsets in _RECT_SETS:
                    use = todo & (green | ((offsets[0][0] & 1) == 0))
                    if not use.any():
                        continue
                    total = np.zeros(rows.size)
                    count = np.zeros(rows.size)
                    for dy, dx in offsets:
                        ok = valid(rows + dy, cols + dx) & use
                        total += np.where(ok, get(rows + dy, cols + dx), 0.0)
                        count += ok
                    done = use & (count > 0)
                    put(rows[done], cols[done], ar.mean(total[done], count[done]))
                    todo &= ~done
        return data

    def _describe(self):
        return {"bayer_phase": self.bayer_phase, "bad_points": int(len(self.points)),
                "bad_rects": int(len(self.rects))}


def _isolated(win: np.ndarray, green: np.ndarray, ar: _Arith) -> np.ndarray:
    """FixIsolatedPixel on (N, 5, 5) neighbourhoods (the bad pixel at the
    centre); the estimate per pixel."""
    a = lambda i, j: win[:, i, j]  # noqa: E731
    d = lambda p, q: np.abs(a(*p) - a(*q))  # noqa: E731
    # green: g at even (i + j), the other colours at odd
    g_est = (a(0, 2) + a(4, 2), a(1, 1) + a(3, 3), a(2, 0) + a(2, 4), a(1, 3) + a(3, 1))
    g_grad = (
        d((0, 2), (4, 2)) + d((1, 1), (3, 1)) + d((1, 3), (3, 3)) + d((0, 1), (2, 1))
        + d((0, 3), (2, 3)) + d((2, 1), (4, 1)) + d((2, 3), (4, 3)),
        d((1, 1), (3, 3)) + d((0, 2), (2, 4)) + d((2, 0), (4, 2)) + d((0, 1), (2, 3))
        + d((1, 0), (3, 2)) + d((1, 2), (3, 4)) + d((2, 1), (4, 3)),
        d((2, 0), (2, 4)) + d((1, 1), (1, 3)) + d((3, 1), (3, 3)) + d((1, 0), (1, 2))
        + d((3, 0), (3, 2)) + d((1, 2), (1, 4)) + d((3, 2), (3, 4)),
        d((1, 3), (3, 1)) + d((0, 2), (2, 0)) + d((2, 4), (4, 2)) + d((0, 3), (2, 1))
        + d((1, 4), (3, 2)) + d((1, 2), (3, 0)) + d((2, 3), (4, 1)))
    # red/blue: the same colour at even (i, j)
    c_est = (a(0, 2) + a(4, 2), a(0, 0) + a(4, 4), a(2, 0) + a(2, 4), a(0, 4) + a(4, 0))
    c_grad = (
        d((0, 2), (4, 2)) + d((1, 2), (3, 2)) + d((0, 1), (2, 1)) + d((2, 1), (4, 1))
        + d((0, 3), (2, 3)) + d((2, 3), (4, 3)) + d((1, 1), (3, 1)) + d((1, 3), (3, 3)),
        d((0, 0), (4, 4)) + d((1, 1), (3, 3)) + d((0, 1), (2, 3)) + d((1, 0), (3, 2))
        + d((1, 2), (3, 4)) + d((2, 1), (4, 3)) + d((0, 2), (2, 4)) + d((2, 0), (4, 2)),
        d((2, 0), (2, 4)) + d((2, 1), (2, 3)) + d((1, 0), (1, 2)) + d((1, 2), (1, 4))
        + d((3, 0), (3, 2)) + d((3, 2), (3, 4)) + d((1, 1), (1, 3)) + d((3, 1), (3, 3)),
        d((0, 4), (4, 0)) + d((1, 3), (3, 1)) + d((0, 3), (2, 1)) + d((1, 4), (3, 2))
        + d((1, 2), (3, 0)) + d((2, 3), (4, 1)) + d((0, 2), (2, 0)) + d((2, 4), (4, 2)))
    est = np.where(green, np.array(g_est), np.array(c_est))      # (4, N)
    grad = np.where(green, np.array(g_grad), np.array(c_grad))
    limit = ar.limit(grad.min(axis=0))
    use = grad <= limit
    return ar.mean((est * use).sum(axis=0), 2 * use.sum(axis=0))


def _single_line(p, green: np.ndarray, ar: _Arith) -> np.ndarray:
    """FixSingleColumn for the pixels of a bad column: ``p(i, j)`` reads
    the 9 x 9 neighbourhoods (centre (4, 4); rows and columns swapped for a
    bad row), in 16-bit codes; the estimates."""

    def d(x, y):
        return np.abs(p(*x) - p(*y))

    split = ar.shift5((p(2, 2) + p(6, 2) + p(2, 6) + p(6, 6)) * 4 + (p(4, 2) + p(4, 6)) * 8
                      - (p(1, 1) + p(1, 3) + p(1, 5) + p(1, 7))
                      - (p(3, 1) + p(3, 3) + p(3, 5) + p(3, 7)) * 3
                      - (p(5, 1) + p(5, 3) + p(5, 5) + p(5, 7)) * 3
                      - (p(7, 1) + p(7, 3) + p(7, 5) + p(7, 7)))
    g_est = (p(1, 3) + p(7, 5) + split * 2, p(3, 3) + p(5, 5) + split * 2,
             p(3, 1) + p(5, 7) + split * 2, p(4, 2) + p(4, 6),
             p(3, 7) + p(5, 1) + split * 2, p(3, 5) + p(5, 3) + split * 2,
             p(1, 5) + p(7, 3) + split * 2)
    g_grad = (
        d((1, 3), (7, 5)) + d((1, 5), (4, 6)) + d((2, 2), (5, 3)) + d((3, 5), (6, 6))
        + d((4, 2), (7, 3)) + d((0, 3), (6, 5)) + d((2, 3), (8, 5)),
        d((3, 3), (5, 5)) + d((2, 2), (5, 5)) + d((3, 3), (6, 6)) + d((1, 3), (3, 5))
        + d((5, 3), (7, 5)) + d((2, 3), (4, 5)) + d((4, 3), (6, 5)),
        d((3, 1), (5, 7)) + d((3, 3), (4, 6)) + d((3, 5), (4, 8)) + d((4, 0), (5, 3))
        + d((4, 2), (5, 5)) + d((3, 0), (5, 6)) + d((3, 2), (5, 8)),
        d((4, 2), (4, 6)) * 2 + d((3, 3), (3, 5)) + d((5, 3), (5, 5)) + d((2, 3), (2, 5))
        + d((4, 3), (4, 5)) + d((6, 3), (6, 5)),
        d((3, 7), (5, 1)) + d((3, 5), (4, 2)) + d((3, 3), (4, 0)) + d((4, 8), (5, 5))
        + d((4, 6), (5, 3)) + d((3, 8), (5, 2)) + d((3, 6), (5, 0)),
        d((3, 5), (5, 3)) + d((2, 6), (5, 3)) + d((3, 5), (6, 2)) + d((1, 5), (3, 3))
        + d((5, 5), (7, 3)) + d((2, 5), (4, 3)) + d((4, 5), (6, 3)),
        d((1, 5), (7, 3)) + d((1, 3), (4, 2)) + d((2, 6), (5, 5)) + d((3, 3), (6, 2))
        + d((4, 6), (7, 5)) + d((0, 5), (6, 3)) + d((2, 5), (8, 3)))
    g_lo = np.minimum(np.minimum(p(3, 3), p(3, 5)), np.minimum(p(5, 3), p(5, 5)))
    g_hi = np.maximum(np.maximum(p(3, 3), p(3, 5)), np.maximum(p(5, 3), p(5, 5)))
    g_lo = np.clip(g_lo + split, 0, 65535)
    g_hi = np.clip(g_hi + split, 0, 65535)
    c_est = (p(0, 2) + p(8, 6), p(2, 2) + p(6, 6), p(2, 0) + p(6, 8), p(4, 2) + p(4, 6),
             p(2, 8) + p(6, 0), p(2, 6) + p(6, 2), p(0, 6) + p(8, 2))
    c_grad = (
        d((0, 2), (8, 6)) + d((1, 3), (5, 5)) + d((3, 3), (7, 5)) + d((0, 3), (4, 5))
        + d((2, 3), (6, 5)) + d((4, 3), (8, 5)),
        d((2, 2), (6, 6)) + d((1, 3), (3, 5)) + d((3, 3), (5, 5)) + d((5, 3), (7, 5))
        + d((2, 3), (4, 5)) + d((4, 3), (6, 5)),
        d((2, 0), (6, 8)) + d((3, 1), (5, 5)) + d((3, 3), (5, 7)) + d((2, 3), (4, 7))
        + d((3, 2), (5, 6)) + d((4, 1), (6, 5)),
        # the SDK's fifth term compares g43 with itself, i.e. adds nothing
        d((4, 2), (4, 6)) + d((3, 3), (3, 5)) + d((5, 3), (5, 5)) + d((3, 2), (3, 6))
        + d((5, 2), (5, 6)),
        d((2, 8), (6, 0)) + d((3, 7), (5, 3)) + d((3, 5), (5, 1)) + d((2, 5), (4, 1))
        + d((3, 6), (5, 2)) + d((4, 7), (6, 3)),
        d((2, 6), (6, 2)) + d((1, 5), (3, 3)) + d((3, 5), (5, 3)) + d((5, 5), (7, 3))
        + d((2, 5), (4, 3)) + d((4, 5), (6, 3)),
        d((0, 6), (8, 2)) + d((1, 5), (5, 3)) + d((3, 5), (7, 3)) + d((0, 5), (4, 3))
        + d((2, 5), (6, 3)) + d((4, 5), (8, 3)))
    c_lo = np.minimum(p(4, 2), p(4, 6))
    c_hi = np.maximum(p(4, 2), p(4, 6))
    est = np.where(green, np.array(g_est), np.array(c_est))      # (7, N)
    grad = np.where(green, np.array(g_grad), np.array(c_grad))
    limit = ar.limit(grad.min(axis=0))
    use = grad <= limit
    estimate = ar.mean((est * use).sum(axis=0), 2 * use.sum(axis=0))
    lo = np.where(green, g_lo, c_lo)
    hi = np.where(green, g_hi, c_hi)
    return np.minimum(np.maximum(estimate, lo), hi)

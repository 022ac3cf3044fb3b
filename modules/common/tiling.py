"""Tiled execution of a local image operator: bounded memory, no seams.

A convolutional network is *local*: an output pixel depends only on the
input within its receptive-field radius ``r``. Cut the frame into tiles,
give each tile a context margin ``m ≥ r`` on every side, run the operator
on the tile with its margin, and keep only the tile's *core*: every kept
pixel was computed from exactly the inputs the whole-frame run would have
used, so the stitched frame equals the whole-frame result up to float
rounding, and there is no seam to hide.

This is **crop-centre stitching**, chosen over blending overlapping
outputs with a smooth window (raised cosine, linear ramps):

* with ``m ≥ r`` both give the exact result, so blending buys nothing and
  costs a weight accumulator (or a second output buffer) and a
  multiply-add per overlapped pixel;
* with ``m < r`` blending only smears the error of the two tiles over the
  ramp (the seam becomes a band), it does not remove it; the remedy is a
  larger margin, and the error measurable by comparing against a
  whole-frame run (``tests/modules/common/test_tiling.py`` shows it growing as ``m``
  drops below ``r``).

Frame borders are padded by reflection (numpy's ``"reflect"`` mode, the
edge pixel not repeated), with the same rule in the whole-frame run (one
tile) and the tiled one, so border pixels agree too. Reflection is done by
index (:func:`reflect_indices`), never by padding the whole frame, so the
extra memory is one tile, not one frame.

The reflected context at the frame's borders, ``border``, need not be the
margin between tiles. The margin is set by seams: a tile must see what
the whole-frame run sees up to the receptive radius, or the two differ. The
border context is made up (a mirror image) in both runs alike, so it is
set by quality alone: enough of a plausible surround that the operator's
border pixels do not feel the zero padding beyond it. For an INT8 model the
two differ by much: a seam appears wherever a context change flips one
rounding, so its margin is about its whole receptive radius (64 px for the
packaged model), while its float model's influence has decayed within 32
px (:mod:`export.onnx_export`). The windows at the frame's edges then reach
``border`` beyond it instead of ``margin``.

Operators that downsample (a UNet with stride 2 twice) are translation
equivariant only for shifts by a multiple of their total stride. Tile
origins, margins and core sizes are therefore multiples of ``multiple``,
measured from the same origin as the whole-frame run, and every window has
a side that is a multiple of ``multiple``.

Notes
-----
Along one axis of length ``n``, with ``M = multiple``, margin ``m`` (rounded
up to a multiple of ``M``), tile side ``t`` (the operator's input, margin
included) and ``n_p = ⌈n / M⌉ M``:

* cores ``[s_k, s_k + c)``, ``s_k = k c``, with ``k = 0..K-1``,
  ``K = ⌈n_p / c_max⌉``, ``c_max = ⌊(t - 2m) / M⌋ M`` and
  ``c = ⌈n_p / (K M)⌉ M`` (evenly split, so the last tile is not a sliver);
* windows ``[s_k - m, s_k + c + m)`` read from the frame with reflected
  indices, except at the frame's edges: the first starts at ``-b`` and
  the last ends at ``n_p + b``, ``b`` the border context (rounded up to a
  multiple of ``M``; default ``m``); the output kept is ``[s_k, min(s_k +
  c, n))``.

``t ≤ 0`` (or ``t ≥ n_p + 2b``) gives one window ``[-b, n_p + b)``: the
whole-frame reference, padded exactly as the tiles are.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


def reflect_indices(start: int, stop: int, n: int) -> np.ndarray:
    """Indices ``start .. stop-1`` folded into ``[0, n)`` by reflection.

    The edge sample is not repeated (numpy ``np.pad(mode="reflect")``), and
    indices further than ``n`` outside fold again (periodic with period
    ``2 (n - 1)``), so any margin works on any frame.

    Returns
    -------
    ndarray (stop - start,) int64, values in [0, n).

    >>> reflect_indices(-2, 5, 4)
    array([2, 1, 0, 1, 2, 3, 2])
    """
    if n < 1:
        raise ValueError(f"axis length must be ≥ 1, got {n}")
    i = np.arange(start, stop, dtype=np.int64)
    if n == 1:
        return np.zeros_like(i)
    period = 2 * (n - 1)
    i = np.mod(i, period)
    return np.where(i >= n, period - i, i)


@dataclass(frozen=True)
class Span:
    """One tile along one axis: the window read (frame coordinates, may
    reach outside ``[0, n)``) and the core written (inside ``[0, n)``)."""

    win_start: int
    win_stop: int
    core_start: int
    core_stop: int

    @property
    def core_in_window(self) -> slice:
        """Where the written core sits in the window."""
        a = self.core_start - self.win_start
        return slice(a, a + self.core_stop - self.core_start)


def _round_up(v: int, m: int) -> int:
    return -(-v // m) * m


def split_axis(n: int, tile: int, margin: int, multiple: int = 1, border: int | None = None) -> list[Span]:
    """Tiles along one axis of length ``n`` (see the module Notes).

    Parameters
    ----------
    n : int
        Axis length in pixels.
    tile : int
        Window side (margin included) the operator should see; ``≤ 0`` for
        one window over the whole axis.
    margin : int
        Context between tiles on each side, ≥ the operator's
        receptive-field radius; rounded up to a multiple of ``multiple``.
    multiple : int
        Window sides and tile origins are multiples of it.
    border : int, optional
        Reflected context beyond the frame's edges (default and at most
        ``margin``; module docstring); rounded up to a multiple of
        ``multiple``.

    Raises
    ------
    ValueError
        When ``tile`` leaves no core after the margins.

    Examples
    --------
    >>> [(s.win_start, s.win_stop) for s in split_axis(100, 64, 16, 4, border=8)]
    [(-8, 44), (12, 72), (40, 100), (68, 108)]
    """
    if n < 1 or margin < 0 or multiple < 1 or (border is not None and border < 0):
        raise ValueError(f"need n ≥ 1, margin ≥ 0, multiple ≥ 1, border ≥ 0; "
                         f"got {n}, {margin}, {multiple}, {border}")
    m = _round_up(margin, multiple)
    b = m if border is None else min(_round_up(border, multiple), m)   # nothing past m reaches a kept pixel
    n_pad = _round_up(n, multiple)
    if tile <= 0 or tile >= n_pad + 2 * b:
        return [Span(-b, n_pad + b, 0, n)]
    c_max = (tile - 2 * m) // multiple * multiple
    if c_max < multiple:
        raise ValueError(f"tile {tile} px leaves no core inside a margin of {m} px on each side "
                         f"(multiple {multiple}): use a tile of at least {2 * m + multiple} px")
    k = -(-n_pad // c_max)
    c = _round_up(-(-n_pad // k), multiple)
    return [Span(-b if s == 0 else s - m, n_pad + b if s + c >= n else s + c + m, s, min(s + c, n))
            for s in range(0, n, c)]


@dataclass(frozen=True)
class Tile:
    """A tile of a 2-D frame: the product of a row span and a column span."""

    rows: Span
    cols: Span

    @property
    def window_shape(self) -> tuple[int, int]:
        return (self.rows.win_stop - self.rows.win_start, self.cols.win_stop - self.cols.win_start)


def plan_tiles(shape: tuple[int, int], tile: int, margin: int, multiple: int = 1,
               border: int | None = None) -> list[Tile]:
    """Tiles covering a frame of ``shape = (H, W)``, row-major. Windows are
    at most ``tile`` a side (the cores are split evenly); with ``border <
    margin`` those at the frame's edges are shorter by the difference. See
    :func:`split_axis` for the parameters.

    >>> [t.window_shape for t in plan_tiles((6, 10), 8, 2, 2)]
    [(8, 8), (8, 8), (8, 6), (6, 8), (6, 8), (6, 6)]
    """
    h, w = shape
    return [Tile(r, c) for r in split_axis(h, tile, margin, multiple, border)
            for c in split_axis(w, tile, margin, multiple, border)]


def _reflected_run(idx: np.ndarray, n: int) -> tuple[int, int, int, int] | None:
    """``(start, stop, before, after)`` when ``idx`` is ``reflect_indices``
    of a window that is the run ``start .. stop-1`` of ``[0, n)`` plus
    ``before`` and ``after`` samples reflected within the run (a single
    fold each, shorter than the run). None for anything else.

    >>> _reflected_run(reflect_indices(-2, 5, 6), 6)
    (0, 5, 2, 0)
    """
    if idx.size < 2:
        return None
    before = int(idx[0]) if idx[1] < idx[0] else 0
    after = n - 1 - int(idx[-1]) if idx[-1] < idx[-2] else 0
    w0 = int(idx[0]) if not before else -before
    start, stop = w0 + before, w0 + idx.size - after
    # the folds must read inside the run itself (OpenCV sees the run alone)
    if not (0 <= start < stop <= n) or max(before, after) > stop - start - 1 \
            or not np.array_equal(idx, reflect_indices(w0, w0 + idx.size, n)):
        return None
    return start, stop, before, after


def _gather(a: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``a[rows][:, cols]`` reading only the window's bounding box: a view
    where the indices are runs (tiles inside the frame), else a copy of the
    window alone (tiles reaching a border): by OpenCV's reflecting border
    where the indices fold once (``BORDER_REFLECT_101``, numpy's
    ``"reflect"``; 1.6 ms against numpy's indexed copy's 14 ms for a 1,536²
    × 3 float32 window, 51 of the 120 ms a 12 MP frame spent outside the
    model in 1,536-px tiles), else by indexing."""
    rr, cr = _reflected_run(rows, a.shape[0]), _reflected_run(cols, a.shape[1])
    if rr is not None and cr is not None and (rr[2:] != (0, 0) or cr[2:] != (0, 0)) \
            and a.dtype in (np.float32, np.float64, np.uint8, np.uint16) and a.ndim == 3 and a.shape[2] <= 4:
        import cv2   # here, not at the top: `isp info` reads a correction stage without pixels

        inner = a[rr[0]:rr[1], cr[0]:cr[1]]
        return cv2.copyMakeBorder(inner, rr[2], rr[3], cr[2], cr[3], cv2.BORDER_REFLECT_101)
    box = a[rows.min():rows.max() + 1, cols.min():cols.max() + 1]
    for axis, idx in ((0, rows), (1, cols)):
        i = idx - idx.min()
        if not (i.size == box.shape[axis] and np.all(np.diff(i) == 1)):
            box = np.take(box, i, axis=axis)
    return box


def window_indices(t: Tile, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Frame row and column indices (reflected) each window pixel is read from."""
    return (reflect_indices(t.rows.win_start, t.rows.win_stop, shape[0]),
            reflect_indices(t.cols.win_start, t.cols.win_stop, shape[1]))


def read_window(image: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                out: np.ndarray | None = None, packing: int = 1) -> np.ndarray:
    """The window of an ``(H, W, C)`` image at ``rows × cols`` as ``(C, h,
    w)`` (the layout a network takes), written into ``out[:C]`` when given
    (a buffer reused between tiles), else into a new float32 array.

    ``packing = s > 1``: packed ``s × s`` to depth instead, ``(C·s², h/s,
    w/s)`` with channel ``(dy·s + dx)·C + c`` from pixel ``(s·i + dy, s·j +
    dx)`` (:func:`modules.correction.pack_input`): row ``dy`` of every block
    is a plain view of the window whose pixels interleave ``(dx, c)``, so
    packing costs the same de-interleave as the planar copy.
    """
    sub = _gather(image, rows, cols)
    c, s = image.shape[2], packing
    h, w = rows.size // s, cols.size // s
    if rows.size % s or cols.size % s:
        raise ValueError(f"window {rows.size}×{cols.size} is not a multiple of the packing {s}")
    if out is None:
        out = np.empty((c * s * s, h, w), np.float32)
    for dy in range(s):
        # (h, w, s·c): a view while the window's pixels are contiguous along a row (they are)
        _split(sub[dy::s].reshape(h, w, s * c), out[dy * s * c:(dy + 1) * s * c])
    return out


def _split(src: np.ndarray, planes: np.ndarray) -> None:
    """``planes[k] = src[..., k]``."""
    c = src.shape[2]
    if _cv2_planes(src.dtype, planes.dtype, c):
        import cv2

        # OpenCV's SIMD de-interleave straight into the planes: 3.2× faster than numpy's
        # strided plane copies on a 1,072² × 3 float32 window (8.0 → 2.5 ms)
        cv2.split(src, [planes[k] for k in range(c)])
    else:
        for k in range(c):  # one plane at a time: 3-4× faster than a moveaxis copy
            planes[k] = src[..., k]


def _cv2_planes(a, b, channels: int) -> bool:
    """Whether OpenCV can (de-)interleave between these dtypes: same dtype,
    one it has (float32; float16 only as CV_16F), 2 to 12 channels."""
    return a == b and a in (np.float32, np.float16) and 1 < channels <= 12


def write_planes(dst: np.ndarray, planes: np.ndarray, packing: int = 1) -> None:
    """``dst[..., k] = planes[k]`` for an ``(h, w, C)`` view ``dst`` (rows
    may be strided) and ``(C, h, w)`` planes: OpenCV's interleave into the
    view where it can (5.5× numpy's plane loop on 1,024² × 3 float32), else
    numpy. ``packing = s > 1``: ``planes`` are ``(C·s², ⌈h/s⌉, ⌈w/s⌉)``,
    packed as :func:`read_window` packs (``h, w`` need not be multiples of
    ``s``: a tile cut by the frame's edge)."""
    s = packing
    hh, ww, c = dst.shape
    if s > 1:
        for dy in range(min(s, hh)):
            rows = dst[dy::s]
            nr, p = rows.shape[0], planes[dy * s * c:(dy + 1) * s * c]
            view = rows.reshape(nr, ww // s, s * c) if ww % s == 0 else None
            if view is not None and np.shares_memory(view, dst):   # a view, never a copy to write into
                write_planes(view, p[:, :nr, :ww // s])
                continue
            for dx in range(min(s, ww)):
                cols = rows[:, dx::s]
                write_planes(cols, p[dx * c:(dx + 1) * c, :nr, :cols.shape[1]])
        return
    if _cv2_planes(dst.dtype, planes.dtype, c) and dst.strides[1:] == (c * dst.itemsize, dst.itemsize):
        import cv2

        r = cv2.merge([planes[k] for k in range(c)], dst=dst)
        if r is dst or np.shares_memory(r, dst):   # written in place (OpenCV reallocates otherwise)
            return
        dst[...] = r
        return
    for k in range(c):
        dst[..., k] = planes[k]


#: an operator run per tile: ``fn(window (C + extra, h, w), rows (h,), cols
#: (w,)) -> (C_out, h, w)``; ``rows``/``cols`` are the frame indices the
#: window was read from, so position-dependent inputs can be built per tile.
#: The window is a buffer reused between tiles (channels ``C:`` left for
#: ``fn`` to fill): ``fn`` must not keep it.
TileFn = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def run_tiled(fn: TileFn, image: np.ndarray, *, tile: int, margin: int, multiple: int = 1,
              out_channels: int | None = None, extra_channels: int = 0, dtype=np.float32,
              packing: int = 1, progress: bool | None = False, desc: str = "tiles",
              border: int | None = None, workers: int = 1) -> np.ndarray:
    """Apply a local operator to ``image`` tile by tile (crop-centre stitching).

    Parameters
    ----------
    fn : TileFn
        The operator on one window; must return an array of the window's
        spatial shape.
    image : (H, W, C) ndarray
        Input; read, never copied whole.
    tile, margin, multiple : int
        See :func:`split_axis`; ``tile ≤ 0`` runs the whole frame at once.
    border : int, optional
        Reflected context beyond the frame's edges (:func:`split_axis`;
        default ``margin``).
    out_channels : int, optional
        Channels of the output (default: ``C``).
    extra_channels : int
        Channels added to the window after the image's, for ``fn`` to fill
        (e.g. field position), so the window can go to a model as it is.
    dtype : numpy dtype
        Of the window buffer.
    packing : int
        ``s > 1``: ``fn`` takes the window packed ``s × s`` to depth and
        returns its output packed the same way (:func:`read_window`,
        :func:`write_planes`); ``multiple`` must be a multiple of ``s``.
    progress : bool or None
        tqdm bar on stderr; ``None`` shows one when stderr is a terminal and
        there are at least 4 tiles.
    workers : int
        Tiles in flight at once, each on its own thread with its own window
        buffer (``fn`` must then be thread-safe; it is called with disjoint
        windows and the cores it returns are disjoint, so the result does
        not depend on ``workers``). For an operator that releases the GIL
        (onnxruntime, OpenCV, most of numpy) on one thread each: two tiles
        side by side on two cores outrun one tile on two threads, whose
        many short parallel sections wait on each other.

    Returns
    -------
    (H, W, out_channels) float32 ndarray, allocated once; the extra memory
    beyond it is ``workers`` windows and the operator's own.
    """
    if image.ndim != 3:
        raise ValueError(f"image must be (H, W, C), got shape {image.shape}")
    h, w, c = image.shape
    s = int(packing)
    if s < 1 or multiple % s:
        raise ValueError(f"packing {packing} must be ≥ 1 and divide multiple {multiple}")
    tiles = plan_tiles((h, w), tile, margin, multiple, border)
    out = np.empty((h, w, c if out_channels is None else out_channels), np.float32)
    if progress is None:
        progress = len(tiles) >= 4 and sys.stderr.isatty()
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(tiles), unit="tile", desc=desc, file=sys.stderr)
    # one buffer per worker for every window shape (up to 9: edge windows are shorter when
    # border < margin): a prefix of it reshaped is contiguous, as a model's input must be
    depth = c * s * s + extra_channels
    size = depth * max((t.window_shape[0] // s) * (t.window_shape[1] // s) for t in tiles)
    workers = max(1, min(int(workers), len(tiles)))
    free = [np.zeros(size, dtype) for _ in range(workers)]

    def one(t: Tile) -> None:
        # list.pop/append are atomic: each thread holds its own buffer until its tile is
        # stitched (the operator's output may be a view of it)
        flat = free.pop()
        try:
            rows, cols = window_indices(t, (h, w))
            shape = (rows.size // s, cols.size // s)
            buf = flat[:depth * shape[0] * shape[1]].reshape(depth, *shape)
            y = fn(read_window(image, rows, cols, buf, s), rows, cols)
            want = (out.shape[2] * s * s, *shape)
            if y.shape != want:
                raise ValueError(f"tile operator returned shape {y.shape} for a window "
                                 f"{(c * s * s + extra_channels, *shape)}; expected {want}")
            ci, cj = t.rows.core_in_window, t.cols.core_in_window
            dst = out[t.rows.core_start:t.rows.core_stop, t.cols.core_start:t.cols.core_stop]
            # cores start on the packing grid (margins are multiples of `multiple`)
            write_planes(dst, y[:, ci.start // s:-(-ci.stop // s), cj.start // s:-(-cj.stop // s)], s)
        finally:
            free.append(flat)
        if bar is not None:
            bar.update()

    try:
        if workers == 1:
            for t in tiles:
                one(t)
        else:
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(workers) as pool:
                for f in [pool.submit(one, t) for t in tiles]:
                    f.result()
    finally:
        if bar is not None:
            bar.close()
    return out

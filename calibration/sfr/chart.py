"""Slanted-edge charts: find the edges, measure each, map SFR over the field.

Detection (:func:`find_edges`): straight edge segments found by the LSD
line-segment detector (OpenCV's) on the chart reduced to 2,048 px,
collinear pieces joined, and every piece slanted 1–44° from the nearest
axis and long enough given the largest axis-aligned ROI that holds it alone
(the whole piece but its ends, where a square's neighbouring sides blur in).
A curved (distorted) edge comes out as its straight pieces. Pieces found but
not used are listed with the reason. The chart's layout is recognised too
(:mod:`calibration.sfr.layout`: the ISO 12233:2023 e-SFR chart, the
ISO 12233:2000 resolution chart, a slanted-square grid or a single slanted
square) and reported with the results.

Field position of an ROI: its centre relative to the optical centre (the
image centre unless given), as a normalised radius (1 at the image corner)
and an angle (degrees, counter-clockwise from +x, y up).

Orientation, after the usual lens-testing convention (ISO 12233 does not
name it): an edge whose normal points along the radius measures detail that
varies radially, the *tangential* (meridional) SFR; an edge lying along the
radius measures the *sagittal* SFR. Edges within 45° of either are assigned
to the nearer one; at the centre (radius < 0.05) there is no distinction
("axial").

Field maps: the image is divided into the paper's 15 × 20 regions; each
region holds the mean SFRA (and MTF50) of the edges whose ROI centre falls in
it, for all edges and per orientation (NaN where there is none).
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from calibration.sfr.esfr import DEFAULT_METHOD, SfrError, measure_sfr
from calibration.sfr.layout import ChartLayout, detection_image, recognise_chart

if TYPE_CHECKING:   # the executor (and its multiprocessing) loads only where a chart is measured
    from isp.runtime.executor import Executor

GRID = (15, 20)
#: what each end of a side loses to its corner, as a fraction of the side and in pixels
CORNER_MARGIN = 0.03
CORNER_MARGIN_PX = 4.0


@dataclass(frozen=True)
class EdgeROI:
    """One slanted edge found on a chart.

    Attributes
    ----------
    x, y, w, h : int
        The ROI rectangle in image pixels (x right, y down).
    angle_deg : float
        Slant of the edge from the nearest image axis, degrees (from the
        polygon; the SFR measurement refines it).
    direction : {"vertical", "horizontal"}
        Which axis the edge is near.
    radius : float
        Normalised field radius of the ROI centre (0 centre, 1 corner).
    field_angle_deg : float
        Direction of the ROI centre from the optical centre, degrees, CCW
        from +x with y up.
    orientation : {"sagittal", "tangential", "axial"}
    shape : int
        Index of the dark shape the edge belongs to.
    """

    x: int
    y: int
    w: int
    h: int
    angle_deg: float
    direction: str
    radius: float
    field_angle_deg: float
    orientation: str
    shape: int

    @property
    def centre(self) -> tuple[float, float]:
        return (self.x + self.w / 2.0, self.y + self.h / 2.0)

    def as_dict(self) -> dict:
        return {"roi": [self.x, self.y, self.w, self.h], "angle_deg_detected": round(self.angle_deg, 3),
                "direction": self.direction,
                "field": {"radius": round(self.radius, 5), "angle_deg": round(self.field_angle_deg, 3)},
                "orientation": self.orientation, "shape": self.shape}


def _gray(image, channel=None, encoding: str = "linear") -> np.ndarray:
    """The (H, W) plane detection and measurement work on: a single plane of
    uint8/uint16 codes with linear encoding stays as it is (the codes, as
    :func:`calibration.sfr.esfr.measure_sfr` measures a single ROI, with no
    full-frame float copy); luminance and sRGB codes become float64 linear
    units; float input is kept float64 (no copy where it is float64 already)."""
    from calibration.sfr.esfr import LUMINANCE_WEIGHTS

    a = np.asarray(image)
    if a.ndim == 3:
        if channel is None:
            channel = "luminance"
        if channel == "luminance":
            lin = _linear(a[..., :3], encoding)
            return np.tensordot(lin, np.asarray(LUMINANCE_WEIGHTS), axes=([-1], [0]))
        a = a[..., int(channel)]
    if a.ndim != 2:
        raise SfrError(f"chart image must be (H, W) or (H, W, 3), got shape {a.shape}")
    if encoding != "srgb" and a.dtype in (np.uint8, np.uint16):
        return a
    return _linear(a, encoding)


def _linear(a: np.ndarray, encoding: str) -> np.ndarray:
    """Codes to linear float64; integer sRGB codes through a table (the
    per-pixel power costs a second per 12 MP)."""
    from calibration.sfr.esfr import srgb_to_linear

    if encoding != "srgb":
        return _to_float(a)
    if a.dtype in (np.uint8, np.uint16):
        n = 256 if a.dtype == np.uint8 else 65536
        table = srgb_to_linear(np.arange(n, dtype=np.float64) / (n - 1))
        return table[a]
    return srgb_to_linear(_to_float(a))


def _to_float(a: np.ndarray) -> np.ndarray:
    if a.dtype == np.uint8:
        return a.astype(np.float64) / 255.0
    if a.dtype == np.uint16:
        return a.astype(np.float64) / 65535.0
    return np.asarray(a, dtype=np.float64)


def field_position(cx: float, cy: float, centre: tuple[float, float], half_diagonal: float) -> tuple[float, float]:
    """(normalised radius, angle in degrees CCW from +x, y up) of a point."""
    dx, dy = cx - centre[0], centre[1] - cy
    return math.hypot(dx, dy) / half_diagonal, math.degrees(math.atan2(dy, dx))


def classify_orientation(edge_dx: float, edge_dy: float, radius: float, field_angle_deg: float) -> str:
    """"tangential" if the edge's normal is within 45° of the radial
    direction, "sagittal" otherwise, "axial" near the centre (module notes).

    >>> classify_orientation(0.0, 1.0, 0.8, 0.0)   # vertical edge right of centre
    'tangential'
    >>> classify_orientation(1.0, 0.0, 0.8, 0.0)   # horizontal edge right of centre
    'sagittal'
    """
    if radius < 0.05:
        return "axial"
    t = math.radians(field_angle_deg)
    radial = (math.cos(t), -math.sin(t))       # in image coordinates (y down)
    norm = math.hypot(edge_dx, edge_dy)
    normal = (-edge_dy / norm, edge_dx / norm)
    c = abs(normal[0] * radial[0] + normal[1] * radial[1])
    return "tangential" if c >= math.sqrt(0.5) else "sagittal"


def find_edges(image, *, channel=None, encoding: str = "linear", min_length: float = 40.0,
               centre: tuple[float, float] | None = None, max_slant_deg: float = 44.0,
               min_slant_deg: float = 1.0, rejected: list | None = None) -> list[EdgeROI]:
    """Find the slanted edges of a chart image, whatever the shapes: the
    sides of squares and bars, the straight pieces of curved (distorted)
    edges.

    Straight edge segments are found by the LSD line-segment detector
    (Grompone von Gioi et al., *LSD: a Line Segment Detector*, IPOL 2012;
    OpenCV's), on the image reduced to
    :data:`calibration.sfr.layout.DETECT_MAX_SIDE` px at most;
    collinear pieces of one edge are joined (:func:`_join_collinear`). A
    curved edge comes out as the straight pieces LSD finds along it, each
    measured on its own, as ISO 12233 allows for a curved edge. Each piece
    slanted ``min_slant_deg``–``max_slant_deg`` from an axis and at least
    ``min_length`` long gets the largest axis-aligned ROI that holds it
    alone (:func:`_edge_roi`): the whole piece but its ends, ±40 px across,
    narrower (to ±14 px) and then shorter where other edges crowd; a piece
    no ROI isolates is left out.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array_like
    channel, encoding
        As :func:`calibration.sfr.esfr.measure_sfr` (detection only needs the
        luminance; the default for colour input).
    min_length : float
        Shortest edge piece used, pixels.
    centre : (x, y), optional
        Optical centre in pixels (default: the image centre).
    min_slant_deg, max_slant_deg : float
        Accepted slant from the nearest axis: up to 44° (as MTF Mapper), so
        that a 40° edge read a little high is kept; the measurement warns
        below 2° and above 40°, and refuses an edge whose angle samples too
        few phases (near 45°).
    rejected : list, optional
        Receives ``(EdgeROI, reason)`` for every piece at least
        ``min_length`` long that is not used: slanted outside the range,
        too faint, or with no ROI that holds it alone (the box is then the
        piece's middle).

    Returns
    -------
    list of EdgeROI, sorted top-to-bottom, left-to-right; ``shape`` is the
    index of the edge piece.
    """
    g = _gray(image, channel, encoding)
    pieces, spec = _edge_pieces(g, centre=centre, min_length=min_length, min_slant_deg=min_slant_deg,
                                max_slant_deg=max_slant_deg)
    return _select_rois([_piece_roi(g, k, p, q, spec) for k, (p, q) in enumerate(pieces)], rejected)


@dataclass(frozen=True)
class _PieceSpec:
    """What :func:`_piece_roi` needs beside the image and the piece: the
    search's settings and the chart's levels and geometry."""

    min_length: float
    min_slant_deg: float
    max_slant_deg: float
    contrast: float
    centre: tuple[float, float]
    half_diagonal: float


def _edge_pieces(g: np.ndarray, *, centre=None, min_length: float = 40.0, min_slant_deg: float = 1.0,
                 max_slant_deg: float = 44.0) -> tuple[list, _PieceSpec]:
    """The straight edge pieces of a grey chart (:func:`_line_segments`,
    joined by :func:`_join_collinear`), longest first, and the settings
    :func:`_piece_roi` judges each with."""
    if g.dtype.kind == "f" and not np.all(np.isfinite(g)):
        raise SfrError("chart image has NaN or inf pixels")
    h, w = g.shape
    lo, hi = _percentiles(g[::4, ::4], (1, 99))
    if hi - lo <= 1e-9:
        raise SfrError("chart image is uniform: no edges to find")
    spec = _PieceSpec(float(min_length), float(min_slant_deg), float(max_slant_deg), 0.1 * float(hi - lo),
                      centre if centre is not None else (w / 2.0, h / 2.0), 0.5 * math.hypot(w, h))
    return _join_collinear(_line_segments(g, lo, hi)), spec


def _piece_roi(g: np.ndarray, k: int, p, q, spec: _PieceSpec) -> tuple[EdgeROI | None, str]:
    """Piece ``k`` (p→q) as an EdgeROI: ``(roi, "")`` where an ROI holds it
    alone, ``(roi of its middle, reason)`` where it is long enough but
    unusable, ``(None, "")`` where it is too short or leaves the image
    (:func:`_edge_roi`)."""
    roi, why = _edge_roi(p, q, g, spec.min_length, spec.min_slant_deg, spec.max_slant_deg, spec.contrast)
    if roi is None:
        return None, ""
    x, y, rw, rh, slant, direction = roi
    radius, fang = field_position(x + rw / 2, y + rh / 2, spec.centre, spec.half_diagonal)
    orient = classify_orientation(q[0] - p[0], q[1] - p[1], radius, fang)
    return EdgeROI(x, y, rw, rh, slant, direction, radius, fang, orient, k), why


def _select_rois(candidates, rejected: list | None = None) -> list[EdgeROI]:
    """The usable ROIs of :func:`_piece_roi`'s ``(roi, why)`` per piece
    (longest piece first), an edge found twice kept once
    (:func:`_deduplicate`), sorted top-to-bottom, left-to-right;
    ``rejected`` receives the unusable pieces no kept ROI already covers."""
    found = _deduplicate([roi for roi, why in candidates if roi is not None and not why])
    if rejected is not None:
        placed = _Centres(found)
        rejected += [(roi, why) for roi, why in candidates if roi is not None and why and not placed.near(roi)]
    return sorted(found, key=lambda e: (round(e.centre[1] / 8), e.centre[0]))


def _line_segments(g: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(N, 2, 2) straight edge segments ``[[x0, y0], [x1, y1]]`` in the
    image's pixels (centres at integers), found by OpenCV's LSD on the
    image reduced and stretched to 8 bits between ``lo`` and ``hi``
    (:func:`calibration.sfr.layout.detection_image`)."""
    import cv2

    h, w = g.shape
    u8, _ = detection_image(g, lo, hi)
    lines = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD).detect(u8)[0]
    if lines is None:
        return np.zeros((0, 2, 2))
    seg = lines.reshape(-1, 2, 2).astype(np.float64)
    sx, sy = u8.shape[1] / w, u8.shape[0] / h
    seg[..., 0] = (seg[..., 0] + 0.5) / sx - 0.5
    seg[..., 1] = (seg[..., 1] + 0.5) / sy - 0.5
    return seg


def _join_collinear(seg: np.ndarray, angle_tol_deg: float = 1.5, offset_px: float = 1.5,
                    gap_px: float = 6.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Join pieces of one straight edge: segments within ``angle_tol_deg``
    of each other, each end within ``offset_px`` of the other's line, and
    at most ``gap_px`` apart along it (LSD breaks an edge where noise or a
    mark interrupts it). Returns ``(p, q)`` end points, longest first."""
    n = len(seg)
    if n == 0:
        return []
    d = seg[:, 1] - seg[:, 0]
    length = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(length, 1e-9)[:, None]
    parent = list(range(n))

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    cos_tol = math.cos(math.radians(angle_tol_deg))
    for i in _join_candidates(seg, u, length, cos_tol, offset_px, gap_px):
        rest = slice(i + 1, n)
        # j's ends off i's line, and the gap between the two along it
        rel = seg[rest] - seg[i, 0]                                  # (m, 2 ends, xy)
        off = np.abs(rel[..., 0] * u[i, 1] - rel[..., 1] * u[i, 0]).max(axis=1)
        t = rel @ u[i]
        ok = ((np.abs(u[rest] @ u[i]) >= cos_tol) & (off <= offset_px)
              & (t.min(axis=1) <= length[i] + gap_px) & (t.max(axis=1) >= -gap_px))
        for j in np.flatnonzero(ok) + i + 1:
            parent[root(int(j))] = root(i)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(i)
    out = []
    for members in groups.values():
        pts = seg[members].reshape(-1, 2)
        k = members[int(np.argmax(length[members]))]
        t = (pts - seg[k, 0]) @ u[k]
        out.append((seg[k, 0] + t.min() * u[k], seg[k, 0] + t.max() * u[k]))
    out.sort(key=lambda pq: -float(np.hypot(*(pq[1] - pq[0]))))
    return out


def _join_candidates(seg, u, length, cos_tol, offset_px, gap_px) -> list[int]:
    """The segments ``i`` that :func:`_join_collinear`'s test may join to a
    later one: the same test on all pairs at once (in blocks of about a
    million), with a margin of 1e-6 for the rounding of this other order of
    operations, so that the exact test need only run on these."""
    n = len(seg)
    slack = 1e-6
    normal = np.stack([u[:, 1], -u[:, 0]], axis=1)
    level = np.sum(normal * seg[:, 0], axis=1)         # the line of i: normal_i · p = level_i
    rows = max(1, 2**20 // n)
    out = []
    for start in range(0, n, rows):
        i = np.arange(start, min(start + rows, n))
        near = (np.abs(u[i] @ u.T) >= cos_tol - slack) & (np.arange(n) > i[:, None])
        for end in (0, 1):
            near &= np.abs(normal[i] @ seg[:, end].T - level[i, None]) <= offset_px + slack
        pair, j = np.nonzero(near)
        i = i[pair]
        t = np.sum((seg[j] - seg[i, None, 0]) * u[i, None, :], axis=2)    # along i's line, (pairs, 2 ends)
        ok = (t.min(axis=1) <= length[i] + gap_px + slack) & (t.max(axis=1) >= -gap_px - slack)
        out += np.unique(i[ok]).tolist()
    return out


def _edge_roi(p, q, g, min_length, min_slant, max_slant, contrast):
    """Axis-aligned ROI around the middle of the edge piece p→q that holds
    it alone: ``((x, y, w, h, slant, direction), "")``; for a piece long
    enough but unusable, its middle's box and the reason; ``(None, "")``
    for one shorter than ``min_length`` or reaching out of the image."""
    h, w = g.shape
    d = q - p
    length = float(np.hypot(*d))
    if length < min_length:
        return None, ""
    ang = math.degrees(math.atan2(abs(d[1]), abs(d[0])))   # 0 horizontal, 90 vertical
    vertical = ang > 45.0
    slant = 90.0 - ang if vertical else ang
    direction = "vertical" if vertical else "horizontal"
    mid = (p + q) / 2.0
    t = math.tan(math.radians(slant))
    cos = math.cos(math.radians(slant))

    def box(along, across):
        if vertical:
            rh = int(round(along * cos))
            rw = int(round(2 * across + rh * t))
        else:
            rw = int(round(along * cos))
            rh = int(round(2 * across + rw * t))
        return int(round(mid[0] - rw / 2)), int(round(mid[1] - rh / 2)), rw, rh

    def middle():
        x, y, rw, rh = box(0.5 * length, 10.0)
        x, y = max(x, 0), max(y, 0)
        rw, rh = min(rw, w - x), min(rh, h - y)
        return (x, y, rw, rh, slant, direction) if rw > 0 and rh > 0 else None

    if not (min_slant <= slant <= max_slant):
        return middle(), (f"edge slanted {slant:.1f}° from the {'vertical' if vertical else 'horizontal'} axis, "
                          f"outside {min_slant:g}–{max_slant:g}° (too few phases near 0° and 45°)")
    # the largest ROI that holds this edge alone: the whole piece but its
    # ends (CORNER_MARGIN of it and CORNER_MARGIN_PX at each end, where a
    # square's neighbouring sides' blur reaches), ±40 px across; narrower
    # and shorter ones where edges crowd. The SFR's noise falls as the
    # square root of the rows measured (benchmarks/sfr_chart.py: the middle
    # 60 % of each side gave a median |ΔMTF50| of 0.13 %, the whole side
    # 0.10 %, on the same chart). So the box narrows (±20 px; then 0.8 of the side, or ±14 px)
    # before it falls to half the side: slanted 19–40°, a whole side's ±28 px box reaches the
    # square's neighbouring sides, and a
    # box of half the side (53–64 of 137 rows) scatters the per-edge MTF50 of the sweep's
    # σ 0.6–2 px charts up to 1.4× more (benchmarks/sfr_chart.py --sweep).
    whole = max(length - 2.0 * (CORNER_MARGIN * length + CORNER_MARGIN_PX), 0.4 * length)
    inside = False
    for along, across in ((whole, 40.0), (whole, 28.0), (whole, 20.0), (0.8 * whole, 20.0), (whole, 14.0),
                          (0.5 * length, 20.0), (0.4 * length, 14.0), (0.4 * length, 10.0)):
        across = min(across, max(10.0, 0.22 * length))
        x, y, rw, rh = box(along, across)
        if x < 0 or y < 0 or x + rw > w or y + rh > h or min(rw, rh) < 8:
            continue
        inside = True
        patch = g[y:y + rh, x:x + rw]
        lo, hi = _percentiles(patch, (5, 95))
        if hi - lo < contrast:
            return middle(), f"faint edge: step {hi - lo:.3g} below {contrast:.3g}, a tenth of the chart's range"
        if _one_edge(patch < 0.5 * (lo + hi)):
            return (x, y, rw, rh, slant, direction), ""
    if not inside:
        return None, ""
    return middle(), "no ROI holds this edge alone: another edge within 10 px across it"


def _one_edge(patch: np.ndarray) -> bool:
    """True if the binary patch splits into one dark and one light region."""
    import cv2

    if not 0.2 < np.count_nonzero(patch) / patch.size < 0.8:
        return False
    dark = np.ascontiguousarray(patch, dtype=bool)
    n_dark, _ = cv2.connectedComponents(dark.view(np.uint8))
    n_light, _ = cv2.connectedComponents((~dark).view(np.uint8))
    return n_dark == 2 and n_light == 2


def _percentiles(a: np.ndarray, q) -> np.ndarray:
    """``np.percentile(a, q)`` of a finite array (linear interpolation, the
    same order statistics and arithmetic), from one partial sort on just the
    order statistics it reads."""
    x = np.ravel(a)
    n = x.size
    pos = (n - 1) * (np.asarray(q, dtype=np.float64) / 100)
    below = np.floor(pos)
    gamma = pos - below
    i = below.astype(np.intp)
    j = np.minimum(i + 1, n - 1)
    part = np.partition(x, np.union1d(i, j))
    lo, hi = part[i], part[j]
    step = hi - lo
    # numpy's lerp: from the nearer end
    return np.where(gamma >= 0.5, hi - step * (1 - gamma), lo + step * gamma)


class _Centres:
    """ROI centres filed in 4 px cells: whether a point lies within 4 px
    (each way) of one of them, in constant time."""

    def __init__(self, edges=()):
        self.cells: dict[tuple[int, int], list[tuple[float, float]]] = {}
        for e in edges:
            self.add(e)

    def add(self, e: EdgeROI) -> None:
        cx, cy = e.centre
        self.cells.setdefault((int(cx // 4), int(cy // 4)), []).append((cx, cy))

    def near(self, e: EdgeROI) -> bool:
        cx, cy = e.centre
        i, j = int(cx // 4), int(cy // 4)
        return any(abs(cx - ox) < 4 and abs(cy - oy) < 4
                   for di in (-1, 0, 1) for dj in (-1, 0, 1) for ox, oy in self.cells.get((i + di, j + dj), ()))


def _deduplicate(edges: list[EdgeROI]) -> list[EdgeROI]:
    """Drop ROIs whose centres nearly coincide (an edge found twice): the
    first of each cluster of centres within 4 px (each way) of a kept one."""
    out: list[EdgeROI] = []
    kept = _Centres()
    for e in edges:
        if not kept.near(e):
            kept.add(e)
            out.append(e)
    return out


@dataclass
class ChartResult:
    """Every edge found on a chart with its SFR, and the field maps."""

    width: int
    height: int
    centre: tuple[float, float]
    edges: list = field(default_factory=list)      # (EdgeROI, SfrResult)
    skipped: list = field(default_factory=list)    # (EdgeROI, reason)
    grid: tuple[int, int] = GRID
    method: str = DEFAULT_METHOD   # the SFR method every edge was measured with
    layout: ChartLayout | None = None   # the recognised chart (calibration.sfr.layout)

    def field_map(self, value: str = "sfra", orientation: str | None = None) -> np.ndarray:
        """(rows, cols) mean ``value`` ("sfra" or "mtf50") per region; NaN
        where the region has no (matching) edge."""
        rows, cols = self.grid
        total = np.zeros((rows, cols))
        count = np.zeros((rows, cols))
        for roi, res in self.edges:
            if orientation is not None and roi.orientation != orientation:
                continue
            v = getattr(res, value)
            if not np.isfinite(v):
                continue
            cx, cy = roi.centre
            r = min(int(cy / self.height * rows), rows - 1)
            c = min(int(cx / self.width * cols), cols - 1)
            total[r, c] += v
            count[r, c] += 1
        with np.errstate(invalid="ignore"):
            return np.where(count > 0, total / np.maximum(count, 1), np.nan)

    def to_dict(self) -> dict:
        """JSON-ready: ``edges`` (each with freq, sfr, mtf50, sfra, angle_deg,
        roi, field, orientation, warnings), ``skipped`` and ``maps``."""
        def grid_list(a):
            return [[None if not np.isfinite(v) else round(float(v), 6) for v in row] for row in a]

        edges = []
        for roi, res in self.edges:
            d = roi.as_dict()
            r = res.to_dict()
            d.update({"freq": r["freq_cy_per_px"], "sfr": r["sfr"], "mtf50": r["mtf50_cy_per_px"],
                      "sfra": r["sfra_to_nyquist"], "angle_deg": r["angle_deg"],
                      "mtf_nyquist_half": r["mtf_nyquist_half"], "mtf_nyquist": r["mtf_nyquist"],
                      "contrast": r["contrast"], "noise": r["noise"], "step": esf_step(res),
                      "edge_fit_linear": r["edge_fit_linear"], "warnings": r["warnings"]})
            edges.append(d)
        maps = {v: {o or "all": grid_list(self.field_map(v, o)) for o in (None, "sagittal", "tangential")}
                for v in ("sfra", "mtf50")}
        return {"size": [self.width, self.height], "centre": list(self.centre), "grid": list(self.grid),
                "method": self.method,
                "layout": self.layout.as_dict() if self.layout is not None else None,
                "edges": edges,
                "skipped": [{**roi.as_dict(), "reason": reason} for roi, reason in self.skipped],
                "maps": maps}


def esf_step(r) -> float:
    """Bright − dark of an SfrResult's ESF plateaus (its outer tenths), in
    the input's units: with ``noise``, the edge's signal-to-noise ratio."""
    esf = np.asarray(r.esf, dtype=np.float64)
    m = max(4, esf.size // 10)
    return float(abs(esf[-m:].mean() - esf[:m].mean()))


def measure_chart(image, *, channel=None, encoding: str = "linear", centre=None, min_length: float = 40.0,
                  edge_fit_order: int = 1, pixel_pitch_um: float | None = None, method: str = DEFAULT_METHOD,
                  grid: tuple[int, int] = GRID, executor: Executor | None = None) -> ChartResult:
    """Find every slanted edge of a chart and measure its SFR.

    Parameters are those of :func:`find_edges` and
    :func:`calibration.sfr.esfr.measure_sfr`; ``executor`` measures the edges
    (:func:`measure_rois`). Edges the measurement refuses, and the edge pieces the search found
    but could not use (:func:`find_edges`, ``rejected``), are listed in
    ``skipped`` with the reason, not dropped.
    """
    from concurrent.futures import ThreadPoolExecutor

    from isp.runtime.executor import create_executor

    g = _gray(np.asarray(image), channel, encoding)
    h, w = g.shape
    settings = dict(edge_fit_order=edge_fit_order, pixel_pitch_um=pixel_pitch_um, method=method)
    ex = create_executor("serial") if executor is None else executor
    # the workers start while the edges are found here; each piece's ROI is then chosen and
    # measured in one task, on the workers, while the layout is recognised here
    with ex.bind((g, settings)).start() as bound, ThreadPoolExecutor(1) as side:
        pieces, spec = _edge_pieces(g, centre=centre, min_length=min_length)
        layout = side.submit(recognise_chart, g)
        done = bound.map(_measure_piece, [(spec, k, p, q) for k, (p, q) in enumerate(pieces)], desc="SFR",
                         unit="piece")
        layout = layout.result()
    rejected: list = []
    rois = _select_rois([(roi, why) for roi, why, _ in done], rejected)
    res = ChartResult(w, h, spec.centre, grid=grid, method=method, layout=layout)
    res.edges, res.skipped = _sort_measured(rois, [done[roi.shape][2] for roi in rois])
    res.skipped += rejected
    return res


def _measure_piece(task):
    """A worker's task of :func:`measure_chart`: ``(spec, k, p, q)``, piece
    ``k``'s ROI and why it is unusable (:func:`_piece_roi`), and for a
    usable one its measurement as ``(result, None)`` or ``(None, reason)``;
    the worker's payload is ``(image, settings)``."""
    from isp.runtime.executor import worker_payload

    g, settings = worker_payload()
    spec, *piece = task
    roi, why = _piece_roi(g, *piece, spec)
    if roi is None or why:
        return roi, why, None
    try:
        return roi, why, (measure_sfr(g, box=(roi.x, roi.y, roi.w, roi.h), **settings), None)
    except SfrError as e:
        return roi, why, (None, str(e))


def measure_rois(rois, measure, *, executor: Executor | None = None, payload=None) -> tuple[list, list]:
    """``measure(box)`` (an SfrResult for ``box = (x, y, w, h)``) on every
    ROI: ``(edges, skipped)``, edges as (roi, result) and skipped as (roi,
    reason) — refused measurements and results that are not a clean edge
    are listed with the reason, never dropped. ``executor`` runs the
    measurements (default "serial"); its progress bar counts edges.

    Without ``payload``, ``measure`` may be a closure ("serial" or
    "threads" executors). With one, ``measure(payload, box)`` is called
    instead: a module-level function, and the payload (the image and the
    settings) goes to each worker once, so a "processes" executor can
    measure a chart's edges on every core."""
    rois = list(rois)
    from isp.runtime.executor import create_executor

    ex = create_executor("serial") if executor is None else executor
    boxes = [(roi.x, roi.y, roi.w, roi.h) for roi in rois]
    if payload is None:
        def one(box):
            try:
                return measure(box), None
            except SfrError as e:
                return None, str(e)

        results = ex.map(one, boxes, desc="SFR", unit="edge")
    else:
        with ex.bind(payload) as bound:
            results = bound.map(_measure_with_payload, [(measure, b) for b in boxes], desc="SFR", unit="edge")

    return _sort_measured(rois, results)


def _sort_measured(rois, results) -> tuple[list, list]:
    """``(edges, skipped)`` of the ROIs' ``(result, error)``: edges as (roi,
    result); refused measurements and results that are not a clean edge
    (:func:`_not_a_clean_edge`) as (roi, reason)."""
    edges, skipped = [], []
    for roi, (r, err) in zip(rois, results):
        if err is not None:
            skipped.append((roi, err))
            continue
        why = _not_a_clean_edge(r)
        if why:
            skipped.append((roi, why))
            continue
        edges.append((roi, r))
    return edges, skipped


def _measure_with_payload(task):
    """A worker's task of :func:`measure_rois`: ``(result, None)`` or
    ``(None, reason)``."""
    from isp.runtime.executor import worker_payload

    measure, box = task
    try:
        return measure(worker_payload(), box), None
    except SfrError as e:
        return None, str(e)


_RESIDUAL = re.compile(r"edge-fit residual ([0-9.]+) px")


def _not_a_clean_edge(r) -> str:
    """A reason to leave a detected ROI out of a chart's maps: what the
    detector took for a straight edge is not one (a curved or broken
    outline: large edge-fit residual), or the edge sits at the ROI's border.
    A user's own ROI keeps these as warnings instead."""
    for w in r.warnings:
        m = _RESIDUAL.search(w)
        if m and float(m.group(1)) > 1.0:
            return f"not a straight edge ({w})"
        if "plateau too narrow" in w:
            return w
    return ""


def measure_chart_bayer(mosaic, cfa, *, channel: str = "G", mode: str = "plane", centre=None,
                        min_length: float = 40.0, edge_fit_order: int = 1, pixel_pitch_um: float | None = None,
                        method: str = DEFAULT_METHOD, grid: tuple[int, int] = GRID,
                        executor: Executor | None = None) -> ChartResult:
    """:func:`measure_chart` on a raw Bayer mosaic (linear, black removed):
    edges are found on the 2×2-block average (half resolution, all colours)
    and measured on the mosaic itself per colour with
    :func:`calibration.sfr.esfr.measure_sfr_bayer` (``channel`` one of R, G, B,
    Gr, Gb; frequencies per sensor pixel)."""

    m = np.asarray(mosaic, dtype=np.float64)
    if m.ndim != 2:
        raise SfrError(f"mosaic must be (H, W), got shape {m.shape}")
    h, w = m.shape
    half = m[: h // 2 * 2, : w // 2 * 2].reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3))
    c = None if centre is None else (centre[0] / 2.0, centre[1] / 2.0)
    rois = find_edges(half, centre=c, min_length=min_length / 2.0)
    layout = recognise_chart(half)
    layout = dataclasses.replace(layout, centres=[(2 * x + 0.5, 2 * y + 0.5) for x, y in layout.centres])
    res = ChartResult(w, h, centre if centre is not None else (w / 2.0, h / 2.0), grid=grid, method=method,
                      layout=layout)
    full = [EdgeROI(2 * r.x, 2 * r.y, 2 * r.w, 2 * r.h, r.angle_deg, r.direction, r.radius, r.field_angle_deg,
                    r.orientation, r.shape) for r in rois]
    settings = dict(channel=channel, mode=mode, edge_fit_order=edge_fit_order, pixel_pitch_um=pixel_pitch_um,
                    method=method)
    res.edges, res.skipped = measure_rois(full, _measure_mosaic_box, executor=executor, payload=(m, cfa, settings))
    return res


def _measure_mosaic_box(payload, box):
    """:func:`calibration.sfr.esfr.measure_sfr_bayer` of one ROI of a mosaic
    (``payload = (mosaic, cfa, settings)``)."""
    from calibration.sfr.esfr import measure_sfr_bayer

    mosaic, cfa, settings = payload
    return measure_sfr_bayer(mosaic, cfa, box=box, **settings)


#: skip reasons as chart labels: (pattern of the measurement's message, label)
_REASON_LABELS = (
    (r"less than one whole phase cycle|untilted", "edge untilted (under one phase cycle)"),
    (r"quarter-pixel bins filled", "angle samples too few phases"),
    (r"^uniform ROI", "uniform ROI"),
    (r"^no edge found", "no edge found"),
    (r"^not a straight edge", "not a straight edge"),
    (r"plateau too narrow|from the ROI border", "edge at the ROI border"),
    (r"^edge too short", "edge too short"),
    (r"^ROI too narrow", "ROI too narrow"),
    (r"^edge slanted", "slant out of range"),
    (r"^faint edge", "faint edge"),
    (r"^no ROI holds this edge alone", "another edge too close"),
)


def short_reason(reason: str) -> str:
    """A skip reason as a label for the annotated chart: its kind, without
    the numbers of the case (the JSON keeps the whole message).

    >>> short_reason("uniform ROI: every pixel is 0.2; no edge to measure")
    'uniform ROI'
    >>> short_reason("edge angle 0.36° gives less than one whole phase cycle over 51 rows (needs ≥ 3 rows)")
    'edge untilted (under one phase cycle)'
    """
    for pattern, label in _REASON_LABELS:
        if re.search(pattern, reason):
            return label
    first = re.split(r"[:;(]", reason, maxsplit=1)[0]
    return re.sub(r"\s+", " ", re.sub(r"[-+]?\d[\d.,]*\s*[°%]?", "", first)).strip()


def _edge_segment(roi: EdgeROI, res) -> tuple[np.ndarray, np.ndarray]:
    """The fitted edge across its ROI, in image pixels: (x, y) arrays."""
    q = np.asarray(res.edge_fit_linear, dtype=np.float64)
    if res.orientation == "vertical":          # col = q(row)
        rows = np.array([roi.y, roi.y + roi.h - 1], dtype=np.float64)
        return np.polynomial.polynomial.polyval(rows, q), rows
    cols = np.array([roi.x, roi.x + roi.w - 1], dtype=np.float64)
    return cols, np.polynomial.polynomial.polyval(cols, q)


def annotate_chart(result: ChartResult, image, *, value: str = "mtf50", ax=None, labels: bool = True):
    """The chart with every measured edge drawn on it, coloured by its
    ``value`` ("mtf50" or "sfra", cycles/pixel) and labelled with it, and
    every skipped candidate boxed with its reason: what chart tools show.
    The colour scale ("turbo") spans the 2nd to 98th percentile of the
    values, so that one outlier does not flatten the rest.

    Skip reasons are numbered in a legend (the box carries the number), so
    that a crowded chart stays readable; each measured edge is the fitted
    line across its ROI.

    Parameters
    ----------
    result : ChartResult
    image : (H, W) or (H, W, 3) array_like
        The chart the result was measured on (drawn in grey, linear codes
        stretched between the 1st and 99th percentiles).
    value : {"mtf50", "sfra"}
    ax : matplotlib Axes, optional
        Where to draw (default: a new figure sized to the image).
    labels : bool
        Print each edge's value beside it.

    Returns
    -------
    matplotlib Figure
    """
    import matplotlib.pyplot as plt
    from matplotlib.colors import Normalize

    g = _gray(np.asarray(image), None, "linear")
    h, w = g.shape
    if ax is None:
        fig, ax = plt.subplots(figsize=(12.0, 12.0 * h / w + 0.8))
    else:
        fig = ax.figure
    lo, hi = np.percentile(g[::4, ::4], [1, 99])
    ax.imshow(g, cmap="gray", vmin=lo, vmax=hi if hi > lo else lo + 1)
    vals = np.array([getattr(res, value) for _, res in result.edges], dtype=np.float64)
    ok = np.isfinite(vals)
    vmin, vmax = (np.percentile(vals[ok], [2, 98]) if ok.any() else (0.0, 1.0))
    norm = Normalize(vmin, vmax if vmax > vmin else vmin + 1e-6)
    cmap = plt.get_cmap("turbo")
    font = float(np.clip(1100.0 / max(np.sqrt(max(len(result.edges), 1)) * 40.0, 1.0), 3.0, 8.0))
    for (roi, res), v in zip(result.edges, vals):
        colour = cmap(norm(v)) if np.isfinite(v) else (1.0, 0.0, 1.0, 1.0)
        x, y = _edge_segment(roi, res)
        ax.plot(x, y, color=colour, lw=2.0, solid_capstyle="butt")
        if labels:
            cx, cy = roi.centre
            ax.text(cx, cy, "–" if not np.isfinite(v) else f"{v:.3f}", fontsize=font, color="black",
                    ha="center", va="center",
                    bbox=dict(boxstyle="round,pad=0.15", fc=colour, ec="none", alpha=0.85))
    reasons: dict[str, int] = {}
    counts: dict[str, int] = {}
    for roi, why in result.skipped:
        key = short_reason(why)
        k = reasons.setdefault(key, len(reasons) + 1)
        counts[key] = counts.get(key, 0) + 1
        ax.add_patch(plt.Rectangle((roi.x, roi.y), roi.w, roi.h, fill=False, lw=0.9, ls="--", color="red"))
        ax.text(roi.x + roi.w / 2, roi.y + roi.h / 2, str(k), fontsize=font, color="white", ha="center",
                va="center", bbox=dict(boxstyle="circle,pad=0.15", fc="red", ec="none", alpha=0.85))
    sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
    fig.colorbar(sm, ax=ax, fraction=0.035, pad=0.01, label=f"{value} (cycles/pixel)")
    if reasons:
        ax.legend(handles=[plt.Line2D([], [], ls="none", marker="o", color="red", label=f"{k}: {key} ({counts[key]})")
                           for key, k in reasons.items()],
                  loc="upper left", fontsize=7, title="skipped", title_fontsize=7, framealpha=0.85)
    named = f"{result.layout.title}: " if result.layout is not None and result.layout.name != "unknown" else ""
    ax.set_title(f"{named}{len(result.edges)} edges measured ({result.method}), {len(result.skipped)} skipped; "
                 f"{value} from {vmin:.3f} to {vmax:.3f}")
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)
    ax.axis("off")
    return fig


def plot_chart(result: ChartResult, image=None, *, value: str = "mtf50"):
    """A figure: with the image, the annotated chart on top
    (:func:`annotate_chart`); below, the SFR curves coloured by field radius
    and the ``value`` map over the field grid."""
    import matplotlib.pyplot as plt

    if image is not None:
        h, w = np.asarray(image).shape[:2]
        top = 10.4 * h / w
        fig = plt.figure(figsize=(10.4, top + 4.2))
        grid = fig.add_gridspec(2, 2, height_ratios=[top, 4.2])
        annotate_chart(result, image, value=value, ax=fig.add_subplot(grid[0, :]))
        axes = [fig.add_subplot(grid[1, 0]), fig.add_subplot(grid[1, 1])]
    else:
        fig, axes = plt.subplots(1, 2, figsize=(10.4, 4.2))
    ax = axes[0]
    cmap = plt.get_cmap("viridis")
    for roi, res in result.edges:
        ax.plot(res.freq, res.sfr, color=cmap(min(roi.radius, 1.0)), lw=0.7, alpha=0.8)
    ax.set_xlim(0, 0.5)
    ax.set_ylim(0, 1.1)
    ax.set_xlabel("cycles / pixel")
    ax.set_ylabel("SFR")
    ax.set_title("SFR (colour: field radius)")
    ax.grid(alpha=0.3)
    ax = axes[1]
    m = result.field_map(value)
    im = ax.imshow(m, cmap="magma", origin="upper")
    fig.colorbar(im, ax=ax, label=f"{value} ({'cy/px' if value == 'mtf50' else 'cy/px area'})")
    ax.set_title(f"{value} over the {result.grid[0]}×{result.grid[1]} field grid")
    ax.set_xlabel("column")
    ax.set_ylabel("row")
    fig.tight_layout()
    return fig


def edge_record(roi_box, res, field=None, orientation=None) -> dict:
    """One measured edge as ``isp calib sfr`` writes it to JSON (and
    :func:`calibration.fit.measurements.observations_from_sfr_json` reads
    it back).

    Parameters
    ----------
    roi_box : (x, y, w, h)
        The ROI, pixels.
    res : SfrResult
    field : dict, optional
        ``{"radius": r, "angle_deg": a}``: the ROI's field position.
    orientation : str, optional

    Returns
    -------
    dict
        freq (cycles/pixel), sfr, mtf50, sfra, angle_deg, roi, field,
        orientation, direction, edge_fit_linear, step, MTF at Nyquist and
        half Nyquist, contrast, noise, bootstrap spreads, lp_per_mm and
        warnings.
    """
    r = res.to_dict()
    return {"freq": r["freq_cy_per_px"], "sfr": r["sfr"], "mtf50": r["mtf50_cy_per_px"],
            "sfra": r["sfra_to_nyquist"], "angle_deg": r["angle_deg"], "roi": list(roi_box),
            "field": field, "orientation": orientation, "direction": r["orientation"],
            "edge_fit_linear": r["edge_fit_linear"], "step": esf_step(res),
            "mtf_nyquist_half": r["mtf_nyquist_half"], "mtf_nyquist": r["mtf_nyquist"],
            "contrast": r["contrast"], "noise": r["noise"],
            "mtf50_std": r.get("mtf50_std"), "sfra_std": r.get("sfra_std"),
            "lp_per_mm": r.get("lp_per_mm"), "warnings": r["warnings"]}


def plot_sfr(results: dict):
    """A figure of single-ROI measurements: the e-SFR curves (left) and the
    edge spread functions (right), one line per ``{name: SfrResult}``
    (name "" for one unnamed result). Returns the matplotlib figure."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for name, r in results.items():
        axes[0].plot(r.freq, r.sfr, label=f"{name or 'SFR'}: MTF50 {r.mtf50:.3f}")
        x = np.arange(r.esf.size) * r.esf_step_px
        axes[1].plot(x - x.mean(), r.esf, label=name or "ESF")
    axes[0].axhline(0.5, color="gray", lw=0.6, ls=":")
    axes[0].set(xlim=(0, 0.5), ylim=(0, 1.1), xlabel="cycles / pixel", ylabel="SFR", title="e-SFR (ISO 12233)")
    axes[1].set(xlabel="pixels across the edge", ylabel="ESF", title="edge spread")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig

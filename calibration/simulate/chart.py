"""Test charts as vector scenes: slanted dark squares over the field (the
paper's SFR measurement layout) and a ColorChecker patch set.

A :class:`Chart` is a uniform background and convex polygons with a level
per camera channel, in sensor pixel coordinates (pixel centres at integers,
+y down; see :mod:`calibration.simulate.optical_image`). It is rendered exactly by
:func:`calibration.simulate.capture.render_chart`; nothing here is rasterised.

The layout of :func:`slanted_square_chart` follows the paper (section 5.1):
the frame is divided into ``rows × cols`` regions (15 × 20 on the phone), and
each region holds one dark square rotated by a few degrees, so every
region has two near-vertical and two near-horizontal edges whose SFR
characterises that region's PSF. Optionally the 4 × 6 regions at the centre
hold the 24 ColorChecker patches instead (unrotated squares).

Levels are given as linear sRGB reflectances (D65) and turned into camera
RGB by the demo camera's mixing matrix (:data:`calibration.simulate.scene.CAMERA_MIX`), so a
neutral grey ``g`` becomes ``g·CAMERA_MIX·(1, 1, 1)``. The default edge
levels 0.18 and 0.72 give the 4:1 contrast ISO 12233:2017 recommends for
e-SFR charts.

References
----------
ISO 12233:2017, *Photography — Electronic still picture imaging —
Resolution and spatial frequency responses*, 3rd ed., §6 (e-SFR test chart:
slanted edges of 4:1 contrast). ColorChecker sRGB values: X-Rite /
BabelColor (:data:`calibration.simulate.scene.COLORCHECKER_SRGB8`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calibration.simulate.optical_image import ImagingError, inward_normals

__all__ = ["Chart", "EdgeROI", "Shape", "camera_rgb", "slanted_square_chart"]


def camera_rgb(linear_srgb) -> np.ndarray:
    """Camera RGB of linear sRGB values through the demo camera's mixing
    matrix (:data:`calibration.simulate.scene.CAMERA_MIX`), (..., 3)."""
    from calibration.simulate.scene import CAMERA_MIX

    return np.einsum("ij,...j->...i", CAMERA_MIX, np.asarray(linear_srgb, dtype=np.float64))


@dataclass(frozen=True, eq=False)
class Shape:
    """A convex polygon of uniform level.

    Attributes
    ----------
    vertices : (K, 2) ndarray
        (x, y) pixel coordinates, in order around the polygon.
    level : (3,) ndarray
        Camera R, G, B inside (the background's outside).
    cell : (row, col) or None
        The chart cell it was placed in.
    kind : str
        "square" (slanted edge target) or "patch" (colour patch).
    """

    vertices: np.ndarray
    level: np.ndarray
    cell: tuple[int, int] | None = None
    kind: str = "square"

    def __post_init__(self):
        v = np.asarray(self.vertices, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3 or not np.all(np.isfinite(v)):
            raise ImagingError(f"vertices must be finite (K ≥ 3, 2), got shape {v.shape}")
        inward_normals(v)   # raises unless convex
        lv = np.broadcast_to(np.asarray(self.level, dtype=np.float64), (3,)).copy()
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "level", lv)

    @property
    def bbox(self) -> tuple[float, float, float, float]:
        """(x_min, y_min, x_max, y_max), pixels."""
        v = self.vertices
        return (float(v[:, 0].min()), float(v[:, 1].min()), float(v[:, 0].max()), float(v[:, 1].max()))

    def contains(self, x, y) -> np.ndarray:
        """True where pixel centres (x, y) lie inside."""
        n, c = inward_normals(self.vertices)
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        out = np.ones(np.broadcast(x, y).shape, dtype=bool)
        for (a, b), cc in zip(n, c):
            out &= a * x + b * y - cc >= 0
        return out


@dataclass(frozen=True)
class EdgeROI:
    """A slanted-edge region of interest on a chart.

    Attributes
    ----------
    box : (x, y, width, height)
        Pixels (x, y of the top-left pixel).
    cell : (row, col)
    side : {"left", "right", "top", "bottom"}
        Which side of its square.
    orientation : {"vertical", "horizontal"}
    angle_deg : float
        Edge angle from the vertical (vertical edges) or horizontal, degrees.
    point : (x, y)
        The edge's midpoint, pixels.
    """

    box: tuple[int, int, int, int]
    cell: tuple[int, int]
    side: str
    orientation: str
    angle_deg: float
    point: tuple[float, float]


@dataclass(frozen=True, eq=False)
class Chart:
    """A vector chart: background, convex shapes, cell grid.

    Attributes
    ----------
    size_px : (H, W)
    background : (3,) ndarray
        Camera R, G, B of the background.
    shapes : tuple of Shape
        Non-overlapping.
    grid : (rows, cols)
        Cells the shapes were laid out in.
    """

    size_px: tuple[int, int]
    background: np.ndarray
    shapes: tuple[Shape, ...]
    grid: tuple[int, int] = (1, 1)
    rois: tuple[EdgeROI, ...] = field(default=())

    def __post_init__(self):
        object.__setattr__(self, "background",
                           np.broadcast_to(np.asarray(self.background, dtype=np.float64), (3,)).copy())
        object.__setattr__(self, "shapes", tuple(self.shapes))
        object.__setattr__(self, "size_px", (int(self.size_px[0]), int(self.size_px[1])))

    def rasterize(self, supersample: int = 1) -> np.ndarray:
        """The unblurred chart, (H·s, W·s, 3), each cell the mean over its
        ``s × s`` sub-cells of the exact area coverage (for display and
        tests; rendering never rasterises)."""
        from calibration.simulate.optical_image import polygon_coverage

        s = int(supersample)
        h, w = self.size_px
        out = np.empty((h * s, w * s, 3))
        out[:] = self.background
        step = 1.0 / s
        for sh in self.shapes:
            x0, y0, x1, y1 = sh.bbox
            c0 = max(0, math.floor((x0 + 0.5) * s) - 1)
            r0 = max(0, math.floor((y0 + 0.5) * s) - 1)
            c1 = min(w * s, math.ceil((x1 + 0.5) * s) + 1)
            r1 = min(h * s, math.ceil((y1 + 0.5) * s) + 1)
            if c1 <= c0 or r1 <= r0:
                continue
            cov = polygon_coverage(sh.vertices, (c0 + 0.5) * step - 0.5, (r0 + 0.5) * step - 0.5,
                                   c1 - c0, r1 - r0, step)
            out[r0:r1, c0:c1] += cov[:, :, None] * (sh.level - self.background)
        return out


def _square(cx: float, cy: float, side: float, angle_deg: float) -> np.ndarray:
    """Vertices of a square rotated clockwise on the sensor by ``angle_deg``
    (its left and right edges then lean so that x grows with y: the
    positive angle of :mod:`calibration.sfr.synthetic`)."""
    t = math.radians(angle_deg)
    # unit vectors of the square's sides in the (x right, y down) frame
    u = np.array([math.cos(t), -math.sin(t)])    # along the top edge
    v = np.array([math.sin(t), math.cos(t)])     # along the left edge, downward
    h = side / 2.0
    c = np.array([cx, cy])
    return np.array([c - h * u - h * v, c + h * u - h * v, c + h * u + h * v, c - h * u + h * v])


def _edge_rois(verts: np.ndarray, cell, angle_deg: float, side: float, size_px) -> list[EdgeROI]:
    """Four ROIs centred on the edges' midpoints: 60 % of the side along the
    edge, 50 % across (half of it inside the square)."""
    h, w = size_px
    along, across = round(0.6 * side), round(0.5 * side)
    out = []
    names = ("top", "right", "bottom", "left")
    for i, name in enumerate(names):
        a, b = verts[i], verts[(i + 1) % 4]
        mx, my = (a + b) / 2.0
        vertical = name in ("left", "right")
        bw, bh = (across, along) if vertical else (along, across)
        x0 = round(mx - (bw - 1) / 2.0)
        y0 = round(my - (bh - 1) / 2.0)
        if x0 < 0 or y0 < 0 or x0 + bw > w or y0 + bh > h:
            continue
        out.append(EdgeROI((x0, y0, bw, bh), cell, name, "vertical" if vertical else "horizontal",
                           abs(float(angle_deg)), (float(mx), float(my))))
    return out


def slanted_square_chart(height_px: int, width_px: int, grid: tuple[int, int] = (15, 20), *,
                         angle_deg: float = 5.0, fill: float = 0.55, dark: float = 0.18, light: float = 0.72,
                         colorchecker: bool = False, patch_fill: float = 0.8) -> Chart:
    """One slanted dark square per cell of a ``rows × cols`` grid.

    Parameters
    ----------
    height_px, width_px : int
        Frame size.
    grid : (rows, cols)
        Cells (use the PSF map's grid so that each square sits in one PSF
        region).
    angle_deg : float
        Rotation of the squares, degrees (edges 5° off the pixel axes by
        default; avoid 0°, 14.04°, 26.57° and 45°).
    fill : float
        Square side as a fraction of the smaller cell dimension, (0, 0.9].
    dark, light : float
        Linear reflectances (neutral) of the squares and the background.
    colorchecker : bool
        Put the 24 ColorChecker patches in the central 4 × 6 cells (needs a
        grid of at least 4 × 6).
    patch_fill : float
        Patch side as a fraction of the smaller cell dimension.

    Returns
    -------
    Chart
        With ``rois``: the edge ROIs of every square that lies inside the
        frame (each ≥ 0.6·side long).

    Examples
    --------
    >>> ch = slanted_square_chart(300, 400, (3, 4))
    >>> len(ch.shapes), len(ch.rois), ch.rois[0].box
    (12, 48, (31, 9, 33, 28))
    """
    rows, cols = (int(v) for v in grid)
    h, w = int(height_px), int(width_px)
    if rows < 1 or cols < 1:
        raise ImagingError(f"grid must be at least 1 × 1, got {grid!r}")
    if not 0 < fill <= 0.9:
        raise ImagingError(f"fill must be in (0, 0.9], got {fill!r}")
    if colorchecker and (rows < 4 or cols < 6):
        raise ImagingError(f"a ColorChecker needs a grid of at least 4 × 6 cells, got {rows} × {cols}")
    cw, chh = w / cols, h / rows
    side = fill * min(cw, chh)
    if side < 8:
        raise ImagingError(f"cells of {cw:.1f} × {chh:.1f} px are too small for slanted squares")
    bg = camera_rgb(np.full(3, light))
    sq = camera_rgb(np.full(3, dark))
    patches = {}
    if colorchecker:
        from calibration.simulate.scene import COLORCHECKER_SRGB8, srgb_to_linear

        r0, c0 = (rows - 4) // 2, (cols - 6) // 2
        lin = srgb_to_linear(COLORCHECKER_SRGB8 / 255.0)
        for k in range(24):
            patches[(r0 + k // 6, c0 + k % 6)] = camera_rgb(lin[k])
    shapes, rois = [], []
    for r in range(rows):
        for c in range(cols):
            cx, cy = (c + 0.5) * cw - 0.5, (r + 0.5) * chh - 0.5
            if (r, c) in patches:
                v = _square(cx, cy, patch_fill * min(cw, chh), 0.0)
                shapes.append(Shape(v, patches[(r, c)], (r, c), "patch"))
                continue
            v = _square(cx, cy, side, angle_deg)
            shapes.append(Shape(v, sq, (r, c), "square"))
            rois += _edge_rois(v, (r, c), angle_deg, side, (h, w))
    return Chart((h, w), bg, tuple(shapes), (rows, cols), tuple(rois))

"""Which chart a picture shows: the ISO 12233:2023 e-SFR chart, the
ISO 12233:2000 resolution chart, a grid of slanted squares, or a single
slanted square (the ISO 12233 / ISO 14524 "Camera SFR & OECF" target), told
apart by the dark shapes that carry their slanted edges.

The shapes are the dark regions of a locally thresholded copy of the chart
(OpenCV's mean adaptive threshold over an eighth of the image, on the chart
reduced to 2,048 px), each outline reduced to a polygon
(Douglas–Peucker, 3 % of its perimeter):

* a **slanted quadrilateral**: four corners, solid (area ≥ 93 % of its
  convex hull), at least one side 1–44° off the axes and none further
  (an axis-aligned grey patch is not one);
* a **slanted square**: such a quadrilateral of aspect ≤ 1.3, every side
  1–20° off its axis (the squares of ISO 12233:2014+ charts, of MTF
  Mapper's and Imatest's grids);
* a **pinwheel**: three or more slanted quadrilaterals with a corner each
  within 1 % of the image size of one point, the blades of the e-SFR
  chart's nine star-shaped targets (ISO 12233:2017 Annex C / 2023);
* a **slanted bar**: a solid region (≥ 85 % of its hull) at least four times
  longer than wide and at least 12 % of the image long, tilted 1.5–15°,
  black on white (100 of 255 levels below the ring around it): the ~5°
  bars at the centre of the ISO 12233:2000 chart, one along each axis.

The rule, first match wins: ≥ 3 pinwheels, the e-SFR chart; ≥ 4 slanted
squares, a slanted-square grid; two to four slanted bars, among them one
horizontal and one vertical, the ISO 12233:2000 chart; a slanted square at
least a tenth of the image wide and 40 levels darker than its ground, a
slanted-square target; otherwise unknown. Natural images (Kodak, McMaster:
blinds, stripes, windows) come out unknown: stripes are parallel, and
nothing in them is a clean dark square.
The counts come with the name, so a user sees why.

Imports NumPy and OpenCV; nothing of the optics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["ChartLayout", "DETECT_MAX_SIDE", "LAYOUTS", "detection_image", "recognise_chart"]

#: layout name → what it is, as reports print it
LAYOUTS = {
    "esfr_2023": "ISO 12233:2023 e-SFR chart",
    "square_grid": "slanted-square grid",
    "iso12233_2000": "ISO 12233:2000 resolution chart",
    "slanted_square": "slanted-square target",
    "unknown": "unrecognised layout",
}
#: the longest side of the image a chart's shapes and edge segments are found on
#: (here and by :func:`calibration.sfr.chart.find_edges`): a 12 MP chart is halved
#: (LSD takes 0.13 s instead of 0.64 s; the SFR is measured at full resolution)
DETECT_MAX_SIDE = 2048


def detection_image(gray: np.ndarray, lo: float, hi: float) -> tuple[np.ndarray, float]:
    """``(u8, scale)``: the chart reduced to :data:`DETECT_MAX_SIDE` px at
    most (area average; ``scale`` its size over the input's) and stretched
    to 8 bits between the levels ``lo`` and ``hi``.

    >>> step = np.repeat([0.2, 0.8], 2048)[None].repeat(8, 0)     # a 4096 px wide edge
    >>> u8, s = detection_image(step, 0.2, 0.8)
    >>> u8.shape, s, int(u8[0, 0]), int(u8[0, -1])
    ((4, 2048), 0.5, 0, 255)
    """
    import cv2

    g = np.asarray(gray)
    h, w = g.shape
    s = min(1.0, DETECT_MAX_SIDE / max(h, w))
    work = g if g.dtype in (np.uint8, np.uint16, np.float32) else g.astype(np.float32)
    if s < 1.0:
        work = cv2.resize(work, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    u8 = np.clip((work.astype(np.float32) - np.float32(lo)) * np.float32(255.0 / (hi - lo)), 0, 255)
    return u8.astype(np.uint8), s


@dataclass(frozen=True)
class ChartLayout:
    """A chart's recognised layout: ``name`` (a key of :data:`LAYOUTS`) and
    the shapes that decided it, counted, with the centres of the pinwheels
    and squares in the image's pixels."""

    name: str
    pinwheels: int = 0
    squares: int = 0
    bars: int = 0
    quadrilaterals: int = 0
    centres: list = field(default_factory=list)

    @property
    def title(self) -> str:
        """The layout as a report names it, e.g. "ISO 12233:2023 e-SFR chart"."""
        return LAYOUTS[self.name]

    def as_dict(self) -> dict:
        return {"name": self.name, "title": self.title, "pinwheels": self.pinwheels, "squares": self.squares,
                "bars": self.bars, "quadrilaterals": self.quadrilaterals,
                "centres": [[round(float(x), 1), round(float(y), 1)] for x, y in self.centres]}


def _slant(deg: float) -> float:
    """Angle from the nearest axis, degrees (0–45)."""
    a = abs(deg) % 90.0
    return min(a, 90.0 - a)


def recognise_chart(gray: np.ndarray) -> ChartLayout:
    """The layout of a chart image (module notes).

    Parameters
    ----------
    gray : (H, W) ndarray
        The chart's luminance or one colour plane: float, uint8 or uint16,
        dark features on a lighter ground.

    Returns
    -------
    ChartLayout

    Examples
    --------
    >>> from calibration.sfr.synthetic import render_square_chart
    >>> chart = render_square_chart((600, 800), (3, 4), sigma_px=1.0)
    >>> layout = recognise_chart(chart.image)
    >>> layout.name, layout.squares
    ('square_grid', 12)
    """
    import cv2

    g = np.asarray(gray)
    if g.ndim != 2 or min(g.shape) < 16:
        return ChartLayout("unknown")
    lo, hi = np.percentile(g[::4, ::4], [1, 99])     # the edge search's stretch
    if not hi > lo:
        return ChartLayout("unknown")
    u8, s = detection_image(g, lo, hi)
    block = int(max(u8.shape) / 8) | 1
    dark = cv2.adaptiveThreshold(u8, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV, max(block, 3), 10)
    contours, _ = cv2.findContours(dark, cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
    side = max(u8.shape)
    min_area, max_area = (0.01 * side) ** 2, 0.25 * u8.size
    quads, bars = [], []
    for c in contours:
        area = cv2.contourArea(c)
        if not min_area <= area <= max_area:
            continue
        solidity = area / max(cv2.contourArea(cv2.convexHull(c)), 1.0)
        (cx, cy), (w, h), ang = cv2.minAreaRect(c)
        aspect = max(w, h) / max(min(w, h), 1.0)
        if (solidity >= 0.85 and aspect >= 4.0 and 1.5 <= _slant(ang) <= 15.0
                and max(w, h) >= 0.12 * side and _contrast(u8, c) >= 100):
            # which axis the bar runs along: minAreaRect's angle is that of its side w
            bars.append("h" if (w >= h) == (_slant(ang) == abs(ang) % 90.0) else "v")
        poly = cv2.approxPolyDP(c, 0.03 * cv2.arcLength(c, True), True).reshape(-1, 2).astype(np.float64)
        if len(poly) != 4 or solidity < 0.93:
            continue
        d = np.diff(np.vstack([poly, poly[:1]]), axis=0)
        slants = [_slant(math.degrees(math.atan2(y, x))) for x, y in d]
        if not 1.0 <= max(slants) <= 44.0:
            continue
        quads.append(((cx, cy), poly, aspect, min(slants), max(slants), math.sqrt(area), c))
    squares = [q for q in quads if q[2] <= 1.3 and q[3] >= 1.0 and q[4] <= 20.0]
    wheels = _pinwheels([q[1] for q in quads], 0.01 * side)
    if len(wheels) >= 3:
        name, centres = "esfr_2023", wheels
    elif len(squares) >= 4:
        name, centres = "square_grid", [q[0] for q in squares]
    elif 2 <= len(bars) <= 4 and {"h", "v"} <= set(bars):
        name, centres = "iso12233_2000", []
    elif (big := [q for q in squares if q[5] >= 0.1 * side and _contrast(u8, q[6]) >= 40]):
        name, centres = "slanted_square", [q[0] for q in big]
    else:
        name, centres = "unknown", []
    return ChartLayout(name, len(wheels), len(squares), len(bars), len(quads),
                       [(x / s, y / s) for x, y in centres])


def _contrast(u8: np.ndarray, contour) -> float:
    """Mean of the 8-bit image in a 4-px ring just outside ``contour`` minus
    the mean inside it (positive: a dark shape on a lighter ground)."""
    import cv2

    x, y, w, h = cv2.boundingRect(contour)
    pad = 5
    x0, y0 = max(x - pad, 0), max(y - pad, 0)
    x1, y1 = min(x + w + pad, u8.shape[1]), min(y + h + pad, u8.shape[0])
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.drawContours(mask, [contour], -1, 255, -1, offset=(-x0, -y0))
    ring = cv2.dilate(mask, np.ones((9, 9), np.uint8)) > mask
    patch = u8[y0:y1, x0:x1]
    inside = patch[mask > 0]
    return float(patch[ring].mean() - inside.mean()) if inside.size and ring.any() else 0.0


def _pinwheels(polys: list, radius: float) -> list[tuple[float, float]]:
    """Points where corners of three or more different quadrilaterals meet
    (within ``radius``), one per pinwheel (points closer than 4 radii merged)."""
    if not polys:
        return []
    verts = np.concatenate(polys)
    owner = np.repeat(np.arange(len(polys)), [len(p) for p in polys])
    centres: list[tuple[float, float]] = []
    for v in verts:
        near = np.hypot(*(verts - v).T) < radius
        if len(set(owner[near].tolist())) >= 3 and all(math.hypot(v[0] - x, v[1] - y) >= 4 * radius
                                                       for x, y in centres):
            centres.append((float(verts[near, 0].mean()), float(verts[near, 1].mean())))
    return centres

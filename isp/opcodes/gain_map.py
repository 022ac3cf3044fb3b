"""GainMap (ID 9): a 2-D map of gains, bilinearly interpolated over the
image, as phones use it for lens shading, with the SDK's interpolation
(DNG 1.7.1.0, chapter 7; SDK ``dng_gain_map.cpp``)."""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from isp.opcodes.base import AreaSpec, Opcode, OpcodeContext, data_planes, plane_view
from isp.opcodes.binary import OpcodeError, expect_size, frozen_array, set_field

_GAIN_MAP_HEADER = struct.Struct(">II4dI")


# --------------------------------------------------------------------------
# gain map

def _interp_points(pos: np.ndarray, origin: float, spacing: float, points: int):
    """The map samples either side of relative positions ``pos`` and the
    weight of the second: ``(i0, i1, frac)``, the value at ``pos`` being
    ``(1 − frac)·v[i0] + frac·v[i1]``; clamped to the first/last sample
    outside the map (``i0 = i1`` there)."""
    index = np.clip((pos - origin) / spacing, 0.0, points - 1)
    i0 = np.floor(index).astype(np.int64)
    return i0, np.minimum(i0 + 1, points - 1), index - i0


def _interp_weights(pos: np.ndarray, origin: float, spacing: float, points: int) -> np.ndarray:
    """(len(pos), points) linear-interpolation weights of map samples at
    relative positions ``pos``, clamped to the first/last sample outside
    the map (no extrapolation), as ``dng_gain_map_interpolator`` does."""
    i0, i1, frac = _interp_points(pos, origin, spacing, points)
    w = np.zeros((pos.size, points), dtype=np.float64)
    k = np.arange(pos.size)
    w[k, i0] = 1.0 - frac
    w[k, i1] += frac
    return w


@dataclass(frozen=True, eq=False, repr=False)
class GainMap(Opcode):
    """A 2-D map of gains, bilinearly interpolated over the image (ID 9):
    lens-shading (colour shading and vignetting) correction.

    Parameters: area spec; uint32 MapPointsV, MapPointsH; float64
    MapSpacingV, MapSpacingH, MapOriginV, MapOriginH; uint32 MapPlanes;
    float32 gains in the order ``[row][col][plane]`` (MapPointsV x MapPointsH x
    MapPlanes).

    Attributes
    ----------
    area : AreaSpec
        Which pixels and planes the gains multiply.
    gains : (MapPointsV, MapPointsH, MapPlanes) ndarray of float32
        The gains, dimensionless. Must be finite.
    spacing_v, spacing_h : float
        Distance between map points, as a fraction of the image height /
        width (> 0). Ignored, as stored, where that axis has one point.
    origin_v, origin_h : float
        Position of the first map point, as a fraction of the image height /
        width, measured from the image's top-left corner (not the area's).

    Notes
    -----
    Image plane ``p`` of the area uses map plane ``min(p, MapPlanes - 1)``
    (:meth:`map_plane_for`). With one point on an axis the SDK forces that
    axis's spacing to 1 and origin to 0 (:attr:`map_spacing`,
    :attr:`map_origin` give the values used); the stored ones are kept for
    byte-exact round trips.
    """

    ID = 9
    area: AreaSpec
    gains: Any
    spacing_v: float = 1.0
    spacing_h: float = 1.0
    origin_v: float = 0.0
    origin_h: float = 0.0

    HEADER_SIZE: ClassVar[int] = AreaSpec.SIZE + _GAIN_MAP_HEADER.size   # 76

    def _validate(self):
        gains = np.asarray(self.gains)
        if gains.ndim == 2:
            gains = gains[:, :, None]
        gains = frozen_array(gains, np.float32, 3, "gains")
        if min(gains.shape) < 1:
            raise OpcodeError(f"map has {gains.shape[0]}x{gains.shape[1]} points and "
                              f"{gains.shape[2]} planes, each must be >= 1")
        bad = ~np.isfinite(gains)
        if bad.any():
            first = [int(i) for i in np.argwhere(bad)[0]]
            raise OpcodeError(f"{int(bad.sum())} non-finite gain(s), first "
                              f"{gains[tuple(first)]!r} at [{first[0]}][{first[1]}][{first[2]}]")
        set_field(self, "gains", gains)
        for name in ("spacing_v", "spacing_h", "origin_v", "origin_h"):
            set_field(self, name, float(getattr(self, name)))
        for axis, (sp, org) in zip("vh", zip(self.map_spacing, self.map_origin)):
            if not (math.isfinite(sp) and sp > 0.0):
                raise OpcodeError(f"map spacing {axis.upper()} is {sp!r}, must be > 0")
            if not math.isfinite(org):
                raise OpcodeError(f"map origin {axis.upper()} is {org!r}, must be finite")

    @classmethod
    def spanning_image(cls, gains, area: AreaSpec | None = None, **kw) -> "GainMap":
        """A map whose first and last points sit on the image's edges
        (origin 0, spacing 1 / (points - 1)), as most phones write them.
        ``area`` defaults to the whole image, every plane of the map."""
        g = np.asarray(gains)
        if g.ndim == 2:
            g = g[:, :, None]
        if g.ndim != 3:
            raise OpcodeError(f"gains must be 2-D or 3-D, got shape {g.shape}", name="GainMap")
        pv, ph = g.shape[:2]
        if area is None:
            area = AreaSpec(0, 0, 0, 0, 0, max(g.shape[2], 1))
        return cls(area, g, 1.0 / max(pv - 1, 1), 1.0 / max(ph - 1, 1), 0.0, 0.0, **kw)

    @property
    def points_v(self) -> int:
        """MapPointsV."""
        return self.gains.shape[0]

    @property
    def points_h(self) -> int:
        """MapPointsH."""
        return self.gains.shape[1]

    @property
    def map_planes(self) -> int:
        """MapPlanes."""
        return self.gains.shape[2]

    @property
    def map_spacing(self) -> tuple[float, float]:
        """(V, H) spacing used for interpolation (1 on a one-point axis)."""
        return (1.0 if self.points_v == 1 else self.spacing_v,
                1.0 if self.points_h == 1 else self.spacing_h)

    @property
    def map_origin(self) -> tuple[float, float]:
        """(V, H) origin used for interpolation (0 on a one-point axis)."""
        return (0.0 if self.points_v == 1 else self.origin_v,
                0.0 if self.points_h == 1 else self.origin_h)

    def map_plane_for(self, plane: int) -> int:
        """The map plane that image plane ``plane`` uses."""
        return min(int(plane), self.map_planes - 1)

    def pixels(self, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
        """Which pixels of a ``height`` x ``width`` image the map multiplies.

        Returns
        -------
        rows, cols : 1-D ndarrays of int64
            Row and column indices (the area's lattice, clipped to the
            image); the pixels are their outer product
            (``image[np.ix_(rows, cols)]``).
        """
        return self.area.rows(height), self.area.cols(width)

    def evaluate(self, rows, cols, image_height: int, image_width: int,
                 map_plane: int = 0) -> np.ndarray:
        """Gains at pixel coordinates, as the DNG SDK interpolates them.

        Parameters
        ----------
        rows, cols : 1-D array_like of int
            Pixel row and column indices in the image the opcode list
            applies to (0 = top/left of that image, not of the area).
        image_height, image_width : int
            Size of that image in pixels: the map's coordinates are
            fractions of it.
        map_plane : int, optional
            Which map plane (see :meth:`map_plane_for`).

        Returns
        -------
        gain : (len(rows), len(cols)) ndarray of float32
            Gain at each (row, col), dimensionless.

        Notes
        -----
        For row i (columns likewise), per ``dng_gain_map_interpolator``:

        .. math::

            v = \\frac{i + 0.5}{H},\\qquad
            t = \\operatorname{clip}\\left(\\frac{v - \\text{MapOriginV}}
                {\\text{MapSpacingV}},\\ 0,\\ \\text{MapPointsV} - 1\\right)

        and the gain is bilinear in (t_v, t_h) between the four surrounding
        map points; outside the map the nearest edge row/column of points
        holds (no extrapolation). The SDK steps the column interpolation
        incrementally in float32; the two agree to about 1e-6.
        Separable: a (rows x PointsV) and a (cols x PointsH) weight matrix,
        two matrix products.
        """
        h, w = int(image_height), int(image_width)
        if h < 1 or w < 1:
            raise ValueError(f"image size must be positive, got {image_height}x{image_width}")
        if not 0 <= int(map_plane) < self.map_planes:
            raise ValueError(f"map_plane {map_plane} out of range 0..{self.map_planes - 1}")
        r = np.asarray(rows, dtype=np.float64)
        c = np.asarray(cols, dtype=np.float64)
        if r.ndim != 1 or c.ndim != 1:
            raise ValueError(f"rows and cols must be 1-D, got shapes {r.shape} and {c.shape}")
        if not (np.isfinite(r).all() and np.isfinite(c).all()):
            raise ValueError("rows and cols must be finite pixel indices")
        return self.row_weights(r, h) @ self.column_profile(c, w, map_plane)

    def row_weights(self, rows, image_height: int) -> np.ndarray:
        """(len(rows), MapPointsV) float32 interpolation weights of the map's
        point rows at pixel rows ``rows`` (the left factor of
        :meth:`evaluate`)."""
        r = np.asarray(rows, dtype=np.float64)
        sv, ov = self.map_spacing[0], self.map_origin[0]
        return _interp_weights((r + 0.5) / int(image_height), ov, sv, self.points_v).astype(np.float32)

    def column_profile(self, cols, image_width: int, map_plane: int = 0) -> np.ndarray:
        """(MapPointsV, len(cols)) float32: each map row interpolated at
        pixel columns ``cols`` (the right factor of :meth:`evaluate`).

        Maps that share their row geometry (the per-CFA-phase maps of a
        phone DNG) can interleave their profiles and be evaluated with one
        matrix product."""
        c = np.asarray(cols, dtype=np.float64)
        sh, oh = self.map_spacing[1], self.map_origin[1]
        i0, i1, frac = _interp_points((c + 0.5) / int(image_width), oh, sh, self.points_h)
        # the two map points either side of each column, blended (the product with the
        # (cols × points) weight matrix, whose rows hold these two weights, without a
        # matrix product: a multithreaded BLAS call costs more in start-up than it computes)
        g = self.gains[:, :, int(map_plane)].astype(np.float64)
        return (g[:, i0] * (1.0 - frac) + g[:, i1] * frac).astype(np.float32)

    def apply(self, data: np.ndarray, ctx: OpcodeContext) -> np.ndarray:
        """Multiply the area's pixels by the interpolated gains, in place
        (SDK ``dng_opcode_GainMap::ProcessArea``): image plane p of the area
        uses map plane :meth:`map_plane_for` (p), positions are fractions
        of the list's image (:meth:`evaluate`). Stage-1 results are rounded
        and clipped to 0..``code_max``; stages 2 and 3 are not clipped (the
        SDK clips the product at white). Returns ``data``."""
        self._check_apply(data, ctx)
        window = self.area.window(ctx, data.shape)
        if window is None:
            return data
        h, w = ctx.size(data.shape)
        oy, ox = ctx.origin
        rows = np.arange(data.shape[0])[window[0]] + oy
        cols = np.arange(data.shape[1])[window[1]] + ox
        for p in self.area.plane_range(data_planes(data)):
            view = plane_view(data, p)
            y = view[window] * self.evaluate(rows, cols, h, w, self.map_plane_for(p))
            if ctx.stage == 1:
                y = np.clip(np.rint(y), 0.0, ctx.code_max)
            view[window] = y
        return data

    def same_rows(self, other: "GainMap") -> bool:
        """True if ``other`` has the same point rows (count, spacing, origin)."""
        return (self.points_v == other.points_v and self.map_spacing[0] == other.map_spacing[0]
                and self.map_origin[0] == other.map_origin[0])

    def _params(self):
        return (self.area.to_bytes()
                + _GAIN_MAP_HEADER.pack(self.points_v, self.points_h, self.spacing_v,
                                        self.spacing_h, self.origin_v, self.origin_h,
                                        self.map_planes)
                + self.gains.astype(">f4").tobytes())

    @classmethod
    def _parse(cls, r, size, **header):
        if size < cls.HEADER_SIZE:
            raise OpcodeError(f"declares {size} parameter bytes but needs at least "
                              f"{cls.HEADER_SIZE} for the area spec and map header")
        area = AreaSpec._read(r)
        pv, ph = r.u32s(2, "map points")
        sv, sh, ov, oh = r.f64s(4, "map spacing and origin")
        planes = r.u32("map planes")
        if min(pv, ph, planes) < 1:
            raise OpcodeError(f"map has {pv}x{ph} points and {planes} planes, "
                              "each must be >= 1")
        expect_size(size, cls.HEADER_SIZE + 4 * pv * ph * planes,
                     f"{pv}x{ph}x{planes} gains")
        gains = r.array(">f4", pv * ph * planes, "gains").reshape(pv, ph, planes)
        return cls(area, gains, sv, sh, ov, oh, **header)

    def _describe(self):
        out = self.area.describe()
        out.update(points=[self.points_v, self.points_h], map_planes=self.map_planes,
                   spacing=[self.spacing_v, self.spacing_h],
                   origin=[self.origin_v, self.origin_h],
                   gain_min=float(self.gains.min()), gain_max=float(self.gains.max()))
        return out

r"""Lens-distortion warps: WarpRectilinear (ID 1), WarpFisheye (ID 2) and
WarpRectilinear2 (ID 14, DNG 1.6), read, written and applied as DNG
1.7.1.0 chapter 7 and the Adobe DNG SDK (``dng_lens_correction.cpp``,
``dng_filter_warp``) do.

The warp maps each pixel of the corrected image back to a position in the
uncorrected one (an inverse mapping) and resamples there. The optical
centre sits at ``cx W`` columns and ``cy H`` rows
(pixel indices, the image's top-left pixel at 0); distances are normalised
by R, the distance from the centre to the farthest image corner (corners at
the pixel edges, rows scaled by ``s = 1 / PixelAspectRatio``); for a
destination pixel at offset ``d = (d_v, d_h)`` from the centre, with
``n = d / R``, ``n_s = (s n_v, n_h)`` and ``r^2 = min(|n_s|^2, 1)``, the
source position is

.. math::

    p = c + R\,\big(n\,f(r^2) + (t_v / s,\ t_h)\big)

with the radial ratio ``f`` of each opcode (:meth:`WarpRectilinear.ratio`,
...) and, for the rectilinear warps, the tangential terms

.. math::

    t_v = k_{t0}(r^2 + 2 n_{s,v}^2) + 2 k_{t1} n_{s,h} n_{s,v},\qquad
    t_h = k_{t1}(r^2 + 2 n_{s,h}^2) + 2 k_{t0} n_{s,h} n_{s,v}.

Each plane has its own coefficients (lateral colour); a one-plane opcode
applies to every plane. The position is clipped to the image, cut to the
SDK's 1/32-pixel lattice by truncation (its ``kResampleSubsampleCount2D``)
and resampled with the bicubic kernel (Keys, a = -0.75, the SDK's
``dng_resample_bicubic`` and OpenCV's ``INTER_CUBIC``), which OpenCV's
``remap`` runs here from fixed-point maps built band by band.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from isp.opcodes.base import MAX_WARP_PLANES, Opcode, OpcodeContext, data_planes
from isp.opcodes.binary import OpcodeError, Reader, as_floats, as_u32, check_center, expect_size, set_field

#: subpixel positions per pixel of the resampling lattice (SDK and OpenCV: 32)
SUBPIXELS = 32
#: destination rows computed per band (bounds the maps' memory)
_BAND_ROWS = 128

# --------------------------------------------------------------------------
# warps

def _plane_rows(rows, width: int, what: str) -> tuple[tuple[float, ...], ...]:
    out = tuple(as_floats(r, width, what) for r in rows)
    if not 1 <= len(out) <= MAX_WARP_PLANES:
        raise OpcodeError(f"{what}: {len(out)} planes, must be 1..{MAX_WARP_PLANES}")
    return out


def _read_warp_planes(r: Reader, size: int, per_plane: int, tail: int, name: str) -> int:
    planes = r.u32("plane count")
    if not 1 <= planes <= MAX_WARP_PLANES:
        raise OpcodeError(f"plane count is {planes}, must be 1..{MAX_WARP_PLANES}")
    expect_size(size, 4 + 8 * per_plane * planes + tail,
                 f"{planes} plane(s) of {name} coefficients")
    return planes


def _as_float(x) -> np.ndarray:
    """``x`` as float32 where it is float32, else float64."""
    x = np.asarray(x)
    return x if x.dtype == np.float32 else x.astype(np.float64)


def _sdk_edges(plane: np.ndarray) -> None:
    """What the SDK's resampler does to a plane it maps onto itself, in
    place: the first row and column read their neighbour, the last three
    read the fourth from last (see :meth:`_Warp._fixed_maps`)."""
    h, w = plane.shape
    if w >= 5:
        plane[:, 0] = plane[:, 1]
        plane[:, w - 3:] = plane[:, w - 4:w - 3]
    if h >= 5:
        plane[0, :] = plane[1, :]
        plane[h - 3:, :] = plane[h - 4:h - 3, :]


def _round_half_up(x: float) -> int:
    """The SDK's ``Round_int32`` for non-negative values."""
    return int(math.floor(x + 0.5))


@dataclass(frozen=True, repr=False)
class _Warp(Opcode):
    """What the three warps share: the geometry of ``dng_filter_warp`` and
    its application (see the module docstring). Subclasses give the radial
    ratio, the tangential coefficients and which planes are identities."""

    def _plane_index(self, plane: int) -> int:
        """The coefficient plane that image plane ``plane`` uses: its own, or
        plane 0 where the opcode has fewer (the SDK propagates plane 0)."""
        return plane if plane < self.planes else 0

    def ratio(self, plane: int, r2) -> np.ndarray:
        """The radial ratio f(r^2) of coefficient plane ``plane`` at squared
        normalised radii ``r2`` (0..1): source radius / destination
        radius. float64, the shape of ``r2``."""
        raise NotImplementedError

    def _tangential(self, plane: int) -> tuple[float, float]:
        return (0.0, 0.0)

    def _is_identity(self, plane: int) -> bool:
        return False

    def _plane_key(self, plane: int) -> tuple:
        raise NotImplementedError

    def _coefficients(self) -> tuple[float, ...]:
        """Every coefficient of every plane."""
        return tuple(v for p in range(self.planes) for v in self._plane_key(p))

    def unsupported(self, stage, planes):
        if self.planes == 1 or self.planes == planes or (planes == 1 and self.planes == 3):
            return None
        return (f"{self.planes} planes of coefficients for an image of {planes} planes "
                "(must be 1 or the image's)")

    @staticmethod
    def geometry(center_x: float, center_y: float, height: int, width: int,
                 pixel_aspect_ratio: float = 1.0) -> tuple[float, float, float]:
        """Optical centre and normalising radius in pixels for an image of
        ``height`` x ``width``, as ``dng_filter_warp`` sets them up.

        Returns
        -------
        cy, cx, radius : float
            The centre at ``cy = center_y H`` rows and ``cx = center_x W``
            columns (pixel indices); ``radius`` is the distance from the
            centre to the farthest corner of the image (corners at 0 and
            H, W; rows counted in square units, ``round(H / PAR)``).
        """
        h, w = int(height), int(width)
        hs = _round_half_up(h / float(pixel_aspect_ratio))
        cys, cx = center_y * hs, center_x * w
        radius = math.hypot(max(cys, hs - cys), max(cx, w - cx))
        return center_y * h, cx, radius

    def source_positions(self, rows, cols, image_size: tuple[int, int], plane: int = 0,
                         pixel_aspect_ratio: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Where in the uncorrected image each corrected pixel comes from.

        Parameters
        ----------
        rows, cols : 1-D array_like of float
            Destination pixel rows and columns in the list's image (pixel
            indices; integers for pixels).
        image_size : (int, int)
            (H, W) of that image in pixels.
        plane : int
            Image plane (its coefficients; plane 0's where the opcode has
            one plane).
        pixel_aspect_ratio : float
            DefaultScale H / V.

        Returns
        -------
        src_rows, src_cols : (len(rows), len(cols)) ndarrays of float64
            Source positions in pixels, not clipped to the image (see the
            module docstring for the mapping).
        """
        h, w = image_size
        q = self._plane_index(int(plane))
        cy, cx, radius = self.geometry(self.center_x, self.center_y, h, w, pixel_aspect_ratio)
        sv = 1.0 / float(pixel_aspect_ratio)
        nv = ((np.asarray(rows, dtype=np.float64) - cy) / radius)[:, None]
        nh = ((np.asarray(cols, dtype=np.float64) - cx) / radius)[None, :]
        nsv2 = (nv * sv) ** 2
        nh2 = nh * nh
        r2 = np.minimum(nsv2 + nh2, 1.0)
        f = self.ratio(q, r2)
        src_v = nv * f
        src_h = nh * f
        kt0, kt1 = self._tangential(q)
        if kt0 or kt1:
            cross = 2.0 * (nv * sv) * nh
            src_v += (kt0 * (r2 + 2.0 * nsv2) + kt1 * cross) / sv
            src_h += kt1 * (r2 + 2.0 * nh2) + kt0 * cross
        src_v *= radius
        src_v += cy
        src_h *= radius
        src_h += cx
        return src_v, src_h

    def _constant_ratio(self, plane: int) -> bool:
        """True where the plane's radial ratio does not depend on r."""
        return False

    def ratio_minus_one(self, plane: int, r2) -> np.ndarray:
        """f(r^2) - 1, computed so that it keeps its relative precision
        where f is close to 1 (the displacement is ``(d) (f - 1)``)."""
        return np.asarray(self.ratio(plane, np.asarray(r2, dtype=np.float64)), np.float64) - 1.0

    def _fixed_maps(self, rows, cols, ctx: OpcodeContext, plane: int, shape, image_size):
        """OpenCV fixed-point remap maps for destination data rows ``rows``
        and columns ``cols`` (1-D integer-valued): int16 (n, m, 2) integer
        (x, y) parts and uint16 (n, m) 1/32 fractions of the positions of
        :meth:`source_positions`, clipped to the image and to the window
        held, truncated to 1/32 pixel as the SDK does.

        Each position is split into the destination pixel (an integer) and
        its displacement ``d (f - 1) + R t``; only the displacement is
        computed in float32, so the truncation agrees with the SDK's
        float64 one (measured on dng_validate's stage-3 images: within one
        16-bit code everywhere). Where the ratio is a constant and there is
        no tangential term the map is separable and computed in 1-D."""
        oy, ox = ctx.origin
        h, w = image_size
        q = self._plane_index(int(plane))
        cy, cx, radius = self.geometry(self.center_x, self.center_y, h, w, ctx.pixel_aspect_ratio)
        sv = 1.0 / float(ctx.pixel_aspect_ratio)
        y = np.asarray(rows, dtype=np.float64) + oy       # destination, image pixels
        x = np.asarray(cols, dtype=np.float64) + ox
        dv, dh = y - cy, x - cx
        kt0, kt1 = self._tangential(q)
        sub = float(SUBPIXELS)
        if self._constant_ratio(q) and not (kt0 or kt1):
            # separable: the SDK's own float64 arithmetic, in 1-D
            f = float(self.ratio(q, np.zeros(1))[0])
            if any(self._tangential(p) != (0.0, 0.0) for p in range(self.planes)):
                inv = 1.0 / radius          # its radial-and-tangential branch
                pv, ph = cy + radius * ((dv * inv) * f), cx + radius * ((dh * inv) * f)
            else:                           # its radial-only branch
                pv, ph = cy + dv * f, cx + dh * f
            big = float(1 << 24)
            disp_v = np.clip(np.nan_to_num(np.floor(sub * pv) - sub * y, nan=0.0), -big, big)[:, None]
            disp_h = np.clip(np.nan_to_num(np.floor(sub * ph) - sub * x, nan=0.0), -big, big)[None, :]
        else:
            f32 = np.float32
            nv = (dv * (sv / radius)).astype(f32)[:, None]    # scaled, normalised
            nh = (dh / radius).astype(f32)[None, :]
            nv2 = nv * nv
            nh2 = nh * nh
            r2 = nv2 + nh2
            np.minimum(r2, f32(1.0), out=r2)
            fm1 = np.asarray(self.ratio_minus_one(q, r2), dtype=f32)
            disp_v = fm1 * (dv * sub).astype(f32)[:, None]
            disp_h = fm1 * (dh * sub).astype(f32)[None, :]
            del fm1
            if kt0 or kt1:
                cross = f32(2.0) * nv * nh
                t = r2 + f32(2.0) * nv2
                t *= f32(kt0 * sub * radius / sv)
                t += cross * f32(kt1 * sub * radius / sv)
                disp_v += t
                t = r2 + f32(2.0) * nh2
                t *= f32(kt1 * sub * radius)
                t += cross * f32(kt0 * sub * radius)
                disp_h += t
                del t, cross
            del r2, nv2, nh2
            for disp in (disp_v, disp_h):      # far outside is as good as clipped
                big = float(1 << 24)
                np.nan_to_num(disp, copy=False, nan=0.0, posinf=big, neginf=-big)
                np.clip(disp, -big, big, out=disp)
                np.floor(disp, out=disp)
        # 32 x the source position in the data: destination pixel plus the
        # truncated displacement (exact integers in float32 below 2^24)
        qv = (disp_v + (SUBPIXELS * (y - oy)).astype(disp_v.dtype)[:, None]).astype(np.int32)
        qh = (disp_h + (SUBPIXELS * (x - ox)).astype(disp_h.dtype)[None, :]).astype(np.int32)
        parts = []
        for qa, n in ((qv, shape[0]), (qh, shape[1])):
            if n >= 5:
                # clipped to the image (the window held), and the SDK's edge:
                # its 4-tap window (from the pixel before) is kept inside
                # [0, n - 5] by moving it and dropping the fraction, so the
                # first pixel reads pixel 1 and the last three read pixel
                # n - 4 (dng_filter_warp::ProcessArea)
                qa = np.maximum(qa, SUBPIXELS)
                qa = np.where(qa >= SUBPIXELS * (n - 3), SUBPIXELS * (n - 4), qa)
            else:
                qa = np.clip(qa, 0, SUBPIXELS * (n - 1))
            parts.append((qa >> 5, qa & (SUBPIXELS - 1)))
        (whole_v, frac_v), (whole_h, frac_h) = parts
        shape2 = np.broadcast_shapes(qv.shape, qh.shape)
        map1 = np.empty(shape2 + (2,), np.int16)
        map1[..., 0] = whole_h
        map1[..., 1] = whole_v
        map2 = np.empty(shape2, np.uint16)
        np.add(frac_v * SUBPIXELS, frac_h, out=map2, casting="unsafe")
        return map1, map2

    def apply(self, data: np.ndarray, ctx: OpcodeContext) -> np.ndarray:
        """The warped image: a new float32 array the shape of ``data``.

        Each plane is resampled at its source positions
        (:meth:`source_positions`, clipped to the image and to the window
        held), truncated to 1/32 pixel, with the bicubic kernel of the SDK
        (OpenCV ``remap`` ``INTER_CUBIC``, the border replicated). Planes
        whose coefficients are the identity are copied; planes that share
        coefficients are resampled together. Not clipped to [0, 1] (the
        SDK pins its float result there).
        """
        self._check_apply(data, ctx)
        import cv2

        bad = [v for v in self._coefficients() if not math.isfinite(v)]
        if bad:
            raise OpcodeError(f"non-finite coefficient(s) {bad[:4]}", name=self.name)

        data = np.asarray(data, dtype=np.float32)
        h, w = data.shape[:2]
        if max(h, w) >= 32767:
            raise OpcodeError(f"{w}x{h} pixels: the remap handles images below 32767 pixels "
                              "a side", name=self.name)
        image_size = ctx.size(data.shape)
        src = data if data.ndim == 3 else data[:, :, None]
        out = np.empty_like(data)
        dst = out if out.ndim == 3 else out[:, :, None]
        groups: dict[tuple, list[int]] = {}
        identity = [self._is_identity(self._plane_index(p)) for p in range(data_planes(data))]
        for p in range(data_planes(data)):
            q = self._plane_index(p)
            if identity[p]:
                dst[:, :, p] = src[:, :, p]
                if not all(identity):
                    _sdk_edges(dst[:, :, p])
            else:
                groups.setdefault(self._plane_key(q), []).append(p)
        cols = np.arange(w, dtype=np.float64)
        for planes in groups.values():
            if len(planes) == src.shape[2]:
                image = np.ascontiguousarray(data)
            else:
                image = np.ascontiguousarray(src[:, :, planes])
                if len(planes) == 1:
                    image = image[:, :, 0]
            for r0 in range(0, h, _BAND_ROWS):
                r1 = min(h, r0 + _BAND_ROWS)
                with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                    # extreme coefficients overflow to positions far outside: clipped
                    map1, map2 = self._fixed_maps(np.arange(r0, r1, dtype=np.float64), cols,
                                                  ctx, planes[0], data.shape, image_size)
                res = cv2.remap(image, map1, map2, cv2.INTER_CUBIC,
                                borderMode=cv2.BORDER_REPLICATE)
                dst[r0:r1, :, planes] = res.reshape(r1 - r0, w, len(planes))
        return out


@dataclass(frozen=True, repr=False)
class WarpRectilinear(_Warp):
    """Radial and tangential distortion of a rectilinear lens (ID 1).

    Parameters: uint32 N planes (1 or the image's colour planes); per plane
    float64 kr0, kr1, kr2, kr3 (radial, r^0..r^6) and kt0, kt1
    (tangential); then float64 cx, cy, the optical centre relative to the
    image (0..1, 0 = left/top edge).

    Attributes
    ----------
    radial : tuple of N (kr0, kr1, kr2, kr3)
    tangential : tuple of N (kt0, kt1)
    center_x, center_y : float
        Optical centre, fractions of the image width and height.
    """

    ID = 1
    radial: tuple
    tangential: tuple
    center_x: float = 0.5
    center_y: float = 0.5

    def _validate(self):
        set_field(self, "radial", _plane_rows(self.radial, 4, "radial coefficients"))
        set_field(self, "tangential", _plane_rows(self.tangential, 2, "tangential coefficients"))
        if len(self.tangential) != len(self.radial):
            raise OpcodeError(f"{len(self.radial)} radial but {len(self.tangential)} "
                              "tangential planes")
        set_field(self, "center_x", float(self.center_x))
        set_field(self, "center_y", float(self.center_y))
        check_center(self.center_x, self.center_y)

    @property
    def planes(self) -> int:
        return len(self.radial)

    def _params(self):
        values = [v for kr, kt in zip(self.radial, self.tangential) for v in kr + kt]
        values += [self.center_x, self.center_y]
        return struct.pack(f">I{len(values)}d", self.planes, *values)

    @classmethod
    def _parse(cls, r, size, **header):
        n = _read_warp_planes(r, size, 6, 16, "WarpRectilinear")
        coeffs = [r.f64s(6, "plane coefficients") for _ in range(n)]
        cx, cy = r.f64s(2, "optical centre")
        return cls(tuple(c[:4] for c in coeffs), tuple(c[4:] for c in coeffs), cx, cy,
                   **header)

    def ratio(self, plane, r2):
        """:math:`f(r^2) = k_{r0} + k_{r1} r^2 + k_{r2} r^4 + k_{r3} r^6`
        (DNG 1.7.1.0 ch. 7 WarpRectilinear; SDK
        ``dng_warp_params_radial::EvaluateRatio``)."""
        k0, k1, k2, k3 = self.radial[plane]
        r2 = _as_float(r2)
        return k0 + r2 * (k1 + r2 * (k2 + r2 * k3))

    def ratio_minus_one(self, plane, r2):
        k0, k1, k2, k3 = self.radial[plane]
        r2 = _as_float(r2)
        return (k0 - 1.0) + r2 * (k1 + r2 * (k2 + r2 * k3))

    def _tangential(self, plane):
        return self.tangential[plane]

    def _constant_ratio(self, plane):
        return self.radial[plane][1:] == (0.0, 0.0, 0.0)

    def _is_identity(self, plane):
        return self.radial[plane] == (1.0, 0.0, 0.0, 0.0) and self.tangential[plane] == (0.0, 0.0)

    def _plane_key(self, plane):
        return self.radial[plane] + self.tangential[plane]

    def _describe(self):
        return {"planes": self.planes, "radial": [list(k) for k in self.radial],
                "tangential": [list(k) for k in self.tangential],
                "center": [self.center_x, self.center_y]}


@dataclass(frozen=True, repr=False)
class WarpFisheye(_Warp):
    """Fisheye-to-rectilinear remapping (ID 2).

    Parameters: uint32 N planes; per plane float64 kr0..kr3; then float64
    cx, cy (optical centre relative to the image, 0..1).

    Attributes
    ----------
    radial : tuple of N (kr0, kr1, kr2, kr3)
    center_x, center_y : float
    """

    ID = 2
    radial: tuple
    center_x: float = 0.5
    center_y: float = 0.5

    def _validate(self):
        set_field(self, "radial", _plane_rows(self.radial, 4, "radial coefficients"))
        set_field(self, "center_x", float(self.center_x))
        set_field(self, "center_y", float(self.center_y))
        check_center(self.center_x, self.center_y)

    @property
    def planes(self) -> int:
        return len(self.radial)

    def _params(self):
        values = [v for kr in self.radial for v in kr] + [self.center_x, self.center_y]
        return struct.pack(f">I{len(values)}d", self.planes, *values)

    @classmethod
    def _parse(cls, r, size, **header):
        n = _read_warp_planes(r, size, 4, 16, "WarpFisheye")
        radial = tuple(r.f64s(4, "plane coefficients") for _ in range(n))
        cx, cy = r.f64s(2, "optical centre")
        return cls(radial, cx, cy, **header)

    def ratio(self, plane, r2):
        """With :math:`r = \\sqrt{r^2}` and :math:`\\theta = \\arctan r`:
        :math:`f = \\theta (k_0 + k_1\\theta^2 + k_2\\theta^4 + k_3\\theta^6) / r`,
        1 where :math:`r^2 < 10^{-12}` (DNG 1.7.1.0 ch. 7 WarpFisheye; SDK
        ``dng_warp_params_fisheye::EvaluateRatio``)."""
        k0, k1, k2, k3 = self.radial[plane]
        r2 = _as_float(r2)
        r = np.sqrt(r2)
        t = np.arctan(r)
        t2 = t * t
        with np.errstate(divide="ignore", invalid="ignore"):
            f = t * (k0 + t2 * (k1 + t2 * (k2 + t2 * k3))) / r
        return np.where(r2 < 1e-12, 1.0, f)

    def _plane_key(self, plane):
        return self.radial[plane]

    def _describe(self):
        return {"planes": self.planes, "radial": [list(k) for k in self.radial],
                "center": [self.center_x, self.center_y]}


@dataclass(frozen=True, repr=False)
class WarpRectilinear2(_Warp):
    """Rectilinear warp with 15 radial terms and a valid radius range
    (ID 14, DNG 1.6).

    Parameters (SDK ``dng_opcode_WarpRectilinear2``): uint32 N planes; per
    plane float64 kr0..kr14 (radial polynomial in r, all powers), kt0, kt1
    (tangential), min and max valid radius (0 <= min < max <= 1); then
    float64 cx, cy; then uint32 reciprocal flag (non-zero: the radial
    polynomial gives the reciprocal of the ratio).

    Attributes
    ----------
    radial : tuple of N tuples of 15 float
    tangential : tuple of N (kt0, kt1)
    valid_range : tuple of N (min_radius, max_radius)
    center_x, center_y : float
    reciprocal : int
        The stored uint32 (kept as is for byte-exact round trips).
    """

    ID = 14
    MIN_VERSION = (1, 6, 0, 0)
    RADIAL_TERMS: ClassVar[int] = 15
    radial: tuple
    tangential: tuple
    valid_range: tuple
    center_x: float = 0.5
    center_y: float = 0.5
    reciprocal: int = 0

    def _validate(self):
        set_field(self, "radial", _plane_rows(self.radial, self.RADIAL_TERMS, "radial coefficients"))
        set_field(self, "tangential", _plane_rows(self.tangential, 2, "tangential coefficients"))
        set_field(self, "valid_range", _plane_rows(self.valid_range, 2, "valid radius range"))
        n = len(self.radial)
        if len(self.tangential) != n or len(self.valid_range) != n:
            raise OpcodeError(f"plane counts differ: radial {n}, tangential "
                              f"{len(self.tangential)}, valid range {len(self.valid_range)}")
        for p, (lo, hi) in enumerate(self.valid_range):
            if not 0.0 <= lo < hi <= 1.0:   # SDK dng_warp_params_radial::IsValid
                raise OpcodeError(f"plane {p}: valid radius range ({lo!r}, {hi!r}) "
                                  "must satisfy 0 <= min < max <= 1")
        set_field(self, "center_x", float(self.center_x))
        set_field(self, "center_y", float(self.center_y))
        check_center(self.center_x, self.center_y)
        set_field(self, "reciprocal", as_u32(self.reciprocal, "reciprocal flag"))

    @property
    def planes(self) -> int:
        return len(self.radial)

    def _params(self):
        values = [v for kr, kt, vr in zip(self.radial, self.tangential, self.valid_range)
                  for v in kr + kt + vr]
        values += [self.center_x, self.center_y]
        return (struct.pack(f">I{len(values)}d", self.planes, *values)
                + struct.pack(">I", self.reciprocal))

    @classmethod
    def _parse(cls, r, size, **header):
        n = _read_warp_planes(r, size, cls.RADIAL_TERMS + 4, 20, "WarpRectilinear2")
        k = cls.RADIAL_TERMS
        coeffs = [r.f64s(k + 4, "plane coefficients") for _ in range(n)]
        cx, cy = r.f64s(2, "optical centre")
        reciprocal = r.u32("reciprocal flag")
        return cls(tuple(c[:k] for c in coeffs), tuple(c[k:k + 2] for c in coeffs),
                   tuple(c[k + 2:] for c in coeffs), cx, cy, reciprocal, **header)

    def ratio(self, plane, r2):
        """With r^2 pinned to the plane's valid range [min^2, max^2] and
        :math:`r = \\sqrt{r^2}`: :math:`P(r) = \\sum_{i=0}^{14} k_{ri} r^i`,
        f = P, or 1 / P where the reciprocal flag is set (SDK
        ``dng_warp_params_radial::EvaluateRatio``)."""
        lo, hi = self.valid_range[plane]
        r = np.sqrt(np.clip(_as_float(r2), lo * lo, hi * hi))
        k = self.radial[plane]
        poly = np.full_like(r, k[-1])
        for c in k[-2::-1]:
            poly *= r
            poly += c
        if self.reciprocal:
            with np.errstate(divide="ignore"):
                return 1.0 / poly
        return poly

    def ratio_minus_one(self, plane, r2):
        lo, hi = self.valid_range[plane]
        r = np.sqrt(np.clip(_as_float(r2), lo * lo, hi * hi))
        k = self.radial[plane]
        pm1 = np.full_like(r, k[-1])
        for c in k[-2:0:-1]:
            pm1 *= r
            pm1 += c
        pm1 *= r
        pm1 += k[0] - 1.0                      # P - 1
        if self.reciprocal:
            with np.errstate(divide="ignore", invalid="ignore"):
                return -pm1 / (pm1 + 1.0)       # 1 / P - 1
        return pm1

    def _tangential(self, plane):
        return self.tangential[plane]

    def _constant_ratio(self, plane):
        return not any(self.radial[plane][1:])

    def _is_identity(self, plane):
        return (self.radial[plane] == (1.0,) + (0.0,) * (self.RADIAL_TERMS - 1)
                and self.tangential[plane] == (0.0, 0.0))

    def _plane_key(self, plane):
        return self.radial[plane] + self.tangential[plane] + self.valid_range[plane]

    def _describe(self):
        return {"planes": self.planes, "radial": [list(k) for k in self.radial],
                "tangential": [list(k) for k in self.tangential],
                "valid_range": [list(v) for v in self.valid_range],
                "center": [self.center_x, self.center_y], "reciprocal": self.reciprocal}

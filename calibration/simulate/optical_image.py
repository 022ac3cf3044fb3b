"""The optical image on the sensor: PSFs as pixel-unit kernels, exact
blurred edges, exact sub-pixel coverage of polygons, region tiling.

The image value a pixel integrates (paper eq. 14, before the CFA and the
noise) is, for a scene ``L`` and a PSF ``h``:

.. math::

    I(\\mathbf{x}) = \\int L(\\mathbf{u})\\,K(\\mathbf{x} - \\mathbf{u})\\,d\\mathbf{u},
    \\qquad K = h \\otimes \\frac{1}{a^2}\\,\\mathbb{1}_{[-a/2, a/2]^2}

with the pixel aperture a centred square of side ``a = sqrt(fill factor)``
pixels. A PSF is taken as its samples — point masses ``w_i`` at offsets
``v_i`` (the PSF module's samples sum to 1) — so ``K`` is exactly a sum of
shifted aperture squares, and:

* a **straight edge** (half-plane ``n·(u − p) ≥ 0``) gives, with
  ``d = n·(x − p)`` the signed distance of the pixel centre,
  ``C(d) = Σ_i w_i · F_a(d − n·v_i)`` where ``F_a(s)`` is the fraction of the
  aperture square on the side ``n·a' ≤ s`` — a closed form (below). The
  profile is tabulated on a 1/256-pixel grid (the masses splatted linearly,
  which keeps their mean) and interpolated: exact up to O(δ²) ≈ 1e-5.
  This is the "exact edge-area integral" and costs no 2-D convolution.
* a **polygon** is rendered from the 1-D profiles wherever at most one of
  its edges is within the kernel's reach, and near its vertices from a
  supersampled raster (``s × s`` sub-cells per pixel) whose cells hold the
  exact area fraction covered by the polygon (closed form for one edge,
  Sutherland–Hodgman clipping where two meet), convolved with the kernel
  resampled to the sub-cell pitch and integrated over the aperture.

Closed form of ``F_a``: the projection of a uniform square of side ``a``
onto a unit direction ``n = (n_x, n_y)`` is the sum of two uniform
variables of widths ``p = a|n_x|`` and ``q = a|n_y|``, whose CDF is

.. math::

    F(s) = \\frac{R(s + \\tfrac{p+q}{2}) - R(s + \\tfrac{p-q}{2})
                  - R(s - \\tfrac{p-q}{2}) + R(s - \\tfrac{p+q}{2})}{2pq},
    \\qquad R(t) = \\max(t, 0)^2

(and ``clip(s/p + ½, 0, 1)`` when ``q → 0``). It is also the area fraction
of a square cell cut by a straight line.

Coordinates
-----------
As :mod:`calibration.optics.psf.map` documents them. Sensor pixel coordinates
``(x, y)``: pixel ``[row, col]`` centred at ``x = col``, ``y = row`` (+x right,
+y down; also the convention of :mod:`calibration.sfr.synthetic`). The image
plane is a pure shift and scale of it, **no flip**:
``x_mm = (x − (W−1)/2)·p``, ``y_mm = (y − (H−1)/2)·p`` (+y down the array).
A PSF array (:mod:`calibration.optics.psf.result`: ``data[i, j]`` at image-plane offset
``((j − n//2)·pitch, (i − n//2)·pitch)``) is therefore directly a kernel
on the sensor: offset ``((j − n//2)·q, (i − n//2)·q)`` pixels,
``q = pitch_um / pixel_pitch_um``.

A PSF map's region ``(row, col)`` of a ``rows × cols`` grid covers
``x ∈ [col·W/cols − ½, (col+1)·W/cols − ½)``,
``y ∈ [row·H/rows − ½, (row+1)·H/rows − ½)``
(:meth:`calibration.optics.psf.map.PSFMap.region_of`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calibration.optics.lens import LensError

__all__ = [
    "EdgeProfile",
    "Kernel",
    "KernelBank",
    "aperture_decimate",
    "aperture_fraction",
    "convolve",
    "inward_normals",
    "polygon_coverage",
    "resample_kernel",
]

PROFILE_STEP = 1.0 / 128.0
"""Grid of the tabulated edge profiles, pixels (interpolation error
≈ step²/8 · |C''| ≈ 1e-5 of the step for a 1-px blur)."""

PROFILE_TOL = 1e-9
"""Where an edge profile is within this of 0 or 1 it is taken as exactly so."""

CROP_TOL = 1e-7
"""Energy a kernel may lose at its border when cropped (then renormalised)."""

_CHANNELS = {"R": 0, "G": 1, "B": 2}


class ImagingError(LensError):
    """Invalid imaging input (PSF, scene, geometry); the message names it."""


# -- closed forms ---------------------------------------------------------------

def aperture_fraction(s, nx: float, ny: float, a: float = 1.0) -> np.ndarray:
    """Fraction of a square of side ``a`` (centred at 0) on the side
    ``nx·u + ny·v ≤ s`` of a line (``(nx, ny)`` a unit normal).

    >>> round(float(aperture_fraction(0.0, 0.6, 0.8)), 12), float(aperture_fraction(0.25, 1.0, 0.0))
    (0.5, 0.75)
    """
    s = np.asarray(s, dtype=np.float64)
    p, q = abs(nx) * a, abs(ny) * a
    if p < q:
        p, q = q, p
    if q < 1e-9 * max(p, 1e-300):
        return np.where(s >= 0.5 * p, 1.0, np.where(s <= -0.5 * p, 0.0, np.clip(s / p + 0.5, 0.0, 1.0)))
    hs, hd = 0.5 * (p + q), 0.5 * (p - q)

    def r2(t):
        t = np.maximum(t, 0.0)
        return t * t

    out = (r2(s + hs) - r2(s + hd) - r2(s - hd) + r2(s - hs)) / (2.0 * p * q)
    out = np.clip(out, 0.0, 1.0)
    return np.where(s >= hs, 1.0, np.where(s <= -hs, 0.0, out))   # exact outside the ramp


# -- kernels -----------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Kernel:
    """A PSF on the sensor in pixel units: point masses on a square grid.

    Attributes
    ----------
    data : (m0, m1) ndarray of float64
        Masses summing to 1 (rows +y = down the sensor, columns +x).
    pitch_px : float
        Spacing of the masses, pixels.
    anchor : (row, col)
        Index of the zero offset: ``data[i, j]`` sits at
        ``((j − col)·pitch_px, (i − row)·pitch_px)``.
    """

    data: np.ndarray
    pitch_px: float
    anchor: tuple[int, int]

    @classmethod
    def from_psf_array(cls, data, pitch_um: float, pixel_pitch_um: float, *,
                       crop_tol: float = CROP_TOL) -> Kernel:
        """A kernel from a PSF array in the :mod:`calibration.optics.psf.result` convention
        (rows along +y = down the sensor, centre ``n//2``), cropped to the
        window that keeps all but ``crop_tol`` of its energy and
        renormalised."""
        d = np.asarray(data, dtype=np.float64)
        if d.ndim != 2 or d.shape[0] != d.shape[1]:
            raise ImagingError(f"PSF data must be a square (n, n) array, got shape {d.shape}")
        if not np.all(np.isfinite(d)):
            raise ImagingError("PSF data holds NaN or inf")
        if np.any(d < 0):
            d = np.maximum(d, 0.0)
        tot = d.sum()
        if not tot > 0:
            raise ImagingError("PSF data sums to 0")
        if not (math.isfinite(pitch_um) and pitch_um > 0 and math.isfinite(pixel_pitch_um) and pixel_pitch_um > 0):
            raise ImagingError(f"PSF pitch and pixel pitch must be > 0, got {pitch_um!r} and {pixel_pitch_um!r}")
        n = d.shape[0]
        d = d / tot
        anchor = (n // 2, n // 2)
        r0, r1, c0, c1 = _energy_window(d, crop_tol)
        out = d[r0:r1, c0:c1]
        out = out / out.sum()
        return cls(out, float(pitch_um) / float(pixel_pitch_um), (anchor[0] - r0, anchor[1] - c0))

    @property
    def offsets(self) -> tuple[np.ndarray, np.ndarray]:
        """(dx, dy) offsets of the columns and rows, pixels (+y down)."""
        m0, m1 = self.data.shape
        return ((np.arange(m1) - self.anchor[1]) * self.pitch_px, (np.arange(m0) - self.anchor[0]) * self.pitch_px)

    @property
    def reach(self) -> float:
        """Largest distance of a mass from the zero offset, pixels."""
        dx, dy = self.offsets
        return float(math.hypot(np.abs(dx).max(), np.abs(dy).max()))

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """(mean (x, y), covariance 2×2), pixels."""
        dx, dy = self.offsets
        X, Y = np.meshgrid(dx, dy)
        w = self.data
        mx, my = float((w * X).sum()), float((w * Y).sum())
        cxx = float((w * (X - mx) ** 2).sum())
        cyy = float((w * (Y - my) ** 2).sum())
        cxy = float((w * (X - mx) * (Y - my)).sum())
        return np.array([mx, my]), np.array([[cxx, cxy], [cxy, cyy]])


def _energy_window(d: np.ndarray, tol: float) -> tuple[int, int, int, int]:
    """Smallest [r0:r1, c0:c1] losing at most ``tol`` of the energy (half
    on each axis, split between the two sides)."""
    def bounds(profile):
        c = np.cumsum(profile)
        tot = c[-1]
        lo = int(np.searchsorted(c, 0.25 * tol * tot, side="right"))
        hi = int(np.searchsorted(c, tot * (1.0 - 0.25 * tol), side="left")) + 1
        return max(0, min(lo, len(profile) - 1)), max(lo + 1, min(hi, len(profile)))

    r0, r1 = bounds(d.sum(axis=1))
    c0, c1 = bounds(d.sum(axis=0))
    return r0, r1, c0, c1


def resample_kernel(k: Kernel, pitch_px: float) -> Kernel:
    """The kernel on a grid of spacing ``pitch_px`` with a node at the zero
    offset, conserving energy.

    Coarser grids (``pitch_px ≥ k.pitch_px``): each mass is spread over its
    own cell and each new cell takes the overlap (area rebinning, as
    :meth:`calibration.optics.psf.result.PSF.resample`; it adds the blur of one old cell,
    variance ``q²/12``). Finer grids: band-limited (Whittaker–Shannon)
    interpolation of the samples, ``Σ_i d_i sinc((y − y_i)/q)`` per axis,
    scaled to unit sum — exact for a PSF sampled above its Nyquist rate
    (the interpolant may dip a little below 0 where the PSF is ~0).
    """
    if not pitch_px > 0:
        raise ImagingError(f"pitch must be > 0, got {pitch_px!r}")
    dx, dy = k.offsets
    if abs(pitch_px - k.pitch_px) <= 1e-12 * pitch_px:
        return k
    q = k.pitch_px
    finer = pitch_px < q

    def axis_weights(o: np.ndarray) -> tuple[np.ndarray, int]:
        pad = 3.0 * q if finer else q
        lo = math.floor((o.min() - pad) / pitch_px) - 1
        hi = math.ceil((o.max() + pad) / pitch_px) + 1
        new = np.arange(lo, hi + 1) * pitch_px
        if finer:
            w = np.sinc((new[:, None] - o[None, :]) / q)
        else:
            a0, a1 = o - 0.5 * q, o + 0.5 * q
            b0, b1 = new - 0.5 * pitch_px, new + 0.5 * pitch_px
            w = np.minimum(b1[:, None], a1[None, :]) - np.maximum(b0[:, None], a0[None, :])
            w = np.maximum(w, 0.0) / q
        return w, -lo

    wx, ax = axis_weights(dx)
    wy, ay = axis_weights(dy)
    out = wy @ k.data @ wx.T
    return Kernel(out / out.sum(), float(pitch_px), (ay, ax))


# -- edge profiles -------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class EdgeProfile:
    """Blurred coverage of a half-plane as a function of the signed distance
    of the pixel centre into it (pixels): 0 far outside, 1 far inside.

    Attributes
    ----------
    start : float
        Distance of the first tabulated value, pixels.
    step : float
        Grid step, pixels.
    values : (N,) ndarray
        ``C`` at ``start + k·step``.
    support : (lo, hi)
        ``C`` is exactly 0 below ``lo`` and 1 above ``hi``.
    """

    start: float
    step: float
    values: np.ndarray
    support: tuple[float, float]

    def __call__(self, d) -> np.ndarray:
        d = np.asarray(d, dtype=np.float64)
        x = self.start + self.step * np.arange(self.values.size)
        return np.interp(d, x, self.values, left=0.0, right=1.0)


def _lowpass(step: float, pitch: float) -> np.ndarray:
    """Kaiser-windowed sinc (β = 10, ≈ −100 dB) on a grid of ``step``,
    cut-off ``1/(2·pitch)`` (the Nyquist frequency of the PSF's samples),
    half-length 12 pitches, unit sum."""
    half = math.ceil(12.0 * pitch / step)
    t = np.arange(-half, half + 1) * step
    h = np.sinc(t / pitch) * np.kaiser(2 * half + 1, 10.0)
    return h / h.sum()


def edge_profile(k: Kernel, normal: tuple[float, float], aperture_px: float = 1.0,
                 step: float = PROFILE_STEP) -> EdgeProfile:
    """The profile ``C(d) = Σ_i w_i F_a(d − n·v_i)`` of the module notes,
    band-limited.

    Parameters
    ----------
    k : Kernel
    normal : (nx, ny)
        Unit normal of the edge, pointing into the covered side (sensor
        frame, +y down).
    aperture_px : float
        Side of the square pixel aperture, pixels.
    step : float
        Tabulation grid, pixels.

    Notes
    -----
    The PSF's samples stand for a band-limited intensity (a PSF is
    band-limited by the pupil's autocorrelation, and :mod:`calibration.optics.psf.result`
    samples it at twice the Nyquist rate). Projected on the edge normal
    they are a comb whose spectrum holds, besides the true line spread
    function (``|f| < f_c``), replicas of the 2-D sampling lattice at
    ``|f| ≥ sqrt(1/q² − f_c²)``; near 0° and 45° the comb is coarse and the
    pixel aperture lets those replicas through (an O(q²) error, 1e-3 of the
    step for ``q = ¼`` px at 0°). A low-pass at ``1/(2q)`` (windowed sinc)
    removes them and leaves the band untouched, so the profile is that of
    the band-limited PSF at every angle.
    """
    nx, ny = (float(v) for v in normal)
    nn = math.hypot(nx, ny)
    nx, ny = nx / nn, ny / nn
    dx, dy = k.offsets
    t = (nx * dx[None, :] + ny * dy[:, None]).ravel()
    w = k.data.ravel()
    keep = w != 0
    t, w = t[keep], w[keep]
    filt = _edge_filter(step, k.pitch_px, nx, ny, aperture_px)     # low-pass ⊗ aperture density
    g0 = math.floor(t.min() / step) - 1
    n = math.ceil(t.max() / step) - g0 + 2
    pos = t / step - g0
    i0 = np.floor(pos).astype(np.int64)
    f = pos - i0
    hist = np.bincount(i0, w * (1.0 - f), minlength=n + 1) + np.bincount(i0 + 1, w * f, minlength=n + 1)
    from scipy.signal import fftconvolve

    g = fftconvolve(hist, filt)                                # node (g0 − F + m)·step, F = half filter
    cdf = np.cumsum(g)                                         # C at the node + step/2
    cdf /= cdf[-1]
    start = (g0 - filt.size // 2) * step + 0.5 * step
    values = np.concatenate([[0.0], cdf])
    x0 = start - step
    # beyond these the profile is 0 or 1 to PROFILE_TOL (the low-pass rings a little past the kernel)
    inner = np.nonzero((values > PROFILE_TOL) & (values < 1.0 - PROFILE_TOL))[0]
    if inner.size:
        lo, hi = x0 + (inner[0] - 1) * step, x0 + (inner[-1] + 1) * step
    else:
        lo = hi = x0 + int(np.argmax(values > 0.5)) * step
    return EdgeProfile(x0, step, values, (float(lo), float(hi)))


_FILTERS: dict = {}


def _edge_filter(step: float, pitch: float, nx: float, ny: float, aperture_px: float) -> np.ndarray:
    """The low-pass (:func:`_lowpass`) convolved with the projected
    aperture's density (bin masses of ``F_a``), cached."""
    key = (step, pitch, round(abs(nx), 12), round(abs(ny), 12), aperture_px)
    f = _FILTERS.get(key)
    if f is None:
        half_ap = 0.5 * aperture_px * (abs(nx) + abs(ny))
        jmax = math.ceil(half_ap / step) + 1
        j = np.arange(-jmax, jmax + 1)
        cdf_edges = aperture_fraction((j + 0.5) * step, nx, ny, aperture_px)
        dens = np.diff(np.concatenate([[0.0], cdf_edges]))    # mass of the bin around j·step
        f = np.convolve(_lowpass(step, pitch), dens)
        if len(_FILTERS) > 256:
            _FILTERS.clear()
        _FILTERS[key] = f
    return f


# -- polygons on a sub-cell grid -------------------------------------------------------

def inward_normals(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The half-planes of a convex polygon.

    Parameters
    ----------
    vertices : (K, 2) ndarray
        The polygon's vertices in order (either sense), pixels.

    Returns
    -------
    normals : (K, 2) ndarray
        Unit normals of the sides, pointing inside.
    offsets : (K,) ndarray
        ``c`` with ``n·u − c ≥ 0`` inside, pixels.

    Raises
    ------
    ImagingError
        The polygon is not convex or has repeated vertices.
    """
    v = np.asarray(vertices, dtype=np.float64)
    e = np.roll(v, -1, axis=0) - v
    n = np.column_stack([-e[:, 1], e[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    centre = v.mean(axis=0)
    sign = np.sign(np.einsum("ij,ij->i", n, centre - v))
    if np.any(sign == 0) or not (np.all(sign > 0) or np.all(sign < 0)):
        raise ImagingError("polygon must be convex with distinct vertices")
    n *= sign[:, None]
    c = np.einsum("ij,ij->i", n, v)
    return n, c


def _clip_area(cx: float, cy: float, h: float, normals: np.ndarray, offsets: np.ndarray) -> float:
    """Area of the square cell (centre, side h) inside all half-planes
    ``n·u ≥ c`` (Sutherland–Hodgman)."""
    poly = [(cx - h / 2, cy - h / 2), (cx + h / 2, cy - h / 2), (cx + h / 2, cy + h / 2), (cx - h / 2, cy + h / 2)]
    for (nx, ny), c in zip(normals, offsets):
        out = []
        m = len(poly)
        for i in range(m):
            p, q = poly[i], poly[(i + 1) % m]
            fp, fq = nx * p[0] + ny * p[1] - c, nx * q[0] + ny * q[1] - c
            if fp >= 0:
                out.append(p)
            if (fp >= 0) != (fq >= 0):
                t = fp / (fp - fq)
                out.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
        poly = out
        if not poly:
            return 0.0
    a = 0.0
    for i in range(len(poly)):
        x0, y0 = poly[i]
        x1, y1 = poly[(i + 1) % len(poly)]
        a += x0 * y1 - x1 * y0
    return abs(a) / 2.0


def polygon_coverage(vertices, x0: float, y0: float, nx: int, ny: int, step: float) -> np.ndarray:
    """Exact fraction of each cell of a grid covered by a convex polygon.

    Parameters
    ----------
    vertices : (K, 2) array_like
        (x, y) in pixels.
    x0, y0 : float
        Centre of cell [0, 0].
    nx, ny : int
        Cells across and down.
    step : float
        Cell side (and spacing), pixels.

    Returns
    -------
    (ny, nx) ndarray of float64 in [0, 1].

    >>> cov = polygon_coverage([(0, 0), (2, 0), (2, 2), (0, 2)], -0.25, -0.25, 3, 3, 1.0)
    >>> cov.round(4).tolist()
    [[0.0625, 0.25, 0.1875], [0.25, 1.0, 0.75], [0.1875, 0.75, 0.5625]]
    """
    normals, offsets = inward_normals(vertices)
    xs = x0 + step * np.arange(nx)
    ys = y0 + step * np.arange(ny)
    cov = np.ones((ny, nx))
    partial = np.zeros((ny, nx), dtype=np.int8)
    for (a, b), c in zip(normals, offsets):
        half = 0.5 * step * (abs(a) + abs(b))
        # d is linear: its extremes over the grid are at the grid's corners
        dc = [a * x + b * y - c for x in (xs[0], xs[-1]) for y in (ys[0], ys[-1])]
        if min(dc) >= half:
            continue                                        # the whole grid is inside this edge
        if max(dc) <= -half:
            return np.zeros((ny, nx))                       # ... or outside it
        d = a * xs[None, :] + b * ys[:, None] - c
        band = np.abs(d) < half
        cov[d <= -half] = 0.0
        if band.any():
            f = aperture_fraction(d[band], -a, -b, step)   # the part with n·u ≥ c
            cov[band] *= f
            partial[band] += ((f > 0) & (f < 1)).astype(np.int8)
    for i, j in zip(*np.nonzero(partial > 1)):
        cov[i, j] = _clip_area(xs[j], ys[i], step, normals, offsets) / (step * step)
    return cov


# -- convolution and aperture ------------------------------------------------------

def convolve(src: np.ndarray, k: Kernel) -> np.ndarray:
    """``out[y, x] = Σ k.data[i, j] · src[y − (i − ai), x − (j − aj)]``: the
    kernel's masses as offsets on ``src``'s grid (which must have the
    kernel's pitch). Borders replicate ``src``'s edge; callers pad by the
    kernel's reach and crop. Uses ``cv2.filter2D`` (a DFT for large
    kernels)."""
    import cv2

    data, (ar, ac) = k.data, k.anchor
    if not (0 <= ar < data.shape[0] and 0 <= ac < data.shape[1]):   # cv2 wants the anchor inside
        pr0, pc0 = max(0, -ar), max(0, -ac)
        pr1, pc1 = max(0, ar - data.shape[0] + 1), max(0, ac - data.shape[1] + 1)
        data = np.pad(data, ((pr0, pr1), (pc0, pc1)))
        ar, ac = ar + pr0, ac + pc0
    kd = np.ascontiguousarray(data[::-1, ::-1])
    m0, m1 = kd.shape
    anchor = (m1 - 1 - ac, m0 - 1 - ar)      # cv2: (x, y)
    a = np.ascontiguousarray(src, dtype=np.float64)
    if m0 > a.shape[0] or m1 > a.shape[1]:                    # cv2 wants the image at least as large
        py, px = max(0, m0 - a.shape[0]), max(0, m1 - a.shape[1])
        big = np.pad(a, ((0, py), (0, px)), mode="edge")
        return cv2.filter2D(big, cv2.CV_64F, kd, anchor=anchor, borderType=cv2.BORDER_REPLICATE)[:a.shape[0], :a.shape[1]]
    return cv2.filter2D(a, cv2.CV_64F, kd, anchor=anchor, borderType=cv2.BORDER_REPLICATE)


def fold_aperture(k: Kernel, s: int, aperture_px: float = 1.0) -> Kernel:
    """The kernel (pitch ``1/s`` pixel) convolved with the aperture's
    ``s``-tap sub-cell weights along both axes, anchored so that sub-cell
    ``p·s + anchor`` of the full convolution of a sub-cell field with it is
    the aperture-integrated value of pixel ``p`` (see
    :func:`blur_decimate`; the weights are symmetric)."""
    w = aperture_weights(s, aperture_px)

    def along(a: np.ndarray, axis: int) -> np.ndarray:
        shape = list(a.shape)
        shape[axis] += s - 1
        out = np.zeros(shape)
        for t in range(s):
            sl = [slice(None)] * 2
            sl[axis] = slice(t, t + a.shape[axis])
            out[tuple(sl)] += w[t] * a
        return out

    kk = along(along(k.data, 0), 1)
    return Kernel(kk, k.pitch_px, (k.anchor[0] + s - 1, k.anchor[1] + s - 1))


def fft_shape_for(field_shape: tuple[int, int], folded: list, s: int, keep: tuple[int, int, int, int]) -> tuple:
    """Smallest fast FFT shape for which the circular convolution of a
    field of ``field_shape`` sub-cells with the ``folded`` kernels is exact
    at the pixels ``keep = (row0, row1, col0, col1)`` (the others wrap)."""
    from scipy import fft as sfft

    out = []
    for ax, (p0, p1) in enumerate(((keep[0], keep[1]), (keep[2], keep[3]))):
        n_f = max(f.data.shape[ax] for f in folded)
        a_min = min(f.anchor[ax] for f in folded)
        a_max = max(f.anchor[ax] for f in folded)
        n0, n1 = p0 * s + a_min, (p1 - 1) * s + a_max
        out.append(sfft.next_fast_len(max(n1 + 1, field_shape[ax] + n_f - 1 - n0), True))
    return tuple(out)


def blur_decimate(field_s: np.ndarray, kernels: list, s: int, aperture_px: float = 1.0,
                  *, folded: list | None = None, spectra: list | None = None, shape=None) -> list:
    """``aperture_decimate(convolve(field_s, k), s, aperture_px)`` for each
    kernel ``k`` (all of pitch ``1/s`` pixel), by FFT: one forward
    transform of the field, the aperture folded into each kernel
    (:func:`fold_aperture`, or given as ``folded``), the pixels taken by
    stride. ``spectra`` (the folded kernels' ``rfft2`` at ``shape``) may be
    passed to reuse them. Pixels within a kernel's reach of the field's
    edge see zeros beyond it (callers pad)."""
    from scipy import fft as sfft

    ny, nx = field_s.shape[0] // s, field_s.shape[1] // s
    if folded is None:
        folded = [fold_aperture(k, s, aperture_px) for k in kernels]
    if shape is None:
        my = max(f.data.shape[0] for f in folded)
        mx = max(f.data.shape[1] for f in folded)
        shape = (sfft.next_fast_len(field_s.shape[0] + my - 1, True),
                 sfft.next_fast_len(field_s.shape[1] + mx - 1, True))
    spec = sfft.rfft2(field_s.astype(np.float32), shape, workers=-1)   # float32: ~1e-7, twice as fast
    out = []
    for i, f in enumerate(folded):
        ks = spectra[i] if spectra is not None else sfft.rfft2(f.data.astype(np.float32), shape, workers=-1)
        full = sfft.irfft2(spec * ks, shape, workers=-1).astype(np.float64)
        r0, c0 = f.anchor
        rows = (np.arange(ny) * s + r0) % shape[0]         # a short ``shape`` wraps the unused pixels
        cols = (np.arange(nx) * s + c0) % shape[1]
        out.append(full[np.ix_(rows, cols)])
    return out


def aperture_weights(s: int, aperture_px: float) -> np.ndarray:
    """(s,) weights of a pixel's ``s`` sub-cells under a centred aperture of
    side ``aperture_px`` (≤ 1), summing to 1."""
    edges = (np.arange(s + 1) / s) - 0.5
    lo, hi = -0.5 * aperture_px, 0.5 * aperture_px
    w = np.clip(np.minimum(edges[1:], hi) - np.maximum(edges[:-1], lo), 0.0, None)
    return w / w.sum()


def aperture_decimate(field_s: np.ndarray, s: int, aperture_px: float = 1.0) -> np.ndarray:
    """Pixel values from a sub-cell field (``s × s`` cells per pixel):
    the aperture-weighted mean of each pixel's cells."""
    ny, nx = field_s.shape[0] // s, field_s.shape[1] // s
    w = aperture_weights(s, aperture_px)
    f = field_s[:ny * s, :nx * s].reshape(ny, s, nx, s)
    return np.einsum("iajb,a,b->ij", f, w, w, optimize=True)


# -- kernel banks: PSFs or PSF maps, duck-typed ---------------------------------------------

@dataclass(eq=False)
class KernelBank:
    """The kernels of a PSF (one region) or a PSF map (``rows × cols``
    regions), per colour channel, with caches of their edge profiles and
    resampled forms.

    Build with :meth:`from_psf`. Anything with ``data`` and ``pitch_um``
    is a PSF; anything with ``psfs`` (rows, cols, channels, n, n),
    ``pitch_um`` and ``channels`` a PSF map (``sensor.pixel_pitch_um``,
    ``width_px``, ``height_px`` are used when present).
    """

    psfs: np.ndarray                  # (rows, cols, channels, n, n), calibration.optics.psf.result convention
    pitch_um: float
    channel_index: tuple[int, int, int]   # PSF channel used for R, G, B
    pixel_pitch_um: float
    size_px: tuple[int, int] | None = None  # (H, W) the map's regions divide
    aperture_px: float = 1.0
    _kernels: dict = field(default_factory=dict)
    _profiles: dict = field(default_factory=dict)
    _resampled: dict = field(default_factory=dict)

    @classmethod
    def from_psf(cls, psf, *, pixel_pitch_um: float | None = None, size_px: tuple[int, int] | None = None,
                 aperture_px: float = 1.0) -> KernelBank:
        """Bank of a PSF object, a list/tuple of three PSFs (R, G, B), or a
        PSF map (see the class notes)."""
        if hasattr(psf, "psfs"):
            arr = np.asarray(psf.psfs, dtype=np.float64)
            if arr.ndim != 5 or arr.shape[3] != arr.shape[4]:
                raise ImagingError(f"PSF map psfs must be (rows, cols, channels, n, n), got {arr.shape}")
            names = tuple(getattr(psf, "channels", ("R", "G", "B")[:arr.shape[2]]))
            sens = getattr(psf, "sensor", None)
            if pixel_pitch_um is None and sens is not None:
                pixel_pitch_um = float(sens.pixel_pitch_um)
            if size_px is None and sens is not None:
                size_px = (int(sens.height_px), int(sens.width_px))
            pitch = float(psf.pitch_um)
        elif isinstance(psf, (list, tuple)):
            if len(psf) != 3:
                raise ImagingError(f"give one PSF or three (R, G, B), got {len(psf)}")
            pitches = {float(p.pitch_um) for p in psf}
            if len(pitches) != 1:
                raise ImagingError(f"the three PSFs must share one pitch, got {sorted(pitches)}")
            n = {np.asarray(p.data).shape for p in psf}
            if len(n) != 1:
                raise ImagingError(f"the three PSFs must share one size, got {sorted(n)}")
            arr = np.stack([np.asarray(p.data, dtype=np.float64) for p in psf])[None, None]
            names, pitch = ("R", "G", "B"), pitches.pop()
        elif hasattr(psf, "data") and hasattr(psf, "pitch_um"):
            arr = np.asarray(psf.data, dtype=np.float64)[None, None, None]
            names, pitch = ("mono",), float(psf.pitch_um)
        else:
            raise ImagingError(f"not a PSF or PSF map: {type(psf).__name__} (needs data and pitch_um, or psfs)")
        if pixel_pitch_um is None:
            raise ImagingError("pixel_pitch_um is needed to put the PSF on the sensor (give it, or a sensor)")
        if len(names) != arr.shape[2]:
            raise ImagingError(f"{len(names)} channel names for {arr.shape[2]} PSF channels")
        if arr.shape[2] == 1:
            idx = (0, 0, 0)
        else:
            try:
                idx = tuple(names.index(c) for c in ("R", "G", "B"))
            except ValueError:
                raise ImagingError(f"PSF map channels {names} lack one of R, G, B") from None
        return cls(arr, pitch, idx, float(pixel_pitch_um), size_px, float(aperture_px))

    @property
    def grid(self) -> tuple[int, int]:
        return self.psfs.shape[0], self.psfs.shape[1]

    def kernel(self, region: tuple[int, int], channel: int) -> Kernel:
        """Kernel of region ``(row, col)`` for colour ``channel`` (0 R, 1 G, 2 B)."""
        key = (int(region[0]), int(region[1]), int(channel))
        if key not in self._kernels:
            r, c, ch = key
            self._kernels[key] = Kernel.from_psf_array(self.psfs[r, c, self.channel_index[ch]], self.pitch_um,
                                                       self.pixel_pitch_um)
        return self._kernels[key]

    def profile(self, region, channel: int, normal) -> EdgeProfile:
        key = (int(region[0]), int(region[1]), int(channel), round(float(normal[0]), 12), round(float(normal[1]), 12))
        if key not in self._profiles:
            self._profiles[key] = edge_profile(self.kernel(region, channel), normal, self.aperture_px)
        return self._profiles[key]

    def resampled(self, region, channel: int, pitch_px: float) -> Kernel:
        key = (int(region[0]), int(region[1]), int(channel), float(pitch_px))
        if key not in self._resampled:
            self._resampled[key] = resample_kernel(self.kernel(region, channel), pitch_px)
        return self._resampled[key]

    def folded(self, region, channel: int, s: int) -> Kernel:
        """The kernel at pitch ``1/s`` with the pixel aperture folded in."""
        key = ("fold", int(region[0]), int(region[1]), int(channel), int(s))
        if key not in self._resampled:
            self._resampled[key] = fold_aperture(self.resampled(region, channel, 1.0 / s), s, self.aperture_px)
        return self._resampled[key]

    def reach(self, region) -> float:
        """Largest kernel reach over the channels of a region, pixels."""
        return max(self.kernel(region, c).reach for c in range(3))

    # -- regions -------------------------------------------------------------
    def _size(self, size_px) -> tuple[int, int]:
        s = size_px if size_px is not None else self.size_px
        if s is None:
            if self.grid == (1, 1):
                return (1, 1)
            raise ImagingError("the sensor size is needed to locate PSF map regions")
        return (int(s[0]), int(s[1]))

    def region_at(self, x: float, y: float, size_px=None) -> tuple[int, int]:
        """Region holding pixel coordinates (x, y) (centres at integers)."""
        rows, cols = self.grid
        h, w = self._size(size_px) if (rows, cols) != (1, 1) else (1, 1)
        r = min(max(math.floor((y + 0.5) * rows / h), 0), rows - 1)
        c = min(max(math.floor((x + 0.5) * cols / w), 0), cols - 1)
        return r, c

    def axis_weights(self, axis: int, coords: np.ndarray, blend: str, size_px=None) -> list[tuple[int, np.ndarray]]:
        """Per region index along ``axis`` (0 rows, 1 cols): its weight at
        pixel coordinates ``coords`` (centres at integers), for
        ``blend="nearest"`` (the region holding the pixel) or ``"bilinear"``
        (tents between region centres, flat beyond the outermost ones).
        Only regions with a nonzero weight somewhere are returned."""
        n = self.grid[axis]
        if n == 1:
            return [(0, np.ones(coords.shape))]
        size = self._size(size_px)[axis]
        pos = (np.asarray(coords, dtype=np.float64) + 0.5) * n / size   # in region units
        out = []
        for k in range(n):
            if blend == "nearest":
                w = (np.clip(np.floor(pos), 0, n - 1) == k).astype(np.float64)
            elif blend == "bilinear":
                t = pos - (k + 0.5)
                w = np.maximum(0.0, 1.0 - np.abs(t))
                if k == 0:
                    w = np.where(t < 0, 1.0, w)
                if k == n - 1:
                    w = np.where(t > 0, 1.0, w)
            else:
                raise ImagingError(f"unknown blend {blend!r}; valid: 'nearest', 'bilinear'")
            if np.any(w > 0):
                out.append((k, w))
        return out

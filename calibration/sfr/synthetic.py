"""Exact slanted edges with a known MTF: the analytic oracle of the SFR tests.

A straight edge at angle ``θ`` from vertical, blurred by an isotropic
Gaussian PSF of standard deviation ``σ`` (pixels) and integrated over the
square pixel aperture (100 % fill factor), rendered without approximation:

.. math::

    I(x, y) = L + (H - L) \\iint_{\\text{pixel}(x, y)}
              \\Phi\\!\\left(\\frac{d(u, v)}{\\sigma}\\right) du\\,dv,
    \\qquad d(u, v) = (u - c_x)\\cos\\theta - (v - c_y)\\sin\\theta

(``Φ`` the standard normal CDF, ``d`` the signed distance to the edge, pixel
centres at integer coordinates). The integral over ``u`` is closed-form
(:math:`\\int \\Phi = t\\Phi(t) + \\varphi(t)`); the one over ``v`` is a
16-node Gauss–Legendre rule on an integrand that is smooth on the scale
``σ / sin θ`` — together exact to ~1e-12 of the step (checked against ×64
supersampling in ``tests/calibration/sfr/test_esfr.py``).

The modulation transfer along the edge normal is that of the 2-D PSF
(Gaussian ⊗ pixel box) on the line of direction ``θ``:

.. math::

    \\mathrm{MTF}(f) = e^{-2\\pi^2\\sigma^2 f^2}\\,
                       |\\mathrm{sinc}(f\\cos\\theta)\\,\\mathrm{sinc}(f\\sin\\theta)|

(``f`` in cycles per pixel along the normal; ``sinc(x) = sin(πx)/(πx)``).
For small angles this is ``exp(−2π²σ²f²)·|sinc f|``, the form usually quoted.
This module is the *test oracle* for :mod:`calibration.sfr.esfr`; the general edge
imaging (lens PSFs, Bayer sampling, Poisson–Gaussian noise) lives elsewhere.

References
----------
ISO 12233:2023, *Photography — Electronic still picture imaging — Resolution
and spatial frequency responses*, Annex D (e-SFR), and the pixel-aperture
MTF of a square detector (e.g. Boreman, *Modulation Transfer Function in
Optical and Electro-Optical Systems*, SPIE 2001, ch. 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

__all__ = ["ChartEdge", "SquareChart", "edge_mtf", "mtf50_of", "render_slanted_edge", "render_square_chart"]

_GL_X, _GL_W = np.polynomial.legendre.leggauss(16)
_INV_SQRT_2PI = 1.0 / np.sqrt(2.0 * np.pi)


def _int_phi(t: np.ndarray) -> np.ndarray:
    """Antiderivative of the normal CDF: ``t Φ(t) + φ(t)``."""
    return t * ndtr(t) + _INV_SQRT_2PI * np.exp(-0.5 * t * t)


def render_slanted_edge(
    shape: tuple[int, int],
    angle_deg: float,
    sigma_px: float,
    *,
    low: float = 0.2,
    high: float = 0.8,
    center: tuple[float, float] | None = None,
    horizontal: bool = False,
) -> np.ndarray:
    """Render a Gaussian-blurred slanted edge integrated over square pixels.

    Parameters
    ----------
    shape : (H, W) tuple of int
        Image size in pixels.
    angle_deg : float
        Edge angle from vertical (from horizontal if ``horizontal``), degrees,
        in (−45, 45]. Positive: the edge moves right (down) as rows (columns)
        increase.
    sigma_px : float
        Standard deviation of the Gaussian PSF in pixels, > 0.
    low, high : float
        Levels far on the left (top) and right (bottom) side of the edge; any
        order, so ``low > high`` gives a bright→dark edge.
    center : (x, y) tuple of float, optional
        A point on the edge in pixel coordinates (pixel centres at integers);
        default: the image centre.
    horizontal : bool
        Render a near-horizontal edge (the transpose of a vertical one).

    Returns
    -------
    (H, W) ndarray of float64
        Pixel values between ``low`` and ``high``.

    Examples
    --------
    >>> img = render_slanted_edge((8, 16), 5.0, 1.0)
    >>> img.shape, bool(img[:, 0].max() < 0.21), bool(img[:, -1].min() > 0.79)
    ((8, 16), True, True)
    """
    h, w = int(shape[0]), int(shape[1])
    if sigma_px <= 0:
        raise ValueError(f"sigma_px must be > 0, got {sigma_px}")
    if horizontal:
        c = None if center is None else (center[1], center[0])
        return render_slanted_edge((w, h), angle_deg, sigma_px, low=low, high=high, center=c).T
    cx, cy = ((w - 1) / 2.0, (h - 1) / 2.0) if center is None else center
    th = np.deg2rad(angle_deg)
    a, b = np.cos(th), np.sin(th)
    x = np.arange(w, dtype=np.float64)[None, :, None]
    # Gauss–Legendre nodes inside each pixel row [y − ½, y + ½].
    v = np.arange(h, dtype=np.float64)[:, None, None] + 0.5 * _GL_X[None, None, :]
    base = (-(v - cy) * b - cx * a) / sigma_px  # d/σ at u = 0
    t_hi = base + (x + 0.5) * (a / sigma_px)
    t_lo = base + (x - 0.5) * (a / sigma_px)
    frac = (sigma_px / a) * (_int_phi(t_hi) - _int_phi(t_lo))  # ∫ Φ du over the pixel row
    area = 0.5 * (frac @ _GL_W)
    return low + (high - low) * area


def edge_mtf(freq, sigma_px: float, angle_deg: float = 0.0) -> np.ndarray:
    """True MTF of :func:`render_slanted_edge` along the edge normal.

    Parameters
    ----------
    freq : array_like
        Spatial frequency in cycles per pixel (along the edge normal).
    sigma_px : float
        Gaussian PSF standard deviation, pixels.
    angle_deg : float
        Edge angle from the pixel axis, degrees.

    Returns
    -------
    ndarray
        ``exp(−2π²σ²f²)·|sinc(f cos θ)·sinc(f sin θ)|``, in [0, 1].

    Examples
    --------
    >>> round(float(edge_mtf(0.0, 1.0)), 6)
    1.0
    """
    f = np.asarray(freq, dtype=np.float64)
    th = np.deg2rad(angle_deg)
    return np.exp(-2.0 * np.pi**2 * sigma_px**2 * f * f) * np.abs(
        np.sinc(f * np.cos(th)) * np.sinc(f * np.sin(th))
    )


def mtf50_of(sigma_px: float, angle_deg: float = 0.0, *, pixel_aperture: bool = True) -> float:
    """Frequency (cycles/pixel) where the true MTF falls to 0.5.

    ``pixel_aperture=False`` gives the Gaussian alone,
    ``sqrt(ln 2 / (2π²σ²))``.

    Examples
    --------
    >>> round(mtf50_of(1.0, 5.0), 5)
    0.17996
    >>> round(mtf50_of(1.0, pixel_aperture=False), 5)
    0.18739
    """
    if not pixel_aperture:
        return float(np.sqrt(np.log(2.0) / (2.0 * np.pi**2 * sigma_px**2)))
    lo, hi = 0.0, 1.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if edge_mtf(mid, sigma_px, angle_deg) > 0.5:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class ChartEdge:
    """One side of a square of :func:`render_square_chart`.

    Attributes
    ----------
    centre : (x, y)
        The side's midpoint, pixels (pixel centres at integers).
    angle_deg : float
        Its angle from the nearest pixel axis, degrees, in [0, 45].
    orientation : {"vertical", "horizontal"}
        The pixel axis it is near.
    length : float
        Side length, pixels.
    mtf50 : float
        True MTF50 along its normal, cycles/pixel (:func:`mtf50_of`).
    square : int
        Index of its square.
    """

    centre: tuple[float, float]
    angle_deg: float
    orientation: str
    length: float
    mtf50: float
    square: int


@dataclass(frozen=True)
class SquareChart:
    """A rendered chart: the image and every square side with its truth."""

    image: np.ndarray
    edges: tuple[ChartEdge, ...]
    sigma_px: float
    pixel_aperture: bool


def render_square_chart(
    shape: tuple[int, int],
    grid: tuple[int, int] = (9, 13),
    *,
    sigma_px: float = 1.2,
    angles_deg=(5.0,),
    side: float = 0.55,
    low: float = 0.2,
    high: float = 0.8,
    pixel_aperture: bool = True,
    nodes: int = 6,
) -> SquareChart:
    """A chart of dark slanted squares on a light ground, rendered exactly:
    the analytic oracle for chart tools (edge finding and per-edge SFR).

    Each square, rotated by its angle about its centre, is blurred by an
    isotropic Gaussian PSF of ``sigma_px``. In the square's own frame
    ``(u, v)`` the Gaussian's mass inside it is separable,

    .. math::

        P(u, v) = [\\Phi(\\tfrac{a-u}{\\sigma}) - \\Phi(\\tfrac{-a-u}{\\sigma})]
                  [\\Phi(\\tfrac{a-v}{\\sigma}) - \\Phi(\\tfrac{-a-v}{\\sigma})]

    (``a`` the half side), corners included. With ``pixel_aperture`` each
    pixel is the mean of ``P`` over its square (a ``nodes × nodes``
    Gauss–Legendre rule; 6 nodes are exact to ~1e-9 of the step for
    σ ≥ 0.6 px), without it ``P`` at the pixel centre (a point-sampled
    image, the form many chart generators write). Squares do not overlap:
    each owns its grid cell, and a pixel takes the mass of every square
    within 8σ of it.

    Parameters
    ----------
    shape : (H, W)
        Image size, pixels.
    grid : (rows, cols)
        One square per cell.
    sigma_px : float
        Gaussian PSF standard deviation, pixels, > 0.
    angles_deg : sequence of float
        Rotation of each square in turn (cycled), degrees; its sides are
        that far from the pixel axes (modulo 90°).
    side : float
        Square side as a fraction of the smaller cell dimension, (0, 0.8].
    low, high : float
        Level of the squares and of the ground.
    pixel_aperture : bool
        Integrate over each pixel (a 100 % fill-factor sensor) or sample
        at its centre.
    nodes : int
        Gauss–Legendre nodes per pixel axis (with ``pixel_aperture``).

    Returns
    -------
    SquareChart
        ``image`` (H, W) float64 between ``low`` and ``high``; ``edges``
        the four sides of every square with their true MTF50
        (:func:`mtf50_of` at the side's angle, with or without the pixel
        aperture).

    Examples
    --------
    >>> ch = render_square_chart((120, 160), (1, 1), sigma_px=1.0, angles_deg=(5.0,))
    >>> len(ch.edges), round(ch.edges[0].mtf50, 5), ch.edges[0].orientation
    (4, 0.17996, 'vertical')
    >>> float(ch.image[0, 0]), round(float(ch.image[60, 80]), 6)
    (0.8, 0.2)
    """
    from scipy.special import ndtr

    h, w = int(shape[0]), int(shape[1])
    rows, cols = int(grid[0]), int(grid[1])
    if sigma_px <= 0:
        raise ValueError(f"sigma_px must be > 0, got {sigma_px}")
    if rows < 1 or cols < 1 or not 0 < side <= 0.8:
        raise ValueError(f"need a grid of at least 1 × 1 and 0 < side ≤ 0.8; got {grid!r}, {side!r}")
    angles = [float(a) for a in np.atleast_1d(angles_deg)]
    cw, ch = w / cols, h / rows
    half = 0.5 * side * min(cw, ch)
    if half < 4 * sigma_px:
        raise ValueError(f"squares of {2 * half:.1f} px are too small for σ = {sigma_px} px")
    if pixel_aperture:
        gx, gw = np.polynomial.legendre.leggauss(int(nodes))
        offs, wts = 0.5 * gx, 0.5 * gw
    else:
        offs, wts = np.zeros(1), np.ones(1)
    img = np.full((h, w), float(high))
    reach = 8.0 * sigma_px
    edges = []
    k = 0
    for r in range(rows):
        for c in range(cols):
            cx, cy = (c + 0.5) * cw - 0.5, (r + 0.5) * ch - 0.5
            ang = angles[k % len(angles)]
            th = np.deg2rad(ang)
            co, si = np.cos(th), np.sin(th)
            ext = half * (abs(co) + abs(si)) + reach + 1
            y0, y1 = max(0, int(np.floor(cy - ext))), min(h, int(np.ceil(cy + ext)) + 1)
            x0, x1 = max(0, int(np.floor(cx - ext))), min(w, int(np.ceil(cx + ext)) + 1)
            ys = np.arange(y0, y1, dtype=np.float64)[:, None] - cy
            xs = np.arange(x0, x1, dtype=np.float64)[None, :] - cx
            u = xs * co + ys * si
            v = -xs * si + ys * co
            du, dv = np.abs(u) - half, np.abs(v) - half
            near = (np.maximum(du, dv) > -reach - 1) & (np.maximum(du, dv) < reach + 1)
            inside = np.maximum(du, dv) <= 0
            mass = np.where(inside, 1.0, 0.0)
            py, px = np.nonzero(near)
            if py.size:
                yy = ys[py, 0][:, None, None] + offs[None, :, None]
                xx = xs[0, px][:, None, None] + offs[None, None, :]
                uu = (xx * co + yy * si) / sigma_px
                vv = (-xx * si + yy * co) / sigma_px
                a = half / sigma_px
                p = (ndtr(a - uu) - ndtr(-a - uu)) * (ndtr(a - vv) - ndtr(-a - vv))
                mass[py, px] = np.einsum("nij,i,j->n", p, wts, wts)
            img[y0:y1, x0:x1] -= (high - low) * mass
            m50 = mtf50_of(sigma_px, ang, pixel_aperture=pixel_aperture)
            fold = abs((ang + 45.0) % 90.0 - 45.0)
            for sx, sy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                ex = cx + half * (sx * co - sy * si)
                ey = cy + half * (sx * si + sy * co)
                # a side whose normal is near x runs near the y axis: a vertical edge
                nx = abs(sx * co - sy * si)
                orient = "vertical" if nx > 0.7071 else "horizontal"
                edges.append(ChartEdge((float(ex), float(ey)), float(fold), orient, 2 * half, float(m50), k))
            k += 1
    return SquareChart(img, tuple(edges), float(sigma_px), bool(pixel_aperture))

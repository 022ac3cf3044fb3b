"""Numerical core of the ISO 12233 e-SFR: edge location, projection, SFR.

The steps of ISO 12233:2023 Annex D as implemented by Burns' sfrmat3/4/5
(the reference code of the standard), written anew and vectorised. The
public entry points are in :mod:`calibration.sfr.esfr`, which validates input,
orients the edge and adds warnings; this module assumes a near-vertical edge
whose values *rise* along +x once multiplied by ``sign``.

Samples are given as ``values`` (R, M), sample ``j`` of row ``r`` at column
``x0[r] + dx·j`` (``dx = 2`` and alternating ``x0`` on the green quincunx of
a Bayer mosaic), rows at ``rows`` (R,). Positions are pixel-centre
coordinates (0-based, pixel centres at integers).

Steps (sfrmat5 function names in brackets):

1. per row, the derivative ``[−0.5, 0.5]`` of neighbouring samples, the
   first replaced by the second and the last repeated (``deriv1``);
2. its centroid under a window centred on the ROI (``centroid``), a fit
   ``x = p(row)`` of order 1–5 (``findedge2``), then the centroid again
   under a window centred on each row's fitted edge, and the final fit; the
   windows are Tukey α = 1 scaled ``0.95·w + 0.05`` (``tukey2``) or Hamming
   (``ahamming``); a linear fit is always kept for the angle and trimming;
3. rows trimmed to whole phase cycles, ``round(floor(R·|s|)/|s|)`` (the
   first rows kept);
4. projection along the edge into ``1/oversampling``-px bins, empty bins
   filled from their neighbours (``project2``);
5. LSF = ESF ⊛ [0.5, 0, −0.5], ends repeated;
6. LSF shifted so its peak is mid-array (``cent``), times the window:
   symmetric Hann (``"tukey"``: sfrmat5's Tukey α = 1, *not* rescaled) or
   Hamming (``"hamming"``: sfrmat3/4, sfrmat5 with ``wflag = 1``);
7. ``|DFT| / DC``, times the derivative correction ``fir2fix(nn2, 3)``:
   ``x / sin x`` with ``x = π(k+1)/(nn2+1)`` for ``k ≥ 1``, capped at 10;
8. frequencies ``k / (nn·Δ)`` with ``Δ = cos(atan s) / oversampling`` pixels,
   the bin spacing along the edge normal, ``s`` the linear slope.

Four departures from the standard are available, all off by default (the
``"accurate"`` method of :func:`calibration.sfr.esfr.measure_sfr`):

* :func:`refine_edge` — after step 2, per-row centroids under a window a few
  LSF widths wide around the fit (sfrmat's spans the whole row), refitted;
* :func:`binning_correction` — the SFR divided by the transfer function of
  step 4, the mean phasor of the samples' offsets from their bin centres
  (``sinc(fΔ)`` for uniform offsets), which ISO 12233 leaves in;
* :func:`apodize_lsf` — in step 6, the LSF kept within a few widths of the
  edge (:func:`adaptive_window`) and only low-pass filtered beyond, instead
  of the record-length window;
* ``derivative_correction(nn2, nn)`` — step 7 at the true frequency
  ``x = 2πk/nn`` instead of fir2fix's ``2π(k+1)/(nn+4)``.

Notes
-----
This reproduces sfrmat5 to rounding (max |ΔSFR| 4e-16 on the two reference
edges, both windows, fit orders 1 and 5, against a line-by-line port). The
one departure: rows without a positive derivative centroid inside the row
are left out of the edge fit (sfrmat5 would fit their NaN); the caller
refuses the ROI when more than a fifth of its rows are such.

References
----------
ISO 12233:2023 (4th ed.), Annex D, "Edge-based spatial frequency response".
P. D. Burns, sfrmat5 (2023) and sfrmat3 (2009), BSD licence,
http://losburns.com/imaging/software/SFRedge/ .
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import as_strided

__all__ = [
    "LSF_WINDOWS",
    "WINDOWS",
    "EdgeFit",
    "adaptive_window",
    "apodize_lsf",
    "area_to",
    "area_weights",
    "binning_correction",
    "binning_transfer",
    "crossing",
    "derivative_correction",
    "esf_to_sfr",
    "interp_at",
    "locate_edge",
    "lsf_extent",
    "mean_of",
    "mround",
    "output_length",
    "poly_compose_linear",
    "polyval",
    "project_esf",
    "refine_edge",
    "transition_width",
]

#: LSF windows by name: sfrmat5's default (Tukey α=1, i.e. Hann) and sfrmat3/4's Hamming.
WINDOWS = ("tukey", "hamming")

#: LSF window extents: sfrmat5's window over the whole record, or one that follows the LSF.
LSF_WINDOWS = ("full", "adaptive")

#: sfrmat caps the derivative correction at this factor (and the binning correction here).
MAX_DERIVATIVE_CORRECTION = 10.0

#: Adaptive LSF window (:func:`apodize_lsf`), in units of the ESF's 10–90 % rise
#: distance ``w``: flat (weight 1) over the LSF's significant structure
#: (:func:`lsf_extent`) and at least ``LSF_FLAT·w`` either side of the edge, then a
#: raised-cosine taper over a further ``LSF_TAPER·w``; at least ``LSF_MIN_PX`` px
#: each. On a side where the structure reaches past that least flat top it fades
#: out below the threshold there (a sharpening halo's tail, a glare halo), and the
#: taper is the longer ``LSF_TAIL_TAPER·w``, at least ``LSF_TAIL_MIN_PX`` px. So
#: the window is narrower only where the LSF is compact: against 1.5·w, 1·w and
#: 2 px throughout, the MTF50 of Gaussian edges (σ 0.6–2 px, 100 rows, SNR 120)
#: scatters 2–5 % less, for the same error noise-free.
LSF_FLAT = 1.0
LSF_TAPER = 0.75
LSF_MIN_PX = 1.0
LSF_TAIL_TAPER = 1.0
LSF_TAIL_MIN_PX = 2.0
#: :func:`refine_edge`'s centroid window, the same shape: flat ``ADAPTIVE_FLAT·w``,
#: taper ``ADAPTIVE_TAPER·w``, at least ``ADAPTIVE_MIN_PX`` px each.
ADAPTIVE_FLAT = 1.5
ADAPTIVE_TAPER = 1.0
ADAPTIVE_MIN_PX = 2.0
#: Beyond the flat top and taper the LSF is smoothed by a Gaussian of
#: ``ADAPTIVE_SMOOTH·w`` (at least ``ADAPTIVE_MIN_PX``), see :func:`apodize_lsf`.
ADAPTIVE_SMOOTH = 1.0
#: :func:`lsf_extent` keeps LSF structure above this fraction of the peak (and 4× its noise).
EXTENT_FLOOR = 0.01

#: Cells per bin of the histogram of within-bin sample offsets (binning transfer).
_OFFSET_CELLS = 64
#: Longest edge-finding window kept in :func:`_tukey2_table` (4 MB), samples.
_MAX_CACHED_WINDOW = 1024


def mround(x):
    """MATLAB ``round``: halves away from zero."""
    return np.sign(x) * np.floor(np.abs(x) + 0.5)


def _mround_int(x: float) -> int:
    """``int(mround(x))`` for a scalar."""
    r = math.floor(abs(x) + 0.5)
    return r if x >= 0 else -r


@dataclass(frozen=True)
class EdgeFit:
    """``x = Σ coef[i]·row**i`` (ascending powers, pixel coordinates), plus the
    linear fit kept for the angle and the row trimming."""

    coef: np.ndarray
    coef_linear: np.ndarray
    rms: float

    @property
    def slope(self) -> float:
        """dx/drow of the linear fit."""
        return float(self.coef_linear[1])

    def __call__(self, rows) -> np.ndarray:
        return polyval(self.coef, rows)


def polyval(coef: np.ndarray, x):
    """``Σ coef[i]·x**i`` (ascending coefficients), by Horner's rule."""
    x = np.asarray(x, dtype=np.float64)
    if len(coef) == 1:
        return np.full(x.shape, coef[0], dtype=np.float64)
    out = np.multiply(x, coef[-1], out=np.empty(x.shape))
    for c in coef[-2:0:-1]:
        out += c
        out *= x
    out += coef[0]
    return out if out.ndim else out[()]


def poly_compose_linear(coef: np.ndarray, a: float, b: float) -> np.ndarray:
    """Ascending coefficients of ``p(a·t + b)``."""
    out = [0.0] * len(coef)
    for i, c in enumerate(np.asarray(coef, dtype=np.float64).tolist()):  # (a t + b)^i = Σ_k C(i,k) a^k b^(i−k) t^k
        for k in range(i + 1):
            out[k] += c * math.comb(i, k) * a**k * b ** (i - k)
    return np.array(out)


def _fit(rows: np.ndarray, loc: np.ndarray, order: int) -> np.ndarray:
    """Least-squares polynomial ``loc = p(rows)``, fitted on centred and
    scaled rows (as sfrmat5's ``polyfit`` with ``mu``), returned unscaled,
    ascending."""
    n = rows.size
    mu = float(np.add.reduce(rows)) / n  # the sums of ndarray.mean and .std, without their overhead
    dev = rows - mu
    sd = math.sqrt(float(np.add.reduce(dev * dev)) / n) or 1.0
    t = dev / sd
    v = np.empty((n, order + 1))  # np.vander(t, order + 1, increasing=True)
    v[:, 0] = 1.0
    v[:, 1] = t
    for i in range(2, order + 1):
        np.multiply(v[:, i - 1], t, out=v[:, i])
    ct = np.linalg.lstsq(v, loc, rcond=None)[0]
    return poly_compose_linear(ct, 1.0 / sd, -mu / sd)


def _clip(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """``np.clip(x, lo, hi)`` of a float array, in place, without its overhead."""
    return np.minimum(np.maximum(x, lo, out=x), hi, out=x)


def mean_of(x: np.ndarray) -> float:
    """``x.mean()`` of a non-empty array (the same sum), without its overhead
    (a measurement takes a few dozen means of small arrays).

    >>> bool(mean_of(np.array([1.0, 2.0, 4.0])) == np.array([1.0, 2.0, 4.0]).mean())
    True
    """
    return float(np.add.reduce(x, axis=None)) / x.size


def _median(x: np.ndarray) -> float:
    """``np.median`` of a non-empty 1-D float array (the same order
    statistics and mean), without its overhead."""
    n = x.size
    h = n // 2
    part = np.partition(x, [h, n - 1] if n % 2 else [h - 1, h, n - 1])
    if np.isnan(part[-1]):
        return float("nan")
    return float(part[h]) if n % 2 else (float(part[h - 1]) + float(part[h])) / 2.0


def _hann_at(i: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Symmetric Hann window of length ``n`` (Tukey α = 1) at index ``i``."""
    return 0.5 - 0.5 * np.cos(2.0 * np.pi * i / np.maximum(n - 1, 1))


def _edge_window(m: int, mid: np.ndarray, kind: str) -> np.ndarray:
    """Edge-finding windows over sample indices ``1..m`` centred at ``mid``
    (R, 1), 1-based as in sfrmat5: ``tukey2(m, 1, mid)`` scaled
    ``0.95·w + 0.05``, or ``ahamming(m, mid)``."""
    i = np.arange(1, m + 1, dtype=np.float64)[None, :]
    if kind == "hamming":
        mid = mid + 0.5
        wid = np.maximum(np.maximum(mid - 1.0, m - mid), 1e-9)
        return 0.54 + 0.46 * np.cos(np.pi * (i - mid) / wid)
    n2 = np.floor(2.0 * np.maximum(mid, m - mid) + 0.5)  # mround of a positive length
    # tukey2: the first m samples of a length-n2 window, or the last m.
    first = mid >= m / 2.0
    longest = np.maximum.reduce(n2, axis=None)
    if longest <= _MAX_CACHED_WINDOW:  # false for NaN, which takes the direct form
        return _tukey2_rows(m, n2.ravel(), first.ravel(), int(longest))
    j = np.where(first, i - 1.0, i - 1.0 + n2 - m)
    return 0.95 * _hann_at(j, n2) + 0.05


@functools.lru_cache(maxsize=64)
def _centred_window(m: int, kind: str) -> np.ndarray:
    """:func:`_edge_window` centred on the row, (1, m), read-only: the
    first centroid pass's, the same for every ROI ``m`` samples wide."""
    w = _edge_window(m, np.full((1, 1), (m + 1) / 2.0), kind)
    w.flags.writeable = False
    return w


def _tukey2_rows(m: int, n2: np.ndarray, first: np.ndarray, longest: int) -> np.ndarray:
    """(R, m) rows of :func:`_edge_window`'s Tukey windows: row ``r`` is the
    first (``first[r]``) or last ``m`` values of :func:`_tukey2_scaled`
    ``(n2[r])``, read from :func:`_tukey2_table` (``n2 ≤ longest``)."""
    table = _tukey2_table(longest)
    start = n2 * (n2 - 1) / 2 + np.where(first, 0.0, n2 - m)
    rows = as_strided(table, (table.size - m + 1, m), table.strides * 2, writeable=False)  # rows[i] = table[i:i + m]
    return rows[start.astype(np.intp)]


_TUKEY2_TABLE = [np.zeros(0)]


def _tukey2_table(longest: int) -> np.ndarray:
    """:func:`_tukey2_scaled` of every length 1, 2, … up to at least
    ``longest`` (≤ :data:`_MAX_CACHED_WINDOW`), back to back, length ``n``
    from ``n(n − 1)/2`` on; computed once and extended when a longer one is
    asked for."""
    table = _TUKEY2_TABLE[0]
    if table.size < longest * (longest + 1) // 2:
        top = min(max(2 * longest, 256), _MAX_CACHED_WINDOW)
        table = np.concatenate([_tukey2_scaled(n) for n in range(1, top + 1)])
        table.flags.writeable = False
        _TUKEY2_TABLE[0] = table
    return table


def _tukey2_scaled(n2: int) -> np.ndarray:
    """``0.95·w + 0.05`` for the symmetric Hann window ``w`` of ``n2`` points."""
    return 0.95 * _hann_at(np.arange(n2, dtype=np.float64), np.float64(n2)) + 0.05


def _centroids(deriv: np.ndarray, win: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """sfrmat ``centroid(c .* win) − 0.5``: 1-based centroid index minus ½,
    i.e. the position in sample units where sample ``j`` (0-based) of the
    derivative sits at ``j + ½``."""
    wd = deriv * win
    den = np.add.reduce(wd, axis=1)
    idx = np.arange(1, deriv.shape[1] + 1, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        loc = (wd @ idx) / den - 0.5
    return loc, den


def locate_edge(
    values: np.ndarray,
    x0: np.ndarray,
    dx: float,
    rows: np.ndarray,
    sign: float,
    order: int,
    window: str,
) -> tuple[EdgeFit, np.ndarray, np.ndarray]:
    """Edge position per row by windowed derivative centroids, twice, and
    the polynomial fit ``x = p(row)``.

    Parameters
    ----------
    values : (R, M) ndarray of float
        Samples, one row per line along the edge; sample ``j`` of row ``r``
        lies at column ``x0[r] + dx·j``.
    x0 : (R,) ndarray of float
        Column of each row's first sample.
    dx : float
        Sample spacing along the rows, pixels (1, or 2 on a Bayer quincunx).
    rows : (R,) ndarray of float
        Row coordinate of each line.
    sign : {+1, −1}
        Multiplies the derivative so that the edge is a positive peak.
    order : int
        Polynomial order of the final fit, 1–5.
    window : {"tukey", "hamming"}
        Edge-finding window.

    Returns
    -------
    fit : EdgeFit
        Final fit and the linear fit (on the rows with a valid centroid).
    loc : (R,) ndarray
        Per-row edge positions, pixels (NaN where no centroid exists).
    valid : (R,) bool ndarray
        Rows whose centroid exists and lies inside the row.

    Notes
    -----
    As sfrmat5 (``deriv1`` with ``conv(…, 'same')``): the derivative keeps
    ``M`` samples, the first replaced by the second and the last repeated;
    the windows and centroids work in sample indices.
    """
    m = values.shape[1]
    d = (0.5 * sign) * (values[:, 1:] - values[:, :-1])
    deriv = np.concatenate([d[:, 1:2], d[:, 1:], d[:, -1:]], axis=1) if m > 2 else np.repeat(d, 2, 1)
    x0c = np.asarray(x0, dtype=np.float64)

    def fit_from(win):
        q, den = _centroids(deriv, win)
        return q, (den > 0) & (q >= 0.0) & (q <= m)  # NaN and ±inf fail the bounds

    def bad():
        return EdgeFit(np.full(order + 1, np.nan), np.full(2, np.nan), np.nan)

    q, valid = fit_from(_centred_window(m, window))
    if np.count_nonzero(valid) < order + 2:
        return bad(), x0c + dx * q, valid
    coef = _fit(rows[valid], (x0c + dx * q)[valid], order)
    place = (polyval(coef, rows) - x0c) / dx
    q, valid = fit_from(_edge_window(m, place[:, None], window))
    loc = x0c + dx * q
    if np.count_nonzero(valid) < order + 2:
        return bad(), loc, valid
    coef = _fit(rows[valid], loc[valid], order)
    coef1 = coef if order == 1 else _fit(rows[valid], loc[valid], 1)
    resid = loc[valid] - polyval(coef, rows[valid])
    rms = math.sqrt(mean_of(resid * resid))
    return EdgeFit(coef, coef1, rms), loc, valid


def refine_edge(
    values: np.ndarray,
    x0: np.ndarray,
    dx: float,
    rows: np.ndarray,
    sign: float,
    fit: EdgeFit,
    order: int,
    width_px: float,
    *,
    passes: int = 2,
) -> tuple[EdgeFit, np.ndarray, np.ndarray]:
    """Refit the edge from derivative centroids under a narrow window around
    a first fit (not in ISO 12233).

    Parameters
    ----------
    values, x0, dx, rows, sign, order
        As :func:`locate_edge`.
    fit : EdgeFit
        First fit (e.g. :func:`locate_edge`'s).
    width_px : float
        10–90 % rise distance of the ESF along the rows, pixels; the window
        is :func:`adaptive_window`'s shape around ``fit(row)`` with this width
        (flat to ``max(1.5·w, 2 px)``, taper ``max(w, 2 px)``).
    passes : int
        Centroid-and-fit rounds, each centred on the previous fit.

    Returns
    -------
    fit, loc, valid
        As :func:`locate_edge`.

    Notes
    -----
    sfrmat's centroid window spans the whole row, so every row's edge
    position carries the noise of every sample times its distance from the
    edge, and the window centred on the ROI pulls it towards the middle:
    0.37 px rms per row at SNR 60 on 128 px (σ = 0.5–2 px), against
    0.05–0.12 px under a window a few LSF widths wide (the Cramér–Rao bound
    is ≈ 0.02 px at σ = 0.5 px). The slope error ``δs`` shifts the rows'
    ESFs against one another by up to ``±δs·R/2`` and so blurs the projected
    ESF — an MTF *loss*, growing with the ROI length ``R`` because the
    whole-row centroid's angle error falls only as ``R^−0.76`` (0.072° at
    100 rows, 0.033° at 300; refined: 0.012°, 0.002° at σ = 0.5 px); at
    300 rows, SNR 60, it took 0.4 % off MTF50 on average at σ = 0.5 px, and
    2.8 % in the worst case of the sweep.
    """
    nlin, m = values.shape
    x0c = np.broadcast_to(np.asarray(x0, dtype=np.float64), (nlin,))
    a = max(ADAPTIVE_FLAT * width_px, ADAPTIVE_MIN_PX)
    b = max(ADAPTIVE_TAPER * width_px, ADAPTIVE_MIN_PX)
    band = min(m - 1, math.ceil(2.0 * (a + b) / dx) + 3)  # derivative samples the window can reach
    lo_x = x0c + 0.5 * dx
    hi_x = x0c + dx * (m - 1.5)
    coef = fit.coef
    loc = np.full(nlin, np.nan)
    valid = np.zeros(nlin, dtype=bool)
    # derivative sample j (0-based) lies half-way between samples j and j + 1
    deriv = ((0.5 * sign) * (values[:, 1:] - values[:, :-1])).ravel()
    row_start = (np.arange(nlin) * (m - 1))[:, None]
    for _ in range(max(1, passes)):
        p = polyval(coef, rows)
        j0 = _clip(np.floor((p - x0c - a - b) / dx - 0.5), 0, m - 1 - band)
        j = j0.astype(np.intp)[:, None] + np.arange(band)
        d = deriv.take(row_start + j)
        xs = x0c[:, None] + dx * (j + 0.5)
        t = np.abs(xs - p[:, None])
        t -= a
        t /= b
        wd = _raised_cosine(_clip(t, 0.0, 1.0)) * d
        den = np.add.reduce(wd, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            loc = np.add.reduce(wd * xs, axis=1) / den
        valid = (den > 0) & (loc >= lo_x) & (loc <= hi_x)  # NaN and ±inf fail the bounds
        if np.count_nonzero(valid) < order + 2:
            return fit, loc, valid
        coef = _fit(rows[valid], loc[valid], order)
    coef1 = coef if order == 1 else _fit(rows[valid], loc[valid], 1)
    resid = loc[valid] - polyval(coef, rows[valid])
    return EdgeFit(coef, coef1, math.sqrt(mean_of(resid * resid))), loc, valid


def project_esf(
    values: np.ndarray,
    xs: np.ndarray,
    rows: np.ndarray,
    fit: EdgeFit,
    oversampling: int,
    nn: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Project samples along the edge into ``1/oversampling``-px bins
    (sfrmat5 ``project2``).

    With ``p2(row) = p(row) − p(rows[0])``, ``c1`` the linear coefficient of
    the fit and ``o = round(−oversampling·(R−1)·c1)``, sample ``(row, x)``
    goes to bin ``ceil((x − p2)·oversampling) − min(o, 0) − round(|o|/2)``,
    so that the ``nn`` bins are centred on the sheared rows. Empty bins take
    the mean of their neighbours' counts and sums, in order (the first from
    the next bin, the last from the previous), as sfrmat5.

    Returns
    -------
    esf : (nn,) ndarray
        Mean sample value per bin.
    counts : (nn,) ndarray of int
        Samples per bin before filling (0 = filled).
    u : ndarray, shape of ``values``
        Distance of every sample from the edge along its row, pixels.
    uc : (nn,) ndarray
        Bin centres in the same coordinate.
    """
    nlin = values.shape[0]
    edge = fit(rows)[:, None]
    p0 = float(edge[0, 0])
    u = xs - edge
    c1 = float(fit.coef[1])
    off = _mround_int(-oversampling * (nlin - 1) * c1)
    k0 = min(off, 0) + _mround_int(abs(off) / 2.0)
    # ceil(t) for t = (x − p2)·os; bin k ↔ t ∈ (k + k0 − 1, k + k0].
    t = u + p0
    t *= oversampling
    np.ceil(t, out=t)
    # bins −1 and nn are kept for sfrmat's neighbour filling, at k + 2; samples
    # beyond them are counted apart, in bins 0 and nn + 3
    k = t.ravel()
    k -= k0 - 2
    k = _clip(k, 0, nn + 3).astype(np.intp)
    counts = np.bincount(k, minlength=nn + 4)[1:-1].astype(np.float64)
    sums = np.bincount(k, weights=values.ravel(), minlength=nn + 4)[1:-1]
    raw_counts = counts[1 : nn + 1].astype(np.int64)
    empty = (raw_counts == 0).nonzero()[0] + 1
    if empty.size == 0:
        esf = sums[1 : nn + 1] / counts[1 : nn + 1]
    else:
        esf = _fill_empty(counts, sums, empty)
    uc = (np.arange(nn) + k0 - 0.5) / oversampling - p0
    return esf, raw_counts, u, uc


def _fill_empty(counts: np.ndarray, sums: np.ndarray, empty: np.ndarray) -> np.ndarray:
    """ESF of bins ``1 … nn`` of ``counts`` and ``sums`` (bins ``0`` and
    ``nn + 1`` being the neighbours outside), the ``empty`` ones filled as
    sfrmat5: each takes the mean of its neighbours' counts and sums, in
    order, so that earlier fills feed later ones (the last bin takes the
    previous one's); what stays empty is interpolated."""
    nn = counts.size - 2
    for i in empty:
        if i == nn:
            counts[i], sums[i] = counts[i - 1], sums[i - 1]
        else:
            counts[i] = 0.5 * (counts[i - 1] + counts[i + 1])
            sums[i] = 0.5 * (sums[i - 1] + sums[i + 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        esf = sums[1 : nn + 1] / counts[1 : nn + 1]
    good = np.isfinite(esf)
    if good.any() and not good.all():
        esf = np.interp(np.arange(nn), np.flatnonzero(good), esf[good])
    return esf


def output_length(nn: int, oversampling: int) -> int:
    """Number of SFR values sfrmat returns for an ``nn``-bin record: about
    1 cycle/pixel (2 for ``oversampling = 1``).

    Examples
    --------
    >>> output_length(512, 4)
    129
    """
    freqlim = 2 if oversampling == 1 else 1
    return _mround_int((nn // 2 + 1) * freqlim / 2.0)


def derivative_correction(nn2: int, nn: int | None = None) -> np.ndarray:
    """Correction for the response of the 3-tap derivative, capped at 10.

    Without ``nn``: sfrmat's ``fir2fix(nn2, 3)``, ``x/sin x`` with
    ``x = π(k+1)/(nn2+1)`` for frequency index ``k ≥ 1`` (1 at ``k = 0``).
    With ``nn`` (the record length): the exact inverse response of
    ``[0.5, 0, −0.5]`` at ``f = k/(nn·Δ)``, ``x = 2πfΔ = 2πk/nn``.
    sfrmat's index is one step high on a grid of ``nn + 4``
    (``x = 2π(k+1)/(nn+4)``), which over-corrects by
    ``≈ x²/3 · (nn − 4k)/(k·(nn + 4))``: +0.1 % at MTF50 of 128-px ROIs.

    Examples
    --------
    >>> c = derivative_correction(5)
    >>> float(c[0]), round(float(c[1]), 4)
    (1.0, 1.2092)
    >>> round(float(derivative_correction(5, 8)[1]), 4)     # x = π/4
    1.1107
    """
    k = np.arange(nn2, dtype=np.float64)
    x = np.pi * (k + 1.0) / (nn2 + 1.0) if nn is None else 2.0 * np.pi * k / nn
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.abs(x / np.sin(x))
    c[0] = 1.0
    return np.minimum(np.where(np.isfinite(c), c, MAX_DERIVATIVE_CORRECTION), MAX_DERIVATIVE_CORRECTION)


def binning_transfer(u: np.ndarray, uc: np.ndarray, oversampling: int, nfreq: int) -> np.ndarray:
    """Transfer function of the projection into bins, from the samples' own
    positions inside their bins.

    Parameters
    ----------
    u : ndarray
        Distance of every sample from the edge along its row, pixels (as
        returned by :func:`project_esf`).
    uc : (nn,) ndarray
        Bin centres in the same coordinate, spacing ``1/oversampling``.
    oversampling : int
        Bins per pixel.
    nfreq : int
        Number of frequencies ``k/(nn·Δ)``, ``k = 0 … nfreq−1``, to return.

    Returns
    -------
    (nfreq,) ndarray
        ``|H(k/(nn·Δ))|``, 1 at DC, in (0, 1].

    Notes
    -----
    Bin ``b`` holds the mean of the ``n_b`` samples in it, each at offset
    ``δ_i ∈ (−½, ½]`` bins from the bin centre to which the mean is
    assigned: the ESF is averaged over the offsets, so a component
    ``exp(2πi f x)`` of it comes out multiplied by
    ``(1/n_b) Σ_i exp(2πi f Δ δ_i)`` (``Δ`` the bin width along the edge
    normal). Averaged over the ``N`` filled bins,

    .. math::

        H(f) = \\Big|\\frac{1}{N}\\sum_b \\frac{1}{n_b}
               \\sum_{i \\in b} e^{2\\pi i f \\Delta \\delta_i}\\Big|,
        \\qquad f\\Delta = k/nn .

    Offsets spread uniformly over the bin give ``sinc(fΔ)`` (a box of width
    ``Δ``); ``m`` equally spaced phases give the Dirichlet kernel
    ``sin(πfΔ)/(m·sin(πfΔ/m))``; an angle with few phases (near 0°, 14°,
    26.6°) gives its own, closer to 1. The offsets are pooled in a
    histogram of 64 cells per bin, each at its mean offset with a
    second-order term for its spread (error < 1e-7).
    ISO 12233 and sfrmat leave this factor in the SFR (at ¼-px bins it is
    ``sinc(f·cos θ/4)``: 0.974 at Nyquist, 0.903 at 1 cycle/pixel).

    Examples
    --------
    >>> uc = (np.arange(400) - 199.5) / 4
    >>> u = np.linspace(-50, 50, 40001)           # uniform offsets in every bin
    >>> h = binning_transfer(u, uc, 4, 201)
    >>> round(float(h[100]), 4), round(float(np.sinc(100 / 400)), 4)
    (0.9003, 0.9003)
    """
    nn = uc.size
    t = np.asarray(u, dtype=np.float64).ravel() - uc[0]
    t *= oversampling
    k = t - 0.5
    np.ceil(k, out=k)
    d = t - k  # in (−½, ½ + ulp]
    # bin k at k + 1; 0 and nn + 1 hold the samples outside the record, of weight 0
    k += 1.0
    b = _clip(k, 0, nn + 1).astype(np.intp)
    n_b = np.bincount(b, minlength=nn + 2).astype(np.float64)
    if n_b[0] + n_b[-1] == t.size:
        return np.ones(nfreq)
    inv = 1.0 / np.maximum(n_b, 1.0)
    inv[0] = inv[-1] = 0.0
    w = inv[b]
    x = d + 0.5
    x *= _OFFSET_CELLS
    cell = np.minimum(x, _OFFSET_CELLS - 1, out=x).astype(np.intp)
    # the samples of a row share a cell: sum runs of equal cells first
    run = np.concatenate([[0], (cell[1:] != cell[:-1]).nonzero()[0] + 1])
    wd = w * d
    cell = cell[run]
    h = np.bincount(cell, weights=np.add.reduceat(w, run), minlength=_OFFSET_CELLS)
    hd = np.bincount(cell, weights=np.add.reduceat(wd, run), minlength=_OFFSET_CELLS)
    hdd = np.bincount(cell, weights=np.add.reduceat(wd * d, run), minlength=_OFFSET_CELLS)
    used = h > 0
    h, dm = h[used], hd[used] / h[used]
    hv = np.maximum(hdd[used] - h * dm * dm, 0.0)  # weight × variance inside each cell
    nu = np.arange(nfreq, dtype=np.float64) / nn
    # Σ w·exp(iφ) over a cell = h·exp(iφ̄)·(1 − 2π²ν²·var + O(ν⁴var²))
    damp = 2.0 * np.pi**2 * nu * nu
    re, im = _phase_sums(dm, np.array([h, hv]), nfreq, nn)
    return np.hypot(re[0] - damp * re[1], im[0] - damp * im[1]) / np.add.reduce(h)


def _phase_sums(x: np.ndarray, g: np.ndarray, n: int, nn: int) -> tuple[np.ndarray, np.ndarray]:
    """``Σ_c g[w, c]·cos φ_kc`` and ``Σ_c g[w, c]·sin φ_kc``, (W, n) each,
    with ``φ_kc = 2π·k·x_c/nn``, ``k = 0 … n−1``.

    With ``k = q + r``, ``q`` a multiple of ``s = ⌊√n⌋`` and ``0 ≤ r < s``,
    ``e^{iφ} = e^{iφ_q}·e^{iφ_r}``: the sums are products of (q, c) and
    (c, r) matrices, and only about ``2√n`` rows of sines and cosines are
    evaluated (the sums agree with direct evaluation within a few ulp)."""
    step = max(1, math.isqrt(n))
    q = np.arange(0, n, step)
    ph = (2.0 * np.pi / nn) * np.multiply.outer(np.concatenate([q, np.arange(step)]), x)
    c, s = np.cos(ph), np.sin(ph)
    nq = q.size
    coarse = np.concatenate([c[:nq], s[:nq]])[None, :, :] * g[:, None, :]  # (W, 2q, c): cos, sin
    m = coarse @ np.concatenate([c[nq:], s[nq:]]).T  # (W, 2q, 2r): products with cos, sin of φ_r
    re = m[:, :nq, :step] - m[:, nq:, step:]
    im = m[:, nq:, :step] + m[:, :nq, step:]
    return re.reshape(len(g), -1)[:, :n], im.reshape(len(g), -1)[:, :n]


def binning_correction(u: np.ndarray, uc: np.ndarray, oversampling: int, nfreq: int) -> np.ndarray:
    """``1 / binning_transfer(…)``, capped at 10 as the derivative correction.

    Examples
    --------
    >>> uc = (np.arange(400) - 199.5) / 4
    >>> c = binning_correction(np.linspace(-50, 50, 40001), uc, 4, 201)
    >>> round(float(c[0]), 6), round(float(c[50]), 4)
    (1.0, 1.0262)
    """
    h = binning_transfer(u, uc, oversampling, nfreq)
    with np.errstate(divide="ignore"):
        return np.minimum(1.0 / h, MAX_DERIVATIVE_CORRECTION)


def transition_width(esf: np.ndarray, sign: float, centre: float) -> float:
    """10–90 % rise distance of a binned ESF, in bins, measured outward
    from ``centre`` (a bin index on the edge); NaN if there is no rise.

    The plateau levels are the means of the first and last
    ``max(4, nn/10)`` bins; the 10 % crossing is the last one at or left of
    the centre, the 90 % crossing the first one at or right of it (so that
    noise in the plateaus cannot widen it), each interpolated linearly.

    Examples
    --------
    >>> x = np.arange(200.0)
    >>> e = np.clip((x - 90.0) / 20.0, 0, 1)      # a 20-bin linear ramp
    >>> round(transition_width(e, 1.0, 100.0), 6)
    16.0
    """
    e = np.asarray(esf, dtype=np.float64) * (1.0 if sign >= 0 else -1.0)
    nn = e.size
    m = max(4, nn // 10)
    lo, hi = mean_of(e[:m]), mean_of(e[-m:])
    if not hi > lo:
        return float("nan")
    en = (e - lo) / (hi - lo)
    c = min(max(round(centre), 1), nn - 2)
    left = (en[: c + 1] <= 0.1).nonzero()[0]
    right = (en[c:] >= 0.9).nonzero()[0]
    if left.size == 0 or right.size == 0:
        return float("nan")
    i = int(left[-1])
    j = int(right[0]) + c
    xl = i + (0.1 - en[i]) / (en[i + 1] - en[i]) if i + 1 < nn and en[i + 1] > en[i] else float(i)
    xr = j - (en[j] - 0.9) / (en[j] - en[j - 1]) if j > 0 and en[j] > en[j - 1] else float(j)
    return float(max(xr - xl, 0.0))


def _gauss_smooth(x: np.ndarray, sig: float) -> np.ndarray:
    """``x`` convolved with a normalised Gaussian of ``sig`` bins (zero
    outside the record); the sum is kept."""
    half = math.ceil(4.0 * sig)
    k = np.exp(-0.5 * (np.arange(-half, half + 1, dtype=np.float64) / sig) ** 2)
    k /= np.add.reduce(k)
    if half >= x.size:
        return np.full(x.size, x.sum() / x.size)
    return np.convolve(x, k, mode="full")[half : half + x.size]


def lsf_extent(
    lsf: np.ndarray,
    esf: np.ndarray,
    centre: float,
    width: float,
    oversampling: int,
) -> tuple[float, float]:
    """How far the LSF's significant structure reaches on each side, bins.

    Parameters
    ----------
    lsf : (nn,) ndarray
        Line spread function, positive peak.
    esf : (nn,) ndarray
        The binned ESF it came from (for the noise level).
    centre : float
        Bin index of the edge.
    width : float
        10–90 % rise distance of the ESF, bins.
    oversampling : int
        Bins per pixel.

    Returns
    -------
    left, right : float
        Distance from ``centre`` to the outermost bin, on each side, where
        the LSF smoothed by a Gaussian of ``max(w/4, ½ px)`` exceeds
        ``T = max(4·σ_s, EXTENT_FLOOR·peak)``, walking outward and stopping at the
        first gap longer than ``max(2w, 2 px)``.

    Notes
    -----
    ``σ_s`` is the noise of the smoothed LSF, from the bin noise of the ESF
    ``σ_b`` (robust: the MAD of its second differences beyond
    ``max(4w, 4 px)`` from the edge, which a slow flare tail or illumination
    gradient does not reach) through the derivative and the smoothing
    kernel ``h``: ``σ_s = σ_b·‖h‖``. Sharpening halos and ringing are
    significant and so kept in the core; a faint far-field tail is not, and
    is left to the smoothing of :func:`apodize_lsf`.

    Examples
    --------
    >>> x = np.arange(400.0)
    >>> lsf = np.exp(-0.5 * ((x - 200) / 4) ** 2) - 0.3 * np.exp(-0.5 * ((x - 200) / 12) ** 2)
    >>> esf = np.cumsum(lsf)                       # noise-free, with a wide undershoot
    >>> [round(v) for v in lsf_extent(lsf, esf, 200.0, 10.0, 4)]
    [34, 34]
    """
    nn = lsf.size
    c = float(centre)
    ds = max(0.25 * width, 0.5 * oversampling)
    sm = _gauss_smooth(lsf, ds)
    e = np.asarray(esf, dtype=np.float64)
    d2 = e[2:] - 2.0 * e[1:-1] + e[:-2]
    far = np.abs(np.arange(1, nn - 1) - c) > max(4.0 * width, 4.0 * oversampling)
    sigma_s = 0.0
    if np.count_nonzero(far) >= 16:
        v = d2[far]
        sigma_b = 1.4826 * _median(np.abs(v - _median(v))) / math.sqrt(6.0)
        pad = math.ceil(4 * ds) + 2
        h = np.zeros(2 * pad + 3)
        h[pad], h[pad + 2] = 0.5, -0.5
        h = _gauss_smooth(h, ds)
        sigma_s = sigma_b * math.sqrt(np.add.reduce(h * h))
    thr = max(4.0 * sigma_s, EXTENT_FLOOR * float(np.maximum.reduce(sm)))
    sig = np.abs(sm) > thr
    gap = max(2.0 * width, 2.0 * oversampling)
    ic = min(max(round(c), 0), nn - 1)

    def reach(side: np.ndarray) -> float:
        idx = side.nonzero()[0]
        if idx.size == 0:
            return 0.0
        idx = np.concatenate([[0], idx])
        jumps = (idx[1:] - idx[:-1] > gap).nonzero()[0]
        return float(idx[jumps[0]] if jumps.size else idx[-1])

    right = reach(sig[ic:]) + (ic - c)
    left = reach(sig[ic::-1]) + (c - ic)
    return max(left, 0.0), max(right, 0.0)


def adaptive_window(
    nn: int,
    centre: float,
    width: float,
    oversampling: int,
    *,
    extent: tuple[float, float] = (0.0, 0.0),
    flat: float = LSF_FLAT,
    taper: float = LSF_TAPER,
    min_px: float = LSF_MIN_PX,
) -> np.ndarray:
    """LSF window that follows the LSF's extent: flat-topped, raised-cosine
    edges, zero beyond.

    Parameters
    ----------
    nn : int
        Length of the LSF record, bins.
    centre : float
        Bin index of the edge (the LSF's centre).
    width : float
        10–90 % rise distance of the ESF, bins (:func:`transition_width`).
    oversampling : int
        Bins per pixel (for ``min_px``).
    extent : (left, right)
        Reach of the LSF's significant structure, bins (:func:`lsf_extent`);
        the flat top covers at least that much on each side.
    flat, taper : float
        Least half-width of the flat top and length of each taper, in units
        of ``width``.
    min_px : float
        Least flat half-width and least taper, pixels.

    Returns
    -------
    (nn,) ndarray
        ``1`` for ``−a_l ≤ i − centre ≤ a_r``, ``½(1 + cos(π(d − a)/b))``
        for a distance ``d`` up to ``a + b`` beyond, 0 further out;
        ``a = max(flat·width, min_px·os, extent)`` per side,
        ``b = max(taper·width, min_px·os)``, or on a side whose extent
        passes ``max(flat·width, min_px·os)``
        ``b = max(LSF_TAIL_TAPER·width, LSF_TAIL_MIN_PX·os)``.

    Examples
    --------
    >>> w = adaptive_window(64, 32.0, 4.0, 4)     # a = b = 4 bins
    >>> float(w[32]), float(w[36]), float(w[38]), float(w[40]), float(w[60])
    (1.0, 1.0, 0.5, 0.0, 0.0)
    """
    a0 = max(flat * width, min_px * oversampling)
    b0 = max(taper * width, min_px * oversampling)
    tail = max(LSF_TAIL_TAPER * width, LSF_TAIL_MIN_PX * oversampling)
    i = np.arange(nn, dtype=np.float64) - centre
    left, right = (tail if e > a0 else b0 for e in extent)
    a = np.where(i < 0, max(a0, extent[0]), max(a0, extent[1]))
    b = np.where(i < 0, left, right)
    t = np.abs(i)
    t -= a
    t /= b
    return _raised_cosine(_clip(t, 0.0, 1.0))


def _raised_cosine(t: np.ndarray) -> np.ndarray:
    """``½(1 + cos πt)``: 1 at ``t = 0`` down to 0 at ``t = 1``."""
    return 0.5 * (1.0 + np.cos(np.pi * t))


def _record_window(kind: str, nn: int, centre: float) -> np.ndarray:
    """sfrmat's record-length window (symmetric Hann or Hamming of ``nn``
    points) centred on bin ``centre`` instead of shifting the LSF; 0 beyond
    its half-length."""
    d = np.arange(nn, dtype=np.float64) - centre
    half = 0.5 * (nn - 1)
    a = 0.54 if kind == "hamming" else 0.5
    return np.where(np.abs(d) <= half, a + (1.0 - a) * np.cos(np.pi * d / max(half, 1.0)), 0.0)


def apodize_lsf(
    lsf: np.ndarray,
    esf: np.ndarray,
    centre: float,
    width: float,
    oversampling: int,
    window: str = "tukey",
) -> np.ndarray:
    """Adaptive LSF window: the core kept as it is, the far field smoothed.

    Parameters
    ----------
    lsf : (nn,) ndarray
        Line spread function (positive peak), bins.
    esf : (nn,) ndarray
        The binned ESF (for :func:`lsf_extent`'s noise level).
    centre : float
        Bin index of the edge.
    width : float
        10–90 % rise distance of the ESF, bins (:func:`transition_width`).
    oversampling : int
        Bins per pixel.
    window : {"tukey", "hamming"}
        sfrmat's record-length window, applied to the far field.

    Returns
    -------
    (nn,) ndarray
        ``w·LSF + G ⊛ ((1 − w)·W·LSF)``: ``w`` = :func:`adaptive_window`
        (flat over the LSF's significant structure, :func:`lsf_extent`, and
        at least ``max(width, 1 px)``; taper ``max(0.75·width, 1 px)``, or
        ``max(width, 2 px)`` where the structure reaches past that), ``W``
        the record-length window centred on the edge, ``G`` a normalised
        Gaussian of standard deviation ``max(width, 2 px)``.

    Notes
    -----
    Outside the LSF a blurred edge carries only noise, which the derivative
    turns into SFR noise growing with frequency and with the length of
    record kept; cutting the LSF there (zero weight) removes it, but a real
    lens also spreads a few per cent of the light over tens of pixels
    (flare, veiling glare), too faint per bin to stand above the noise, and
    cutting *that* drops a low-frequency shelf of the SFR and renormalises
    the rest upwards (+2.7–3.7 % of MTF50 on the two reference camera
    edges). The far field is therefore kept but low-pass filtered, as in
    the "modified apodization" of LaVeigne, Burks & Nehring (SPIE 6543,
    2007; Imatest's slanted-edge noise reduction): ``G`` keeps its sum (the
    normalisation at DC is sfrmat's) and its slow shelf, and rejects its
    noise above ≈ ``0.19/σ_G`` cycles/pixel. Structure that stands above
    the noise — a sharpening halo, ringing — is inside the core and kept
    as it is. On exact Gaussian edges this costs nothing against plain
    truncation (same bias, spread and SFR error).
    """
    nn = lsf.size
    ext = lsf_extent(lsf, esf, centre, width, oversampling)
    b = max(LSF_TAIL_TAPER * width, LSF_TAIL_MIN_PX * oversampling)
    # the core's taper (the longer, a tail's) must end inside the record
    ext = (min(ext[0], centre - b), min(ext[1], nn - 1 - centre - b))
    core = adaptive_window(nn, centre, width, oversampling, extent=ext)
    far = (1.0 - core) * _record_window(window, nn, centre) * lsf
    smooth = _gauss_smooth(far, max(width * ADAPTIVE_SMOOTH, ADAPTIVE_MIN_PX * oversampling))
    return core * lsf + smooth


_WINDOW_CACHE: dict[tuple[str, int], np.ndarray] = {}
_DCORR_CACHE: dict[tuple[int, int | None], np.ndarray] = {}


def _lsf_window(kind: str, nn: int) -> np.ndarray:
    key = (kind, nn)
    w = _WINDOW_CACHE.get(key)
    if w is None:
        # sfrmat5: tukey2(nn, 1, nn/2) is the symmetric Hann of nn points;
        # ahamming(nn, nn/2) is the symmetric Hamming of nn points.
        w = np.hamming(nn) if kind == "hamming" else np.hanning(nn)
        if len(_WINDOW_CACHE) > 64:
            _WINDOW_CACHE.clear()
        _WINDOW_CACHE[key] = w
    return w


def esf_to_sfr(
    esf: np.ndarray,
    sign: float,
    window: str,
    slope: float,
    oversampling: int,
    *,
    correction: np.ndarray | None = None,
    exact_derivative: bool = False,
    adaptive: tuple[float, float] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """LSF, window, |DFT|/DC and derivative correction of a binned ESF.

    Parameters
    ----------
    esf : (nn,) ndarray
        Edge spread function in ``1/oversampling``-px bins (along the rows).
    sign : {+1, −1}
        Makes the LSF a positive peak.
    window : {"tukey", "hamming"}
        Record-length LSF window (sfrmat: the LSF is first shifted so that
        its peak is mid-record, then windowed over the whole record).
    slope : float
        dx/drow of the linear edge fit (sets the bin spacing along the normal).
    oversampling : int
        Bins per pixel.
    correction : (K,) ndarray, optional
        A further factor for the first ``K`` frequency indices, e.g.
        :func:`binning_correction` (``K ≥ output_length(nn, oversampling)``
        covers every frequency returned).
    exact_derivative : bool
        Derivative correction at the true frequency instead of sfrmat's
        ``fir2fix`` (see :func:`derivative_correction`).
    adaptive : (centre, width), optional
        Bin index of the edge and the ESF's 10–90 % rise distance in bins:
        window the LSF by :func:`apodize_lsf` instead (not in ISO 12233).

    Returns
    -------
    freq : (K,) ndarray
        Cycles per pixel along the edge normal, ``k/(nn·Δ)``; ``K`` as
        sfrmat (up to about 1 cycle/pixel for ``oversampling = 4``).
    sfr : (K,) ndarray
        Normalised SFR (1 at DC).
    lsf : (nn,) ndarray
        The LSF before shifting and windowing (positive peak).
    dc : float
        Sum of the windowed LSF (≤ 0 means there is no edge).
    """
    nn = esf.size
    lsf = np.empty(nn)
    lsf[1:-1] = 0.5 * (esf[2:] - esf[:-2])
    lsf[0], lsf[-1] = lsf[1], lsf[-2]
    if sign < 0:
        lsf = -lsf
    if adaptive is None:
        peak = mean_of((lsf == np.maximum.reduce(lsf)).nonzero()[0])
        shift = _mround_int(peak - (_mround_int((nn + 1) / 2.0) - 1))  # sfrmat ``cent``
        c = np.zeros(nn)
        if shift >= 0:
            c[: nn - shift] = lsf[shift:]
        else:
            c[-shift:] = lsf[: nn + shift]
        c *= _lsf_window(window, nn)
    else:
        # no shift: the modulus of the DFT does not depend on where the LSF lies
        c = apodize_lsf(lsf, esf, adaptive[0], adaptive[1], oversampling, window)
    spec = np.abs(np.fft.rfft(c))
    dc = float(np.add.reduce(c))
    nn2 = nn // 2 + 1
    key = (nn2, nn if exact_derivative else None)
    dcorr = _DCORR_CACHE.get(key)
    if dcorr is None:
        if len(_DCORR_CACHE) > 64:
            _DCORR_CACHE.clear()
        dcorr = _DCORR_CACHE.setdefault(key, derivative_correction(*key))
    if correction is not None:
        k = min(correction.size, nn2)
        dcorr = dcorr.copy()
        dcorr[:k] *= correction[:k]
    with np.errstate(divide="ignore", invalid="ignore"):
        mtf = spec[:nn2] / spec[0] * dcorr
    nout = output_length(nn, oversampling)
    delta = np.cos(np.arctan(slope)) / oversampling
    freq = np.arange(nout) / (nn * delta)
    return freq, mtf[:nout], lsf, dc


def crossing(freq: np.ndarray, sfr: np.ndarray, level: float = 0.5) -> float:
    """First frequency where ``sfr`` falls below ``level``, by linear
    interpolation between the two samples around it (sfrmat ``findfreq``);
    NaN if it never does.

    Examples
    --------
    >>> crossing(np.array([0.0, 0.1, 0.2]), np.array([1.0, 0.7, 0.3]))
    0.15
    """
    below = (np.asarray(sfr) < level).nonzero()[0]
    if below.size == 0 or below[0] == 0:
        return float("nan")
    i = int(below[0])
    y0, y1 = sfr[i - 1], sfr[i]
    return float(freq[i - 1] + (y0 - level) / (y0 - y1) * (freq[i] - freq[i - 1]))


def interp_at(freq: np.ndarray, sfr: np.ndarray, f: float) -> float:
    """SFR at ``f`` by linear interpolation; NaN beyond the measured range."""
    if f < freq[0] or f > freq[-1]:
        return float("nan")
    return float(np.interp(f, freq, sfr))


def area_to(freq: np.ndarray, sfr: np.ndarray, fmax: float = 0.5) -> float:
    """Trapezoid area under ``sfr`` from 0 to ``fmax`` (the end value
    interpolated); NaN if the curve stops short of ``fmax``.

    Examples
    --------
    >>> area_to(np.array([0.0, 0.25, 0.5, 0.75]), np.ones(4))
    0.5
    """
    w = area_weights(np.asarray(freq, float), fmax)
    return float(np.asarray(sfr, float)[:w.size] @ w)


def area_weights(freq: np.ndarray, fmax: float) -> np.ndarray:
    """Weights ``w`` of :func:`area_to`: the area is linear in the curve,
    ``area_to(freq, sfr, fmax) == sfr[:len(w)] @ w``, so many curves on one
    grid take one product. Trapezoids over ``freq`` up to ``fmax``, the end
    value interpolated between its neighbours (as ``np.interp``). ``w``
    covers only the samples the area reads (a curve may be undefined past
    them); ``[nan]`` where ``freq`` stops short of ``fmax``.

    >>> area_weights(np.array([0.0, 0.25, 0.5, 0.75]), 0.5).tolist()
    [0.125, 0.25, 0.125]
    """
    if freq[-1] < fmax:
        return np.array([np.nan])
    n = int(freq.searchsorted(fmax, side="right"))
    x = np.empty(n + 1)
    x[:n] = freq[:n]
    x[n] = fmax
    d = np.zeros(n + 2)  # the gaps between the n + 1 points, and none beyond either end
    d[1:-1] = x[1:] - x[:-1]
    t = 0.5 * (d[:-1] + d[1:])   # trapezoid weights of the n + 1 points
    w = np.zeros(freq.size)
    w[:n] = t[:n]
    # the end value, interpolated between its neighbours, carries t[n]
    i = max(n - 1, 0)
    j = i if freq[i] == fmax else min(i + 1, freq.size - 1)   # an end on a sample reads no further
    a = 0.0 if j == i else (fmax - freq[i]) / (freq[j] - freq[i])
    w[i] += t[n] * (1.0 - a)
    w[j] += t[n] * a
    return w[:j + 1]

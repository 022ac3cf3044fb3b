"""Numerical core of the ISO 12233 e-SFR: edge location, projection, SFR.

The steps of ISO 12233:2023 Annex D as implemented by Burns' sfrmat3/4/5
(the reference code of the standard), written anew and vectorised. The
public entry points are in :mod:`calibration.sfr`, which validates input,
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

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "WINDOWS",
    "EdgeFit",
    "area_to",
    "crossing",
    "derivative_correction",
    "esf_to_sfr",
    "interp_at",
    "locate_edge",
    "mround",
    "poly_compose_linear",
    "polyval",
    "project_esf",
]

#: LSF windows by name: sfrmat5's default (Tukey α=1, i.e. Hann) and sfrmat3/4's Hamming.
WINDOWS = ("tukey", "hamming")

#: sfrmat caps the derivative correction at this factor.
MAX_DERIVATIVE_CORRECTION = 10.0


def mround(x):
    """MATLAB ``round``: halves away from zero."""
    return np.sign(x) * np.floor(np.abs(x) + 0.5)


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
    out = np.full(x.shape, coef[-1], dtype=np.float64)
    for c in coef[-2::-1]:
        out = out * x + c
    return out


def poly_compose_linear(coef: np.ndarray, a: float, b: float) -> np.ndarray:
    """Ascending coefficients of ``p(a·t + b)``."""
    n = len(coef)
    out = np.zeros(n)
    for i, c in enumerate(coef):  # (a t + b)^i = Σ_k C(i,k) a^k b^(i−k) t^k
        for k in range(i + 1):
            out[k] += c * math.comb(i, k) * a**k * b ** (i - k)
    return out


def _fit(rows: np.ndarray, loc: np.ndarray, order: int) -> np.ndarray:
    """Least-squares polynomial ``loc = p(rows)``, fitted on centred and
    scaled rows (as sfrmat5's ``polyfit`` with ``mu``), returned unscaled,
    ascending."""
    mu = float(rows.mean())
    sd = float(rows.std()) or 1.0
    t = (rows - mu) / sd
    v = np.vander(t, order + 1, increasing=True)
    ct = np.linalg.lstsq(v, loc, rcond=None)[0]
    return poly_compose_linear(ct, 1.0 / sd, -mu / sd)


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
    n2 = mround(2.0 * np.maximum(mid, m - mid))
    # tukey2: the first m samples of a length-n2 window, or the last m.
    first = mid >= m / 2.0
    j = np.where(first, i - 1.0, i - 1.0 + n2 - m)
    return 0.95 * _hann_at(j, n2) + 0.05


def _centroids(deriv: np.ndarray, win: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """sfrmat ``centroid(c .* win) − 0.5``: 1-based centroid index minus ½,
    i.e. the position in sample units where sample ``j`` (0-based) of the
    derivative sits at ``j + ½``."""
    wd = deriv * win
    den = wd.sum(axis=1)
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
    d = (0.5 * sign) * np.diff(values, axis=1)
    deriv = np.concatenate([d[:, 1:2], d[:, 1:], d[:, -1:]], axis=1) if m > 2 else np.repeat(d, 2, 1)
    x0c = np.asarray(x0, dtype=np.float64)

    def fit_from(win):
        q, den = _centroids(deriv, win)
        ok = (den > 0) & np.isfinite(q) & (q >= 0.0) & (q <= m)
        return q, ok

    q, valid = fit_from(_edge_window(m, np.full((1, 1), (m + 1) / 2.0), window))
    bad = EdgeFit(np.full(order + 1, np.nan), np.full(2, np.nan), np.nan)
    if valid.sum() < order + 2:
        return bad, x0c + dx * q, valid
    coef = _fit(rows[valid], (x0c + dx * q)[valid], order)
    place = (polyval(coef, rows) - x0c) / dx
    q, valid = fit_from(_edge_window(m, place[:, None], window))
    loc = x0c + dx * q
    if valid.sum() < order + 2:
        return bad, loc, valid
    coef = _fit(rows[valid], loc[valid], order)
    coef1 = coef if order == 1 else _fit(rows[valid], loc[valid], 1)
    resid = loc[valid] - polyval(coef, rows[valid])
    rms = float(np.sqrt(np.mean(resid * resid)))
    return EdgeFit(coef, coef1, rms), loc, valid


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
    r0 = float(rows[0])
    p0 = float(fit(r0))
    edge = fit(rows)[:, None]
    u = np.broadcast_to(xs, values.shape) - edge
    c1 = float(fit.coef[1])
    off = int(mround(-oversampling * (nlin - 1) * c1))
    k0 = min(off, 0) + int(mround(abs(off) / 2.0))
    # ceil(t) for t = (x − p2)·os; bin k ↔ t ∈ (k + k0 − 1, k + k0].
    k = np.ceil((u + p0) * oversampling).astype(np.intp).ravel() - k0
    v = values.ravel()
    # bins −1 and nn are kept for sfrmat's neighbour filling.
    inside = (k >= -1) & (k <= nn)
    if not inside.all():
        k, v = k[inside], v[inside]
    counts = np.bincount(k + 1, minlength=nn + 2).astype(np.float64)
    sums = np.bincount(k + 1, weights=v, minlength=nn + 2)
    empty = np.flatnonzero(counts[1 : nn + 1] == 0) + 1
    nempty = empty.size
    raw_counts = counts[1 : nn + 1].astype(np.int64)
    for i in empty:  # sfrmat5 order: earlier fills feed later ones
        if i == nn:
            counts[i], sums[i] = counts[i - 1], sums[i - 1]
        else:
            counts[i] = 0.5 * (counts[i - 1] + counts[i + 1])
            sums[i] = 0.5 * (sums[i - 1] + sums[i + 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        esf = sums[1 : nn + 1] / counts[1 : nn + 1]
    if nempty and not np.isfinite(esf).all():
        good = np.isfinite(esf)
        if good.any():
            esf = np.interp(np.arange(nn), np.flatnonzero(good), esf[good])
    uc = (np.arange(nn) + k0 - 0.5) / oversampling - p0
    return esf, raw_counts, u, uc


def derivative_correction(nn2: int) -> np.ndarray:
    """sfrmat's ``fir2fix(nn2, 3)``: ``x/sin x`` with ``x = π(k+1)/(nn2+1)``
    for frequency index ``k ≥ 1`` (1 at ``k = 0``), capped at 10.

    Examples
    --------
    >>> c = derivative_correction(5)
    >>> float(c[0]), round(float(c[1]), 4)
    (1.0, 1.2092)
    """
    k = np.arange(nn2, dtype=np.float64)
    x = np.pi * (k + 1.0) / (nn2 + 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.abs(x / np.sin(x))
    c[0] = 1.0
    return np.minimum(np.where(np.isfinite(c), c, MAX_DERIVATIVE_CORRECTION), MAX_DERIVATIVE_CORRECTION)


_WINDOW_CACHE: dict[tuple[str, int], np.ndarray] = {}
_DCORR_CACHE: dict[int, np.ndarray] = {}


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
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """LSF, window, |DFT|/DC and derivative correction of a binned ESF.

    Parameters
    ----------
    esf : (nn,) ndarray
        Edge spread function in ``1/oversampling``-px bins (along the rows).
    sign : {+1, −1}
        Makes the LSF a positive peak.
    window : {"tukey", "hamming"}
        LSF window.
    slope : float
        dx/drow of the linear edge fit (sets the bin spacing along the normal).
    oversampling : int
        Bins per pixel.

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
    peak = float(np.mean(np.flatnonzero(lsf == lsf.max())))
    shift = int(mround(peak - (mround((nn + 1) / 2.0) - 1)))  # sfrmat ``cent``
    c = np.zeros(nn)
    if shift >= 0:
        c[: nn - shift] = lsf[shift:]
    else:
        c[-shift:] = lsf[: nn + shift]
    c *= _lsf_window(window, nn)
    spec = np.abs(np.fft.rfft(c))
    dc = float(c.sum())
    nn2 = nn // 2 + 1
    dcorr = _DCORR_CACHE.get(nn2)
    if dcorr is None:
        dcorr = _DCORR_CACHE.setdefault(nn2, derivative_correction(nn2))
    with np.errstate(divide="ignore", invalid="ignore"):
        mtf = spec[:nn2] / spec[0] * dcorr
    freqlim = 2 if oversampling == 1 else 1
    nout = int(mround(nn2 * freqlim / 2.0))
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
    below = np.flatnonzero(sfr < level)
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
    if freq[-1] < fmax:
        return float("nan")
    n = int(np.searchsorted(freq, fmax, side="right"))
    f = np.append(freq[:n], fmax)
    s = np.append(sfr[:n], np.interp(fmax, freq, sfr))
    return float(np.sum(0.5 * (s[1:] + s[:-1]) * np.diff(f)))

"""LSF asymmetry: the odd part of an edge's transfer, which the SFR drops.

The SFR is the modulus of the edge's transfer; its phase is lost, and with
it the asymmetry of the line spread — coma from a decentered element, the
one-sided flare of a tilted one. A fit to SFRA alone cannot tell a coma
tail pointing to the centre from one pointing away; edge images can, which
is why a pixel-level fit beat SFRA fits on decentred phone lenses
(``benchmarks/proxy.py``). The asymmetry is measurable on the same slanted
edge without knowing where the chart is:

    A(f) = Im Σ_s w(s − c) l(s) exp(−2πi f (s − c)) / Σ_s w(s − c) l(s)
         = −Σ w l sin(2πf(s − c)) / Σ w l

the imaginary part of the transfer of the LSF ``l`` re-centred on its own
windowed centroid ``c`` (so the edge's position, which a chart capture does
not give, drops out: A is zero for every symmetric LSF whatever its
position). For small f it is (2πf)³ κ₃ / 6 with κ₃ the third central
moment: positive when the LSF has its long tail toward +s. The window ``w``
(Hann, half-width :data:`HALF_WIDTH_PX`) keeps the noise of the far tails
out; the model side uses the same window, and the measurement's own bias is
computed like the SFR's (:meth:`calibration.fit.forward_model.SfrModel.measurement_bias`).

Direction: :func:`calibration.sfr.esfr.measure_sfr` bins the ESF along +x of the
oriented ROI — +x for a near-vertical edge, +y for a near-horizontal one
(turned by ``np.rot90``) — and makes the LSF a positive peak whatever the
edge's polarity, so ``s`` runs along the edge normal that points to +x
(vertical edges) or +y (horizontal ones): :func:`lsf_direction`.

A is reported as its mean over the frequency bands :data:`BANDS`
(cycles/pixel), with a standard deviation propagated from the ESF's noise
through A's full linearisation (the window and the centroid included):
:func:`odd_bands_std`.

References
----------
ISO 12233:2023, Annex D (the e-SFR's ESF, LSF and its derivative filter).
ISO 9334:2012, *Optical transfer function — definitions*: the OTF's phase
(PTF) is what the MTF leaves out; A is the imaginary part of the OTF
re-centred on the LSF's centroid, i.e. |OTF| sin(PTF − linear phase).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["BANDS", "HALF_WIDTH_PX", "MODEL_SD", "esf_bin_noise", "lsf_direction", "model_odd_bands", "odd_bands",
           "odd_bands_std", "odd_sigma", "project_masses"]

#: frequency bands (cycles/pixel) over which A(f) is averaged; A grows as f³
#: at first, so the lowest band carries little and starts at 0.05
BANDS = ((0.05, 0.15), (0.15, 0.25), (0.25, 0.35), (0.35, 0.5))

#: Hann window half-width (pixels) around the LSF's centroid: wide enough for
#: the coma and flare of a phone lens at the corner (the forward model's PSF
#: window is ±8 px), narrow enough to keep the record's noisy tails out
HALF_WIDTH_PX = 6.0

#: the forward model's own error in the bands (ISO's record and binning
#: against the model's continuous projection: ≈ 1 % of A ≈ 0.1 on a coma-like
#: PSF), added in quadrature to the measurement's σ (:func:`odd_sigma`) so
#: that low-noise observations do not fit the model's approximation
MODEL_SD = 1e-3

_F_PER_BAND = 12
_ITERATIONS = 12


def lsf_direction(normal_deg) -> np.ndarray:
    """Direction (degrees, y down) along which a measured LSF runs for an
    edge of normal ``normal_deg`` ([0°, 180°)): the normal with a positive x
    component for near-vertical edges, a positive y component for
    near-horizontal ones (module docstring).

    Examples
    --------
    >>> lsf_direction([5.0, 175.0, 95.0]).tolist()
    [5.0, -5.0, 95.0]
    """
    a = np.mod(np.asarray(normal_deg, dtype=np.float64), 180.0)
    horizontal = (a >= 45.0) & (a < 135.0)
    return np.where(horizontal | (a < 45.0), a, a - 180.0)


def _band_kernel(bands=BANDS) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies (F,) and the (K, F) averaging matrix of the bands."""
    freq = np.concatenate([np.linspace(lo, hi, _F_PER_BAND) for lo, hi in bands])
    avg = np.zeros((len(bands), len(freq)))
    for k in range(len(bands)):
        avg[k, k * _F_PER_BAND:(k + 1) * _F_PER_BAND] = 1.0 / _F_PER_BAND
    return freq, avg


def _hann(d: np.ndarray, half: float, derivative: bool = True):
    """Hann window cos²(πd/2h) on |d| < h and (``derivative``) its
    derivative in d."""
    inside = np.abs(d) < half
    arg = np.pi * d / (2.0 * half)
    w = np.where(inside, 0.5 + 0.5 * np.cos(2.0 * arg), 0.0)
    if not derivative:
        return w
    return w, np.where(inside, -np.sin(2.0 * arg) * np.pi / (2.0 * half), 0.0)


def _centroid(lsf: np.ndarray, s: np.ndarray, half: float) -> np.ndarray:
    """Windowed centroid c of each row of ``lsf`` (N, n) on positions ``s``:
    the fixed point c = Σ w(s − c) l s / Σ w(s − c) l, started at the peak
    of the LSF smoothed over a pixel."""
    step = float(s[1] - s[0])
    k = max(1, int(round(1.0 / step)))
    c = s[np.argmax(_box(lsf, float(k)), axis=1)]
    for _ in range(_ITERATIONS):
        w = _hann(s[None, :] - c[:, None], half, derivative=False)
        d = np.sum(w * lsf, axis=1)
        c_new = np.where(d > 0, np.sum(w * lsf * s[None, :], axis=1) / np.where(d > 0, d, 1.0), c)
        if np.all(np.abs(c_new - c) < 1e-6):     # px: A moves by 2πf·1e-6 at most
            c = c_new
            break
        c = c_new
    return c


def _odd(lsf: np.ndarray, s: np.ndarray, half: float, bands=BANDS, gradient: bool = False):
    """Band means of A (N, K) for rows of ``lsf`` on positions ``s``; with
    ``gradient``, also dA/dl (N, K, n): the linearisation through the
    window, the centroid and the normalisation."""
    lsf = np.atleast_2d(np.asarray(lsf, dtype=np.float64))
    freq, avg = _band_kernel(bands)
    c = _centroid(lsf, s, half)
    d = s[None, :] - c[:, None]                                     # (N, n)
    if not gradient:
        # exp(−2πif(s − c)) = exp(−2πifs)·exp(2πifc): one GEMM on the common grid
        # instead of a sine per row, frequency and sample (20× faster on 600 rows)
        wl = _hann(d, half, derivative=False) * lsf
        t = (wl @ np.exp(-2j * np.pi * np.outer(s, freq))) * np.exp(2j * np.pi * c[:, None] * freq[None, :])
        return (t.imag / wl.sum(axis=1)[:, None]) @ avg.T
    w, dw = _hann(d, half)
    ph = 2.0 * np.pi * freq[None, :, None] * d[:, None, :]          # (N, F, n)
    sn, cs = np.sin(ph), np.cos(ph)
    wl = w * lsf
    den = wl.sum(axis=1)                                            # (N,)
    num = np.einsum("nfs,ns->nf", sn, wl)                           # (N, F)
    out = (-num / den[:, None]) @ avg.T
    # direct part: A = −N/D with c held
    g = -(w[:, None, :] * sn * den[:, None, None] - num[:, :, None] * w[:, None, :]) / den[:, None, None] ** 2
    # the centroid moves with l: M(c) = Σ w(s−c) l (s−c) = 0
    dm_dl = w * d                                                   # (N, n)
    dm_dc = np.sum(lsf * (-dw * d - w), axis=1)                     # (N,)
    dc_dl = -dm_dl / np.where(dm_dc != 0, dm_dc, np.inf)[:, None]
    dn_dc = np.einsum("nfs,ns->nf", -dw[:, None, :] * sn - w[:, None, :] * 2.0 * np.pi * freq[None, :, None] * cs,
                      lsf)
    dd_dc = np.sum(-dw * lsf, axis=1)
    da_dc = -(dn_dc * den[:, None] - num * dd_dc[:, None]) / den[:, None] ** 2
    g = g + da_dc[:, :, None] * dc_dl[:, None, :]
    return out, np.einsum("kf,nfs->nks", avg, g)


def odd_bands(lsf, step_px: float, *, half_width_px: float = HALF_WIDTH_PX, bands=BANDS) -> np.ndarray:
    """Band means of the odd transfer A of a measured LSF (module docstring).

    Parameters
    ----------
    lsf : (n,) or (N, n) array_like
        Line spread on a uniform grid (any scale, positive peak), e.g.
        :attr:`calibration.sfr.esfr.SfrResult.lsf`.
    step_px : float
        Its sample spacing along the edge normal, pixels.

    Returns
    -------
    (K,) or (N, K) ndarray
        Dimensionless, in [−1, 1]; 0 for a symmetric LSF.

    Examples
    --------
    >>> s = np.arange(-64, 65) * 0.25
    >>> sym = np.exp(-s**2 / 2)
    >>> bool(np.allclose(odd_bands(sym, 0.25), 0.0, atol=1e-12))
    True
    >>> tail = sym + 0.3 * np.exp(-(s - 1.5)**2 / 2)     # a tail toward +s
    >>> bool(np.all(odd_bands(tail, 0.25) > 0))
    True
    """
    l = np.asarray(lsf, dtype=np.float64)
    s = np.arange(l.shape[-1]) * float(step_px)
    out = _odd(np.atleast_2d(l), s, half_width_px, bands)
    return out[0] if l.ndim == 1 else out


def odd_bands_std(lsf, step_px: float, esf_noise, *, half_width_px: float = HALF_WIDTH_PX,
                  bands=BANDS) -> np.ndarray:
    """Standard deviation of :func:`odd_bands` from white noise on the ESF.

    The LSF is ISO 12233's central difference of the binned ESF,
    ``l_j = (e_{j+1} − e_{j−1}) / 2``, so A's gradient in ``l`` maps to
    the ESF bins as ``(G_{k−1} − G_{k+1}) / 2``; with independent bins of
    standard deviation ``esf_noise`` (the pixel noise over √(samples per
    bin): rows / oversampling for a slanted edge), the variance is that
    vector's squared norm times ``esf_noise²``.

    Parameters
    ----------
    lsf : (n,) or (N, n) array_like
    step_px : float
    esf_noise : float or (N,) array_like
        Noise per ESF bin, the LSF's units.

    Returns
    -------
    (K,) or (N, K) ndarray
    """
    l = np.asarray(lsf, dtype=np.float64)
    l2 = np.atleast_2d(l)
    s = np.arange(l2.shape[-1]) * float(step_px)
    _, g = _odd(l2, s, half_width_px, bands, gradient=True)        # (N, K, n)
    gp = np.pad(g, ((0, 0), (0, 0), (1, 1)))
    h = 0.5 * (gp[:, :, :-2] - gp[:, :, 2:])
    sd = np.sqrt(np.sum(h * h, axis=2)) * np.broadcast_to(np.asarray(esf_noise, float), (l2.shape[0],))[:, None]
    return sd[0] if l.ndim == 1 else sd


def model_odd_bands(psf, pitch_px: float, normal_deg, *, aperture_px: float = 1.0,
                    oversampling: int = 4, step_px: float = 1.0 / 16.0, half_width_px: float = HALF_WIDTH_PX,
                    bands=BANDS) -> np.ndarray:
    """:func:`odd_bands` of the LSFs that sampled PSFs and a square pixel
    aperture of side ``aperture_px`` make along each edge's measurement
    direction (:func:`lsf_direction` of ``normal_deg``), as ISO 12233 sees
    them: binned at ``1/oversampling`` px and differentiated by
    ``[0.5, 0, −0.5]`` (two boxes, 1 and 2 bins wide; 3–8 % of A in the top
    band on a coma-like PSF). The projection's grid ``step_px``: on a
    perturbed e9 (600 observations) 1/16 px is 2e-4–5e-4 RMS per band from
    1/32 px, 1/8 px 8e-4–1.8e-3 (the model's own error allowance is
    :data:`MODEL_SD`); 0.17 s for 600 observations.

    Parameters
    ----------
    psf : (N, m, m) ndarray
        Masses (rows +y down), centred at ``m // 2``.
    pitch_px : float
        PSF sample spacing, pixels.
    normal_deg : (N,) array_like

    Returns
    -------
    (N, K) ndarray
    """
    direction = lsf_direction(normal_deg)
    hist, x = project_masses(psf, pitch_px, direction, step_px)
    # the pixel aperture, projected on the direction: two boxes of widths a|cos|, a|sin|
    t = np.radians(direction)
    one = np.ones_like(t)
    for width in (aperture_px * np.abs(np.cos(t)), aperture_px * np.abs(np.sin(t)), one / oversampling,
                  2.0 * one / oversampling):
        hist = _box(hist, width / step_px)
    return _odd(hist, x, half_width_px, bands)


def _box(rows: np.ndarray, width_bins: np.ndarray) -> np.ndarray:
    """Each row convolved with a unit-area box ``width_bins`` wide (per row,
    fractional: exact for the piecewise-linear cumulative sum). Rows of one
    width are done together: their box is one shift of the cumulative sum."""
    cum = np.concatenate([np.zeros((rows.shape[0], 1)), np.cumsum(rows, axis=1)], axis=1)   # at edges j − ½
    width_bins = np.broadcast_to(np.asarray(width_bins, float), (rows.shape[0],))
    out = rows.copy()
    for wb in np.unique(width_bins):
        if wb < 1e-6:
            continue
        sel = width_bins == wb
        c = cum[sel]
        out[sel] = (_cum_at(c, 0.5 * wb) - _cum_at(c, -0.5 * wb)) / wb
    return out


def _cum_at(cum: np.ndarray, t: float) -> np.ndarray:
    """Rows of a cumulative sum sampled at edges ``m − ½`` (m = 0..n), read
    at positions ``j + t`` (j = 0..n−1) by linear interpolation, clamped at
    the ends (as ``np.interp``)."""
    n = cum.shape[1] - 1
    k0 = int(np.floor(t + 0.5))
    frac = t + 0.5 - k0
    j = np.arange(n) + k0
    return cum[:, np.clip(j, 0, n)] * (1.0 - frac) + cum[:, np.clip(j + 1, 0, n)] * frac


def odd_sigma(odd_std) -> np.ndarray:
    """σ a residual in the bands is divided by: the measurement's
    ``odd_std`` in quadrature with the model's :data:`MODEL_SD`."""
    return np.hypot(np.asarray(odd_std, float), MODEL_SD)


def esf_bin_noise(noise, rows, oversampling) -> np.ndarray:
    """Noise of one ESF bin (the pixel noise's units): a slanted edge of
    ``rows`` lines puts about rows / oversampling pixels into each bin."""
    per_bin = np.maximum(np.asarray(rows, float) / float(oversampling), 1.0)
    return np.asarray(noise, float) / np.sqrt(per_bin)


def project_masses(psf: np.ndarray, pitch_px: float, normal_deg, step_px: float):
    """Line spread of sampled PSFs along directions: each mass binned on
    the direction at ``step_px`` with linear weights (moves a mass by less
    than ``step_px``).

    Returns
    -------
    hist : (N, nb) ndarray
        Mass per bin (each row sums to the PSF's mass).
    x : (nb,) ndarray
        Bin positions, pixels from the PSF's centre sample along the direction.

    Examples
    --------
    >>> p = np.zeros((5, 5)); p[2, 3] = 1.0            # one sample right of centre
    >>> h, x = project_masses(p, 1.0, [0.0], step_px=0.5)
    >>> float(x[np.argmax(h[0])])
    1.0
    """
    p = np.asarray(psf, dtype=np.float64)
    if p.ndim == 2:
        p = p[None]
    n_obs, m, _ = p.shape
    a = np.radians(np.broadcast_to(np.asarray(normal_deg, dtype=np.float64), (n_obs,)))
    o = (np.arange(m) - m // 2) * float(pitch_px)
    t = np.cos(a)[:, None, None] * o[None, None, :] + np.sin(a)[:, None, None] * o[None, :, None]
    half = math.ceil(abs(o).max() * math.sqrt(2.0) / step_px) + 2
    pos = t / step_px + half
    i0 = np.floor(pos).astype(np.int64)
    frac = pos - i0
    nb = 2 * half + 2
    base = (np.arange(n_obs) * nb)[:, None, None]
    hist = (np.bincount((i0 + base).ravel(), (p * (1.0 - frac)).ravel(), minlength=n_obs * nb)
            + np.bincount((i0 + 1 + base).ravel(), (p * frac).ravel(), minlength=n_obs * nb))
    return hist.reshape(n_obs, nb), (np.arange(nb) - half) * step_px

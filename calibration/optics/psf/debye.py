"""The Debye PSF: the Huygens sum in the Debye approximation, evaluated
directly on the requested grid (the PSF-map default).

``E(Δ) = (1/λ') Σ_i a_i e^{ikW_i} e^{ik' ŝ_i·Δ}`` with ``ŝ_i`` the unit
vector from the source ``Q_i`` on the reference sphere
(:mod:`calibration.optics.psf.pupil`) to ``P0``: the Huygens sum
(:mod:`calibration.optics.psf.huygens`) with ``r ≈ R + ŝ·Δ`` and each ray's
*real* direction, without the terms of second order in ``|Δ|/R`` — their
ray-dependent part, ``k'(ŝ·Δ)²/2R``, is ≈ 0.01 rad at 8 µm from the centre
on e9; the part common to all rays drops out of |E|² — with ``K = 1`` and
``R/r = 1``. On a grid ``e^{ik'ŝ·Δ} = e^{ik'ŝ_x Δx} e^{ik'ŝ_y Δy}``, so
``E = Yᵀ·diag(a e^{ikW})·X``: two phasor tables (:func:`phasors`) and one
matrix product (a "matrix Fourier transform", Soummer et al., *Opt.
Express* 15 (2007) 15935) instead of rays × pixels exponentials; no affine
pupil map, no interpolation.

:func:`debye_node_psfs` sums the Debye PSFs of many fields at once (the SFR
model's path, :mod:`calibration.fit.forward_model`), with
:func:`debye_psf`'s per-field path as its oracle (equal to ~1e-10 of the
peak in complex128; :data:`DEBYE_SUM_DTYPE`).

References: M. Born and E. Wolf, *Principles of Optics*, 7th ed., Cambridge
University Press 1999, §8.8 (Debye integral); R. Soummer et al., "Fast
computation of Lyot-style coronagraph propagation", *Opt. Express* 15
(2007) 15935–15951.

Imports :mod:`~calibration.optics.psf.pupil`,
:mod:`~calibration.optics.psf.sampling`,
:mod:`~calibration.optics.psf.linalg` and
:mod:`~calibration.optics.psf.result` of this package.
"""

from __future__ import annotations

import math

import numpy as np

from calibration.optics.lens import Lens
from calibration.optics.perturb import PerturbedLens
from calibration.optics.psf.linalg import a_bt, at_b
from calibration.optics.psf.pupil import ReferenceSphere, TracedNodes, node_spheres
from calibration.optics.psf.result import PSF, PSFError
from calibration.optics.psf.sampling import monochromatic_psf, normalized_samples

__all__ = ["DEBYE_SUM_DTYPE", "debye_intensity", "debye_node_psfs", "debye_psf", "debye_samples", "phasors"]


def phasors(kvec: np.ndarray, offsets: np.ndarray, scale: np.ndarray | None = None,
            dtype=np.complex128) -> np.ndarray:
    """``scale[..., i]·exp(i·kvec[..., i]·offsets[a])`` for uniformly spaced
    ``offsets`` (n,), shape (..., n, M) for ``kvec`` (..., M) (``scale``
    default 1), as ``dtype``.

    By doubling along the offsets: rows a..2a−1 are rows 0..a−1 times the
    phasor of a steps, so each entry is a product of ≤ log2(n) + 1 phasors
    (relative error ≲ (log2(n) + 1)·ε plus the rounding of the phases:
    1e-13 at 100 rad in complex128, 4e-7 in complex64) and each product is
    one vectorised call over whole rows. The first row and the step are
    evaluated in float64 (phases of ~100 rad need it); on a grid centred on
    row n//2 (the PSF windows) the first row is the inverse of the step's
    n//2-th power, which saves one of the two complex exponentials."""
    kvec = np.asarray(kvec, dtype=np.float64)
    offsets = np.asarray(offsets, dtype=np.float64)
    n = len(offsets)
    out = np.empty(kvec.shape[:-1] + (n, kvec.shape[-1]), dtype=dtype)
    d = offsets[1] - offsets[0] if n > 1 else 0.0
    step = np.exp(1j * kvec * d) if n > 1 else None
    if n > 2 and abs(offsets[0] + (n // 2) * d) <= 1e-12 * n * abs(d):
        first = np.conj(_power(step, n // 2))          # centred grid: e^{ik·o0} = 1/step^(n//2), no exp
    else:
        first = np.exp(1j * kvec * offsets[0])
    out[..., 0, :] = first if scale is None else scale * first
    if n > 1:
        step = step.astype(dtype)[..., None, :]
        done = 1
        while done < n:
            w = min(done, n - done)
            np.multiply(out[..., :w, :], step, out=out[..., done:done + w, :])
            done += w
            if done < n:
                step = step * step
    return out


def _power(z: np.ndarray, k: int) -> np.ndarray:
    """``z**k`` for an integer k ≥ 1 by repeated squaring (relative error ≲
    2·log2(k)·ε; 5× faster than ``z ** k`` on a complex array)."""
    out = None
    while k:
        if k & 1:
            out = z if out is None else out * z
        k >>= 1
        if k:
            z = z * z
    return out


def debye_intensity(sp: ReferenceSphere, ox: np.ndarray, oy: np.ndarray, zero_opd: bool = False) -> np.ndarray:
    """|E|² from the Debye sum (module docstring) at the image-plane points
    ``P0 + (ox[j], oy[i])``.

    ``E = (1/λ') Σ_i c_i e^{ikW_i} e^{ik' ŝ_i·Δ}``, ``ŝ_i`` the unit vector
    from the source on the sphere to P0 (the Huygens sum with
    ``r ≈ R + ŝ·Δ``, K = 1, R/r = 1). Separable in x and y on a grid, so
    two matrix products instead of rays × pixels exponentials.

    Parameters
    ----------
    sp : ReferenceSphere
    ox, oy : (nx,), (ny,) ndarray
        Uniformly spaced offsets from P0 along x and y, mm.
    zero_opd : bool
        Drop the optical path differences (the aberration-free pupil).

    Returns
    -------
    (ny, nx) ndarray
        Intensity in the units of :func:`calibration.optics.psf.huygens.huygens_intensity`.
    """
    lam_m = sp.wavelength_nm * 1e-6 / sp.n_img
    k_m = 2.0 * math.pi / lam_m
    s = -sp.q / np.linalg.norm(sp.q, axis=1, keepdims=True)
    c = sp.amp * np.exp(1j * sp.k * sp.opd) if not zero_opd else sp.amp.astype(np.complex128)
    x = phasors(k_m * s[:, 0], ox)                     # (nx, M)
    y = phasors(k_m * s[:, 1], oy, scale=c)            # (ny, M), times c
    e = at_b(y.T, x.T) / lam_m                         # (ny, nx)
    return e.real ** 2 + e.imag ** 2


def debye_samples(sp: ReferenceSphere, ox: np.ndarray, oy: np.ndarray) -> tuple[np.ndarray, float]:
    """The Debye PSF's samples on ``P0 + (ox[j], oy[i])`` (summing to 1)
    and its window energy, in the Huygens units
    (:func:`~calibration.optics.psf.huygens.huygens_samples`)."""
    inten = debye_intensity(sp, ox, oy)
    return normalized_samples(sp, inten, sp.power / sp.flux_cos, ox)


DEBYE_SUM_DTYPE = np.complex64
"""Precision of the phasor tables and their product in the batched Debye
sums of the SFR model (:func:`debye_node_psfs`); the rays' phases, the
tables' first rows and steps and the intensities stay float64. Measured
on e9 (15 × 20 nodes, 48 pupil samples, 600 edges, 3 perturbed lenses):
SFRA within 5e-9 cycles/pixel RMS (2e-8 max) of complex128, PSFs within
3.4e-7 of their peak, for a fifth less PSF time (half the GEMM's). The
per-field PSFs (:func:`debye_psf`, PSF maps) stay complex128."""


def debye_node_psfs(tn: TracedNodes, centers: np.ndarray, z_image, ox: np.ndarray, oy: np.ndarray,
                    chunk: int = 2, dtype=None, energy: bool = False):
    """Normalised Debye PSFs of every field of ``tn``, (K, len(oy), len(ox)):
    ``debye_samples(reference_sphere(tn.node(k), centers[k]), ox, oy)[0]``
    about the image-plane points ``centers`` (K, 2) mm, with the image
    plane at ``z_image`` (scalar or (K,), mm), ``chunk`` fields per
    vectorised step. Rays off the sphere enter with zero amplitude.
    ``dtype``: of the phasor tables and their product, default
    :data:`DEBYE_SUM_DTYPE` (complex128 reproduces the per-field path to
    ~1e-12). ``energy``: also return each field's window energy (K,), the
    fraction of its exit-pupil power on the window (``PSF.window_energy``,
    :mod:`calibration.optics.psf.pupil`)."""
    dtype = DEBYE_SUM_DTYPE if dtype is None else dtype
    k = len(tn)
    z = np.broadcast_to(np.asarray(tn.z_image if z_image is None else z_image, dtype=np.float64), (k,))
    q, opd, amp = node_spheres(tn, np.asarray(centers, dtype=np.float64), z)
    lam_m = tn.wavelength_nm * 1e-6 / tn.n_img
    k_m = 2.0 * math.pi / lam_m
    s = -q / np.linalg.norm(q, axis=2, keepdims=True)
    c = amp * np.exp(1j * (2.0 * math.pi / (tn.wavelength_nm * 1e-6)) * opd)
    out = np.empty((k, len(oy), len(ox)))
    for a in range(0, k, chunk):
        b = slice(a, min(a + chunk, k))
        y = phasors(k_m * s[b, :, 1], oy, scale=c[b], dtype=dtype)      # (B, ny, M), times c
        x = phasors(k_m * s[b, :, 0], ox, dtype=dtype)                  # (B, nx, M)
        e = a_bt(y, x)
        out[b] = (e.real.astype(np.float64) ** 2 + e.imag.astype(np.float64) ** 2) / (lam_m * lam_m)
    total = out.sum(axis=(1, 2))
    bad = ~(np.isfinite(total) & (total > 0))
    if np.any(bad):
        i = int(np.argmax(bad))
        raise PSFError(f"the PSF at {tn.wavelength_nm:g} nm has no energy in the window (centre "
                       f"{np.asarray(centers)[i]} mm); check center, n and pitch_um")
    if not energy:
        return out / total[:, None, None]
    # Σ I·pitch²·N_h / P, as debye_samples: P the rays' power M Δp², N_h their harmonic-mean cosine to the plane
    ok = amp > 0
    dp = 2.0 / tn.samples
    power = np.count_nonzero(ok, axis=1) * dp * dp
    inv_cos = np.where(ok, 1.0 / np.maximum(np.abs(tn.dirn[..., 2]), 1e-12), 0.0)
    n_h = np.count_nonzero(ok, axis=1) / inv_cos.sum(axis=1)
    pitch2 = float(ox[1] - ox[0]) * float(oy[1] - oy[0]) if len(ox) > 1 and len(oy) > 1 else 0.0
    return out / total[:, None, None], total * pitch2 * n_h / power


def debye_psf(lens: Lens | PerturbedLens, field_deg, wavelength_nm: float, *, pupil_samples: int = 64,
              n: int = 128, pitch_um: float | None = None, center="chief", aiming: str = "real") -> PSF:
    """Monochromatic PSF by the Debye-approximated Huygens sum on the grid
    (module docstring): the accuracy of
    :func:`~calibration.optics.psf.huygens.huygens_psf` to ~1e-3 of the
    peak at a fraction of its cost. Parameters as
    :func:`~calibration.optics.psf.huygens.huygens_psf`.

    Returns
    -------
    PSF
        ``data`` (n, n) summing to 1, ``method="debye"``.
    """
    return monochromatic_psf(lens, field_deg, wavelength_nm, "debye", debye_samples, pupil_samples=pupil_samples,
                             n=n, pitch_um=pitch_um, center=center, aiming=aiming)

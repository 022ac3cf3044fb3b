"""The pupil-function FFT PSF: the classical cross-check of the Huygens sum
(Goodman §6.3–6.4; the Debye integral, Born & Wolf §8.8).

The optical path difference on the reference sphere
(:mod:`calibration.optics.psf.pupil`), sampled on the pupil grid,
zero-padded and Fourier transformed.

With ``r ≈ R + D·(P − P0)`` (Debye) the Huygens sum becomes
``E(Δ) ∝ Σ_p a_p e^{ik(W_p + L̃_p Δx + M̃_p Δy)}`` (``L̃ = n'L``, optical
direction cosines). The pupil grid is assumed uniform in direction cosines,
``(L̃, M̃) ≈ (L̃₀, M̃₀) + A·(px, py)`` with ``A`` the 2×2 least-squares fit of
the real rays (anamorphic and sheared off axis; a ``diag`` matrix only on a
symmetry plane; :attr:`~calibration.optics.psf.pupil.ReferenceSphere.affine`);
the error of the approximation is the pupil distortion, ``k·δL̃·|Δ|``. Then
``E`` is a function of ``ξ = Aᵀ Δ``, sampled by ``ifft2`` of the
zero-padded pupil at ``Δξ = λ/(N_fft·Δp)`` (mm per unit of ``ξ``; the
image-plane spacing is ``λ/(N_fft·Δ(direction cosine))``), and the
intensity is interpolated (cubic spline, periodic; ``N_fft = 4·pupil_samples``
samples it at twice Nyquist) onto the requested square grid, so it can be
compared sample by sample with the Huygens PSF. The FFT period,
``λ·pupil_samples/(2·NA)`` ≈ ``pupil_samples·λ·N`` in the image, must exceed
the window (else the PSF wraps): :class:`~calibration.optics.psf.result.PSFError`
says so.

The window energy is the window's share of the lattice's own energy — by
Parseval all of the power, wrapped into one period — which avoids the ≈ 1 %
error of the affine pupil map in absolute units.

References: J. W. Goodman, *Introduction to Fourier Optics*, 3rd ed.,
Roberts & Co. 2005, §6.3–6.4; M. Born and E. Wolf, *Principles of Optics*,
7th ed., Cambridge University Press 1999, §8.8 (Debye integral).

Imports scipy (lazily) and :mod:`~calibration.optics.psf.pupil`,
:mod:`~calibration.optics.psf.sampling` and
:mod:`~calibration.optics.psf.result` of this package.
"""

from __future__ import annotations

import numpy as np

from calibration.optics.lens import Lens
from calibration.optics.perturb import PerturbedLens
from calibration.optics.psf.pupil import ReferenceSphere
from calibration.optics.psf.result import PSF, PSFError
from calibration.optics.psf.sampling import monochromatic_psf, normalized_samples

__all__ = ["fft_intensity", "fft_lattice", "fft_psf", "fft_samples", "pupil_function"]


def pupil_function(sp: ReferenceSphere, zero_opd: bool = False) -> np.ndarray:
    """The sampled pupil function ``a·e^{ikW}``, (samples, samples) complex128:
    each ray's energy-conserving amplitude and phase at its pupil-grid cell
    (row ``iy``, column ``ix``), zero outside the traced rays;
    ``zero_opd`` drops the phase (the aberration-free pupil)."""
    f = np.zeros((sp.samples, sp.samples), dtype=np.complex128)
    ph = np.zeros_like(sp.opd) if zero_opd else sp.k * sp.opd
    f[sp.iy, sp.ix] = sp.amp * np.exp(1j * ph)
    return f


def fft_lattice(sp: ReferenceSphere, pad: int = 4, workers: int | None = None) -> tuple[np.ndarray, float]:
    """|E|² on the ξ lattice and its spacing.

    Parameters
    ----------
    sp : ReferenceSphere
    pad : int
        Zero-padding factor: the lattice is ``next_fast_len(pad·samples)``
        square.
    workers : int, optional
        FFT threads, default one per core.

    Returns
    -------
    lattice : (nf, nf) ndarray
        Intensity, fftshifted (``ξ = 0`` at ``[nf//2, nf//2]``), in absolute
        units (:mod:`calibration.optics.psf.pupil`).
    dxi : float
        Lattice spacing Δξ, mm.
    """
    from scipy import fft as sfft

    nf = sfft.next_fast_len(pad * sp.samples)
    f = np.zeros((nf, nf), dtype=np.complex128)
    f[:sp.samples, :sp.samples] = pupil_function(sp)
    e = sfft.ifft2(f, workers=workers if workers is not None else -1) * (nf * nf)
    lam_m = sp.wavelength_nm * 1e-6 / sp.n_img
    inten = (e.real ** 2 + e.imag ** 2) / (lam_m * lam_m)
    dxi = sp.wavelength_nm * 1e-6 * sp.samples / (2.0 * nf)      # λ/(N_fft Δp), Δp = 2/samples
    return np.fft.fftshift(inten), dxi


def fft_intensity(sp: ReferenceSphere, ox: np.ndarray, oy: np.ndarray, pad: int = 4,
                  workers: int | None = None) -> tuple[np.ndarray, float]:
    """The FFT model's |E|² at ``P0 + (ox[j], oy[i])`` (offsets in mm),
    interpolated from the lattice (shape (len(oy), len(ox))), and the
    lattice's total energy ``∫|E|² dA`` (Parseval: one period holds all of
    it). :class:`PSFError` if the window exceeds the FFT period."""
    from scipy.ndimage import map_coordinates

    lat, dxi = fft_lattice(sp, pad, workers)
    nf = lat.shape[0]
    a = sp.affine
    gx, gy = np.meshgrid(ox, oy)
    xi_x = a[0, 0] * gx + a[1, 0] * gy                 # ξ = Aᵀ Δ
    xi_y = a[0, 1] * gx + a[1, 1] * gy
    half = 0.5 * nf * dxi
    if np.max(np.abs(xi_x)) > half or np.max(np.abs(xi_y)) > half:
        period_um = 2 * half / max(np.abs(a).max(), 1e-300) * 1e3
        raise PSFError(f"the PSF window ({_span_um(ox, oy):.3g} µm) exceeds the FFT period (≈ {period_um:.3g} µm "
                       f"at {sp.wavelength_nm:g} nm with {sp.samples} pupil samples); increase pupil_samples "
                       "or reduce n·pitch")
    coords = np.array([xi_y / dxi + nf // 2, xi_x / dxi + nf // 2])
    out = map_coordinates(lat, coords, order=3, mode="grid-wrap", prefilter=True)
    total = float(lat.sum()) * dxi * dxi / abs(float(np.linalg.det(a)))
    return np.maximum(out, 0.0), total


def _span_um(ox, oy) -> float:
    return float(max(np.ptp(ox), np.ptp(oy)) * 1e3)


def fft_samples(sp: ReferenceSphere, ox: np.ndarray, oy: np.ndarray, *, pad: int = 4,
                workers: int | None = None) -> tuple[np.ndarray, float]:
    """The FFT PSF's samples on ``P0 + (ox[j], oy[i])`` (summing to 1) and
    its window energy: the window's share of the lattice's own energy
    (module docstring). ``pad``: zero-padding factor; ``workers``: FFT
    threads, default one per core."""
    inten, total = fft_intensity(sp, ox, oy, pad, workers)
    return normalized_samples(sp, inten, total, ox)


def fft_psf(lens: Lens | PerturbedLens, field_deg, wavelength_nm: float, *, pupil_samples: int = 128,
            n: int = 256, pitch_um: float | None = None, center="chief", aiming: str = "real") -> PSF:
    """Monochromatic PSF by the pupil-function FFT (the Huygens cross-check).

    Parameters are those of :func:`~calibration.optics.psf.huygens.huygens_psf`. The pupil function
    ``a·e^{ikW}`` (amplitude ``a`` the energy-conserving weight, zero
    outside the traced rays) is zero-padded to ``4·pupil_samples``,
    inverse-transformed, squared, and interpolated onto the requested grid
    through the real rays' affine direction-cosine map (module docstring).
    The window ``n·pitch_um`` must stay inside the FFT period
    ``≈ pupil_samples·λ·N``.

    Returns
    -------
    PSF
        ``data`` (n, n) summing to 1, ``method="fft"``.
    """
    return monochromatic_psf(lens, field_deg, wavelength_nm, "fft", fft_samples, pupil_samples=pupil_samples,
                             n=n, pitch_um=pitch_um, center=center, aiming=aiming)

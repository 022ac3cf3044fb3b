"""The Huygens PSF: spherical wavelets from the exit-pupil reference sphere,
summed on the image plane (paper, section 3.1.2, eqs. 11–13).

The paper's method and the reference (oracle) of the other two models
(:mod:`~calibration.optics.psf.fft`, :mod:`~calibration.optics.psf.debye`):
every traced ray, where it crosses the reference sphere
(:mod:`calibration.optics.psf.pupil`), is the source of a spherical wavelet;
the wavelets are summed on the image-plane grid and the intensity is |E|².

Huygens sum (eqs. 11–13). For sources ``Q_i`` on the sphere and image points
``P_j``

.. math::

    E(P_j) = \\frac{1}{i\\lambda'} \\sum_i R\\sqrt{J_{\\Omega,i}}\\,\\Delta p^2\\,
             \\frac{e^{ik'(r_{ij} - R) + ik W_i}}{r_{ij}}\\,K_{ij},\\qquad
    I_j = E_j E_j^*,

``r_ij = |P_j − Q_i|``, ``k = 2π/λ`` (vacuum), ``k' = n'k`` and ``λ' = λ/n'``
in the image-space medium. The paper's ``e^{ikl}/l`` (the wave from the
object point to the pupil) is the ray's optical path ``l`` (through ``W``);
its ``1/l`` is constant over the pupil for a distant object and is absorbed
by the energy-conserving amplitude (:mod:`calibration.optics.psf.pupil`).

Obliquity factor. We write

.. math::

    K_{ij} = \\tfrac{1}{2}\\left[\\cos\\langle \\mathbf{n}_i, \\mathbf{r}_{ij}\\rangle
                           + \\cos\\langle \\mathbf{n}_i, \\mathbf{D}_i\\rangle\\right]

with ``n_i`` the sphere's unit normal at ``Q_i`` pointing toward the image
(toward its centre ``P0``), ``D_i`` the ray's unit direction *of travel* and
``r_ij`` the vector from ``Q_i`` to ``P_j``, so K ≈ 1 for near-axial
propagation. The paper's eq. 12, ``½[cos⟨n, r⟩ − cos⟨n, D⟩]``, is the same
factor with ``D`` the Fresnel–Kirchhoff incidence vector pointing from the
aperture point back toward the source (Born & Wolf §8.3.2, their ``s``), i.e.
``D_paper = −D_i``: ``−cos⟨n, −D⟩ = +cos⟨n, D⟩``.

References: the paper (``../shared/paper``), §3.1.2; J. W. Goodman,
*Introduction to Fourier Optics*, 3rd ed., Roberts & Co. 2005, §3.5
(Rayleigh–Sommerfeld); M. Born and E. Wolf, *Principles of Optics*, 7th ed.,
Cambridge University Press 1999, §8.3 (Fresnel–Kirchhoff obliquity factor).

Imports :mod:`~calibration.optics.psf.pupil`,
:mod:`~calibration.optics.psf.sampling` and
:mod:`~calibration.optics.psf.result` of this package.
"""

from __future__ import annotations

import math
import os

import numpy as np

from isp.runtime.executor import shared_threads

from calibration.optics.lens import Lens
from calibration.optics.perturb import PerturbedLens
from calibration.optics.psf.pupil import ReferenceSphere
from calibration.optics.psf.result import PSF
from calibration.optics.psf.sampling import monochromatic_psf, normalized_samples

__all__ = ["huygens_intensity", "huygens_psf", "huygens_samples"]


_HUYGENS_PAIRS = 1 << 17   # rays × pixels per chunk (≈ 1 MB per float64 array; ~10 arrays live)


def huygens_intensity(sp: ReferenceSphere, ox: np.ndarray, oy: np.ndarray, *, zero_opd: bool = False,
                      workers: int | None = None) -> np.ndarray:
    """|E|² by the Huygens sum (module docstring) at the image-plane points
    ``P0 + (ox[j], oy[i])``.

    Parameters
    ----------
    sp : ReferenceSphere
        The sources: the traced rays on the reference sphere about P0.
    ox, oy : (nx,), (ny,) ndarray
        Offsets from P0 along x and y, mm.
    zero_opd : bool
        Drop the optical path differences (the aberration-free pupil).
    workers : int, optional
        Threads, default one per core (at most 8).

    Returns
    -------
    (ny, nx) ndarray
        Intensity in the absolute units of the energy-conserving amplitudes
        (:mod:`calibration.optics.psf.pupil`).
    """
    lam_m = sp.wavelength_nm * 1e-6 / sp.n_img
    k_m = 2.0 * math.pi / lam_m
    gx, gy = np.meshgrid(ox, oy)
    d = np.column_stack([gx.ravel(), gy.ravel()])       # (P, 2), z offset 0 (image plane)
    dd = np.einsum("ij,ij->i", d, d)
    q = sp.q
    rq = np.sqrt(np.einsum("ij,ij->i", q, q))           # = R up to rounding
    nrm = -q / rq[:, None]                              # sphere normal toward P0
    qxy = np.ascontiguousarray(q[:, :2])
    nxy = np.ascontiguousarray(nrm[:, :2])
    cos_d = np.einsum("ij,ij->i", nrm, sp.dirn)
    weight = 0.5 * sp.radius * sp.amp                   # ½ of K folded in
    phase0 = np.zeros_like(sp.opd) if zero_opd else sp.k * sp.opd
    rq2 = rq * rq
    m = len(q)
    block = max(1, _HUYGENS_PAIRS // m)
    out = np.empty(len(d), dtype=np.complex128)

    def one(a: int):
        b = min(a + block, len(d))
        dc = d[a:b]
        r = qxy @ (-2.0 * dc.T)
        r += rq2[:, None]
        r += dd[None, a:b]
        np.sqrt(r, out=r)
        amp = nxy @ dc.T                                # n·(P − Q) = |Q − P0| + n·d
        amp += rq[:, None]
        amp /= r
        amp += cos_d[:, None]                           # 2K
        amp *= weight[:, None]
        amp /= r
        ph = r - sp.radius
        ph *= k_m
        ph += phase0[:, None]
        c = np.cos(ph)
        np.sin(ph, out=ph)
        c *= amp
        ph *= amp
        out[a:b] = c.sum(axis=0) + 1j * ph.sum(axis=0)

    starts = range(0, len(d), block)
    ex = shared_threads(workers if workers is not None else min(os.cpu_count() or 1, 8))
    if ex.parallel and len(starts) > 1:
        ex.map(one, starts)
    else:
        for a in starts:
            one(a)
    e = out / lam_m                                     # the 1/(iλ') prefactor (its phase drops out)
    return (e.real ** 2 + e.imag ** 2).reshape(len(oy), len(ox))


def huygens_samples(sp: ReferenceSphere, ox: np.ndarray, oy: np.ndarray, *, workers: int | None = None
                    ) -> tuple[np.ndarray, float]:
    """The Huygens PSF's samples on ``P0 + (ox[j], oy[i])`` (summing to 1)
    and its window energy (:func:`~calibration.optics.psf.sampling.normalized_samples`).

    ``∫|E|² dA`` over the image plane is ``Σ P_i / N_i`` (each plane-wave
    component crosses it obliquely) ``= P / N_h``
    (:attr:`~calibration.optics.psf.pupil.ReferenceSphere.flux_cos`).
    ``workers``: threads, default one per core.
    """
    inten = huygens_intensity(sp, ox, oy, workers=workers)
    return normalized_samples(sp, inten, sp.power / sp.flux_cos, ox)


def huygens_psf(lens: Lens | PerturbedLens, field_deg, wavelength_nm: float, *, pupil_samples: int = 64,
                n: int = 128, pitch_um: float | None = None, center="chief", aiming: str = "real") -> PSF:
    """Monochromatic PSF by Huygens superposition from the exit pupil
    (paper eqs. 11–13).

    Parameters
    ----------
    lens : Lens or PerturbedLens
    field_deg : float or (θx, θy)
        Object field, degrees (a scalar is θy).
    wavelength_nm : float
    pupil_samples : int
        Pupil grid size across the stop (≈ 0.785·pupil_samples² rays).
    n : int
        PSF grid size (n × n samples).
    pitch_um : float, optional
        Sample spacing, µm; default ``λ·N_w/4``
        (:func:`calibration.optics.psf.sampling.default_pitch_um`).
    center : {"chief", "centroid"} or (x, y)
        Centre sample: the chief ray's image point at this wavelength, the
        geometric ray centroid, or an image-plane point in mm. The reference
        sphere is centred there.
    aiming : {"real", "paraxial"}
        Pupil ray aiming (:func:`calibration.optics.trace.pupil_rays`).

    Returns
    -------
    PSF
        ``data`` (n, n) summing to 1, ``method="huygens"``.

    Notes
    -----
    Cost ∝ rays × pixels (cos and sin in float64, chunked to ≈ 1 MB per
    array, on a thread per core): 3.2k rays × 128² samples take ≈ 1.5 s on
    2 cores (:func:`debye_psf`: 0.06 s for the same PSF within ~1e-4 of
    the peak on e9).
    """
    return monochromatic_psf(lens, field_deg, wavelength_nm, "huygens", huygens_samples, pupil_samples=pupil_samples,
                             n=n, pitch_um=pitch_um, center=center, aiming=aiming)

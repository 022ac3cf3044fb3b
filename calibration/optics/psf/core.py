"""Point spread functions from the exit pupil (paper, section 3.1.2, eqs. 11–14).

References: the paper (``../shared/paper``), §3.1.2; J. W. Goodman,
*Introduction to Fourier Optics*, 3rd ed., Roberts & Co. 2005, §3.5
(Rayleigh–Sommerfeld) and §6.3–6.4; M. Born and E. Wolf, *Principles of
Optics*, 7th ed., Cambridge University Press 1999, §8.3 (Fresnel–Kirchhoff
obliquity factor) and §8.8 (Debye integral); G. H. Golub and J. H. Welsch,
"Calculation of Gauss quadrature rules", *Math. Comp.* 23 (1969) 221–230.

Three diffraction models share one ray trace:

* :func:`huygens_psf` — the paper's method (eqs. 11–13): every traced ray,
  where it crosses the exit-pupil reference sphere, is the source of a
  spherical Huygens wavelet; the wavelets are summed on the image-plane grid
  and the intensity is |E|². The reference (oracle) of the other two.
* :func:`fft_psf` — the pupil-function method (Goodman §6.3–6.4; the Debye
  integral, Born & Wolf §8.8): the optical path difference on the same
  reference sphere, sampled on the pupil grid, zero-padded and Fourier
  transformed; the classical cross-check.
* :func:`debye_psf` — the Huygens sum in the Debye approximation
  (``r ≈ R + ŝ·Δ``) with each ray's *real* direction, evaluated directly on
  the requested grid: separable in x and y, so two phasor tables and one
  matrix product (a "matrix Fourier transform", Soummer et al., *Opt.
  Express* 15 (2007) 15935) instead of rays × pixels exponentials; no
  affine pupil map, no interpolation. The PSF-map default.

Measured on US-12210142-B2-e9 (32² PSFs at 0.5 µm, 64 pupil samples, 450–610
nm, six regions from the centre to the corner; ``benchmarks/psf.py``): the
Debye PSFs are within 0.06 % of the Huygens PSFs' peak, the FFT PSFs within
0.2–0.9 % and up to 4.5 % in the corner, where the pupil map is least
affine.

:func:`polychromatic_psf` integrates either over a sensor channel's spectral
response (eq. 14), :func:`strehl_ratio` compares the peak with the
aberration-free pupil's.

The SFR model (:mod:`calibration.fit.forward_model`) needs the Debye PSFs of a few
hundred fields per lens evaluation; it traces them in one batch
(:class:`_TracedNodes`) and fits their pupils and sums their wavelets all
at once (:func:`_node_jacobians`, :func:`_debye_nodes`), with the
per-field functions here as the oracle (equal to ~1e-10 of the peak in
complex128; :data:`DEBYE_SUM_DTYPE`).

Conventions
-----------
Units: mm for geometry (image-plane positions ``center_mm``), µm for the PSF
sample spacing ``pitch_um`` and offsets, nm for wavelengths, degrees for
fields ``(θx, θy)`` (object-space direction, :mod:`calibration.optics.trace`).
Light travels +z; the image plane is the lens's (``z`` of its image pose).

Sample grid. ``PSF.data[i, j]`` is the intensity at the image-plane point
``x = cx + (j − n//2)·pitch``, ``y = cy + (i − n//2)·pitch`` with
``(cx, cy) = center_mm``: columns run along +x, rows along +y, and the centre
sample is ``data[n//2, n//2]``. ``data`` holds point samples of the
intensity, scaled so that the samples sum to 1 (so a sample ≈ the energy of
its ``pitch²`` cell).

Pupil sampling. A square ``pupil_samples × pupil_samples`` grid of cell
centres in the unit disc (:func:`calibration.optics.trace.pupil_grid`, "grid"),
aimed at the real stop by default (``aiming="real"``: the rays fill the stop,
chief ray through its centre) and traced per wavelength; vignetted rays are
dropped. Each ray carries the same power (uniformly filled stop).

Reference sphere. Centred on the PSF centre ``P0`` (the chief ray's image
point by default) and passing through the exit-pupil centre ``E``: where the
real chief ray, continued as a straight line in image space, crosses the
paraxial exit-pupil plane (:func:`calibration.optics.paraxial.first_order` at the
primary wavelength; the last surface's vertex plane if the lens is
telecentric in image space). For a virtual exit pupil (the usual case in
phone lenses: the pupil plane lies inside the lens) the image-space rays are
continued *backwards* to it; their optical path is extended (or shortened)
by ``n'·s`` accordingly. The OPD of a ray is its optical path to the sphere
minus the chief ray's, ``W = OPL − OPL_chief`` (mm); only W enters the
phases, so they stay small and float64 keeps them to ~1e-11 rad.

Amplitude. A ray of power ``Δp²`` (``Δp = 2/pupil_samples``) that covers the
solid angle ``dΩ = J_Ω Δp²`` on the sphere (``J_Ω = |∂(L, M)/∂(px, py)|/N``
from a least-squares polynomial fit of the real ray direction cosines
``(L, M, N)`` over the normalised pupil coordinates) has amplitude
``1/(R √J_Ω)``; its wavelet weight ``U dA = R √J_Ω Δp²`` therefore conserves
energy, and pupil aberrations (a non-uniform mapping of the stop onto the
sphere) apodise the pupil as they physically do. Fresnel losses and
coatings are not modelled. With this normalisation the intensity is
absolute: ``PSF.window_energy`` is the fraction of the exit-pupil power that
crosses the sampled window, ``Σ I·pitch²·N_h / P`` (``N_h`` the harmonic mean
of the rays' direction cosine to the image-plane normal: off axis the beam
crosses the plane obliquely); a truncation check, ≈ 1 for a generous window.
(The FFT model reports the window's share of its own lattice energy — by
Parseval all of the power, wrapped into one period — which avoids the ≈ 1 %
error of its affine pupil map in absolute units.)

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
by the energy-conserving amplitude.

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

FFT model. With ``r ≈ R + D·(P − P0)`` (Debye) the sum becomes
``E(Δ) ∝ Σ_p a_p e^{ik(W_p + L̃_p Δx + M̃_p Δy)}`` (``L̃ = n'L``, optical
direction cosines). The pupil grid is assumed uniform in direction cosines,
``(L̃, M̃) ≈ (L̃₀, M̃₀) + A·(px, py)`` with ``A`` the 2×2 least-squares fit of
the real rays (anamorphic and sheared off axis; a ``diag`` matrix only on a
symmetry plane); the error of the approximation is the pupil distortion,
``k·δL̃·|Δ|``. Then ``E`` is a function of ``ξ = Aᵀ Δ``, sampled by
``ifft2`` of the zero-padded pupil at ``Δξ = λ/(N_fft·Δp)`` (mm per unit of
``ξ``; the image-plane spacing is ``λ/(N_fft·Δ(direction cosine))``), and the
intensity is interpolated (cubic spline, periodic; ``N_fft = 4·pupil_samples``
samples it at twice Nyquist) onto the requested square grid, so it can be
compared sample by sample with the Huygens PSF. The FFT period,
``λ·pupil_samples/(2·NA)`` ≈ ``pupil_samples·λ·N`` in the image, must exceed
the window (else the PSF wraps): :class:`PSFError` says so.

Debye model. ``E(Δ) = (1/λ') Σ_i a_i e^{ikW_i} e^{ik' ŝ_i·Δ}`` with ``ŝ_i``
the unit vector from the source ``Q_i`` on the sphere to ``P0``: the Huygens
sum without the terms of second order in ``|Δ|/R`` — their ray-dependent
part, ``k'(ŝ·Δ)²/2R``, is ≈ 0.01 rad at 8 µm from the centre on e9; the
part common to all rays drops out of |E|² — with ``K = 1`` and ``R/r = 1``. On a grid
``e^{ik'ŝ·Δ} = e^{ik'ŝ_x Δx} e^{ik'ŝ_y Δy}``, so ``E = Yᵀ·diag(a e^{ikW})·X``.

Default sample spacing: ``λ_min·N_w/4`` — half the Nyquist spacing
``λN_w/2`` of the incoherent cut-off ``1/(λN_w)`` (``N_w`` the paraxial
working F/# in image space, ``λ_min`` the shortest wavelength used), so peaks
and the first dark ring are resolved.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from calibration.optics import paraxial
from calibration.optics.lens import Lens, LensError
from calibration.optics.perturb import PerturbedLens, nominal
from calibration.optics.trace import Rays, pupil_grid, pupil_rays, stop_and_pupil, trace_to_exit

__all__ = [
    "DEFAULT_CAMERA",
    "METHODS",
    "PSF",
    "PSFError",
    "debye_psf",
    "fft_psf",
    "huygens_psf",
    "ncc",
    "polychromatic_psf",
    "spectral_quadrature",
    "spectral_response",
    "strehl_ratio",
]

DEFAULT_CAMERA = "Nikon 5100 (NPL)"
"""Measured camera sensitivities used for the "R", "G", "B" channels
(``colour.MSDS_CAMERA_SENSITIVITIES``, NPL measurements shipped with
colour-science; the only other entry is "Sigma SDMerill (NPL)"). No phone
sensor is in that set: pass measured phone curves as ``(wavelengths, weights)``
where they are known."""

DEFAULT_WAVELENGTHS_PER_CHANNEL = 3
"""Gauss nodes per channel (see :func:`spectral_quadrature`). Measured on
US-12210142-B2-e9 (Debye PSFs 48² at 0.25 µm centred on the primary chief
ray, D65 × Nikon 5100, worst of R/G/B), largest |PSF − dense 5 nm sum| /
peak (the dense sum has 56–60 wavelengths):

========  =========  =========  =========
nodes     on axis    0.7 field  1.0 field
========  =========  =========  =========
1         1.5 %      7.0 %      17 %
2         0.19 %     0.88 %     4.9 %
3         0.03 %     0.16 %     1.5 %
4         0.01 %     0.06 %     0.64 %
========  =========  =========  =========

(NCC ≥ 0.9998 with 3 nodes everywhere; ``benchmarks/psf.py --quadrature``).
Lateral colour spreads the wavelengths apart toward the corners, so the
error grows with field."""

_HUYGENS_PAIRS = 1 << 17   # rays × pixels per chunk (≈ 1 MB per float64 array; ~10 arrays live)


class PSFError(LensError):
    """A PSF that cannot be computed as asked (bad settings, no rays through
    the lens, a window larger than the FFT period); the message says what to
    change."""


# -- the PSF record ------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class PSF:
    """A sampled point spread function.

    Attributes
    ----------
    data : (n, n) ndarray, float64
        Intensity samples, summing to 1 (see the module docstring for the
        grid: rows along +y, columns along +x, centre ``data[n//2, n//2]``).
    pitch_um : float
        Sample spacing on the image plane, µm.
    center_mm : (2,) tuple
        Image-plane (x, y) of the centre sample, mm.
    field_deg : (2,) tuple
        Object field (θx, θy), degrees.
    wavelengths_nm : tuple of float
        The wavelengths summed (one for a monochromatic PSF).
    weights : tuple of float
        Their weights (sum 1).
    method : str
        "huygens", "fft", or "resampled(<method>)".
    window_energy : float
        Fraction of the exit-pupil power that fell on the window before
        normalisation (weighted over wavelengths); NaN where unknown.
    """

    data: np.ndarray
    pitch_um: float
    center_mm: tuple[float, float]
    field_deg: tuple[float, float]
    wavelengths_nm: tuple[float, ...]
    weights: tuple[float, ...]
    method: str
    window_energy: float = math.nan

    def __post_init__(self):
        d = np.asarray(self.data, dtype=np.float64)
        if d.ndim != 2 or d.shape[0] != d.shape[1]:
            raise PSFError(f"PSF data must be square (n, n), got shape {d.shape}")
        if not (math.isfinite(self.pitch_um) and self.pitch_um > 0):
            raise PSFError(f"pitch_um must be positive, got {self.pitch_um!r}")
        object.__setattr__(self, "data", d)
        object.__setattr__(self, "center_mm", tuple(float(v) for v in self.center_mm))
        object.__setattr__(self, "field_deg", tuple(float(v) for v in self.field_deg))
        object.__setattr__(self, "wavelengths_nm", tuple(float(v) for v in self.wavelengths_nm))
        object.__setattr__(self, "weights", tuple(float(v) for v in self.weights))

    @property
    def n(self) -> int:
        return self.data.shape[0]

    def offsets_um(self) -> np.ndarray:
        """(n,) sample offsets from the centre along x (and y), µm."""
        return (np.arange(self.n) - self.n // 2) * self.pitch_um

    def coordinates_mm(self) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) image-plane coordinates of the columns and rows, mm."""
        o = self.offsets_um() * 1e-3
        return self.center_mm[0] + o, self.center_mm[1] + o

    @property
    def centroid_um(self) -> np.ndarray:
        """(x, y) intensity centroid relative to the centre sample, µm."""
        o = self.offsets_um()
        s = self.data.sum()
        return np.array([float(self.data.sum(axis=0) @ o / s), float(self.data.sum(axis=1) @ o / s)])

    @property
    def peak_um(self) -> np.ndarray:
        """(x, y) of the brightest sample relative to the centre sample, µm."""
        i, j = np.unravel_index(int(np.argmax(self.data)), self.data.shape)
        o = self.offsets_um()
        return np.array([o[j], o[i]])

    def encircled_energy(self, radius_um, about: str | Sequence[float] = "centroid",
                         supersample: int = 8) -> np.ndarray | float:
        """Share of the window's energy within ``radius_um`` (scalar or array,
        µm) of the centroid (``about="centroid"``), the centre sample
        ("center") or an (x, y) offset in µm. Each sample is spread
        uniformly over its ``pitch²`` cell, integrated on a
        ``supersample²`` sub-grid.

        >>> p = PSF(np.full((4, 4), 1 / 16), 1.0, (0, 0), (0, 0), (550,), (1,), "test")
        >>> round(float(p.encircled_energy(10.0)), 6)
        1.0
        """
        if isinstance(about, str):
            if about == "centroid":
                c = self.centroid_um
            elif about == "center":
                c = np.zeros(2)
            else:
                raise PSFError(f"unknown about={about!r}; valid: 'centroid', 'center', or an (x, y) offset in µm")
        else:
            c = np.asarray(about, dtype=np.float64).reshape(2)
        r = np.asarray(radius_um, dtype=np.float64)
        s = int(supersample)
        sub = ((np.arange(s) + 0.5) / s - 0.5) * self.pitch_um
        o = self.offsets_um()
        xs = (o[:, None] + sub[None, :]).ravel() - c[0]
        ys = (o[:, None] + sub[None, :]).ravel() - c[1]
        d2 = (ys[:, None] ** 2 + xs[None, :] ** 2).reshape(self.n, s, self.n, s)
        w = self.data / (s * s)
        out = np.array([float(np.sum(w * np.count_nonzero(d2 <= rr * rr, axis=(1, 3)))) for rr in r.ravel()])
        out /= float(self.data.sum())
        return float(out[0]) if r.ndim == 0 else out.reshape(r.shape)

    def resample(self, pitch_um: float, n: int, center_mm: Sequence[float] | None = None,
                 *, normalize: bool = False) -> PSF:
        """The PSF rebinned onto another square grid, conserving energy.

        Each sample is spread uniformly over its ``pitch²`` cell and each new
        cell receives the energy of the overlap (separable overlap
        matrices), so the result's sum is exactly the energy of the old PSF
        inside the new window — 1 (to rounding) when the new window covers
        the old one. Suited to coarser grids (it integrates, e.g. over a
        pixel aperture); for a finer grid compute the PSF at that pitch.

        Parameters
        ----------
        pitch_um : float
            New spacing, µm.
        n : int
            New size.
        center_mm : (x, y), optional
            New centre sample position (default: the same centre).
        normalize : bool
            Rescale to sum 1 (when the new window cuts off energy).

        >>> p = PSF(np.full((4, 4), 1 / 16), 1.0, (0, 0), (0, 0), (550,), (1,), "test")
        >>> q = p.resample(2.0, 3)
        >>> round(float(q.data.sum()), 12), float(q.data[1, 1])
        (1.0, 0.25)
        """
        if not (math.isfinite(pitch_um) and pitch_um > 0):
            raise PSFError(f"pitch_um must be positive, got {pitch_um!r}")
        n = _positive_int(n, "n")
        c_new = self.center_mm if center_mm is None else tuple(float(v) for v in center_mm)
        shift = (np.asarray(c_new) - np.asarray(self.center_mm)) * 1e3   # µm, new centre in old frame
        o_old = self.offsets_um()
        o_new = (np.arange(n) - n // 2) * float(pitch_um)

        def overlap(shift_1d):
            a0 = o_old - 0.5 * self.pitch_um
            a1 = o_old + 0.5 * self.pitch_um
            b0 = o_new + shift_1d - 0.5 * pitch_um
            b1 = o_new + shift_1d + 0.5 * pitch_um
            w = np.minimum(b1[:, None], a1[None, :]) - np.maximum(b0[:, None], a0[None, :])
            return np.maximum(w, 0.0) / self.pitch_um

        wx, wy = overlap(shift[0]), overlap(shift[1])
        out = wy @ self.data @ wx.T
        if normalize:
            s = out.sum()
            if s <= 0:
                raise PSFError("the new window holds none of the PSF's energy")
            out = out / s
        return PSF(out, float(pitch_um), c_new, self.field_deg, self.wavelengths_nm, self.weights,
                   f"resampled({self.method})", self.window_energy)


def ncc(a: np.ndarray, b: np.ndarray) -> float:
    """Normalised cross-correlation of two equally sampled arrays at zero
    lag, ``Σ(a−ā)(b−b̄)/√(Σ(a−ā)² Σ(b−b̄)²)`` (1 = identical up to gain and
    offset).

    >>> ncc(np.arange(4.0), 2 * np.arange(4.0) + 1)
    1.0
    """
    a = np.asarray(a, dtype=np.float64).ravel()
    b = np.asarray(b, dtype=np.float64).ravel()
    if a.shape != b.shape:
        raise PSFError(f"ncc needs equal shapes, got {a.shape} and {b.shape}")
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b) / den if den > 0 else 0.0


# -- validation ------------------------------------------------------------------

def _positive_int(v, name: str) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
        raise PSFError(f"{name} must be a positive integer, got {v!r}")
    return int(v)


def _field(field_deg) -> tuple[float, float]:
    """A field as (θx, θy) degrees; a scalar is θy (the meridional plane)."""
    if np.ndim(field_deg) == 0:
        f = (0.0, float(field_deg))
    else:
        f = tuple(float(v) for v in np.asarray(field_deg, dtype=np.float64).ravel())
        if len(f) != 2:
            raise PSFError(f"field_deg must be θy or (θx, θy) in degrees, got {field_deg!r}")
    if not all(math.isfinite(v) and abs(v) < 90 for v in f):
        raise PSFError(f"field angles must be finite and within ±90°, got {field_deg!r}")
    return f


def _wavelength(w) -> float:
    w = float(w)
    if not (math.isfinite(w) and w > 0):
        raise PSFError(f"wavelength must be a positive number of nm, got {w!r}")
    return w


def _aiming(a: str) -> str:
    if a not in ("real", "paraxial"):
        raise PSFError(f"unknown aiming {a!r}; valid: 'real', 'paraxial'")
    return a


# -- tracing the pupil -----------------------------------------------------------

@dataclass(frozen=True, eq=False)
class _Traced:
    """Rays of one field and wavelength after the last surface (valid ones)."""

    wavelength_nm: float
    n_img: float
    samples: int
    ix: np.ndarray          # (M,) pupil-grid column of each valid ray
    iy: np.ndarray          # (M,) pupil-grid row
    p: np.ndarray           # (M, 2) normalised pupil coordinates
    pos: np.ndarray         # (M, 3) on the last surface, global mm
    dirn: np.ndarray        # (M, 3) unit directions in image space
    opl: np.ndarray         # (M,) optical path to the last surface, mm
    chief_pos: np.ndarray   # (3,) chief ray (clip=False), same data
    chief_dir: np.ndarray
    chief_opl: float
    z_image: float
    z_pupil: float          # z of the reference sphere's pupil plane

    def image_points(self) -> np.ndarray:
        """(M, 2) where the valid rays cross the image plane, mm."""
        t = (self.z_image - self.pos[:, 2]) / self.dirn[:, 2]
        return self.pos[:, :2] + t[:, None] * self.dirn[:, :2]

    def chief_image_point(self) -> np.ndarray:
        t = (self.z_image - self.chief_pos[2]) / self.chief_dir[2]
        return self.chief_pos[:2] + t * self.chief_dir[:2]


def _exit_pupil_z(pl: PerturbedLens) -> float:
    """z of the paraxial exit pupil (primary wavelength), or the last vertex
    plane for an image-space telecentric lens."""
    lens = pl.lens
    z_img = float(pl.image_pose.vertex[2])
    try:
        z = paraxial.first_order(lens).exit_pupil_z
    except (LensError, ZeroDivisionError, ValueError):
        z = math.inf
    if not math.isfinite(z) or abs(z_img - z) < 1e-6 or abs(z_img - z) > 1e4:
        z = float(pl.poses[-1].vertex[2])
    return float(z)


def _finish(pl: PerturbedLens, rays: Rays, res, field_deg, samples: int, z_pupil: float) -> _Traced:
    """_Traced from a trace of the pupil grid with the chief ray appended last."""
    lam = rays.wavelength_nm
    ok = res.valid & (res.direction[:, 2] > 0)
    chief_ok = bool(ok[-1])
    ok[-1] = False
    if np.count_nonzero(ok) < 8:
        raise PSFError(f"field {tuple(field_deg)} at {lam:g} nm: only {int(np.count_nonzero(ok))} "
                       f"of {len(rays) - 1} pupil rays reach the image (vignetted or failed)")
    if chief_ok:
        c_pos, c_dir, c_opl = res.position[-1].copy(), res.direction[-1].copy(), float(res.opl[-1])
    else:   # a vignetted chief ray still defines the field's centre: trace it without clipping
        ch = trace_to_exit(pl, Rays(rays.origin[-1:], rays.direction[-1:], lam, rays.opl[-1:], rays.status[-1:]),
                           clip=False)
        if not ch.valid[0] or ch.direction[0, 2] <= 0:
            raise PSFError(f"field {tuple(field_deg)} at {lam:g} nm: the chief ray does not reach the image")
        c_pos, c_dir, c_opl = ch.position[0].copy(), ch.direction[0].copy(), float(ch.opl[0])
    pc = rays.pupil[ok]
    ix = np.rint((pc[:, 0] + 1.0) * 0.5 * samples - 0.5).astype(np.intp)
    iy = np.rint((pc[:, 1] + 1.0) * 0.5 * samples - 0.5).astype(np.intp)
    n_img = float(pl.lens.surfaces[-1].material.index(lam))
    return _Traced(float(lam), n_img, samples, ix, iy, pc, res.position[ok], res.direction[ok], res.opl[ok],
                   c_pos, c_dir, c_opl, float(pl.image_pose.vertex[2]), float(z_pupil))


def _pupil_points(samples: int) -> np.ndarray:
    """The pupil grid with the chief ray (0, 0) appended."""
    return np.vstack([pupil_grid(samples, "grid"), [0.0, 0.0]])


def _trace(pl: PerturbedLens, field_deg, wavelength_nm: float, samples: int, aiming: str,
           z_pupil: float | None = None) -> _Traced:
    """Trace the pupil grid and the chief ray (one more pupil point, so real
    aiming runs once) to the last surface, aimed at this wavelength."""
    rays = pupil_rays(pl, field_deg, samples, wavelength_nm, aiming=aiming, pupil=_pupil_points(samples))
    return _finish(pl, rays, trace_to_exit(pl, rays), field_deg, samples,
                   _exit_pupil_z(pl) if z_pupil is None else z_pupil)


def _trace_set(pl: PerturbedLens, field_deg, wavelengths_nm: Sequence[float], samples: int, aiming: str,
               z_pupil: float | None = None, aim_each: bool = True) -> list[_Traced]:
    """:func:`_trace` for several wavelengths.

    ``aim_each=False`` (real aiming only): aim once, at the lens's primary
    wavelength, and send every wavelength through the same entrance-pupil
    points — the entrance pupil is defined at the primary wavelength.
    Pupil chromatism then over- or under-fills the stop slightly (e9:
    +1.5 µm of 1.08 mm at 440 nm); measured on e9 (FFT, 32² at 0.5 µm, 440
    and 650 nm, on axis to full field) the PSFs move by ≤ 0.6 % of the peak
    (NCC ≥ 0.99998), for half the tracing time.
    """
    z_pupil = _exit_pupil_z(pl) if z_pupil is None else float(z_pupil)
    wls = [float(w) for w in wavelengths_nm]
    if aim_each or aiming != "real":
        return [_trace(pl, field_deg, w, samples, aiming, z_pupil) for w in wls]
    pc = _pupil_points(samples)
    primary = float(pl.nominal.primary_nm)
    r0 = pupil_rays(pl, field_deg, samples, primary, aiming="real", pupil=pc)
    pp = stop_and_pupil(pl)
    t = (pp.z - r0.origin[:, 2]) / r0.direction[:, 2]
    ep = (r0.origin[:, :2] + t[:, None] * r0.direction[:, :2]) / pp.radius   # paraxial pupil coordinates
    out = []
    for w in wls:
        if w == primary:
            rays = r0
        else:
            r = pupil_rays(pl, field_deg, samples, w, aiming="paraxial", pupil=ep)
            rays = Rays(r.origin, r.direction, w, r.opl, r0.status, pc, r.field_deg)
        out.append(_finish(pl, rays, trace_to_exit(pl, rays), field_deg, samples, z_pupil))
    return out


# -- the reference sphere ----------------------------------------------------------

@dataclass(frozen=True, eq=False)
class _Sphere:
    """The traced rays on the exit-pupil reference sphere about P0."""

    wavelength_nm: float
    n_img: float
    samples: int
    ix: np.ndarray
    iy: np.ndarray
    p: np.ndarray          # (M, 2)
    q: np.ndarray          # (M, 3) sources relative to P0, mm
    dirn: np.ndarray       # (M, 3) unit ray directions
    opd: np.ndarray        # (M,) W = OPL − OPL_chief on the sphere, mm
    amp: np.ndarray        # (M,) √J_Ω Δp² (energy-conserving wavelet weight / R)
    radius: float          # R, mm
    p0: np.ndarray         # (3,) the sphere's centre (image plane), global mm
    power: float           # M Δp² (power through the pupil, same units)
    affine: np.ndarray     # (2, 2) A: d(n'L, n'M)/d(px, py)
    flux_cos: float        # harmonic mean of the rays' N (cosine to the image-plane normal)

    @property
    def k(self) -> float:
        """Vacuum wavenumber, 1/mm."""
        return 2.0 * math.pi / (self.wavelength_nm * 1e-6)


def _poly_terms(p: np.ndarray, degree: int):
    """Monomials px^a py^b (a + b ≤ degree) and their x/y derivatives."""
    x, y = p[:, 0], p[:, 1]
    cols, dx, dy = [], [], []
    for tot in range(degree + 1):
        for a in range(tot + 1):
            b = tot - a
            cols.append(x ** a * y ** b)
            dx.append(a * x ** max(a - 1, 0) * y ** b if a else np.zeros_like(x))
            dy.append(b * x ** a * y ** max(b - 1, 0) if b else np.zeros_like(x))
    return np.column_stack(cols), np.column_stack(dx), np.column_stack(dy)


_BLAS_ONE_THREAD = 1 << 18
"""OpenBLAS runs a real GEMM of more than 2^18 multiply-adds (a complex one
of almost any size) on all cores. When the cores are shared (a busy machine,
a process pool) its spin-waiting threads add ~30 ms to every such call —
measured 75 ms instead of 3.5 ms for the 3.2k-ray pupil fit, 20 ms instead of
50 µs for a 33×239×33 complex product. The small products here are
therefore done as real GEMMs chunked below that size, on one thread."""


def _at_b(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a.T @ b`` for tall (K, m), (K, n) arrays (real or complex), as real
    GEMMs in chunks of K that stay on one BLAS thread (see
    :data:`_BLAS_ONE_THREAD`); one plain product when even 32 rows of K
    would not."""
    if np.iscomplexobj(a) or np.iscomplexobj(b):
        ac, bc = np.asarray(a, np.complex128), np.asarray(b, np.complex128)
        m, n = ac.shape[1], bc.shape[1]
        r = _at_b(np.concatenate([ac.real, ac.imag], axis=1), np.concatenate([bc.real, bc.imag], axis=1))
        return (r[:m, :n] - r[m:, n:]) + 1j * (r[:m, n:] + r[m:, :n])
    k = a.shape[0]
    step = _BLAS_ONE_THREAD // max(a.shape[1] * b.shape[1], 1) - 1
    if step < 32:
        return a.T @ b
    out = a[:step].T @ b[:step]
    for s in range(step, k, step):
        out += a[s:s + step].T @ b[s:s + step]
    return out


def _lstsq(v: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least squares by the normal equations (columns scaled to unit norm;
    the monomials here are well conditioned on the unit disc)."""
    scale = np.sqrt(np.einsum("ij,ij->j", v, v))
    scale[scale == 0] = 1.0
    vs = v / scale
    return np.linalg.solve(_at_b(vs, vs), _at_b(vs, y)) / scale[:, None]


def _solid_angle_jacobian(p: np.ndarray, dirn: np.ndarray) -> np.ndarray:
    """J_Ω = |∂(L, M)/∂(px, py)| / N per ray, from a least-squares
    polynomial fit (degree ≤ 4, lower with few rays) of the direction
    cosines over the normalised pupil; the affine fit's constant J if the
    fit is unusable."""
    m = len(p)
    for degree in (4, 3, 2, 1):
        nterms = (degree + 1) * (degree + 2) // 2
        if m >= 4 * nterms:
            break
    v, vx, vy = _poly_terms(p, degree)
    coef = _lstsq(v, dirn[:, :2])
    lx, mx = (vx @ coef).T
    ly, my = (vy @ coef).T
    j = np.abs(lx * my - ly * mx) / dirn[:, 2]
    if not np.all(np.isfinite(j)) or np.any(j <= 0.05 * np.median(j)):
        v1 = _lstsq(_poly_terms(p, 1)[0], dirn[:, :2])
        j = np.full(m, abs(v1[1, 0] * v1[2, 1] - v1[2, 0] * v1[1, 1])) / dirn[:, 2]
    return j


def _sphere(tr: _Traced, center_xy: np.ndarray) -> _Sphere:
    p0 = np.array([center_xy[0], center_xy[1], tr.z_image])
    # Pupil centre: the chief ray (a straight line in image space) at the pupil plane.
    t = (tr.z_pupil - tr.chief_pos[2]) / tr.chief_dir[2]
    e = tr.chief_pos + t * tr.chief_dir
    radius = float(np.linalg.norm(p0 - e))

    def to_sphere(pos, d):
        w = pos - p0
        b = np.einsum("...i,...i->...", w, d)
        c = np.einsum("...i,...i->...", w, w) - radius * radius
        disc = b * b - c
        with np.errstate(invalid="ignore", divide="ignore"):
            s = c / (-b + np.sqrt(disc))   # the root on the lens side of P0 (stable form)
        return s, disc

    s, disc = to_sphere(tr.pos, tr.dirn)
    sc, _ = to_sphere(tr.chief_pos, tr.chief_dir)
    ok = (disc > 0) & np.isfinite(s)
    if np.count_nonzero(ok) < 8 or not math.isfinite(float(sc)):
        raise PSFError(f"the rays at {tr.wavelength_nm:g} nm do not cross the reference sphere "
                       f"(R = {radius:g} mm about {p0[:2]} mm)")
    n_img = tr.n_img
    q = tr.pos[ok] + s[ok, None] * tr.dirn[ok] - p0
    opd = (tr.opl[ok] + n_img * s[ok]) - (tr.chief_opl + n_img * float(sc))
    p = tr.p[ok]
    d = tr.dirn[ok]
    dp = 2.0 / tr.samples
    jac = _solid_angle_jacobian(p, d)
    amp = np.sqrt(jac) * dp * dp
    v1 = _lstsq(_poly_terms(p, 1)[0], n_img * d[:, :2])
    affine = np.array([[v1[2, 0], v1[1, 0]], [v1[2, 1], v1[1, 1]]])   # rows (L̃, M̃), columns (px, py)
    return _Sphere(tr.wavelength_nm, n_img, tr.samples, tr.ix[ok], tr.iy[ok], p, q, d, opd, amp, radius, p0,
                   float(np.count_nonzero(ok)) * dp * dp, affine, float(1.0 / np.mean(1.0 / d[:, 2])))


# -- the two diffraction models -------------------------------------------------------

def _grid_offsets_mm(n: int, pitch_um: float) -> np.ndarray:
    return (np.arange(n) - n // 2) * (pitch_um * 1e-3)


def _huygens_intensity(sp: _Sphere, ox: np.ndarray, oy: np.ndarray, *, zero_opd: bool = False,
                       workers: int | None = None) -> np.ndarray:
    """|E|² (absolute units, see the module docstring) at the image-plane
    points P0 + (ox[j], oy[i]) (mm offsets); shape (len(oy), len(ox))."""
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
    nw = workers if workers is not None else min(os.cpu_count() or 1, 8)
    if nw > 1 and len(starts) > 1:
        with ThreadPoolExecutor(max_workers=nw) as ex:
            list(ex.map(one, starts))
    else:
        for a in starts:
            one(a)
    e = out / lam_m                                     # the 1/(iλ') prefactor (its phase drops out)
    return (e.real ** 2 + e.imag ** 2).reshape(len(oy), len(ox))


def _phasors(kvec: np.ndarray, offsets: np.ndarray, scale: np.ndarray | None = None,
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


def _debye_intensity(sp: _Sphere, ox: np.ndarray, oy: np.ndarray, zero_opd: bool = False) -> np.ndarray:
    """|E|² (Huygens units) at P0 + (ox[j], oy[i]) from the Debye sum
    ``E = (1/λ') Σ_i c_i e^{ikW_i} e^{ik' ŝ_i·Δ}``, ``ŝ_i`` the unit vector
    from the source on the sphere to P0 (the Huygens sum with
    ``r ≈ R + ŝ·Δ``, K = 1, R/r = 1). Separable in x and y on a grid, so
    two matrix products instead of rays × pixels exponentials."""
    lam_m = sp.wavelength_nm * 1e-6 / sp.n_img
    k_m = 2.0 * math.pi / lam_m
    s = -sp.q / np.linalg.norm(sp.q, axis=1, keepdims=True)
    c = sp.amp * np.exp(1j * sp.k * sp.opd) if not zero_opd else sp.amp.astype(np.complex128)
    x = _phasors(k_m * s[:, 0], ox)                     # (nx, M)
    y = _phasors(k_m * s[:, 1], oy, scale=c)            # (ny, M), times c
    e = _at_b(y.T, x.T) / lam_m                         # (ny, nx)
    return e.real ** 2 + e.imag ** 2


def _pupil_array(sp: _Sphere, zero_opd: bool = False) -> np.ndarray:
    f = np.zeros((sp.samples, sp.samples), dtype=np.complex128)
    ph = np.zeros_like(sp.opd) if zero_opd else sp.k * sp.opd
    f[sp.iy, sp.ix] = sp.amp * np.exp(1j * ph)
    return f


def _fft_lattice(sp: _Sphere, pad: int = 4, workers: int | None = None):
    """|E|² on the ξ lattice (fftshifted, absolute units) and Δξ (mm)."""
    from scipy import fft as sfft

    nf = sfft.next_fast_len(pad * sp.samples)
    f = np.zeros((nf, nf), dtype=np.complex128)
    f[:sp.samples, :sp.samples] = _pupil_array(sp)
    e = sfft.ifft2(f, workers=workers if workers is not None else -1) * (nf * nf)
    lam_m = sp.wavelength_nm * 1e-6 / sp.n_img
    inten = (e.real ** 2 + e.imag ** 2) / (lam_m * lam_m)
    dxi = sp.wavelength_nm * 1e-6 * sp.samples / (2.0 * nf)      # λ/(N_fft Δp), Δp = 2/samples
    return np.fft.fftshift(inten), dxi


def _fft_intensity(sp: _Sphere, ox: np.ndarray, oy: np.ndarray, pad: int = 4,
                   workers: int | None = None) -> tuple[np.ndarray, float]:
    """The FFT model's |E|² at P0 + (ox[j], oy[i]), interpolated from the
    lattice (shape (len(oy), len(ox))), and the lattice's total energy
    ``∫|E|² dA`` (Parseval: one period holds all of it)."""
    from scipy.ndimage import map_coordinates

    lat, dxi = _fft_lattice(sp, pad, workers)
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


# -- many fields at once (the SFR model's path) --------------------------------------------

@dataclass(frozen=True, eq=False)
class _TracedNodes:
    """The pupil grids of K fields at one wavelength after the last surface.

    :class:`_Traced` of every field stacked on the common pupil grid: ray
    ``m`` of each field comes from pupil point ``p[m]``; ``valid`` marks the
    rays that reach the image (the others hold finite placeholders: position
    0, direction +z, OPL 0). ``jac`` is the solid-angle Jacobian J_Ω of the
    valid rays (:func:`_node_jacobians`; 0 elsewhere): it depends on the
    trace alone, so a change of the image plane (defocus) reuses it.
    """

    wavelength_nm: float
    n_img: float
    samples: int
    p: np.ndarray           # (M, 2) normalised pupil coordinates, shared
    valid: np.ndarray       # (K, M) bool
    pos: np.ndarray         # (K, M, 3) on the last surface, global mm
    dirn: np.ndarray        # (K, M, 3) unit directions in image space
    opl: np.ndarray         # (K, M) optical path to the last surface, mm
    chief_pos: np.ndarray   # (K, 3)
    chief_dir: np.ndarray   # (K, 3)
    chief_opl: np.ndarray   # (K,)
    z_image: float
    z_pupil: float
    jac: np.ndarray         # (K, M)

    def __len__(self) -> int:
        return self.valid.shape[0]

    def chief_image_points(self, z_image=None) -> np.ndarray:
        """(K, 2) where the chief rays cross ``z = z_image`` (scalar or (K,);
        default the image plane), mm — :meth:`_Traced.chief_image_point`."""
        z = self.z_image if z_image is None else np.asarray(z_image, dtype=np.float64)
        t = (z - self.chief_pos[:, 2]) / self.chief_dir[:, 2]
        return self.chief_pos[:, :2] + t[:, None] * self.chief_dir[:, :2]

    def node(self, k: int, z_image: float | None = None) -> _Traced:
        """Field ``k`` as a :class:`_Traced` (the per-field path: the
        reference of the batched one, and its fallback)."""
        ok = self.valid[k]
        pc = self.p[ok]
        ix = np.rint((pc[:, 0] + 1.0) * 0.5 * self.samples - 0.5).astype(np.intp)
        iy = np.rint((pc[:, 1] + 1.0) * 0.5 * self.samples - 0.5).astype(np.intp)
        return _Traced(self.wavelength_nm, self.n_img, self.samples, ix, iy, pc, self.pos[k, ok], self.dirn[k, ok],
                       self.opl[k, ok], self.chief_pos[k], self.chief_dir[k], float(self.chief_opl[k]),
                       self.z_image if z_image is None else float(z_image), self.z_pupil)


def _finish_nodes(pl: PerturbedLens, rays: Rays, res, fields, pupil: np.ndarray, samples: int,
                  z_pupil: float) -> _TracedNodes:
    """:func:`_finish` of K fields traced in one call: ``rays`` holds each
    field's ``pupil`` grid (M, 2) followed by its chief ray, field after
    field (K·(M + 1) rays)."""
    lam = rays.wavelength_nm
    k = len(fields)
    m1 = len(rays) // k
    ok = (res.valid & (res.direction[:, 2] > 0)).reshape(k, m1)
    pos = res.position.reshape(k, m1, 3)
    dirn = res.direction.reshape(k, m1, 3)
    opl = res.opl.reshape(k, m1)
    valid = ok[:, :-1]
    count = np.count_nonzero(valid, axis=1)
    if np.any(count < 8):
        i = int(np.argmax(count < 8))
        raise PSFError(f"field {tuple(float(v) for v in fields[i])} at {lam:g} nm: only {int(count[i])} "
                       f"of {m1 - 1} pupil rays reach the image (vignetted or failed)")
    c_pos, c_dir, c_opl = pos[:, -1].copy(), dirn[:, -1].copy(), opl[:, -1].copy()
    for i in np.flatnonzero(~ok[:, -1]):   # a vignetted chief ray: traced again without clipping
        j = slice(i * m1 + m1 - 1, (i + 1) * m1)
        ch = trace_to_exit(pl, Rays(rays.origin[j], rays.direction[j], lam, rays.opl[j], rays.status[j]), clip=False)
        if not ch.valid[0] or ch.direction[0, 2] <= 0:
            raise PSFError(f"field {tuple(float(v) for v in fields[i])} at {lam:g} nm: the chief ray does not "
                           "reach the image")
        c_pos[i], c_dir[i], c_opl[i] = ch.position[0], ch.direction[0], ch.opl[0]
    pos, dirn, opl = pos[:, :-1], dirn[:, :-1], opl[:, :-1]
    odd = ~valid & res.valid.reshape(k, m1)[:, :-1]     # traced, but not toward the image
    if np.any(odd):   # the tracer's placeholders for them too
        pos, dirn, opl = pos.copy(), dirn.copy(), opl.copy()
        pos[odd], dirn[odd], opl[odd] = 0.0, (0.0, 0.0, 1.0), 0.0
    p = np.asarray(pupil, dtype=np.float64)
    n_img = float(pl.lens.surfaces[-1].material.index(lam))
    return _TracedNodes(float(lam), n_img, samples, p, valid, pos, dirn, opl, c_pos, c_dir, c_opl,
                        float(pl.image_pose.vertex[2]), float(z_pupil), _node_jacobians(p, dirn, valid))


def _node_jacobians(p: np.ndarray, dirn: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """:func:`_solid_angle_jacobian` of K fields on one pupil grid, (K, M),
    0 for invalid rays.

    The degree-4 fit of every field at once: the monomials of the grid are
    built once, each field's normal equations are the Gram matrix of its
    valid rows (one product for all fields: ``valid @ (v_i v_j)``), the
    systems are solved together with the same column scaling as
    :func:`_lstsq`. Fields with fewer than 60 valid rays (a lower degree)
    or whose fit falls back to the affine J take the per-field function.
    """
    k, m = valid.shape
    degree = 4
    v, vx, vy = _poly_terms(p, degree)
    nt = v.shape[1]
    w = valid.astype(np.float64)
    gram = (w @ (v[:, :, None] * v[:, None, :]).reshape(m, nt * nt)).reshape(k, nt, nt)
    rhs = np.stack([(w * dirn[..., 0]) @ v, (w * dirn[..., 1]) @ v], axis=2)  # (K, nt, 2)
    scale = np.sqrt(np.einsum("kii->ki", gram))
    scale[scale == 0] = 1.0
    gram = gram / (scale[:, :, None] * scale[:, None, :])
    rhs = rhs / scale[:, :, None]
    many = np.count_nonzero(valid, axis=1) >= 4 * nt
    if not np.all(many):   # the singular systems of the per-field fits are not solved here
        gram[~many] = np.eye(nt)
    coef = (np.linalg.solve(gram, rhs) / scale[:, :, None]).transpose(1, 0, 2).reshape(nt, 2 * k)
    dx = (vx @ coef).reshape(m, k, 2)
    dy = (vy @ coef).reshape(m, k, 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        j = (np.abs(dx[..., 0] * dy[..., 1] - dy[..., 0] * dx[..., 1]).T / dirn[..., 2])
        j[~valid] = 0.0
        med = _row_medians(j, valid)
        off = valid & ~(np.isfinite(j) & (j > 0.05 * med[:, None]))
    for i in np.flatnonzero(~many | off.any(axis=1)):
        ok = valid[i]
        j[i] = 0.0
        j[i, ok] = _solid_angle_jacobian(p[ok], dirn[i, ok])
    return j


def _row_medians(a: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``np.median(a[k][mask[k]])`` of every row (NaN for an empty row),
    by one sort (a per-row ``np.nanmedian`` loops in Python)."""
    n = np.count_nonzero(mask, axis=1)
    srt = np.sort(np.where(mask, a, np.inf), axis=1)
    lo = np.take_along_axis(srt, np.maximum((n - 1) // 2, 0)[:, None], axis=1)[:, 0]
    hi = np.take_along_axis(srt, np.maximum(n // 2, 0)[:, None], axis=1)[:, 0]
    with np.errstate(invalid="ignore"):
        return np.where(n > 0, (lo + hi) / 2.0, np.nan)


def _node_spheres(tn: _TracedNodes, centers: np.ndarray, z_image: np.ndarray):
    """:func:`_sphere` of every field of ``tn``, about the image-plane
    points ``(centers[k], z_image[k])`` (mm).

    Returns ``q`` (K, M, 3) sources relative to P0, ``opd`` (K, M) and
    ``amp`` (K, M), rays that do not reach the sphere with ``amp = 0``,
    ``opd = 0`` and ``q = (0, 0, −1)`` (finite, so that they add exactly
    nothing to a sum over rays)."""
    k = len(tn)
    p0 = np.column_stack([centers[:, 0], centers[:, 1], np.broadcast_to(z_image, (k,))])
    t = (tn.z_pupil - tn.chief_pos[:, 2]) / tn.chief_dir[:, 2]
    e = tn.chief_pos + t[:, None] * tn.chief_dir
    radius = np.linalg.norm(p0 - e, axis=1)

    def to_sphere(pos, d):
        w = pos - p0[:, None]
        b = np.einsum("kmi,kmi->km", w, d)
        c = np.einsum("kmi,kmi->km", w, w) - (radius * radius)[:, None]
        disc = b * b - c
        with np.errstate(invalid="ignore", divide="ignore"):
            s = c / (-b + np.sqrt(disc))
        return s, disc

    s, disc = to_sphere(tn.pos, tn.dirn)
    sc, _ = to_sphere(tn.chief_pos[:, None], tn.chief_dir[:, None])
    sc = sc[:, 0]
    ok = tn.valid & (disc > 0) & np.isfinite(s)
    bad = (np.count_nonzero(ok, axis=1) < 8) | ~np.isfinite(sc)
    if np.any(bad):
        i = int(np.argmax(bad))
        raise PSFError(f"the rays at {tn.wavelength_nm:g} nm do not cross the reference sphere "
                       f"(R = {radius[i]:g} mm about {p0[i, :2]} mm)")
    s = np.where(ok, s, 0.0)
    q = tn.pos + s[..., None] * tn.dirn - p0[:, None]
    q[~ok] = (0.0, 0.0, -1.0)
    n_img = tn.n_img
    opd = np.where(ok, (tn.opl + n_img * s) - (tn.chief_opl + n_img * sc)[:, None], 0.0)
    jac = tn.jac
    for i in np.flatnonzero(np.any(ok != tn.valid, axis=1)):   # the fit is over the rays on the sphere
        jac = jac.copy() if jac is tn.jac else jac
        jac[i] = 0.0
        jac[i, ok[i]] = _solid_angle_jacobian(tn.p[ok[i]], tn.dirn[i, ok[i]])
    dp = 2.0 / tn.samples
    amp = np.where(ok, np.sqrt(jac) * dp * dp, 0.0)
    return q, opd, amp


def _blas_on_one_thread() -> bool:
    """Whether BLAS was told to use one thread (``OPENBLAS_NUM_THREADS`` or,
    which OpenBLAS also reads, ``OMP_NUM_THREADS`` = 1, as the benchmarks
    set them before importing numpy) or there is one core: then any GEMM
    may be one call (see :data:`_BLAS_ONE_THREAD`)."""
    env = os.environ.get("OPENBLAS_NUM_THREADS") or os.environ.get("OMP_NUM_THREADS")
    return env == "1" or (os.cpu_count() or 1) == 1


def _a_bt(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a[k] @ b[k].T`` for complex (B, na, M), (B, nb, M): (B, na, nb).

    One complex GEMM per k where BLAS runs on one thread; else real GEMMs
    of the float views (re, im interleaved along M): ``Re = a·conj(b)`` and
    ``Im = a·(i conj(b))`` summed over the 2M floats, the sum cut into
    blocks that OpenBLAS keeps on one thread (:data:`_BLAS_ONE_THREAD`;
    it threads a complex GEMM of almost any size)."""
    if _blas_on_one_thread():
        return np.matmul(a, b.transpose(0, 2, 1))
    nbatch, na, m = a.shape
    nb = b.shape[1]
    real = np.float32 if a.dtype == np.complex64 else np.float64
    s = np.empty((nbatch, 2 * nb, m), dtype=a.dtype)
    np.conjugate(b, out=s[:, :nb])
    np.multiply(s[:, :nb], 1j, out=s[:, nb:])
    av = np.ascontiguousarray(a).view(real)                       # (B, na, 2M)
    sv = s.view(real)                                             # (B, 2nb, 2M)
    step = max(2, _BLAS_ONE_THREAD // (na * 2 * nb) - 1)
    r = np.zeros((nbatch, na, 2 * nb), dtype=real)
    for j in range(0, 2 * m, step):
        r += np.matmul(av[:, :, j:j + step], sv[:, :, j:j + step].transpose(0, 2, 1))
    return r[:, :, :nb] + 1j * r[:, :, nb:]


DEBYE_SUM_DTYPE = np.complex64
"""Precision of the phasor tables and their product in the batched Debye
sums of the SFR model (:func:`_debye_nodes`); the rays' phases, the
tables' first rows and steps and the intensities stay float64. Measured
on e9 (15 × 20 nodes, 48 pupil samples, 600 edges, 3 perturbed lenses):
SFRA within 5e-9 cycles/pixel RMS (2e-8 max) of complex128, PSFs within
3.4e-7 of their peak, for a fifth less PSF time (half the GEMM's). The
per-field PSFs (:func:`debye_psf`, PSF maps) stay complex128."""


def _debye_nodes(tn: _TracedNodes, centers: np.ndarray, z_image, ox: np.ndarray, oy: np.ndarray,
                 chunk: int = 2, dtype=None, energy: bool = False):
    """Normalised Debye PSFs of every field of ``tn``, (K, len(oy), len(ox)):
    ``_mono(_sphere(tn.node(k), centers[k]), "debye", ox, oy)[0]`` with the
    image plane at ``z_image`` (scalar or (K,), mm), ``chunk`` fields per
    vectorised step. Rays off the sphere enter with zero amplitude.
    ``dtype``: of the phasor tables and their product, default
    :data:`DEBYE_SUM_DTYPE` (complex128 reproduces the per-field path to
    ~1e-12). ``energy``: also return each field's window energy (K,), the
    fraction of its exit-pupil power on the window (``PSF.window_energy``,
    module docstring)."""
    dtype = DEBYE_SUM_DTYPE if dtype is None else dtype
    k = len(tn)
    z = np.broadcast_to(np.asarray(tn.z_image if z_image is None else z_image, dtype=np.float64), (k,))
    q, opd, amp = _node_spheres(tn, np.asarray(centers, dtype=np.float64), z)
    lam_m = tn.wavelength_nm * 1e-6 / tn.n_img
    k_m = 2.0 * math.pi / lam_m
    s = -q / np.linalg.norm(q, axis=2, keepdims=True)
    c = amp * np.exp(1j * (2.0 * math.pi / (tn.wavelength_nm * 1e-6)) * opd)
    out = np.empty((k, len(oy), len(ox)))
    for a in range(0, k, chunk):
        b = slice(a, min(a + chunk, k))
        y = _phasors(k_m * s[b, :, 1], oy, scale=c[b], dtype=dtype)      # (B, ny, M), times c
        x = _phasors(k_m * s[b, :, 0], ox, dtype=dtype)                  # (B, nx, M)
        e = _a_bt(y, x)
        out[b] = (e.real.astype(np.float64) ** 2 + e.imag.astype(np.float64) ** 2) / (lam_m * lam_m)
    total = out.sum(axis=(1, 2))
    bad = ~(np.isfinite(total) & (total > 0))
    if np.any(bad):
        i = int(np.argmax(bad))
        raise PSFError(f"the PSF at {tn.wavelength_nm:g} nm has no energy in the window (centre "
                       f"{np.asarray(centers)[i]} mm); check center, n and pitch_um")
    if not energy:
        return out / total[:, None, None]
    # Σ I·pitch²·N_h / P, as _mono: P the rays' power M Δp², N_h their harmonic-mean cosine to the plane
    ok = amp > 0
    dp = 2.0 / tn.samples
    power = np.count_nonzero(ok, axis=1) * dp * dp
    inv_cos = np.where(ok, 1.0 / np.maximum(np.abs(tn.dirn[..., 2]), 1e-12), 0.0)
    n_h = np.count_nonzero(ok, axis=1) / inv_cos.sum(axis=1)
    pitch2 = float(ox[1] - ox[0]) * float(oy[1] - oy[0]) if len(ox) > 1 and len(oy) > 1 else 0.0
    return out / total[:, None, None], total * pitch2 * n_h / power


# -- public PSFs ---------------------------------------------------------------------

METHODS = ("huygens", "fft", "debye")


def _default_pitch_um(pl: PerturbedLens, lam_nm: float) -> float:
    n_w = paraxial.first_order(pl.lens).working_f_number
    if not (math.isfinite(n_w) and n_w > 0):
        raise PSFError("the lens has no finite working F-number; give pitch_um")
    return lam_nm * 1e-3 * n_w / 4.0


def _center(traced: Sequence[_Traced], weights: Sequence[float], center, ref: _Traced | None = None) -> np.ndarray:
    if isinstance(center, str):
        if center == "chief":
            return (ref if ref is not None else traced[0]).chief_image_point()
        if center == "centroid":
            c = sum(w * t.image_points().mean(axis=0) for t, w in zip(traced, weights))
            return np.asarray(c) / float(sum(weights))
        raise PSFError(f"unknown center {center!r}; valid: 'chief', 'centroid', or (x, y) in mm")
    c = np.asarray(center, dtype=np.float64).ravel()
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise PSFError(f"center must be 'chief', 'centroid' or a finite (x, y) in mm, got {center!r}")
    return c


def _mono(sp: _Sphere, method: str, ox: np.ndarray, oy: np.ndarray, pad: int = 4,
          workers: int | None = None) -> tuple[np.ndarray, float]:
    """Normalised samples and the window energy of one wavelength
    (``workers``: threads, default one per core)."""
    if method == "huygens":
        inten = _huygens_intensity(sp, ox, oy, workers=workers)
        total = sp.power / sp.flux_cos
    elif method == "debye":
        inten = _debye_intensity(sp, ox, oy)
        total = sp.power / sp.flux_cos
    elif method == "fft":
        inten, total = _fft_intensity(sp, ox, oy, pad, workers)
    else:
        raise PSFError(f"unknown PSF method {method!r}; valid: {', '.join(METHODS)}")
    s = float(inten.sum())
    if not (s > 0 and math.isfinite(s)):
        raise PSFError(f"the PSF at {sp.wavelength_nm:g} nm has no energy in the window (centre {sp.p0[:2]} mm); "
                       "check center, n and pitch_um")
    pitch_mm = float(ox[1] - ox[0]) if len(ox) > 1 else 0.0
    # Huygens: ∫|E|² dA over the image plane is Σ P_i / N_i (each plane-wave
    # component crosses it obliquely) = P / N_h. FFT: the lattice's own total.
    return inten / s, s * pitch_mm * pitch_mm / total


def _monochromatic(lens, field_deg, wavelength_nm, method, *, pupil_samples, n, pitch_um, center,
                   aiming) -> PSF:
    pl = nominal(lens)
    f = _field(field_deg)
    lam = _wavelength(wavelength_nm)
    samples = _positive_int(pupil_samples, "pupil_samples")
    n = _positive_int(n, "n")
    tr = _trace(pl, f, lam, samples, _aiming(aiming))
    c = _center([tr], [1.0], center)
    pitch = _default_pitch_um(pl, lam) if pitch_um is None else float(pitch_um)
    if not (math.isfinite(pitch) and pitch > 0):
        raise PSFError(f"pitch_um must be positive, got {pitch_um!r}")
    o = _grid_offsets_mm(n, pitch)
    data, energy = _mono(_sphere(tr, c), method, o, o)
    return PSF(data, pitch, (float(c[0]), float(c[1])), f, (lam,), (1.0,), method, energy)


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
        Sample spacing, µm; default ``λ·N_w/4`` (see the module docstring).
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
    return _monochromatic(lens, field_deg, wavelength_nm, "huygens", pupil_samples=pupil_samples, n=n,
                          pitch_um=pitch_um, center=center, aiming=aiming)


def fft_psf(lens: Lens | PerturbedLens, field_deg, wavelength_nm: float, *, pupil_samples: int = 128,
            n: int = 256, pitch_um: float | None = None, center="chief", aiming: str = "real") -> PSF:
    """Monochromatic PSF by the pupil-function FFT (the Huygens cross-check).

    Parameters are those of :func:`huygens_psf`. The pupil function
    ``a·e^{ikW}`` (amplitude ``a`` the energy-conserving weight, zero
    outside the traced rays) is zero-padded to ``4·pupil_samples``,
    inverse-transformed, squared, and interpolated onto the requested grid
    through the real rays' affine direction-cosine map (see the module
    docstring). The window ``n·pitch_um`` must stay inside the FFT period
    ``≈ pupil_samples·λ·N``.

    Returns
    -------
    PSF
        ``data`` (n, n) summing to 1, ``method="fft"``.
    """
    return _monochromatic(lens, field_deg, wavelength_nm, "fft", pupil_samples=pupil_samples, n=n,
                          pitch_um=pitch_um, center=center, aiming=aiming)


def debye_psf(lens: Lens | PerturbedLens, field_deg, wavelength_nm: float, *, pupil_samples: int = 64,
              n: int = 128, pitch_um: float | None = None, center="chief", aiming: str = "real") -> PSF:
    """Monochromatic PSF by the Debye-approximated Huygens sum on the grid
    (see the module docstring): the accuracy of :func:`huygens_psf` to
    ~1e-3 of the peak at a fraction of its cost. Parameters as
    :func:`huygens_psf`.

    Returns
    -------
    PSF
        ``data`` (n, n) summing to 1, ``method="debye"``.
    """
    return _monochromatic(lens, field_deg, wavelength_nm, "debye", pupil_samples=pupil_samples, n=n,
                          pitch_um=pitch_um, center=center, aiming=aiming)


# -- spectral response (eq. 14) -------------------------------------------------------------

def spectral_response(channel: str, *, camera: str = DEFAULT_CAMERA, illuminant: str = "D65"
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The spectral weight ``C(λ) = S_channel(λ)·E_illuminant(λ)`` of a
    camera channel, on the camera data's grid.

    Parameters
    ----------
    channel : {"R", "G", "B"}
    camera : str
        A key of ``colour.MSDS_CAMERA_SENSITIVITIES`` (default
        :data:`DEFAULT_CAMERA`; no phone sensor is in that set).
    illuminant : str
        A key of ``colour.SDS_ILLUMINANTS`` (default CIE D65).

    Returns
    -------
    wavelengths_nm : (K,) ndarray
        380–780 nm in 5 nm steps for the NPL data.
    weights : (K,) ndarray
        ``C(λ)`` normalised to sum 1 (≥ 0).
    """
    import colour

    names = {"R": 0, "G": 1, "B": 2}
    key = str(channel).upper()
    if key not in names:
        raise PSFError(f"unknown channel {channel!r}; valid: 'R', 'G', 'B', or (wavelengths_nm, weights)")
    if camera not in colour.MSDS_CAMERA_SENSITIVITIES:
        raise PSFError(f"unknown camera {camera!r}; valid: {sorted(colour.MSDS_CAMERA_SENSITIVITIES)}")
    if illuminant not in colour.SDS_ILLUMINANTS:
        raise PSFError(f"unknown illuminant {illuminant!r}; e.g. 'D65', 'A', 'D50', 'FL2'")
    cam = colour.MSDS_CAMERA_SENSITIVITIES[camera]
    wl = np.asarray(cam.wavelengths, dtype=np.float64)
    s = np.asarray(cam.values, dtype=np.float64)[:, names[key]]
    e = np.asarray(colour.SDS_ILLUMINANTS[illuminant].copy().align(colour.SpectralShape(wl[0], wl[-1], wl[1] - wl[0]))
                   [wl], dtype=np.float64)
    c = np.clip(np.nan_to_num(s * e), 0.0, None)
    return wl, c / c.sum()


def spectral_quadrature(wavelengths_nm, weights, n: int) -> tuple[np.ndarray, np.ndarray]:
    """An ``n``-node Gauss rule for the discrete spectral measure
    ``Σ_j weights_j δ(λ − λ_j)``.

    The nodes and weights integrate every polynomial in λ of degree
    ≤ 2n − 1 exactly against ``weights`` (Golub & Welsch, *Math. Comp.* 23
    (1969) 221–230: eigen-decomposition of the Jacobi matrix, built here by
    the Lanczos process with full reorthogonalisation). Nodes lie inside the
    measure's support; weights are positive and keep the total.

    Returns
    -------
    nodes_nm, node_weights : (n,) ndarrays
        Ascending nodes; with ``n`` ≥ the number of positive weights, the
        input points themselves.

    >>> x, w = spectral_quadrature([500.0, 550.0, 600.0], [0.25, 0.5, 0.25], 1)
    >>> x.round(9).tolist(), w.round(9).tolist()
    ([550.0], [1.0])
    """
    x = np.asarray(wavelengths_nm, dtype=np.float64).ravel()
    w = np.asarray(weights, dtype=np.float64).ravel()
    if x.shape != w.shape or not len(x):
        raise PSFError(f"wavelengths and weights must be equal-length non-empty 1-D, got {x.shape} and {w.shape}")
    if np.any(w < 0) or not np.all(np.isfinite(w)) or not np.all(np.isfinite(x)) or w.sum() <= 0:
        raise PSFError("spectral weights must be finite, ≥ 0 and not all 0")
    n = _positive_int(n, "n")
    keep = w > 0
    x, w = x[keep], w[keep]
    total = float(w.sum())
    if n >= len(x):
        order = np.argsort(x)
        return x[order], w[order]
    mu, sc = float(np.average(x, weights=w)), float(np.ptp(x)) or 1.0
    t = (x - mu) / sc
    qs = [np.sqrt(w / total)]
    alpha, beta = [], []
    for j in range(n):
        v = t * qs[j]
        alpha.append(float(qs[j] @ v))
        for qq in qs:                       # full reorthogonalisation (twice is enough)
            v -= (qq @ v) * qq
        for qq in qs:
            v -= (qq @ v) * qq
        if j < n - 1:
            b = float(np.linalg.norm(v))
            if b < 1e-14:
                break
            beta.append(b)
            qs.append(v / b)
    m = len(alpha)
    jac = np.diag(alpha) + np.diag(beta[:m - 1], 1) + np.diag(beta[:m - 1], -1)
    ev, vec = np.linalg.eigh(jac)
    return ev * sc + mu, total * vec[0] ** 2


def _response(response, n_wavelengths, camera, illuminant) -> tuple[np.ndarray, np.ndarray]:
    """(nodes, weights summing to 1) of a channel name or (wavelengths, weights)."""
    if isinstance(response, str):
        wl, c = spectral_response(response, camera=camera, illuminant=illuminant)
        n_wl = DEFAULT_WAVELENGTHS_PER_CHANNEL if n_wavelengths is None else n_wavelengths
    else:
        try:
            wl, c = (np.asarray(a, dtype=np.float64).ravel() for a in response)
        except (TypeError, ValueError):
            raise PSFError(f"response must be 'R', 'G', 'B' or (wavelengths_nm, weights), got {response!r}") from None
        n_wl = len(wl) if n_wavelengths is None else n_wavelengths
    x, w = spectral_quadrature(wl, c, n_wl)
    return x, w / w.sum()


def polychromatic_psf(lens: Lens | PerturbedLens, field_deg, response, *, method: str = "huygens",
                      n_wavelengths: int | None = None, camera: str = DEFAULT_CAMERA, illuminant: str = "D65",
                      pupil_samples: int | None = None, n: int | None = None, pitch_um: float | None = None,
                      center="chief", aiming: str = "real", aim_each_wavelength: bool = True) -> PSF:
    """The PSF of a sensor channel: ``∫ C(λ)·PSF(λ) dλ`` (paper eq. 14).

    Parameters
    ----------
    lens : Lens or PerturbedLens
    field_deg : float or (θx, θy)
    response : {"R", "G", "B"} or (wavelengths_nm, weights)
        A channel of ``camera`` under ``illuminant`` (:func:`spectral_response`),
        or a sampled spectral weight ``C(λ)`` (any scale).
    method : {"huygens", "fft", "debye"}
    n_wavelengths : int, optional
        Gauss nodes of :func:`spectral_quadrature`; default
        :data:`DEFAULT_WAVELENGTHS_PER_CHANNEL` for a channel name, every
        given wavelength for arrays.
    camera, illuminant : str
        For channel names.
    pupil_samples, n : int, optional
        Defaults of :func:`huygens_psf` / :func:`fft_psf` / :func:`debye_psf`
        by ``method``.
    pitch_um : float, optional
        Default ``λ_min·N_w/4`` over the nodes.
    center : {"chief", "centroid"} or (x, y)
        One centre for every wavelength: the chief ray at the lens's
        primary wavelength (so lateral colour shows as a shift between
        channels), the spectrally weighted ray centroid, or a point (mm).
    aiming : {"real", "paraxial"}
    aim_each_wavelength : bool
        Real aiming at every wavelength (True), or once at the primary
        wavelength for all (False: half the tracing, ≤ 0.6 % of the peak on
        e9; see :func:`_trace_set`).

    Returns
    -------
    PSF
        Sum of the per-wavelength PSFs (each normalised to 1 on the common
        grid) with the node weights; ``wavelengths_nm`` and ``weights`` are
        the nodes.
    """
    if method not in METHODS:
        raise PSFError(f"unknown PSF method {method!r}; valid: {', '.join(METHODS)}")
    pl = nominal(lens)
    f = _field(field_deg)
    nodes, w = _response(response, n_wavelengths, camera, illuminant)
    samples = _positive_int(pupil_samples if pupil_samples is not None else (128 if method == "fft" else 64),
                            "pupil_samples")
    n = _positive_int(n if n is not None else (256 if method == "fft" else 128), "n")
    aiming = _aiming(aiming)
    z_pupil = _exit_pupil_z(pl)
    traced = _trace_set(pl, f, nodes, samples, aiming, z_pupil, bool(aim_each_wavelength))
    ref = None
    if isinstance(center, str) and center == "chief":
        primary = float(pl.nominal.primary_nm)
        ref = next((t for t in traced if t.wavelength_nm == primary), None)
        ref = ref if ref is not None else _trace(pl, f, primary, samples, aiming, z_pupil)
    c = _center(traced, w, center, ref)
    pitch = _default_pitch_um(pl, float(nodes.min())) if pitch_um is None else float(pitch_um)
    o = _grid_offsets_mm(n, pitch)
    data = np.zeros((n, n))
    energy = 0.0
    for t, wk in zip(traced, w):
        d, e = _mono(_sphere(t, c), method, o, o)
        data += wk * d
        energy += wk * e
    return PSF(data, pitch, (float(c[0]), float(c[1])), f, tuple(nodes), tuple(w), method, energy)


# -- Strehl ratio -------------------------------------------------------------------------------

def strehl_ratio(lens: Lens | PerturbedLens, field_deg, wavelength_nm: float, *, method: str = "fft",
                 pupil_samples: int = 128, aiming: str = "real") -> float:
    """Peak intensity of the PSF over the peak of the aberration-free PSF of
    the same pupil (same rays, amplitudes and vignetting, W = 0).

    The peak is searched on a coarse grid about the ray centroid (FFT: the
    whole lattice) and refined by three 4× zooms of the method's own sum
    (for "fft" the direct sum of its affine pupil model), so sampling does
    not bias it.
    With W = 0 the peak is at the reference-sphere centre, where every
    wavelet arrives in phase. Values are in (0, 1]; a single-wavelength,
    image-plane figure (no refocusing).
    """
    pl = nominal(lens)
    f = _field(field_deg)
    lam = _wavelength(wavelength_nm)
    samples = _positive_int(pupil_samples, "pupil_samples")
    tr = _trace(pl, f, lam, samples, _aiming(aiming))
    sp = _sphere(tr, tr.image_points().mean(axis=0))
    step = lam * 1e-6 * max(paraxial.first_order(pl.lens).working_f_number, 0.5) / 2.0    # λN/2, mm
    if method == "fft":
        lat, dxi = _fft_lattice(sp)
        nf = lat.shape[0]
        iy, ix = np.unravel_index(int(np.argmax(lat)), lat.shape)
        xi0 = np.array([(ix - nf // 2) * dxi, (iy - nf // 2) * dxi])
        f0 = _pupil_array(sp)
        px = -1.0 + (np.arange(samples) + 0.5) * (2.0 / samples)

        def debye(xi_x, xi_y):   # |Σ a e^{ikW} e^{ik p·ξ}|² / λ'² on a (len(xi_y), len(xi_x)) grid
            ex = np.exp(1j * sp.k * np.outer(px, xi_x))
            ey = np.exp(1j * sp.k * np.outer(xi_y, px))
            e = _at_b(_at_b(ey.T, f0).T, ex)
            lam_m = lam * 1e-6 / sp.n_img
            return (e.real ** 2 + e.imag ** 2) / (lam_m * lam_m)

        span = dxi
        best = xi0
        peak = float(lat.max())
        for _ in range(3):
            g = np.linspace(-span, span, 9)
            v = debye(best[0] + g, best[1] + g)
            i, j = np.unravel_index(int(np.argmax(v)), v.shape)
            best = np.array([best[0] + g[j], best[1] + g[i]])
            peak = max(peak, float(v[i, j]))
            span = span / 4.0
        ref = float(sp.amp.sum() ** 2 / (lam * 1e-6 / sp.n_img) ** 2)    # W = 0: all in phase at ξ = 0
        return peak / ref
    if method in ("huygens", "debye"):
        def inten(ox, oy, sphere=sp, zero=False):
            if method == "huygens":
                return _huygens_intensity(sphere, ox, oy, zero_opd=zero)
            return _debye_intensity(sphere, ox, oy, zero_opd=zero)

        o = np.arange(-16, 17) * step
        v = inten(o, o)
        i, j = np.unravel_index(int(np.argmax(v)), v.shape)
        best = np.array([o[j], o[i]])
        peak = float(v.max())
        span = step
        for _ in range(3):
            g = np.linspace(-span, span, 9)
            v = inten(best[0] + g, best[1] + g)
            i, j = np.unravel_index(int(np.argmax(v)), v.shape)
            best = np.array([best[0] + g[j], best[1] + g[i]])
            peak = max(peak, float(v[i, j]))
            span /= 4.0
        # zero OPD: every wavelet in phase at the reference sphere's centre
        ref = float(inten(np.zeros(1), np.zeros(1), _sphere(tr, tr.chief_image_point()), True)[0, 0])
        return peak / ref
    raise PSFError(f"unknown PSF method {method!r}; valid: {', '.join(METHODS)}")

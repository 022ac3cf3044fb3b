"""The exit pupil: the rays of one field traced through the lens, and the
reference sphere they cross (paper, section 3.1.2).

Every diffraction model of this package (:mod:`~calibration.optics.psf.huygens`,
:mod:`~calibration.optics.psf.fft`, :mod:`~calibration.optics.psf.debye`)
starts from the same two steps: :func:`trace_pupil` (or
:func:`trace_pupils` for several wavelengths) traces a grid over the stop
to the last surface (:class:`TracedPupil`), and :func:`reference_sphere`
carries the rays on to the exit-pupil reference sphere about the PSF
centre, with each ray's optical path difference and wavelet amplitude
(:class:`ReferenceSphere`). The SFR model (:mod:`calibration.fit.forward_model`)
needs a few hundred fields per lens evaluation and takes the batched path:
:class:`TracedNodes` holds the pupils of K fields traced in one call
(:func:`nodes_from_trace`), :func:`node_jacobians` fits all their pupils
at once and :func:`node_spheres` puts them on their spheres; the per-field
functions are its oracle.

Units: mm for geometry, nm for wavelengths, degrees for fields ``(θx, θy)``
(object-space direction, :mod:`calibration.optics.trace`). Light travels
+z; the image plane is the lens's (``z`` of its image pose).

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
telecentric in image space; :func:`exit_pupil_z`). For a virtual exit pupil
(the usual case in phone lenses: the pupil plane lies inside the lens) the
image-space rays are continued *backwards* to it; their optical path is
extended (or shortened) by ``n'·s`` accordingly. The OPD of a ray is its
optical path to the sphere minus the chief ray's, ``W = OPL − OPL_chief``
(mm); only W enters the phases, so they stay small and float64 keeps them to
~1e-11 rad.

Amplitude. A ray of power ``Δp²`` (``Δp = 2/pupil_samples``) that covers the
solid angle ``dΩ = J_Ω Δp²`` on the sphere (``J_Ω = |∂(L, M)/∂(px, py)|/N``
from a least-squares polynomial fit of the real ray direction cosines
``(L, M, N)`` over the normalised pupil coordinates,
:func:`solid_angle_jacobian`) has amplitude ``1/(R √J_Ω)``; its wavelet
weight ``U dA = R √J_Ω Δp²`` therefore conserves energy, and pupil
aberrations (a non-uniform mapping of the stop onto the sphere) apodise the
pupil as they physically do. Fresnel losses and coatings are not modelled.
With this normalisation the intensity is absolute: ``PSF.window_energy`` is
the fraction of the exit-pupil power that crosses the sampled window,
``Σ I·pitch²·N_h / P`` (``N_h`` the harmonic mean of the rays' direction
cosine to the image-plane normal, :attr:`ReferenceSphere.flux_cos`: off axis
the beam crosses the plane obliquely); a truncation check, ≈ 1 for a
generous window.

References: the paper (``../shared/paper``), §3.1.2; M. Born and E. Wolf,
*Principles of Optics*, 7th ed., Cambridge University Press 1999, §8.8.

Imports the lens model and tracer of :mod:`calibration.optics` and, of this
package, :mod:`~calibration.optics.psf.result` and
:mod:`~calibration.optics.psf.linalg`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calibration.optics import paraxial
from calibration.optics.lens import LensError
from calibration.optics.perturb import PerturbedLens
from calibration.optics.psf.linalg import lstsq, masked_row_medians
from calibration.optics.psf.result import PSFError
from calibration.optics.trace import Rays, pupil_grid, pupil_rays, stop_and_pupil, trace_to_exit

__all__ = [
    "ReferenceSphere",
    "TracedNodes",
    "TracedPupil",
    "exit_pupil_z",
    "node_jacobians",
    "node_spheres",
    "nodes_from_trace",
    "pupil_from_trace",
    "pupil_monomials",
    "pupil_points",
    "reference_sphere",
    "solid_angle_jacobian",
    "trace_pupil",
    "trace_pupils",
]


@dataclass(frozen=True, eq=False)
class TracedPupil:
    """The pupil grid of one field and wavelength, traced to the last
    surface (the rays that reach the image), and its chief ray.

    Attributes: ``ix``, ``iy`` (M,) the pupil-grid column and row of each
    ray; ``p`` (M, 2) its normalised pupil coordinates; ``pos`` (M, 3) where
    it leaves the last surface (global mm); ``dirn`` (M, 3) its unit
    direction in image space; ``opl`` (M,) its optical path to there (mm);
    the same of the chief ray (traced without clipping if vignetted);
    ``n_img`` the image-space index; ``z_image`` the image plane and
    ``z_pupil`` the exit-pupil plane of the reference sphere (mm).
    """

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
        """(2,) where the chief ray crosses the image plane, mm."""
        t = (self.z_image - self.chief_pos[2]) / self.chief_dir[2]
        return self.chief_pos[:2] + t * self.chief_dir[:2]


def exit_pupil_z(pl: PerturbedLens) -> float:
    """z of the reference sphere's pupil plane, mm: the paraxial exit pupil
    (primary wavelength), or the last vertex plane for an image-space
    telecentric lens (or an exit pupil within 1 µm of, or 10 m from, the
    image)."""
    lens = pl.lens
    z_img = float(pl.image_pose.vertex[2])
    try:
        z = paraxial.first_order(lens).exit_pupil_z
    except (LensError, ZeroDivisionError, ValueError):
        z = math.inf
    if not math.isfinite(z) or abs(z_img - z) < 1e-6 or abs(z_img - z) > 1e4:
        z = float(pl.poses[-1].vertex[2])
    return float(z)


def pupil_from_trace(pl: PerturbedLens, rays: Rays, res, field_deg, samples: int, z_pupil: float) -> TracedPupil:
    """The :class:`TracedPupil` of a traced pupil grid.

    Parameters
    ----------
    pl : PerturbedLens
    rays : Rays
        The pupil grid's rays with the chief ray appended last
        (:func:`pupil_points`), as traced.
    res : TraceResult
        ``calibration.optics.trace.trace_to_exit(pl, rays)``.
    field_deg : (θx, θy)
        The field, degrees (for messages).
    samples : int
        The pupil grid size across the stop.
    z_pupil : float
        The exit-pupil plane, mm (:func:`exit_pupil_z`).

    Returns
    -------
    TracedPupil
        The rays that reach the image travelling +z; a vignetted chief ray
        is traced again without clipping (it still defines the field's
        centre). :class:`PSFError` if fewer than 8 rays reach the image or
        the chief ray does not.
    """
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
    return TracedPupil(float(lam), n_img, samples, ix, iy, pc, res.position[ok], res.direction[ok], res.opl[ok],
                       c_pos, c_dir, c_opl, float(pl.image_pose.vertex[2]), float(z_pupil))


def pupil_points(samples: int) -> np.ndarray:
    """(M + 1, 2) normalised pupil coordinates: the ``samples × samples``
    grid of cell centres in the unit disc
    (:func:`calibration.optics.trace.pupil_grid`) with the chief ray (0, 0)
    appended."""
    return np.vstack([pupil_grid(samples, "grid"), [0.0, 0.0]])


def trace_pupil(pl: PerturbedLens, field_deg, wavelength_nm: float, samples: int, aiming: str,
                z_pupil: float | None = None) -> TracedPupil:
    """Trace the pupil grid and the chief ray (one more pupil point, so real
    aiming runs once) to the last surface, aimed at this wavelength.

    Parameters
    ----------
    pl : PerturbedLens
    field_deg : (θx, θy)
        Object field, degrees.
    wavelength_nm : float
    samples : int
        Pupil grid size across the stop.
    aiming : {"real", "paraxial"}
        Pupil ray aiming (:func:`calibration.optics.trace.pupil_rays`).
    z_pupil : float, optional
        The exit-pupil plane, mm; default :func:`exit_pupil_z`.

    Returns
    -------
    TracedPupil
    """
    rays = pupil_rays(pl, field_deg, samples, wavelength_nm, aiming=aiming, pupil=pupil_points(samples))
    return pupil_from_trace(pl, rays, trace_to_exit(pl, rays), field_deg, samples,
                            exit_pupil_z(pl) if z_pupil is None else z_pupil)


def trace_pupils(pl: PerturbedLens, field_deg, wavelengths_nm: Sequence[float], samples: int, aiming: str,
                 z_pupil: float | None = None, aim_each: bool = True) -> list[TracedPupil]:
    """:func:`trace_pupil` for several wavelengths (nm): one
    :class:`TracedPupil` per wavelength, in order.

    ``aim_each=False`` (real aiming only): aim once, at the lens's primary
    wavelength, and send every wavelength through the same entrance-pupil
    points — the entrance pupil is defined at the primary wavelength.
    Pupil chromatism then over- or under-fills the stop slightly (e9:
    +1.5 µm of 1.08 mm at 440 nm); measured on e9 (FFT, 32² at 0.5 µm, 440
    and 650 nm, on axis to full field) the PSFs move by ≤ 0.6 % of the peak
    (NCC ≥ 0.99998), for half the tracing time.
    """
    z_pupil = exit_pupil_z(pl) if z_pupil is None else float(z_pupil)
    wls = [float(w) for w in wavelengths_nm]
    if aim_each or aiming != "real":
        return [trace_pupil(pl, field_deg, w, samples, aiming, z_pupil) for w in wls]
    pc = pupil_points(samples)
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
        out.append(pupil_from_trace(pl, rays, trace_to_exit(pl, rays), field_deg, samples, z_pupil))
    return out


@dataclass(frozen=True, eq=False)
class ReferenceSphere:
    """The traced rays of one field and wavelength on the exit-pupil
    reference sphere about the PSF centre P0 (module docstring): where
    each ray crosses it, its optical path difference and its wavelet
    amplitude. Per-ray arrays have M rows (the rays that reach the sphere).
    """

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


def pupil_monomials(p: np.ndarray, degree: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The monomials ``px^a py^b`` (a + b ≤ degree) of pupil points and
    their derivatives.

    Parameters
    ----------
    p : (M, 2) ndarray
        Normalised pupil coordinates (px, py).
    degree : int

    Returns
    -------
    v, dv_dpx, dv_dpy : (M, T) ndarrays
        ``T = (degree + 1)(degree + 2)/2`` columns, by total degree, then
        by descending power of py.
    """
    x, y = p[:, 0], p[:, 1]
    cols, dx, dy = [], [], []
    for tot in range(degree + 1):
        for a in range(tot + 1):
            b = tot - a
            cols.append(x ** a * y ** b)
            dx.append(a * x ** max(a - 1, 0) * y ** b if a else np.zeros_like(x))
            dy.append(b * x ** a * y ** max(b - 1, 0) if b else np.zeros_like(x))
    return np.column_stack(cols), np.column_stack(dx), np.column_stack(dy)


def solid_angle_jacobian(p: np.ndarray, dirn: np.ndarray) -> np.ndarray:
    """The solid angle each ray's pupil cell covers, per unit pupil area.

    Parameters
    ----------
    p : (M, 2) ndarray
        Normalised pupil coordinates.
    dirn : (M, 3) ndarray
        Unit ray directions (L, M, N) in image space.

    Returns
    -------
    (M,) ndarray
        ``J_Ω = |∂(L, M)/∂(px, py)| / N`` (sr per unit pupil area), from a
        least-squares polynomial fit (degree ≤ 4, lower with few rays) of
        the direction cosines over the pupil; the affine fit's constant J if
        the fit is unusable.
    """
    m = len(p)
    for degree in (4, 3, 2, 1):
        nterms = (degree + 1) * (degree + 2) // 2
        if m >= 4 * nterms:
            break
    v, vx, vy = pupil_monomials(p, degree)
    coef = lstsq(v, dirn[:, :2])
    lx, mx = (vx @ coef).T
    ly, my = (vy @ coef).T
    j = np.abs(lx * my - ly * mx) / dirn[:, 2]
    if not np.all(np.isfinite(j)) or np.any(j <= 0.05 * np.median(j)):
        v1 = lstsq(pupil_monomials(p, 1)[0], dirn[:, :2])
        j = np.full(m, abs(v1[1, 0] * v1[2, 1] - v1[2, 0] * v1[1, 1])) / dirn[:, 2]
    return j


def reference_sphere(tr: TracedPupil, center_xy: np.ndarray) -> ReferenceSphere:
    """The rays of ``tr`` on the reference sphere about the image-plane
    point ``center_xy`` (x, y in mm) through the exit-pupil centre (module
    docstring); rays that miss it are dropped. :class:`PSFError` if fewer
    than 8 rays, or not the chief ray, cross it."""
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
    jac = solid_angle_jacobian(p, d)
    amp = np.sqrt(jac) * dp * dp
    v1 = lstsq(pupil_monomials(p, 1)[0], n_img * d[:, :2])
    affine = np.array([[v1[2, 0], v1[1, 0]], [v1[2, 1], v1[1, 1]]])   # rows (L̃, M̃), columns (px, py)
    return ReferenceSphere(tr.wavelength_nm, n_img, tr.samples, tr.ix[ok], tr.iy[ok], p, q, d, opd, amp, radius, p0,
                           float(np.count_nonzero(ok)) * dp * dp, affine, float(1.0 / np.mean(1.0 / d[:, 2])))


@dataclass(frozen=True, eq=False)
class TracedNodes:
    """The pupil grids of K fields (the SFR model's field nodes) at one
    wavelength after the last surface.

    :class:`TracedPupil` of every field stacked on the common pupil grid: ray
    ``m`` of each field comes from pupil point ``p[m]``; ``valid`` marks the
    rays that reach the image (the others hold finite placeholders: position
    0, direction +z, OPL 0). ``jac`` is the solid-angle Jacobian J_Ω of the
    valid rays (:func:`node_jacobians`; 0 elsewhere): it depends on the
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
        default the image plane), mm — :meth:`TracedPupil.chief_image_point`."""
        z = self.z_image if z_image is None else np.asarray(z_image, dtype=np.float64)
        t = (z - self.chief_pos[:, 2]) / self.chief_dir[:, 2]
        return self.chief_pos[:, :2] + t[:, None] * self.chief_dir[:, :2]

    def node(self, k: int, z_image: float | None = None) -> TracedPupil:
        """Field ``k`` as a :class:`TracedPupil` (the per-field path: the
        reference of the batched one, and its fallback)."""
        ok = self.valid[k]
        pc = self.p[ok]
        ix = np.rint((pc[:, 0] + 1.0) * 0.5 * self.samples - 0.5).astype(np.intp)
        iy = np.rint((pc[:, 1] + 1.0) * 0.5 * self.samples - 0.5).astype(np.intp)
        return TracedPupil(self.wavelength_nm, self.n_img, self.samples, ix, iy, pc, self.pos[k, ok], self.dirn[k, ok],
                           self.opl[k, ok], self.chief_pos[k], self.chief_dir[k], float(self.chief_opl[k]),
                           self.z_image if z_image is None else float(z_image), self.z_pupil)


def nodes_from_trace(pl: PerturbedLens, rays: Rays, res, fields, pupil: np.ndarray, samples: int,
                     z_pupil: float) -> TracedNodes:
    """:func:`pupil_from_trace` of K fields traced in one call: ``rays`` holds
    each field's ``pupil`` grid (M, 2) followed by its chief ray, field
    after field (K·(M + 1) rays; ``fields`` (K, 2) in degrees, ``z_pupil``
    in mm)."""
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
    return TracedNodes(float(lam), n_img, samples, p, valid, pos, dirn, opl, c_pos, c_dir, c_opl,
                       float(pl.image_pose.vertex[2]), float(z_pupil), node_jacobians(p, dirn, valid))


def node_jacobians(p: np.ndarray, dirn: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """:func:`solid_angle_jacobian` of K fields on one pupil grid ``p``
    (M, 2), with directions ``dirn`` (K, M, 3) and ``valid`` (K, M): (K, M),
    0 for invalid rays.

    The degree-4 fit of every field at once: the monomials of the grid are
    built once, each field's normal equations are the Gram matrix of its
    valid rows (one product for all fields: ``valid @ (v_i v_j)``), the
    systems are solved together with the same column scaling as
    :func:`calibration.optics.psf.linalg.lstsq`. Fields with fewer than 60 valid rays (a lower degree)
    or whose fit falls back to the affine J take the per-field function.
    """
    k, m = valid.shape
    degree = 4
    v, vx, vy = pupil_monomials(p, degree)
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
        med = masked_row_medians(j, valid)
        off = valid & ~(np.isfinite(j) & (j > 0.05 * med[:, None]))
    for i in np.flatnonzero(~many | off.any(axis=1)):
        ok = valid[i]
        j[i] = 0.0
        j[i, ok] = solid_angle_jacobian(p[ok], dirn[i, ok])
    return j


def node_spheres(tn: TracedNodes, centers: np.ndarray, z_image: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`reference_sphere` of every field of ``tn``, about the image-plane
    points ``(centers[k], z_image[k])`` (``centers`` (K, 2), ``z_image``
    (K,), mm).

    Returns ``q`` (K, M, 3) sources relative to P0 (mm), ``opd`` (K, M, mm)
    and ``amp`` (K, M, :attr:`ReferenceSphere.amp`), rays that do not reach the sphere with ``amp = 0``,
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
        jac[i, ok[i]] = solid_angle_jacobian(tn.p[ok[i]], tn.dirn[i, ok[i]])
    dp = 2.0 / tn.samples
    amp = np.where(ok, np.sqrt(jac) * dp * dp, 0.0)
    return q, opd, amp

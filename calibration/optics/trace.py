"""Real-ray tracing through perturbed lenses (paper, section 3.1.1, eqs. 1–10).

Rays are traced surface by surface in float64, vectorised over rays and
split into cache-sized chunks that run on a thread pool (numpy releases the
GIL inside its loops). For each surface the rays are

1. moved into the surface's local frame (its :class:`~calibration.optics.perturb.Pose`:
   ``p̄ = R (p − v)``, eq. 9; consecutive frames are composed into one
   relative transform, which is a pure axial shift on a coaxial lens),
2. intersected with the surface by Newton–Raphson on
   ``F(s) = z0 + s·m − sag(ρ(s))`` (eqs. 1–6) with the analytic derivative
   ``F'(s) = D·∇F``, ``∇F = (−g x, −g y, 1)``, ``g = (1/ρ) dsag/dρ``,
   started from the exact intersection with a conic fitted to the
   asphere's sag (:func:`_start_conic`; the plane for rays that miss it)
   and stopped when ``|Δs| < tol`` (default :data:`NEWTON_TOL` = 1e-12
   mm; at most ``max_iter`` = 50 iterations; after :data:`_FULL_ITERS`
   only the rays not yet converged iterate),
3. checked against the clear semi-diameter (vignetting),
4. refracted with the vector form of Snell's law (eqs. 7–8):
   ``D' = μ D + Γ r`` with ``μ = n/n'``, ``r = ∇F`` and Γ the root of
   ``Γ² + 2aΓ + b = 0``, ``a = μ (D·r)/(r·r)``, ``b = (μ² − 1)/(r·r)`` that
   keeps the ray going forward (no real root: total internal reflection),
5. charged the optical path ``n·s`` of the segment.

Surface shape: ``sag(ρ) = cρ²/(1 + √(1 − (1+k)c²ρ²)) + Σ A_i ρ^i`` (eq. 2,
any order), even terms evaluated by Horner in ρ², odd terms as ρ·(Horner in
ρ²). Pure conics (no polynomial terms) are intersected in closed form and
planes directly; only true aspheres iterate.

Rays that miss a surface, fall outside its semi-diameter, are totally
internally reflected or whose Newton iteration does not converge are
flagged (``valid`` False, a :class:`RayStatus` reason and the surface
where it happened) and carried on as a harmless axial placeholder (or,
once they are :data:`_DROP_SHARE` of a chunk, dropped from it), so no
NaN or inf ever leaves the tracer: invalid rays come back with position 0,
direction (0, 0, 1) and OPL 0.

Pupil conventions (:func:`pupil_rays`). The aperture stop has the radius of
the paraxial marginal ray at the stop for the lens's entrance pupil
diameter (given, or EFL/F#, at the primary wavelength; "float by stop
size" lenses use the stop's semi-diameter). Normalised pupil coordinates
``(px, py)`` in the unit disc map

* ``aiming="paraxial"``: to the point ``r_ep·(px, py)`` of the paraxial
  entrance pupil, a disc in the plane ``z = z_ep`` perpendicular to the
  axis; the chief ray passes through its centre;
* ``aiming="real"``: to the real ray that crosses the stop surface at
  ``r_stop·(px, py)`` in the stop's local frame (iterated per ray by a 2-D
  Newton method); the chief ray passes through the stop centre and the
  marginal rays fill the stop (Zemax "ray aiming" convention).

:func:`field_pupil_rays` makes the rays of many fields in one batch (a PSF
map or an SFR model traces hundreds of fields of a few thousand rays each,
where per-field calls would be mostly overhead).

A field is a direction ``field_deg = (θx, θy)`` in object space: rays from
infinity travel along ``(tan θx, tan θy, 1)/‖·‖`` (a positive θy images at
positive y); for a finite object the field is the angle of the chief ray
toward the entrance pupil centre. Units: mm, nm, degrees.

The paraxial pupil comes from :mod:`calibration.optics.paraxial`.
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from isp.runtime.executor import Executor, shared_threads

from calibration.optics import paraxial
from calibration.optics.lens import Lens, LensError
from calibration.optics.perturb import PerturbedLens, Pose, nominal

NEWTON_TOL = 1e-12
"""Newton–Raphson stopping tolerance on |Δs| (paper eq. 6, ε'), mm."""

MAX_ITER = 50
"""Newton iterations before a ray is flagged NOT_CONVERGED."""

CHUNK = 65536
"""Rays per chunk. Measured on the e9 lens (2-core x86, numpy 2.4): chunks
of 8k rays keep the working set (≈ 25 float64 arrays) in L2 and are
fastest per element on one thread, but numpy's per-call dispatch, which
holds the GIL, then serialises two threads (0.36M rays/s); 64k-ray chunks
(≈ 12 MB per thread, in L3) reach 0.63M rays/s on one thread and 1.0M on
two."""

_FULL_ITERS = 3
"""Newton iterations on a whole chunk before only the rays not yet
converged go on (gathered into smaller arrays). From the fitted start
(:func:`_start_conic`) 84 % of e9's rays converge in three; iterating the
whole chunk until its slowest ray converges cost 10 % more evaluations."""

_DROP_SHARE = 0.02
"""Share of a chunk's rays that must have failed before they are dropped
from it (rather than carried through the remaining surfaces as
placeholders, which costs as much as a live ray). On e9 a fifth of each
field's pupil grid is vignetted just after the stop, and carrying it
through the last eight aspheres cost ~10 % of the trace."""


class TraceError(LensError):
    """Invalid ray input (shapes, wavelength, options); the message says which."""


class RayStatus(enum.IntEnum):
    """Why a ray is not valid (``TraceResult.status``; 0 = valid)."""

    OK = 0
    MISS = 1            #: no intersection with the surface / outside the conic's domain / going backward
    VIGNETTED = 2       #: beyond the clear semi-diameter
    TIR = 3             #: total internal reflection
    NOT_CONVERGED = 4   #: Newton–Raphson did not reach the tolerance
    INVALID_INPUT = 5   #: non-finite origin or direction
    AIM_FAILED = 6      #: real ray aiming found no ray through the stop point


@dataclass(frozen=True, eq=False)
class Rays:
    """A batch of rays at one wavelength, in global coordinates.

    Attributes
    ----------
    origin : (N, 3) ndarray
        Start points, mm (before the first surface).
    direction : (N, 3) ndarray
        Unit direction vectors.
    wavelength_nm : float
    opl : (N,) ndarray
        Optical path already travelled, mm (for rays from infinity: the
        path from the plane wavefront through the entrance-pupil centre).
    status : (N,) int8 ndarray
        RayStatus of each ray before tracing (AIM_FAILED from aiming).
    pupil : (N, 2) ndarray or None
        Normalised pupil coordinates the rays were generated from.
    field_deg : (2,) tuple or None
    """

    origin: np.ndarray
    direction: np.ndarray
    wavelength_nm: float
    opl: np.ndarray | None = None
    status: np.ndarray | None = None
    pupil: np.ndarray | None = None
    field_deg: tuple[float, float] | None = None

    def __post_init__(self):
        o = np.asarray(self.origin, dtype=np.float64)
        d = np.asarray(self.direction, dtype=np.float64)
        if o.ndim != 2 or o.shape[1] != 3 or d.shape != o.shape:
            raise TraceError(f"origin and direction must both be (N, 3); got {o.shape} and {d.shape}")
        n = o.shape[0]
        if not (math.isfinite(self.wavelength_nm) and self.wavelength_nm > 0):
            raise TraceError(f"wavelength must be a positive number of nm, got {self.wavelength_nm!r}")
        opl = np.zeros(n) if self.opl is None else np.asarray(self.opl, dtype=np.float64).reshape(-1)
        st = np.zeros(n, np.int8) if self.status is None else np.asarray(self.status, dtype=np.int8).reshape(-1)
        if opl.shape != (n,) or st.shape != (n,):
            raise TraceError(f"opl and status must have one entry per ray ({n})")
        with np.errstate(invalid="ignore"):
            norm = np.sqrt(np.einsum("ij,ij->i", d, d))
            off = np.abs(norm - 1.0) > 1e-9
        if np.any(off & np.isfinite(norm)):
            raise TraceError("directions must be unit vectors (normalise them first)")
        object.__setattr__(self, "origin", o)
        object.__setattr__(self, "direction", d)
        object.__setattr__(self, "opl", opl)
        object.__setattr__(self, "status", st)

    def __len__(self) -> int:
        return self.origin.shape[0]


@dataclass(frozen=True, eq=False)
class TraceResult:
    """Ray data after tracing, global coordinates.

    Attributes
    ----------
    position : (N, 3) ndarray
        Where the rays end (image plane, last surface or the requested
        plane), mm. 0 for invalid rays.
    direction : (N, 3) ndarray
        Unit directions there (after the last refraction). (0, 0, 1) for
        invalid rays.
    opl : (N,) ndarray
        Optical path length, mm, from the input rays' reference (see
        :class:`Rays`). 0 for invalid rays.
    valid : (N,) bool ndarray
    status : (N,) int8 ndarray
        RayStatus codes.
    surface : (N,) int16 ndarray
        0-based surface where an invalid ray stopped (len(surfaces) = the
        image plane or target plane; 0 for INVALID_INPUT and AIM_FAILED);
        −1 for valid rays.
    wavelength_nm : float
    surface_positions : (S, N, 3) ndarray or None
        With ``record=True``: the intersection point with every surface
        (global), invalid rays included (finite placeholders after they fail).
    rays : Rays
        The input.
    """

    position: np.ndarray
    direction: np.ndarray
    opl: np.ndarray
    valid: np.ndarray
    status: np.ndarray
    surface: np.ndarray
    wavelength_nm: float
    surface_positions: np.ndarray | None
    rays: Rays

    @property
    def n_valid(self) -> int:
        return int(np.count_nonzero(self.valid))

    @property
    def fraction_valid(self) -> float:
        """Share of the rays that reached the end (0..1)."""
        return self.n_valid / max(len(self.valid), 1)


# -- compiled geometry -------------------------------------------------------

@dataclass(frozen=True)
class _Surf:
    kind: int                 # 0 plane, 1 conic (closed form), 2 asphere (Newton)
    c: float
    kc2: float                # (1 + k) c²
    even: tuple               # e_jmax..e_0 of Σ e_j u^j (u = ρ²), e_0 = 0
    odd: tuple                # o_jmax..o_0 of ρ Σ o_j u^j
    sd2: float                # semi-diameter², inf = none
    n: float                  # index before the surface
    mu: float                 # n / n'
    refract: bool
    rot: tuple | None         # relative rotation (previous local → this local), row-major 9-tuple
    shift: tuple              # translation in this frame after the rotation
    start: tuple = ()         # (c, (1 + k)c²) of the conic Newton starts from (default the base conic)


_PLANE, _CONIC, _ASPHERE = 0, 1, 2


def _relative(prev: Pose | None, cur: Pose):
    """(rotation 9-tuple or None, shift 3-tuple): p_cur = R p_prev + t."""
    rp = None if prev is None else prev.rotation
    rc = cur.rotation
    vp = np.zeros(3) if prev is None else prev.vertex
    dv = vp - cur.vertex
    if rp is None and rc is None:
        return None, tuple(float(a) for a in dv)
    if rp is not None and rc is not None and np.array_equal(rp, rc):  # within one tilted element
        return None, tuple(float(a) for a in rc @ dv)
    rrel = (np.eye(3) if rc is None else rc) @ (np.eye(3) if rp is None else rp.T)
    t = dv if rc is None else rc @ dv
    if np.array_equal(rrel, np.eye(3)):
        return None, tuple(float(a) for a in t)
    return tuple(float(a) for a in rrel.ravel()), tuple(float(a) for a in t)


@functools.lru_cache(maxsize=256)
def _start_conic(c: float, kc2: float, even: tuple, odd: tuple, sd2: float) -> tuple[float, float]:
    """``(c, (1 + k)c²)`` of the conic from which Newton starts on an asphere.

    The algebraic least-squares conic through the asphere's sag over its
    clear aperture, ``c ρ² + c(1 + k) z² = 2z`` (linear in c and c(1 + k);
    its residual is ≈ 2× the sag error), weighted by ρ as the rays fill
    the aperture (a plane where the fitted c is negligible). Used where it
    covers the aperture and 10 % beyond and is closer to the sag than the
    base conic; else the base conic. Only the start changes: Newton still
    converges to ``tol`` on the asphere. On e9, 10 of the 14 aspheres get
    one, 2–70× closer (largest sag error 0.001–0.3 mm instead of 0.01–1.4
    mm); with :data:`_FULL_ITERS` the Newton evaluations fell by a quarter.
    """
    if not (math.isfinite(sd2) and sd2 > 0):
        return c, kc2
    u = sd2 * np.linspace(0.0, 1.0, 65)[1:] ** 2
    sag, _ = _sag_g(_Surf(_ASPHERE, c, kc2, even, odd, sd2, 1.0, 1.0, False, None, (0.0, 0.0, 0.0)), u)
    w = u ** 0.25                                     # ρ^(1/2): rows weighted by √ρ, squares by ρ
    (a, b), *_ = np.linalg.lstsq(np.column_stack([u, sag * sag]) * w[:, None], 2.0 * sag * w, rcond=None)
    a, kc2_fit = float(a), float(a * b)
    if not (math.isfinite(a) and math.isfinite(kc2_fit)):
        return c, kc2
    if abs(a) * sd2 < 1e-12:                          # flat: start from the vertex plane
        a, kc2_fit = 0.0, 0.0
    if kc2_fit * 1.21 * sd2 >= 1.0:                   # the conic closes inside 1.1 × the aperture
        return c, kc2

    def conic_sag(cc, kk):
        return cc * u / (1.0 + np.sqrt(np.maximum(1.0 - kk * u, 0.0)))

    if np.max(np.abs(conic_sag(a, kc2_fit) - sag)) >= np.max(np.abs(conic_sag(c, kc2) - sag)):
        return c, kc2
    return a, kc2_fit


def _compile(pl: PerturbedLens, wavelength_nm: float) -> list[_Surf]:
    lens = pl.lens
    media = lens.media() + [lens.surfaces[-1].material]
    idx = [float(m.index(wavelength_nm)) for m in media]
    out = []
    prev = None
    for i, s in enumerate(lens.surfaces):
        terms = {o: a for o, a in s.asphere if a != 0.0}
        ev = {o // 2: a for o, a in terms.items() if o % 2 == 0}
        od = {(o - 1) // 2: a for o, a in terms.items() if o % 2 == 1}
        even = tuple(ev.get(j, 0.0) for j in range(max(ev), -1, -1)) if ev else ()
        odd = tuple(od.get(j, 0.0) for j in range(max(od), -1, -1)) if od else ()
        kind = _ASPHERE if terms else (_CONIC if s.curvature != 0 else _PLANE)
        sd2 = math.inf if s.semi_diameter is None else float(s.semi_diameter) ** 2
        rot, shift = _relative(prev, pl.poses[i])
        c, kc2 = float(s.curvature), float((1.0 + s.conic) * s.curvature ** 2)
        start = _start_conic(c, kc2, even, odd, sd2) if kind == _ASPHERE else (c, kc2)
        out.append(_Surf(kind, c, kc2, even, odd, sd2, idx[i], idx[i] / idx[i + 1], idx[i] != idx[i + 1], rot, shift,
                         start))
        prev = pl.poses[i]
    rot, shift = _relative(prev, pl.image_pose)
    out.append(_Surf(_PLANE, 0.0, 0.0, (), (), math.inf, idx[-1], 1.0, False, rot, shift))
    return out


# -- the kernel ---------------------------------------------------------------

def _sag_g(sf: _Surf, u):
    """sag(u) and g = (1/ρ) dsag/dρ at u = ρ² (new arrays, or a scalar g)."""
    c = sf.c
    if c == 0.0:
        sag = np.zeros_like(u)
        g = 0.0
    elif sf.kc2 == 0.0:  # paraboloid: sag = cρ²/2
        sag = (0.5 * c) * u
        g = c
    else:
        w = sf.kc2 * u
        np.subtract(1.0, w, out=w)
        np.maximum(w, 0.0, out=w)  # outside the conic's domain: flagged by the caller
        r = np.sqrt(w, out=w)
        g = c / r
        r += 1.0
        sag = c * u
        sag /= r
    ev = sf.even
    if ev:
        p = ev[0] * u
        if ev[1] != 0.0:
            p += ev[1]
        d = ev[0]
        for a in ev[2:]:
            d = d * u
            d += p
            p *= u
            if a != 0.0:
                p += a
        sag += p
        d *= 2.0
        g = g + d
    od = sf.odd
    if od:
        uu = np.maximum(u, 0.0)
        rho = np.sqrt(uu)
        q = np.full_like(u, od[0])
        dq = np.zeros_like(u)
        for a in od[1:]:
            dq = dq * uu + q
            q = q * uu + a
        sag += rho * q
        g = g + (q + 2.0 * uu * dq) / np.maximum(rho, 1e-150)
    return sag, g


def _conic_start(sf: _Surf, x, y, z, dx, dy, dz):
    """Distance to the start conic (the surface itself for conics; for
    aspheres Newton's start, :func:`_start_conic`) and a mask of rays that
    miss it (for those, the distance to the vertex plane)."""
    c, kc2 = sf.start or (sf.c, sf.kc2)
    if c == 0.0:
        return -z / dz, ~(dz > 0.0)
    k1 = kc2 / (c * c)  # 1 + k
    a = c * (dx * dx + dy * dy + k1 * dz * dz)
    b = c * (x * dx + y * dy + k1 * z * dz) - dz
    cc = c * (x * x + y * y + k1 * z * z) - 2.0 * z
    disc = b * b - a * cc
    miss = ~(disc >= 0.0)
    np.maximum(disc, 0.0, out=disc)
    den = np.sqrt(disc, out=disc)
    den -= b          # the root on the vertex side: s = cc / (−b + √(b² − a·cc))
    miss |= ~(den > 0.0)
    s = cc / den
    if miss.any():
        s[miss] = -z[miss] / dz[miss]
    return s, miss


def _hit_asphere(sf: _Surf, x, y, z, dx, dy, dz, s, tol, max_iter):
    """Newton from ``s`` on the whole chunk; rays still failing get the rest
    of the iterations, then a fresh start from the vertex plane (rays far
    outside the aperture, where the base conic is missed or left).
    Returns s, xs, ys, u, g, D·∇F, not-converged mask, miss mask."""
    out = list(_newton(sf, x, y, z, dx, dy, dz, s, tol, min(_FULL_ITERS, max_iter)))

    def good_hit(conv, u, fp):
        ok = conv & (fp > 0.0) & (fp < math.inf)  # crosses forward, finite normal
        if sf.kc2 > 0.0:
            ok &= sf.kc2 * u < 1.0                # inside the conic's domain
        return ok

    good = good_hit(out[6], out[3], out[5])
    if not good.all() and max_iter > _FULL_ITERS:
        j = np.flatnonzero(~good)
        r = _newton(sf, x[j], y[j], z[j], dx[j], dy[j], dz[j], out[0][j], tol, max_iter - _FULL_ITERS)
        for a, b in zip(out, r):
            a[j] = b
        j = j[~good_hit(r[6], r[3], r[5])]
        if j.size:  # start again from the vertex plane
            sub = [a[j] for a in (x, y, z, dx, dy, dz)]
            r = _newton(sf, *sub, -sub[2] / sub[5], tol, max_iter)
            ok = good_hit(r[6], r[3], r[5])
            for a, b in zip(out, r):
                a[j[ok]] = b[ok]
        good = good_hit(out[6], out[3], out[5])
    s, xs, ys, u, g, fp, conv = out
    forward = dz > 0.0
    return s, xs, ys, u, g, fp, ~conv & forward, (~good & conv) | ~forward


def _newton(sf: _Surf, x, y, z, dx, dy, dz, s, tol, iters):
    """Newton–Raphson on F(s) = z + s dz − sag(ρ(s)) from ``s``.

    Returns s, the hit point (xs, ys), u = ρ², g and F' = D·∇F (the last
    two at the last iterate, within tol of s) and the convergence mask
    (|Δs| < tol at the last step)."""
    # ρ² and the transverse part of D·∇F along the ray, as polynomials in s:
    # u = u0 + s (2p + s q), x·dx + y·dy = p + s q.
    u0 = x * x
    u0 += y * y
    p = x * dx
    p += y * dy
    q = dx * dx
    q += dy * dy
    conv = None
    for _ in range(iters):
        dot = q * s
        dot += p
        u = p + dot
        u *= s
        u += u0
        sag, g = _sag_g(sf, u)
        f = dz * s
        f += z
        f -= sag
        fp = g * dot
        np.subtract(dz, fp, out=fp)
        f /= fp
        s -= f
        np.abs(f, out=f)
        if f.max() < tol:   # NaN compares False: keeps iterating, then flagged
            conv = np.ones(s.shape, bool)
            break
    if conv is None:
        conv = f < tol
    xs = dx * s
    xs += x
    ys = dy * s
    ys += y
    if np.ndim(g) == 0:
        g = np.full_like(s, g)
    return s, xs, ys, u, g, fp, conv


def _kernel(geo: list[_Surf], x, y, z, dx, dy, dz, opl, status, where, *, upto: int, refract_last: bool,
            clip: bool, tol: float, max_iter: int, record):
    """Trace one chunk in place (SoA arrays). Surfaces ``0..upto-1`` of
    ``geo`` are traced; the last one is refracted only if ``refract_last``.
    Ends in the local frame of surface ``upto-1``.

    A ray that fails gets its status and surface in ``status`` and
    ``where`` and is carried on as an axial placeholder; without
    ``record``, failed rays are dropped from the chunk instead once they
    are :data:`_DROP_SHARE` of it (their outputs are placeholders: (0, 0, 0)
    along (0, 0, 1), ``opl`` as given; :func:`_run` overwrites them)."""
    n_all = len(x)
    live = None             # indices of the traced rays in the caller's arrays (None: all, in place)
    op = opl
    if record is None and not np.all(status == 0):
        live = np.flatnonzero(status == 0)
        x, y, z, dx, dy, dz, op = (a[live] for a in (x, y, z, dx, dy, dz, opl))
    carried = 0             # failed rays still carried as placeholders
    for i in range(upto):
        if not len(x):
            break
        sf = geo[i]
        if sf.rot is not None:
            r = sf.rot
            x, y, z = (r[0] * x + r[1] * y + r[2] * z + sf.shift[0],
                       r[3] * x + r[4] * y + r[5] * z + sf.shift[1],
                       r[6] * x + r[7] * y + r[8] * z + sf.shift[2])
            dx, dy, dz = (r[0] * dx + r[1] * dy + r[2] * dz,
                          r[3] * dx + r[4] * dy + r[5] * dz,
                          r[6] * dx + r[7] * dy + r[8] * dz)
        else:
            t0, t1, t2 = sf.shift
            if t0 != 0.0:
                x += t0
            if t1 != 0.0:
                y += t1
            if t2 != 0.0:
                z += t2
        bad = None
        if sf.kind == _PLANE:
            s = z / dz
            np.negative(s, out=s)
            xs = dx * s
            xs += x
            ys = dy * s
            ys += y
            u = xs * xs
            u += ys * ys
            g = None
            fp = dz
            miss = ~(dz > 0.0)
            notconv = None
        else:
            s, miss = _conic_start(sf, x, y, z, dx, dy, dz)
            if sf.kind == _CONIC:
                xs = dx * s
                xs += x
                ys = dy * s
                ys += y
                u = xs * xs
                u += ys * ys
                w = 1.0 - sf.kc2 * u
                miss |= ~(w > 0.0)
                np.maximum(w, 1e-300, out=w)
                g = sf.c / np.sqrt(w)
                fp = xs * dx
                fp += ys * dy
                fp *= g
                np.subtract(dz, fp, out=fp)
                miss |= ~(fp > 0.0)
                notconv = None
            else:
                s, xs, ys, u, g, fp, notconv, miss = _hit_asphere(sf, x, y, z, dx, dy, dz, s, tol, max_iter)
        # failures at this surface
        bad = miss if notconv is None else (miss | notconv)
        vig = None
        if clip and sf.sd2 != math.inf:
            vig = u > sf.sd2
            bad = bad | vig
        refr = sf.refract and (refract_last or i < upto - 1)
        if refr:
            mu = sf.mu
            if g is None:  # plane: r = (0, 0, 1)
                a = mu * dz
                bq = mu * mu - 1.0
                disc = a * a
                disc -= bq
            else:
                rr = g * g
                rr *= u
                rr += 1.0
                a = fp * mu
                a /= rr
                bq = (mu * mu - 1.0) / rr
                disc = a * a
                disc -= bq
            tir = ~(disc >= 0.0)
            bad = bad | tir
        # z at the hit (local): z + s dz
        zs = dz * s
        zs += z
        op += sf.n * s
        if refr:
            np.maximum(disc, 0.0, out=disc)
            np.sqrt(disc, out=disc)
            disc += a
            gam = np.divide(bq, disc, out=disc)
            np.negative(gam, out=gam)
            if g is None:
                dx = dx * mu
                dy = dy * mu
                dz = dz * mu
                dz += gam
            else:
                gg = gam * g
                dx = dx * mu
                dx -= gg * xs
                dy = dy * mu
                dy -= gg * ys
                dz = dz * mu
                dz += gam
        x, y, z = xs, ys, zs
        if bad.any():
            j = np.flatnonzero(bad)
            jc = j if live is None else live[j]
            fresh = status[jc] == 0
            jj = j[fresh]
            if jj.size:
                reason = np.full(jj.size, RayStatus.MISS, np.int8)
                if refr:
                    reason[tir[jj]] = RayStatus.TIR
                if vig is not None:
                    reason[vig[jj]] = RayStatus.VIGNETTED
                if notconv is not None:
                    reason[notconv[jj]] = RayStatus.NOT_CONVERGED
                reason[miss[jj]] = RayStatus.MISS
                status[jc[fresh]] = reason
                where[jc[fresh]] = i
                carried += jj.size
            if record is None and carried >= _DROP_SHARE * len(x):
                keep = status == 0 if live is None else status[live] == 0
                live = np.flatnonzero(keep) if live is None else live[keep]
                x, y, z, dx, dy, dz, op = (a[keep] for a in (x, y, z, dx, dy, dz, op))
                carried = 0
            else:   # axial placeholder at this surface's vertex
                x[j] = 0.0
                y[j] = 0.0
                z[j] = 0.0
                dx[j] = 0.0
                dy[j] = 0.0
                dz[j] = 1.0
        if record is not None:
            record(i, x, y, z)
    if live is None:
        return x, y, z, dx, dy, dz
    opl[live] = op
    out = [np.zeros(n_all) for _ in range(5)] + [np.ones(n_all)]
    for full, part in zip(out, (x, y, z, dx, dy, dz)):
        full[live] = part
    return tuple(out)


def _to_global(pose: Pose, x, y, z):
    if pose.rotation is not None:
        r = pose.rotation  # p_g = Rᵀ p + v
        x, y, z = (r[0, 0] * x + r[1, 0] * y + r[2, 0] * z,
                   r[0, 1] * x + r[1, 1] * y + r[2, 1] * z,
                   r[0, 2] * x + r[1, 2] * y + r[2, 2] * z)
    v = pose.vertex
    return x + v[0], y + v[1], z + v[2]


def _dir_to_global(pose: Pose, dx, dy, dz):
    if pose.rotation is None:
        return dx, dy, dz
    r = pose.rotation
    return (r[0, 0] * dx + r[1, 0] * dy + r[2, 0] * dz,
            r[0, 1] * dx + r[1, 1] * dy + r[2, 1] * dz,
            r[0, 2] * dx + r[1, 2] * dy + r[2, 2] * dz)


def _run(pl: PerturbedLens, rays: Rays, *, to: str, clip: bool, record: bool, tol: float, max_iter: int,
         chunk: int, executor: Executor | None, frame: str = "global", geo=None):
    """Trace ``rays``; ``to`` is "image", "exit" or "stop" (the stop
    surface's intersection, before refraction, in the stop's local frame)."""
    if not (isinstance(tol, float | int) and tol > 0):
        raise TraceError(f"tol must be a positive number of mm, got {tol!r}")
    if not (isinstance(max_iter, int) and max_iter >= 1):
        raise TraceError(f"max_iter must be a positive integer, got {max_iter!r}")
    geo = geo if geo is not None else _compile(pl, rays.wavelength_nm)
    ns = len(pl.lens.surfaces)
    if to == "image":
        upto, refract_last, end_pose = ns + 1, True, pl.image_pose
    elif to == "exit":
        upto, refract_last, end_pose = ns, True, pl.poses[-1]
    elif to == "stop":
        upto, refract_last, end_pose = pl.stop_index + 1, False, pl.poses[pl.stop_index]
    else:
        raise TraceError(f"unknown trace target {to!r}; valid: 'image', 'exit', 'stop'")
    n = len(rays)
    pos = np.zeros((n, 3))
    dirn = np.zeros((n, 3))
    opl = rays.opl.copy()
    status = rays.status.copy()
    where = np.full(n, -1, np.int16)
    where[status != 0] = 0
    rec = np.zeros((upto, n, 3)) if record else None
    o, d = rays.origin, rays.direction
    chunk = max(int(chunk), 1)
    bounds = [(a, min(a + chunk, n)) for a in range(0, n, chunk)]

    def one(b):
        a, e = b
        x, y, z = (np.array(o[a:e, k]) for k in range(3))        # copies: traced in place
        dx, dy, dz = (np.array(d[a:e, k]) for k in range(3))
        op = opl[a:e].copy()
        st = status[a:e].copy()
        wh = where[a:e].copy()
        finite = np.isfinite(x) & np.isfinite(y) & np.isfinite(z) & np.isfinite(dx) & np.isfinite(dy) & np.isfinite(dz)
        pre = ~finite | (st != 0)
        if pre.any():
            st[~finite & (st == 0)] = RayStatus.INVALID_INPUT
            wh[pre] = 0
            # placeholder: an axial ray well before the first surface
            x[pre] = 0.0
            y[pre] = 0.0
            z[pre] = pl.poses[0].vertex[2] - 1.0
            dx[pre] = 0.0
            dy[pre] = 0.0
            dz[pre] = 1.0
        def cb(i, xx, yy, zz):
            pose = pl.poses[i] if i < ns else pl.image_pose
            gx, gy, gz = _to_global(pose, xx, yy, zz)
            rec[i, a:e, 0], rec[i, a:e, 1], rec[i, a:e, 2] = gx, gy, gz
        with np.errstate(all="ignore"):
            x, y, z, dx, dy, dz = _kernel(geo, x, y, z, dx, dy, dz, op, st, wh, upto=upto,
                                          refract_last=refract_last, clip=clip, tol=float(tol),
                                          max_iter=max_iter, record=cb if rec is not None else None)
        if frame == "global":
            x, y, z = _to_global(end_pose, x, y, z)
            dx, dy, dz = _dir_to_global(end_pose, dx, dy, dz)
        pos[a:e, 0], pos[a:e, 1], pos[a:e, 2] = x, y, z
        dirn[a:e, 0], dirn[a:e, 1], dirn[a:e, 2] = dx, dy, dz
        opl[a:e] = op
        status[a:e] = st
        where[a:e] = wh

    ex = shared_threads() if executor is None else executor
    if ex.parallel and len(bounds) > 1:
        ex.map(one, bounds)
    else:
        for b in bounds:
            one(b)
    valid = status == 0
    inv = ~valid
    if inv.any():
        pos[inv] = 0.0
        dirn[inv] = (0.0, 0.0, 1.0)
        opl[inv] = 0.0
    where[valid] = -1
    return TraceResult(pos, dirn, opl, valid, status, where, float(rays.wavelength_nm), rec, rays)


def trace(lens: Lens | PerturbedLens, rays: Rays, *, to: str = "image", clip: bool = True,
          record: bool = False, tol: float = NEWTON_TOL, max_iter: int = MAX_ITER,
          chunk: int = CHUNK, executor: Executor | None = None) -> TraceResult:
    """Trace rays through a (perturbed) lens.

    Parameters
    ----------
    lens : Lens or PerturbedLens
        A plain Lens is traced as its zero perturbation (identity poses).
    rays : Rays
        Global coordinates, one wavelength.
    to : {"image", "exit"}
        End on the image plane, or on the last surface (after its
        refraction: the exit-pupil-side ray data).
    clip : bool
        Vignette by the surfaces' semi-diameters (False: ignore them).
    record : bool
        Keep every surface intersection (``surface_positions``).
    tol : float
        Newton–Raphson tolerance on |Δs|, mm.
    max_iter : int
    chunk : int
        Rays per chunk.
    executor : isp.runtime.executor.Executor, optional
        Runs the chunks; "threads" (the kernel releases the GIL) or
        "serial". Default: :func:`isp.runtime.executor.shared_threads`, a
        persistent pool of all cores.

    Returns
    -------
    TraceResult
        Positions (mm), unit directions, OPL (mm), valid mask and reasons.
    """
    return _run(nominal(lens), rays, to=to, clip=clip, record=record, tol=tol, max_iter=max_iter,
                chunk=chunk, executor=executor)


def trace_to_image(lens: Lens | PerturbedLens, rays: Rays, **kw) -> TraceResult:
    """Trace to the image plane (see :func:`trace`)."""
    return trace(lens, rays, to="image", **kw)


def trace_to_exit(lens: Lens | PerturbedLens, rays: Rays, **kw) -> TraceResult:
    """Ray data after the last surface: position on it (mm, global), the
    direction after its refraction and the OPL up to it — what a PSF
    computation propagates to the exit-pupil reference sphere."""
    return trace(lens, rays, to="exit", **kw)


def trace_to_plane(lens: Lens | PerturbedLens, rays: Rays, point: Sequence[float], normal: Sequence[float],
                   **kw) -> TraceResult:
    """Trace through the lens and on to an arbitrary plane (global
    ``point`` on it, ``normal`` not perpendicular to the rays), in image
    space; OPL includes the last leg (signed: negative if the plane lies
    before the last surface)."""
    pl = nominal(lens)
    res = trace(pl, rays, to="exit", **kw)
    p0 = np.asarray(point, dtype=np.float64).reshape(3)
    nv = np.asarray(normal, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(p0)) and np.all(np.isfinite(nv)) and np.linalg.norm(nv) > 0):
        raise TraceError(f"plane point and normal must be finite, normal non-zero; got {p0}, {nv}")
    nv = nv / np.linalg.norm(nv)
    den = res.direction @ nv
    with np.errstate(all="ignore"):
        s = ((p0 - res.position) @ nv) / den
    ok = res.valid & np.isfinite(s) & (np.abs(den) > 1e-12)
    s = np.where(ok, s, 0.0)
    n_img = float(pl.lens.surfaces[-1].material.index(rays.wavelength_nm))
    pos = res.position + s[:, None] * res.direction
    opl = res.opl + n_img * s
    status = res.status.copy()
    surface = res.surface.copy()
    newly = res.valid & ~ok
    status[newly] = RayStatus.MISS
    surface[newly] = len(pl.lens.surfaces)
    pos[~ok] = 0.0
    opl[~ok] = 0.0
    d = res.direction.copy()
    d[~ok] = (0.0, 0.0, 1.0)
    return TraceResult(pos, d, opl, ok, status, surface, res.wavelength_nm, res.surface_positions, rays)


# -- pupil and ray generation -----------------------------------------------

@dataclass(frozen=True)
class Pupil:
    """Paraxial entrance pupil and stop of a lens at one wavelength.

    Attributes
    ----------
    z : float
        Entrance pupil position on the axis (global z, mm; first vertex = 0).
    radius : float
        Entrance pupil radius, mm.
    stop_radius : float
        Radius of the aperture stop (paraxial marginal ray at the stop), mm.
    efl : float
        Effective focal length, mm.
    """

    z: float
    radius: float
    stop_radius: float
    efl: float


#: the last few lenses' pupils, by identity: lenses are frozen, and a PSF
#: map or an SFR model asks once per field node for the same lens (600
#: times per evaluation of a 15 × 20 model, 0.6 s of paraxial algebra)
_PUPILS: dict[int, tuple[object, "Pupil"]] = {}


def stop_and_pupil(lens: Lens | PerturbedLens) -> Pupil:
    """Paraxial entrance pupil and stop radius at the primary wavelength
    (first-order data from :mod:`calibration.optics.paraxial`).

    For a PerturbedLens the stop keeps the *nominal* lens's radius (it is a
    physical part); the entrance pupil is the image of that stop through
    the perturbed front group (its coaxial part: poses are ignored).
    """
    hit = _PUPILS.get(id(lens))
    if hit is not None and hit[0] is lens:
        return hit[1]
    pupil = _stop_and_pupil(lens)
    if len(_PUPILS) >= 16:
        _PUPILS.pop(next(iter(_PUPILS)))
    _PUPILS[id(lens)] = (lens, pupil)
    return pupil


def _stop_and_pupil(lens: Lens | PerturbedLens) -> Pupil:
    pl = nominal(lens)
    nom = pl.nominal
    lam = nom.primary_nm

    def stop_gain(ln: Lens) -> float:   # y at the stop per unit height of a collimated ray
        k = ln.stop_index
        return 1.0 if k == 0 else float(paraxial.system_matrix(ln, 0, k - 1, lam, transfer_last=True)[0, 0])

    _, epd = paraxial.entrance_pupil(nom, lam)
    r_stop = 0.5 * epd * abs(stop_gain(nom))
    z_ep, _ = paraxial.entrance_pupil(pl.lens, lam)
    a = stop_gain(pl.lens)
    return Pupil(z=float(z_ep), radius=r_stop / abs(a), stop_radius=r_stop, efl=paraxial.efl(pl.lens, lam))


def pupil_grid(n: int, distribution: str = "random", rng: np.random.Generator | None = None) -> np.ndarray:
    """Normalised pupil coordinates (M, 2) in the unit disc.

    * "random": ``n`` points uniform in area (r = √U, θ = 2πV); rng
      default ``np.random.default_rng(0)``.
    * "grid": the points of an ``n × n`` square grid over [−1, 1]² inside
      the disc (cell centres, so the grid is symmetric and avoids the axis).
    * "hexapolar": ``n`` rings, ring k with 6k points, plus the centre
      (1 + 3n(n+1) points), equal-area rings (r_k = k/n).
    """
    if n < 1:
        raise TraceError(f"n must be ≥ 1, got {n!r}")
    if distribution == "random":
        rng = np.random.default_rng(0) if rng is None else rng
        r = np.sqrt(rng.random(n))
        t = 2 * np.pi * rng.random(n)
        return np.column_stack([r * np.cos(t), r * np.sin(t)])
    if distribution == "grid":
        g = (np.arange(n) + 0.5) / n * 2.0 - 1.0
        px, py = np.meshgrid(g, g)
        keep = px * px + py * py <= 1.0
        return np.column_stack([px[keep], py[keep]])
    if distribution == "hexapolar":
        pts = [np.zeros((1, 2))]
        for k in range(1, n + 1):
            t = 2 * np.pi * np.arange(6 * k) / (6 * k)
            pts.append(k / n * np.column_stack([np.cos(t), np.sin(t)]))
        return np.concatenate(pts)
    raise TraceError(f"unknown pupil distribution {distribution!r}; valid: 'random', 'grid', 'hexapolar'")


def _field_direction(field_deg) -> np.ndarray:
    fx, fy = (float(f) for f in field_deg)
    if not (abs(fx) < 90 and abs(fy) < 90):
        raise TraceError(f"field angles must be within ±90°, got {field_deg!r}")
    d = np.array([math.tan(math.radians(fx)), math.tan(math.radians(fy)), 1.0])
    return d / np.linalg.norm(d)


def _start_z(pl: PerturbedLens, z_ep: float) -> float:
    """A plane safely before the first surface (and the pupil)."""
    s = pl.lens.surfaces[0]
    sd = s.semi_diameter if s.semi_diameter is not None else 10.0
    rho = np.linspace(0.0, sd, 64)
    with np.errstate(invalid="ignore"):
        sag = s.sag(rho)
    lo = float(np.nanmin(sag)) if np.any(np.isfinite(sag)) else 0.0
    return min(0.0, z_ep, lo + pl.poses[0].vertex[2]) - 1.0 - sd


def _rays_through(pl: PerturbedLens, dirn: np.ndarray, ep_xy: np.ndarray, z_ep: float, z0: float,
                  wavelength_nm: float, obj_point: np.ndarray | None):
    """Rays crossing the plane z = z_ep at ``ep_xy`` (..., 2): from infinity
    along ``dirn`` (3,), or from ``obj_point`` (3,); either may instead
    have a shape (..., 3) that broadcasts against ``ep_xy`` (one per field
    of a batch). Returns origin (..., 3), direction (..., 3), opl (...)."""
    shape = ep_xy.shape[:-1]
    origin = np.empty(shape + (3,))
    direction = np.empty(shape + (3,))
    if obj_point is None:
        dx, dy, dz = dirn[..., 0], dirn[..., 1], dirn[..., 2]
        t = (z_ep - z0) / dz
        origin[..., 0] = ep_xy[..., 0] - t * dx
        origin[..., 1] = ep_xy[..., 1] - t * dy
        origin[..., 2] = z0
        direction[:] = dirn
        n0 = float(pl.lens.media()[0].index(wavelength_nm))
        # OPL 0 on the plane wavefront through the pupil centre: (o − e_c)·d = ep·d − t
        opl = ep_xy @ dirn[:2] if np.ndim(dirn) == 1 else ep_xy[..., 0] * dx + ep_xy[..., 1] * dy
        opl -= t
        opl *= n0
    else:
        origin[:] = obj_point
        direction[..., :2] = ep_xy - obj_point[..., :2]
        direction[..., 2] = z_ep - obj_point[..., 2]
        direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
        opl = np.zeros(shape)
    return origin, direction, opl


def _object_point(pl: PerturbedLens, pp: Pupil, dirn: np.ndarray) -> np.ndarray | None:
    """The object point of field direction(s) ``dirn`` ((3,) or (K, 3)) for a
    finite object (None at infinity): on the chief ray through the entrance
    pupil centre, in the object plane."""
    if not math.isfinite(pl.lens.object_distance):
        return None
    zo = -float(pl.lens.object_distance)
    if zo >= pp.z:
        raise TraceError("the object must lie before the entrance pupil")
    d = np.asarray(dirn, dtype=np.float64)
    return np.array([0.0, 0.0, pp.z]) - ((pp.z - zo) / d[..., 2])[..., None] * d


def field_pupil_rays(lens: Lens | PerturbedLens, fields_deg, pupil, wavelength_nm: float | None = None, *,
                     aiming: str = "paraxial", status=None, aim_tol: float = 1e-10) -> Rays:
    """Rays of K fields through given pupil points, in one batch:
    :func:`pupil_rays` with ``pupil=pupil[k]`` for every field ``k``,
    concatenated field after field, without the per-call overhead (a PSF
    map or an SFR model traces a few hundred fields of a few thousand
    rays; real aiming iterates all of them together).

    Parameters
    ----------
    lens : Lens or PerturbedLens
    fields_deg : (K, 2) array_like
        Field angles (θx, θy), degrees.
    pupil : (M, 2) or (K, M, 2) array_like
        Normalised entrance-pupil coordinates: one set for every field, or
        one per field (e.g. found by real aiming at the nominal lens).
    wavelength_nm : float, optional
        Default: the primary wavelength.
    aiming : {"paraxial", "real"}
        As :func:`pupil_rays`.
    status : (K, M) array_like, optional
        RayStatus of each ray before tracing (e.g. AIM_FAILED of an
        earlier aiming); real aiming adds its own failures.
    aim_tol : float
        Real aiming: accepted miss of the stop target, mm.

    Returns
    -------
    Rays
        K·M rays; ``pupil`` holds their pupil coordinates, ``field_deg`` is None.
    """
    pl = nominal(lens)
    lam = pl.nominal.primary_nm if wavelength_nm is None else float(wavelength_nm)
    f = np.asarray(fields_deg, dtype=np.float64).reshape(-1, 2)
    k = len(f)
    pc = np.asarray(pupil, dtype=np.float64)
    pc = np.broadcast_to(pc, (k,) + pc.shape) if pc.ndim == 2 else pc
    if pc.ndim != 3 or pc.shape[0] != k or pc.shape[2] != 2:
        raise TraceError(f"pupil must be (M, 2) or ({k}, M, 2) for {k} fields, got {np.shape(pupil)}")
    m = pc.shape[1]
    if not np.all(np.abs(f) < 90):
        raise TraceError(f"field angles must be within ±90°, got {f[np.argmax(np.any(np.abs(f) >= 90, axis=1))]}")
    pp = stop_and_pupil(pl)
    dirn = np.column_stack([np.tan(np.radians(f[:, 0])), np.tan(np.radians(f[:, 1])), np.ones(k)])
    dirn /= np.linalg.norm(dirn, axis=1, keepdims=True)          # as _field_direction, per field
    z0 = _start_z(pl, pp.z)
    obj = _object_point(pl, pp, dirn)
    st = np.zeros(k * m, np.int8) if status is None else np.array(status, dtype=np.int8).reshape(k * m)
    if aiming == "paraxial":
        ep = pp.radius * pc
    elif aiming == "real":
        per_ray = (np.repeat(dirn, m, axis=0), None if obj is None else np.repeat(obj, m, axis=0))
        ep, ok = _aim(pl, pc.reshape(k * m, 2), per_ray[0], pp, z0, lam, per_ray[1], aim_tol)
        ep = ep.reshape(k, m, 2)
        st[~ok & (st == 0)] = RayStatus.AIM_FAILED
    else:
        raise TraceError(f"unknown aiming {aiming!r}; valid: 'paraxial', 'real'")
    o, d, opl = _rays_through(pl, dirn[:, None], ep, pp.z, z0, lam, None if obj is None else obj[:, None])
    return Rays(o.reshape(k * m, 3), d.reshape(k * m, 3), lam, opl.reshape(k * m), st, pc.reshape(k * m, 2))


def pupil_rays(lens: Lens | PerturbedLens, field_deg: Sequence[float] = (0.0, 0.0), n: int = 1000,
               wavelength_nm: float | None = None, *, distribution: str = "random", aiming: str = "paraxial",
               rng: np.random.Generator | None = None, pupil: np.ndarray | None = None,
               aim_tol: float = 1e-10) -> Rays:
    """Rays from one field point filling the pupil.

    Parameters
    ----------
    lens : Lens or PerturbedLens
    field_deg : (θx, θy)
        Field angle in degrees (see the module docstring).
    n : int
        Size of the pupil sampling (see :func:`pupil_grid`).
    wavelength_nm : float, optional
        Default: the lens's primary wavelength. The pupil is always the
        primary wavelength's.
    distribution : {"random", "grid", "hexapolar"}
    aiming : {"paraxial", "real"}
        Paraxial entrance pupil, or real rays aimed at the stop.
    rng : numpy Generator, optional
        For "random".
    pupil : (M, 2) ndarray, optional
        Explicit normalised pupil coordinates (overrides n/distribution).
    aim_tol : float
        Real aiming: accepted miss of the stop target, mm.

    Returns
    -------
    Rays
        Origins before the first surface, unit directions, OPL from the
        wavefront through the entrance-pupil centre (object at infinity) or
        from the object point, the pupil coordinates and field; rays that
        real aiming could not place carry ``AIM_FAILED``.
    """
    pl = nominal(lens)
    lam = pl.nominal.primary_nm if wavelength_nm is None else float(wavelength_nm)
    pc = pupil_grid(n, distribution, rng) if pupil is None else np.asarray(pupil, dtype=np.float64).reshape(-1, 2)
    pp = stop_and_pupil(pl)
    dirn = _field_direction(field_deg)
    z0 = _start_z(pl, pp.z)
    obj = _object_point(pl, pp, dirn)
    status = np.zeros(pc.shape[0], np.int8)
    if aiming == "paraxial":
        ep = pp.radius * pc
    elif aiming == "real":
        ep, ok = _aim(pl, pc, dirn, pp, z0, lam, obj, aim_tol)
        status[~ok] = RayStatus.AIM_FAILED
    else:
        raise TraceError(f"unknown aiming {aiming!r}; valid: 'paraxial', 'real'")
    o, d, opl = _rays_through(pl, dirn, ep, pp.z, z0, lam, obj)
    return Rays(o, d, lam, opl, status, pc, (float(field_deg[0]), float(field_deg[1])))


def _aim(pl, pc, dirn, pp: Pupil, z0, lam, obj, tol, max_iter: int = 30):
    """Real ray aiming: per ray, the entrance-pupil-plane point (M, 2) whose
    real ray hits the stop at r_stop·pc (stop frame), and a success mask.
    ``dirn`` and ``obj`` are the field's (3,), or (M, 3) per ray when the
    rays of many fields are aimed together.

    2-D Newton on the pupil-plane point, all rays at once, the Jacobian by
    forward differences; it is kept (chord steps, one partial trace per
    iteration) while each step shrinks the miss at least tenfold and
    recomputed for the rays where it does not. Only unconverged rays are
    traced again."""
    geo = _compile(pl, lam)
    target = pp.stop_radius * pc
    h = 1e-6 * max(pp.radius, 1e-3)

    per_ray = np.ndim(dirn) == 2            # one field per ray (a batch of fields)

    def stop_hit(ep, idx):
        d_i = dirn[idx] if per_ray else dirn
        obj_i = obj[idx] if per_ray and obj is not None else obj
        o, d, opl = _rays_through(pl, d_i, ep, pp.z, z0, lam, obj_i)
        r = _run(pl, Rays(o, d, lam, opl), to="stop", clip=False, record=False, tol=NEWTON_TOL,
                 max_iter=MAX_ITER, chunk=CHUNK, executor=None, frame="local", geo=geo)
        return r.position[:, :2], r.valid

    m = len(pc)
    ep = pp.radius * pc
    ok = np.zeros(m, bool)
    jac = np.zeros((m, 4))                  # ∂(stop x, y)/∂(pupil-plane x, y), row-major
    fresh = np.ones(m, bool)                # needs a new Jacobian
    last = np.full(m, np.inf)               # miss at the previous iteration
    act = np.arange(m)
    for _ in range(max_iter):
        if not act.size:
            break
        e = ep[act]
        f, v = stop_hit(e, act)
        res = f - target[act]
        err = np.hypot(res[:, 0], res[:, 1])
        done = v & (err < tol)
        ok[act[done]] = True
        fresh[act] |= err > 0.1 * last[act]
        last[act] = err
        keep = v & ~done                    # a ray that fails to reach the stop is given up
        act, e, f, res = act[keep], e[keep], f[keep], res[keep]
        need = fresh[act]
        if need.any():
            k, ek, fk = act[need], e[need], f[need]
            fx, vx = stop_hit(ek + [h, 0.0], k)
            fy, vy = stop_hit(ek + [0.0, h], k)
            jk = np.column_stack([fx[:, 0] - fk[:, 0], fy[:, 0] - fk[:, 0],
                                  fx[:, 1] - fk[:, 1], fy[:, 1] - fk[:, 1]]) / h
            jk[~(vx & vy)] = np.nan
            jac[k] = jk
            fresh[k] = False
        j11, j12, j21, j22 = jac[act].T
        det = j11 * j22 - j12 * j21
        with np.errstate(all="ignore"):
            step = np.column_stack([j22 * res[:, 0] - j12 * res[:, 1], -j21 * res[:, 0] + j11 * res[:, 1]])
            step /= det[:, None]
        finite = np.isfinite(step).all(axis=1)
        act, e, step = act[finite], e[finite], step[finite]
        big = np.hypot(step[:, 0], step[:, 1]) > pp.radius   # far from the solution: damp
        step[big] *= 0.5
        ep[act] = e - step
    return ep, ok

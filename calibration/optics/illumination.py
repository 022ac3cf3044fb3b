"""Relative illumination over the field from the real ray trace.

Relative illumination (RI) is the image irradiance of a uniform Lambertian
scene at an image point, relative to the centre of the field. It combines
vignetting by the semi-diameters (the transmitted fraction of the beam),
the obliquity of the beam, pupil aberrations and distortion; the
"cos⁴ law" is the special case of a small, undistorted pupil and a
distortion-free mapping (Reiss 1945).

Two methods, both from radiance conservation (``L/n²`` is invariant along a
ray through a lossless system):

``"flux"`` (default): flux conservation in object space. A field direction
    ``ω`` (object at infinity; ``a = tan θx``, ``b = tan θy``) sends the
    flux ``dΦ = L · A⊥(ω) · dω`` through the lens, where ``A⊥`` is the
    cross-section, perpendicular to the beam, of the rays that reach the
    image (the transmitted part of the entrance pupil, ``A_EP · cos θ`` for a
    round undistorted pupil without vignetting). That flux lands around the
    beam's centroid ``x'(a, b)`` on the sensor, so

    .. math::

        E(x') = L\\,A_\\perp(a, b)\\,\\frac{d\\omega}{dA'}
              = \\frac{L\\,A_\\perp(a, b)}{(1 + a^2 + b^2)^{3/2}\\,
                \\left|\\det \\partial(x', y')/\\partial(a, b)\\right|}

    (``dω = da db / (1 + a² + b²)^{3/2}``). For a finite object the object
    area element replaces the solid angle: ``E = L · Ω_obj · dA_obj/dA'``
    with ``Ω_obj`` the projected solid angle of the transmitted rays at the
    object point. With an ideal distortion-free lens (``x' = f·(a, b)``) and
    ``A⊥ = A_EP cos θ`` this is exactly ``cos⁴ θ``. Distortion enters
    through the Jacobian, vignetting and pupil aberration through ``A⊥``,
    and nothing assumes the sensor is at the bundle's focus.

``"image_space"``: the projected solid angle of the converging bundle at
    the image point (Rimmer 1986; the method of OpticStudio's and CODE V's
    relative-illumination analyses): ``E = L (n'/n)² ∬ dL' dM'``, the area
    of the transmitted rays' direction cosines ``(L', M')`` in image space.
    It assumes the sensor is a good conjugate of the object: on a lens with
    field curvature the off-axis bundles converge before the sensor and the
    method overestimates the irradiance there (a thin F/10 singlet with its
    stop at the lens: 1.08 at 20° where flux conservation and cos⁴ give
    0.78). On a well-corrected phone lens the two methods agree to about
    0.5 % (US-12210142-B2-e9).

Both integrals are over the normalised pupil ``(px, py)`` of stop-filling
rays (real ray aiming): ``∬ |∂(u, v)/∂(px, py)| dpx dpy`` over the rays that
reach the image, the Jacobian by forward differences (step ``1e-4``) at the
cell centres of an ``n × n`` grid, so vignetting by any semi-diameter is
counted exactly up to the grid's resolution of the pupil's edge (≈ 0.1 %
at n = 64).

The samples, taken along the +y field (as OpticStudio's "Scan Type +y"),
are interpolated in ``r²`` by a monotone piecewise-cubic (PCHIP), so the
fit is even in ``r``, smooth (C¹), passes through every sample and does not
overshoot; beyond the last sample the last value holds.

Units
-----
===================  ==================================================
quantity             unit
===================  ==================================================
``height_mm``        image height of the beam centroid from the optical
                     axis's image (``center_mm``), mm
``field_deg``        object-side field angle, degrees
``value``            RI, 1 on axis, ≥ 0
``transmitted``      fraction of the stop-filling rays that reach the
                     image, 0..1
===================  ==================================================

References
----------
M. Reiss, "The cos⁴ law of illumination", J. Opt. Soc. Am. 35(4), 283–288
(1945). M. P. Rimmer, "Relative illumination calculations", Proc. SPIE 655,
99–104 (1986). D. Reshidko, J. Sasián, "Geometrical irradiance changes in a
symmetric optical system", Opt. Eng. 56(1), 015104 (2017). T. P. Johnson,
J. Sasián, "Image distortion, pupil coma, and relative illumination",
Appl. Opt. 59(22), G19–G23 (2020). Ansys Zemax OpticStudio User Guide,
"Relative Illumination" (integration of the exit pupil's area in direction
cosine space, after Rimmer).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from calibration.optics import paraxial
from calibration.optics import trace as tr
from calibration.optics.lens import Lens, LensError, Sensor
from calibration.optics.perturb import PerturbedLens, nominal

__all__ = ["METHODS", "RelativeIllumination", "relative_illumination", "ri_cos4"]

METHODS = ("flux", "image_space")

_EPS = 1e-4      # forward-difference step in normalised pupil coordinates
_DTAN = 1e-3     # central-difference step in tan(field angle), flux method


def ri_cos4(angle_deg) -> np.ndarray:
    """The cos⁴ law, ``cos⁴ θ`` (θ in degrees).

    >>> round(float(ri_cos4(30.0)), 4)
    0.5625
    """
    return np.cos(np.deg2rad(np.asarray(angle_deg, dtype=np.float64))) ** 4


@dataclass(frozen=True, eq=False)
class RelativeIllumination:
    """Relative illumination samples over the field and their smooth fit.

    Attributes
    ----------
    height_mm : (K,) ndarray
        Image heights of the samples, mm, increasing, the first 0.
    value : (K,) ndarray
        RI at those heights (1 at the first).
    field_deg : (K,) ndarray
        Object-side field angles of the samples, degrees.
    transmitted : (K,) ndarray
        Fraction of the stop-filling rays that reach the image.
    chief_ray_angle_deg : (K,) ndarray
        Angle of the real chief ray to the axis in image space, degrees
        (NaN where the chief ray is vignetted).
    center_mm : (x, y)
        Image of the on-axis field (the optical axis on the sensor; not 0
        for a decentred lens), mm, in the lens's image-plane frame (that of
        :mod:`calibration.optics.psf.map`: +y down the sensor array).
    method : str
    wavelength_nm : float
    """

    height_mm: np.ndarray
    value: np.ndarray
    field_deg: np.ndarray
    transmitted: np.ndarray
    chief_ray_angle_deg: np.ndarray
    center_mm: tuple[float, float] = (0.0, 0.0)
    method: str = "flux"
    wavelength_nm: float = 587.5618
    _fit: object = field(default=None, repr=False)

    def __post_init__(self):
        from scipy.interpolate import PchipInterpolator

        h = np.asarray(self.height_mm, dtype=np.float64)
        v = np.asarray(self.value, dtype=np.float64)
        if h.ndim != 1 or h.shape != v.shape or h.size < 2:
            raise LensError(f"need ≥ 2 samples of matching (K,) heights and values, got {h.shape} and {v.shape}")
        if not (np.all(np.isfinite(h)) and np.all(np.isfinite(v))):
            raise LensError("relative illumination samples must be finite")
        if np.any(np.diff(h) <= 0):
            raise LensError("sample heights must increase strictly")
        for name in ("height_mm", "value", "field_deg", "transmitted", "chief_ray_angle_deg"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=np.float64))
        object.__setattr__(self, "_fit", PchipInterpolator(h * h, v, extrapolate=False))

    @classmethod
    def from_samples(cls, height_mm, value, **kw) -> RelativeIllumination:
        """An RI from given samples (e.g. a measured flat field, or a model);
        the other arrays default to NaN."""
        h = np.asarray(height_mm, dtype=np.float64)
        nan = np.full(h.shape, np.nan)
        kw.setdefault("field_deg", nan)
        kw.setdefault("transmitted", nan)
        kw.setdefault("chief_ray_angle_deg", nan)
        return cls(h, np.asarray(value, dtype=np.float64), **kw)

    @property
    def max_height_mm(self) -> float:
        return float(self.height_mm[-1])

    def __call__(self, r_mm) -> np.ndarray:
        """RI at image heights ``r_mm`` (mm from ``center_mm``); the last
        sample's value beyond it."""
        r = np.abs(np.asarray(r_mm, dtype=np.float64))
        u = np.minimum(r * r, self.height_mm[-1] ** 2)
        out = self._fit(u)
        return np.maximum(out, 0.0)

    def at(self, x_mm, y_mm) -> np.ndarray:
        """RI at image-plane points (mm)."""
        cx, cy = self.center_mm
        return self(np.hypot(np.asarray(x_mm, dtype=np.float64) - cx, np.asarray(y_mm, dtype=np.float64) - cy))

    def on_sensor(self, sensor, *, box: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """Per-pixel RI at the pixel centres of a sensor.

        Parameters
        ----------
        sensor : object with ``pixel_pitch_um``, ``width_px``, ``height_px``
            (:class:`calibration.optics.lens.Sensor` or
            :class:`calibration.simulate.sensor.SensorModel`); the optical axis at its
            centre.
        box : (x, y, width, height), optional
            Only these pixels (default the whole sensor).

        Returns
        -------
        (H, W) ndarray of float64.
        """
        x0, y0, w, h = (0, 0, sensor.width_px, sensor.height_px) if box is None else box
        p = sensor.pixel_pitch_um * 1e-3
        # image plane of calibration.optics.psf.map: x_mm = (x − (W−1)/2)·p, y likewise, +y down the array
        xs = (np.arange(x0, x0 + w) - 0.5 * (sensor.width_px - 1)) * p - self.center_mm[0]
        ys = (np.arange(y0, y0 + h) - 0.5 * (sensor.height_px - 1)) * p - self.center_mm[1]
        r2 = xs[None, :] ** 2 + ys[:, None] ** 2
        u = np.minimum(r2, self.height_mm[-1] ** 2)
        return np.maximum(self._fit(u.ravel()).reshape(u.shape), 0.0)

    def fit_residual(self) -> float:
        """Largest |fit − sample| (0 up to rounding: PCHIP interpolates)."""
        return float(np.max(np.abs(self(self.height_mm) - self.value)))

    def summary(self) -> dict:
        return {"method": self.method, "wavelength_nm": self.wavelength_nm,
                "height_mm": self.height_mm.tolist(), "value": self.value.tolist(),
                "field_deg": self.field_deg.tolist(), "transmitted": self.transmitted.tolist(),
                "chief_ray_angle_deg": self.chief_ray_angle_deg.tolist(),
                "center_mm": list(self.center_mm)}


# -- the bundle integrals -----------------------------------------------------

def _pupil_grid(n: int) -> tuple[np.ndarray, float]:
    """Cell centres of an n × n grid over [−1, 1]² inside the unit disc, and
    the cell area."""
    g = (np.arange(n) + 0.5) / n * 2.0 - 1.0
    px, py = np.meshgrid(g, g)
    keep = px * px + py * py <= 1.0
    return np.column_stack([px[keep], py[keep]]), (2.0 / n) ** 2


@dataclass
class _Bundle:
    valid: np.ndarray          # (m,) all three rays of a cell valid
    fraction: float            # valid fraction of the cell-centre rays
    image_xy: np.ndarray       # (m, 2) landing points on the image plane, mm
    weight: np.ndarray         # (m,) flux weight of each cell (object-side measure)
    object_measure: float      # A⊥ (mm²) or Ω_obj (sr, projected) of the transmitted rays
    image_solid_angle: float   # ∬ dL' dM' of the transmitted rays (projected sr)
    chief_angle_deg: float     # image-space chief-ray angle (NaN if vignetted)

    def centroid(self) -> np.ndarray | None:
        w = self.weight[self.valid]
        if w.size == 0 or not w.sum() > 0:
            return None
        return (self.image_xy[self.valid] * w[:, None]).sum(0) / w.sum()


def _det(u: np.ndarray, a: slice, b: slice, c: slice) -> np.ndarray:
    """Jacobian determinant of (u0, u1) by forward differences: rows a (the
    points), b (+ε in px), c (+ε in py)."""
    return ((u[b, 0] - u[a, 0]) * (u[c, 1] - u[a, 1]) - (u[b, 1] - u[a, 1]) * (u[c, 0] - u[a, 0])) / _EPS ** 2


def _bundle(pl: PerturbedLens, field_deg, pc: np.ndarray, cell: float, wavelength_nm: float,
            aiming: str) -> _Bundle:
    m = len(pc)
    pupil = np.concatenate([pc, pc + (_EPS, 0.0), pc + (0.0, _EPS), np.zeros((1, 2))])
    rays = tr.pupil_rays(pl, field_deg, wavelength_nm=wavelength_nm, pupil=pupil, aiming=aiming)
    res = tr.trace_to_image(pl, rays)
    a, b, c = slice(0, m), slice(m, 2 * m), slice(2 * m, 3 * m)
    ok = res.valid[a] & res.valid[b] & res.valid[c]
    d_img = res.direction
    n_img = float(pl.lens.surfaces[-1].material.index(wavelength_nm))
    j_img = np.abs(_det(d_img[:, :2] * n_img, a, b, c))
    if math.isfinite(pl.lens.object_distance):
        # projected solid angle at the object point: direction cosines of the input rays
        j_obj = np.abs(_det(rays.direction[:, :2], a, b, c))
        measure = float(j_obj[ok].sum() * cell)
    else:
        z = tr.stop_and_pupil(pl).z
        t = (z - rays.origin[:, 2]) / rays.direction[:, 2]
        ep = rays.origin[:, :2] + t[:, None] * rays.direction[:, :2]
        j_obj = np.abs(_det(ep, a, b, c)) * abs(rays.direction[0, 2])
        measure = float(j_obj[ok].sum() * cell)
    xy = res.position[a, :2]
    chief = float(np.degrees(np.arccos(min(1.0, abs(d_img[-1, 2]))))) if res.valid[-1] else math.nan
    return _Bundle(ok, float(np.count_nonzero(res.valid[a])) / m, xy, j_obj[a], measure,
                   float(j_img[ok].sum() * cell), chief)


def _field_of_tan(a: float, b: float) -> tuple[float, float]:
    return (math.degrees(math.atan(a)), math.degrees(math.atan(b)))


def _flux_irradiance(pl, a, b, pc, cell, lam, aiming, centre: _Bundle) -> float:
    """E/L at the centroid of field (a, b) = tan of the field angles."""
    if not centre.object_measure > 0:
        return 0.0
    pts = {}
    for da, db in ((_DTAN, 0.0), (-_DTAN, 0.0), (0.0, _DTAN), (0.0, -_DTAN)):
        bb = _bundle(pl, _field_of_tan(a + da, b + db), pc, cell, lam, aiming)
        pts[(da, db)] = bb.centroid()
    if any(p is None for p in pts.values()):   # the neighbourhood is (partly) vignetted away
        return 0.0
    dxa = (pts[(_DTAN, 0.0)] - pts[(-_DTAN, 0.0)]) / (2 * _DTAN)
    dxb = (pts[(0.0, _DTAN)] - pts[(0.0, -_DTAN)]) / (2 * _DTAN)
    jac = abs(dxa[0] * dxb[1] - dxa[1] * dxb[0])
    if not jac > 0:
        return 0.0
    if math.isfinite(pl.lens.object_distance):
        # object point = EP centre − D·(a, b, 1): dA_obj = D² da db
        dist = tr.stop_and_pupil(pl).z + float(pl.lens.object_distance)
        return centre.object_measure * dist * dist / jac
    return centre.object_measure / ((1.0 + a * a + b * b) ** 1.5 * jac)


def relative_illumination(lens: Lens | PerturbedLens, *, sensor: Sensor | None = None,
                          samples: int = 17, max_height_mm: float | None = None,
                          method: str = "flux", wavelength_nm: float | None = None,
                          pupil_samples: int = 64, aiming: str = "real",
                          refine: float = 0.1, fields_deg=None) -> RelativeIllumination:
    """Relative illumination of a (perturbed) lens from the real ray trace.

    Parameters
    ----------
    lens : Lens or PerturbedLens
    sensor : Sensor, optional
        Whose half-diagonal the samples must cover (default the lens's).
    samples : int
        Number of field samples, ≥ 3, evenly spaced in paraxial image height
        from the axis to ``max_height_mm`` (more are added, see ``refine``).
    max_height_mm : float, optional
        Image height to cover, mm; default 1.02 × the sensor's
        half-diagonal. If distortion keeps the last sample short of it,
        samples are added further out.
    method : {"flux", "image_space"}
        See the module notes.
    wavelength_nm : float, optional
        Default the lens's primary wavelength.
    pupil_samples : int
        Pupil grid cells across the diameter (≈ 0.8·n² rays per bundle;
        64 resolves the transmitted area to ≈ 0.1 %).
    aiming : {"real", "paraxial"}
        Rays fill the real stop (default) or the paraxial entrance pupil.
    fields_deg : sequence of float, optional
        Sample exactly these object-side field angles (degrees, along +y;
        the axis is always added) instead of ``samples`` heights; no
        extension or refinement.
    refine : float
        Neighbouring samples whose RI differs by more than this get a
        sample between them (bisection in field angle, at most
        ``samples`` extra samples in all): the onset of hard vignetting
        is steep.

    Returns
    -------
    RelativeIllumination
        Samples at the real image heights of the beams' flux centroids and
        their smooth fit.

    Examples
    --------
    >>> from calibration.optics.lens import Lens, Surface
    >>> from calibration.optics.materials import model_material
    >>> lens = Lens((Surface(curvature=0.05, thickness=0.3, material=model_material(1.5), stop=True),
    ...              Surface(curvature=-0.05, thickness=19.8)), f_number=10.0, half_fov_deg=20.0)
    >>> ri = relative_illumination(lens, samples=3, max_height_mm=7.28, pupil_samples=32)
    >>> th = ri.field_deg[-1]                                # ≈ 20°
    >>> bool(abs(ri.value[-1] - ri_cos4(th)) < 0.003)        # the cos⁴ law
    True
    """
    if method not in METHODS:
        raise LensError(f"unknown method {method!r}; valid: {', '.join(METHODS)}")
    if samples < 3:
        raise LensError(f"samples must be ≥ 3, got {samples!r}")
    if pupil_samples < 8:
        raise LensError(f"pupil_samples must be ≥ 8, got {pupil_samples!r}")
    pl = nominal(lens)
    nom = pl.nominal
    lam = nom.primary_nm if wavelength_nm is None else float(wavelength_nm)
    sens = nom.sensor if sensor is None else sensor
    if max_height_mm is None:
        w, h = sens.width_px * sens.pixel_pitch_um * 1e-3, sens.height_px * sens.pixel_pitch_um * 1e-3
        max_height_mm = 1.02 * 0.5 * math.hypot(w, h)
    if not max_height_mm > 0:
        raise LensError(f"max_height_mm must be > 0, got {max_height_mm!r}")
    pc, cell = _pupil_grid(int(pupil_samples))

    def evaluate(theta_deg: float):
        b = math.tan(math.radians(theta_deg))
        bun = _bundle(pl, (0.0, theta_deg), pc, cell, lam, aiming)
        cen = bun.centroid()
        if method == "image_space":
            e = bun.image_solid_angle
        else:
            e = _flux_irradiance(pl, 0.0, b, pc, cell, lam, aiming, bun)
        return e, cen, bun

    e0, c0, b0 = evaluate(0.0)
    if c0 is None or not e0 > 0:
        raise LensError("no ray of the on-axis beam reaches the image: cannot normalise the illumination")

    def sample(th: float) -> tuple:
        e, cen, bun = evaluate(th)
        if cen is None:
            # nothing transmitted: the sample sits where the unvignetted chief ray lands
            rays = tr.pupil_rays(pl, (0.0, th), wavelength_nm=lam, pupil=np.zeros((1, 2)), aiming=aiming)
            res = tr.trace_to_image(pl, rays, clip=False)
            cen = res.position[0, :2] if res.valid[0] else None
            e = 0.0
        r = float(np.hypot(*(cen - c0))) if cen is not None else abs(paraxial.image_height(pl.lens, th, lam))
        return (th, r, e / e0, bun.fraction, bun.chief_angle_deg)

    rows = [(0.0, 0.0, 1.0, b0.fraction, b0.chief_angle_deg)]
    if fields_deg is not None:
        rows += [sample(float(th)) for th in fields_deg if float(th) > 0.0]
        budget = 0
    else:
        heights = np.linspace(0.0, max_height_mm, int(samples))
        rows += [sample(paraxial.field_angle(pl.lens, float(hh), lam)) for hh in heights[1:]]
        budget = int(samples)
    # distortion may leave the last sample short of the height asked for
    while budget > 0 and rows[-1][1] < max_height_mm and rows[-1][0] < 80.0:
        th, r = rows[-1][0], rows[-1][1]
        t = math.tan(math.radians(th)) * max(max_height_mm / max(r, 1e-9), 1.01)
        rows.append(sample(min(80.0, math.degrees(math.atan(t)))))
        budget -= 1
    # refine where the illumination changes fast (onset of hard vignetting)
    while budget > 0:
        rows.sort(key=lambda t: t[0])
        steps = [abs(rows[i + 1][2] - rows[i][2]) for i in range(len(rows) - 1)]
        i = int(np.argmax(steps))
        if steps[i] <= refine or rows[i + 1][0] - rows[i][0] < 0.02:
            break
        rows.append(sample(0.5 * (rows[i][0] + rows[i + 1][0])))
        budget -= 1
    rows.sort(key=lambda t: t[1])
    arr = np.array(rows, dtype=np.float64)
    keep = np.concatenate([[True], np.diff(arr[:, 1]) > 1e-9])
    arr = arr[keep]
    if fields_deg is None and arr[-1, 1] < max_height_mm * 0.999:
        warnings.warn(f"relative illumination sampled to {arr[-1, 1]:.3f} mm only (asked "
                      f"{max_height_mm:.3f} mm); beyond it the last value holds", stacklevel=2)
    return RelativeIllumination(arr[:, 1], arr[:, 2], arr[:, 0], arr[:, 3], arr[:, 4],
                                center_mm=(float(c0[0]), float(c0[1])), method=method, wavelength_nm=lam)

"""First-order (paraxial) optics of a :class:`~calibration.optics.lens.Lens`.

A paraxial y–nu trace (ray height ``y`` and reduced angle ``ν = n·u``) of the
marginal and chief rays gives the cardinal data: effective and back focal
lengths, entrance and exit pupils, F-numbers, the paraxial image plane and
image height. The treatment is the standard one of R. Kingslake and R. B.
Johnson, *Lens Design Fundamentals*, 2nd ed., Academic Press 2010, ch. 3
("Paraxial optics"), and W. J. Smith, *Modern Optical Engineering*, 4th ed.,
McGraw-Hill 2008, §2.5 and §4.

Notes
-----
At surface ``j`` with paraxial curvature ``c_j``, media ``n_j`` before and
``n'_j`` after, and thickness ``t_j`` to the next surface:

.. math::

    \\nu'_j = \\nu_j - y_j\\,\\varphi_j,\\quad
    \\varphi_j = (n'_j - n_j)\\,c_j,\\qquad
    y_{j+1} = y_j + \\frac{t_j}{n'_j}\\,\\nu'_j .

Both steps are 2×2 matrices of determinant 1 acting on (y, ν); a run of
surfaces is their product ``[[A, B], [C, D]]``. With the state taken in
object space at the first vertex plane:

* equivalent focal length ``EFL = −1/C`` of the whole lens (image space in
  air: the image-side focal length), back focal length ``−n'·A/C``;
* entrance pupil: the image of the stop through the surfaces before it; with
  ``M`` the matrix from the first vertex plane to the stop plane, a ray with
  ``y_stop = 0`` crosses the axis in object space at ``z_EP = n₀·B/A`` and the
  pupil magnification is ``1/A``, so ``EPD = 2·sd_stop/|A|``;
* exit pupil: the image of the stop through the surfaces from the stop on;
  with ``N`` the matrix from the stop plane to image space,
  ``z_XP = −n'·N₀₁/N₁₁`` from the last vertex and ``XPD = 2·a/|N₁₁|`` for a
  stop of semi-aperture ``a`` (``det N = 1``).

Only the quadratic term of a surface's sag enters paraxial optics: an ``A2·ρ²``
polynomial term (Zemax EVENASPH PARM 1, DeepLens ``ai2``) adds ``2·A2`` to the
vertex curvature. The conic constant and higher orders do not. A first-order
``A1·ρ`` term (odd aspheres) is a cone: it has no paraxial power and is left
out here (the real-ray tracer sees it).

Conventions: lengths in mm, z from the first vertex (light travels +z),
angles in degrees at the public boundary; the object space is air.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calibration.optics.lens import Lens, LensError, Surface


def paraxial_curvature(surface: Surface) -> float:
    """Curvature (1/mm) a paraxial ray sees: ``c + 2·A2``.

    >>> paraxial_curvature(Surface(curvature=0.1, asphere=((2, 0.25), (4, 1e-3))))
    0.6
    """
    return surface.curvature + 2.0 * surface.coefficient(2)


def _indices(lens: Lens, wavelength_nm: float) -> tuple[np.ndarray, np.ndarray]:
    """Refractive index before and after each surface at ``wavelength_nm``."""
    after = np.array([s.material.index(wavelength_nm) for s in lens.surfaces], dtype=np.float64)
    before = np.concatenate([[1.0], after[:-1]])
    return before, after


def _refraction(phi: float) -> np.ndarray:
    return np.array([[1.0, 0.0], [-phi, 1.0]])


def _transfer(t: float, n: float) -> np.ndarray:
    return np.array([[1.0, t / n], [0.0, 1.0]])


def system_matrix(lens: Lens, first: int, last: int, wavelength_nm: float | None = None,
                  *, refract_first: bool = True, transfer_last: bool = False) -> np.ndarray:
    """2×2 paraxial matrix on (y, ν) from surface ``first`` to ``last``
    (0-based, inclusive).

    The state starts at the vertex plane of ``first`` before (or, with
    ``refract_first=False``, after) its refraction, and ends after the
    refraction at ``last`` (``transfer_last=True``: at the vertex plane of
    the next surface, or the image plane after the last surface).
    """
    wl = lens.primary_nm if wavelength_nm is None else wavelength_nm
    n_before, n_after = _indices(lens, wl)
    m = np.eye(2)
    for j in range(first, last + 1):
        s = lens.surfaces[j]
        if j > first or refract_first:
            m = _refraction((n_after[j] - n_before[j]) * paraxial_curvature(s)) @ m
        if j < last or transfer_last:
            m = _transfer(s.thickness, n_after[j]) @ m
    return m


def _to_stop(lens: Lens, wl: float) -> np.ndarray:
    """Matrix from the first vertex plane (object space) to the stop plane,
    before the stop surface refracts."""
    s = lens.stop_index
    if s == 0:
        return np.eye(2)
    return system_matrix(lens, 0, s - 1, wl, transfer_last=True)


def efl(lens: Lens, wavelength_nm: float | None = None) -> float:
    """Effective (equivalent) focal length, mm; inf for an afocal lens.

    >>> from calibration.optics.lens import Lens, Surface
    >>> from calibration.optics.materials import model_material
    >>> glass = model_material(1.5)
    >>> lens = Lens((Surface(curvature=0.01, thickness=0.0, material=glass),
    ...              Surface(curvature=-0.01, thickness=100.0)), epd=10.0)
    >>> round(efl(lens), 9)       # thin lens: 1/((n − 1)(c1 − c2)) = 100
    100.0
    """
    c = system_matrix(lens, 0, len(lens.surfaces) - 1, wavelength_nm)[1, 0]
    return math.inf if c == 0 else -1.0 / float(c)


@dataclass(frozen=True)
class FirstOrder:
    """First-order data of a lens at one wavelength (lengths in mm, z from
    the first vertex).

    Attributes
    ----------
    wavelength_nm : float
    efl : float
        Equivalent focal length (image-side focal length in air).
    bfl : float
        Last vertex to the paraxial image of the lens's object (for a
        distant object: to the back focal point).
    paraxial_image_z : float
        z of the paraxial image plane; the lens's actual image plane is at
        ``Lens.total_track`` (their difference is the defocus).
    epd, entrance_pupil_z : float
        Entrance pupil diameter and position.
    exit_pupil_diameter, exit_pupil_z : float
        Exit pupil diameter and position (inf if telecentric).
    exit_pupil_to_image : float
        Exit pupil position from the lens's image plane (negative: in front
        of it), as optical design programs report it.
    f_number : float
        Image-space F/# = EFL/EPD (infinite-conjugate definition).
    working_f_number : float
        1/(2 n' |u'|) of the paraxial marginal ray at the lens's conjugates.
    magnification : float
        Paraxial lateral magnification (0 for a distant object).
    image_height : float
        Paraxial chief-ray height on the lens's image plane at the lens's
        half field of view (:func:`image_height`).
    focus_image_height : float
        The same at the paraxial image plane (EFL·tan θ for a distant
        object).
    total_track : float
        First vertex to the image plane.
    ttl : float
        First optical (non-dummy) surface to the image plane: the "TTL" of
        lens patents, which leaves out a stop placed in front of the first
        lens.
    """

    wavelength_nm: float
    efl: float
    bfl: float
    paraxial_image_z: float
    epd: float
    entrance_pupil_z: float
    exit_pupil_diameter: float
    exit_pupil_z: float
    exit_pupil_to_image: float
    f_number: float
    working_f_number: float
    magnification: float
    image_height: float
    focus_image_height: float
    total_track: float
    ttl: float


def entrance_pupil(lens: Lens, wavelength_nm: float | None = None) -> tuple[float, float]:
    """(z, diameter) of the entrance pupil in mm.

    The diameter comes from ``lens.epd``, else ``EFL / lens.f_number``, else
    the stop's semi-diameter imaged into object space.

    Raises
    ------
    LensError
        The stop is imaged to infinity (object-space telecentric), or the
        aperture is set by an F-number on an afocal lens.
    """
    wl = lens.primary_nm if wavelength_nm is None else wavelength_nm
    m = _to_stop(lens, wl)
    if m[0, 0] == 0:
        raise LensError(f"surface {lens.stop_index + 1} (stop): its image in object space is at "
                        "infinity (telecentric in object space); give the aperture as an EPD")
    z = float(m[0, 1] / m[0, 0])
    if lens.epd is not None:
        return z, float(lens.epd)
    if lens.f_number is not None:
        f = efl(lens, wl)
        if not math.isfinite(f):
            raise LensError("F-number given for an afocal lens (EFL is infinite); give the EPD")
        return z, abs(f) / lens.f_number
    sd = lens.surfaces[lens.stop_index].semi_diameter
    return z, 2.0 * sd / abs(float(m[0, 0]))


def _object_ray(z_ep: float, height_at_ep: float, slope: float) -> tuple[float, float]:
    """(y, ν) at the first vertex plane of an object-space ray."""
    return height_at_ep - slope * z_ep, slope


def _marginal_ray(lens: Lens, z_ep: float, epd: float) -> tuple[float, float]:
    if math.isinf(lens.object_distance):
        return 0.5 * epd, 0.0
    slope = 0.5 * epd / (z_ep + lens.object_distance)
    return _object_ray(z_ep, 0.5 * epd, slope)


def first_order(lens: Lens, wavelength_nm: float | None = None) -> FirstOrder:
    """Paraxial marginal- and chief-ray analysis of ``lens``.

    Parameters
    ----------
    lens : Lens
    wavelength_nm : float, optional
        Default ``lens.primary_nm``.

    Returns
    -------
    FirstOrder
        Lengths in mm, see its attributes.
    """
    wl = lens.primary_nm if wavelength_nm is None else float(wavelength_nm)
    k = len(lens.surfaces) - 1
    n_img = lens.surfaces[-1].material.index(wl)
    whole = system_matrix(lens, 0, k, wl)
    f = math.inf if whole[1, 0] == 0 else -1.0 / float(whole[1, 0])
    z_ep, epd = entrance_pupil(lens, wl)
    z_last = float(lens.vertex_z()[k])

    y_m, nu_m = (float(v) for v in whole @ np.array(_marginal_ray(lens, z_ep, epd)))
    l_img = math.inf if nu_m == 0 else -y_m * n_img / nu_m
    image_z = z_last + l_img
    working = math.inf if nu_m == 0 else 1.0 / (2.0 * abs(nu_m))
    y0, nu0 = _marginal_ray(lens, z_ep, epd)
    magnification = 0.0 if math.isinf(lens.object_distance) or nu_m == 0 else nu0 / nu_m

    s = lens.stop_index
    after = system_matrix(lens, s, k, wl)
    stop_sd = 0.5 * epd * abs(float(_to_stop(lens, wl)[0, 0]))
    if after[1, 1] == 0:
        z_xp, xpd = math.inf, math.inf
    else:
        z_xp = z_last - n_img * float(after[0, 1] / after[1, 1])
        xpd = 2.0 * stop_sd / abs(float(after[1, 1]))

    height = image_height(lens, lens.half_fov_deg, wl) if lens.half_fov_deg else 0.0
    focus_height = image_height(lens, lens.half_fov_deg, wl, at="focus") if lens.half_fov_deg else 0.0
    first = first_optical_surface(lens)
    return FirstOrder(
        wavelength_nm=wl, efl=f, bfl=l_img, paraxial_image_z=image_z, epd=epd,
        entrance_pupil_z=z_ep, exit_pupil_diameter=xpd, exit_pupil_z=z_xp,
        exit_pupil_to_image=z_xp - lens.total_track, f_number=abs(f) / epd, working_f_number=working,
        magnification=magnification, image_height=height, focus_image_height=focus_height,
        total_track=lens.total_track, ttl=lens.total_track - float(lens.vertex_z()[first]))


def first_optical_surface(lens: Lens) -> int:
    """0-based index of the first surface that is not a dummy (a dummy is
    flat, without polynomial terms, with the same medium on both sides —
    e.g. a stop in front of the first lens)."""
    media = lens.media()
    for i, s in enumerate(lens.surfaces):
        if s.curvature or any(a for _, a in s.asphere) or s.material != media[i]:
            return i
    return 0


def image_height(lens: Lens, field_deg: float, wavelength_nm: float | None = None,
                 *, at: str = "image") -> float:
    """Paraxial image height (mm) of a field angle.

    The paraxial chief ray leaves object space at slope tan(``field_deg``)
    through the entrance pupil centre and is traced to the lens's image
    plane (``at="image"``, where the sensor is) or to the paraxial image
    plane (``at="focus"``; for a distant object that is EFL·tan θ). The two
    differ by the defocus of the image plane times the chief-ray slope: for
    the 3.5 mm image-height field of the rayoptics cell-phone lens the image
    plane gives the 31.76° of lenses/README.md, the focus the 32.21° of
    rayoptics' own specsheet. Positive for a positive lens and a positive
    angle.

    >>> from calibration.optics.lens import Lens, Surface
    >>> from calibration.optics.materials import model_material
    >>> lens = Lens((Surface(curvature=0.01, material=model_material(1.5)),
    ...              Surface(curvature=-0.01, thickness=100.0)), epd=10.0)
    >>> round(image_height(lens, 45.0), 9)    # f·tan θ, image plane at the focus
    100.0
    """
    if at not in ("image", "focus"):
        raise ValueError(f"at must be 'image' or 'focus', got {at!r}")
    wl = lens.primary_nm if wavelength_nm is None else wavelength_nm
    k = len(lens.surfaces) - 1
    whole = system_matrix(lens, 0, k, wl)
    z_ep, epd = entrance_pupil(lens, wl)
    y_c, nu_c = whole @ np.array(_object_ray(z_ep, 0.0, math.tan(math.radians(field_deg))))
    n_img = lens.surfaces[-1].material.index(wl)
    if at == "image":
        distance = lens.surfaces[-1].thickness
    else:
        y_m, nu_m = whole @ np.array(_marginal_ray(lens, z_ep, epd))
        distance = -y_m * n_img / nu_m
    return float(y_c + nu_c / n_img * distance)


def field_angle(lens: Lens, height: float, wavelength_nm: float | None = None,
                *, at: str = "image") -> float:
    """The field angle (degrees) whose paraxial image height is ``height``
    (mm) on the image plane (or, ``at="focus"``, the paraxial image plane):
    the inverse of :func:`image_height` (heights are linear in tan θ).

    >>> from calibration.optics.lens import Lens, Surface
    >>> from calibration.optics.materials import model_material
    >>> lens = Lens((Surface(curvature=0.01, material=model_material(1.5)),
    ...              Surface(curvature=-0.01, thickness=100.0)), epd=10.0)
    >>> round(field_angle(lens, 100.0), 9)
    45.0
    """
    per_tan = image_height(lens, 45.0, wavelength_nm, at=at)
    if per_tan == 0:
        raise LensError("the paraxial image height does not depend on the field angle (afocal lens)")
    return math.degrees(math.atan(height / per_tan))

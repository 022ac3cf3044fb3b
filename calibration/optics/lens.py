"""The lens model: surfaces, materials, aperture, field, sensor.

Conventions (DESIGN.md): lengths in mm, pixel pitch in µm, wavelengths in
nm; z along the optical axis, light travels +z; float64 throughout.

A :class:`Lens` is a list of rotationally symmetric refracting surfaces in
sequence. Surface ``i`` sits at axial position ``z_i`` (the first at 0) and
is followed by ``thickness`` mm of ``material`` up to the next surface; the
last surface's thickness is the distance to the image plane. The object is
at infinity unless ``object_distance`` says otherwise. Surfaces are numbered
from 1 in names and messages (``s3`` is ``lens.surfaces[2]``), as in optical
design programs; *elements* (numbered from 1, ``e2``) are runs of surfaces
with a solid between them.

Surface shape (paper, eq. 2; Zemax EVENASPH/XASPHERE/ODDASPH):

.. math::

    z(\\rho) = \\frac{c\\rho^2}{1 + \\sqrt{1 - (1 + k)c^2\\rho^2}}
               + \\sum_i A_i \\rho^i

with curvature ``c`` (1/mm), conic ``k`` and polynomial terms ``A_i`` of any
order ``i ≥ 1`` (even orders are the usual aspheres; odd orders come from
"odd" and extended aspheres). Materials are in :mod:`calibration.optics.materials`.

The model is immutable: perturbations (``calibration.optics.perturb``) return new
lenses, so the nominal lens is never changed by a fit.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from isp.errors import IspError

from calibration.optics.materials import AIR, Material


class LensError(IspError, ValueError):
    """An invalid lens (file or model); the message names the surface (and
    the file, where there is one), so ``str(err)`` is a one-line report."""


@dataclass(frozen=True)
class Surface:
    """One refracting (or dummy/stop) surface.

    Attributes
    ----------
    curvature : float
        Vertex curvature c = 1/R in 1/mm (0 = flat).
    conic : float
        Conic constant k (0 sphere, -1 paraboloid).
    asphere : tuple of (int, float)
        Polynomial terms (order i, A_i) with sag ``A_i ρ^i`` in mm; any
        order ≥ 1, sorted by order.
    thickness : float
        Axial distance to the next surface (or to the image plane), mm.
    material : Material
        The medium after this surface.
    semi_diameter : float or None
        Clear semi-aperture in mm; rays outside are vignetted. None: no
        limit.
    stop : bool
        This surface is the aperture stop.
    name : str
        Free text (e.g. "L1 front", "IR filter").
    """

    curvature: float = 0.0
    conic: float = 0.0
    asphere: tuple[tuple[int, float], ...] = ()
    thickness: float = 0.0
    material: Material = AIR
    semi_diameter: float | None = None
    stop: bool = False
    name: str = ""

    @property
    def radius(self) -> float:
        """Radius of curvature in mm (inf for a flat surface)."""
        return math.inf if self.curvature == 0 else 1.0 / self.curvature

    def coefficient(self, order: int) -> float:
        """A_order (0 if the term is absent)."""
        for i, a in self.asphere:
            if i == order:
                return a
        return 0.0

    def sag(self, rho: np.ndarray) -> np.ndarray:
        """Sag z(ρ) in mm at radial distances ``rho`` (mm).

        Where the conic's square root is negative (beyond the surface's
        domain) the result is NaN; callers mask it.

        >>> s = Surface(curvature=0.1)
        >>> float(s.sag(np.array(1.0)))   # sphere R = 10 mm
        0.0501256289...
        """
        rho = np.asarray(rho, dtype=np.float64)
        r2 = rho * rho
        c, k = self.curvature, self.conic
        with np.errstate(invalid="ignore"):
            root = np.sqrt(1.0 - (1.0 + k) * c * c * r2)
        z = c * r2 / (1.0 + root)
        for i, a in self.asphere:
            z = z + a * rho ** i
        return z

    def sag_derivative(self, rho: np.ndarray) -> np.ndarray:
        """dz/dρ (dimensionless) at ``rho`` (mm).

        Notes
        -----
        d/dρ [cρ²/(1+√(1−(1+k)c²ρ²))] = cρ/√(1−(1+k)c²ρ²).
        """
        rho = np.asarray(rho, dtype=np.float64)
        c, k = self.curvature, self.conic
        with np.errstate(invalid="ignore", divide="ignore"):
            d = c * rho / np.sqrt(1.0 - (1.0 + k) * c * c * rho * rho)
        for i, a in self.asphere:
            if i == 1:
                d = d + a
            else:
                d = d + i * a * rho ** (i - 1)
        return d

    def replace(self, **changes) -> "Surface":
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class Sensor:
    """The image sensor: pixel pitch (µm) and size in pixels."""

    pixel_pitch_um: float = 1.0
    width_px: int = 4000
    height_px: int = 3000

    @property
    def size_mm(self) -> tuple[float, float]:
        """(width, height) in mm."""
        return (self.width_px * self.pixel_pitch_um * 1e-3, self.height_px * self.pixel_pitch_um * 1e-3)

    @property
    def half_diagonal_mm(self) -> float:
        w, h = self.size_mm
        return 0.5 * math.hypot(w, h)

    def at_pitch(self, pixel_pitch_um: float) -> Sensor:
        """The same sensor area sampled at ``pixel_pitch_um`` µm (a binned or
        full-resolution mode of one sensor): pixel counts rounded.

        >>> Sensor(2.807, 2000, 1500).at_pitch(1.0)
        Sensor(pixel_pitch_um=1.0, width_px=5614, height_px=4210)
        """
        p = float(pixel_pitch_um)
        if not (math.isfinite(p) and p > 0):
            raise ValueError(f"pixel pitch must be positive, got {pixel_pitch_um!r}")
        return Sensor(pixel_pitch_um=p, width_px=max(1, round(self.width_px * self.pixel_pitch_um / p)),
                      height_px=max(1, round(self.height_px * self.pixel_pitch_um / p)))


@dataclass(frozen=True)
class Lens:
    """A sequential, nominally coaxial lens.

    Attributes
    ----------
    surfaces : tuple of Surface
        In order from object to image; the last thickness reaches the image.
    f_number : float or None
        Image-space F/# = EFL / EPD (infinite conjugates); sets the entrance
        pupil when ``epd`` is None.
    epd : float or None
        Entrance pupil diameter, mm (takes precedence over ``f_number``).
        With neither, the stop surface's semi-diameter sets the aperture
        ("float by stop size"), imaged into object space.
    half_fov_deg : float
        Maximum half field of view, degrees (object side).
    wavelengths_nm : tuple of float
        Design wavelengths; ``primary_nm`` is the one paraxial figures use.
    object_distance : float
        mm from the first surface to the object (inf for a distant object).
    sensor : Sensor
    name : str
    """

    surfaces: tuple[Surface, ...]
    f_number: float | None = None
    epd: float | None = None
    half_fov_deg: float = 0.0
    wavelengths_nm: tuple[float, ...] = (486.1327, 587.5618, 656.2725)  # F, d, C lines
    primary_nm: float = 587.5618
    object_distance: float = math.inf
    sensor: Sensor = field(default_factory=Sensor)
    name: str = ""
    metadata: dict[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self):
        validate(self)

    # -- structure -----------------------------------------------------------
    @property
    def stop_index(self) -> int:
        """0-based index of the stop surface (the first one marked; else the
        first surface)."""
        for i, s in enumerate(self.surfaces):
            if s.stop:
                return i
        return 0

    def vertex_z(self) -> np.ndarray:
        """Axial vertex positions (mm) of the surfaces, the first at 0, and of
        the image plane as the last element (len = surfaces + 1)."""
        t = np.array([s.thickness for s in self.surfaces], dtype=np.float64)
        return np.concatenate([[0.0], np.cumsum(t)])

    @property
    def total_track(self) -> float:
        """First surface to image plane, mm."""
        return float(sum(s.thickness for s in self.surfaces))

    def elements(self) -> list[tuple[int, int]]:
        """(first, last) 0-based surface indices of each element: a run of
        surfaces with a non-air medium between them (a cemented doublet is
        one element of three surfaces; a filter plate is an element too)."""
        out = []
        i = 0
        n = len(self.surfaces)
        while i < n:
            if not self.surfaces[i].material.is_air and i + 1 < n:
                j = i
                while j + 1 < n and not self.surfaces[j].material.is_air:
                    j += 1
                out.append((i, j))
                i = j + 1
            else:
                i += 1
        return out

    def media(self) -> list[Material]:
        """Medium before each surface (len = surfaces; the first is object
        space, air)."""
        return [AIR] + [s.material for s in self.surfaces[:-1]]

    def replace(self, **changes) -> "Lens":
        return dataclasses.replace(self, **changes)

    def with_surface(self, index: int, **changes) -> "Lens":
        """A copy with surface ``index`` (0-based) changed."""
        s = list(self.surfaces)
        s[index] = s[index].replace(**changes)
        return self.replace(surfaces=tuple(s))


def validate(lens: Lens) -> None:
    """Raise :class:`LensError` naming the first surface that makes no sense."""
    if not lens.surfaces:
        raise LensError("lens has no surfaces")
    for i, s in enumerate(lens.surfaces, start=1):
        for name in ("curvature", "conic", "thickness"):
            v = getattr(s, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                raise LensError(f"surface {i}: {name} must be a finite number, got {v!r}")
        if s.semi_diameter is not None and not (math.isfinite(s.semi_diameter) and s.semi_diameter > 0):
            raise LensError(f"surface {i}: semi-diameter must be positive, got {s.semi_diameter!r}")
        for order, a in s.asphere:
            if not (isinstance(order, int) and order >= 1):
                raise LensError(f"surface {i}: aspheric order must be an integer ≥ 1, got {order!r}")
            if not math.isfinite(a):
                raise LensError(f"surface {i}: aspheric coefficient A{order} is {a!r}")
        if s.thickness < 0 and i < len(lens.surfaces):
            pass  # negative air gaps exist in real prescriptions (overlapping sags are checked by the tracer)
    if lens.epd is None and lens.f_number is None and lens.surfaces[lens.stop_index].semi_diameter is None:
        raise LensError("lens needs an entrance pupil diameter (epd), an F-number, or a stop "
                        "surface with a semi-diameter")
    if lens.epd is not None and not (math.isfinite(lens.epd) and lens.epd > 0):
        raise LensError(f"epd must be positive, got {lens.epd!r}")
    if lens.f_number is not None and not (math.isfinite(lens.f_number) and lens.f_number > 0):
        raise LensError(f"F-number must be positive, got {lens.f_number!r}")
    if not 0 <= lens.half_fov_deg < 90:
        raise LensError(f"half field of view must be in [0, 90) degrees, got {lens.half_fov_deg!r}")
    if sum(1 for s in lens.surfaces if s.stop) > 1:
        raise LensError("more than one surface is marked as the stop")

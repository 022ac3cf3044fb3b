"""Spot diagrams: where the rays of one field point land on the image plane.

The RMS spot radius is

.. math::

    r_\\mathrm{rms} = \\sqrt{\\frac{1}{N}\\sum_i \\lVert \\mathbf{p}_i - \\mathbf{p}_0 \\rVert^2}

over the N valid rays' image-plane positions p_i (x, y), with the
reference p_0 the centroid of the spot (``reference="centroid"``) or the
chief ray's intersection (``reference="chief"``).

Pupil sampling: rays fill the entrance pupil uniformly in area
(``distribution="random"``, the Monte Carlo estimate optiland and
rayoptics use for their published RMS; "grid" and "hexapolar" are
deterministic alternatives, see :func:`calibration.optics.trace.pupil_grid`), aimed
paraxially or at the real stop (:func:`calibration.optics.trace.pupil_rays`).
Vignetted rays are left out of the statistics (their count is kept).
Polychromatic spots pool the wavelengths with equal ray counts.

Units: mm for positions and radii, degrees for fields, nm for wavelengths.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calibration.optics import paraxial
from calibration.optics.lens import Lens
from calibration.optics.perturb import Perturbation, PerturbedLens, apply, nominal
from calibration.optics.trace import TraceError, pupil_rays, trace_to_exit, trace_to_image


def centroid(points: np.ndarray) -> np.ndarray:
    """Mean (x, y) of (N, 2) points, mm; (0, 0) for no points."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return p.mean(axis=0) if len(p) else np.zeros(2)


def rms_radius(points: np.ndarray, reference: Sequence[float] | None = None) -> float:
    """RMS distance of (N, 2) points from ``reference`` (default: their
    centroid), mm; 0 for no points.

    >>> rms_radius(np.array([[1.0, 0.0], [-1.0, 0.0]]))
    1.0
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if not len(p):
        return 0.0
    ref = centroid(p) if reference is None else np.asarray(reference, dtype=np.float64)
    d = p - ref
    return float(np.sqrt(np.mean(np.einsum("ij,ij->i", d, d))))


@dataclass(frozen=True, eq=False)
class Spot:
    """The spot of one field point.

    Attributes
    ----------
    field_deg : (2,) tuple
    wavelengths_nm : tuple of float
    points : (M, 2) ndarray
        Image-plane (x, y) of the valid rays, mm.
    wavelength_of_point : (M,) ndarray
        Wavelength (nm) of each point.
    chief : (2,) ndarray or None
        Image-plane (x, y) of the chief ray (pupil centre, same aiming) at
        the lens's primary wavelength, mm; None if it is vignetted.
    n_rays : int
        Rays launched (all wavelengths).
    """

    field_deg: tuple[float, float]
    wavelengths_nm: tuple[float, ...]
    points: np.ndarray
    wavelength_of_point: np.ndarray
    chief: np.ndarray | None
    n_rays: int

    @property
    def centroid(self) -> np.ndarray:
        """(x, y) centroid of the spot, mm."""
        return centroid(self.points)

    @property
    def fraction_valid(self) -> float:
        """Share of the launched rays that reached the image (0..1)."""
        return len(self.points) / max(self.n_rays, 1)

    def rms_radius(self, reference: str = "centroid") -> float:
        """RMS spot radius, mm, about the centroid or the chief ray."""
        if reference == "centroid":
            return rms_radius(self.points)
        if reference == "chief":
            if self.chief is None:
                raise TraceError(f"field {self.field_deg}: the chief ray is vignetted; use reference='centroid'")
            return rms_radius(self.points, self.chief)
        raise TraceError(f"unknown reference {reference!r}; valid: 'centroid', 'chief'")


def spot(lens: Lens | PerturbedLens, field_deg: Sequence[float] = (0.0, 0.0), n: int = 10_000,
         wavelengths_nm: float | Sequence[float] | None = None, *, distribution: str = "random",
         aiming: str = "paraxial", rng: np.random.Generator | None = None, **trace_kw) -> Spot:
    """Trace one field point's spot.

    Parameters
    ----------
    lens : Lens or PerturbedLens
    field_deg : (θx, θy), degrees
    n : int
        Pupil samples per wavelength (see :func:`calibration.optics.trace.pupil_grid`).
    wavelengths_nm : float or sequence, optional
        Default: the lens's primary wavelength.
    distribution, aiming, rng
        As :func:`calibration.optics.trace.pupil_rays`.
    **trace_kw
        Passed to :func:`calibration.optics.trace.trace_to_image`.

    Returns
    -------
    Spot
    """
    base = lens.nominal if isinstance(lens, PerturbedLens) else lens
    if wavelengths_nm is None:
        wls = (float(base.primary_nm),)
    elif np.ndim(wavelengths_nm) == 0:
        wls = (float(wavelengths_nm),)
    else:
        wls = tuple(float(w) for w in wavelengths_nm)
    rng = np.random.default_rng(0) if rng is None else rng
    pts, wof, total = [], [], 0
    for w in wls:
        rays = pupil_rays(lens, field_deg, n, w, distribution=distribution, aiming=aiming, rng=rng)
        res = trace_to_image(lens, rays, **trace_kw)
        total += len(rays)
        p = res.position[res.valid, :2]
        pts.append(p)
        wof.append(np.full(len(p), w))
    c = trace_to_image(lens, pupil_rays(lens, field_deg, 1, base.primary_nm, aiming=aiming, pupil=np.zeros((1, 2))),
                       **trace_kw)
    chief = c.position[0, :2].copy() if c.valid[0] else None
    return Spot((float(field_deg[0]), float(field_deg[1])), wls, np.concatenate(pts), np.concatenate(wof),
                chief, total)


def spot_diagram(lens: Lens | PerturbedLens, fields_deg: Sequence[Sequence[float]], n: int = 10_000,
                 wavelengths_nm: float | Sequence[float] | None = None, **kw) -> list[Spot]:
    """:func:`spot` for each field; fields as (θx, θy) pairs in degrees."""
    return [spot(lens, f, n, wavelengths_nm, **kw) for f in fields_deg]


def best_focus(lens: Lens | PerturbedLens, field_deg: Sequence[float] = (0.0, 0.0), n: int = 4000,
               wavelength_nm: float | None = None, *, aiming: str = "paraxial",
               rng: np.random.Generator | None = None) -> float:
    """Image-plane shift (mm along +z; + = away from the lens) that
    minimises the centroid-referenced RMS spot radius of one field.

    Notes
    -----
    Beyond the last surface the rays are straight: at a plane shifted by
    δ their positions are ``a_i + b_i δ`` (``b_i`` = transverse slope), so
    the mean-square spot radius is quadratic in δ and its minimum is exact,
    ``δ* = −Σ cov(a, b) / Σ var(b)`` over x and y — no search.
    """
    pl = nominal(lens)
    rays = pupil_rays(pl, field_deg, n, wavelength_nm, aiming=aiming,
                      rng=np.random.default_rng(0) if rng is None else rng)
    ex = trace_to_exit(pl, rays)
    p, d = ex.position[ex.valid], ex.direction[ex.valid]
    if len(p) < 3:
        raise TraceError(f"field {tuple(field_deg)}: fewer than 3 rays reach the image; no focus to find")
    z = pl.image_pose.vertex[2]
    b = d[:, :2] / d[:, 2:3]
    a = p[:, :2] + (z - p[:, 2:3]) * b
    a = a - a.mean(axis=0)
    b = b - b.mean(axis=0)
    return float(-np.sum(a * b) / np.sum(b * b))


def defocus(lens: Lens | PerturbedLens, focus_nominal: float | None = None, **kw) -> float:
    """How far the image plane lies beyond the lens's RMS best focus on
    axis, mm (+: away from the lens), against the design's own focus
    offset: ``best_focus(design) − best_focus(lens)`` (``**kw`` passed on
    to :func:`best_focus`). Zero for the design and for a device set by
    :func:`refocus`; the last gap moved by d gives d exactly (the rays are
    straight beyond the last surface). ``focus_nominal``: the design's
    :func:`best_focus` where already known.

    >>> from calibration.optics.lens import Surface
    >>> from calibration.optics.materials import Material
    >>> g = Material("g", 1.5, 60.0)
    >>> lens = Lens((Surface(0.1, thickness=2.0, material=g, semi_diameter=2.0, stop=True),
    ...              Surface(-0.1, thickness=9.0, semi_diameter=2.0)), epd=2.0)
    >>> tilted = {"e1.decenter_y": 0.01}
    >>> d0, d1 = (defocus(apply(lens, {**tilted, "s2.thickness": t})) for t in (0.0, 0.007))
    >>> round(1e3 * (d1 - d0), 6)
    7.0
    """
    if focus_nominal is None:
        focus_nominal = best_focus(lens.nominal if isinstance(lens, PerturbedLens) else lens, **kw)
    return focus_nominal - best_focus(lens, **kw)


def design_foci(lens: Lens | PerturbedLens, points_mm, **kw) -> tuple[np.ndarray, list]:
    """The reference :func:`defocus_map` measures against: the fields
    (θx, θy) whose real chief rays land on image points (N, 2) mm in the
    design (:func:`calibration.optics.psf.map.chief_ray_fields`), and the
    design's :func:`best_focus` there (``**kw`` passed on), mm."""
    from calibration.optics.psf.map import chief_ray_fields

    design = nominal(lens).nominal
    fields = chief_ray_fields(design, np.asarray(points_mm, float).reshape(-1, 2))
    return fields, [best_focus(design, f, **kw) for f in fields]


def defocus_map(lens: Lens | PerturbedLens, points_mm, reference=None, **kw) -> np.ndarray:
    """:func:`defocus` at image points: how far a flat sensor at the
    design's image plane lies beyond the lens's RMS best focus at each
    point, mm (+: away from the lens), against the design's own best focus
    there (its field curvature and astigmatism are the design's, not the
    device's). Each point is reached at the field whose real chief ray
    lands on it in the design (:func:`calibration.optics.psf.map.chief_ray_fields`).

    Parameters
    ----------
    lens : Lens or PerturbedLens
    points_mm : (N, 2) array_like
        Image-plane (x, y), mm, in the convention of the lens's traces.
    reference : (fields, foci), optional
        :func:`design_foci` of those points, where already known.
    **kw
        Passed on to :func:`best_focus`.

    Returns
    -------
    (N,) ndarray, mm

    Example
    -------
    A decentred element tilts the image plane: the defocus differs by
    field side, where the design's is the same on both.

    >>> from calibration.optics.lens import Surface
    >>> from calibration.optics.materials import Material
    >>> g = Material("g", 1.5, 60.0)
    >>> lens = Lens((Surface(0.1, thickness=2.0, material=g, semi_diameter=2.0, stop=True),
    ...              Surface(-0.1, thickness=9.0, semi_diameter=2.0)), epd=2.0)
    >>> pts = [(-0.5, 0.0), (0.5, 0.0)]
    >>> [round(1e3 * float(d), 1) for d in defocus_map(lens, pts)]
    [0.0, 0.0]
    >>> left, right = defocus_map(apply(lens, {"e1.decenter_x": 0.05}), pts)
    >>> round(1e3 * float(right - left), 1)
    9.4
    """
    fields, foci = design_foci(lens, points_mm, **kw) if reference is None else reference
    return np.array([f0 - best_focus(lens, f, **kw) for f0, f in zip(foci, fields)])


def refocus(lens: PerturbedLens, method: str = "rms", **kw) -> PerturbedLens:
    """Re-set the image distance of a perturbed lens as assembly does
    (focus is adjusted, not toleranced): the last thickness changes by the
    perturbed lens's best-focus shift minus the nominal lens's, so the
    designer's own focus offset is kept.

    Parameters
    ----------
    lens : PerturbedLens
    method : {"rms", "paraxial"}
        "rms": :func:`best_focus` on axis (``**kw`` passed on);
        "paraxial": the change of the paraxial back focal length.

    Returns
    -------
    PerturbedLens
        The same perturbation plus ``s<N>.thickness`` (N = last surface).
    """
    if not isinstance(lens, PerturbedLens):
        raise TraceError("refocus() takes a PerturbedLens (the nominal lens is in focus by definition)")
    if method == "rms":
        shift = -defocus(lens, **kw)
    elif method == "paraxial":
        shift = paraxial.first_order(lens.lens).bfl - paraxial.first_order(lens.nominal).bfl
    else:
        raise TraceError(f"unknown focus method {method!r}; valid: 'rms', 'paraxial'")
    name = f"s{len(lens.surfaces)}.thickness"
    d = lens.perturbation.as_dict()
    d[name] = d.get(name, 0.0) + shift
    return apply(lens.nominal, Perturbation.from_dict(d))


def plot_spot_diagram(spots: Sequence[Spot], *, reference: str = "centroid", scale_um: float | None = None,
                      ax=None, max_points: int = 5000):
    """Spot diagrams side by side, in µm about each spot's reference.

    Parameters
    ----------
    spots : sequence of Spot
    reference : {"centroid", "chief"}
    scale_um : float, optional
        Half-width of each panel, µm (default: 1.2 × the largest spot).
    ax : sequence of matplotlib Axes, optional
        One per spot; default a new figure.
    max_points : int
        Points drawn per spot (a random subset beyond that).

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    spots = list(spots)
    if ax is None:
        fig, axes = plt.subplots(1, len(spots), figsize=(2.6 * len(spots), 2.9), squeeze=False)
        axes = axes[0]
    else:
        axes = list(np.atleast_1d(ax))
        fig = axes[0].figure
    refs = [s.centroid if reference == "centroid" or s.chief is None else s.chief for s in spots]
    if scale_um is None:
        ext = [np.max(np.abs(s.points - r)) * 1e3 if len(s.points) else 1.0 for s, r in zip(spots, refs)]
        scale_um = 1.2 * max(ext)
    sel_rng = np.random.default_rng(0)
    for a, s, r in zip(axes, spots, refs):
        p = (s.points - r) * 1e3
        idx = np.arange(len(p))
        if len(p) > max_points:
            idx = sel_rng.choice(len(p), max_points, replace=False)
        for w in s.wavelengths_nm:
            m = s.wavelength_of_point[idx] == w
            a.plot(p[idx][m, 0], p[idx][m, 1], ".", ms=1.0, label=f"{w:g} nm")
        if len(s.wavelengths_nm) > 1 and a is axes[0]:
            a.legend(fontsize=6, markerscale=6, loc="upper right", frameon=False)
        a.set_xlim(-scale_um, scale_um)
        a.set_ylim(-scale_um, scale_um)
        a.set_aspect("equal")
        a.set_title(f"({s.field_deg[0]:g}°, {s.field_deg[1]:g}°)\nRMS {s.rms_radius() * 1e3:.2f} µm", fontsize=8)
        a.set_xlabel("x (µm)", fontsize=8)
        a.tick_params(labelsize=7)
    axes[0].set_ylabel("y (µm)", fontsize=8)
    return fig


def lens_report(lens) -> dict:
    """First-order data, vignetting and RMS spot radii of a lens, JSON-ready.

    Returns
    -------
    dict
        Name, surface and element counts, stop surface (1-based); EFL, BFL,
        EPD, pupil positions, exit-pupil diameter, TTL and total track (mm);
        F-number and working F-number; half field of view (degrees);
        paraxial image height (mm); primary wavelength (nm); the sensor;
        and at 0, 0.5, 0.7 and 1.0 of the field (real aiming, 4000 rays,
        primary wavelength) the transmitted fraction, the RMS spot radius
        about the centroid (µm) and the chief ray's image height (mm).
    """
    fo = paraxial.first_order(lens)
    fields = []
    for frac in (0.0, 0.5, 0.7, 1.0):
        theta = frac * lens.half_fov_deg
        sp = spot(lens, (0.0, theta), n=4000, aiming="real")
        fields.append({"field": frac, "angle_deg": round(theta, 4),
                       "transmitted": round(sp.fraction_valid, 4),
                       "rms_spot_um": round(sp.rms_radius("centroid") * 1e3, 4),
                       "chief_y_mm": None if sp.chief is None else round(float(sp.chief[1]), 5)})
    return {
        "name": lens.name,
        "surfaces": len(lens.surfaces),
        "elements": len(lens.elements()),
        "stop_surface": lens.stop_index + 1,
        "efl_mm": fo.efl, "bfl_mm": fo.bfl, "f_number": fo.f_number,
        "working_f_number": fo.working_f_number, "epd_mm": fo.epd,
        "entrance_pupil_z_mm": fo.entrance_pupil_z, "exit_pupil_z_mm": fo.exit_pupil_z,
        "exit_pupil_diameter_mm": fo.exit_pupil_diameter, "ttl_mm": fo.ttl,
        "total_track_mm": fo.total_track, "half_fov_deg": lens.half_fov_deg,
        "paraxial_image_height_mm": fo.image_height,
        "primary_wavelength_nm": lens.primary_nm,
        "sensor": {"pixel_pitch_um": lens.sensor.pixel_pitch_um, "width_px": lens.sensor.width_px,
                   "height_px": lens.sensor.height_px},
        "fields": fields,
    }

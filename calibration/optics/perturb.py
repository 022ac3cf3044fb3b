"""Perturbed lenses: manufacturing deviations as named parameters.

A *perturbation* is an ordered set of named deviations from the nominal
prescription (DESIGN.md, "Perturbations are named parameters"); applying it
to a :class:`~calibration.optics.lens.Lens` gives a :class:`PerturbedLens`: the
perturbed coaxial prescription plus a *pose* (rotation and vertex position
in global coordinates) for every surface, which is what the ray tracer
(:mod:`calibration.optics.trace`) consumes.

Parameter names (surfaces, elements and solid media numbered from 1 as in
optical design programs; values are *deltas* added to the nominal value):

=====================  ==========  ==============================================
name                   unit        meaning
=====================  ==========  ==============================================
``s3.curvature``       1/mm        vertex curvature c of surface 3
``s3.conic``           --          conic constant k of surface 3
``s4.A6``              mm^(1-i)    polynomial coefficient A_i (any order i ≥ 1)
``s2.thickness``       mm          axial distance after surface 2 (the centre
                                   thickness or air gap that follows it);
                                   everything after it moves with it
``e1.decenter_x``      mm          lateral shift of element 1 (all its surfaces)
``e1.decenter_y``      mm
``e1.tilt_zx``         degree      Euler angle α (rotation in the z–x plane)
``e1.tilt_yz``         degree      Euler angle β (rotation in the y–z plane)
``e1.tilt_xy``         degree      Euler angle γ (rotation about the axis)
``m2.nd``              --          d-line index of solid medium 2
``m2.vd``              --          Abbe number of solid medium 2
=====================  ==========  ==============================================

*Elements* are :meth:`Lens.elements` (runs of surfaces with a solid between
them, so a filter plate is an element and a dummy stop surface is not).
*Media* ``m1, m2, ...`` are the solid media in order from the object (the
glass or plastic after each non-air surface); for lenses made of singlets
and plates, medium j is element j's material.

Element pose (paper, eqs. 9–10). The rotation maps global ray data into the
element frame, ``p̄ = R (p − v)``, with

.. math::

    R = R_z(γ)\\,R_x(β)\\,R_y(α),\\quad
    R_y(α) = \\begin{pmatrix}\\cos α & 0 & -\\sin α\\\\ 0&1&0\\\\ \\sin α&0&\\cos α\\end{pmatrix},

``R_x(β)`` and ``R_z(γ)`` as printed in eq. 9 (α = t_zx, β = t_yz,
γ = t_xy); the element's axis points along ``Rᵀ e_z = (cos β sin α, sin β,
cos β cos α)``, so a positive tilt_zx turns it toward +x and a positive
tilt_yz toward +y. The element is first decentred by (decenter_x, decenter_y), then
tilted about its (decentred) **first vertex**: the vertex of its surface j is
``v_first + Rᵀ (0, 0, z_j − z_first)``. Surfaces after the element keep
their nominal axis (they sit in the barrel, not on the tilted element), as
Zemax's element tolerances (TEDX/TETX) do.

Zero perturbation is the nominal lens exactly: parameters whose value is 0
are skipped, every pose is the identity at ``(0, 0, z_i)``, and the tracer
runs the same code on both, so the traces agree bit for bit.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from calibration.optics.lens import Lens, LensError, Surface
from calibration.optics.materials import LAMBDA_C, LAMBDA_D, LAMBDA_F, Material


class PerturbationError(LensError):
    """An invalid perturbation or parameter name; the message names it."""


_SURFACE_RE = re.compile(r"^s(\d+)\.(curvature|conic|thickness|A(\d+))$")
_ELEMENT_RE = re.compile(r"^e(\d+)\.(decenter_x|decenter_y|tilt_zx|tilt_yz|tilt_xy)$")
_MEDIUM_RE = re.compile(r"^m(\d+)\.(nd|vd)$")
NAME_FORMS = ("s<i>.curvature", "s<i>.conic", "s<i>.A<order>", "s<i>.thickness",
              "e<j>.decenter_x", "e<j>.decenter_y", "e<j>.tilt_zx", "e<j>.tilt_yz",
              "e<j>.tilt_xy", "m<j>.nd", "m<j>.vd")


def parse_name(name: str) -> tuple[str, int, str]:
    """Split a parameter name into (kind, 1-based index, attribute).

    ``kind`` is "s" (surface), "e" (element) or "m" (medium); the attribute
    of an aspheric term is "A<order>".

    >>> parse_name("s4.A6")
    ('s', 4, 'A6')
    >>> parse_name("e1.tilt_zx")
    ('e', 1, 'tilt_zx')
    """
    for kind, rx in (("s", _SURFACE_RE), ("e", _ELEMENT_RE), ("m", _MEDIUM_RE)):
        m = rx.match(name)
        if m:
            idx = int(m.group(1))
            if idx < 1:
                raise PerturbationError(f"parameter {name!r}: indices start at 1")
            if kind == "s" and m.group(3) is not None and int(m.group(3)) < 1:
                raise PerturbationError(f"parameter {name!r}: aspheric order must be ≥ 1")
            return kind, idx, m.group(2)
    raise PerturbationError(f"unknown parameter name {name!r}; valid forms: {', '.join(NAME_FORMS)}")


@dataclass(frozen=True)
class Perturbation:
    """Named deviations from a nominal lens (deltas, in each name's unit).

    Attributes
    ----------
    names : tuple of str
        Parameter names (see the module docstring), no duplicates.
    values : tuple of float
        The deltas, same order.

    >>> p = Perturbation.from_dict({"e1.decenter_y": 0.002, "s3.thickness": -0.005})
    >>> p.as_dict()["e1.decenter_y"]
    0.002
    """

    names: tuple[str, ...] = ()
    values: tuple[float, ...] = ()

    def __post_init__(self):
        names = tuple(self.names)
        values = tuple(float(v) for v in np.asarray(self.values, dtype=np.float64).ravel())
        if len(names) != len(values):
            raise PerturbationError(f"{len(names)} names but {len(values)} values")
        seen = set()
        for n, v in zip(names, values):
            parse_name(n)
            if n in seen:
                raise PerturbationError(f"parameter {n!r} given twice")
            seen.add(n)
            if not math.isfinite(v):
                raise PerturbationError(f"parameter {n!r}: value must be finite, got {v!r}")
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "values", values)

    @classmethod
    def from_dict(cls, d: Mapping[str, float]) -> Perturbation:
        return cls(tuple(d), tuple(d.values()))

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.names, self.values))

    def __len__(self) -> int:
        return len(self.names)

    @property
    def is_zero(self) -> bool:
        return all(v == 0.0 for v in self.values)


@dataclass(frozen=True, eq=False)
class Pose:
    """Where a surface sits: ``p_local = rotation @ (p_global − vertex)``.

    Attributes
    ----------
    rotation : (3, 3) ndarray or None
        Global → local rotation; None is the identity (kept apart so the
        coaxial case costs nothing and stays exact).
    vertex : (3,) ndarray
        The surface vertex in global coordinates, mm.
    """

    rotation: np.ndarray | None
    vertex: np.ndarray

    def to_local(self, p: np.ndarray, d: np.ndarray | None = None):
        """Global (…, 3) points (and directions) into the local frame."""
        q = np.asarray(p, dtype=np.float64) - self.vertex
        if self.rotation is not None:
            q = q @ self.rotation.T
            if d is not None:
                d = np.asarray(d, dtype=np.float64) @ self.rotation.T
        return q if d is None else (q, d)

    def to_global(self, p: np.ndarray, d: np.ndarray | None = None):
        """Local (…, 3) points (and directions) into global coordinates."""
        q = np.asarray(p, dtype=np.float64)
        if self.rotation is not None:
            q = q @ self.rotation
            if d is not None:
                d = np.asarray(d, dtype=np.float64) @ self.rotation
        q = q + self.vertex
        return q if d is None else (q, d)


def euler_rotation(tilt_zx_deg: float, tilt_yz_deg: float, tilt_xy_deg: float) -> np.ndarray:
    """R = Rz(γ)·Rx(β)·Ry(α) of paper eq. 9 (global → element frame), angles
    in degrees (α = t_zx, β = t_yz, γ = t_xy).

    >>> np.allclose(euler_rotation(0, 0, 0), np.eye(3))
    True
    """
    a, b, g = (math.radians(t) for t in (tilt_zx_deg, tilt_yz_deg, tilt_xy_deg))
    ca, sa, cb, sb, cg, sg = math.cos(a), math.sin(a), math.cos(b), math.sin(b), math.cos(g), math.sin(g)
    rz = np.array([[cg, -sg, 0.0], [sg, cg, 0.0], [0.0, 0.0, 1.0]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cb, -sb], [0.0, sb, cb]])
    ry = np.array([[ca, 0.0, -sa], [0.0, 1.0, 0.0], [sa, 0.0, ca]])
    return rz @ rx @ ry


@dataclass(frozen=True)
class PerturbedMaterial(Material):
    """A catalogue material with its nd/vd perturbed: ``n'(λ) = n(λ) + Δnd +
    ΔB (1/λ² − 1/λ_d²)``, ΔB chosen so that the new Abbe number is ``vd``.

    For model (nd, vd) materials this is the same function as the Cauchy
    model refitted to the perturbed nd and vd (see :mod:`calibration.optics.materials`).
    """

    base: Material | None = None
    delta_nd: float = 0.0
    delta_b: float = 0.0

    def index(self, wavelength_nm):
        lam = np.asarray(wavelength_nm, dtype=np.float64)
        n = self.base.index(lam) + self.delta_nd + self.delta_b * (1.0 / (lam * lam) - 1.0 / LAMBDA_D ** 2)
        return n if lam.ndim else float(n)


def perturb_material(m: Material, delta_nd: float = 0.0, delta_vd: float = 0.0) -> Material:
    """``m`` with its d-line index and Abbe number shifted (the paper's
    material tolerance). Model materials stay model materials; catalogue
    (Sellmeier) ones become a :class:`PerturbedMaterial`."""
    if delta_nd == 0.0 and delta_vd == 0.0:
        return m
    if m.is_air:
        raise PerturbationError("cannot perturb the index of air")
    if m.formula == "model" and math.isfinite(m.vd):
        return dataclasses.replace(m, nd=m.nd + delta_nd, vd=m.vd + delta_vd)
    if not math.isfinite(m.vd):
        if delta_vd != 0.0:
            raise PerturbationError(f"material {m.name!r} has no dispersion; its vd cannot be perturbed")
        return dataclasses.replace(m, nd=m.nd + delta_nd, formula="constant")
    # Catalogue glass: measured nd/vd from its own formula.
    nd, nf, nc = (float(m.index(w)) for w in (LAMBDA_D, LAMBDA_F, LAMBDA_C))
    vd = (nd - 1.0) / (nf - nc)
    nd2, vd2 = nd + delta_nd, vd + delta_vd
    dfc_new = (nd2 - 1.0) / vd2
    db = (dfc_new - (nf - nc)) / (1.0 / LAMBDA_F ** 2 - 1.0 / LAMBDA_C ** 2)
    return PerturbedMaterial(name=m.name, nd=nd2, vd=vd2, formula="perturbed", base=m, delta_nd=delta_nd,
                             delta_b=db)


def solid_media(lens: Lens) -> list[int]:
    """0-based indices of the surfaces followed by a solid medium (medium
    ``m{j}`` is ``lens.surfaces[solid_media(lens)[j-1]].material``)."""
    return [i for i, s in enumerate(lens.surfaces[:-1]) if not s.material.is_air]


@dataclass(frozen=True, eq=False)
class PerturbedLens:
    """A lens with manufacturing deviations, ready to trace.

    Attributes
    ----------
    lens : Lens
        The perturbed coaxial prescription (curvatures, conics, aspheric
        terms, thicknesses, materials).
    poses : tuple of Pose
        One per surface, in global coordinates (first vertex of the
        nominal lens at the origin).
    image_pose : Pose
        The image plane (identity at the image vertex).
    nominal : Lens
        The lens the perturbation was applied to.
    perturbation : Perturbation
    """

    lens: Lens
    poses: tuple[Pose, ...]
    image_pose: Pose
    nominal: Lens
    perturbation: Perturbation = field(default_factory=Perturbation)

    @property
    def surfaces(self) -> tuple[Surface, ...]:
        return self.lens.surfaces

    @property
    def stop_index(self) -> int:
        return self.lens.stop_index


def apply(lens: Lens | PerturbedLens, perturbation: Perturbation | Mapping[str, float] | None = None
          ) -> PerturbedLens:
    """Apply named deviations to a nominal lens.

    Parameters
    ----------
    lens : Lens
        The nominal lens (a PerturbedLens is refused: perturb its nominal).
    perturbation : Perturbation or mapping name → delta, optional
        None or empty: the nominal lens (identity poses).

    Returns
    -------
    PerturbedLens
        Perturbed prescription and per-surface poses (see the module
        docstring for the conventions).

    Examples
    --------
    >>> from calibration.optics.lens import Lens, Surface
    >>> from calibration.optics.materials import Material
    >>> g = Material("g", 1.5, 60.0)
    >>> lens = Lens((Surface(0.1, thickness=2.0, material=g, semi_diameter=2.0, stop=True),
    ...              Surface(-0.1, thickness=9.0, semi_diameter=2.0)), epd=2.0)
    >>> pl = apply(lens, {"e1.decenter_y": 0.01, "s1.thickness": 0.02})
    >>> pl.poses[1].vertex.tolist()
    [0.0, 0.01, 2.02]
    """
    if isinstance(lens, PerturbedLens):
        raise PerturbationError("apply() takes the nominal Lens; combine perturbations instead")
    if perturbation is None:
        perturbation = Perturbation()
    elif not isinstance(perturbation, Perturbation):
        perturbation = Perturbation.from_dict(perturbation)
    surfaces = list(lens.surfaces)
    n_s = len(surfaces)
    elements = lens.elements()
    media = solid_media(lens)
    elem: dict[int, dict[str, float]] = {}
    med: dict[int, dict[str, float]] = {}
    for name, value in zip(perturbation.names, perturbation.values):
        kind, idx, attr = parse_name(name)
        if value == 0.0:
            continue
        if kind == "s":
            if idx > n_s:
                raise PerturbationError(f"parameter {name!r}: the lens has {n_s} surfaces")
            s = surfaces[idx - 1]
            if attr == "curvature":
                s = s.replace(curvature=s.curvature + value)
            elif attr == "conic":
                s = s.replace(conic=s.conic + value)
            elif attr == "thickness":
                s = s.replace(thickness=s.thickness + value)
            else:
                order = int(attr[1:])
                terms = dict(s.asphere)
                terms[order] = terms.get(order, 0.0) + value
                s = s.replace(asphere=tuple(sorted(terms.items())))
            surfaces[idx - 1] = s
        elif kind == "e":
            if idx > len(elements):
                raise PerturbationError(f"parameter {name!r}: the lens has {len(elements)} elements")
            elem.setdefault(idx, {})[attr] = value
        else:
            if idx > len(media):
                raise PerturbationError(f"parameter {name!r}: the lens has {len(media)} solid media")
            med.setdefault(idx, {})[attr] = value
    for j, d in med.items():
        i = media[j - 1]
        surfaces[i] = surfaces[i].replace(
            material=perturb_material(surfaces[i].material, d.get("nd", 0.0), d.get("vd", 0.0)))
    plens = lens.replace(surfaces=tuple(surfaces)) if perturbation.names else lens
    z = plens.vertex_z()
    poses = [Pose(None, np.array([0.0, 0.0, z[i]])) for i in range(n_s)]
    for j, d in elem.items():
        first, last = elements[j - 1]
        dx, dy = d.get("decenter_x", 0.0), d.get("decenter_y", 0.0)
        r = euler_rotation(d.get("tilt_zx", 0.0), d.get("tilt_yz", 0.0), d.get("tilt_xy", 0.0))
        rot = None if np.array_equal(r, np.eye(3)) else r
        for i in range(first, last + 1):
            if rot is None:
                v = np.array([dx, dy, z[i]])
            else:
                v = np.array([dx, dy, z[first]]) + (z[i] - z[first]) * rot[2, :]
            poses[i] = Pose(rot, v)
    image = Pose(None, np.array([0.0, 0.0, z[n_s]]))
    return PerturbedLens(plens, tuple(poses), image, lens, perturbation)


def nominal(lens: Lens | PerturbedLens) -> PerturbedLens:
    """A PerturbedLens for ``lens`` (unchanged if it already is one)."""
    return lens if isinstance(lens, PerturbedLens) else apply(lens, None)


# -- tolerances ----------------------------------------------------------------

FRINGE_WAVELENGTH_MM = 632.8e-6
"""Test wavelength of power fringes (He–Ne), mm."""

DEFAULT_TOLERANCES = {
    "power_fringes": 1.0,
    "curvature_rel": 0.0,
    "form_pv_mm": 0.3e-3,
    "thickness_mm": 0.005,
    "decenter_mm": 0.002,
    "tilt_deg": 0.02,
    "tilt_xy_deg": 0.5,
    "nd": 0.001,
    "vd_rel": 0.008,
}
"""Default phone-lens tolerances (half-widths of the ± band): those of a
precision moulded lens actively aligned in its barrel, the usual practice
for F/2-class phone lenses (the looser drop-in values are quoted per item).

Measured on US-12210142-B2-e9 (nominal on-axis RMS spot 0.80 µm): random
devices refocused by assembly (:func:`calibration.optics.spot.refocus`) have a
median on-axis RMS spot of 2.1 µm (worst of 8: 2.7 µm; 3.3 µm at 0.7 field)
with these defaults, and 4.9 µm (worst 5.9 µm) with the drop-in values
(2 fringes, 0.5 µm form, ±10 µm, ±5 µm, ±0.05°) — a lens visibly softer than
any shipping phone camera, which is why the tighter set is the default.

* ``power_fringes`` 1 (drop-in: 2): curvature ±N λ/sd² (λ = 632.8 nm), the power error
  that changes the sag at the clear semi-diameter by N λ/2 = 0.63 µm (the
  Zemax TFRN "fringes of power" convention). Moulded phone aspheres are
  held to a form error of a few tenths of a µm PV *including* power (the
  mould insert is corrected until they are), so the fringe form fits them
  better than the "R ± 0.5 %" callout of polished glass, which on these
  surfaces (R ≈ 1.5–3 mm at sd ≈ 1–1.6 mm) allows 1–2 µm of sag.
  ``curvature_rel`` (default 0) adds that relative form:
  tolerance = max(curvature_rel·|c|, N λ/sd²); pass
  ``tolerances={"curvature_rel": 0.005}`` for ±0.5 %.
* ``form_pv_mm`` 0.3 µm (drop-in: 0.5 µm): the sag change at the clear semi-diameter allowed
  to a conic or an aspheric coefficient (tolerance = 0.5 µm / |∂sag/∂p| at
  ρ = sd; a conic's at most ±1 and kept inside the conic's domain).
* ``thickness_mm`` ±5 µm (drop-in: ±10 µm) for centre thicknesses and spacer air gaps
  (injection-moulded lenses and stamped spacers hold ±5–10 µm). The last
  gap (focus) is not toleranced: assembly sets it, see
  :func:`calibration.optics.spot.refocus`.
* ``decenter_mm`` ±2 µm element decenter and ``tilt_deg`` ±0.02° element
  tilt about x and y after active alignment (drop-in assembly in a moulded
  barrel: ±5 µm and ±0.05° (3′)). A
  published desensitisation study of a 4-element phone lens toleranced
  5 µm decenter and 5′ tilt (Opt. Precision Eng. 34(2), 191–200, 2026,
  doi:10.37188/OPE.20263402.0191). Rotation about the axis (``tilt_xy``,
  ±0.5°) only matters together with other asymmetries and is left out of
  the default space.
* ``nd`` ±0.001 and ``vd_rel`` ±0.8 %: SCHOTT's standard catalogue
  tolerance is nd ±0.0005 and νd ±0.8 %; optical plastics vary more from
  lot and moulding (stress, density), so nd is doubled.

These are engineering defaults of the right order for phone lenses, not
published values for any one lens: replace them with the supplier's
drawing where known (``ParameterSpace.default(..., tolerances=...)``).
On US-12210142-B2-e9 (F/1.95) curvature (power) and element decenter are
the most sensitive entries, each of the order of the whole budget.
"""


def _conic_sag_derivative(c: float, k: float, rho: float) -> float:
    """∂sag/∂k at ρ (mm per unit conic)."""
    u = rho * rho
    w = 1.0 - (1.0 + k) * c * c * u
    if w <= 0:
        return 0.0
    r = math.sqrt(w)
    return c ** 3 * u * u / (2.0 * r * (1.0 + r) ** 2)


def default_tolerance(lens: Lens, name: str, tolerances: Mapping[str, float] | None = None) -> float:
    """The default ± tolerance of one parameter (see DEFAULT_TOLERANCES)."""
    t = dict(DEFAULT_TOLERANCES)
    if tolerances:
        unknown = set(tolerances) - set(t)
        if unknown:
            raise PerturbationError(f"unknown tolerance keys {sorted(unknown)}; valid: {sorted(t)}")
        t.update(tolerances)
    kind, idx, attr = parse_name(name)
    if kind == "s":
        s = lens.surfaces[idx - 1]
        sd = s.semi_diameter if s.semi_diameter is not None else 1.0
        if attr == "curvature":
            return max(t["curvature_rel"] * abs(s.curvature),
                       t["power_fringes"] * FRINGE_WAVELENGTH_MM / (sd * sd))
        if attr == "thickness":
            return t["thickness_mm"]
        if attr == "conic":
            # The form budget, at most ±1, and small enough that the conic
            # stays defined over the clear aperture ((1+k)c²sd² < 0.9).
            dk = _conic_sag_derivative(s.curvature, s.conic, sd)
            tol = min(t["form_pv_mm"] / abs(dk), 1.0) if dk != 0 else 1.0
            room = 0.9 / (s.curvature ** 2 * sd * sd) - 1.0 - s.conic if s.curvature != 0 else math.inf
            return min(tol, room) if room > 0 else tol
        order = int(attr[1:])
        return t["form_pv_mm"] / sd ** order
    if kind == "e":
        if attr.startswith("decenter"):
            return t["decenter_mm"]
        return t["tilt_xy_deg"] if attr == "tilt_xy" else t["tilt_deg"]
    m = lens.surfaces[solid_media(lens)[idx - 1]].material
    if attr == "nd":
        return t["nd"]
    return t["vd_rel"] * (m.vd if math.isfinite(m.vd) else 0.0)


def nominal_value(lens: Lens, name: str) -> float:
    """The nominal value of a parameter (0 for decenters and tilts)."""
    kind, idx, attr = parse_name(name)
    if kind == "s":
        s = lens.surfaces[idx - 1]
        if attr in ("curvature", "conic", "thickness"):
            return float(getattr(s, attr))
        return float(s.coefficient(int(attr[1:])))
    if kind == "e":
        return 0.0
    m = lens.surfaces[solid_media(lens)[idx - 1]].material
    return float(m.nd if attr == "nd" else m.vd)


#: the kinds of perturbation :func:`default_names` knows
PARAMETER_KINDS = ("curvature", "conic", "asphere", "thickness", "decenter", "tilt", "tilt_xy", "nd", "vd")
#: the kinds a default tolerance analysis perturbs (and ``isp calib simulate --perturb random`` draws)
TOLERANCED_KINDS = ("curvature", "conic", "thickness", "decenter", "tilt", "nd", "vd")


def default_names(lens: Lens, kinds: Iterable[str] = TOLERANCED_KINDS) -> list[str]:
    """The parameters a default tolerance analysis perturbs.

    * curvature / conic: every surface of an element that is curved or
      aspheric (flat plates and dummy surfaces have none); conic only
      where the surface is curved.
    * asphere: every existing non-zero A_i of those surfaces (not in the
      default set: dozens of strongly correlated parameters).
    * thickness: each element's centre thickness(es) and the air gap to
      the next element, represented by the thickness of the surface just
      before that element (so a dummy stop stays with the front group); the
      last air gap to the image (focus) is left out: focus is set at
      assembly.
    * decenter, tilt: decenter_x/y, tilt_zx/yz of every element (tilt_xy
      with ``"tilt_xy"``).
    * nd, vd: every solid medium (vd only where it disperses).
    """
    kinds = tuple(kinds)
    bad = set(kinds) - set(PARAMETER_KINDS)
    if bad:
        raise PerturbationError(f"unknown parameter kinds {sorted(bad)}; valid: {sorted(PARAMETER_KINDS)}")
    elements = lens.elements()
    in_element = sorted({i for a, b in elements for i in range(a, b + 1)})
    names: list[str] = []
    for i in in_element:
        s = lens.surfaces[i]
        shaped = s.curvature != 0 or any(a != 0 for _, a in s.asphere)
        if "curvature" in kinds and shaped:
            names.append(f"s{i + 1}.curvature")
        if "conic" in kinds and s.curvature != 0:
            names.append(f"s{i + 1}.conic")
        if "asphere" in kinds:
            names += [f"s{i + 1}.A{o}" for o, a in s.asphere if a != 0]
    if "thickness" in kinds:
        thick = set()
        for j, (a, b) in enumerate(elements):
            thick.update(range(a, b))
            if j + 1 < len(elements):
                thick.add(elements[j + 1][0] - 1)
        names += [f"s{i + 1}.thickness" for i in sorted(thick)]
    for j in range(1, len(elements) + 1):
        if "decenter" in kinds:
            names += [f"e{j}.decenter_x", f"e{j}.decenter_y"]
        if "tilt" in kinds:
            names += [f"e{j}.tilt_zx", f"e{j}.tilt_yz"]
        if "tilt_xy" in kinds:
            names.append(f"e{j}.tilt_xy")
    for j, i in enumerate(solid_media(lens), start=1):
        m = lens.surfaces[i].material
        if "nd" in kinds:
            names.append(f"m{j}.nd")
        if "vd" in kinds and math.isfinite(m.vd):
            names.append(f"m{j}.vd")
    return names


@dataclass(frozen=True, eq=False)
class ParameterSpace:
    """The parameters a fitter or a Monte Carlo run varies.

    Attributes
    ----------
    lens : Lens
        The nominal lens.
    names : tuple of str
    nominal : (P,) ndarray
        Nominal value of each parameter (0 for decenters/tilts), in its unit.
    tolerance : (P,) ndarray
        Half-width of the ± tolerance band of each delta.
    lower, upper : (P,) ndarray
        Bounds on each delta for a fitter (default ±2 tolerances).

    A *vector* is the deltas in ``names`` order; :meth:`to_perturbation`
    and :meth:`to_vector` convert.
    """

    lens: Lens
    names: tuple[str, ...]
    nominal: np.ndarray
    tolerance: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    def __post_init__(self):
        n = len(self.names)
        Perturbation(self.names, (0.0,) * n)  # validates the names
        for a in ("nominal", "tolerance", "lower", "upper"):
            v = np.asarray(getattr(self, a), dtype=np.float64).reshape(-1)
            if v.shape != (n,):
                raise PerturbationError(f"{a} has {v.size} entries for {n} parameters")
            v.setflags(write=False)
            object.__setattr__(self, a, v)
        if np.any(self.tolerance < 0) or np.any(self.lower > self.upper):
            raise PerturbationError("tolerances must be ≥ 0 and lower ≤ upper")

    @classmethod
    def default(cls, lens: Lens, names: Sequence[str] | None = None, *,
                kinds: Iterable[str] = ("curvature", "conic", "thickness", "decenter", "tilt", "nd", "vd"),
                tolerances: Mapping[str, float] | None = None,
                overrides: Mapping[str, float] | None = None,
                bound_factor: float = 2.0) -> ParameterSpace:
        """A space with default tolerances.

        Parameters
        ----------
        lens : Lens
        names : sequence of str, optional
            The parameters; default :func:`default_names` (``kinds``).
        tolerances : mapping, optional
            Replacements for :data:`DEFAULT_TOLERANCES` entries.
        overrides : mapping name → tolerance, optional
            Per-parameter tolerances.
        bound_factor : float
            Fitter bounds are ± bound_factor × tolerance.
        """
        names = tuple(names) if names is not None else tuple(default_names(lens, kinds))
        overrides = dict(overrides or {})
        tol = np.array([overrides.pop(n) if n in overrides else default_tolerance(lens, n, tolerances)
                        for n in names])
        if overrides:
            raise PerturbationError(f"overrides for parameters not in the space: {sorted(overrides)}")
        nom = np.array([nominal_value(lens, n) for n in names])
        return cls(lens, names, nom, tol, -bound_factor * tol, bound_factor * tol)

    def __len__(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise PerturbationError(f"{name!r} is not a parameter of this space") from None

    def to_perturbation(self, vector) -> Perturbation:
        """Deltas vector (P,) → Perturbation."""
        v = np.asarray(vector, dtype=np.float64).reshape(-1)
        if v.shape != (len(self.names),):
            raise PerturbationError(f"vector has {v.size} entries for {len(self.names)} parameters")
        return Perturbation(self.names, tuple(v))

    def to_vector(self, perturbation: Perturbation | Mapping[str, float]) -> np.ndarray:
        """Perturbation → deltas vector (P,); absent parameters are 0, names
        outside the space are an error."""
        d = perturbation.as_dict() if isinstance(perturbation, Perturbation) else dict(perturbation)
        extra = set(d) - set(self.names)
        if extra:
            raise PerturbationError(f"parameters not in the space: {sorted(extra)}")
        return np.array([d.get(n, 0.0) for n in self.names])

    def absolute(self, vector) -> np.ndarray:
        """Absolute parameter values (nominal + delta), (P,)."""
        return self.nominal + np.asarray(vector, dtype=np.float64)

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """(n, P) deltas drawn uniformly within ± tolerance (the paper's
        Monte Carlo lenses, section 4.1)."""
        u = rng.uniform(-1.0, 1.0, size=(int(n), len(self.names)))
        return u * self.tolerance

    def clip(self, vector) -> np.ndarray:
        """The vector clipped to [lower, upper]."""
        return np.clip(np.asarray(vector, dtype=np.float64), self.lower, self.upper)

    def apply(self, vector) -> PerturbedLens:
        """The perturbed lens for a deltas vector."""
        return apply(self.lens, self.to_perturbation(vector))

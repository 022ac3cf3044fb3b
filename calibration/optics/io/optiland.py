"""optiland lens files: the JSON of ``optiland.optic.Optic.to_dict()``.

Layout (optiland 0.5–0.6): ``surface_group.surfaces`` is a list whose first
entry is the object surface and last the image surface; each real surface
has ``geometry`` (``type``, ``radius``, ``conic``, ``coefficients``, and a
coordinate system ``cs`` with vertex ``z``), ``thickness``, ``material_post``
(the medium after it), ``is_stop`` and ``aperture``. ``aperture`` at the top
is ``{"type": "EPD" | "imageFNO", "value": ...}``, ``fields`` lists
angle fields (degrees), ``wavelengths`` values in µm with one primary.

Geometries: ``Plane``, ``StandardGeometry`` (radius, conic), ``EvenAsphere``
(``coefficients[i]`` on ρ^(2i+2): ρ², ρ⁴, ...), ``OddAsphere``
(``coefficients[i]`` on ρ^(i+1)); decentred or tilted coordinate systems are
refused. Materials: ``IdealMaterial`` (a constant index), ``AbbeMaterial``
(nd, vd: a model glass here, where optiland fits its own polynomial), and
``Material`` (a named glass: ``reference`` is the catalogue, e.g.
``hikari`` SK16, ``schott`` F2), looked up in :mod:`calibration.optics.materials`.
"""

from __future__ import annotations

import math
from pathlib import Path

from calibration.optics.io.common import (
    DEFAULT_PIXEL_PITCH_UM,
    Source,
    combined_field_angle,
    default_sensor,
    default_wavelengths,
    read_json_lens,
)
from calibration.optics.lens import Lens, LensError, Surface
from calibration.optics.materials import AIR, Material, model_material

GEOMETRIES = ("Plane", "StandardGeometry", "EvenAsphere", "OddAsphere")
APERTURES = ("EPD", "imageFNO")


def read_optiland(path, *, data=None, pixel_pitch_um: float | None = None) -> Lens:
    """Read an optiland ``Optic.to_dict()`` JSON file.

    Parameters
    ----------
    path : str or Path
        The file (also the name in error messages).
    data : dict, optional
        Its parsed content, if already read.
    pixel_pitch_um : float, optional
        Pixel pitch of the assumed sensor (:func:`default_sensor`).

    Raises
    ------
    LensError
        One line naming the file and the surface.
    """
    return read_json_lens(path, data, pixel_pitch_um, _build, "optiland")


def _build(src: Source, d: dict, pixel_pitch_um) -> Lens:
    raw = d["surface_group"]["surfaces"]
    if len(raw) < 3:
        raise src.error(f"needs an object, at least one surface and an image; found {len(raw)} surfaces")
    obj_z = raw[0].get("geometry", {}).get("cs", {}).get("z", -math.inf)
    surfaces = []
    for i, s in enumerate(raw[1:-1], start=1):
        surfaces.append(_surface(src, s, i, raw[i + 1]))
    z1 = raw[1]["geometry"]["cs"].get("z", 0.0)
    object_distance = math.inf if math.isinf(obj_z) else z1 - obj_z

    ap = d.get("aperture") or {}
    kind, value = ap.get("type"), ap.get("value")
    if kind not in APERTURES:
        raise src.error(f"aperture type {kind!r} is not supported (supported: {', '.join(APERTURES)})")
    value = src.number(value, f"aperture {kind}", positive=True)
    f_number, epd = (value, None) if kind == "imageFNO" else (None, value)

    wavelengths, primary = _wavelengths(src, d.get("wavelengths") or {})
    lens = src.build(surfaces=tuple(surfaces), f_number=f_number, epd=epd, wavelengths_nm=wavelengths,
                     primary_nm=primary, object_distance=object_distance,
                     name=d.get("name") or Path(src.label).stem,
                     metadata={"source": {"format": "optiland", "file": Path(src.label).name}})
    lens = src.replace(lens, half_fov_deg=_half_fov(src, d.get("fields") or {}, lens))
    return lens.replace(sensor=default_sensor(lens, pixel_pitch_um or DEFAULT_PIXEL_PITCH_UM))


def _surface(src: Source, s: dict, i: int, nxt: dict) -> Surface:
    if s.get("type", "Surface") != "Surface":
        raise src.error(f"surface kind {s.get('type')!r} is not supported (only 'Surface')", i)
    g = s["geometry"]
    gtype = g.get("type")
    if gtype not in GEOMETRIES:
        raise src.error(f"geometry {gtype!r} is not supported (supported: {', '.join(GEOMETRIES)})", i)
    cs = g.get("cs", {})
    for k in ("x", "y", "rx", "ry", "rz"):
        if cs.get(k, 0.0):
            raise src.error(f"decentred or tilted surfaces are not supported ({k} = {cs[k]!r})", i)
    radius = g.get("radius", math.inf)
    radius = src.number(radius, "radius", i, allow_inf=True)
    if radius == 0:
        raise src.error("radius 0", i)
    c = 0.0 if math.isinf(radius) or gtype == "Plane" else 1.0 / radius
    conic = src.number(g.get("conic", 0.0), "conic", i)
    coef = g.get("coefficients", []) if gtype in ("EvenAsphere", "OddAsphere") else []
    if not isinstance(coef, list):
        raise src.error(f"coefficients must be a list, got {coef!r}", i)
    even = gtype == "EvenAsphere"
    asphere = tuple((2 * (k + 1) if even else k + 1, src.number(a, f"coefficient {k}", i))
                    for k, a in enumerate(coef) if a != 0)
    if "thickness" in s:
        t = src.number(s["thickness"], "thickness", i)
    else:
        t = src.number(nxt["geometry"]["cs"]["z"], "next z", i) - src.number(cs.get("z", 0.0), "z", i)
    sd = None
    ap = s.get("aperture")
    if isinstance(ap, dict):
        r = ap.get("r_max", ap.get("radius"))
        if r is None:
            raise src.error(f"aperture {ap.get('type')!r} is not supported (a radial aperture with r_max)", i)
        sd = src.number(r, "aperture r_max", i, positive=True)
    return Surface(curvature=c, conic=conic, asphere=asphere, thickness=t,
                   material=_material(src, s.get("material_post") or {}, i), semi_diameter=sd,
                   stop=bool(s.get("is_stop", False)), name=s.get("comment", "") or "")


def _material(src: Source, m: dict, i: int) -> Material:
    kind = m.get("type")
    if kind in ("IdealMaterial", "Air"):
        n = m.get("index", 1.0)
        if isinstance(n, list) and len(n) == 1:
            n = n[0]
        n = src.number(n, "material index", i, positive=True)
        return AIR if n == 1.0 else Material(f"n={n:g}", n, math.inf, "constant")
    if kind == "AbbeMaterial":
        return model_material(src.number(m.get("index"), "material index", i, positive=True),
                              src.number(m.get("abbe"), "material abbe", i, positive=True))
    if kind == "Material":
        name, ref = m.get("name"), m.get("reference")
        return src.material(f"{ref}:{name}" if ref else name, i)
    raise src.error(f"material type {kind!r} is not supported "
                    "(IdealMaterial, AbbeMaterial, Material)", i)


def _wavelengths(src: Source, w: dict) -> tuple[tuple[float, ...], float]:
    items = w.get("wavelengths", [])
    if not items:
        return default_wavelengths()
    scale = {"um": 1e3, "µm": 1e3, "nm": 1.0, "mm": 1e6}
    out, primary = [], None
    for item in items:
        unit = item.get("unit", "um")
        if unit not in scale:
            raise src.error(f"wavelength unit {unit!r} is not supported (um, nm, mm)")
        nm = src.number(item.get("value"), "wavelength", positive=True) * scale[unit]
        out.append(nm)
        if item.get("is_primary"):
            primary = nm
    return tuple(out), out[len(out) // 2] if primary is None else primary


def _half_fov(src: Source, f: dict, lens: Lens) -> float:
    fields = f.get("fields", [])
    if not fields:
        return 0.0
    kind = (f.get("field_definition") or {}).get("field_type") or f.get("field_type", "AngleField")
    xy = [(src.number(x.get("x", 0.0), "field x"), src.number(x.get("y", 0.0), "field y")) for x in fields]
    if kind in ("AngleField", "angle"):
        return max(combined_field_angle(x, y) for x, y in xy)
    h = max(math.hypot(x, y) for x, y in xy)
    if kind in ("ParaxialImageHeightField", "paraxial_image_height"):
        from calibration.optics.paraxial import field_angle
        try:
            theta = field_angle(lens, h)
        except LensError as e:
            raise src.error(str(e)) from None
        lens.metadata["field_conversion"] = f"paraxial image height {h!r} mm converted paraxially"
        return theta
    raise src.error(f"field type {kind!r} is not supported (AngleField, ParaxialImageHeightField)")

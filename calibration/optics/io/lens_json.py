"""The project's lens file format, ``lens/v1`` JSON: :func:`load_lens`,
:func:`save_lens`, and the dict form (:func:`lens_from_dict`,
:func:`lens_to_dict`). :func:`calibration.optics.io.read.read_lens` reads
this format and the other programs' files alike.

The format
----------
A UTF-8 JSON object; lengths in mm, pixel pitch in µm, wavelengths in nm::

    {
      "schema": "lens/v1",
      "name": "US-12210142-B2 e9",
      "units": "mm",
      "surfaces": [
        {"name": "L1 front", "radius": 3.055, "conic": -11.705,
         "aspheric": {"4": 0.0032982, "6": 0.011557},
         "thickness": 0.26, "material": {"nd": 1.544, "vd": 55.9},
         "semi_diameter": 1.598},
        {"curvature": 0.0, "thickness": 0.055, "stop": true, "semi_diameter": 1.114},
        ...
      ],
      "aperture": {"f_number": 1.95},
      "field": {"half_fov_deg": 36.8},
      "wavelengths_nm": [486.1327, 587.5618, 656.2725],
      "primary_nm": 587.5618,
      "object_distance": null,
      "sensor": {"pixel_pitch_um": 1.0, "width_px": 4000, "height_px": 3000},
      "metadata": {}
    }

Surface keys (surfaces numbered from 1 in messages):

=================  ==========================================================
``radius``         mm; ``"inf"`` or null for a flat surface. Or:
``curvature``      1/mm (0: flat). Not both.
``conic``          conic constant k (default 0).
``aspheric``       ``{"order": A, ...}``: sag term A·ρ^order (mm), any order
                   ≥ 1, odd orders included; or a list ``[A2, A4, A6, ...]``
                   of even orders from ρ² (the Zemax EVENASPH / optiland
                   convention).
``thickness``      mm to the next surface (last surface: to the image plane).
``material``       medium after the surface: a catalogue name
                   (:mod:`calibration.optics.materials`), ``{"nd": .., "vd": ..}``,
                   or a full description; default air.
``semi_diameter``  mm; rays outside are vignetted (default: no limit).
``stop``           true on the aperture stop (at most one surface).
``name``           free text.
=================  ==========================================================

``aperture`` is ``{"f_number": F}`` (image-space F/# = EFL/EPD), ``{"epd":
mm}`` (wins over an F-number if both are given), or ``{"stop_semi_diameter":
mm}`` ("float by stop size": the marked stop surface's semi-diameter sets the
beam). ``field`` is ``{"half_fov_deg": θ}`` or ``{"image_height": mm}`` (the
paraxial chief-ray height on the image plane at full field, converted to θ
at the primary wavelength by :func:`calibration.optics.paraxial.field_angle`). Without
``wavelengths_nm`` the F, d, C lines are used; without ``primary_nm`` the
middle wavelength. ``object_distance`` is mm from the first surface, null for
a distant object. Unknown keys are errors that list the valid ones.

:func:`save_lens` writes ``curvature`` (never ``radius``) and the exact
float values, so ``load_lens(save_lens(lens))`` equals ``lens``.

Errors are :class:`~calibration.optics.lens.LensError` with one line that names the
file and the surface: ``lens.json: surface 3: conic must be a number, got
'x'`` (:class:`calibration.optics.io.common.Source`).

Imports :mod:`calibration.optics` (lens, materials, paraxial),
:mod:`~calibration.optics.io.common` and ``isp.io.files`` (atomic writes).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from calibration.optics.lens import Lens, LensError, Sensor, Surface
from calibration.optics.io.common import Source, read_json
from calibration.optics.materials import material_to_spec

SCHEMA = "lens/v1"

TOP_KEYS = ("schema", "name", "units", "surfaces", "aperture", "field", "wavelengths_nm",
            "primary_nm", "object_distance", "sensor", "metadata", "perturbation")
SURFACE_KEYS = ("name", "radius", "curvature", "conic", "aspheric", "thickness", "material",
                "semi_diameter", "stop")
APERTURE_KEYS = ("f_number", "epd", "stop_semi_diameter")
FIELD_KEYS = ("half_fov_deg", "image_height")
SENSOR_KEYS = ("pixel_pitch_um", "width_px", "height_px")

_DEFAULT = Lens((Surface(),), epd=1.0)


# -- dict <-> Lens ------------------------------------------------------------

def lens_from_dict(data: Any, source: str = "<dict>") -> Lens:
    """A :class:`Lens` from a ``lens/v1`` dict.

    Parameters
    ----------
    data : dict
        The parsed JSON object.
    source : str
        Name used in error messages (the file).

    Raises
    ------
    LensError
        One line naming ``source``, the surface and the offending value.
    """
    src = Source(source)
    d = src.keys(data, TOP_KEYS, "the lens")
    if d.get("schema") != SCHEMA:
        raise src.error(f"'schema' must be {SCHEMA!r}, got {d.get('schema')!r}")
    if d.get("units", "mm") != "mm":
        raise src.error(f"'units' must be 'mm', got {d.get('units')!r}")
    name = d.get("name", "")
    if not isinstance(name, str):
        raise src.error(f"'name' must be a string, got {name!r}")
    raw = d.get("surfaces")
    if not isinstance(raw, list) or not raw:
        raise src.error(f"'surfaces' must be a non-empty list, got {raw!r}")
    surfaces = [_surface_from_dict(src, s, i) for i, s in enumerate(raw, start=1)]
    if sum(s.stop for s in surfaces) > 1:
        first, second = [i for i, s in enumerate(surfaces, start=1) if s.stop][:2]
        raise src.error("more than one surface is marked as the stop", second)

    f_number, epd, surfaces = _aperture_from_dict(src, d.get("aperture"), surfaces)
    wavelengths, primary = _wavelengths_from_dict(src, d)
    obj = d.get("object_distance")
    if obj is None or (isinstance(obj, str) and obj.lower() in ("inf", "infinity")):
        obj = math.inf
    else:
        obj = src.number(obj, "object_distance", positive=True)
    sensor = _sensor_from_dict(src, d.get("sensor"))
    metadata = d.get("metadata", {})
    if not isinstance(metadata, dict):
        raise src.error(f"'metadata' must be a JSON object, got {metadata!r}")
    if "perturbation" in d:  # a proxy lens: the nominal lens plus fitted perturbations
        pert = d["perturbation"]
        if not isinstance(pert, dict) or not all(isinstance(v, (int, float)) for v in pert.values()):
            raise src.error(f"'perturbation' must map parameter names to numbers, got {str(pert)[:60]!r}")
        metadata = {**metadata, "perturbation": dict(pert)}

    lens = src.build(surfaces=tuple(surfaces), f_number=f_number, epd=epd,
                     wavelengths_nm=wavelengths, primary_nm=primary, object_distance=obj,
                     sensor=sensor, name=name, metadata=dict(metadata))
    return _field_from_dict(src, d.get("field"), lens)


def _surface_from_dict(src: Source, s: Any, i: int) -> Surface:
    src.keys(s, SURFACE_KEYS, "the surface", i)
    if "radius" in s and "curvature" in s:
        raise src.error("give 'radius' or 'curvature', not both", i)
    if "radius" in s:
        r = s["radius"]
        if r is None or (isinstance(r, str) and r.lower() in ("inf", "infinity", "-inf", "-infinity")):
            c = 0.0
        else:
            r = src.number(r, "radius", i, allow_inf=True)
            if r == 0:
                raise src.error("radius 0 is ambiguous; write \"inf\" (or curvature 0) for a flat surface", i)
            c = 0.0 if math.isinf(r) else 1.0 / r
    else:
        c = src.number(s.get("curvature", 0.0), "curvature", i)
    conic = src.number(s.get("conic", 0.0), "conic", i)
    asphere = _aspheric_from_dict(src, s.get("aspheric", {}), i)
    if "thickness" not in s:
        raise src.error("'thickness' is missing", i)
    thickness = src.number(s["thickness"], "thickness", i)
    mat = src.material(s.get("material", "air"), i)
    sd = s.get("semi_diameter")
    if sd is not None:
        sd = src.number(sd, "semi_diameter", i, positive=True)
    stop = s.get("stop", False)
    if not isinstance(stop, bool):
        raise src.error(f"'stop' must be true or false, got {stop!r}", i)
    name = s.get("name", "")
    if not isinstance(name, str):
        raise src.error(f"'name' must be a string, got {name!r}", i)
    return Surface(curvature=c, conic=conic, asphere=asphere, thickness=thickness, material=mat,
                   semi_diameter=sd, stop=stop, name=name)


def _aspheric_from_dict(src: Source, a: Any, i: int) -> tuple[tuple[int, float], ...]:
    if isinstance(a, list):
        items = [(2 * (k + 1), v) for k, v in enumerate(a)]
    elif isinstance(a, dict):
        items = []
        for k, v in a.items():
            try:
                order = int(k)
            except (TypeError, ValueError):
                order = None
            if order is None or str(order) != str(k).strip() or order < 1:
                raise src.error(f"aspheric order must be an integer ≥ 1, got {k!r}", i)
            items.append((order, v))
    else:
        raise src.error(f"'aspheric' must be {{\"4\": A4, ...}} or a list [A2, A4, ...], got {a!r}", i)
    out = {}
    for order, v in items:
        if order in out:
            raise src.error(f"aspheric order {order} is given twice", i)
        out[order] = src.number(v, f"aspheric coefficient A{order}", i)
    return tuple(sorted(out.items()))


def _aperture_from_dict(src: Source, a: Any, surfaces: list[Surface]):
    if a is None:
        raise src.error("'aperture' is missing (give f_number, epd or stop_semi_diameter)")
    src.keys(a, APERTURE_KEYS, "'aperture'")
    if not a:
        raise src.error("'aperture' is empty (give f_number, epd or stop_semi_diameter)")
    f_number = src.number(a["f_number"], "aperture.f_number", positive=True) if "f_number" in a else None
    epd = src.number(a["epd"], "aperture.epd", positive=True) if "epd" in a else None
    if "stop_semi_diameter" in a:
        if f_number is not None or epd is not None:
            raise src.error("'aperture' takes stop_semi_diameter alone, or f_number and/or epd")
        sd = src.number(a["stop_semi_diameter"], "aperture.stop_semi_diameter", positive=True)
        stops = [i for i, s in enumerate(surfaces) if s.stop]
        if not stops:
            raise src.error("aperture.stop_semi_diameter needs a surface marked \"stop\": true")
        i = stops[0]
        if surfaces[i].semi_diameter is not None and surfaces[i].semi_diameter != sd:
            raise src.error(f"semi_diameter {surfaces[i].semi_diameter!r} differs from "
                            f"aperture.stop_semi_diameter {sd!r}", i + 1)
        surfaces = list(surfaces)
        surfaces[i] = surfaces[i].replace(semi_diameter=sd)
    return f_number, epd, surfaces


def _wavelengths_from_dict(src: Source, d: dict):
    if "wavelengths_nm" not in d:
        w = _DEFAULT.wavelengths_nm
        primary = d.get("primary_nm", _DEFAULT.primary_nm)
    else:
        w = d["wavelengths_nm"]
        if not isinstance(w, list) or not w:
            raise src.error(f"'wavelengths_nm' must be a non-empty list, got {w!r}")
        w = tuple(src.number(x, "wavelengths_nm entry", positive=True) for x in w)
        primary = d.get("primary_nm", w[len(w) // 2])
    return tuple(w), src.number(primary, "primary_nm", positive=True)


def _sensor_from_dict(src: Source, s: Any) -> Sensor:
    if s is None:
        return Sensor()
    src.keys(s, SENSOR_KEYS, "'sensor'")
    kw = {}
    if "pixel_pitch_um" in s:
        kw["pixel_pitch_um"] = src.number(s["pixel_pitch_um"], "sensor.pixel_pitch_um", positive=True)
    for k in ("width_px", "height_px"):
        if k in s:
            v = s[k]
            if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
                raise src.error(f"sensor.{k} must be a positive integer, got {v!r}")
            kw[k] = v
    return Sensor(**kw)


def _field_from_dict(src: Source, f: Any, lens: Lens) -> Lens:
    if f is None:
        return lens
    src.keys(f, FIELD_KEYS, "'field'")
    if len(f) != 1:
        raise src.error("'field' takes exactly one of half_fov_deg, image_height")
    if "half_fov_deg" in f:
        theta = src.number(f["half_fov_deg"], "field.half_fov_deg")
    else:
        from calibration.optics.paraxial import field_angle
        h = src.number(f["image_height"], "field.image_height", positive=True)
        try:
            theta = field_angle(lens, h)
        except LensError as e:
            raise src.error(str(e)) from None
    return src.replace(lens, half_fov_deg=theta)


def lens_to_dict(lens: Lens) -> dict:
    """The ``lens/v1`` dict of ``lens``: JSON-safe (no inf/NaN), exact floats.

    Raises
    ------
    LensError
        The aperture floats by stop size and no surface is marked as the stop
        (a file must name its stop; :func:`lens_from_dict` refuses it).

    >>> from calibration.optics.lens import Lens, Surface
    >>> d = lens_to_dict(Lens((Surface(curvature=0.1, thickness=5.0),), epd=2.0))
    >>> d["aperture"], d["surfaces"][0]["curvature"]
    ({'epd': 2.0}, 0.1)
    """
    out: dict = {"schema": SCHEMA}
    if lens.name:
        out["name"] = lens.name
    out["units"] = "mm"
    out["surfaces"] = [_surface_to_dict(s) for s in lens.surfaces]
    if lens.f_number is None and lens.epd is None:
        if not any(s.stop for s in lens.surfaces):
            raise LensError("the aperture floats by stop size but no surface is marked as the stop "
                            "(the model then takes surface 1); mark it, e.g. lens.with_surface(0, stop=True)")
        out["aperture"] = {"stop_semi_diameter": lens.surfaces[lens.stop_index].semi_diameter}
    else:
        out["aperture"] = {k: getattr(lens, k) for k in ("f_number", "epd") if getattr(lens, k) is not None}
    out["field"] = {"half_fov_deg": lens.half_fov_deg}
    out["wavelengths_nm"] = list(lens.wavelengths_nm)
    out["primary_nm"] = lens.primary_nm
    out["object_distance"] = None if math.isinf(lens.object_distance) else lens.object_distance
    out["sensor"] = {"pixel_pitch_um": lens.sensor.pixel_pitch_um, "width_px": lens.sensor.width_px,
                     "height_px": lens.sensor.height_px}
    out["metadata"] = dict(lens.metadata)
    return out


def _surface_to_dict(s: Surface) -> dict:
    d: dict = {}
    if s.name:
        d["name"] = s.name
    d["curvature"] = s.curvature
    d["conic"] = s.conic
    if s.asphere:
        d["aspheric"] = {str(order): a for order, a in s.asphere}
    d["thickness"] = s.thickness
    d["material"] = material_to_spec(s.material)
    if s.semi_diameter is not None:
        d["semi_diameter"] = s.semi_diameter
    if s.stop:
        d["stop"] = True
    return d


# -- files ----------------------------------------------------------------------

def load_lens(path) -> Lens:
    """Read a ``lens/v1`` JSON file.

    Raises
    ------
    LensError
        Unreadable, not JSON (e.g. truncated), or not a valid lens; the
        message starts with ``path``.
    """
    return lens_from_dict(read_json(path), str(path))


def save_lens(lens: Lens, path) -> Path:
    """Write ``lens`` as ``lens/v1`` JSON, atomically (a temporary file in the
    same folder, then a rename), and return the path."""
    path = Path(path)
    text = json.dumps(lens_to_dict(lens), indent=2, allow_nan=False, ensure_ascii=False) + "\n"
    from isp.io.files import write_bytes_atomic

    write_bytes_atomic(path, text.encode("utf-8"))
    return path

"""rayoptics lens files (``.roa``: ``OpticalModel.save_model``'s JSON).

Every object is ``{"__instance_type__": [module, class], "attributes":
{...}}``. The lens lives in ``optical_model.attributes``:

* ``seq_model.ifcs`` — the interfaces, object first and image last; a
  surface's shape is its ``profile`` (inline, or ``profile_id`` into
  ``profile_dict``): ``Spherical`` (``cv``), ``Conic`` (``cv``, ``cc``),
  ``EvenPolynomial`` (``cv``, ``cc`` or ``ec`` = cc + 1, ``coefs[i]`` on
  ρ^(2i+2)), ``RadialPolynomial`` (``cv``, ``ec`` = cc + 1, ``coefs[i]`` on
  ρ^(i+1), odd and even); pre-0.9.5 files keep the coefficients in
  ``coef2``…/``coef1``… instead. ``max_aperture`` (or a ``Circular`` clear
  aperture's ``radius``) is the semi-diameter.
* ``seq_model.gaps`` — ``gaps[i]`` follows ``ifcs[i]``: ``thi`` (mm) and
  ``medium``: ``Air``, ``ModelGlass`` (``n``, ``v``), a catalogue glass
  (``SchottGlass``, ``HikariGlass``, ... with ``gname``; SCHOTT entries carry
  their Sellmeier ``coefs`` B1, B2, B3, C1, C2, C3, used when the name is not
  in :mod:`calibration.optics.materials`), or ``ConstantIndex`` (``n``).
* ``seq_model.stop_surface`` — index of the stop in ``ifcs``.
* ``optical_spec`` — ``pupil`` (key ``aperture/object/epd`` or
  ``aperture/image/f/#`` and its ``value``), ``field_of_view`` (key
  ``field/object/angle`` or ``field/image/height``, ``value``,
  ``is_relative``, ``fields``), ``spectral_region`` (``wavelengths`` in nm,
  ``reference_wvl`` the primary's index).

An image-height field is converted to the angle paraxially (the specsheet
of rayoptics does the same); decentred interfaces, mirrors, thin lenses and
other interface kinds are refused.
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
from calibration.optics.materials import AIR, LAMBDA_D, Material, MaterialError, abbe_number, lookup, model_material

PROFILES = ("Spherical", "Conic", "EvenPolynomial", "RadialPolynomial")


def read_rayoptics(path, *, data=None, pixel_pitch_um: float | None = None) -> Lens:
    """Read a rayoptics ``.roa`` file.

    Parameters
    ----------
    path : str or Path
    data : dict, optional
        Its parsed content, if already read.
    pixel_pitch_um : float, optional
        Pixel pitch of the assumed sensor (:func:`default_sensor`).

    Raises
    ------
    LensError
        One line naming the file and the surface.
    """
    return read_json_lens(path, data, pixel_pitch_um, _build, "rayoptics")


def _cls(obj: dict) -> str:
    return obj.get("__instance_type__", ["", ""])[1]


def _module(obj: dict) -> str:
    return obj.get("__instance_type__", ["", ""])[0]


def _build(src: Source, d: dict, pixel_pitch_um) -> Lens:
    om = d["optical_model"]["attributes"]
    sm = om["seq_model"]["attributes"]
    ifcs, gaps = sm["ifcs"], sm["gaps"]
    if len(ifcs) < 3 or len(gaps) != len(ifcs) - 1:
        raise src.error(f"expected an object, surfaces and an image with a gap between each; "
                        f"found {len(ifcs)} interfaces and {len(gaps)} gaps")
    profiles = om.get("profile_dict", {})
    stop = sm.get("stop_surface")
    if stop is not None and not 0 < stop < len(ifcs) - 1:
        raise src.error(f"stop_surface {stop} is the object or the image")
    surfaces = tuple(_surface(src, ifcs[i], gaps[i], profiles, i, i == stop) for i in range(1, len(ifcs) - 1))

    spec = om["optical_spec"]["attributes"]
    f_number, epd = _aperture(src, spec["pupil"]["attributes"])
    wavelengths, primary = _wavelengths(src, spec.get("spectral_region", {}).get("attributes", {}))
    thi0 = src.number(gaps[0]["attributes"]["thi"], "object distance", allow_inf=True)
    conj = om.get("specsheet", {}).get("attributes", {}).get("conjugate_type")
    object_distance = math.inf if conj == "infinite" or thi0 >= 1e10 else thi0
    title = om.get("system_spec", {}).get("attributes", {}).get("title") or Path(src.label).stem
    lens = src.build(surfaces=surfaces, f_number=f_number, epd=epd, wavelengths_nm=wavelengths,
                     primary_nm=primary, object_distance=object_distance, name=title,
                     metadata={"source": {"format": "rayoptics", "file": Path(src.label).name,
                                          "version": om.get("ro_version", "")}})
    lens = src.replace(lens, half_fov_deg=_half_fov(src, spec.get("field_of_view", {}).get("attributes", {}),
                                                    lens))
    return lens.replace(sensor=default_sensor(lens, pixel_pitch_um or DEFAULT_PIXEL_PITCH_UM))


def _surface(src: Source, ifc: dict, gap: dict, profiles: dict, i: int, stop: bool) -> Surface:
    if _cls(ifc) != "Surface":
        raise src.error(f"interface kind {_cls(ifc)!r} is not supported (only Surface)", i)
    a = ifc["attributes"]
    if a.get("interact_mode", "transmit") not in ("transmit", "dummy"):
        raise src.error(f"interact_mode {a.get('interact_mode')!r} is not supported (refraction only)", i)
    if a.get("decenter"):
        raise src.error("decentred or tilted surfaces are not supported", i)
    prof = a.get("profile") or profiles.get(str(a.get("profile_id")))
    if prof is None:
        raise src.error(f"profile {a.get('profile_id')!r} is missing from profile_dict", i)
    c, conic, asphere = _profile(src, prof, i)
    sd = None
    for ca in a.get("clear_apertures") or []:
        if _cls(ca) != "Circular":
            raise src.error(f"clear aperture {_cls(ca)!r} is not supported (Circular)", i)
        sd = src.number(ca["attributes"]["radius"], "clear aperture radius", i, positive=True)
    if sd is None and a.get("max_aperture"):
        sd = src.number(a["max_aperture"], "max_aperture", i, positive=True)
    g = gap["attributes"]
    return Surface(curvature=c, conic=conic, asphere=asphere,
                   thickness=src.number(g["thi"], "gap thickness", i),
                   material=_medium(src, g["medium"], i), semi_diameter=sd, stop=stop,
                   name=a.get("label", "") or "")


def _profile(src: Source, prof: dict, i: int):
    kind = _cls(prof)
    if kind not in PROFILES:
        raise src.error(f"surface profile {kind!r} is not supported (supported: {', '.join(PROFILES)})", i)
    p = prof["attributes"]
    c = src.number(p.get("cv", 0.0), "cv", i)
    if "cc" in p:
        conic = src.number(p["cc"], "cc", i)
    elif "ec" in p:
        conic = src.number(p["ec"], "ec", i) - 1.0
    else:
        conic = 0.0
    terms = []
    if kind in ("EvenPolynomial", "RadialPolynomial"):
        even = kind == "EvenPolynomial"
        coefs = list(p.get("coefs") or [])
        if not any(coefs):  # pre-0.9.5 files: named coefficients
            names = [f"coef{2 * k}" for k in range(1, 11)] if even else [f"coef{k}" for k in range(1, 11)]
            coefs = [p.get(n, 0.0) for n in names]
        for k, v in enumerate(coefs):
            v = src.number(v, f"coefficient {k}", i)
            if v:
                terms.append((2 * (k + 1) if even else k + 1, v))
    return c, conic, tuple(terms)


def _medium(src: Source, m: dict, i: int) -> Material:
    kind, a = _cls(m), m.get("attributes", {})
    if kind == "Air":
        return AIR
    if kind == "ModelGlass":
        return model_material(src.number(a["n"], "ModelGlass n", i, positive=True),
                              src.number(a["v"], "ModelGlass v", i, positive=True))
    if kind in ("ConstantIndex", "Medium") and "n" in a:
        n = src.number(a["n"], "medium index", i, positive=True)
        return AIR if n == 1.0 else Material(a.get("label") or f"n={n:g}", n, math.inf, "constant")
    if kind.endswith("Glass") and "gname" in a:
        catalog = kind[:-len("Glass")].upper()
        try:
            return lookup(f"{catalog}:{a['gname']}")
        except MaterialError as e:
            coefs = a.get("coefs")
            if catalog == "SCHOTT" and isinstance(coefs, list) and len(coefs) == 6:
                b1, b2, b3, c1, c2, c3 = (src.number(v, "Sellmeier coefficient", i) for v in coefs)
                coef = (b1, c1, b2, c2, b3, c3)
                probe = Material(a["gname"], 1.0, math.inf, "sellmeier", coef, catalog="SCHOTT")
                return Material(a["gname"], probe.index(LAMBDA_D), abbe_number(probe), "sellmeier", coef,
                                catalog="SCHOTT")
            raise src.error(str(e), i) from None
    raise src.error(f"medium {_module(m)}.{kind} is not supported (Air, ModelGlass, ConstantIndex, "
                    "catalogue glasses)", i)


def _key(attrs: dict) -> tuple:
    return tuple(attrs.get("_key") or attrs.get("key") or ())


def _aperture(src: Source, p: dict):
    key = _key(p)
    value = src.number(p.get("value"), "pupil value", positive=True)
    if key[1:] in (("object", "epd"), ("object", "pupil")):
        return None, value
    if key[1:] == ("image", "f/#"):
        return value, None
    raise src.error(f"pupil specification {'/'.join(key)!r} is not supported "
                    "(aperture/object/epd, aperture/image/f/#)")


def _wavelengths(src: Source, w: dict):
    nm = w.get("wavelengths")
    if not nm:
        return default_wavelengths()
    nm = tuple(src.number(x, "wavelength", positive=True) for x in nm)
    ref = w.get("reference_wvl", len(nm) // 2)
    if not isinstance(ref, int) or not 0 <= ref < len(nm):
        raise src.error(f"reference_wvl {ref!r} names no wavelength (have {len(nm)})")
    return nm, nm[ref]


def _half_fov(src: Source, f: dict, lens: Lens) -> float:
    fields = f.get("fields") or []
    if not fields:
        return 0.0
    key = _key(f)
    xy = [(src.number(x["attributes"].get("x", 0.0), "field x"),
           src.number(x["attributes"].get("y", 0.0), "field y")) for x in fields]
    scale = src.number(f.get("value", 1.0), "field value") if f.get("is_relative") else 1.0
    if key[1:] == ("object", "angle"):
        return max(combined_field_angle(x * scale, y * scale) for x, y in xy)
    if key[1:] == ("image", "height"):
        from calibration.optics.paraxial import field_angle
        h = max(math.hypot(x, y) for x, y in xy) * scale
        try:
            theta = field_angle(lens, h)
        except LensError as e:
            raise src.error(str(e)) from None
        lens.metadata["field_conversion"] = (f"image height {h!r} mm converted to an angle paraxially "
                                             f"at {lens.primary_nm} nm")
        return theta
    raise src.error(f"field specification {'/'.join(key)!r} is not supported "
                    "(field/object/angle, field/image/height)")

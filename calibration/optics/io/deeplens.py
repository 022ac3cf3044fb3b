"""DeepLens lens files (the JSON of ``deeplens.GeoLens.write_lens_json``).

Layout: ``surfaces`` in order, each with ``type`` (``Spheric``,
``Aspheric``, ``Stop``/``Aperture``, ``Plane``), ``d`` — the **absolute**
axial position of the vertex (mm, the first usually 0) —, ``r`` — the
semi-diameter (mm) —, ``c`` (curvature, 1/mm) or ``roc`` (radius),
``k`` (conic) and ``ai`` (``[ai2, ai4, ...]`` on ρ², ρ⁴, ...) for
aspheres, and ``mat2``, the medium after the surface (a glass name such as
``n-sk16`` or ``f2``, ``air``, ``occluder`` behind a stop, or ``"nd/vd"``).
``d_sensor`` is the position of the image plane, ``r_sensor`` the sensor's
half-diagonal and ``sensor_size`` its width and height (mm); ``foclen``,
``fnum`` and ``hfov`` (radians) are DeepLens's own first-order figures.

The aperture is the ``Stop`` surface's ``r`` ("float by stop size"), as in
DeepLens. The half field of view is ``hfov`` if the file has it, else
DeepLens's own definition atan(r_sensor / foclen) with the file's ``foclen``,
else the paraxial angle whose image height is ``r_sensor``. DeepLens traces
the d line by default: the wavelengths are F, d, C with d primary.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from calibration.optics.io.common import (
    DEFAULT_PIXEL_PITCH_UM,
    Source,
    default_sensor,
    default_wavelengths,
    read_json_lens,
)
from calibration.optics.lens import Lens, LensError, Sensor, Surface
from calibration.optics.materials import AIR, model_material

TYPES = ("Spheric", "Aspheric", "Stop", "Aperture", "Plane")
_NV = re.compile(r"^\s*([0-9.]+)\s*/\s*([0-9.]+)\s*$")


def read_deeplens(path, *, data=None, pixel_pitch_um: float | None = None) -> Lens:
    """Read a DeepLens lens JSON file.

    Parameters
    ----------
    path : str or Path
    data : dict, optional
        Its parsed content, if already read.
    pixel_pitch_um : float, optional
        Pixel pitch (µm) when the file gives no ``sensor_res``; default 1.0.

    Raises
    ------
    LensError
        One line naming the file and the surface.
    """
    return read_json_lens(path, data, pixel_pitch_um, _build, "DeepLens")


def _build(src: Source, d: dict, pixel_pitch_um) -> Lens:
    raw = d["surfaces"]
    if not isinstance(raw, list) or not raw:
        raise src.error("'surfaces' must be a non-empty list")
    z = [src.number(s["d"], "d (vertex position)", i) for i, s in enumerate(raw, start=1)]
    z_image = src.number(d["d_sensor"], "d_sensor")
    ends = z[1:] + [z_image]
    surfaces = tuple(_surface(src, s, i, ends[i - 1] - z[i - 1]) for i, s in enumerate(raw, start=1))
    wavelengths, primary = default_wavelengths()
    lens = src.build(surfaces=surfaces, wavelengths_nm=wavelengths, primary_nm=primary,
                     name=d.get("name") or Path(src.label).stem,
                     metadata={"source": {"format": "deeplens", "file": Path(src.label).name,
                                          **{k: d[k] for k in ("foclen", "fnum", "hfov", "r_sensor")
                                             if k in d}}})
    lens = src.replace(lens, half_fov_deg=_half_fov(src, d, lens))
    return lens.replace(sensor=_sensor(src, d, lens, pixel_pitch_um))


def _surface(src: Source, s: dict, i: int, thickness: float) -> Surface:
    kind = s.get("type")
    if kind not in TYPES:
        raise src.error(f"surface type {kind!r} is not supported (supported: {', '.join(TYPES)})", i)
    sd = src.number(s["r"], "r (semi-diameter)", i, positive=True)
    stop = kind in ("Stop", "Aperture")
    c = 0.0
    if not stop and kind != "Plane":
        if "c" in s:
            c = src.number(s["c"], "c (curvature)", i)
        elif "roc" in s:
            roc = src.number(s["roc"], "roc (radius)", i, allow_inf=True)
            c = 0.0 if roc == 0 or math.isinf(roc) else 1.0 / roc
        else:
            raise src.error("needs 'c' (curvature) or 'roc' (radius)", i)
    asphere = ()
    conic = 0.0
    if kind == "Aspheric":
        conic = src.number(s.get("k", 0.0), "k (conic)", i)
        ai = s.get("ai") or []
        if not isinstance(ai, list):
            raise src.error(f"'ai' must be a list [ai2, ai4, ...], got {ai!r}", i)
        asphere = tuple((2 * (j + 1), src.number(a, f"ai{2 * (j + 1)}", i)) for j, a in enumerate(ai) if a != 0)
    return Surface(curvature=c, conic=conic, asphere=asphere, thickness=thickness,
                   material=_material(src, s.get("mat2", "air"), i), semi_diameter=sd, stop=stop)


def _material(src: Source, name, i: int):
    if not isinstance(name, str):
        raise src.error(f"mat2 must be a material name, got {name!r}", i)
    if name.strip().lower() in ("air", "vacuum", "occluder"):
        return AIR
    m = _NV.match(name)
    if m:
        return model_material(float(m.group(1)), float(m.group(2)))
    return src.material(name, i)


def _half_fov(src: Source, d: dict, lens: Lens) -> float:
    if "hfov" in d:
        return math.degrees(src.number(d["hfov"], "hfov (radians)"))
    if "r_sensor" not in d:
        return 0.0
    r = src.number(d["r_sensor"], "r_sensor", positive=True)
    if "foclen" in d:
        return math.degrees(math.atan(r / src.number(d["foclen"], "foclen", positive=True)))
    from calibration.optics.paraxial import field_angle
    try:
        return field_angle(lens, r)
    except LensError as e:
        raise src.error(str(e)) from None


def _sensor(src: Source, d: dict, lens: Lens, pixel_pitch_um) -> Sensor:
    size = d.get("sensor_size")
    if size is None:
        return default_sensor(lens, pixel_pitch_um or DEFAULT_PIXEL_PITCH_UM)
    w, h = (src.number(v, "sensor_size", positive=True) for v in size)
    res = d.get("sensor_res")
    if res is not None:
        pitch = w / src.number(res[0], "sensor_res", positive=True) * 1e3
    else:
        pitch = pixel_pitch_um or DEFAULT_PIXEL_PITCH_UM
    return Sensor(pixel_pitch_um=pitch, width_px=max(1, round(w * 1e3 / pitch)),
                  height_px=max(1, round(h * 1e3 / pitch)))

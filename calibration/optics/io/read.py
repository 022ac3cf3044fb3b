"""Reading a lens from any supported file: :func:`read_lens` chooses the
reader by file type.

* :func:`~calibration.optics.io.lens_json.load_lens`: the project's
  ``lens/v1`` JSON;
* :func:`~calibration.optics.io.zmx.read_zmx`: Zemax OpticStudio sequential
  ``.zmx`` (text, UTF-8 or UTF-16 with or without BOM);
* :func:`~calibration.optics.io.optiland.read_optiland`: optiland
  ``Optic.to_dict()`` JSON;
* :func:`~calibration.optics.io.deeplens.read_deeplens`: DeepLens
  ``GeoLens`` JSON;
* :func:`~calibration.optics.io.rayoptics.read_rayoptics`: rayoptics
  ``.roa`` (its JSON save format).

Every reader raises :class:`~calibration.optics.lens.LensError` with one
line naming the file and, where it applies, the surface (numbered as the
lens model numbers them: the first surface after the object is surface 1,
as in Zemax). Files that carry no sensor get
:func:`calibration.optics.io.common.default_sensor`.

Imports every reader of :mod:`calibration.optics.io`; none imports this
module.
"""

from __future__ import annotations

from pathlib import Path

from calibration.optics.io.common import Source, read_json
from calibration.optics.io.deeplens import read_deeplens
from calibration.optics.io.lens_json import lens_from_dict
from calibration.optics.io.optiland import read_optiland
from calibration.optics.io.rayoptics import read_rayoptics
from calibration.optics.io.zmx import read_zmx
from calibration.optics.lens import Lens, LensError, Sensor

__all__ = ["FORMATS", "read_lens"]


FORMATS = ("lens/v1 JSON", "Zemax .zmx", "optiland JSON", "DeepLens JSON", "rayoptics .roa")


def read_lens(path, *, sensor: Sensor | None = None, pixel_pitch_um: float | None = None) -> Lens:
    """Read a lens from any supported file, choosing the reader by file type.

    ``.zmx`` → :func:`~calibration.optics.io.zmx.read_zmx`; ``.roa`` →
    :func:`~calibration.optics.io.rayoptics.read_rayoptics`; ``.json`` → by content:
    ``lens/v1`` (a ``"schema"`` key), rayoptics (``"optical_model"``),
    optiland (``"surface_group"``), DeepLens (``"surfaces"`` with
    ``"d_sensor"``).

    Parameters
    ----------
    path : str or Path
    sensor : Sensor, optional
        Replaces the file's (or the default) sensor.
    pixel_pitch_um : float, optional
        Pixel pitch (µm) of the default sensor given to files without one
        (see :func:`calibration.optics.io.common.default_sensor`); default 1.0.

    Raises
    ------
    LensError
        A missing or unreadable file, an unsupported file type or an
        invalid file; one line that starts with (or names) the file.
    """
    src = Source(str(path))
    try:
        lens = _read(src, path, {} if pixel_pitch_um is None else {"pixel_pitch_um": pixel_pitch_um})
    except LensError as e:
        if str(path) in str(e):
            raise
        raise src.error(str(e)) from None
    if sensor is not None:
        lens = lens.replace(sensor=sensor)
    return lens


def _read(src: Source, path, pitch: dict) -> Lens:
    suffix = Path(path).suffix.lower()
    if suffix == ".zmx":
        lens = read_zmx(path, **pitch)
    elif suffix == ".roa":
        lens = read_rayoptics(path, **pitch)
    elif suffix == ".json":
        data = read_json(path)
        if isinstance(data, dict) and "schema" in data:
            lens = lens_from_dict(data, str(path))
        elif isinstance(data, dict) and "optical_model" in data:
            lens = read_rayoptics(path, data=data, **pitch)
        elif isinstance(data, dict) and "surface_group" in data:
            lens = read_optiland(path, data=data, **pitch)
        elif isinstance(data, dict) and "surfaces" in data and "d_sensor" in data:
            lens = read_deeplens(path, data=data, **pitch)
        else:
            raise src.error("unrecognised JSON lens file (expected one of: " + ", ".join(FORMATS) + ")")
    else:
        raise src.error(f"unsupported lens file type {suffix or '(none)'!r} (supported: .json, .zmx, .roa)")
    return lens

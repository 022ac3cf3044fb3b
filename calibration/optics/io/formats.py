"""Readers of other programs' lens files, each returning a
:class:`~calibration.optics.lens.Lens`.

=====================  =======================================================
:func:`read_zmx`       Zemax OpticStudio sequential ``.zmx`` (text, UTF-8 or
                       UTF-16 with or without BOM)
:func:`read_optiland`  optiland ``Optic.to_dict()`` JSON
:func:`read_deeplens`  DeepLens ``GeoLens`` JSON
:func:`read_rayoptics` rayoptics ``.roa`` (its JSON save format)
=====================  =======================================================

:func:`calibration.optics.io.lens_json.read_lens` chooses among them by file type. Every
reader raises :class:`~calibration.optics.lens.LensError` with one line naming the
file and, where it applies, the surface (numbered as the lens model numbers
them: the first surface after the object is surface 1, as in Zemax).

Files that carry no sensor get :func:`default_sensor`.
"""

from __future__ import annotations

import math

from calibration.optics.lens import Lens, Sensor

DEFAULT_PIXEL_PITCH_UM = 1.0
"""Pixel pitch (µm) of :func:`default_sensor` when the caller gives none."""


def default_sensor(lens: Lens, pixel_pitch_um: float = DEFAULT_PIXEL_PITCH_UM,
                   aspect: tuple[int, int] = (4, 3)) -> Sensor:
    """The sensor assumed for a lens file that names none.

    A 4:3 sensor whose half-diagonal is the paraxial image height at the
    lens's full field (:func:`calibration.optics.paraxial.image_height` at
    ``lens.half_fov_deg``), with ``pixel_pitch_um`` pixels (1.0 µm unless
    given). Without a field, the model's default :class:`Sensor` at that
    pitch.

    Returns
    -------
    Sensor
        Width and height in whole pixels (rounded).
    """
    if pixel_pitch_um is None or not pixel_pitch_um > 0 or not math.isfinite(pixel_pitch_um):
        raise ValueError(f"pixel_pitch_um must be positive, got {pixel_pitch_um!r}")
    if not lens.half_fov_deg:
        return Sensor(pixel_pitch_um=pixel_pitch_um)
    from calibration.optics.paraxial import image_height

    half_diag = abs(image_height(lens, lens.half_fov_deg))
    aw, ah = aspect
    diag = math.hypot(aw, ah)
    width_mm, height_mm = 2 * half_diag * aw / diag, 2 * half_diag * ah / diag
    return Sensor(pixel_pitch_um=pixel_pitch_um,
                  width_px=max(1, round(width_mm * 1e3 / pixel_pitch_um)),
                  height_px=max(1, round(height_mm * 1e3 / pixel_pitch_um)))


def read_json_lens(path, data, pixel_pitch_um, build, kind: str):
    """Shared body of the JSON importers: parse (unless ``data`` is given),
    build, and turn a structural surprise into one LensError line naming the
    file."""
    from calibration.optics.io.lens_json import Source, _read_json

    src = Source(str(path))
    d = _read_json(path) if data is None else data
    try:
        return build(src, d, pixel_pitch_um)
    except (KeyError, TypeError, IndexError, AttributeError) as e:
        raise src.error(f"not a {kind} lens file ({type(e).__name__}: {e})") from None


def default_wavelengths() -> tuple[tuple[float, ...], float]:
    """(wavelengths, primary) in nm for a file that names none: the
    :class:`~calibration.optics.lens.Lens` defaults (F, d, C lines; d primary)."""
    fields = Lens.__dataclass_fields__
    return fields["wavelengths_nm"].default, fields["primary_nm"].default


def combined_field_angle(x_deg: float, y_deg: float) -> float:
    """Field angle (degrees) from the axis of a field given by its x and y
    angles (degrees): atan(√(tan²x + tan²y)).

    >>> combined_field_angle(0.0, 36.8)
    36.8
    """
    if x_deg == 0 or y_deg == 0:
        return abs(x_deg) + abs(y_deg)
    return math.degrees(math.atan(math.hypot(math.tan(math.radians(x_deg)), math.tan(math.radians(y_deg)))))


from calibration.optics.io.deeplens import read_deeplens  # noqa: E402
from calibration.optics.io.optiland import read_optiland  # noqa: E402
from calibration.optics.io.rayoptics import read_rayoptics  # noqa: E402
from calibration.optics.io.zmx import read_zmx  # noqa: E402

__all__ = ["DEFAULT_PIXEL_PITCH_UM", "combined_field_angle", "default_sensor", "default_wavelengths",
           "read_deeplens", "read_optiland", "read_rayoptics", "read_zmx"]

"""What every lens-file reader shares: error messages that name the file
(:class:`Source`), JSON reading, and the defaults for what a file leaves out
(sensor, wavelengths, combined field angle).

The readers (:mod:`~calibration.optics.io.lens_json`,
:mod:`~calibration.optics.io.zmx`, :mod:`~calibration.optics.io.optiland`,
:mod:`~calibration.optics.io.rayoptics`, :mod:`~calibration.optics.io.deeplens`)
import this module; it imports none of them.

Imports :mod:`calibration.optics` (lens, materials, paraxial).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from calibration.optics.lens import Lens, LensError, Sensor
from calibration.optics.materials import MaterialError, material

__all__ = ["DEFAULT_PIXEL_PITCH_UM", "Source", "combined_field_angle", "default_sensor", "default_wavelengths",
           "read_json", "read_json_lens"]


class Source:
    """Error messages for one input: ``"<file>: surface <i>: <what>"``.

    Parameters
    ----------
    label : str
        The file as the caller named it (or ``"<dict>"``).
    """

    def __init__(self, label: str):
        self.label = str(label)

    def error(self, message: str, surface: int | None = None) -> LensError:
        """A :class:`LensError`; ``surface`` is the 1-based surface number."""
        where = f"surface {surface}: " if surface is not None else ""
        return LensError(f"{self.label}: {where}{message}")

    def number(self, value: Any, what: str, surface: int | None = None, *,
               positive: bool = False, allow_inf: bool = False) -> float:
        """``value`` as a float, or a LensError naming ``what``."""
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(f"{what} must be a number, got {value!r}", surface)
        v = float(value)
        if math.isnan(v) or (math.isinf(v) and not allow_inf):
            raise self.error(f"{what} must be finite, got {value!r}", surface)
        if positive and not v > 0:
            raise self.error(f"{what} must be positive, got {value!r}", surface)
        return v

    def keys(self, d: Any, valid: tuple[str, ...], what: str, surface: int | None = None) -> dict:
        """Check that ``d`` is an object with only ``valid`` keys."""
        if not isinstance(d, dict):
            raise self.error(f"{what} must be a JSON object, got {d!r}", surface)
        unknown = [k for k in d if k not in valid]
        if unknown:
            raise self.error(f"unknown key {unknown[0]!r} in {what} (valid: {', '.join(valid)})", surface)
        return d

    def material(self, spec: Any, surface: int | None = None):
        try:
            return material(spec)
        except MaterialError as e:
            raise self.error(str(e), surface) from None

    def replace(self, lens: Lens, **changes) -> Lens:
        """``lens.replace(**changes)`` with validation errors prefixed by the
        file name."""
        try:
            return lens.replace(**changes)
        except LensError as e:
            raise self.error(str(e)) from None

    def build(self, **kwargs) -> Lens:
        """``Lens(**kwargs)`` with the model's own validation errors prefixed
        by the file name."""
        try:
            return Lens(**kwargs)
        except LensError as e:
            raise self.error(str(e)) from None


def read_json(path) -> Any:
    """The parsed JSON of a lens file (UTF-8, a BOM allowed).

    Raises
    ------
    LensError
        Unreadable, not UTF-8, or not JSON; one line starting with ``path``.
    """
    src = Source(str(path))
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except OSError as e:
        raise src.error(f"cannot read: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        raise src.error(f"not UTF-8 text ({e.reason} at byte {e.start})") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise src.error(f"not valid JSON ({e.msg} at line {e.lineno} column {e.colno})") from None


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


def read_json_lens(path, data, pixel_pitch_um, build, kind: str) -> Lens:
    """Shared body of the JSON importers: parse (unless ``data`` is given),
    build, and turn a structural surprise into one LensError line naming the
    file.

    Parameters
    ----------
    path : str or Path
        The file (read unless ``data`` is given; named in messages).
    data : object or None
        Its parsed JSON, if the caller has it.
    pixel_pitch_um : float or None
        Passed to ``build``.
    build : callable
        ``build(source, data, pixel_pitch_um) -> Lens``.
    kind : str
        The format's name, for the message ("optiland").
    """
    src = Source(str(path))
    d = read_json(path) if data is None else data
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

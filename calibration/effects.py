"""Physical effects the base model may lack, as plug-ins (the loop closure's
registry).

An effect adds a few parameters and changes the predicted SFR in one of
three ways, each with a physical reason:

* ``defocus_mm(x, geom)`` — moves the image plane at every node (focus
  shift, a tilted sensor, a curved field): the PSFs are recomputed from the
  same traced rays;
* ``shifts_px(x, geom)`` — moves each colour's PSF sideways (lateral
  colour): changes what a mixed-colour ("L") edge measures;
* ``transfer(x, geom)`` — multiplies the SFR by a transfer function of the
  sensor or the processing (crosstalk, sharpening, glare).

``geom`` describes the observations and nodes (:class:`Geometry`).
Registry: :func:`register_effect` (a decorator, like timm's
``register_model``) and the ``calib.effects`` entry-point group for other
packages; :func:`create_effect` builds one by name, :func:`list_effects`
lists them.

Example
-------
>>> sorted(list_effects())[:3]
['field_curvature', 'focus_shift', 'lateral_ca']
>>> e = create_effect("sensor_tilt")
>>> e.names, e.units
(('tilt_x_deg', 'tilt_y_deg'), ('degree', 'degree'))
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib.metadata import entry_points

import numpy as np

__all__ = ["Effect", "Geometry", "create_effect", "list_effects", "register_effect"]

ENTRY_POINT_GROUP = "calib.effects"
_REGISTRY: dict[str, type] = {}


def register_effect(cls):
    """Class decorator: make an :class:`Effect` subclass available by its
    ``name``."""
    if not getattr(cls, "name", None):
        raise TypeError(f"{cls.__name__} needs a `name`")
    _REGISTRY[cls.name] = cls
    return cls


def _load_entry_points() -> None:
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name not in _REGISTRY:
            try:
                register_effect(ep.load())
            except Exception as e:    # a broken plug-in must not break the loop: say so
                import warnings

                warnings.warn(f"effect plug-in {ep.name!r} failed to load: {e}", stacklevel=2)


def list_effects() -> dict[str, str]:
    """name → one-line description of every registered effect."""
    _load_entry_points()
    return {n: (c.__doc__ or "").strip().splitlines()[0] for n, c in sorted(_REGISTRY.items())}


def create_effect(name: str) -> "Effect":
    """An effect by registered name."""
    _load_entry_points()
    try:
        return _REGISTRY[name]()
    except KeyError:
        raise KeyError(f"unknown effect {name!r}; registered: {', '.join(sorted(_REGISTRY))}") from None


@dataclass(frozen=True, eq=False)
class Geometry:
    """What effects need to know about the observations and nodes.

    ``x_mm``, ``y_mm``: node positions on the image plane (y down);
    ``node_r``: their field radius normalised to the corner; ``normal_deg``
    (N,), ``freq`` (F,), ``channel`` (N,) of the observations; ``obs_r``
    (N,) normalised radius; ``obs_xy`` (N, 2) offsets from the centre in
    pixels, ``half_diag_px`` the centre-to-corner distance; ``channels``:
    the model's colour channels."""

    x_mm: np.ndarray
    y_mm: np.ndarray
    node_r: np.ndarray
    normal_deg: np.ndarray
    freq: np.ndarray
    channel: np.ndarray
    obs_r: np.ndarray
    obs_xy: np.ndarray
    channels: tuple
    half_diag_px: float


class Effect:
    """Base class: ``names``, ``units``, ``x0``, ``lower``, ``upper``,
    ``scale`` (a typical magnitude, for steps) and the hooks (module
    docstring); hooks return None where the effect has no such action."""

    name = ""
    names: tuple = ()
    units: tuple = ()
    x0: tuple = ()
    lower: tuple = ()
    upper: tuple = ()
    scale: tuple = ()

    def defocus_mm(self, x, geom: Geometry):
        return None

    def shifts_px(self, x, geom: Geometry):
        return None

    def transfer(self, x, geom: Geometry):
        return None

    def describe(self, x) -> str:
        return ", ".join(f"{n} = {v:.4g} {u}" for n, v, u in zip(self.names, x, self.units))


# -- optics: where the image plane is --------------------------------------------------------

@register_effect
class FocusShift(Effect):
    """Focus shift: the whole sensor sits Δz from the model's image plane."""

    name = "focus_shift"
    names, units = ("dz_um",), ("µm",)
    x0, lower, upper, scale = (0.0,), (-40.0,), (40.0,), (3.0,)

    def defocus_mm(self, x, geom):
        return np.full(len(geom.x_mm), 1e-3 * x[0])


@register_effect
class SensorTilt(Effect):
    """Sensor tilt: the image plane tilted about x and y (defocus linear in
    position)."""

    name = "sensor_tilt"
    names, units = ("tilt_x_deg", "tilt_y_deg"), ("degree", "degree")
    x0, lower, upper, scale = (0.0, 0.0), (-1.0, -1.0), (1.0, 1.0), (0.05, 0.05)

    def defocus_mm(self, x, geom):
        # a tilt about the x axis moves the plane along z in proportion to y
        return geom.y_mm * math.tan(math.radians(x[0])) + geom.x_mm * math.tan(math.radians(x[1]))


@register_effect
class FieldCurvature(Effect):
    """Field curvature: defocus growing with the square of the field radius
    (a Petzval surface the design did not flatten, or a bent sensor)."""

    name = "field_curvature"
    names, units = ("dz_corner_um",), ("µm",)
    x0, lower, upper, scale = (0.0,), (-40.0,), (40.0,), (3.0,)

    def defocus_mm(self, x, geom):
        return 1e-3 * x[0] * geom.node_r ** 2


@register_effect
class LateralCA(Effect):
    """Lateral chromatic aberration: R and B magnified differently from G
    (shift ∝ field radius); seen only on edges that mix colours."""

    name = "lateral_ca"
    names, units = ("red_px_at_corner", "blue_px_at_corner"), ("px", "px")
    x0, lower, upper, scale = (0.0, 0.0), (-5.0, -5.0), (5.0, 5.0), (0.3, 0.3)

    def shifts_px(self, x, geom):
        n = len(geom.obs_r)
        out = np.zeros((n, len(geom.channels), 2))
        radial = geom.obs_xy / geom.half_diag_px        # 1 at the corner
        for c, k in (("R", x[0]), ("B", x[1])):
            if c in geom.channels:
                out[:, geom.channels.index(c)] = k * radial
        return out


# -- sensor and processing: transfer functions ------------------------------------------------

@register_effect
class PixelCrosstalk(Effect):
    """Pixel crosstalk / sensor MTF: a share c of each pixel's charge leaks
    to each 4-neighbour (transfer (1 − 2c + 2c·cos 2πf_x)(…f_y))."""

    name = "pixel_crosstalk"
    names, units = ("leak",), ("fraction",)
    x0, lower, upper, scale = (0.0,), (0.0,), (0.2,), (0.02,)

    def transfer(self, x, geom):
        c = x[0]
        t = np.radians(geom.normal_deg)[:, None]
        f = geom.freq[None, :]
        return np.abs((1 - 2 * c + 2 * c * np.cos(2 * np.pi * f * np.cos(t)))
                      * (1 - 2 * c + 2 * c * np.cos(2 * np.pi * f * np.sin(t))))


@register_effect
class Sharpening(Effect):
    """Sharpening in the measurement chain: an unsharp mask of gain k and
    Gaussian radius σ (transfer 1 + k·(1 − exp(−2π²σ²f²)))."""

    name = "sharpening"
    names, units = ("gain", "sigma_px"), ("—", "px")
    x0, lower, upper, scale = (0.0, 1.0), (0.0, 0.4), (3.0, 4.0), (0.1, 0.2)

    def transfer(self, x, geom):
        k, s = x
        f = geom.freq[None, :]
        return np.broadcast_to(1.0 + k * (1.0 - np.exp(-2.0 * np.pi ** 2 * s ** 2 * f ** 2)),
                               (len(geom.normal_deg), len(geom.freq)))


@register_effect
class VeilingGlare(Effect):
    """Veiling glare: a share g of the light spread far beyond the ROI
    (the SFR above the lowest frequencies falls to 1 − g)."""

    name = "veiling_glare"
    names, units = ("share",), ("fraction",)
    x0, lower, upper, scale = (0.0,), (0.0,), (0.5,), (0.02,)

    #: transfer of the halo itself: gone by ~0.02 cycles/pixel (wider than an ROI)
    HALO_F = 0.01

    def transfer(self, x, geom):
        g = x[0]
        f = geom.freq[None, :]
        return np.broadcast_to((1.0 - g) + g * np.exp(-(f / self.HALO_F) ** 2),
                               (len(geom.normal_deg), len(geom.freq)))

"""Physical effects the base model may lack, as plug-ins (the loop closure's
registry).

An effect adds a few parameters and changes the predicted SFR in one of
three ways, each with a physical reason:

* ``defocus_mm(x, geom)`` — moves the image plane at every node (focus
  shift, a tilted sensor, a curved field), (K,), or each colour's
  separately (longitudinal colour), (K, C) in ``geom.channels``' order:
  the PSFs are recomputed from the same traced rays;
* ``shifts_px(x, geom)`` — moves each colour's PSF sideways (lateral
  colour): changes what a mixed-colour ("L") edge measures;
* ``transfer(x, geom)`` — multiplies the SFR by a transfer function of the
  sensor, the processing or the exposure (crosstalk, sharpening, glare,
  motion blur).

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
import numpy as np

from isp.registry import Registry

__all__ = ["ROI_ACROSS_PX", "Effect", "Geometry", "create_effect", "list_effects", "register_effect"]

ENTRY_POINT_GROUP = "calib.effects"


def _check_entry(name: str, cls) -> type:
    if not getattr(cls, "name", None):
        raise TypeError(f"{getattr(cls, '__name__', cls)!r} needs a `name`")
    return cls


#: the effect classes by name
EFFECTS = Registry("effect", ENTRY_POINT_GROUP, check=_check_entry)


def register_effect(cls):
    """Class decorator: make an :class:`Effect` subclass available by its
    ``name``."""
    if not getattr(cls, "name", None):
        raise TypeError(f"{cls.__name__} needs a `name`")
    return EFFECTS.add(cls.name, cls)


def list_effects() -> dict[str, str]:
    """name → one-line description of every registered effect. A plug-in
    that failed to load is named in a warning (the loop runs without it)."""
    entries = EFFECTS.entries()
    for name, why in EFFECTS.broken().items():
        import warnings

        warnings.warn(f"effect plug-in {name!r} failed to load: {why}", stacklevel=2)
    return {n: (c.__doc__ or "").strip().splitlines()[0] for n, c in entries.items()}


def create_effect(name: str) -> "Effect":
    """An effect by registered name (:class:`isp.errors.ConfigError` for an
    unknown one, listing the registered names)."""
    return EFFECTS.get(name)()


@dataclass(frozen=True, eq=False)
class Geometry:
    """What effects need to know about the observations and nodes.

    ``x_mm``, ``y_mm``: node positions on the image plane (y down);
    ``node_r``: their field radius normalised to the corner; ``normal_deg``
    (N,), ``freq`` (F,), ``channel`` (N,) of the observations; ``obs_r``
    (N,) normalised radius; ``obs_xy`` (N, 2) offsets from the centre in
    pixels, ``half_diag_px`` the centre-to-corner distance; ``channels``:
    the model's colour channels; ``roi_across_px`` (N,): each edge ROI's
    extent across the edge, pixels — the length of the LSF record the SFR
    was computed over (None: unknown, :data:`ROI_ACROSS_PX` assumed)."""

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
    roi_across_px: np.ndarray | None = None


#: LSF record length assumed where the observations carry no ROI, pixels
ROI_ACROSS_PX = 64.0


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
    #: further start points for the fit besides ``x0`` — for an effect whose
    #: response is flat at ``x0`` (|Δz| of a uniform defocus) and which the
    #: base may have absorbed already (a uniform blur): the fit from x0 alone
    #: stalls there
    starts: tuple = ()

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
    starts = ((6.0,), (-6.0,))

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
    (shift ∝ field radius); seen only on edges that mix colours.

    An "L" edge's transfer is |Σ_c w_c exp(−2πi f d_c)| (d_c: channel c's
    shift along the normal, w_c its luminance weight): to second order the
    SFR falls by 2π²f²·s², s² = Σ w_c d_c² − (Σ w_c d_c)² the weighted
    spread of the colour planes. SFRs therefore determine that spread, not R
    and B apart (B weighs 0.07), and never the overall sign (a modulus):
    edge positions per channel would be needed for those."""

    name = "lateral_ca"
    names, units = ("red_px_at_corner", "blue_px_at_corner"), ("px", "px")
    x0, lower, upper, scale = (0.0, 0.0), (-5.0, -5.0), (5.0, 5.0), (0.3, 0.3)
    # the SFR falls with the square of the spread: flat at x0, so the fit also starts from a
    # spread (one sign each way; the overall sign is not seen). From x0 alone the fit stays at
    # zero, and a spread of 0.6–0.8 px at the corner is named field curvature instead
    # (benchmarks/detection_limits.py)
    starts = ((0.5, 0.5), (0.5, -0.5))

    def shifts_px(self, x, geom):
        if not np.any(np.asarray(geom.channel) == "L") or not ({"R", "B"} & set(geom.channels)):
            return None             # no edge mixes colours: nothing to see (and nothing to recompute)
        n = len(geom.obs_r)
        out = np.zeros((n, len(geom.channels), 2))
        radial = geom.obs_xy / geom.half_diag_px        # 1 at the corner
        for c, k in (("R", x[0]), ("B", x[1])):
            if c in geom.channels:
                out[:, geom.channels.index(c)] = k * radial
        return out


@register_effect
class LongitudinalCA(Effect):
    """Longitudinal chromatic aberration: R and B focus Δz from G (a glass
    or an IR-cut filter off its design), the same at every field position.

    Each colour's PSFs are traced at its own image plane. Separate R, G and
    B edges see it as one defocus per colour, which no achromatic effect
    gives; a mixed ("L") edge sees its colours' blurs averaged. G is the
    reference (a focus shift of all three is ``focus_shift``); without R or
    B observations it is not seen. The blur of a small Δz is even in Δz, so
    the fit starts from both signs."""

    name = "longitudinal_ca"
    names, units = ("red_dz_um", "blue_dz_um"), ("µm", "µm")
    x0, lower, upper, scale = (0.0, 0.0), (-40.0, -40.0), (40.0, 40.0), (3.0, 3.0)
    starts = ((6.0, 6.0), (-6.0, -6.0), (6.0, -6.0), (-6.0, 6.0))

    def defocus_mm(self, x, geom):
        if not {"R", "B"} & set(geom.channels):
            return None
        out = np.zeros((len(geom.x_mm), len(geom.channels)))
        for c, dz in (("R", x[0]), ("B", x[1])):
            if c in geom.channels:
                out[:, geom.channels.index(c)] = 1e-3 * dz
        return out


# -- sensor and processing: transfer functions ------------------------------------------------

@register_effect
class PixelCrosstalk(Effect):
    """Pixel crosstalk / sensor MTF: a share c of each pixel's charge leaks
    to each 4-neighbour (kernel [[0, c, 0], [c, 1 − 4c, c], [0, c, 0]],
    transfer 1 − 2c(1 − cos 2πf_x) − 2c(1 − cos 2πf_y), f_x, f_y the
    frequency's components along the pixel axes)."""

    name = "pixel_crosstalk"
    names, units = ("leak",), ("fraction",)
    x0, lower, upper, scale = (0.0,), (0.0,), (0.2,), (0.02,)

    def transfer(self, x, geom):
        c = x[0]
        t = np.radians(geom.normal_deg)[:, None]
        f = geom.freq[None, :]
        return np.abs(1 - 2 * c * (1 - np.cos(2 * np.pi * f * np.cos(t)))
                      - 2 * c * (1 - np.cos(2 * np.pi * f * np.sin(t))))


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
class MotionBlur(Effect):
    """Motion blur: the camera or the chart moved L px along a direction θ
    during the exposure (a test station's vibration, a conveyor).

    The blur is a segment of length L along θ (θ from the x axis, y down):
    an edge whose normal points at φ sees a box of L·|cos(φ − θ)| across it,
    transfer |sinc(f·L·cos(φ − θ))| (sinc(u) = sin πu / πu). The same at
    every field position and turning with the edge's orientation, which no
    lens perturbation does: a lens's blur turns with the field angle. θ and
    θ + 180° are one blur."""

    name = "motion_blur"
    names, units = ("length_px", "angle_deg"), ("px", "degree")
    x0, lower, upper, scale = (1.0, 0.0), (0.0, -90.0), (20.0, 90.0), (0.5, 10.0)
    starts = ((1.0, 60.0), (1.0, -60.0))

    def transfer(self, x, geom):
        length, theta = float(x[0]), math.radians(float(x[1]))
        across = length * np.abs(np.cos(np.radians(geom.normal_deg) - theta))
        return np.abs(np.sinc(across[:, None] * geom.freq[None, :]))


@register_effect
class VeilingGlare(Effect):
    """Veiling glare: a share g of the light in a wide halo (Gaussian of σ_h
    px), seen through the ISO LSF record window — a low-frequency shelf.

    The slanted-edge SFR is normalised at DC by the *windowed* LSF over the
    ROI: halo light beyond the record is simply not seen, and the part
    inside is weighted by the record window (sfrmat5: a Hann over the whole
    record, centred on the LSF peak). So the measured SFR is

        SFR(f) = core(f) · |(1 − g) + g·Ĥ_w(f)| / ((1 − g) + g·Ĥ_w(0)),
        Ĥ_w(f) = ∫ h(u) w(u) cos(2πfu) du,

    h the halo's LSF (unit area), w the record window over the ROI's extent
    across the edge (:attr:`Geometry.roi_across_px`). Above the halo's
    frequencies the SFR sits at (1 − g)/((1 − g) + g·Ĥ_w(0)): for σ_h = 20 px
    in a 64-px ROI about half of g. A halo much wider than the ROI only
    offsets the ROI and leaves the SFR unchanged (so glare far wider than
    the ROI is not measurable here; σ_h is bounded accordingly)."""

    name = "veiling_glare"
    names, units = ("share", "halo_sigma_px"), ("fraction", "px")
    x0, lower, upper, scale = (0.0, 12.0), (0.0, 2.0), (0.5, 40.0), (0.02, 3.0)

    #: sampling of the halo's LSF across the record, px
    STEP_PX = 0.25

    @classmethod
    def seen(cls, sigma_px: float, across_px: float, freq) -> np.ndarray:
        """Ĥ_w(f) (F,): the halo's LSF (unit area) windowed by the Hann
        record window of ``across_px``, transformed at ``freq``."""
        half = 0.5 * float(across_px)
        u = np.arange(-half, half + 1e-9, cls.STEP_PX)
        h = np.exp(-0.5 * (u / sigma_px) ** 2) / (math.sqrt(2.0 * math.pi) * sigma_px) * cls.STEP_PX
        w = 0.5 + 0.5 * np.cos(np.pi * u / half)
        return np.cos(2.0 * np.pi * np.asarray(freq, float)[:, None] * u[None, :]) @ (h * w)

    def transfer(self, x, geom):
        g, s = float(x[0]), float(x[1])
        n = len(geom.normal_deg)
        across = np.full(n, ROI_ACROSS_PX) if geom.roi_across_px is None else np.asarray(geom.roi_across_px, float)
        out = np.empty((n, len(geom.freq)))
        for a in np.unique(across):
            hw = self.seen(s, a, geom.freq)
            h0 = float(self.seen(s, a, [0.0])[0])
            out[across == a] = np.abs((1.0 - g) + g * hw) / ((1.0 - g) + g * h0)
        return out

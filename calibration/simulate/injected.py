"""Effects put into a simulated capture that the lens model lacks: what a
production line meets between the lens and the measured DNG.

Each maker returns an :class:`Injection`: where it acts and what it does
there. ``"optics"`` moves the sensor's surface off the lens's image plane
(a focus shift, a tilted or a curved sensor): the PSF map is computed on
that surface (:func:`calibration.optics.psf.map.psf_map`'s
``image_dz_mm``), so the defocus is the lens's own, aberrations and
diffraction included. The others act on the mosaic (0..1 signal, ``(H,
W)``) and its CFA: ``"light"`` on the noise-free signal before the sensor's
noise (charge and stray light: glare, crosstalk, colour), ``"chain"``
after the noise, before quantisation (processing in the measurement chain:
sharpening). :func:`calibration.simulate.capture.simulate_capture`
applies them (``injections=``; the surface by
:func:`~calibration.simulate.capture.surface_dz_mm`); :func:`make_injection` builds one by the name of the
loop's registry effect whose signature it leaves
(:mod:`calibration.loop.effects`), so that a benchmark can check that the
loop names what was put in.

The sensor's surface is ``Δz = dz`` for a focus shift, ``y tan θx + x
tan θy`` for a sensor tilted by θx about x and θy about y, and ``dz_corner
(r / r_corner)²`` for a curved one (x, y, r on the image plane, mm; +:
away from the lens); each PSF-map region takes the value at its centre.
Crosstalk leaks charge to the four neighbouring sites whatever their
colour; lateral colour
magnifies the R and B planes about the centre; longitudinal colour blurs
the R and B planes by a uniform disc each (a colour focused off the
sensor, :func:`disc_blur`), G untouched; glare adds a share of each
plane's light in a wide Gaussian halo; motion blur spreads each plane's
light along a segment (:func:`motion_blur`); sharpening is an unsharp mask
of each plane. Lengths on a plane are in plane pixels (two sensor pixels).

:data:`OUTSIDE` holds what a line meets that the loop's registry lacks, for
the loop to leave unexplained: an edge-preserving denoiser and a JPEG
encoder in the measurement chain, and a smudge on the lens (glare in one
part of the field).

Examples
--------
>>> import numpy as np
>>> from isp.frame import CFA
>>> flat = np.full((64, 64), 0.5)
>>> bool(np.allclose(make_injection("sharpening", gain=0.8, sigma_px=1.0).apply(flat, CFA.RGGB), 0.5))
True
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from isp.errors import ConfigError
from isp.frame import CFA

__all__ = ["Injection", "INJECTIONS", "OUTSIDE", "WHERE", "disc_blur", "motion_blur", "make_injection"]

#: where an injection acts, in the order a capture meets them
WHERE = ("optics", "light", "chain")


@dataclass(frozen=True)
class Injection:
    """An effect put into a capture.

    Attributes
    ----------
    effect : str
        The loop registry's effect whose signature it leaves.
    params : dict
        Its magnitudes (units in :data:`INJECTIONS`).
    where : {"optics", "light", "chain"}
        The sensor's surface (``"optics"``), or the mosaic before the
        sensor noise (``"light"``) or after it (``"chain"``).
    apply : callable
        ``"optics"``: ``apply(x_mm, y_mm, half_diagonal_mm) -> Δz_mm``,
        the surface's distance beyond the image plane at image-plane
        points; else ``apply(mosaic, cfa) -> mosaic``, both ``(H, W)``
        float on 0..1.
    """

    effect: str
    params: dict
    where: str
    apply: Callable[[np.ndarray, CFA], np.ndarray] = field(repr=False)

    def __post_init__(self):
        if self.where not in WHERE:
            raise ConfigError(f"an injection acts on 'light' or 'chain', not {self.where!r}")


def _planes(mosaic: np.ndarray):
    """The four CFA phases: ``(dy, dx, plane)``."""
    for dy in (0, 1):
        for dx in (0, 1):
            yield dy, dx, mosaic[dy::2, dx::2]


def _per_plane(fn) -> Callable[[np.ndarray, CFA], np.ndarray]:
    """``fn(plane, ys, xs, channel)`` on each phase, ``ys, xs`` the plane's
    sensor coordinates relative to the centre over the half diagonal."""
    def apply(mosaic: np.ndarray, cfa: CFA) -> np.ndarray:
        m = np.asarray(mosaic, dtype=np.float64)
        out = np.empty_like(m)
        h, w = m.shape
        half = 0.5 * np.hypot(h, w)
        for dy, dx, p in _planes(m):
            ys = (np.arange(dy, h, 2) - (h - 1) / 2.0) / half
            xs = (np.arange(dx, w, 2) - (w - 1) / 2.0) / half
            out[dy::2, dx::2] = fn(p, ys, xs, "RGB"[cfa.pattern[dy, dx]])
        return out
    return apply


def _gauss(plane: np.ndarray, sigma: float) -> np.ndarray:
    from scipy.ndimage import gaussian_filter

    return plane if sigma <= 0 else gaussian_filter(plane, sigma, mode="nearest", truncate=4.0)


def _focus(dz_um: float):
    return lambda x_mm, y_mm, half_mm: np.full(np.shape(x_mm), 1e-3 * dz_um)


def _tilt(tilt_x_deg: float, tilt_y_deg: float):
    return lambda x_mm, y_mm, half_mm: (np.asarray(y_mm) * math.tan(math.radians(tilt_x_deg))
                                        + np.asarray(x_mm) * math.tan(math.radians(tilt_y_deg)))


def _curvature(dz_corner_um: float):
    return lambda x_mm, y_mm, half_mm: 1e-3 * dz_corner_um * (np.square(x_mm) + np.square(y_mm)) / half_mm ** 2


def _lateral_ca(red_px_at_corner: float, blue_px_at_corner: float):
    from scipy.ndimage import map_coordinates

    def fn(p, ys, xs, c):
        k = {"R": red_px_at_corner, "B": blue_px_at_corner}.get(c, 0.0)
        if k == 0.0:
            return p
        h, w = p.shape
        half = 0.5 * np.hypot(h, w)                  # plane px; a shift of k sensor px at the corner
        scale = 1.0 + 0.5 * k / half                 # the plane magnified about its centre
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
        cy, cx = (h - 1) / 2.0, (w - 1) / 2.0
        return map_coordinates(p, [cy + (yy - cy) / scale, cx + (xx - cx) / scale], order=3, mode="nearest")
    return _per_plane(fn)


def disc_blur(image: np.ndarray, diameter_px: float) -> np.ndarray:
    """``image`` blurred by a uniform disc of ``diameter_px`` (the blur
    circle of light focused off the sensor, geometric optics): its spectrum
    times 2 J₁(πDf)/(πDf), f the radial frequency, exactly (no kernel
    sampling adds blur), the image padded by its edge values.

    >>> img = np.zeros((32, 64)); img[:, 32:] = 1.0
    >>> out = disc_blur(img, 3.0)
    >>> round(float(out[16].sum()), 6), bool(0.1 < out[16, 31] < 0.5)
    (32.0, True)
    """
    from calibration.loop.base import disc_otf

    return _filtered(image, diameter_px, lambda fx, fy: disc_otf(np.hypot(fx, fy), diameter_px))


def _filtered(image: np.ndarray, reach_px: float, transfer) -> np.ndarray:
    """``image`` times ``transfer(fx, fy)`` (cycles/px) in its spectrum,
    padded by its edge values beyond ``reach_px`` so that its borders do
    not wrap; a copy where ``reach_px`` ≤ 0 (no blur)."""
    img = np.asarray(image, dtype=np.float64)
    if reach_px <= 0:
        return img.copy()
    m = int(np.ceil(reach_px)) + 8
    pad = np.pad(img, m, mode="edge")
    fy = np.fft.fftfreq(pad.shape[0])[:, None]
    fx = np.fft.rfftfreq(pad.shape[1])[None, :]
    out = np.fft.irfft2(np.fft.rfft2(pad) * transfer(fx, fy), s=pad.shape)
    return out[m:-m, m:-m]


def _longitudinal_ca(red_disc_px: float, blue_disc_px: float):
    def fn(p, ys, xs, c):
        return disc_blur(p, {"R": red_disc_px, "B": blue_disc_px}.get(c, 0.0))
    return _per_plane(fn)


def motion_blur(image: np.ndarray, length_px: float, angle_deg: float) -> np.ndarray:
    """``image`` moved uniformly along a segment of ``length_px`` at
    ``angle_deg`` from the x axis (y down) during the exposure: its spectrum
    times sinc(L·(f_x cos θ + f_y sin θ)), exactly (no kernel sampling adds
    blur), the image padded by its edge values so that its borders do not
    wrap.

    >>> img = np.zeros((32, 64)); img[:, 32:] = 1.0
    >>> bool(np.allclose(motion_blur(img, 4.0, 90.0), img, atol=1e-9))   # along the edge: nothing
    True
    >>> out = motion_blur(img, 4.0, 0.0)                                  # across it: spread, light kept
    >>> round(float(out[16].sum()), 6), bool(out[16, 30] > 0.01)
    (32.0, True)
    """
    a = np.radians(angle_deg)
    return _filtered(image, length_px, lambda fx, fy: np.sinc(length_px * (fx * np.cos(a) + fy * np.sin(a))))


def _motion(length_px: float, angle_deg: float):
    return _per_plane(lambda p, ys, xs, c: motion_blur(p, length_px, angle_deg))


def _glare(share: float, halo_sigma_px: float):
    return _per_plane(lambda p, ys, xs, c: (1.0 - share) * p + share * _gauss(p, halo_sigma_px))


def _sharpening(gain: float, sigma_px: float):
    return _per_plane(lambda p, ys, xs, c: p + gain * (p - _gauss(p, sigma_px)))


def _crosstalk(leak: float):
    def apply(mosaic: np.ndarray, cfa: CFA) -> np.ndarray:
        from scipy.ndimage import convolve

        k = np.array([[0.0, leak, 0.0], [leak, 1.0 - 4.0 * leak, leak], [0.0, leak, 0.0]])
        return convolve(np.asarray(mosaic, dtype=np.float64), k, mode="nearest")
    return apply


#: effect name → (maker, where, parameter names with units)
INJECTIONS = {
    "focus_shift": (_focus, "optics", {"dz_um": "µm (+: away from the lens)"}),
    "sensor_tilt": (_tilt, "optics", {"tilt_x_deg": "degree about x", "tilt_y_deg": "degree about y"}),
    "field_curvature": (_curvature, "optics", {"dz_corner_um": "µm at the corner"}),
    "lateral_ca": (_lateral_ca, "light", {"red_px_at_corner": "sensor px", "blue_px_at_corner": "sensor px"}),
    "longitudinal_ca": (_longitudinal_ca, "light", {"red_disc_px": "plane px", "blue_disc_px": "plane px"}),
    "pixel_crosstalk": (_crosstalk, "light", {"leak": "fraction to each neighbour"}),
    "veiling_glare": (_glare, "light", {"share": "fraction", "halo_sigma_px": "plane px"}),
    "sharpening": (_sharpening, "chain", {"gain": "-", "sigma_px": "plane px"}),
    "motion_blur": (_motion, "light", {"length_px": "plane px", "angle_deg": "degree from x (y down)"}),
}


def _denoise(sigma_range: float, sigma_px: float):
    """An edge-preserving denoiser in the chain: OpenCV's bilateral filter
    on each plane (Tomasi & Manduchi, ICCV 1998), range σ in signal units."""
    import cv2

    d = 2 * int(math.ceil(2.0 * sigma_px)) + 1
    return _per_plane(lambda p, ys, xs, c: cv2.bilateralFilter(p.astype(np.float32), d, float(sigma_range),
                                                               float(sigma_px)).astype(np.float64))


def _jpeg(quality: float):
    """Each plane through 8-bit baseline JPEG at ``quality`` (OpenCV's
    libjpeg): 8 × 8 DCT blocks quantised, the detail of the edges lost
    block by block."""
    import cv2

    def fn(p, ys, xs, c):
        u8 = np.clip(np.round(p * 255.0), 0, 255).astype(np.uint8)
        ok, buf = cv2.imencode(".jpg", u8, [cv2.IMWRITE_JPEG_QUALITY, int(round(quality))])
        return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED).astype(np.float64) / 255.0
    return _per_plane(fn)


def _haze(share: float, halo_sigma_px: float, x: float, y: float, radius: float):
    """A smudge on the lens: glare whose share falls off as a Gaussian of
    ``radius`` (over the half diagonal) about (``x``, ``y``) (relative to
    the centre, over the half diagonal, y down); the registry's glare is
    the same everywhere."""
    def fn(p, ys, xs, c):
        w = share * np.exp(-((xs[None, :] - x) ** 2 + (ys[:, None] - y) ** 2) / (2.0 * radius ** 2))
        return (1.0 - w) * p + w * _gauss(p, halo_sigma_px)
    return _per_plane(fn)


#: effects a line meets that the loop's registry lacks: the loop must leave them unexplained
#: (name → (maker, where, parameter names with units))
OUTSIDE = {
    "denoise": (_denoise, "chain", {"sigma_range": "signal (0..1)", "sigma_px": "plane px"}),
    "jpeg": (_jpeg, "chain", {"quality": "libjpeg 1–100"}),
    "haze": (_haze, "light", {"share": "fraction at the centre", "halo_sigma_px": "plane px",
                              "x": "over the half diagonal", "y": "over the half diagonal",
                              "radius": "over the half diagonal"}),
}


def make_injection(effect: str, **params: float) -> Injection:
    """The injection leaving ``effect``'s signature, with its magnitudes
    (:data:`INJECTIONS` names them and their units; :data:`OUTSIDE` those
    outside the loop's registry).

    Raises
    ------
    ConfigError
        An unknown effect, or parameters that are not its own.
    """
    known = {**INJECTIONS, **OUTSIDE}
    if effect not in known:
        raise ConfigError(f"no injection for effect {effect!r}; known: {', '.join(known)}")
    maker, where, names = known[effect]
    if set(params) != set(names):
        raise ConfigError(f"{effect} takes {', '.join(names)}; got {', '.join(params) or 'nothing'}")
    values = {k: float(params[k]) for k in names}
    return Injection(effect, values, where, maker(**values))

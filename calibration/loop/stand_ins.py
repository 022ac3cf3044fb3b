"""A stand-in device for the loop: optics built from closed forms, and the
effects a measurement chain adds, put into its edges' pixels.

The device (:class:`StandInDevice`) is a PSF map whose PSF at each region
centre is diffraction at f/N × a Gaussian aberration blur × the disc of the
device's defocus there (geometric optics: diameter |Δz|/N), with lateral
colour as R and B planes shifted radially on mixed ("L") edges and
longitudinal colour as R and B planes focused Δz from G. Its
:func:`calibration.fit.synthetic_devices.synthetic_observations` are edges
rendered through those PSFs and measured with ISO 12233; the loop's
:class:`calibration.loop.base.ParametricBase` models exactly these optics,
so what the loop names on such a device is set by the effect, the noise and
the edges alone: a lower bound on what it can tell apart on a real lens.

The chain's effects (:func:`sharpen`, :func:`crosstalk`, :func:`glare`,
:func:`motion`) act on each rendered ROI before the noise (``image_ops``),
in pixels, not in the registry's own transfer terms
(:mod:`calibration.loop.effects`); the defocus effects are the device's own
(:func:`curvature`, :func:`tilt_about_y`, ``dz``, ``loca``).

Example
-------
>>> dev = StandInDevice(dz=lambda x, y: 0.004)
>>> p = dev.psf(2, 3, "G").data
>>> p.shape, round(float(p.sum()), 6)
((256, 256), 1.0)
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from calibration.fit.synthetic_devices import edge_sites
from calibration.loop.base import diffraction_mtf, disc_otf
from calibration.optics.lens import Sensor
from calibration.sfr.esfr import LUMINANCE_WEIGHTS

__all__ = ["SENSOR", "HALF_DIAG", "StandInDevice", "stand_in_psf", "curvature", "tilt_about_y", "sharpen",
           "crosstalk", "motion", "glare"]

#: the stand-in's sensor: 4000 × 3000 px of 1 µm
SENSOR = Sensor(pixel_pitch_um=1.0, width_px=4000, height_px=3000)
#: its centre-to-corner distance, px
HALF_DIAG = 2500.0
_CX, _CY = (SENSOR.width_px - 1) / 2.0, (SENSOR.height_px - 1) / 2.0
_LUMA = dict(zip("RGB", LUMINANCE_WEIGHTS))


def stand_in_psf(dz_mm: float, sigma: float = 0.6, n_f: float = 2.0, n: int = 256, q: float = 0.5,
                 shifts=((1.0, 0.0, 0.0),)) -> np.ndarray:
    """PSF masses (n, n) sampled every ``q`` µm: diffraction at f/``n_f`` (550 nm) × a Gaussian of ``sigma`` µm × the
    defocus disc of diameter |``dz_mm``|/``n_f``; ``shifts``: (weight, dx,
    dy px) of colour planes that share the PSF but lie apart (lateral
    colour), mixed into one (an "L" edge). Built from its OTF, real and
    signed (a disc PSF is non-negative), on a grid that holds its tails.

    >>> p = stand_in_psf(0.0)
    >>> bool(abs(p.sum() - 1) < 1e-12 and p.argmax() == 128 * 256 + 128)
    True
    """
    f = np.fft.fftfreq(n, d=q)
    fx, fy = np.meshgrid(f, f)
    fr = np.hypot(fx, fy)
    otf = diffraction_mtf(fr / 1e-3, 550.0, n_f) * np.exp(-2 * np.pi ** 2 * sigma ** 2 * fr ** 2)
    if dz_mm:
        otf = otf * disc_otf(fr, abs(dz_mm) / n_f / 1e-3)
    otf = otf * sum(w * np.exp(-2j * np.pi * (fx * dx + fy * dy)) for w, dx, dy in shifts)
    p = np.maximum(np.fft.fftshift(np.real(np.fft.ifft2(otf))), 0)
    return p / p.sum()


class StandInDevice:
    """A PSF map of closed-form optics (module docstring), read as
    :func:`calibration.fit.synthetic_devices.synthetic_observations` reads
    one: ``psf(row, col, channel).data`` at each region centre of ``grid``.

    Parameters
    ----------
    dz : callable ``(x, y) -> mm``
        Defocus over the field (x, y px from the centre).
    sigma : callable ``(x, y) -> µm``
        The aberration blur over the field.
    grid : (rows, cols)
    ca : (red, blue)
        Lateral colour: the R and B planes' radial shift at the corner, px,
        ∝ field height, on "L" edges.
    loca : dict, optional
        Longitudinal colour: each colour plane's own focus offset, mm (on R,
        G or B edges).
    """

    def __init__(self, dz=lambda x, y: 0.0, sigma=lambda x, y: 0.6, grid=(5, 7), ca=(0.0, 0.0), loca=None):
        self.sensor, self.grid, self.pitch_um = SENSOR, grid, 0.5
        self.sites = {(r, k): (x - _CX, y - _CY) for r, k, x, y in edge_sites(SENSOR, grid)}
        self.dz, self.sigma, self.ca, self.loca = dz, sigma, ca, loca or {}

    def psf(self, r: int, k: int, ch: str):
        x, y = self.sites[(r, k)]
        shifts = ((1.0, 0.0, 0.0),)
        if ch == "L":
            kr, kb = self.ca
            shifts = tuple((_LUMA[c], kc * x / HALF_DIAG, kc * y / HALF_DIAG)
                           for c, kc in (("R", kr), ("G", 0.0), ("B", kb)))
        return SimpleNamespace(data=stand_in_psf(self.dz(x, y) + self.loca.get(ch, 0.0), sigma=self.sigma(x, y),
                                                 shifts=shifts))


# -- defocus over the field ----------------------------------------------------------------------

def curvature(dz_corner_mm: float):
    """Defocus ∝ r², ``dz_corner_mm`` at the corner (a curved field)."""
    return lambda x, y: dz_corner_mm * (np.hypot(x, y) / HALF_DIAG) ** 2


def tilt_about_y(deg: float):
    """The plane tilted about the y axis: defocus grows along x (SensorTilt's ``tilt_y_deg``)."""
    return lambda x, y: x * 1e-3 * np.tan(np.radians(deg))


# -- the chain's effects on an ROI (``image_ops``: ``op(roi, x_px, y_px)``) ----------------------

def sharpen(gain: float, sigma_px: float):
    """An unsharp mask: ``roi + gain·(roi − G_σ ⊛ roi)``."""
    from scipy.ndimage import gaussian_filter

    return lambda img, x, y: img + gain * (img - gaussian_filter(img, sigma_px, mode="nearest"))


def crosstalk(leak: float):
    """``leak`` of each pixel's charge to each 4-neighbour."""
    from scipy.ndimage import convolve

    k = np.array([[0.0, leak, 0.0], [leak, 1.0 - 4.0 * leak, leak], [0.0, leak, 0.0]])
    return lambda img, x, y: convolve(img, k, mode="nearest")


def motion(length_px: float, angle_deg: float):
    """A uniform motion of ``length_px`` along ``angle_deg`` during the exposure."""
    from calibration.simulate.injected import motion_blur

    return lambda img, x, y: motion_blur(img, length_px, angle_deg)


def glare(share: float, sigma_px: float):
    """A halo of ``share`` of the light, Gaussian of ``sigma_px``
    (``mode="nearest"`` continues the edge's plateaus beyond the ROI)."""
    from scipy.ndimage import gaussian_filter

    return lambda img, x, y: (1.0 - share) * img + share * gaussian_filter(img, sigma_px, mode="nearest",
                                                                           truncate=6.0)

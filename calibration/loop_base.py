"""Base models for the loop closure (:mod:`calibration.loop`).

A base model predicts every observation's SFR from its own parameters plus
the hooks of added effects (:mod:`calibration.effects`):

* :class:`LensBase` — a lens prescription and its perturbations
  (:class:`calibration.sfr_model.SfrModel`); its parameters are the
  screened lens perturbations of :mod:`calibration.proxy` *without* focus,
  so that a focus shift is something the loop must find.
* :class:`ParametricBase` — no prescription (an unknown camera): a
  diffraction-limited circular pupil at F-number N (ISO 12233 Annex /
  Goodman eq. 6-33) × a Gaussian aberration blur of σ px × the square pixel
  aperture. Defocus Δz adds a uniform disc of diameter |Δz|/N (geometric
  optics).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from .effects import Geometry
from .proxy_data import Observations
from .sfr_model import Prediction, aperture_mtf, sfra_of

__all__ = ["LensBase", "ParametricBase", "diffraction_mtf", "disc_mtf"]


def diffraction_mtf(f_cy_per_mm, wavelength_nm: float, f_number: float) -> np.ndarray:
    """MTF of an aberration-free circular pupil (Goodman, *Introduction to
    Fourier Optics*, eq. 6-33): (2/π)(φ − cos φ sin φ), φ = acos(f/fc),
    fc = 1/(λN).

    >>> float(diffraction_mtf(0.0, 550.0, 2.0)), round(float(diffraction_mtf(1e6 / 1100.0, 550.0, 2.0)), 12)
    (1.0, 0.0)
    """
    fc = 1.0 / (wavelength_nm * 1e-6 * f_number)
    v = np.clip(np.abs(np.asarray(f_cy_per_mm, float)) / fc, 0.0, 1.0)
    phi = np.arccos(v)
    return (2.0 / np.pi) * (phi - np.cos(phi) * np.sin(phi))


def disc_mtf(f, diameter) -> np.ndarray:
    """|2 J₁(πDf)/(πDf)|: a uniform disc of diameter D (same length unit as 1/f)."""
    from scipy.special import j1

    x = np.pi * np.asarray(diameter, float) * np.asarray(f, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(np.abs(x) < 1e-9, 1.0, 2.0 * j1(x) / np.where(x == 0, 1.0, x))
    return np.abs(out)


def _geometry(obs: Observations, x_mm, y_mm, channels) -> Geometry:
    cx, cy = (obs.sensor.width_px - 1) / 2.0, (obs.sensor.height_px - 1) / 2.0
    half_px = 0.5 * math.hypot(obs.sensor.width_px, obs.sensor.height_px)
    half_mm = half_px * obs.sensor.pixel_pitch_um * 1e-3
    xy = np.stack([np.asarray(obs.x_px) - cx, np.asarray(obs.y_px) - cy], axis=1)
    return Geometry(np.asarray(x_mm, float), np.asarray(y_mm, float), np.hypot(x_mm, y_mm) / half_mm,
                    np.asarray(obs.normal_deg, float), np.asarray(obs.freq, float), np.asarray(obs.channel),
                    np.asarray(obs.radius, float), xy, tuple(channels), half_px)


class ParametricBase:
    """Parametric optical MTF (module docstring). Parameters: ``sigma_px``
    (aberration blur) and, with ``fit_f_number``, ``f_number``. Nodes are
    the observations themselves (no PSFs to interpolate)."""

    refit_in_cv = True     # cheap: the loop re-fits it with each candidate effect

    def __init__(self, obs: Observations, *, f_number: float = 2.0, wavelength_nm: float = 550.0,
                 fit_f_number: bool = False, aperture_px: float = 1.0):
        self.obs = obs
        self.f_number = float(f_number)
        self.wavelength_nm = float(wavelength_nm)
        self.aperture_px = aperture_px
        self.names = ("sigma_px",) + (("f_number",) if fit_f_number else ())
        self.x0 = np.array([0.5] + ([f_number] if fit_f_number else []))
        self.lower = np.array([0.0] + ([0.7] if fit_f_number else []))
        self.upper = np.array([6.0] + ([16.0] if fit_f_number else []))
        self.scale = np.array([0.2] + ([0.2] if fit_f_number else []))
        pitch_mm = obs.sensor.pixel_pitch_um * 1e-3
        cx, cy = (obs.sensor.width_px - 1) / 2.0, (obs.sensor.height_px - 1) / 2.0
        self.geometry = _geometry(obs, (np.asarray(obs.x_px) - cx) * pitch_mm, (np.asarray(obs.y_px) - cy) * pitch_mm,
                                  sorted(set(np.asarray(obs.channel).tolist()) & {"R", "G", "B"}) or ("G",))
        self._ap = aperture_mtf(obs.freq, obs.normal_deg, aperture_px)
        self.description = (f"parametric optics: diffraction at f/{self.f_number:g} ({self.wavelength_nm:g} nm) "
                            "× Gaussian aberration blur × pixel aperture")

    def predict(self, xb, *, defocus_mm=None, shifts_px=None, transfer=None) -> Prediction:
        obs = self.obs
        sigma = float(xb[0])
        n = float(xb[1]) if len(xb) > 1 else self.f_number
        f = np.asarray(obs.freq, float)[None, :]
        pitch_mm = obs.sensor.pixel_pitch_um * 1e-3
        sfr = diffraction_mtf(f / pitch_mm, self.wavelength_nm, n) * np.exp(-2 * np.pi ** 2 * sigma ** 2 * f ** 2)
        sfr = sfr * self._ap
        if defocus_mm is not None:
            d_px = np.abs(np.asarray(defocus_mm, float)) / n / pitch_mm
            sfr = sfr * disc_mtf(f, d_px[:, None])
        if transfer is not None:
            sfr = sfr * transfer
        sfr = np.broadcast_to(sfr, (len(obs), f.shape[1])).copy()
        return Prediction(sfra_of(obs.freq, sfr), sfr, obs.freq)

    def measurement_bias(self, xb):
        """No PSF to render: the noise's rise is estimated from a Gaussian
        edge of the same SFRA (:func:`calibration.sfr_synth.render_slanted_edge`)."""
        return _gaussian_bias(self.obs, self.predict(xb))


class LensBase:
    """A lens prescription and its perturbations (module docstring)."""

    refit_in_cv = False    # every evaluation traces the lens: candidates are fitted with it held

    def __init__(self, nominal, obs: Observations, *, settings=None, names=None, n_params: int = 12,
                 workers: int | None = None, progress: bool = False):
        from .perturb import nominal as as_perturbed
        from .proxy import default_names, focus_name, parameter_space, screen_parameters
        from .sfr_model import ModelSettings, SfrModel

        self.model = SfrModel(nominal, obs, settings or ModelSettings())
        self.obs = obs
        self.nominal = nominal
        if names is None:
            names = [n for n in default_names(nominal) if n != focus_name(nominal)]
            names = screen_parameters(self.model, names, n_params)
        self.space = parameter_space(nominal, names)
        self.names = tuple(self.space.names)
        k = len(self.names)
        self.x0, self.lower, self.upper = np.zeros(k), np.full(k, -2.0), np.full(k, 2.0)
        self.scale = np.full(k, 0.1)
        self.geometry = _geometry(obs, self.model.node_mm[:, 0], self.model.node_mm[:, 1], self.model.channels)
        self._pl = as_perturbed(nominal)
        self.description = f"lens {nominal.name or ''} with {k} perturbations (tolerance units)".replace("  ", " ")

    def lens(self, xb):
        return self.space.apply(np.asarray(xb, float) * self.space.tolerance)

    def predict(self, xb, *, defocus_mm=None, shifts_px=None, transfer=None) -> Prediction:
        return self.model.predict(self.lens(xb), defocus_mm=defocus_mm, shifts_px=shifts_px, transfer=transfer)

    def measurement_bias(self, xb):
        a, c = self.model.measurement_bias(self.lens(xb))
        return a, c, self.model.last_sfra_noise


def _gaussian_bias(obs: Observations, pred: Prediction):
    """(sfra bias, sfr bias, sfra noise std) per observation from noisy
    renders of a Gaussian edge with the predicted SFRA."""
    from .sfr import SfrError, measure_sfr
    from .sfr_synth import render_slanted_edge

    rng = np.random.default_rng(0)
    n = len(obs)
    a_bias, sd, c_bias = np.zeros(n), np.zeros(n), np.zeros((n, len(obs.freq)))
    f = np.asarray(obs.freq)
    for i in range(n):
        # the Gaussian σ whose SFRA (with the pixel aperture) matches the prediction
        target = pred.sfra[i]
        sig = _sigma_for_sfra(target)
        step = float(obs.step[i]) or 0.6
        noise = float(obs.noise[i])
        img = render_slanted_edge((96, 64), 5.0, sigma_px=sig, low=0.2, high=0.2 + step)
        vals, curves = [], []
        for _ in range(4 if noise > 0 else 1):
            try:
                r = measure_sfr(img + rng.normal(0, noise, img.shape) if noise > 0 else img)
            except SfrError:
                continue
            vals.append(r.sfra)
            curves.append(np.interp(f, r.freq, r.sfr, right=np.nan))
        if not vals:
            continue
        exact = np.exp(-2 * np.pi ** 2 * sig ** 2 * f ** 2) * np.abs(np.sinc(f))
        a_bias[i] = np.mean(vals) - sfra_of(f, exact[None])[0]
        c_bias[i] = np.nan_to_num(np.nanmean(curves, axis=0) - exact)
        sd[i] = np.std(vals, ddof=1) if len(vals) > 1 else 0.0
    return a_bias, c_bias, sd


@functools.lru_cache(maxsize=1)
def _sfra_table() -> tuple[np.ndarray, np.ndarray]:
    """(σ px, SFRA) of Gaussian blur × pixel aperture, SFRA falling with σ."""
    f = np.linspace(0, 0.5, 65)
    sig = np.linspace(0.05, 6.0, 240)
    mtf = np.exp(-2 * np.pi ** 2 * sig[:, None] ** 2 * f[None, :] ** 2) * np.abs(np.sinc(f))[None, :]
    return sig, np.trapezoid(mtf, f, axis=1)


def _sigma_for_sfra(target: float) -> float:
    """The Gaussian σ (px) whose SFRA with the pixel aperture is ``target``."""
    sig, a = _sfra_table()
    return float(np.interp(-target, -a, sig))

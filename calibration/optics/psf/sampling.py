"""The PSF window: its sample grid, default spacing and centre, and the
normalisation every method shares.

A PSF is sampled on a square ``n × n`` grid of spacing ``pitch_um`` about a
centre on the image plane (:mod:`calibration.optics.psf.result` fixes the
orientation: rows along +y, columns along +x, centre ``data[n//2, n//2]``).

Default sample spacing: ``λ_min·N_w/4`` (:func:`default_pitch_um`) — half
the Nyquist spacing ``λN_w/2`` of the incoherent cut-off ``1/(λN_w)``
(``N_w`` the paraxial working F/# in image space, ``λ_min`` the shortest
wavelength used), so peaks and the first dark ring are resolved.

:func:`normalized_samples` turns a method's intensity on the window into
the PSF's samples (summing to 1) and its window energy;
:func:`monochromatic_psf` is the one driver of the three methods' ``*_psf``
functions (trace, centre, grid, sample), given the method's sampler.

Imports :mod:`calibration.optics` (paraxial, perturb) and
:mod:`~calibration.optics.psf.pupil`, :mod:`~calibration.optics.psf.result`
of this package; never a method module (they import this one).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from calibration.optics import paraxial
from calibration.optics.perturb import PerturbedLens, nominal
from calibration.optics.psf.pupil import ReferenceSphere, TracedPupil, reference_sphere, trace_pupil
from calibration.optics.psf.result import (
    PSF,
    PSFError,
    check_aiming,
    check_field,
    check_positive_int,
    check_wavelength,
)

__all__ = ["Sampler", "default_pitch_um", "grid_offsets_mm", "monochromatic_psf", "normalized_samples", "psf_center"]

Sampler = Callable[[ReferenceSphere, np.ndarray, np.ndarray], tuple[np.ndarray, float]]
"""A method's samples on a window: ``(sphere, ox, oy) -> (data, window_energy)``
with ``data`` (len(oy), len(ox)) summing to 1 (:func:`normalized_samples`)."""


def grid_offsets_mm(n: int, pitch_um: float) -> np.ndarray:
    """(n,) offsets of a window's samples from its centre sample, mm:
    ``(j − n//2)·pitch``.

    >>> grid_offsets_mm(4, 500.0).tolist()
    [-1.0, -0.5, 0.0, 0.5]
    """
    return (np.arange(n) - n // 2) * (pitch_um * 1e-3)


def default_pitch_um(pl: PerturbedLens, lam_nm: float) -> float:
    """The default sample spacing at wavelength ``lam_nm`` (the shortest
    used), µm: ``λ·N_w/4`` (module docstring)."""
    n_w = paraxial.first_order(pl.lens).working_f_number
    if not (math.isfinite(n_w) and n_w > 0):
        raise PSFError("the lens has no finite working F-number; give pitch_um")
    return lam_nm * 1e-3 * n_w / 4.0


def psf_center(traced: Sequence[TracedPupil], weights: Sequence[float], center,
               ref: TracedPupil | None = None) -> np.ndarray:
    """The PSF's centre on the image plane, (2,) mm.

    Parameters
    ----------
    traced : sequence of TracedPupil
        The pupils of the wavelengths summed.
    weights : sequence of float
        Their weights.
    center : {"chief", "centroid"} or (x, y)
        The chief ray's image point (of ``ref``, default ``traced[0]``), the
        weighted centroid of the rays' image points, or a point in mm.
    ref : TracedPupil, optional
        The pupil whose chief ray "chief" means.
    """
    if isinstance(center, str):
        if center == "chief":
            return (ref if ref is not None else traced[0]).chief_image_point()
        if center == "centroid":
            c = sum(w * t.image_points().mean(axis=0) for t, w in zip(traced, weights))
            return np.asarray(c) / float(sum(weights))
        raise PSFError(f"unknown center {center!r}; valid: 'chief', 'centroid', or (x, y) in mm")
    c = np.asarray(center, dtype=np.float64).ravel()
    if c.shape != (2,) or not np.all(np.isfinite(c)):
        raise PSFError(f"center must be 'chief', 'centroid' or a finite (x, y) in mm, got {center!r}")
    return c


def normalized_samples(sp: ReferenceSphere, intensity: np.ndarray, total: float, ox: np.ndarray
                       ) -> tuple[np.ndarray, float]:
    """A method's intensity on the window as PSF samples and window energy.

    Parameters
    ----------
    sp : ReferenceSphere
        The sphere the intensity was computed from (for the message).
    intensity : (ny, nx) ndarray
        |E|² on the window, the method's units.
    total : float
        ``∫|E|² dA`` over the whole image plane in the same units.
    ox : (nx,) ndarray
        The window's x offsets, mm (their spacing is the pitch).

    Returns
    -------
    data : (ny, nx) ndarray
        ``intensity`` scaled to sum 1.
    window_energy : float
        ``Σ I·pitch² / total``: the share of the energy on the window.
    """
    s = float(intensity.sum())
    if not (s > 0 and math.isfinite(s)):
        raise PSFError(f"the PSF at {sp.wavelength_nm:g} nm has no energy in the window (centre {sp.p0[:2]} mm); "
                       "check center, n and pitch_um")
    pitch_mm = float(ox[1] - ox[0]) if len(ox) > 1 else 0.0
    return intensity / s, s * pitch_mm * pitch_mm / total


def monochromatic_psf(lens, field_deg, wavelength_nm, method: str, sample: Sampler, *, pupil_samples, n,
                      pitch_um, center, aiming) -> PSF:
    """The monochromatic PSF of one method: trace the pupil, place the
    window, sample it with ``sample`` (:data:`Sampler`).

    Parameters are those of :func:`calibration.optics.psf.huygens.huygens_psf`;
    ``method`` is the name the PSF records.

    Returns
    -------
    PSF
        ``data`` (n, n) summing to 1.
    """
    pl = nominal(lens)
    f = check_field(field_deg)
    lam = check_wavelength(wavelength_nm)
    samples = check_positive_int(pupil_samples, "pupil_samples")
    n = check_positive_int(n, "n")
    tr = trace_pupil(pl, f, lam, samples, check_aiming(aiming))
    c = psf_center([tr], [1.0], center)
    pitch = default_pitch_um(pl, lam) if pitch_um is None else float(pitch_um)
    if not (math.isfinite(pitch) and pitch > 0):
        raise PSFError(f"pitch_um must be positive, got {pitch_um!r}")
    o = grid_offsets_mm(n, pitch)
    data, energy = sample(reference_sphere(tr, c), o, o)
    return PSF(data, pitch, (float(c[0]), float(c[1])), f, (lam,), (1.0,), method, energy)

"""The diffraction models by name: ``"huygens"``, ``"fft"``, ``"debye"``.

Three models share one ray trace (:mod:`calibration.optics.psf.pupil`):
:mod:`~calibration.optics.psf.huygens` (the paper's Huygens sum, the
oracle), :mod:`~calibration.optics.psf.fft` (the pupil-function FFT, the
classical cross-check) and :mod:`~calibration.optics.psf.debye` (the Debye
sum on the grid, the PSF-map default). :func:`monochromatic_samples` runs
the one named; a wrong name lists the valid ones.

Imports the three method modules and :mod:`~calibration.optics.psf.result`;
they do not import this one.
"""

from __future__ import annotations

import numpy as np

from calibration.optics.psf.debye import debye_samples
from calibration.optics.psf.fft import fft_samples
from calibration.optics.psf.huygens import huygens_samples
from calibration.optics.psf.pupil import ReferenceSphere
from calibration.optics.psf.result import PSFError

__all__ = ["METHODS", "check_method", "monochromatic_samples"]

METHODS = ("huygens", "fft", "debye")
"""The diffraction models, by name."""


def check_method(method: str) -> str:
    """``method`` if it is one of :data:`METHODS`; :class:`PSFError` listing
    them otherwise."""
    if method not in METHODS:
        raise PSFError(f"unknown PSF method {method!r}; valid: {', '.join(METHODS)}")
    return method


def monochromatic_samples(sp: ReferenceSphere, method: str, ox: np.ndarray, oy: np.ndarray, pad: int = 4,
                          workers: int | None = None) -> tuple[np.ndarray, float]:
    """One wavelength's PSF by the named method on the window
    ``P0 + (ox[j], oy[i])``.

    Parameters
    ----------
    sp : ReferenceSphere
        The traced rays on the reference sphere about ``P0``.
    method : {"huygens", "fft", "debye"}
    ox, oy : (nx,), (ny,) ndarray
        Uniformly spaced offsets from ``P0`` along x and y, mm.
    pad : int
        FFT zero-padding factor (``"fft"`` only).
    workers : int, optional
        Threads (``"huygens"``, ``"fft"``), default one per core.

    Returns
    -------
    data : (ny, nx) ndarray
        Samples summing to 1.
    window_energy : float
        The share of the pupil's power on the window (``PSF.window_energy``).
    """
    if method == "huygens":
        return huygens_samples(sp, ox, oy, workers=workers)
    if method == "debye":
        return debye_samples(sp, ox, oy)
    if method == "fft":
        return fft_samples(sp, ox, oy, pad=pad, workers=workers)
    raise PSFError(f"unknown PSF method {method!r}; valid: {', '.join(METHODS)}")

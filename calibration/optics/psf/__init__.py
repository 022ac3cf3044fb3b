"""Point spread functions from the exit pupil (paper, section 3.1.2, eqs. 11–14).

Three diffraction models share one ray trace, each in its module:

* :mod:`~calibration.optics.psf.pupil` — the ray trace to the exit pupil
  (pupil sampling, :func:`~calibration.optics.psf.pupil.trace_pupil`) and
  the reference sphere (:func:`~calibration.optics.psf.pupil.reference_sphere`:
  optical path differences, energy-conserving wavelet amplitudes), for one
  field or many at once (the SFR model's path).
* :mod:`~calibration.optics.psf.huygens` — :func:`huygens_psf`, the paper's
  method (eqs. 11–13): every traced ray, where it crosses the reference
  sphere, is the source of a spherical Huygens wavelet; the wavelets are
  summed on the image-plane grid and the intensity is |E|². The reference
  (oracle) of the other two.
* :mod:`~calibration.optics.psf.fft` — :func:`fft_psf`, the pupil-function
  method (Goodman §6.3–6.4; the Debye integral, Born & Wolf §8.8): the
  optical path difference on the same reference sphere, sampled on the
  pupil grid, zero-padded and Fourier transformed; the classical
  cross-check.
* :mod:`~calibration.optics.psf.debye` — :func:`debye_psf`, the Huygens sum
  in the Debye approximation with each ray's *real* direction, evaluated
  directly on the requested grid as a matrix Fourier transform; no affine
  pupil map, no interpolation. The PSF-map default.

Measured on US-12210142-B2-e9 (32² PSFs at 0.5 µm, 64 pupil samples, 450–610
nm, six regions from the centre to the corner; ``benchmarks/psf.py``): the
Debye PSFs are within 0.06 % of the Huygens PSFs' peak, the FFT PSFs within
0.2–0.9 % and up to 4.5 % in the corner, where the pupil map is least
affine.

The rest: :mod:`~calibration.optics.psf.methods` runs a model by name
(:data:`METHODS`); :mod:`~calibration.optics.psf.spectral` integrates over a
sensor channel's spectral response (eq. 14, :func:`polychromatic_psf`);
:mod:`~calibration.optics.psf.strehl` compares the peak with the
aberration-free pupil's (:func:`strehl_ratio`);
:mod:`~calibration.optics.psf.map` computes one polychromatic PSF per sensor
region and channel (``psf_map``, cached on disk);
:mod:`~calibration.optics.psf.result` holds the :class:`PSF` record and
:class:`PSFError`; :mod:`~calibration.optics.psf.sampling` the window (grid,
default spacing, centre, normalisation); :mod:`~calibration.optics.psf.linalg`
the small products kept on one BLAS thread.

Conventions: mm for geometry (image-plane positions ``center_mm``), µm for
the PSF sample spacing ``pitch_um`` and offsets, nm for wavelengths, degrees
for fields ``(θx, θy)`` (object-space direction,
:mod:`calibration.optics.trace`). Light travels +z; the image plane is the
lens's. ``PSF.data[i, j]`` is the intensity at ``x = cx + (j − n//2)·pitch``,
``y = cy + (i − n//2)·pitch``: rows along +y, columns along +x, summing to 1.

References: the paper (``../shared/paper``), §3.1.2; J. W. Goodman,
*Introduction to Fourier Optics*, 3rd ed., Roberts & Co. 2005, §3.5 and
§6.3–6.4; M. Born and E. Wolf, *Principles of Optics*, 7th ed., Cambridge
University Press 1999, §8.3 and §8.8; G. H. Golub and J. H. Welsch,
"Calculation of Gauss quadrature rules", *Math. Comp.* 23 (1969) 221–230.

May import: ``calibration.optics`` and numpy/scipy/colour-science. Inside
the package the imports run one way: result, linalg → pupil → sampling →
huygens, fft, debye → methods → spectral, strehl → map (each module imports
only those to its left).
"""

from calibration.optics.psf.debye import debye_psf
from calibration.optics.psf.fft import fft_psf
from calibration.optics.psf.huygens import huygens_psf
from calibration.optics.psf.methods import METHODS
from calibration.optics.psf.result import PSF, PSFError, ncc
from calibration.optics.psf.spectral import (
    DEFAULT_CAMERA,
    DEFAULT_WAVELENGTHS_PER_CHANNEL,
    polychromatic_psf,
    spectral_quadrature,
    spectral_response,
)
from calibration.optics.psf.strehl import strehl_ratio

__all__ = [
    "DEFAULT_CAMERA",
    "DEFAULT_WAVELENGTHS_PER_CHANNEL",
    "METHODS",
    "PSF",
    "PSFError",
    "debye_psf",
    "fft_psf",
    "huygens_psf",
    "ncc",
    "polychromatic_psf",
    "spectral_quadrature",
    "spectral_response",
    "strehl_ratio",
]

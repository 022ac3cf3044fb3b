"""The Strehl ratio: a PSF's peak over the aberration-free pupil's.

Computed with any of the three models' intensity kernels
(:mod:`~calibration.optics.psf.huygens`, :mod:`~calibration.optics.psf.fft`,
:mod:`~calibration.optics.psf.debye`) on the same traced pupil with the
optical path differences set to zero.

Imports :mod:`calibration.optics` and the method, pupil, linalg and result
modules of this package.
"""

from __future__ import annotations

import numpy as np

from calibration.optics import paraxial
from calibration.optics.lens import Lens
from calibration.optics.perturb import PerturbedLens, nominal
from calibration.optics.psf.debye import debye_intensity
from calibration.optics.psf.fft import fft_lattice, pupil_function
from calibration.optics.psf.huygens import huygens_intensity
from calibration.optics.psf.linalg import at_b
from calibration.optics.psf.methods import METHODS
from calibration.optics.psf.pupil import reference_sphere, trace_pupil
from calibration.optics.psf.result import PSFError, check_aiming, check_field, check_positive_int, check_wavelength

__all__ = ["strehl_ratio"]


def strehl_ratio(lens: Lens | PerturbedLens, field_deg, wavelength_nm: float, *, method: str = "fft",
                 pupil_samples: int = 128, aiming: str = "real") -> float:
    """Peak intensity of the PSF over the peak of the aberration-free PSF of
    the same pupil (same rays, amplitudes and vignetting, W = 0).

    The peak is searched on a coarse grid about the ray centroid (FFT: the
    whole lattice) and refined by three 4× zooms of the method's own sum
    (for "fft" the direct sum of its affine pupil model), so sampling does
    not bias it.
    With W = 0 the peak is at the reference-sphere centre, where every
    wavelet arrives in phase. Values are in (0, 1]; a single-wavelength,
    image-plane figure (no refocusing).

    Parameters
    ----------
    lens : Lens or PerturbedLens
    field_deg : float or (θx, θy)
        Object field, degrees (a scalar is θy).
    wavelength_nm : float
    method : {"huygens", "fft", "debye"}
    pupil_samples : int
        Pupil grid size across the stop.
    aiming : {"real", "paraxial"}

    Returns
    -------
    float
    """
    pl = nominal(lens)
    f = check_field(field_deg)
    lam = check_wavelength(wavelength_nm)
    samples = check_positive_int(pupil_samples, "pupil_samples")
    tr = trace_pupil(pl, f, lam, samples, check_aiming(aiming))
    sp = reference_sphere(tr, tr.image_points().mean(axis=0))
    step = lam * 1e-6 * max(paraxial.first_order(pl.lens).working_f_number, 0.5) / 2.0    # λN/2, mm
    if method == "fft":
        lat, dxi = fft_lattice(sp)
        nf = lat.shape[0]
        iy, ix = np.unravel_index(int(np.argmax(lat)), lat.shape)
        xi0 = np.array([(ix - nf // 2) * dxi, (iy - nf // 2) * dxi])
        f0 = pupil_function(sp)
        px = -1.0 + (np.arange(samples) + 0.5) * (2.0 / samples)

        def debye(xi_x, xi_y):   # |Σ a e^{ikW} e^{ik p·ξ}|² / λ'² on a (len(xi_y), len(xi_x)) grid
            ex = np.exp(1j * sp.k * np.outer(px, xi_x))
            ey = np.exp(1j * sp.k * np.outer(xi_y, px))
            e = at_b(at_b(ey.T, f0).T, ex)
            lam_m = lam * 1e-6 / sp.n_img
            return (e.real ** 2 + e.imag ** 2) / (lam_m * lam_m)

        span = dxi
        best = xi0
        peak = float(lat.max())
        for _ in range(3):
            g = np.linspace(-span, span, 9)
            v = debye(best[0] + g, best[1] + g)
            i, j = np.unravel_index(int(np.argmax(v)), v.shape)
            best = np.array([best[0] + g[j], best[1] + g[i]])
            peak = max(peak, float(v[i, j]))
            span = span / 4.0
        ref = float(sp.amp.sum() ** 2 / (lam * 1e-6 / sp.n_img) ** 2)    # W = 0: all in phase at ξ = 0
        return peak / ref
    if method in ("huygens", "debye"):
        def inten(ox, oy, sphere=sp, zero=False):
            if method == "huygens":
                return huygens_intensity(sphere, ox, oy, zero_opd=zero)
            return debye_intensity(sphere, ox, oy, zero_opd=zero)

        o = np.arange(-16, 17) * step
        v = inten(o, o)
        i, j = np.unravel_index(int(np.argmax(v)), v.shape)
        best = np.array([o[j], o[i]])
        peak = float(v.max())
        span = step
        for _ in range(3):
            g = np.linspace(-span, span, 9)
            v = inten(best[0] + g, best[1] + g)
            i, j = np.unravel_index(int(np.argmax(v)), v.shape)
            best = np.array([best[0] + g[j], best[1] + g[i]])
            peak = max(peak, float(v[i, j]))
            span /= 4.0
        # zero OPD: every wavelet in phase at the reference sphere's centre
        ref = float(inten(np.zeros(1), np.zeros(1), reference_sphere(tr, tr.chief_image_point()), True)[0, 0])
        return peak / ref
    raise PSFError(f"unknown PSF method {method!r}; valid: {', '.join(METHODS)}")

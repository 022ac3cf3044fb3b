"""Lenses and measurements the PSF tests share (and ``benchmarks/psf.py``
reuses): an aberration-free singlet, its real working F-number, the first
dark ring of a PSF row."""

from __future__ import annotations

import math

import numpy as np

import calibration.optics.psf as P
from calibration.optics import trace as tr
from calibration.optics.lens import Lens, Sensor, Surface
from calibration.optics.materials import Material
from calibration.optics.psf.result import PSF

LAM = 587.6
"""The d line, nm."""

FN = {"huygens": P.huygens_psf, "fft": P.fft_psf, "debye": P.debye_psf}
"""The monochromatic PSF of each method."""


def perfect_lens(n=1.5, c=-0.1, f_number=4.0):
    """Plano-convex singlet, collimated light entering the flat side (the
    stop), leaving through the hyperboloid k = −n²: focuses on axis without
    aberration at f = 1/((1−n)c) behind the vertex (20 mm here)."""
    glass = Material("g", n, math.inf, "constant")
    f = 1.0 / ((1.0 - n) * c)
    return Lens((Surface(0.0, thickness=3.0, material=glass, stop=True), Surface(c, -n * n, (), f)),
                epd=f / f_number, half_fov_deg=1.0, sensor=Sensor(1.0, 200, 150))


def real_working_f_number(lens, lam=LAM):
    """1/(2 n' sin u') of the real marginal ray (image-space NA)."""
    r = tr.pupil_rays(lens, (0, 0), 1, lam, aiming="real", pupil=np.array([[0.0, 1.0]]))
    d = tr.trace_to_exit(lens, r).direction[0]
    return 1.0 / (2.0 * math.hypot(d[0], d[1]))


def first_zero_um(p: PSF) -> float:
    """First minimum of the row through the centre, +x side (parabolic refinement)."""
    row = p.data[p.n // 2]
    k = p.n // 2 + 1
    while row[k + 1] < row[k]:
        k += 1
    y0, y1, y2 = row[k - 1], row[k], row[k + 1]
    return float(p.offsets_um()[k] + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2) * p.pitch_um)

"""Optical materials: refractive index as a function of wavelength.

A :class:`Material` is either a catalogue glass or plastic with a published
dispersion formula, or a *model* material known only by ``nd`` (index at
the helium d line, 587.56 nm) and ``vd`` (Abbe number, (nd − 1)/(nF − nC)),
as patents give phone-lens plastics. Model materials use the two-term Cauchy
form ``n(λ) = A + B/λ²`` fitted to nd and to nF − nC = (nd − 1)/vd, which
reproduces nd exactly and the F–C dispersion exactly; a perturbation of nd or
vd (the paper's material tolerance) therefore changes the index at every
wavelength consistently.

Wavelengths in nm. Fraunhofer lines: F 486.13, d 587.56, C 656.27 nm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

LAMBDA_F, LAMBDA_D, LAMBDA_C = 486.1327, 587.5618, 656.2725


@dataclass(frozen=True)
class Material:
    """A refractive medium.

    Attributes
    ----------
    name : str
    nd : float
        Index at 587.56 nm.
    vd : float
        Abbe number (inf: no dispersion).
    formula : {"model", "constant", "sellmeier"}
        How :meth:`index` is computed: the Cauchy model from nd/vd, a
        constant nd, or a Sellmeier formula (``coefficients`` = B1, C1, B2,
        C2, B3, C3 with λ in µm, C in µm²).
    coefficients : tuple of float
    """

    name: str
    nd: float
    vd: float = math.inf
    formula: str = "model"
    coefficients: tuple[float, ...] = ()

    @property
    def is_air(self) -> bool:
        return self.formula == "constant" and self.nd == 1.0

    def index(self, wavelength_nm):
        """Refractive index at ``wavelength_nm`` (scalar or array, nm).

        >>> round(float(Material("model", 1.544, 55.9).index(587.5618)), 6)
        1.544
        """
        lam = np.asarray(wavelength_nm, dtype=np.float64)
        if self.formula == "constant" or not math.isfinite(self.vd) and self.formula == "model":
            return np.full_like(lam, self.nd) if lam.ndim else float(self.nd)
        if self.formula == "model":
            a, b = cauchy_from_abbe(self.nd, self.vd)
            n = a + b / (lam * lam)
        elif self.formula == "sellmeier":
            um2 = (lam * 1e-3) ** 2
            c = self.coefficients
            n2 = 1.0 + sum(c[2 * i] * um2 / (um2 - c[2 * i + 1]) for i in range(len(c) // 2))
            n = np.sqrt(n2)
        else:
            raise ValueError(f"material {self.name!r}: unknown formula {self.formula!r}")
        return n if lam.ndim else float(n)


def cauchy_from_abbe(nd: float, vd: float) -> tuple[float, float]:
    """(A, B) of n = A + B/λ² (λ in nm) with n(d) = nd and
    n(F) − n(C) = (nd − 1)/vd."""
    dn = (nd - 1.0) / vd
    b = dn / (1.0 / LAMBDA_F ** 2 - 1.0 / LAMBDA_C ** 2)
    a = nd - b / LAMBDA_D ** 2
    return a, b


AIR = Material("air", 1.0, math.inf, "constant")

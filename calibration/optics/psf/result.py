"""The PSF record, its error, and the checks every PSF method shares.

Sample grid. ``PSF.data[i, j]`` is the intensity at the image-plane point
``x = cx + (j − n//2)·pitch``, ``y = cy + (i − n//2)·pitch`` with
``(cx, cy) = center_mm``: columns run along +x, rows along +y, and the centre
sample is ``data[n//2, n//2]``. ``data`` holds point samples of the
intensity, scaled so that the samples sum to 1 (so a sample ≈ the energy of
its ``pitch²`` cell). Units: µm for ``pitch_um`` and offsets, mm for
image-plane positions, nm for wavelengths, degrees for fields.

Imports numpy and :mod:`calibration.optics.lens` (for the error's parent).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calibration.optics.lens import LensError

__all__ = ["PSF", "PSFError", "check_aiming", "check_field", "check_positive_int", "check_wavelength", "ncc",
           "sample_centroid_um"]


class PSFError(LensError):
    """A PSF that cannot be computed as asked (bad settings, no rays through
    the lens, a window larger than the FFT period); the message says what to
    change."""


@dataclass(frozen=True, eq=False)
class PSF:
    """A sampled point spread function.

    Attributes
    ----------
    data : (n, n) ndarray, float64
        Intensity samples, summing to 1 (see the module docstring for the
        grid: rows along +y, columns along +x, centre ``data[n//2, n//2]``).
    pitch_um : float
        Sample spacing on the image plane, µm.
    center_mm : (2,) tuple
        Image-plane (x, y) of the centre sample, mm.
    field_deg : (2,) tuple
        Object field (θx, θy), degrees.
    wavelengths_nm : tuple of float
        The wavelengths summed (one for a monochromatic PSF).
    weights : tuple of float
        Their weights (sum 1).
    method : str
        "huygens", "fft", "debye", or "resampled(<method>)".
    window_energy : float
        Fraction of the exit-pupil power that fell on the window before
        normalisation (weighted over wavelengths); NaN where unknown.
    """

    data: np.ndarray
    pitch_um: float
    center_mm: tuple[float, float]
    field_deg: tuple[float, float]
    wavelengths_nm: tuple[float, ...]
    weights: tuple[float, ...]
    method: str
    window_energy: float = math.nan

    def __post_init__(self):
        d = np.asarray(self.data, dtype=np.float64)
        if d.ndim != 2 or d.shape[0] != d.shape[1]:
            raise PSFError(f"PSF data must be square (n, n), got shape {d.shape}")
        if not (math.isfinite(self.pitch_um) and self.pitch_um > 0):
            raise PSFError(f"pitch_um must be positive, got {self.pitch_um!r}")
        object.__setattr__(self, "data", d)
        object.__setattr__(self, "center_mm", tuple(float(v) for v in self.center_mm))
        object.__setattr__(self, "field_deg", tuple(float(v) for v in self.field_deg))
        object.__setattr__(self, "wavelengths_nm", tuple(float(v) for v in self.wavelengths_nm))
        object.__setattr__(self, "weights", tuple(float(v) for v in self.weights))

    @property
    def n(self) -> int:
        return self.data.shape[0]

    def offsets_um(self) -> np.ndarray:
        """(n,) sample offsets from the centre along x (and y), µm."""
        return (np.arange(self.n) - self.n // 2) * self.pitch_um

    def coordinates_mm(self) -> tuple[np.ndarray, np.ndarray]:
        """(x, y) image-plane coordinates of the columns and rows, mm."""
        o = self.offsets_um() * 1e-3
        return self.center_mm[0] + o, self.center_mm[1] + o

    @property
    def centroid_um(self) -> np.ndarray:
        """(x, y) intensity centroid relative to the centre sample, µm."""
        return sample_centroid_um(self.data, self.pitch_um)

    @property
    def peak_um(self) -> np.ndarray:
        """(x, y) of the brightest sample relative to the centre sample, µm."""
        i, j = np.unravel_index(int(np.argmax(self.data)), self.data.shape)
        o = self.offsets_um()
        return np.array([o[j], o[i]])

    def encircled_energy(self, radius_um, about: str | Sequence[float] = "centroid",
                         supersample: int = 8) -> np.ndarray | float:
        """Share of the window's energy within ``radius_um`` (scalar or array,
        µm) of the centroid (``about="centroid"``), the centre sample
        ("center") or an (x, y) offset in µm. Each sample is spread
        uniformly over its ``pitch²`` cell, integrated on a
        ``supersample²`` sub-grid.

        >>> p = PSF(np.full((4, 4), 1 / 16), 1.0, (0, 0), (0, 0), (550,), (1,), "test")
        >>> round(float(p.encircled_energy(10.0)), 6)
        1.0
        """
        if isinstance(about, str):
            if about == "centroid":
                c = self.centroid_um
            elif about == "center":
                c = np.zeros(2)
            else:
                raise PSFError(f"unknown about={about!r}; valid: 'centroid', 'center', or an (x, y) offset in µm")
        else:
            c = np.asarray(about, dtype=np.float64).reshape(2)
        r = np.asarray(radius_um, dtype=np.float64)
        s = int(supersample)
        sub = ((np.arange(s) + 0.5) / s - 0.5) * self.pitch_um
        o = self.offsets_um()
        xs = (o[:, None] + sub[None, :]).ravel() - c[0]
        ys = (o[:, None] + sub[None, :]).ravel() - c[1]
        d2 = (ys[:, None] ** 2 + xs[None, :] ** 2).reshape(self.n, s, self.n, s)
        w = self.data / (s * s)
        out = np.array([float(np.sum(w * np.count_nonzero(d2 <= rr * rr, axis=(1, 3)))) for rr in r.ravel()])
        out /= float(self.data.sum())
        return float(out[0]) if r.ndim == 0 else out.reshape(r.shape)

    def resample(self, pitch_um: float, n: int, center_mm: Sequence[float] | None = None,
                 *, normalize: bool = False) -> PSF:
        """The PSF rebinned onto another square grid, conserving energy.

        Each sample is spread uniformly over its ``pitch²`` cell and each new
        cell receives the energy of the overlap (separable overlap
        matrices), so the result's sum is exactly the energy of the old PSF
        inside the new window — 1 (to rounding) when the new window covers
        the old one. Suited to coarser grids (it integrates, e.g. over a
        pixel aperture); for a finer grid compute the PSF at that pitch.

        Parameters
        ----------
        pitch_um : float
            New spacing, µm.
        n : int
            New size.
        center_mm : (x, y), optional
            New centre sample position (default: the same centre).
        normalize : bool
            Rescale to sum 1 (when the new window cuts off energy).

        Examples
        --------
        >>> p = PSF(np.full((4, 4), 1 / 16), 1.0, (0, 0), (0, 0), (550,), (1,), "test")
        >>> q = p.resample(2.0, 3)
        >>> round(float(q.data.sum()), 12), float(q.data[1, 1])
        (1.0, 0.25)
        """
        if not (math.isfinite(pitch_um) and pitch_um > 0):
            raise PSFError(f"pitch_um must be positive, got {pitch_um!r}")
        n = check_positive_int(n, "n")
        c_new = self.center_mm if center_mm is None else tuple(float(v) for v in center_mm)
        shift = (np.asarray(c_new) - np.asarray(self.center_mm)) * 1e3   # µm, new centre in old frame
        o_old = self.offsets_um()
        o_new = (np.arange(n) - n // 2) * float(pitch_um)

        def overlap(shift_1d):
            a0 = o_old - 0.5 * self.pitch_um
            a1 = o_old + 0.5 * self.pitch_um
            b0 = o_new + shift_1d - 0.5 * pitch_um
            b1 = o_new + shift_1d + 0.5 * pitch_um
            w = np.minimum(b1[:, None], a1[None, :]) - np.maximum(b0[:, None], a0[None, :])
            return np.maximum(w, 0.0) / self.pitch_um

        wx, wy = overlap(shift[0]), overlap(shift[1])
        out = wy @ self.data @ wx.T
        if normalize:
            s = out.sum()
            if s <= 0:
                raise PSFError("the new window holds none of the PSF's energy")
            out = out / s
        return PSF(out, float(pitch_um), c_new, self.field_deg, self.wavelengths_nm, self.weights,
                   f"resampled({self.method})", self.window_energy)


def sample_centroid_um(data: np.ndarray, pitch_um: float) -> np.ndarray:
    """(x, y) intensity centroid of PSF samples ``data`` (rows along +y,
    centre ``data[n//2, n//2]``, pitch ``pitch_um``) relative to the centre
    sample, µm; (0, 0) for samples that sum to 0.

    >>> p = np.zeros((5, 5)); p[2, 3] = 1.0
    >>> sample_centroid_um(p, 0.5).tolist()
    [0.5, 0.0]
    """
    d = np.asarray(data, dtype=np.float64)
    s = d.sum()
    if not s > 0:
        return np.zeros(2)
    n0, n1 = d.shape
    return np.array([float(d.sum(axis=0) @ ((np.arange(n1) - n1 // 2) * pitch_um) / s),
                     float(d.sum(axis=1) @ ((np.arange(n0) - n0 // 2) * pitch_um) / s)])


def ncc(a: np.ndarray, b: np.ndarray) -> float:
    """Normalised cross-correlation of two equally sampled arrays at zero
    lag, ``Σ(a−ā)(b−b̄)/√(Σ(a−ā)² Σ(b−b̄)²)`` (1 = identical up to gain and
    offset).

    >>> ncc(np.arange(4.0), 2 * np.arange(4.0) + 1)
    1.0
    """
    a = np.asarray(a, dtype=np.float64).ravel()
    b = np.asarray(b, dtype=np.float64).ravel()
    if a.shape != b.shape:
        raise PSFError(f"ncc needs equal shapes, got {a.shape} and {b.shape}")
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float(a @ a) * float(b @ b))
    return float(a @ b) / den if den > 0 else 0.0


# -- validation ------------------------------------------------------------------

def check_positive_int(v, name: str) -> int:
    """``v`` as an int, or :class:`PSFError` naming ``name`` unless it is a
    positive integer (a bool is refused)."""
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
        raise PSFError(f"{name} must be a positive integer, got {v!r}")
    return int(v)


def check_field(field_deg) -> tuple[float, float]:
    """A field as (θx, θy) degrees; a scalar is θy (the meridional plane).
    :class:`PSFError` unless both are finite and within ±90°."""
    if np.ndim(field_deg) == 0:
        f = (0.0, float(field_deg))
    else:
        f = tuple(float(v) for v in np.asarray(field_deg, dtype=np.float64).ravel())
        if len(f) != 2:
            raise PSFError(f"field_deg must be θy or (θx, θy) in degrees, got {field_deg!r}")
    if not all(math.isfinite(v) and abs(v) < 90 for v in f):
        raise PSFError(f"field angles must be finite and within ±90°, got {field_deg!r}")
    return f


def check_wavelength(w) -> float:
    """A wavelength in nm as a float; :class:`PSFError` unless positive and finite."""
    w = float(w)
    if not (math.isfinite(w) and w > 0):
        raise PSFError(f"wavelength must be a positive number of nm, got {w!r}")
    return w


def check_aiming(a: str) -> str:
    """A pupil ray aiming, "real" or "paraxial"
    (:func:`calibration.optics.trace.pupil_rays`); :class:`PSFError` otherwise."""
    if a not in ("real", "paraxial"):
        raise PSFError(f"unknown aiming {a!r}; valid: 'real', 'paraxial'")
    return a

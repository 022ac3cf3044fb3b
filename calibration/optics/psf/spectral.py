"""Polychromatic PSFs through a sensor channel's spectral response (paper,
eq. 14).

:func:`spectral_response` is a camera channel's spectral weight
``C(λ) = S(λ)·E(λ)`` (measured camera sensitivities shipped with
colour-science, times an illuminant); :func:`spectral_quadrature` reduces it
to a few Gauss nodes (:data:`DEFAULT_WAVELENGTHS_PER_CHANNEL`);
:func:`polychromatic_psf` sums the monochromatic PSFs of any method
(:mod:`calibration.optics.psf.methods`) at those nodes on one grid;
:func:`channel_quadrature` pools the nodes of several channels, as the PSF
maps compute them.

References: the paper (``../shared/paper``), eq. 14; G. H. Golub and
J. H. Welsch, "Calculation of Gauss quadrature rules", *Math. Comp.* 23
(1969) 221–230.

Imports colour-science (lazily), :mod:`calibration.optics` and
:mod:`~calibration.optics.psf.methods`, :mod:`~calibration.optics.psf.pupil`,
:mod:`~calibration.optics.psf.sampling`, :mod:`~calibration.optics.psf.result`
of this package.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from calibration.optics.lens import Lens
from calibration.optics.perturb import PerturbedLens, nominal
from calibration.optics.psf.methods import check_method, monochromatic_samples
from calibration.optics.psf.pupil import exit_pupil_z, reference_sphere, trace_pupil, trace_pupils
from calibration.optics.psf.result import PSF, PSFError, check_aiming, check_field, check_positive_int
from calibration.optics.psf.sampling import default_pitch_um, grid_offsets_mm, psf_center

__all__ = [
    "DEFAULT_CAMERA",
    "DEFAULT_WAVELENGTHS_PER_CHANNEL",
    "channel_quadrature",
    "polychromatic_psf",
    "spectral_quadrature",
    "spectral_response",
]


DEFAULT_CAMERA = "Nikon 5100 (NPL)"
"""Measured camera sensitivities used for the "R", "G", "B" channels
(``colour.MSDS_CAMERA_SENSITIVITIES``, NPL measurements shipped with
colour-science; the only other entry is "Sigma SDMerill (NPL)"). No phone
sensor is in that set: pass measured phone curves as ``(wavelengths, weights)``
where they are known."""

DEFAULT_WAVELENGTHS_PER_CHANNEL = 3
"""Gauss nodes per channel (see :func:`spectral_quadrature`). Measured on
US-12210142-B2-e9 (Debye PSFs 48² at 0.25 µm centred on the primary chief
ray, D65 × Nikon 5100, worst of R/G/B), largest |PSF − dense 5 nm sum| /
peak (the dense sum has 56–60 wavelengths):

========  =========  =========  =========
nodes     on axis    0.7 field  1.0 field
========  =========  =========  =========
1         1.5 %      7.0 %      17 %
2         0.19 %     0.88 %     4.9 %
3         0.03 %     0.16 %     1.5 %
4         0.01 %     0.06 %     0.64 %
========  =========  =========  =========

(NCC ≥ 0.9998 with 3 nodes everywhere; ``benchmarks/psf.py --quadrature``).
Lateral colour spreads the wavelengths apart toward the corners, so the
error grows with field."""


def spectral_response(channel: str, *, camera: str = DEFAULT_CAMERA, illuminant: str = "D65"
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The spectral weight ``C(λ) = S_channel(λ)·E_illuminant(λ)`` of a
    camera channel, on the camera data's grid.

    Parameters
    ----------
    channel : {"R", "G", "B"}
    camera : str
        A key of ``colour.MSDS_CAMERA_SENSITIVITIES`` (default
        :data:`DEFAULT_CAMERA`; no phone sensor is in that set).
    illuminant : str
        A key of ``colour.SDS_ILLUMINANTS`` (default CIE D65).

    Returns
    -------
    wavelengths_nm : (K,) ndarray
        380–780 nm in 5 nm steps for the NPL data.
    weights : (K,) ndarray
        ``C(λ)`` normalised to sum 1 (≥ 0).
    """
    import colour

    names = {"R": 0, "G": 1, "B": 2}
    key = str(channel).upper()
    if key not in names:
        raise PSFError(f"unknown channel {channel!r}; valid: 'R', 'G', 'B', or (wavelengths_nm, weights)")
    if camera not in colour.MSDS_CAMERA_SENSITIVITIES:
        raise PSFError(f"unknown camera {camera!r}; valid: {sorted(colour.MSDS_CAMERA_SENSITIVITIES)}")
    if illuminant not in colour.SDS_ILLUMINANTS:
        raise PSFError(f"unknown illuminant {illuminant!r}; e.g. 'D65', 'A', 'D50', 'FL2'")
    cam = colour.MSDS_CAMERA_SENSITIVITIES[camera]
    wl = np.asarray(cam.wavelengths, dtype=np.float64)
    s = np.asarray(cam.values, dtype=np.float64)[:, names[key]]
    e = np.asarray(colour.SDS_ILLUMINANTS[illuminant].copy().align(colour.SpectralShape(wl[0], wl[-1], wl[1] - wl[0]))
                   [wl], dtype=np.float64)
    c = np.clip(np.nan_to_num(s * e), 0.0, None)
    return wl, c / c.sum()


def spectral_quadrature(wavelengths_nm, weights, n: int) -> tuple[np.ndarray, np.ndarray]:
    """An ``n``-node Gauss rule for the discrete spectral measure
    ``Σ_j weights_j δ(λ − λ_j)``.

    The nodes and weights integrate every polynomial in λ of degree
    ≤ 2n − 1 exactly against ``weights`` (Golub & Welsch, *Math. Comp.* 23
    (1969) 221–230: eigen-decomposition of the Jacobi matrix, built here by
    the Lanczos process with full reorthogonalisation). Nodes lie inside the
    measure's support; weights are positive and keep the total.

    Returns
    -------
    nodes_nm, node_weights : (n,) ndarrays
        Ascending nodes; with ``n`` ≥ the number of positive weights, the
        input points themselves.

    >>> x, w = spectral_quadrature([500.0, 550.0, 600.0], [0.25, 0.5, 0.25], 1)
    >>> x.round(9).tolist(), w.round(9).tolist()
    ([550.0], [1.0])
    """
    x = np.asarray(wavelengths_nm, dtype=np.float64).ravel()
    w = np.asarray(weights, dtype=np.float64).ravel()
    if x.shape != w.shape or not len(x):
        raise PSFError(f"wavelengths and weights must be equal-length non-empty 1-D, got {x.shape} and {w.shape}")
    if np.any(w < 0) or not np.all(np.isfinite(w)) or not np.all(np.isfinite(x)) or w.sum() <= 0:
        raise PSFError("spectral weights must be finite, ≥ 0 and not all 0")
    n = check_positive_int(n, "n")
    keep = w > 0
    x, w = x[keep], w[keep]
    total = float(w.sum())
    if n >= len(x):
        order = np.argsort(x)
        return x[order], w[order]
    mu, sc = float(np.average(x, weights=w)), float(np.ptp(x)) or 1.0
    t = (x - mu) / sc
    qs = [np.sqrt(w / total)]
    alpha, beta = [], []
    for j in range(n):
        v = t * qs[j]
        alpha.append(float(qs[j] @ v))
        for qq in qs:                       # full reorthogonalisation (twice is enough)
            v -= (qq @ v) * qq
        for qq in qs:
            v -= (qq @ v) * qq
        if j < n - 1:
            b = float(np.linalg.norm(v))
            if b < 1e-14:
                break
            beta.append(b)
            qs.append(v / b)
    m = len(alpha)
    jac = np.diag(alpha) + np.diag(beta[:m - 1], 1) + np.diag(beta[:m - 1], -1)
    ev, vec = np.linalg.eigh(jac)
    return ev * sc + mu, total * vec[0] ** 2


def channel_quadrature(channels: Sequence[str], n_wavelengths: int, camera: str = DEFAULT_CAMERA,
                       illuminant: str = "D65") -> tuple[np.ndarray, np.ndarray]:
    """The Gauss nodes of several channels, pooled.

    Parameters
    ----------
    channels : sequence of {"R", "G", "B"}
    n_wavelengths : int
        Nodes per channel (:func:`spectral_quadrature`).
    camera, illuminant : str
        As :func:`spectral_response`.

    Returns
    -------
    nodes_nm : (K,) ndarray
        Every channel's nodes (rounded to 1e-9 nm), ascending; a node two
        channels share is computed once.
    weights : (C, K) ndarray
        Each channel's node weights (each row sums to 1).
    """
    per = []
    for ch in channels:
        wl, c = spectral_response(ch, camera=camera, illuminant=illuminant)
        x, w = spectral_quadrature(wl, c, n_wavelengths)
        per.append((np.round(x, 9), w / w.sum()))
    nodes = np.unique(np.concatenate([x for x, _ in per]))
    weights = np.zeros((len(channels), len(nodes)))
    for i, (x, w) in enumerate(per):
        for xv, wv in zip(x, w):
            weights[i, np.searchsorted(nodes, xv)] += wv
    return nodes, weights


def _response(response, n_wavelengths, camera, illuminant) -> tuple[np.ndarray, np.ndarray]:
    """(nodes, weights summing to 1) of a channel name or (wavelengths, weights)."""
    if isinstance(response, str):
        wl, c = spectral_response(response, camera=camera, illuminant=illuminant)
        n_wl = DEFAULT_WAVELENGTHS_PER_CHANNEL if n_wavelengths is None else n_wavelengths
    else:
        try:
            wl, c = (np.asarray(a, dtype=np.float64).ravel() for a in response)
        except (TypeError, ValueError):
            raise PSFError(f"response must be 'R', 'G', 'B' or (wavelengths_nm, weights), got {response!r}") from None
        n_wl = len(wl) if n_wavelengths is None else n_wavelengths
    x, w = spectral_quadrature(wl, c, n_wl)
    return x, w / w.sum()


def polychromatic_psf(lens: Lens | PerturbedLens, field_deg, response, *, method: str = "huygens",
                      n_wavelengths: int | None = None, camera: str = DEFAULT_CAMERA, illuminant: str = "D65",
                      pupil_samples: int | None = None, n: int | None = None, pitch_um: float | None = None,
                      center="chief", aiming: str = "real", aim_each_wavelength: bool = True) -> PSF:
    """The PSF of a sensor channel: ``∫ C(λ)·PSF(λ) dλ`` (paper eq. 14).

    Parameters
    ----------
    lens : Lens or PerturbedLens
    field_deg : float or (θx, θy)
    response : {"R", "G", "B"} or (wavelengths_nm, weights)
        A channel of ``camera`` under ``illuminant`` (:func:`spectral_response`),
        or a sampled spectral weight ``C(λ)`` (any scale).
    method : {"huygens", "fft", "debye"}
    n_wavelengths : int, optional
        Gauss nodes of :func:`spectral_quadrature`; default
        :data:`DEFAULT_WAVELENGTHS_PER_CHANNEL` for a channel name, every
        given wavelength for arrays.
    camera, illuminant : str
        For channel names.
    pupil_samples, n : int, optional
        Defaults of :func:`~calibration.optics.psf.huygens.huygens_psf` /
        :func:`~calibration.optics.psf.fft.fft_psf` /
        :func:`~calibration.optics.psf.debye.debye_psf` by ``method``.
    pitch_um : float, optional
        Default ``λ_min·N_w/4`` over the nodes.
    center : {"chief", "centroid"} or (x, y)
        One centre for every wavelength: the chief ray at the lens's
        primary wavelength (so lateral colour shows as a shift between
        channels), the spectrally weighted ray centroid, or a point (mm).
    aiming : {"real", "paraxial"}
    aim_each_wavelength : bool
        Real aiming at every wavelength (True), or once at the primary
        wavelength for all (False: half the tracing, ≤ 0.6 % of the peak on
        e9; see :func:`calibration.optics.psf.pupil.trace_pupils`).

    Returns
    -------
    PSF
        Sum of the per-wavelength PSFs (each normalised to 1 on the common
        grid) with the node weights; ``wavelengths_nm`` and ``weights`` are
        the nodes.
    """
    check_method(method)
    pl = nominal(lens)
    f = check_field(field_deg)
    nodes, w = _response(response, n_wavelengths, camera, illuminant)
    samples = check_positive_int(pupil_samples if pupil_samples is not None else (128 if method == "fft" else 64),
                                 "pupil_samples")
    n = check_positive_int(n if n is not None else (256 if method == "fft" else 128), "n")
    aiming = check_aiming(aiming)
    z_pupil = exit_pupil_z(pl)
    traced = trace_pupils(pl, f, nodes, samples, aiming, z_pupil, bool(aim_each_wavelength))
    ref = None
    if isinstance(center, str) and center == "chief":
        primary = float(pl.nominal.primary_nm)
        ref = next((t for t in traced if t.wavelength_nm == primary), None)
        ref = ref if ref is not None else trace_pupil(pl, f, primary, samples, aiming, z_pupil)
    c = psf_center(traced, w, center, ref)
    pitch = default_pitch_um(pl, float(nodes.min())) if pitch_um is None else float(pitch_um)
    o = grid_offsets_mm(n, pitch)
    data = np.zeros((n, n))
    energy = 0.0
    for t, wk in zip(traced, w):
        d, e = monochromatic_samples(reference_sphere(t, c), method, o, o)
        data += wk * d
        energy += wk * e
    return PSF(data, pitch, (float(c[0]), float(c[1])), f, tuple(nodes), tuple(w), method, energy)

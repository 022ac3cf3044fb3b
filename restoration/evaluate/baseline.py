"""Classical non-blind deconvolution with the true PSF: the baseline the
learned correction is evaluated against (``isp eval --baseline``).

It runs where the model runs — on the correction slot's input ``J``
(balanced camera RGB after demosaic) — and is handed what a non-blind
method is allowed to know: the PSF map of the lens that blurred the crop,
where the crop lies on the sensor, and the noise level of the capture.

Spatially varying PSF
---------------------
The synthesis blurs with a PSF interpolated bilinearly between region
centres (:class:`restoration.synth.optics.CropBlur`: ``y = Σ_r w_r ·
(x ⊛ h_r)`` with tent weights ``w_r``). The baseline mirrors it on the
inverse side: every region ``r`` whose weight is non-zero somewhere in the
crop deconvolves the part of the crop it covers (plus a reflected margin
of the kernel's reach and 8 px) with its own PSF ``h_r``, and the results
are blended with the same weights,

.. math::

    \\hat x = \\sum_r w_r \\cdot \\mathrm{deconv}(J, h_r),

a blend of overlapping region tiles with no seam (the weights sum to 1).
``blend="nearest"`` gives one PSF per region, as the paper's maps.

The two deconvolutions
----------------------
``"wiener"`` — :func:`skimage.restoration.wiener`, the Wiener–Hunt
deconvolution with a Laplacian regulariser ``L``:

.. math::

    \\hat X = \\frac{H^*}{|H|^2 + \\lambda |L|^2}\\, Y,\\qquad
    \\lambda = \\max_c \\frac{\\sigma_c^2}{s_c^2} + \\lambda_0,\\quad
    s_c^2 = \\max\\big(\\mathrm{var}(L ⊛ J_c) - \\lVert L\\rVert^2 \\sigma_c^2,\\;
    0.05\\,\\mathrm{var}(L ⊛ J_c)\\big)

``σ_c²/s_c²`` is the MAP balance of channel ``c`` under white Gaussian
noise of variance ``σ_c²`` and a white Gaussian prior of variance ``s_c²``
on the Laplacian of the sharp image. ``σ_c²`` is the NoiseProfile's
variance at the channel's mean level, taken to the balanced domain
(``(S·n_c·J̄_c + O)/n_c²``, ``n`` the camera neutral; quantisation ``Δ²/12``
added); ``s_c²`` is estimated from the observation itself (``‖L‖² = 20``
for the 5-point Laplacian, whose noise contribution is removed).

Two choices were made on measurements, not derived (regression values:
e9 proxy, 6 Kodak images × 3 rings, 128-px crops, noise off and scaled
×0.02, ×0.5–2 and ×2; PSNR in sRGB after ``Process``):

* **one balance for the three channels, the largest**: the CCM after the
  slot mixes the channels, so the noisiest channel's noise reaches every
  output channel. Per-channel balances gained 0.3–0.7 dB less (noise
  ×0.5–2: +0.2–0.3 dB over the uncorrected image against +0.7–0.8 dB).
* **a floor** ``λ₀ = 0.003``: what is left when the capture has no noise
  — the demosaic's interpolation error and the PSF map's own
  interpolation — is not in ``σ²``. Without noise, λ₀ = 0 lost 0.95 dB
  to the uncorrected image at the centre; 0.001, 0.003 and 0.01 gained
  +0.3, +0.9 and +0.9 dB there (+1.6, +1.7, +1.5 dB at FoV 0.9); 0.003
  also did best at noise ×0.02.

``λ`` is kept in ``[1e-4, 10]``.

``"rl"`` — :func:`skimage.restoration.richardson_lucy` with 30
iterations (its regularisation is early stopping; 30 is the common choice
for mildly blurred, low-noise images), on ``max(J, 0)``. It does not look
at the noise level: on the default synthesis noise (×0.5–2 of the phone's
NoiseProfile, up to 2 EV of compression) it amplifies noise and loses PSNR
(e9, 2 Kodak images: −2.5 dB at FoV 0.1, −0.4 dB at 0.9; Wiener gained
+0.8 dB at 0.9), and costs ≈ 5 s per 320-px crop against ≈ 0.4 s.

References
----------
* N. Wiener, *Extrapolation, Interpolation, and Smoothing of Stationary
  Time Series*, MIT Press, 1949; B. R. Hunt, "A matrix theory proof of the
  discrete convolution theorem", IEEE Trans. Audio Electroacoust. 19(4),
  285–288, 1971 (the Laplacian-regularised form of scikit-image).
* W. H. Richardson, "Bayesian-based iterative method of image
  restoration", JOSA 62(1), 55–59, 1972; L. B. Lucy, "An iterative
  technique for the rectification of observed distributions", AJ 79, 745,
  1974.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from isp.errors import ConfigError

__all__ = ["BASELINES", "Deconvolution", "centred_kernel", "deconvolve", "noise_variance", "wiener_balance"]

#: methods by name (``"none"``: no baseline)
BASELINES = ("wiener", "rl", "none")
#: 5-point Laplacian of scikit-image's Wiener regulariser, and its squared norm
LAPLACIAN = np.array([[0.0, -1.0, 0.0], [-1.0, 4.0, -1.0], [0.0, -1.0, 0.0]], np.float32)
LAPLACIAN_NORM2 = 20.0
#: bounds of the Wiener balance λ, and the floor λ₀ added to the noise term
BALANCE_RANGE = (1e-4, 10.0)
BALANCE_FLOOR = 0.003
#: Richardson–Lucy iterations
RL_ITERATIONS = 30


def _check_method(method: str) -> str:
    if method not in BASELINES:
        raise ConfigError(f"unknown baseline {method!r}; valid: {', '.join(BASELINES)}")
    return method


def centred_kernel(kernel) -> np.ndarray:
    """A :class:`calibration.simulate.optical_image.Kernel` (pixel pitch) as an odd
    square array with its zero offset at the centre, the convention of
    scikit-image's deconvolutions (``ir2tf`` rolls ``shape // 2`` to 0).

    >>> from calibration.simulate.optical_image import Kernel
    >>> centred_kernel(Kernel(np.array([[1.0, 0.0]]), 1.0, (0, 1))).tolist()
    [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    """
    data = np.asarray(kernel.data, dtype=np.float64)
    ar, ac = kernel.anchor
    h, w = data.shape
    a = max(ar, h - 1 - ar, ac, w - 1 - ac, 0)
    out = np.zeros((2 * a + 1, 2 * a + 1))
    out[a - ar:a - ar + h, a - ac:a - ac + w] = data
    return out


def noise_variance(image: np.ndarray, noise_profile, neutral, quantisation_step: float = 0.0) -> np.ndarray:
    """Per-channel noise variance of balanced camera RGB at its mean level.

    Parameters
    ----------
    image : (h, w, 3) ndarray
        Balanced camera RGB (the slot's input).
    noise_profile : (S, O)
        Of the capture (variance ``S·m + O`` at raw level ``m``, 0..1).
    neutral : (3,) array_like
        Camera neutral (the white-balance gains are ``1 / neutral``).
    quantisation_step : float
        Raw quantisation step (0..1 scale); adds ``Δ²/12``.

    Returns
    -------
    (3,) ndarray, float64: variances in the balanced domain.
    """
    s, o = (float(v) for v in noise_profile)
    n = np.asarray(neutral, dtype=np.float64)
    mean = np.maximum(np.asarray(image, dtype=np.float64).mean(axis=(0, 1)), 0.0)
    raw = mean * n
    return (s * raw + o + quantisation_step ** 2 / 12.0) / (n * n)


def wiener_balance(image: np.ndarray, sigma2) -> float:
    """The balance ``λ`` of the module Notes for a crop.

    Parameters
    ----------
    image : (h, w, 3) ndarray
        Balanced camera RGB.
    sigma2 : (3,) array_like
        Noise variance per channel (:func:`noise_variance`).
    """
    import cv2

    ratios = []
    for c in range(3):
        lap = cv2.filter2D(np.asarray(image[:, :, c], dtype=np.float32), -1, LAPLACIAN,
                           borderType=cv2.BORDER_REFLECT_101)
        v = float(lap.var(dtype=np.float64))
        s2 = max(v - LAPLACIAN_NORM2 * float(sigma2[c]), 0.05 * v, 1e-12)
        ratios.append(float(sigma2[c]) / s2)
    lo, hi = BALANCE_RANGE
    return float(min(max(max(ratios) + BALANCE_FLOOR, lo), hi))


@dataclass(frozen=True)
class Deconvolution:
    """What one baseline run used (for the report)."""

    method: str
    balance: float | None       # the Wiener balance λ
    regions: int


def deconvolve(image: np.ndarray, bank, origin: tuple[int, int], size_px: tuple[int, int], *,
               method: str = "wiener", sigma2=None, blend: str = "bilinear") -> tuple[np.ndarray, Deconvolution]:
    """Non-blind deconvolution of a crop with the spatially varying PSF
    (module Notes).

    Parameters
    ----------
    image : (h, w, 3) ndarray
        Balanced camera RGB of the crop.
    bank : calibration.simulate.optical_image.KernelBank
        The PSF map's kernels (``CropBlur.bank``).
    origin : (row, col)
        Sensor pixel of ``image[0, 0]``.
    size_px : (H, W)
        The sensor (the frame the map's regions divide).
    method : {"wiener", "rl"}
    sigma2 : (3,) array_like, optional
        Noise variance per channel (:func:`noise_variance`); needed by
        ``"wiener"``.
    blend : {"bilinear", "nearest"}
        How region results are combined (as the blur was made).

    Returns
    -------
    (h, w, 3) float32 ndarray, and a :class:`Deconvolution` record.
    """
    from skimage.restoration import richardson_lucy, wiener

    _check_method(method)
    if method == "none":
        return np.asarray(image, np.float32), Deconvolution("none", None, 0)
    img = np.asarray(image, dtype=np.float64)
    h, w = img.shape[:2]
    if method == "wiener":
        if sigma2 is None:
            raise ConfigError("the Wiener baseline needs the noise variance (sigma2)")
        balance = wiener_balance(img, sigma2)
    else:
        balance = None
    ys = np.arange(h, dtype=np.float64) + float(origin[0])
    xs = np.arange(w, dtype=np.float64) + float(origin[1])
    wys = bank.axis_weights(0, ys, blend, size_px)
    wxs = bank.axis_weights(1, xs, blend, size_px)
    kernels = {}
    for ri, _ in wys:
        for ci, _ in wxs:
            for c in range(3):
                kernels[ri, ci, c] = centred_kernel(bank.resampled((ri, ci), c, 1.0))
    pad = max(k.shape[0] for k in kernels.values()) // 2 + 8
    padded = np.pad(img, ((pad, pad), (pad, pad), (0, 0)), mode="symmetric")
    out = np.zeros((h, w, 3), np.float64)
    for ri, wy in wys:
        rsel = np.nonzero(wy > 0)[0]
        r0, r1 = int(rsel[0]), int(rsel[-1]) + 1
        for ci, wx in wxs:
            csel = np.nonzero(wx > 0)[0]
            c0, c1 = int(csel[0]), int(csel[-1]) + 1
            wt = wy[r0:r1, None] * wx[None, c0:c1]
            for c in range(3):
                tile = padded[r0:r1 + 2 * pad, c0:c1 + 2 * pad, c]
                k = kernels[ri, ci, c]
                if method == "wiener":
                    d = wiener(tile, k, balance, clip=False)
                else:
                    d = richardson_lucy(np.maximum(tile, 0.0), k, num_iter=RL_ITERATIONS, clip=False)
                out[r0:r1, c0:c1, c] += wt * d[pad:pad + r1 - r0, pad:pad + c1 - c0]
    return out.astype(np.float32), Deconvolution(method, balance, len(wys) * len(wxs))


def quantisation_step(white_level: float, black_level: float) -> float:
    """One DN on the 0..1 scale after black level (``1 / (white − black)``)."""
    span = float(white_level) - float(black_level)
    return 1.0 / span if span > 0 and math.isfinite(span) else 0.0

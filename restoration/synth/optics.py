"""The optics of data synthesis: proxy-camera lenses, lenses drawn within
tolerance, their PSF maps, and the spatially varying blur of a crop
(paper, section 4.1, eq. 23 "optical degraded observation": ``J_e = ∫ C_e(λ)·I(λ) dλ ⊗ L_e + N_e``).

Single sample and multiple samples
----------------------------------
``samples = 1`` blurs with the proxy lens itself (the paper's "single
sample"). ``samples = N > 1`` adds ``N − 1`` lenses drawn around it: every
default tolerance parameter of :func:`calibration.optics.perturb.default_names`
(curvatures, conics, thicknesses, element decenters and tilts, materials)
gets a delta uniform in ``±tolerance_scale × tolerance``
(:meth:`calibration.optics.perturb.ParameterSpace.sample`, the paper's "max bias
of each system parameter as the tolerance"), added to the proxy's own
perturbation, then the lens is refocused as assembly does: the image
distance moves by the drawn lens's best-focus shift relative to the proxy
(:func:`calibration.optics.spot.best_focus`), so a draw is a plausible *device*
and not a defocused one.

PSF maps
--------
:func:`calibration.optics.psf.map.psf_map` (the paper's 15 × 20 regions, 3
channels), cached on disk under the SHA-256 of the perturbed lens and the
settings: a second run over the same lenses reads them back (one lens:
≈ 15 s on 2 cores the first time for a coaxial lens, ≈ 25–55 s with
decenters, which need all 300 regions).

Blur
----
:func:`calibration.simulate.capture.blur_image` with ``blend="bilinear"``: every
region's PSF (integrated over the pixel cells) convolves the tile where its
weight is non-zero, and the results are blended by tent weights between
region centres. Since ``Σ_r w_r(x)·(I ⊗ h_r)(x) = (I ⊗ Σ_r w_r(x) h_r)(x)``
pointwise, this *is* per-pixel PSF interpolation (bilinear between the
region centres), computed as overlapping tiles. ``blend="nearest"`` is the
paper's piecewise-constant PSF per field patch.

The interpolation acts on the kernel each *output* pixel gathers with, so
every output pixel's kernel sums to 1 (a flat field stays flat, the mean of
a scene is kept); the energy of a single point is kept exactly only where
the PSF does not vary, and to first order in its change across the PSF's
width elsewhere (tested).

Error of the shortcuts against a per-pixel-varying reference: PSFs
computed with the map's own settings on a 4-px lattice over a 48 × 48
window and interpolated between them (the reference moves by 0.13 % of the
blur when its lattice goes from 8 to 4 px); a kodim05 crop in linear RGB;
lens e9, windows straddling a corner of four regions, near the sensor
corner and at 0.7 of the field. RMS error in % of the RMS of the blur
itself (reference − sharp), and PSNR on the 0..1 scale
(``benchmarks/synth.py``):

========================================  ================  ================
shortcut                                  corner            0.7 field
========================================  ================  ================
bilinear, 15 × 20 map (**default**)       6.1 %  (46.0 dB)  2.5 %  (54.8 dB)
bilinear, 30 × 40 map (``grid=``)         2.0 %  (55.5 dB)  0.8 %  (64.8 dB)
nearest: one PSF per region (paper)       17.1 % (37.0 dB)  10.7 % (42.2 dB)
one PSF per 256-px crop, at its centre    6.3 %  (45.7 dB)  2.3 %  (55.4 dB)
the same, 128 px from the crop's centre   18.5 % (36.3 dB)  11.4 % (41.6 dB)
FFT (float32) vs direct convolution       < 1e-6            < 1e-6
========================================  ================  ================

Per 256² crop (+ 13-px context, 3 channels, 2 shared cores under load):
bilinear by FFT ≈ 40–100 ms, nearest ≈ 15–40 ms, bilinear by direct
convolution (``calibration.simulate.capture.blur_image``) ≈ 47–117 ms. The
interpolation error falls as the square of the region size (×4 regions →
÷3); a denser map costs its PSFs once (30 × 40: ≈ 2 min, cached).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from calibration.simulate.device import draw_lenses
from isp.errors import InputError

__all__ = ["CropBlur", "blur_crop", "draw_lenses", "load_lens", "map_margin_px", "psf_maps",
           "psf_options", "window_reach_px"]

#: default settings of the synthesis's PSF maps (the rest: those of
#: :func:`calibration.optics.psf.map.psf_map`). The window: ``n`` None is
#: psf_map's 32 µm (:data:`calibration.optics.psf.map.WINDOW_UM`; 64 samples of
#: half a pixel on e9's 1 µm pixels). A lens drawn within tolerance throws
#: light far out, and a 16 µm window drops up to 32 % of a corner PSF of
#: the default training set's lenses (2.5 % even at the centre), so the
#: pairs would be blurred less than the lenses blur; at 32 µm every region
#: keeps ≥ 95 % (the same lenses), for 1.3× the map's cost. The window is
#: set in µm, not samples: a fixed 64 samples would give pairs made at
#: 2.8 µm pixels (``--pixel-um``) a 90 µm window, past the pupil sampling's
#: replica period.
PSF_DEFAULTS = {"grid": (15, 20), "n": None}


def load_lens(path):
    """A lens file (lens/v1, Zemax .zmx, ...) or a fitted proxy file (lens/v1
    with a ``perturbation``) as a :class:`calibration.optics.perturb.PerturbedLens`.

    Raises
    ------
    InputError
        Missing, unreadable or invalid file (one line naming it).
    """
    from calibration.optics.lens import LensError
    from calibration.fit.proxy import load_proxy

    try:
        return load_proxy(path)
    except FileNotFoundError:
        raise InputError(path, "no such lens file") from None
    except IsADirectoryError:
        raise InputError(path, "is a folder, not a lens file") from None
    except LensError as e:
        msg = str(e)
        raise InputError(None, msg if str(path) in msg else f"{path}: {msg}") from None


def psf_maps(lenses: Sequence, *, executor=None, cache_dir=None, **options) -> list:
    """PSF maps of the lenses (:func:`calibration.optics.psf.map.psf_map`, cached on
    disk), computed one lens after the other, ``executor`` (an
    :class:`isp.runtime.executor.Executor`; default psf_map's) running the
    regions. ``options`` are :class:`calibration.optics.psf.map.PSFMapSettings`
    fields (grid, n, method, ...) over :data:`PSF_DEFAULTS`."""
    from calibration.optics.psf.map import PSFMapSettings, psf_map

    settings = PSFMapSettings(**psf_options(options))
    return [psf_map(pl, settings, cache_dir=cache_dir, executor=executor) for pl in lenses]


def map_margin_px(psfmap) -> int:
    """Pixels of context a crop needs so that its inner part is blurred as
    in the full frame: the PSF window's reach on the sensor (half its
    diagonal), rounded up."""
    if psfmap is None:
        return 0
    return window_reach_px(psfmap.n, psfmap.pitch_um, psfmap.sensor.pixel_pitch_um)


def window_reach_px(n: int | None, pitch_um: float | None, pixel_pitch_um: float) -> int:
    """:func:`map_margin_px` before the map exists: an ``n``-sample window
    (None: psf_map's default, :func:`calibration.optics.psf.map.default_psf_n`)
    at ``pitch_um`` (default half a pixel) on pixels of ``pixel_pitch_um``."""
    from calibration.optics.psf.map import default_psf_n

    pitch = float(pitch_um or 0.5 * pixel_pitch_um)
    n = default_psf_n(pitch) if n is None else int(n)
    return math.ceil(0.5 * n * pitch / pixel_pitch_um * math.sqrt(2.0)) + 1


def psf_options(options: dict | None = None) -> dict:
    """:data:`PSF_DEFAULTS` updated with ``options`` (keys of
    :func:`calibration.optics.psf.map.psf_map`)."""
    return {**PSF_DEFAULTS, **(options or {})}


class CropBlur:
    """The spatially varying blur of :func:`calibration.simulate.capture.blur_image`
    for crops of a PSF map's sensor, by FFT: one forward transform per
    channel, one product and inverse transform per region the crop
    touches (instead of one direct 2-D convolution per region), in float32.

    ``blur_image`` stays the readable oracle: the two agree to ~1e-6 of
    the signal away from the crop's border (``tests/restoration/synth/test_optics.py``); within
    :func:`map_margin_px` of it, this one sees zeros and ``blur_image`` the
    border replicated — callers crop that band off.

    Parameters
    ----------
    psfmap : PSFMap
    blend : {"bilinear", "nearest"}
    """

    def __init__(self, psfmap, blend: str = "bilinear"):
        from calibration.simulate.optical_image import KernelBank

        if blend not in ("bilinear", "nearest"):
            raise ValueError(f"unknown blend {blend!r}; valid: 'bilinear', 'nearest'")
        self.bank = KernelBank.from_psf(psfmap)
        self.size = (psfmap.sensor.height_px, psfmap.sensor.width_px)
        self.blend = blend
        self.reach = map_margin_px(psfmap) + 1
        self._spectra: dict = {}

    def _kernel(self, key) -> tuple[np.ndarray, tuple[int, int]]:
        k = self.bank.resampled(key[:2], key[2], 1.0)
        data, (ar, ac) = k.data, k.anchor
        pr0, pc0 = max(0, -ar), max(0, -ac)
        pr1, pc1 = max(0, ar - data.shape[0] + 1), max(0, ac - data.shape[1] + 1)
        if pr0 or pc0 or pr1 or pc1:
            data = np.pad(data, ((pr0, pr1), (pc0, pc1)))
        return np.asarray(data, dtype=np.float32), (ar + pr0, ac + pc0)

    def _spectrum(self, key, shape):
        from scipy import fft as sfft

        hit = self._spectra.get((key, shape))
        if hit is None:
            data, anchor = self._kernel(key)
            hit = (sfft.rfft2(data, shape, workers=1), anchor)
            if len(self._spectra) >= 64:                      # bounded: ~27 spectra per crop
                self._spectra.pop(next(iter(self._spectra)))
            self._spectra[(key, shape)] = hit
        return hit

    def __call__(self, image: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        """Blur ``image`` ((h, w, 3) linear camera RGB) whose first pixel is
        sensor pixel ``origin``; returns (h, w, 3) float32."""
        from scipy import fft as sfft

        img = np.asarray(image, dtype=np.float32)
        h, w = img.shape[:2]
        ext = 2 * self.reach + 1
        shape = (sfft.next_fast_len(h + ext, True), sfft.next_fast_len(w + ext, True))
        ys = np.arange(h, dtype=np.float64) + float(origin[0])
        xs = np.arange(w, dtype=np.float64) + float(origin[1])
        wys = self.bank.axis_weights(0, ys, self.blend, self.size)
        wxs = self.bank.axis_weights(1, xs, self.blend, self.size)
        out = np.zeros((h, w, 3), np.float32)
        for c in range(3):
            spec = sfft.rfft2(img[:, :, c], shape, workers=1)
            for ri, wy in wys:
                rsel = np.nonzero(wy > 0)[0]
                r0, r1 = rsel[0], rsel[-1] + 1
                for ci, wx in wxs:
                    csel = np.nonzero(wx > 0)[0]
                    c0, c1 = csel[0], csel[-1] + 1
                    ks, (ar, ac) = self._spectrum((ri, ci, c), shape)
                    full = sfft.irfft2(spec * ks, shape, workers=1)
                    wt = (wy[r0:r1, None] * wx[None, c0:c1]).astype(np.float32)
                    out[r0:r1, c0:c1, c] += wt * full[ar + r0:ar + r1, ac + c0:ac + c1]
        return out


def blur_crop(image: np.ndarray, psfmap, origin: tuple[int, int], *, blend: str = "bilinear") -> np.ndarray:
    """Blur a crop of the sensor with the PSFs of where it lies (the
    readable path: :func:`calibration.simulate.capture.blur_image`; :class:`CropBlur`
    is the fast one).

    Parameters
    ----------
    image : (h, w, 3) ndarray
        Linear camera RGB of the crop (scene at pixel resolution).
    psfmap : PSFMap or None
        None: no blur (an ideal lens; used by the tests).
    origin : (row, col)
        Sensor pixel of ``image[0, 0]`` (may be negative near the border).
    blend : {"bilinear", "nearest"}

    Returns
    -------
    (h, w, 3) ndarray, float32. Pixels within :func:`map_margin_px` of the
    crop's border see the border replicated: callers crop them off.
    """
    if psfmap is None:
        return np.asarray(image, dtype=np.float32)
    from calibration.simulate.capture import blur_image

    sensor = psfmap.sensor
    out = blur_image(image, psfmap, blend=blend, size_px=(sensor.height_px, sensor.width_px),
                     origin=(int(origin[0]), int(origin[1])))
    return out.astype(np.float32)

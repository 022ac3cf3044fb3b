"""Simulated captures: edge imaging and whole charts through a proxy camera
(paper, section 3.1.2, eq. 14; section 4.1, eq. 15).

The forward model, per colour channel ``c`` (R, G, B) and pixel ``x``:

.. math::

    J(\\mathbf{x}) = Q\\Big(\\mathrm{RI}(\\mathbf{x})\\,\\varepsilon\\,
        \\big[(L_c \\otimes h_{c,r(\\mathbf{x})}) \\otimes A\\big](\\mathbf{x})
        + N\\Big),\\qquad c = \\mathrm{CFA}(\\mathbf{x})

* ``L_c`` the scene in camera channel ``c`` (linear; 1 reaches the white
  level at exposure ``ε = 1`` and RI 1), ``h_{c,r}`` the PSF of channel ``c``
  (the sensor's spectral response is inside it, eq. 14) in the PSF-map
  region ``r`` that holds the pixel (or blended between regions),
* ``A`` the square pixel aperture (side ``sqrt(fill factor)``), then Bayer
  sampling: each site keeps its filter's channel,
* ``RI`` the relative illumination (:mod:`calibration.optics.illumination`),
* ``N`` Poisson–Gaussian noise of the DNG NoiseProfile and ``Q`` the
  quantisation to DN with black level and clipping at white
  (:mod:`calibration.simulate.sensor`).

Rendering (:mod:`calibration.simulate.optical_image`): straight edges exactly (a
1-D profile per edge direction: the PSF's samples projected on the edge
normal, convolved with the projected pixel aperture — no supersampling
error), polygon corners on an ``s × s`` supersampled grid with exact
sub-cell coverage (default s = 8), raster scenes by per-region-tile
convolution (``cv2.filter2D``) with the regions' results blended
bilinearly between region centres (``blend="bilinear"``, seamless) or
taken per region (``"nearest"``, the paper's piecewise-constant "PSF per
field patch", with a step at region borders). Geometric distortion is not
simulated: a PSF is applied about its centre sample (the chief ray), so
lateral colour between channels is kept but the image is not warped.

The DNG a capture is written to carries what a phone's does: CFA, black and
white levels, NoiseProfile, ColorMatrix1 (D65) and AsShotNeutral of the demo
camera (:mod:`calibration.simulate.scene`: camera RGB = ``CAMERA_MIX`` · linear sRGB),
lens name, F-number and focal length, and four per-CFA-phase GainMaps in
OpcodeList2 (``17 × 23`` points by default) that undo the relative
illumination, so ``isp process`` treats a simulated capture like a real
one. (The pixel pitch is in the CameraMeta but :func:`isp.io.dng_write.write_dng`
does not write FocalPlaneXResolution yet, so it is not in the file.)

Coordinates and units: :mod:`calibration.simulate.optical_image` (those of
:mod:`calibration.optics.psf.map`: pixel centres at integers, +y down; the image
plane a shift and scale of the pixel grid, no flip). Arrays are float64
internally; raw data are uint16 DN.

References
----------
Paper (``paper/``), eqs. 14–15. M. Delbracio, P. Musé, A. Almansa,
J.-M. Morel, "The non-parametric sub-pixel local point spread function
estimation is a well posed problem", Int. J. Comput. Vis. 96, 175–194
(2012), §2 (image formation: PSF ⊗ pixel aperture, then sampling).
J. G. Nagy, D. P. O'Leary, "Restoring images degraded by spatially variant
blur", SIAM J. Sci. Comput. 19(4), 1063–1082 (1998) (piecewise-constant
PSFs blended by interpolation between region centres).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from isp.frame import CFA

from calibration.simulate.chart import Chart, EdgeROI, Shape, camera_rgb, slanted_square_chart
from calibration.simulate.optical_image import (
    ImagingError,
    KernelBank,
    aperture_decimate,
    blur_decimate,
    convolve,
    fft_shape_for,
    inward_normals,
    polygon_coverage,
)
from calibration.optics.lens import LensError
from calibration.simulate.sensor import SensorModel, as_rng, cfa_channels, expose, mosaic

__all__ = [
    "Chart",
    "EdgeROI",
    "ImagingError",
    "Rendering",
    "SensorModel",
    "Shape",
    "blur_image",
    "camera_rgb",
    "capture_meta",
    "render_chart",
    "render_slanted_edge",
    "shading_gain_maps",
    "simulate_capture",
    "slanted_square_chart",
    "surface_dz_mm",
    "write_capture",
]

BLENDS = ("nearest", "bilinear")


@dataclass(frozen=True, eq=False)
class Rendering:
    """A rendered region of the sensor.

    Attributes
    ----------
    optical : (h, w, 3) ndarray or None
        Noise-free optical image per channel (R, G, B) in scene units,
        after PSF and pixel aperture, before the CFA, exposure and RI.
    signal : (h, w) ndarray or None
        Noise-free mosaic on the 0..1 scale (exposure and RI applied).
    raw : (h, w) uint16 ndarray or None
        Sensor DN: ``signal`` with noise, quantised (needs a sensor).
    cfa : CFA or None
        Pattern of ``raw[0, 0]`` (the sensor's, shifted by ``box``'s origin).
    box : (x, y, width, height)
        Where the rendering sits on the sensor, pixels.
    region : (row, col) or None
        PSF region used (edges).
    """

    optical: np.ndarray | None
    signal: np.ndarray | None
    raw: np.ndarray | None
    cfa: CFA | None
    box: tuple[int, int, int, int]
    region: tuple[int, int] | None = None


# -- helpers ---------------------------------------------------------------------

def _bank(psf, sensor: SensorModel | None, pixel_pitch_um, fill_factor) -> KernelBank:
    pitch = pixel_pitch_um
    if pitch is None and sensor is not None:
        pitch = sensor.pixel_pitch_um
    ff = fill_factor if fill_factor is not None else (sensor.fill_factor if sensor is not None else 1.0)
    if not 0 < ff <= 1:
        raise ImagingError(f"fill_factor must be in (0, 1], got {ff!r}")
    size = None if sensor is None else sensor.shape
    bank = KernelBank.from_psf(psf, pixel_pitch_um=pitch, aperture_px=math.sqrt(ff))
    if bank.size_px is None:
        bank.size_px = size
    return bank


def _levels(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    try:
        a = np.broadcast_to(a, (3,)).copy()
    except ValueError:
        raise ImagingError(f"{name} must be a scalar or 3 values (R, G, B), got shape {a.shape}") from None
    if not np.all(np.isfinite(a)):
        raise ImagingError(f"{name} must be finite, got {a}")
    return a


def _ri_map(relative_illumination, sensor: SensorModel, box) -> np.ndarray | float:
    """RI over ``box`` (x, y, w, h): from a RelativeIllumination, a full-sensor
    (H, W) array, a number, or None (1)."""
    if relative_illumination is None:
        return 1.0
    if hasattr(relative_illumination, "on_sensor"):
        return relative_illumination.on_sensor(sensor, box=box)
    a = np.asarray(relative_illumination, dtype=np.float64)
    if a.ndim == 0:
        return float(a)
    if a.shape != sensor.shape:
        raise ImagingError(f"relative illumination map must be the sensor's shape {sensor.shape}, got {a.shape}")
    x, y, w, h = box
    return a[y:y + h, x:x + w]


def _finish(optical_or_mosaic, sensor: SensorModel | None, box, exposure, relative_illumination, noise, rng,
            *, is_mosaic: bool):
    """Exposure, RI, CFA, noise and quantisation of a rendered region."""
    if sensor is None:
        return None, None, None
    x0, y0 = box[0], box[1]
    m = optical_or_mosaic if is_mosaic else mosaic(optical_or_mosaic, sensor.cfa, origin=(y0, x0))
    signal = float(exposure) * m * _ri_map(relative_illumination, sensor, box)
    if not np.all(np.isfinite(signal)):
        raise ImagingError("the rendered signal holds NaN or inf (check the PSF and the scene levels)")
    raw = expose(signal, sensor, rng, noise=noise)
    return signal, raw, sensor.cfa.shifted(y0, x0)


# -- slanted edge ------------------------------------------------------------------

def render_slanted_edge(psf, center_px, size_px, angle_deg: float, *, horizontal: bool = False,
                        low=0.2, high=0.8, sensor: SensorModel | None = None, pixel_pitch_um: float | None = None,
                        fill_factor: float | None = None, exposure: float = 1.0, relative_illumination=None,
                        noise: bool = True, rng=None, edge_px=None) -> Rendering:
    """A slanted-edge ROI through the local PSF, exactly.

    Parameters
    ----------
    psf : PSF, three PSFs (R, G, B) or PSF map
        Duck-typed (:class:`calibration.simulate.optical_image.KernelBank`). A map
        contributes the PSFs of the region holding ``center_px``.
    center_px : (x, y)
        A point of the edge and the ROI's centre, sensor pixel coordinates
        (pixel centres at integers).
    size_px : int or (height, width)
        ROI size, pixels.
    angle_deg : float
        Edge angle from vertical (from horizontal if ``horizontal``),
        degrees; positive: the edge moves right as rows increase (down as
        columns increase) — the convention of
        :func:`calibration.sfr.synthetic.render_slanted_edge`.
    horizontal : bool
    low, high : float or (3,)
        Scene levels (camera R, G, B) left/top and right/bottom of the edge.
    sensor : SensorModel, optional
        Without one only ``optical`` is computed.
    pixel_pitch_um : float, optional
        Needed when neither ``sensor`` nor the PSF map gives it.
    fill_factor : float, optional
        Overrides ``sensor.fill_factor`` (default 1).
    exposure : float
        Scale from scene units to the 0..1 signal.
    relative_illumination : RelativeIllumination, (H, W) array or None
    noise : bool
    rng : numpy Generator, int or None
        Noise; see :func:`calibration.simulate.sensor.as_rng`.
    edge_px : (x, y), optional
        A point of the edge, sensor pixel coordinates, where it is not the
        ROI's centre ``center_px`` (an edge measured off its ROI's middle).

    Returns
    -------
    Rendering
        ``optical`` (h, w, 3) float64; with a sensor also ``signal``,
        ``raw`` and ``cfa``.

    Notes
    -----
    Pixel value ``low + (high − low)·C(d)``, ``d`` the signed distance of the
    pixel centre from the edge and ``C`` the exact blurred-edge profile of
    the kernel (PSF ⊗ aperture) along the edge normal
    (:func:`calibration.simulate.optical_image.edge_profile`); for a Gaussian PSF it
    agrees with :func:`calibration.sfr.synthetic.render_slanted_edge` to ~1e-6.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> o = np.arange(-16, 17) * 0.25
    >>> g = np.exp(-(o[None] ** 2 + o[:, None] ** 2) / 2.0)
    >>> psf = SimpleNamespace(data=g / g.sum(), pitch_um=0.25)
    >>> r = render_slanted_edge(psf, (50, 40), (32, 48), 5.0, pixel_pitch_um=1.0)
    >>> r.optical.shape, r.box, bool(abs(r.optical[:, 0].mean() - 0.2) < 1e-6)
    ((32, 48, 3), (26, 24, 48, 32), True)
    """
    h, w = (int(size_px), int(size_px)) if np.ndim(size_px) == 0 else (int(size_px[0]), int(size_px[1]))
    if h < 2 or w < 2:
        raise ImagingError(f"ROI must be at least 2 × 2 pixels, got {w} × {h}")
    cx, cy = (float(v) for v in center_px)
    if not (math.isfinite(cx) and math.isfinite(cy) and math.isfinite(angle_deg)):
        raise ImagingError(f"center_px and angle_deg must be finite, got {center_px!r}, {angle_deg!r}")
    lo, hi = _levels(low, "low"), _levels(high, "high")
    bank = _bank(psf, sensor, pixel_pitch_um, fill_factor)
    x0, y0 = round(cx - (w - 1) / 2.0), round(cy - (h - 1) / 2.0)
    box = (x0, y0, w, h)
    if sensor is not None and (x0 < 0 or y0 < 0 or x0 + w > sensor.width_px or y0 + h > sensor.height_px):
        raise ImagingError(f"ROI {box} does not fit the {sensor.width_px} × {sensor.height_px} sensor")
    region = bank.region_at(cx, cy)
    t = math.radians(angle_deg)
    normal = (-math.sin(t), math.cos(t)) if horizontal else (math.cos(t), -math.sin(t))
    ex, ey = (cx, cy) if edge_px is None else (float(edge_px[0]), float(edge_px[1]))
    xs = np.arange(x0, x0 + w, dtype=np.float64) - ex
    ys = np.arange(y0, y0 + h, dtype=np.float64) - ey
    d = normal[0] * xs[None, :] + normal[1] * ys[:, None]
    optical = np.empty((h, w, 3))
    for c in range(3):
        optical[:, :, c] = lo[c] + (hi[c] - lo[c]) * bank.profile(region, c, normal)(d)
    signal, raw, cfa = _finish(optical, sensor, box, exposure, relative_illumination, noise, rng, is_mosaic=False)
    return Rendering(optical, signal, raw, cfa, box, region)


# -- vector scenes (charts) -------------------------------------------------------------

def _shape_coverage(shape: Shape, bank: KernelBank, region, xs: np.ndarray, ys: np.ndarray, s: int,
                    channels) -> dict[int, np.ndarray]:
    """Blurred, aperture-integrated coverage of one convex shape on the pixel
    grid ``xs × ys`` through ``region``'s kernels, per channel in
    ``channels``: (ny, nx) arrays in [0, 1]."""
    import cv2

    normals, offsets = inward_normals(shape.vertices)
    D = normals[:, 0, None, None] * xs[None, None, :] + normals[:, 1, None, None] * ys[None, :, None] \
        - offsets[:, None, None]                                   # (K, ny, nx) distance inside
    out, complex_any = {}, np.zeros(D.shape[1:], dtype=bool)
    for c in channels:
        profs = [bank.profile(region, c, n) for n in normals]
        lo = np.array([p.support[0] for p in profs])[:, None, None]
        hi = np.array([p.support[1] for p in profs])[:, None, None]
        outside = np.any(D <= lo, axis=0)
        frac = (D > lo) & (D < hi)
        nfrac = frac.sum(axis=0)
        cov = np.where(outside, 0.0, 1.0)
        single = (nfrac == 1) & ~outside
        if single.any():
            k = np.argmax(frac, axis=0)
            for i, p in enumerate(profs):
                m = single & (k == i)
                if m.any():
                    cov[m] = p(D[i][m])
        complex_any |= (nfrac >= 2) & ~outside
        out[c] = cov
    if complex_any.any():
        from scipy import fft as sfft

        n_lab, labels, stats, _ = cv2.connectedComponentsWithStats(complex_any.astype(np.uint8), connectivity=8)
        step = 1.0 / s
        margin = math.ceil(bank.reach(region) + bank.aperture_px) + 1
        folded = [bank.folded(region, c, s) for c in channels]
        # one patch size for every corner of the shape (rounded up to 4 px): one FFT size, so the
        # kernels' spectra are computed once per shape and channel
        pw = -(-int(stats[1:, 2].max()) // 4) * 4
        ph = -(-int(stats[1:, 3].max()) // 4) * 4
        nx_p, ny_p = pw + 2 * margin, ph + 2 * margin
        fft_shape = fft_shape_for((ny_p * s, nx_p * s), folded, s, (margin, margin + ph, margin, margin + pw))
        spectra = [sfft.rfft2(f.data.astype(np.float32), fft_shape, workers=-1) for f in folded]
        for lab in range(1, n_lab):
            bx, by, bw, bh = (int(v) for v in stats[lab, :4])
            px0, py0 = xs[bx] - margin, ys[by] - margin             # pixel coords of the padded box
            cov_s = polygon_coverage(shape.vertices, px0 - 0.5 + 0.5 * step, py0 - 0.5 + 0.5 * step,
                                     nx_p * s, ny_p * s, step)
            pix = blur_decimate(cov_s, [], s, bank.aperture_px, folded=folded, spectra=spectra, shape=fft_shape)
            mask = labels[by:by + bh, bx:bx + bw] == lab
            for c, p in zip(channels, pix):
                sub = p[margin:margin + bh, margin:margin + bw]
                out[c][by:by + bh, bx:bx + bw][mask] = sub[mask]
    return out


def _render_vector(chart: Chart, bank: KernelBank, cfa, *, supersample: int, blend: str,
                   rgb: bool) -> np.ndarray:
    """The chart's noise-free optical image: (H, W, 3) if ``rgb`` else the
    (H, W) mosaic (each site its CFA channel)."""
    h, w = chart.size_px
    chan = cfa_channels((h, w), cfa)
    bg = chart.background
    out = np.empty((h, w, 3)) if rgb else bg[chan].astype(np.float64)
    if rgb:
        out[:] = bg
    rows, cols = bank.grid
    reach = max(bank.reach((r, c)) for r in range(rows) for c in range(cols)) + bank.aperture_px + 2.0
    for sh in chart.shapes:
        delta = sh.level - bg
        if not np.any(delta):
            continue
        bx0, by0, bx1, by1 = sh.bbox
        c0, r0 = max(0, math.floor(bx0 - reach)), max(0, math.floor(by0 - reach))
        c1, r1 = min(w, math.ceil(bx1 + reach) + 1), min(h, math.ceil(by1 + reach) + 1)
        if c1 <= c0 or r1 <= r0:
            continue
        xs = np.arange(c0, c1, dtype=np.float64)
        ys = np.arange(r0, r1, dtype=np.float64)
        ch_box = chan[r0:r1, c0:c1]
        channels = [c for c in range(3) if delta[c] != 0]
        for ri, wy in bank.axis_weights(0, ys, blend, (h, w)):
            for ci, wx in bank.axis_weights(1, xs, blend, (h, w)):
                wt = wy[:, None] * wx[None, :]
                cov = _shape_coverage(sh, bank, (ri, ci), xs, ys, supersample, channels)
                if rgb:
                    for c in channels:
                        out[r0:r1, c0:c1, c] += wt * delta[c] * cov[c]
                else:
                    add = np.zeros(ch_box.shape)
                    for c in channels:
                        m = ch_box == c
                        add[m] = delta[c] * cov[c][m]
                    out[r0:r1, c0:c1] += wt * add
    return out


def render_chart(chart: Chart, psf, sensor: SensorModel, *, exposure: float = 1.0, relative_illumination=None,
                 noise: bool = True, rng=None, supersample: int = 8, blend: str = "nearest",
                 rgb: bool = False) -> Rendering:
    """A whole chart through a PSF map onto the sensor.

    Parameters
    ----------
    chart : Chart
        Its ``size_px`` must be the sensor's.
    psf : PSF map, PSF or three PSFs
    sensor : SensorModel
    exposure, relative_illumination, noise, rng
        As in :func:`render_slanted_edge`.
    supersample : int
        Sub-cells per pixel and axis near polygon vertices (≥ 2); edges are
        exact regardless.
    blend : {"nearest", "bilinear"}
        A pixel takes its own region's PSF, or a bilinear blend of the four
        nearest regions' results (see :meth:`KernelBank.axis_weights`).
    rgb : bool
        Also return the (H, W, 3) optical image (memory: 24 bytes/pixel).

    Returns
    -------
    Rendering
        ``signal`` and ``raw`` over the whole sensor; ``optical`` if ``rgb``.
    """
    if tuple(chart.size_px) != sensor.shape:
        raise ImagingError(f"chart is {chart.size_px[1]} × {chart.size_px[0]} px, the sensor "
                           f"{sensor.width_px} × {sensor.height_px}")
    if int(supersample) < 2:
        raise ImagingError(f"supersample must be ≥ 2, got {supersample!r}")
    if blend not in BLENDS:
        raise ImagingError(f"unknown blend {blend!r}; valid: {', '.join(BLENDS)}")
    bank = _bank(psf, sensor, None, None)
    img = _render_vector(chart, bank, sensor.cfa, supersample=int(supersample), blend=blend, rgb=rgb)
    box = (0, 0, sensor.width_px, sensor.height_px)
    m = mosaic(img, sensor.cfa) if rgb else img
    signal, raw, cfa = _finish(m, sensor, box, exposure, relative_illumination, noise, rng, is_mosaic=True)
    return Rendering(img if rgb else None, signal, raw, cfa, box)


# -- raster scenes ---------------------------------------------------------------------

def blur_image(image: np.ndarray, psf, *, pixel_pitch_um: float | None = None, supersample: int = 1,
               blend: str = "bilinear", fill_factor: float = 1.0, size_px: tuple[int, int] | None = None,
               origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Spatially varying blur of a raster scene by a PSF map, per region tile.

    Parameters
    ----------
    image : (H·s, W·s, 3) or (H·s, W·s) ndarray
        Scene in camera channels (one channel: blurred with the G PSFs), on
        a grid ``supersample`` times finer than the pixels.
    psf : PSF map, PSF or three PSFs
    pixel_pitch_um : float, optional
        Default the PSF map's sensor pitch.
    supersample : int
        ``s``; the kernels are resampled to ``1/s`` pixel and the result
        integrated over the pixel aperture. With ``s = 1`` the kernel is the
        PSF integrated over pixel cells (area rebinning: the PSF ⊗ a
        full-pixel aperture, sampled at the pixels), applied to the scene's
        samples; the fill factor is then not used.
    blend : {"bilinear", "nearest"}
        See :func:`render_chart`.
    fill_factor : float
    size_px : (H, W), optional
        Sensor size the PSF map's regions divide (default the map's, else
        the image's).
    origin : (row, col)
        Sensor pixel of the image's first pixel: a crop of the sensor is
        blurred with the PSFs of where it lies (may reach outside the
        sensor, where the border regions' PSFs continue).

    Returns
    -------
    (H, W, 3) or (H, W) ndarray of float64
        Pixel values. Outside the frame the scene is taken to continue as
        its border pixels.

    Notes
    -----
    Each region's kernel is applied by ``cv2.filter2D`` to the tile where
    its weight is nonzero, padded by the kernel's reach from the
    neighbouring scene, so tiling itself adds no error (tested against a
    whole-frame convolution to 1e-12); with ``"nearest"`` the result jumps
    at region borders by the difference of the neighbouring PSFs' images,
    with ``"bilinear"`` it is continuous.
    """
    s = int(supersample)
    if s < 1:
        raise ImagingError(f"supersample must be ≥ 1, got {supersample!r}")
    if blend not in BLENDS:
        raise ImagingError(f"unknown blend {blend!r}; valid: {', '.join(BLENDS)}")
    img = np.asarray(image, dtype=np.float64)
    mono = img.ndim == 2
    if mono:
        img = img[:, :, None]
    if img.ndim != 3 or img.shape[2] not in (1, 3):
        raise ImagingError(f"image must be (H, W) or (H, W, 3), got shape {np.shape(image)}")
    if img.shape[0] % s or img.shape[1] % s:
        raise ImagingError(f"image shape {img.shape[:2]} is not a multiple of supersample {s}")
    if not np.all(np.isfinite(img)):
        raise ImagingError("image holds NaN or inf")
    h, w = img.shape[0] // s, img.shape[1] // s
    bank = KernelBank.from_psf(psf, pixel_pitch_um=pixel_pitch_um, aperture_px=math.sqrt(fill_factor))
    size = size_px or bank.size_px or (h, w)
    ap = bank.aperture_px if s > 1 else 1.0
    chans = [1] if mono else [0, 1, 2]
    out = np.zeros((h, w, len(chans)))
    ys = np.arange(h, dtype=np.float64) + float(origin[0])
    xs = np.arange(w, dtype=np.float64) + float(origin[1])
    for ri, wy in bank.axis_weights(0, ys, blend, size):
        rsel = np.nonzero(wy > 0)[0]
        for ci, wx in bank.axis_weights(1, xs, blend, size):
            csel = np.nonzero(wx > 0)[0]
            pr0, pr1, pc0, pc1 = rsel[0], rsel[-1] + 1, csel[0], csel[-1] + 1
            wt = wy[pr0:pr1, None] * wx[None, pc0:pc1]
            for k, c in enumerate(chans):
                ker = bank.resampled((ri, ci), c, 1.0 / s)
                m = math.ceil(ker.reach) + 1          # pixels of context
                sr0, sc0 = max(0, pr0 - m) * s, max(0, pc0 - m) * s
                sr1, sc1 = min(h, pr1 + m) * s, min(w, pc1 + m) * s
                tile = convolve(img[sr0:sr1, sc0:sc1, k], ker)
                if s > 1:
                    tile = aperture_decimate(tile, s, ap)
                oy, ox = pr0 - sr0 // s, pc0 - sc0 // s
                out[pr0:pr1, pc0:pc1, k] += wt * tile[oy:oy + pr1 - pr0, ox:ox + pc1 - pc0]
    return out[:, :, 0] if mono else out


# -- lens shading opcodes ------------------------------------------------------------

def _map_taps(coords: np.ndarray, size: int, points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(i0, i1, f): the two map points bracketing each pixel index in
    ``coords`` and the weight ``f`` of ``i1`` (``1 − f`` of ``i0``), for a
    GainMap spanning the image (origin 0, spacing 1/(points − 1)): the DNG
    SDK's interpolation (:meth:`isp.opcodes.GainMap.evaluate`)."""
    t = np.clip((np.asarray(coords, dtype=np.float64) + 0.5) / size * (points - 1), 0.0, points - 1)
    i0 = np.floor(t).astype(np.int64)
    return i0, np.minimum(i0 + 1, points - 1), t - i0


def _map_weights(coords: np.ndarray, size: int, points: int) -> np.ndarray:
    """(len(coords), points) dense form of :func:`_map_taps`."""
    i0, i1, f = _map_taps(coords, size, points)
    w = np.zeros((i0.size, points))
    k = np.arange(i0.size)
    w[k, i0] = 1.0 - f
    w[k, i1] += f
    return w


def _lsq_gains(sub: np.ndarray, rs: np.ndarray, cs: np.ndarray, h: int, w: int, pv: int, ph: int) -> np.ndarray:
    """Gains g (pv, ph) minimising Σ (RI·G − 1)² over the sites ``rs × cs``
    (RI values ``sub``), G the bilinear interpolation of g: normal equations
    of the sparse design matrix (4 taps per site)."""
    from scipy.sparse import csr_matrix

    r0, r1, fr = _map_taps(rs, h, pv)
    c0, c1, fc = _map_taps(cs, w, ph)
    rows, cols, vals = [], [], []
    site = np.arange(rs.size * cs.size).reshape(rs.size, cs.size)
    for ri, wr in ((r0, 1.0 - fr), (r1, fr)):
        for ci, wc in ((c0, 1.0 - fc), (c1, fc)):
            rows.append(site.ravel())
            cols.append((ri[:, None] * ph + ci[None, :]).ravel())
            vals.append((sub * wr[:, None] * wc[None, :]).ravel())
    a = csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                   shape=(site.size, pv * ph))
    ata = (a.T @ a).toarray()
    atb = np.asarray(a.T @ np.ones(site.size)).ravel()
    ata[np.diag_indices_from(ata)] += 1e-12 * np.trace(ata) / ata.shape[0]   # points no site reaches
    return np.linalg.solve(ata, atb).reshape(pv, ph)


def shading_gain_maps(ri: np.ndarray, cfa, points: tuple[int, int] = (17, 23), *, fit: str = "lsq",
                      max_samples: int = 300):
    """Four per-CFA-phase GainMap opcodes (OpcodeList2) that undo a relative
    illumination, as phone DNGs carry them.

    Parameters
    ----------
    ri : (H, W) ndarray
        Relative illumination per pixel (> 0 where light arrives).
    cfa : CFA or str
        Pattern of the top-left 2×2 block.
    points : (MapPointsV, MapPointsH)
        Map points; the first and last sit on the image edges
        (:meth:`isp.opcodes.GainMap.spanning_image`).
    fit : {"lsq", "samples"}
        ``"samples"``: gain = 1/RI at the pixel nearest each map point.
        ``"lsq"``: the gains whose bilinear interpolation (as a DNG reader
        applies it) best flattens the phase's sites, least squares on
        ``RI·G − 1`` over up to ``max_samples²`` sites (default 300², evenly
        spread, every site of a sensor up to 600 × 600).

    Returns
    -------
    tuple of 4 GainMap

    Notes
    -----
    Bilinear maps cannot follow every falloff. Measured on a smooth RI of
    0.36 at the corner (block means of 10 × 10 px, ``"lsq"``): 13 × 17
    points leave 1.2 % (400 × 300 px) / 2.6 % (4000 × 3000), 17 × 23 points
    0.2 % / 1.5 %, 25 × 33 points 0.1 % / 0.7 %. Where the RI has a
    vignetting cliff (US-12210142-B2-e9 on its default sensor drops from
    0.21 to 0.18 in the last 20 µm of the diagonal) the extreme corners keep
    8–17 % at 12 MP whatever the density.
    """
    from isp.opcodes import AreaSpec, GainMap

    a = np.asarray(ri, dtype=np.float64)
    if a.ndim != 2 or not np.all(np.isfinite(a)) or not np.all(a > 0):
        raise ImagingError("ri must be a finite, positive (H, W) array (the GainMap divides by it)")
    h, w = a.shape
    pv, ph = (int(v) for v in points)
    if pv < 2 or ph < 2:
        raise ImagingError(f"a gain map needs at least 2 × 2 points, got {points!r}")
    CFA.parse(cfa)      # validated; the maps are per phase (each phase's own sites), not per colour
    ops = []
    for i in range(2):
        for j in range(2):
            rows, cols = np.arange(i, h, 2), np.arange(j, w, 2)
            if fit == "samples":
                yy = np.clip(np.rint(np.linspace(0, h, pv) - 0.5).astype(int), 0, h - 1)
                xx = np.clip(np.rint(np.linspace(0, w, ph) - 0.5).astype(int), 0, w - 1)
                gains = 1.0 / a[np.ix_(yy, xx)]
            elif fit == "lsq":
                rs = rows[np.unique(np.linspace(0, rows.size - 1, min(rows.size, max_samples)).astype(int))]
                cs = cols[np.unique(np.linspace(0, cols.size - 1, min(cols.size, max_samples)).astype(int))]
                gains = _lsq_gains(a[np.ix_(rs, cs)], rs, cs, h, w, pv, ph)
            else:
                raise ImagingError(f"unknown fit {fit!r}; valid: 'lsq', 'samples'")
            ops.append(GainMap.spanning_image(
                gains.astype(np.float32)[:, :, None],
                area=AreaSpec(top=i, left=j, bottom=h, right=w, plane=0, planes=1, row_pitch=2, col_pitch=2)))
    return tuple(ops)


# -- captures --------------------------------------------------------------------------

def lens_model(lens) -> str:
    """The LensModel a simulated capture of ``lens`` (a :class:`Lens`)
    carries, the identity a lens profile matches (:mod:`isp.profiles`): the
    stem of the file the prescription was read from where it extends the
    lens's name (a patent's embodiments share its name: ``US-12210142-B2-e9``
    from ``US-12210142-B2-e9.zmx``, named ``US-12210142-B2``), else the name
    ("simulated lens" without one)."""
    name = lens.name or ""
    source = (lens.metadata or {}).get("source")
    stem = Path(str(source.get("file", ""))).stem if isinstance(source, dict) else ""
    if stem and (not name or (stem.startswith(name) and stem != name)):
        return stem
    return name or "simulated lens"


def module_serial(lens) -> str:
    """The CameraSerialNumber a simulated capture of ``lens`` carries: its
    module's identity, ``"SIM-"`` and 12 hex digits of the SHA-256 of its
    design's name and its perturbation, so every capture of one drawn module
    names the same module and two modules differ (the correction stage
    refuses another module's calibration, :mod:`modules.correction`).
    """
    import hashlib
    import json

    from calibration.optics.perturb import nominal

    pl = nominal(lens)
    doc = {"lens": lens_model(pl.lens),
           "perturbation": {k: round(float(v), 12) for k, v in sorted(pl.perturbation.as_dict().items()) if v}}
    return "SIM-" + hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:12]


def capture_meta(sensor: SensorModel, *, gain_maps=None, lens=None, exposure_time_s: float = 1 / 100,
                 iso: float = 100.0):
    """The CameraMeta a simulated capture is written with.

    Colour: the demo camera of :mod:`calibration.simulate.scene` (camera RGB = ``CAMERA_MIX``
    · linear sRGB, so ColorMatrix1 (D65) = ``CAMERA_MIX · M(XYZ→sRGB)`` and the
    D65 neutral is ``CAMERA_MIX·(1, 1, 1)``, normalised to green). Identity:
    UniqueCameraModel "phone-isp simulated phone", LensModel
    :func:`lens_model` (+ " (perturbed)" for a perturbed lens), which the
    lens profiles match, and CameraSerialNumber :func:`module_serial`.
    Optics: F-number and paraxial EFL when given.
    """
    from calibration.simulate.scene import CAMERA_MIX, XYZ_TO_SRGB
    from isp.meta import CameraMeta

    neutral = CAMERA_MIX @ np.ones(3)
    neutral = neutral / neutral[1]
    name, fno, efl, serial = "", None, None, ""
    if lens is not None:
        from calibration.optics import paraxial
        from calibration.optics.perturb import nominal

        pl = nominal(lens)
        name, serial = lens_model(pl.lens), module_serial(pl)
        if not pl.perturbation.is_zero:
            name += " (perturbed)"
        try:
            fo = paraxial.first_order(pl.lens)
        except LensError:      # metadata only: a lens without first-order data still renders
            fo = None
        if fo is not None and math.isfinite(fo.efl):
            fno, efl = float(fo.f_number), float(abs(fo.efl))
    return CameraMeta(
        make="phone-isp", model="simulated phone", unique_camera_model="phone-isp simulated phone", serial=serial,
        cfa=sensor.cfa, black_level=np.full((1, 1, 1), sensor.black_level), white_level=(sensor.white_level,),
        color_matrix_1=CAMERA_MIX @ XYZ_TO_SRGB, calibration_illuminant_1=21, as_shot_neutral=tuple(neutral),
        baseline_exposure=0.0, noise_profile=(tuple(sensor.noise_profile),),
        opcodes={2: tuple(gain_maps)} if gain_maps else {}, pixel_pitch_um=sensor.pixel_pitch_um,
        f_number=fno, focal_length_mm=efl, lens=name, exposure_time_s=exposure_time_s, iso=iso,
        bits_per_sample=sensor.bit_depth, datetime="2026:01:01 12:00:00",
        raw_size=sensor.shape,
    )


def surface_dz_mm(injections, centres_mm: np.ndarray, half_diagonal_mm: float) -> np.ndarray | None:
    """The sensor's surface beyond the image plane (mm) at ``centres_mm``
    (``(..., 2)`` x, y), the ``"optics"`` injections' Δz added; None
    where there are none.

    >>> from calibration.simulate.injected import make_injection
    >>> c = np.array([[[-2.0, 0.0], [2.0, 0.0]]])
    >>> surface_dz_mm([make_injection("sensor_tilt", tilt_x_deg=0.0, tilt_y_deg=0.1)], c, 2.5).round(5).tolist()
    [[-0.00349, 0.00349]]
    """
    parts = [inj.apply(centres_mm[..., 0], centres_mm[..., 1], half_diagonal_mm)
             for inj in injections if inj.where == "optics"]
    return np.sum(parts, axis=0) if parts else None


def _default_psf_map(lens, options: dict | None, injections=()):
    """The lens's PSF map with ``options``, on the sensor surface the
    ``"optics"`` injections make (:func:`surface_dz_mm`)."""
    import dataclasses

    from calibration.optics.perturb import nominal
    from calibration.optics.psf.map import (  # lazily: the PSF map is the expensive part (and cached on disk)
        PSFMapSettings,
        psf_map,
        region_centers_mm,
    )

    options = dict(options or {})
    fields = {f.name for f in dataclasses.fields(PSFMapSettings)}
    settings = PSFMapSettings(**{k: v for k, v in options.items() if k in fields})
    rest = {k: v for k, v in options.items() if k not in fields}
    geo = rest.get("sensor") or nominal(lens).nominal.sensor
    dz = surface_dz_mm(injections, region_centers_mm(geo, settings.grid), 0.5 * math.hypot(*geo.size_mm))
    if dz is not None:
        if rest.get("image_dz_mm") is not None:
            dz = dz + np.asarray(rest["image_dz_mm"], float)
        rest["image_dz_mm"] = dz
    return psf_map(lens, settings, **rest)


def simulate_capture(lens=None, scene=None, *, psfmap=None, sensor: SensorModel | None = None,
                     exposure: float = 1.0, rng=None, lens_shading: str = "gainmap", relative_illumination=None,
                     noise: bool = True, supersample: int | None = None, blend: str | None = None,
                     gain_map_points: tuple[int, int] = (17, 23), gain_map_fit: str = "lsq",
                     psf_map_options: dict | None = None, injections=()):
    """Simulate the raw capture a device with this (perturbed) lens records.

    Parameters
    ----------
    lens : Lens or PerturbedLens, optional
        Needed unless ``psfmap`` and (with ``lens_shading="gainmap"``)
        ``relative_illumination`` are given.
    scene : Chart or (H·s, W·s, 3) ndarray, optional
        A vector chart (rendered exactly), or a raster scene in linear camera
        RGB on a grid ``supersample`` times finer than the pixels. Default:
        :func:`slanted_square_chart` on the PSF map's grid.
    psfmap : PSF map, optional
        Default ``calibration.optics.psf.map.psf_map(lens, ...)`` (imported lazily)
        with ``psf_map_options``: :class:`calibration.optics.psf.map.PSFMapSettings`
        fields and psf_map's keywords (``cache_dir``, ``executor``, ...).
    sensor : SensorModel, optional
        Default: the PSF map's (or lens's) sensor geometry with the
        :class:`SensorModel` defaults (10 bit, black 64, NoiseProfile
        (2e-4, 2e-6)).
    exposure : float
        Scene units to 0..1 signal at the centre.
    rng : numpy Generator, int or None
        Noise (None: seed 0).
    lens_shading : {"gainmap", "none"}
        ``"gainmap"``: the relative illumination darkens the capture and
        GainMaps that undo it go into the metadata; ``"none"``: neither.
    relative_illumination : RelativeIllumination or (H, W) array, optional
        Default :func:`calibration.optics.illumination.relative_illumination` of
        the lens.
    noise : bool
    supersample : int, optional
        Chart: sub-cells per pixel near vertices (default 8). Raster: the
        scene's grid factor (default 1).
    blend : {"nearest", "bilinear"}, optional
        Default "nearest" for charts, "bilinear" for raster scenes.
    gain_map_points, gain_map_fit
        See :func:`shading_gain_maps`.
    injections : sequence of calibration.simulate.injected.Injection
        Effects the lens model lacks: the ``"optics"`` ones move the
        sensor's surface, on which the PSF map is computed (so not with
        ``psfmap``); then, on the mosaic, the ``"light"`` ones on the
        noise-free signal in their order, then the noise, then the
        ``"chain"`` ones, then the quantisation.

    Returns
    -------
    mosaic : (H, W) uint16 ndarray
        Raw DN.
    meta : isp.meta.CameraMeta
        What :func:`write_capture` writes into the DNG.
    """
    if lens_shading not in ("gainmap", "none"):
        raise ImagingError(f"unknown lens_shading {lens_shading!r}; valid: 'gainmap', 'none'")
    on_mosaic = [inj for inj in injections if inj.where != "optics"]
    if psfmap is not None and len(on_mosaic) < len(injections):
        raise ImagingError("an optics injection moves the sensor's surface, on which the PSF map is computed: "
                           "give the lens, not psfmap")
    if psfmap is None:
        if lens is None:
            raise ImagingError("give a lens or a PSF map")
        from calibration.optics.perturb import nominal

        geo = nominal(lens).nominal.sensor
        if sensor is None:
            sensor = SensorModel.from_sensor(geo)
        elif sensor.geometry != geo:
            raise ImagingError(f"the sensor ({sensor.width_px} × {sensor.height_px} px of {sensor.pixel_pitch_um} µm) "
                               f"differs from the lens's ({geo.width_px} × {geo.height_px} px of "
                               f"{geo.pixel_pitch_um} µm), whose regions the PSF map divides: give the lens that "
                               "sensor (lens.replace(sensor=...)) or pass psfmap")
        psfmap = _default_psf_map(lens, psf_map_options, injections)
    if sensor is None:
        geo = getattr(psfmap, "sensor", None)
        if geo is None:
            raise ImagingError("give a sensor: the PSF has no sensor geometry")
        sensor = SensorModel.from_sensor(geo)
    ri = None
    if lens_shading == "gainmap":
        if relative_illumination is None:
            if lens is None:
                raise ImagingError("lens_shading='gainmap' needs the lens or a relative_illumination")
            from calibration.optics.illumination import relative_illumination as compute_ri

            relative_illumination = compute_ri(lens, sensor=sensor.geometry)
        full = (0, 0, sensor.width_px, sensor.height_px)
        ri = _ri_map(relative_illumination, sensor, full)
        if np.ndim(ri) == 0:
            ri = np.full(sensor.shape, float(ri))
        ri = np.maximum(ri, 1e-6)       # a gain map cannot undo total darkness
    gen = as_rng(rng)
    if scene is None:
        bank = KernelBank.from_psf(psfmap, pixel_pitch_um=sensor.pixel_pitch_um)
        rows, cols = bank.grid
        rows = max(1, min(rows, sensor.height_px // 48))
        cols = max(1, min(cols, sensor.width_px // 48))
        scene = slanted_square_chart(sensor.height_px, sensor.width_px, (rows, cols))
    if isinstance(scene, Chart):
        rend = render_chart(scene, psfmap, sensor, exposure=exposure, relative_illumination=ri,
                            noise=noise and not on_mosaic, rng=gen,
                            supersample=8 if supersample is None else supersample, blend=blend or "nearest")
        raw = _injected(rend.signal, sensor, gen, noise, on_mosaic) if on_mosaic else rend.raw
    else:
        s = 1 if supersample is None else int(supersample)
        img = blur_image(scene, psfmap, pixel_pitch_um=sensor.pixel_pitch_um, supersample=s,
                         blend=blend or "bilinear", fill_factor=sensor.fill_factor, size_px=sensor.shape)
        if img.ndim != 3 or img.shape[:2] != sensor.shape:
            raise ImagingError(f"raster scene gives a {img.shape[:2]} image, the sensor is {sensor.shape} "
                               "(the scene must be (H·s, W·s, 3))")
        sig = float(exposure) * mosaic(img, sensor.cfa) * (1.0 if ri is None else ri)
        raw = _injected(sig, sensor, gen, noise, on_mosaic) if on_mosaic else expose(sig, sensor, gen, noise=noise)
    maps = shading_gain_maps(ri, sensor.cfa, gain_map_points, fit=gain_map_fit) if ri is not None else None
    return raw, capture_meta(sensor, gain_maps=maps, lens=lens)


def _injected(signal: np.ndarray, sensor: SensorModel, rng, noise: bool, injections) -> np.ndarray:
    """Raw DN of a noise-free mosaic with ``injections`` put in
    (:mod:`calibration.simulate.injected`): the light ones, the noise, the
    chain ones, the quantisation."""
    from calibration.simulate.sensor import add_noise, quantise

    x = np.asarray(signal, dtype=np.float64)
    for inj in injections:
        if inj.where == "light":
            x = inj.apply(x, sensor.cfa)
    if noise:
        x = add_noise(np.maximum(x, 0.0), sensor.noise_profile, rng, quantisation_step=1.0 / sensor.dn_range)
    for inj in injections:
        if inj.where == "chain":
            x = inj.apply(x, sensor.cfa)
    return quantise(x, sensor)


def write_capture(path: str | os.PathLike, lens=None, *, capture: tuple | None = None, **kw) -> Path:
    """Write a simulated capture as a DNG (:func:`isp.io.dng_write.write_dng`).

    ``capture`` is a ``(mosaic, meta)`` pair from :func:`simulate_capture`;
    without it the capture is simulated here from ``lens`` and ``kw``.
    Returns the path written.
    """
    from isp.io.dng_write import write_dng

    mos, meta = capture if capture is not None else simulate_capture(lens, **kw)
    return write_dng(path, np.asarray(mos, dtype=np.uint16), meta)

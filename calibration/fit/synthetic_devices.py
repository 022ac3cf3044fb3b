"""Synthetic devices: slanted-edge SFR observations of a known (perturbed)
lens, measured the way a chart capture is.

The truth path is independent of the fast forward model
(:mod:`calibration.fit.forward_model`): PSFs come from
:func:`calibration.optics.psf.map.psf_map` at each edge's region centre (real chief
ray aiming, more pupil samples and wavelengths), each edge is rendered
exactly through its PSF and the pixel aperture
(:func:`calibration.simulate.capture.render_slanted_edge`), noise is added whose
standard deviation grows toward the corners as the relative illumination
falls (a photon-limited capture: σ ∝ 1/√RI), and the edge is measured with
ISO 12233 (:func:`calibration.sfr.esfr.measure_sfr`).

``image_ops`` are applied to each rendered ROI before the noise: they stand
for effects in the measurement chain the lens model does not have
(crosstalk, sharpening, glare, ...) — the loop closure's tests inject them
here, on pixels, not in the model's own terms.

With ``return_edges=True`` the noisy ROI images come back too
(:class:`SyntheticEdge`, one per observation, same order), each with the
geometry it was rendered at, so a pixel-level fit
(:mod:`calibration.fit.pixel`) can render the same edge through another
lens and compare pixels.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from calibration.optics.lens import Sensor
from calibration.fit.observations import GRID, Observations
from calibration.optics.psf.map import region_centers_mm, image_to_sensor
from calibration.sfr.chart import classify_orientation

__all__ = ["SyntheticEdge", "edge_sites", "synthetic_observations"]

EDGE_ANGLE_DEG = 5.0


@dataclass(frozen=True, eq=False)
class SyntheticEdge:
    """One measured edge ROI of :func:`synthetic_observations` and how it
    was rendered (arguments of :func:`calibration.simulate.capture.render_slanted_edge`).

    Attributes
    ----------
    image : (h, w) ndarray
        The measured ROI: rendered, ``image_ops`` applied, noise added.
    clean : (h, w) ndarray
        The same before the noise.
    center_px : (x, y)
        Edge point and ROI centre, sensor pixels.
    size : (h, w)
    angle_deg : float
    horizontal : bool
    low, high : float
        Scene levels either side of the edge.
    pixel_pitch_um : float
    box : (x, y, w, h)
        Where the ROI sits on the sensor.
    noise : float
        Noise σ added (0..1 signal units).
    channel : str
    """

    image: np.ndarray
    clean: np.ndarray
    center_px: tuple[float, float]
    size: tuple[int, int]
    angle_deg: float
    horizontal: bool
    low: float
    high: float
    pixel_pitch_um: float
    box: tuple[int, int, int, int]
    noise: float
    channel: str

    def render(self, psf_data, pitch_um: float) -> np.ndarray:
        """The noise-free ROI (h, w) of this edge through another PSF
        (``psf_data`` (m, m) masses at ``pitch_um``), same geometry and
        levels."""
        from types import SimpleNamespace

        from calibration.simulate.capture import render_slanted_edge

        psf = SimpleNamespace(data=np.asarray(psf_data, dtype=np.float64), pitch_um=float(pitch_um))
        ren = render_slanted_edge(psf, self.center_px, self.size, self.angle_deg, horizontal=self.horizontal,
                                  low=self.low, high=self.high, pixel_pitch_um=self.pixel_pitch_um, noise=False)
        return ren.optical[:, :, 0]


def edge_sites(sensor: Sensor, grid: tuple[int, int] = GRID) -> list[tuple[int, int, float, float]]:
    """(row, col, x_px, y_px) of every region centre of ``grid``."""
    c = region_centers_mm(sensor, grid)
    out = []
    for r in range(grid[0]):
        for k in range(grid[1]):
            x, y = image_to_sensor(c[r, k, 0], c[r, k, 1], sensor)
            out.append((r, k, float(x), float(y)))
    return out


def synthetic_observations(psfmap, *, roi: tuple[int, int] = (64, 96), noise: float = 0.004,
                           noise_growth: float = 1.0, channels: Sequence[str] = ("G",),
                           image_ops: Sequence[Callable[[np.ndarray, float, float], np.ndarray]] = (),
                           psf_ops: Sequence[Callable] = (), low: float = 0.2, high: float = 0.8,
                           angle_deg: float = EDGE_ANGLE_DEG, rng=0, return_edges: bool = False,
                           executor=None, method: str | None = None):
    """Observations of the lens whose PSF map is ``psfmap``: one vertical
    and one horizontal edge at every region centre of the map's grid.

    Parameters
    ----------
    psfmap : PSFMap
        Truth PSFs (its grid is the observation grid).
    roi : (short, long)
        ROI size, pixels (across × along the edge).
    noise : float
        Noise σ at the centre, in 0..1 signal units.
    noise_growth : float
        σ(r) = noise · (1 + noise_growth · r²) with r the normalised field
        radius (1 at the corner) — the fall of relative illumination
        (cos⁴-like) on a photon-limited capture.
    channels : sequence of {"R", "G", "B"}
    image_ops : callables ``op(roi, x_px, y_px) -> roi``
        Effects of the measurement chain, applied to each noise-free ROI.
    psf_ops : callables ``op(psf_data, x_px, y_px, channel) -> psf_data``
        Effects on the optics, applied to each PSF before rendering.
    rng : int or Generator
    return_edges : bool
        Also return the measured ROIs.
    executor : isp.runtime.executor.Executor, optional
        Where its progress bar counts the regions (the edges are rendered
        here, in order: they draw from one ``rng``).
    method : {"accurate", "iso"}, optional
        The SFR method (:func:`calibration.sfr.esfr.measure_sfr`; default
        :data:`calibration.sfr.esfr.DEFAULT_METHOD`), recorded in the
        observations' ``meta["sfr_method"]`` for the fit's forward model.

    Returns
    -------
    Observations, or (Observations, list of SyntheticEdge) with ``return_edges``
        The edges in the observations' order (an edge whose SFR could not
        be measured is in neither).
    """
    from types import SimpleNamespace

    from calibration.simulate.capture import render_slanted_edge
    from calibration.sfr.esfr import DEFAULT_METHOD, SfrError, measure_sfr

    method = DEFAULT_METHOD if method is None else method

    rng = np.random.default_rng(rng)
    sensor = psfmap.sensor
    grid = psfmap.grid
    half = 0.5 * math.hypot(sensor.width_px, sensor.height_px)
    cx, cy = (sensor.width_px - 1) / 2.0, (sensor.height_px - 1) / 2.0
    items, chans, rois, edges = [], [], [], []
    sites = edge_sites(sensor, grid)
    bar = None if executor is None else executor.bar(total=len(sites), unit="region", desc="synthetic edges")
    short, long_ = roi
    for r, k, x, y in sites:
        if bar is not None:
            bar.update()
        rad = math.hypot(x - cx, y - cy) / half
        sigma = noise * (1.0 + noise_growth * rad * rad)
        for ch in channels:
            data = np.asarray(psfmap.psf(r, k, ch).data, dtype=np.float64)
            for op in psf_ops:
                data = op(data, x, y, ch)
            psf = SimpleNamespace(data=data, pitch_um=psfmap.pitch_um)
            for horizontal in (False, True):
                size = (short, long_) if horizontal else (long_, short)
                ren = render_slanted_edge(psf, (x, y), size, angle_deg, horizontal=horizontal, low=low, high=high,
                                          pixel_pitch_um=sensor.pixel_pitch_um, noise=False)
                img = ren.optical[:, :, 0]
                for op in image_ops:
                    img = op(img, x, y)
                clean = img
                img = img + rng.normal(0.0, sigma, img.shape)
                try:
                    res = measure_sfr(img, method=method)
                except SfrError:
                    continue
                t = math.radians(angle_deg)
                edge_dir = (math.cos(t), math.sin(t)) if horizontal else (math.sin(t), math.cos(t))
                fa = math.degrees(math.atan2(cy - y, x - cx))
                orient = classify_orientation(edge_dir[0], edge_dir[1], rad, fa)
                normal = 90.0 + angle_deg if horizontal else -angle_deg
                items.append((x, y, normal, orient, res))
                chans.append(ch)
                rois.append((ren.box[0], ren.box[1], size[1], size[0]))
                if return_edges:
                    edges.append(SyntheticEdge(img, clean, (x, y), size, float(angle_deg), horizontal, float(low),
                                               float(high), float(sensor.pixel_pitch_um), tuple(ren.box), float(sigma),
                                               str(ch)))
    if bar is not None:
        bar.close()
    obs = Observations.from_sfr_results(items, sensor, grid=grid, source="synthetic")
    obs = obs.with_fields(channel=np.array(chans), roi=np.array(rois), meta={"measure": "image", "sfr_method": method})
    return (obs, edges) if return_edges else obs

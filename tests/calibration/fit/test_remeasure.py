"""The model re-measures its renders as the observations were measured
(kind: property): an edge measured on a raw mosaic's green plane has half
the pixels of the full image, so its SFRA scatters about √2 more under the
same pixel noise. The re-rendered spread, which the loop takes as each
observation's σ, must show that, and the measurement itself must be the
mosaic's."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.optics.lens import Sensor
from calibration.loop.base import _edge_bias
from calibration.fit.observations import FREQ, Observations
from calibration.sfr.esfr import measure_sfr, measure_sfr_bayer
from calibration.fit.forward_model import measure_like


def _observations(n: int, meta: dict) -> Observations:
    sensor = Sensor(pixel_pitch_um=2.0, width_px=2000, height_px=1500)
    return Observations(x_px=np.full(n, 500.0), y_px=np.full(n, 400.0), normal_deg=np.full(n, -5.0),
                        channel=np.array(["G"] * n), orientation=np.array(["sagittal"] * n),
                        sfra=np.full(n, 0.3), sfra_std=np.full(n, 0.002), noise=np.full(n, 0.01),
                        step=np.full(n, 0.6), freq=FREQ, sfr=np.zeros((n, len(FREQ))), sensor=sensor,
                        roi=np.tile([0, 0, 64, 96], (n, 1)), meta=meta)


def test_measure_like_takes_the_mosaic_plane_of_a_raw_observation():
    from calibration.sfr.synthetic import render_slanted_edge

    img = 0.2 + 0.6 * render_slanted_edge((96, 64), 5.0, 1.0)
    raw = measure_like(_observations(1, {"measure": "raw", "cfa": "GRBG"}), 0)(img)
    assert raw.sfra == measure_sfr_bayer(img, "GRBG", channel="G").sfra
    assert measure_like(_observations(1, {"measure": "image"}), 0)(img).sfra == measure_sfr(img).sfra
    assert raw.sfra != pytest.approx(measure_sfr(img).sfra, abs=1e-6)


def test_a_raw_observation_re_rendered_scatters_as_a_mosaic_plane_does():
    """Spread of four noisy re-renders per observation, median over 60: on
    the green plane it is 1.3–2.5× the full image's (√2 from half the pixels;
    the plane's coarser ESF bins add some)."""
    def otf(nu, normal):
        return np.exp(-2 * np.pi ** 2 * 0.6 ** 2 * np.asarray(nu) ** 2)

    sd_image = np.median(_edge_bias(_observations(60, {"measure": "image"}), otf)[2])
    sd_raw = np.median(_edge_bias(_observations(60, {"measure": "raw", "cfa": "RGGB"}), otf)[2])
    assert 1.3 < sd_raw / sd_image < 2.5, (sd_raw, sd_image)   # 1.81 measured

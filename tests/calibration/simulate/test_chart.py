"""The slanted-square chart (calibration/simulate/chart.py): its
ColorChecker patches, rendered at their camera RGB.

Kind: property (each test marked). The PSF map is filled with Gaussian PSFs
(no ray tracing).
"""

from __future__ import annotations


import numpy as np
import pytest

from calibration.optics.lens import Sensor
from calibration.simulate.capture import SensorModel, render_chart
from calibration.simulate.chart import slanted_square_chart
from tests.helpers import gaussian_psf_map as gaussian_map


@pytest.mark.property
def test_property_colorchecker_chart():
    """property: the ColorChecker chart puts 24 patches in the central 4 × 6
    cells; a rendered patch centre has its camera RGB (no blur reaches it)."""
    chart = slanted_square_chart(300, 400, (6, 8), colorchecker=True)
    patches = [s for s in chart.shapes if s.kind == "patch"]
    assert len(patches) == 24
    sensor = Sensor(1.0, 400, 300)
    pm = gaussian_map(sensor, (1, 1), lambda r, c, k: 1.0, pitch_um=0.5, n=33)
    r = render_chart(chart, pm, SensorModel.from_sensor(sensor), rgb=True, noise=False)
    p = patches[7]
    cx, cy = p.vertices.mean(axis=0)
    assert np.allclose(r.optical[round(cy), round(cx)], p.level, atol=1e-9)

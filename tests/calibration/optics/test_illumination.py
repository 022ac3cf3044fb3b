"""Relative illumination (calibration/optics/illumination.py).

Kinds, as marked on each test:

* property (analytic) — the cos⁴ law of a thin lens with its stop at the
  lens, at the tolerance of the method;
* published — against a cited figure (../shared/data/lenses/README.md);
* property — Rimmer's image-space method on a field-curved singlet, the
  per-pixel map on a sensor.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.optics.illumination import relative_illumination, ri_cos4
from calibration.optics.lens import Lens, Sensor, Surface
from calibration.optics.materials import model_material
from tests.helpers import reference, smooth_ri


E9 = reference("lens_figures.json")["e9"]


def thin_singlet(f_mm: float = 20.0, f_number: float = 10.0, sensor: Sensor | None = None) -> Lens:
    """Equiconvex n = 1.5 singlet, stop at its front surface, image at the
    paraxial focus: distortion-free to third order."""
    from calibration.optics import paraxial
    r = 2 * 0.5 * f_mm
    lens = Lens((Surface(curvature=1 / r, thickness=0.3, material=model_material(1.5), stop=True),
                 Surface(curvature=-1 / r, thickness=f_mm)), f_number=f_number, half_fov_deg=20.0,
                sensor=sensor or Sensor(1.0, 400, 300), name="test singlet")
    return lens.with_surface(1, thickness=paraxial.first_order(lens).bfl)


@pytest.mark.property
def test_analytic_ri_cos4_thin_lens():
    """analytic: a thin F/10 singlet with its stop at the lens is free of
    distortion (third order) and pupil aberration, so flux conservation
    gives the cos⁴ law: within 0.003 of cos⁴θ up to 20° (measured ≤ 0.002;
    the real singlet's residual distortion is ≈ 0.4 %), 1 on axis, falling
    monotonically."""
    lens = thin_singlet()
    ri = relative_illumination(lens, samples=5, max_height_mm=20 * math.tan(math.radians(20)), pupil_samples=32)
    assert ri.value[0] == 1.0 and ri.height_mm[0] == 0.0
    assert np.all(np.diff(ri.value) < 0)
    assert np.abs(ri.value - ri_cos4(ri.field_deg)).max() < 0.003
    assert ri.transmitted.min() == 1.0


@pytest.mark.property
def test_property_ri_image_space_assumes_a_focused_image():
    """property: Rimmer's image-space solid angle assumes the sensor is the
    bundles' focus; on the field-curved singlet the off-axis bundles focus
    before the sensor and it *rises* off axis (documented in
    calibration.optics.illumination), while flux conservation falls as cos⁴."""
    lens = thin_singlet()
    h = 20 * math.tan(math.radians(15))
    img = relative_illumination(lens, samples=3, max_height_mm=h, pupil_samples=24, method="image_space")
    flux = relative_illumination(lens, samples=3, max_height_mm=h, pupil_samples=24)
    assert img.value[-1] > 1.0 > flux.value[-1]


@pytest.mark.property
def test_property_ri_on_sensor():
    """property: the per-pixel map is 1 at the centre, falls toward the
    corners and is symmetric; beyond the last sample the last value holds."""
    sensor = Sensor(2.0, 64, 48)
    ri = smooth_ri(sensor)
    m = ri.on_sensor(sensor)
    assert m.shape == (48, 64)
    assert abs(m[23:25, 31:33].mean() - 1.0) < 1e-3
    assert np.allclose(m, m[::-1, ::-1]) and np.allclose(m, m[:, ::-1])
    assert m.min() == pytest.approx(m[0, 0]) and m[0, 0] < 0.4
    assert float(ri(10.0)) == pytest.approx(float(ri.value[-1]))


@pytest.mark.published
def test_published_e9_relative_illumination(e9_lens):
    """published + property: US-12210142-B2-e9 (F/1.95, 36.8° half field;
    ../shared/data/lenses/README.md: "about 77 % of the stop-filling rays
    pass at 0.7 field and 46 % at full field"). The transmitted fractions
    of the RI bundles match within ±2 points (as tests/calibration/optics/test_trace.py's
    vignetting test; 2-digit figure, grid of 64 across); RI falls monotonically from 1 and, at the sensor
    corner, lies in a plausible phone range (0.1–0.4; we get ≈ 0.18, with
    a vignetting cliff over the last 20 µm). Flux conservation and Rimmer's
    image-space method agree within 1 % of the axial value."""
    flux = relative_illumination(e9_lens, samples=9, pupil_samples=32)
    img = relative_illumination(e9_lens, samples=9, pupil_samples=32, method="image_space")
    assert flux.value[0] == 1.0
    assert np.all(np.diff(flux.value) <= 1e-3)
    corner = float(flux(e9_lens.sensor.half_diagonal_mm))
    assert 0.1 < corner < 0.4
    at = relative_illumination(e9_lens, fields_deg=[0.7 * e9_lens.half_fov_deg, e9_lens.half_fov_deg], pupil_samples=64)
    (f07, t07), (f10, t10) = ((v["field"], v["fraction"]) for v in E9["vignetting_pass_fraction"])
    assert (f07, f10) == (0.7, 1.0)
    assert abs(at.transmitted[1] - t07) < 0.02 and abs(at.transmitted[2] - t10) < 0.02
    common = np.intersect1d(np.round(flux.height_mm, 9), np.round(img.height_mm, 9))
    a = flux(common)
    b = img(common)
    assert np.abs(a - b).max() < 0.01

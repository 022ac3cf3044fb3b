"""What every lens-file reader shares (calibration/optics/io/common.py):
errors that name the file and the surface, JSON reading, the default sensor.

Kind: property (each test marked).
"""

from __future__ import annotations

import json
import math

import pytest

from calibration.optics.io.read import read_lens
from calibration.optics.lens import Sensor
from calibration.optics.paraxial import first_order, image_height

from tests.helpers import minimal_lens_dict as minimal
from tests.helpers import one_line_lens_error as one_line_error
from tests.helpers import write_lens_file as write


@pytest.mark.property
def test_truncated_json(tmp_path):
    """property"""
    text = json.dumps(minimal())
    p = write(tmp_path, "lens.json", text[: len(text) // 2])
    msg = one_line_error(read_lens, p)
    assert msg.startswith(f"{p}: not valid JSON")


@pytest.mark.property
def test_bad_other_formats(tmp_path):
    """property: unsupported geometry / profile / surface type name the surface."""
    opt = {"surface_group": {"surfaces": [
        {"type": "ObjectSurface", "geometry": {"type": "Plane", "cs": {"z": -math.inf}}},
        {"type": "Surface", "thickness": 1.0, "geometry": {"type": "ZernikePolynomialGeometry", "cs": {"z": 0.0}},
         "material_post": {"type": "IdealMaterial", "index": 1.0}},
        {"type": "Surface", "thickness": 0.0, "geometry": {"type": "Plane", "cs": {"z": 1.0}}}]},
        "aperture": {"type": "EPD", "value": 1.0}}
    p = write(tmp_path, "o.json", json.dumps(opt))
    assert "surface 1: geometry 'ZernikePolynomialGeometry' is not supported" in one_line_error(read_lens, p)
    dl = {"surfaces": [{"type": "Cubic", "r": 1.0, "d": 0.0, "mat2": "air"}], "d_sensor": 5.0}
    p = write(tmp_path, "d.json", json.dumps(dl))
    assert "surface 1: surface type 'Cubic' is not supported" in one_line_error(read_lens, p)
    dl["surfaces"][0].update(type="Spheric", c=0.1, mat2="unobtainium")
    p = write(tmp_path, "d.json", json.dumps(dl))
    assert "surface 1: unknown material 'unobtainium'" in one_line_error(read_lens, p)


@pytest.mark.property
def test_default_sensor_and_override(e9_zmx):
    """property: files without a sensor get 4:3 at 1 µm whose half-diagonal is the image height at full
    field; read_lens can replace it or change the pitch."""
    p = e9_zmx
    lens = read_lens(p)
    w, h = lens.sensor.width_px, lens.sensor.height_px
    assert lens.sensor.pixel_pitch_um == 1.0 and abs(w / h - 4 / 3) < 1e-3
    assert lens.sensor.half_diagonal_mm == pytest.approx(image_height(lens, 36.8), abs=1e-3)
    assert read_lens(p, pixel_pitch_um=0.8).sensor.width_px == pytest.approx(w / 0.8, abs=1)
    mine = Sensor(1.22, 4080, 3072)
    assert read_lens(p, sensor=mine).sensor == mine
    assert first_order(read_lens(p, sensor=mine)).efl == first_order(lens).efl

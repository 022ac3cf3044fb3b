"""The DeepLens importer (calibration/optics/io/deeplens.py): absolute
vertex positions, the stop and the sensor.

Kind: published (each test marked; the shared lens file, see lenses/README.md).
"""

from __future__ import annotations

import json
import math

import pytest

from calibration.optics.io.deeplens import read_deeplens

from tests.helpers import data_file


@pytest.mark.published
def test_deeplens_absolute_positions_and_stop():
    """published: DeepLens "d" is the absolute vertex z: thicknesses are its differences, the last
    one to d_sensor; the Stop's r sets the aperture; the sensor is sensor_size."""
    p = data_file("lenses", "classic", "deeplens_cooke.json")
    d = json.loads(p.read_text())
    lens = read_deeplens(p)
    z = [s["d"] for s in d["surfaces"]] + [d["d_sensor"]]
    assert [s.thickness for s in lens.surfaces] == [b - a for a, b in zip(z, z[1:])]
    assert lens.total_track == pytest.approx(d["d_sensor"], abs=1e-12)
    assert lens.stop_index == 4 and lens.surfaces[4].semi_diameter == 5.0 and lens.epd is None
    assert [s.material.key for s in lens.surfaces] == ["SCHOTT:N-SK16", "air", "SCHOTT:F2", "air", "air",
                                                      "SCHOTT:N-SK16", "air"]
    assert lens.sensor.size_mm == pytest.approx(tuple(d["sensor_size"]), abs=1e-3)
    assert lens.half_fov_deg == pytest.approx(math.degrees(math.atan(d["r_sensor"] / d["foclen"])))

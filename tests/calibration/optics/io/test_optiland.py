"""The optiland importer (calibration/optics/io/optiland.py): the Cooke
triplet's materials and geometry.

Kind: published (each test marked; the shared lens file, see lenses/README.md).
"""

from __future__ import annotations


import pytest

from calibration.optics.io.optiland import read_optiland

from tests.helpers import data_file


@pytest.mark.published
def test_optiland_cooke_materials_and_geometry():
    """published: optiland's Cooke triplet: SK16 from the HIKARI catalogue, F2 from SCHOTT, stop on
    surface 4, EPD 10, fields to 20°, primary 0.55 µm."""
    lens = read_optiland(data_file("lenses", "classic", "optiland_CookeTriplet.optiland.json"))
    keys = [s.material.key for s in lens.surfaces]
    assert keys == ["HIKARI:SK16", "air", "SCHOTT:F2", "air", "HIKARI:SK16", "air"]
    assert lens.stop_index == 3 and lens.epd == 10 and lens.half_fov_deg == 20.0 and lens.primary_nm == 550.0
    assert lens.surfaces[0].curvature == 1 / 22.01359 and lens.surfaces[-1].thickness == 42.20778

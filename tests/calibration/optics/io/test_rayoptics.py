"""The rayoptics importer (calibration/optics/io/rayoptics.py).

Kinds (each test marked): published (the shared lens files'
prescriptions; see lenses/README.md) and property (an unsupported profile
names the surface; a glass outside the catalogue is built from the file's
coefficients).
"""

from __future__ import annotations

import json

import pytest

from calibration.optics.io.rayoptics import read_rayoptics
from calibration.optics.io.read import read_lens
from calibration.optics.materials import lookup
from calibration.optics.paraxial import image_height

from tests.helpers import data_file
from tests.helpers import one_line_lens_error as one_line_error
from tests.helpers import write_lens_file as write


@pytest.mark.property
def test_bad_rayoptics_profile(tmp_path):
    """property: an unsupported rayoptics profile names the surface."""
    d = json.loads(data_file("lenses", "classic", "rayoptics_Sasian_Triplet.roa").read_text())
    om = d["optical_model"]["attributes"]
    pid = om["seq_model"]["attributes"]["ifcs"][2]["attributes"]["profile_id"]
    om["profile_dict"][pid]["__instance_type__"][1] = "YToroid"
    p = write(tmp_path, "t.roa", json.dumps(d))
    assert "surface 2: surface profile 'YToroid' is not supported" in one_line_error(read_lens, p)


@pytest.mark.published
def test_rayoptics_radial_polynomial_and_conic():
    """published: the cell-phone lens's RadialPolynomial surfaces keep their odd terms (coefs[i] on
    ρ^(i+1)); ec = conic + 1; the stop is the dummy surface 1; F/3.5; field 3.5 mm image height."""
    lens = read_rayoptics(data_file("lenses", "phone", "rayoptics_cell_phone_camera_US7535658.roa"))
    s = lens.surfaces[1]
    assert s.curvature == 0.509683995922528 and s.conic == pytest.approx(2.153 - 1.0, abs=1e-15)
    assert s.asphere[:3] == ((3, -0.01895), (4, 0.02426), (5, -0.05123))
    assert lens.stop_index == 0 and lens.f_number == 3.5
    assert image_height(lens, lens.half_fov_deg) == pytest.approx(3.5, rel=1e-12)
    sasian = read_rayoptics(data_file("lenses", "classic", "rayoptics_Sasian_Triplet.roa"))
    assert [m.material.key for m in sasian.surfaces][::2] == ["SCHOTT:N-LAK9", "SCHOTT:N-SF5", "SCHOTT:N-LAK9"]
    assert sasian.stop_index == 2 and sasian.epd == 12.5 and sasian.half_fov_deg == 20.0


@pytest.mark.property
def test_rayoptics_glass_outside_the_catalogue_uses_the_file_sellmeier(tmp_path):
    """property: a SCHOTT glass name the catalogue lacks is built from the file's coefficients."""
    d = json.loads(data_file("lenses", "classic", "rayoptics_Sasian_Triplet.roa").read_text())
    gap = d["optical_model"]["attributes"]["seq_model"]["attributes"]["gaps"][1]["attributes"]["medium"]
    gap["attributes"]["gname"] = "N-LAK99"
    m = read_lens(write(tmp_path, "g.roa", json.dumps(d))).surfaces[0].material
    ref = lookup("N-LAK9")
    assert (m.name, m.catalog, m.formula, m.coefficients) == ("N-LAK99", "SCHOTT", "sellmeier", ref.coefficients)
    assert m.nd == pytest.approx(ref.nd, abs=1e-5) and m.vd == pytest.approx(ref.vd, abs=0.01)

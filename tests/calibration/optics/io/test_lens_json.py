"""The lens/v1 JSON format (calibration/optics/io/lens_json.py).

Kind: property (each test marked): round trips (every imported shared lens
file, random lenses), the format's semantics, atomic saves, and one-line
errors naming the file, the surface, the value and the valid choices.
"""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from calibration.optics.io.lens_json import lens_from_dict, lens_to_dict, load_lens, save_lens
from calibration.optics.io.read import read_lens
from calibration.optics.lens import Lens, Sensor, Surface
from calibration.optics.materials import AIR, lookup, model_material
from calibration.optics.paraxial import image_height

from tests.helpers import data_file
from tests.helpers import minimal_lens_dict as minimal
from tests.helpers import one_line_lens_error as one_line_error
from tests.helpers import write_lens_file as write


SHARED = [("phone", "US-12210142-B2-e9.zmx"), ("phone", "US-12210142-B2-e2.zmx"),
          ("phone", "US-11906710-B2-e1.zmx"), ("phone", "US-11933948-B2-e11.zmx"),
          ("phone", "rayoptics_cell_phone_camera_US7535658.roa"), ("classic", "deeplens_cooke.json"),
          ("classic", "optiland_CookeTriplet.optiland.json"), ("classic", "optiland_DoubleGauss.optiland.json"),
          ("classic", "rayoptics_Sasian_Triplet.roa")]


# -- lens/v1 ---------------------------------------------------------------------

@pytest.mark.property
@pytest.mark.parametrize("where", SHARED, ids=lambda w: w[1])
def test_round_trip_is_exact_for_every_imported_lens(where, tmp_path):
    """property: save_lens then load_lens gives an equal Lens (and the same metadata); a
    second save writes the same bytes."""
    lens = read_lens(data_file("lenses", *where))
    p = save_lens(lens, tmp_path / "lens.json")
    again = load_lens(p)
    assert again == lens
    assert again.metadata == json.loads(json.dumps(lens.metadata))
    assert save_lens(again, tmp_path / "lens2.json").read_bytes() == p.read_bytes()
    assert read_lens(p) == lens
    assert list(tmp_path.glob(".*tmp")) == []


_floats = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
_materials = st.sampled_from([AIR, lookup("N-SK16"), lookup("HIKARI:SK16"), model_material(1.544, 55.9),
                              model_material(1.7)])


@st.composite
def lenses(draw):
    n = draw(st.integers(1, 6))
    surfaces = []
    for i in range(n):
        orders = draw(st.lists(st.integers(1, 40), unique=True, max_size=5))
        surfaces.append(Surface(
            curvature=draw(st.floats(-0.5, 0.5, allow_nan=False)), conic=draw(_floats),
            asphere=tuple(sorted((o, draw(_floats)) for o in orders)), thickness=draw(_floats),
            material=draw(_materials), semi_diameter=draw(st.none() | st.floats(1e-3, 50.0)),
            stop=(i == draw(st.integers(0, n - 1))), name=draw(st.text(max_size=8))))
    if sum(s.stop for s in surfaces) > 1:
        surfaces = [s.replace(stop=False) for s in surfaces]
    return Lens(tuple(surfaces), f_number=draw(st.none() | st.floats(0.5, 32.0)),
                epd=draw(st.floats(0.1, 100.0)), half_fov_deg=draw(st.floats(0.0, 89.0)),
                wavelengths_nm=tuple(draw(st.lists(st.floats(300.0, 1100.0), min_size=1, max_size=4))),
                primary_nm=draw(st.floats(300.0, 1100.0)),
                object_distance=draw(st.just(math.inf) | st.floats(1.0, 1e6)),
                sensor=Sensor(draw(st.floats(0.5, 5.0)), draw(st.integers(1, 9000)), draw(st.integers(1, 9000))),
                name=draw(st.text(max_size=12)))


@pytest.mark.property
@settings(max_examples=60, deadline=None)
@given(lens=lenses())
def test_round_trip_property(lens):
    """property: lens_from_dict(json(lens_to_dict(lens))) == lens for random lenses."""
    text = json.dumps(lens_to_dict(lens), allow_nan=False)
    assert lens_from_dict(json.loads(text)) == lens


@pytest.mark.property
def test_lens_v1_semantics():
    """property: radius/curvature, aspheric dict and list forms, defaults."""
    d = minimal()
    d["surfaces"][0]["aspheric"] = {"4": 1e-5, "3": -2e-4, "20": 1e-12}
    d["surfaces"][2]["aspheric"] = [0.001, 2e-6]
    lens = lens_from_dict(d)
    s1, s2, s3 = lens.surfaces
    assert s1.curvature == 1 / 50.0 and s2.curvature == 0.0 and s3.curvature == -0.02
    assert s1.asphere == ((3, -2e-4), (4, 1e-5), (20, 1e-12))
    assert s3.asphere == ((2, 0.001), (4, 2e-6))
    assert s1.material == lookup("SCHOTT:N-BK7") and s2.material == AIR and s2.stop
    assert lens.wavelengths_nm == Lens((Surface(),), epd=1.0).wavelengths_nm
    assert lens.primary_nm == Lens((Surface(),), epd=1.0).primary_nm
    assert math.isinf(lens.object_distance) and lens.half_fov_deg == 0.0
    assert lens_from_dict(minimal(wavelengths_nm=[450.0, 550.0, 650.0])).primary_nm == 550.0


@pytest.mark.property
def test_stop_size_aperture_and_image_height_field():
    """property: aperture.stop_semi_diameter sets the stop; field.image_height converts to an angle."""
    d = minimal(aperture={"stop_semi_diameter": 5.0})
    lens = lens_from_dict(d)
    assert lens.epd is None and lens.f_number is None and lens.surfaces[1].semi_diameter == 5.0
    h = image_height(lens, 12.0)
    lens2 = lens_from_dict(minimal(field={"image_height": h}))
    assert lens2.half_fov_deg == pytest.approx(12.0, abs=1e-12)


@pytest.mark.property
def test_stop_size_lens_without_marked_stop_is_not_written():
    """property: a file must name the stop that sets its aperture."""
    lens = Lens((Surface(thickness=5.0, semi_diameter=2.0),), epd=None)
    assert "no surface is marked as the stop" in one_line_error(lens_to_dict, lens)


@pytest.mark.property
def test_save_is_atomic_and_leaves_no_partial_file(tmp_path, monkeypatch):
    """property: a failing write leaves the old file untouched and no temporary behind."""
    lens = lens_from_dict(minimal())
    p = save_lens(lens, tmp_path / "lens.json")
    before = p.read_bytes()
    import isp.io.files

    def boom(*a, **k):
        raise OSError("disk full")
    monkeypatch.setattr(isp.io.files.os, "replace", boom)  # the one atomic writer the project uses
    with pytest.raises(OSError):
        save_lens(lens.replace(epd=3.0), p)
    assert p.read_bytes() == before and sorted(x.name for x in tmp_path.iterdir()) == ["lens.json"]


# -- bad files ------------------------------------------------------------------

@pytest.mark.property
def test_non_numeric_value_names_file_and_surface(tmp_path):
    """property: the example of the issue, verbatim after the file name."""
    d = minimal()
    d["surfaces"].append({"curvature": 0.0, "conic": "x", "thickness": 1.0})
    p = write(tmp_path, "lens.json", json.dumps(d))
    msg = one_line_error(load_lens, p)
    assert msg == f"{p}: surface 4: conic must be a number, got 'x'"


@pytest.mark.property
@pytest.mark.parametrize("change, expect", [
    (lambda d: d["surfaces"][1].update(radious=3.0),
     "surface 2: unknown key 'radious' in the surface (valid: name, radius,"),
    (lambda d: d.update(colour="red"), "unknown key 'colour' in the lens (valid: schema,"),
    (lambda d: d["surfaces"][0].update(material="N-SK61"),
     "surface 1: unknown material 'N-SK61'; did you mean N-SK16"),
    (lambda d: d.update(aperture={"stop_semi_diameter": 2.0}) or d["surfaces"][1].pop("stop"),
     "aperture.stop_semi_diameter needs a surface marked \"stop\": true"),
    (lambda d: d["surfaces"][2].pop("thickness"), "surface 3: 'thickness' is missing"),
    (lambda d: d["surfaces"][0].update(aspheric={"four": 1.0}),
     "surface 1: aspheric order must be an integer ≥ 1, got 'four'"),
    (lambda d: d["surfaces"][0].update(curvature=0.1), "surface 1: give 'radius' or 'curvature', not both"),
    (lambda d: d["surfaces"][0].update(semi_diameter=-1), "surface 1: semi_diameter must be positive, got -1"),
    (lambda d: d.update(schema="lens/v2"), "'schema' must be 'lens/v1', got 'lens/v2'"),
    (lambda d: d.pop("aperture"), "'aperture' is missing"),
    (lambda d: d["surfaces"][0].update(stop=True), "surface 2: more than one surface is marked as the stop"),
    (lambda d: d.update(field={"half_fov_deg": 95.0}), "half field of view must be in [0, 90) degrees, got 95.0"),
])
def test_bad_lens_v1_files(tmp_path, change, expect):
    """property: one line, the file, the surface, the value, the valid choices."""
    d = minimal()
    change(d)
    p = write(tmp_path, "lens.json", json.dumps(d))
    msg = one_line_error(load_lens, p)
    assert msg.startswith(f"{p}: ") and expect in msg, msg

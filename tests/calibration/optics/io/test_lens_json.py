"""Lens files: the lens/v1 JSON format, the importers (Zemax .zmx, optiland,
DeepLens, rayoptics) and their errors.

Kinds: property (round trips, format semantics, one-line errors naming the
file and the surface) and published (the shared lens files' prescriptions
and README figures; see lenses/README.md)."""

from __future__ import annotations

import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from calibration.optics.io.deeplens import read_deeplens
from calibration.optics.io.lens_json import lens_from_dict, lens_to_dict, load_lens, save_lens
from calibration.optics.io.optiland import read_optiland
from calibration.optics.io.rayoptics import read_rayoptics
from calibration.optics.io.read import read_lens
from calibration.optics.io.zmx import read_zmx
from calibration.optics.lens import Lens, LensError, Sensor, Surface
from calibration.optics.materials import AIR, lookup, model_material
from calibration.optics.paraxial import efl, first_order, image_height

from tests.helpers import data_file

SHARED = [("phone", "US-12210142-B2-e9.zmx"), ("phone", "US-12210142-B2-e2.zmx"),
          ("phone", "US-11906710-B2-e1.zmx"), ("phone", "US-11933948-B2-e11.zmx"),
          ("phone", "rayoptics_cell_phone_camera_US7535658.roa"), ("classic", "deeplens_cooke.json"),
          ("classic", "optiland_CookeTriplet.optiland.json"), ("classic", "optiland_DoubleGauss.optiland.json"),
          ("classic", "rayoptics_Sasian_Triplet.roa")]

SINGLET_ZMX = """VERS 190513 1 1 1
MODE SEQ
NAME singlet
UNIT MM X W X CM MR CPMM
ENPD 10
FTYP 0 0 2 3 0 0 0 2
XFLN 0 0
YFLN 0 10
WAVM 1 0.4861327 1
WAVM 2 0.5875618 1
WAVM 3 0.6562725 1
PWAV 2
SURF 0
  TYPE STANDARD
  CURV 0 0 0 0 0 ""
  DISZ INFINITY
SURF 1
  STOP
  TYPE STANDARD
  CURV 0.0 0 0 0 0 ""
  DISZ 5
  DIAM 5 0 0 0 1 ""
SURF 2
  TYPE EVENASPH
  CURV 0.02 0 0 0 0 ""
  PARM 1 0
  PARM 2 1e-05
  DISZ 4
  GLAS N-BK7 1 0 1.5168 64.17 0 0 0 0 0 0
  DIAM 6 0 0 0 1 ""
SURF 3
  TYPE STANDARD
  CURV -0.02 0 0 0 0 ""
  DISZ 45
  DIAM 6 0 0 0 1 ""
SURF 4
  TYPE STANDARD
  CURV 0 0 0 0 0 ""
  DISZ 0
"""


def write(tmp_path, name, text, encoding="utf-8"):
    p = tmp_path / name
    p.write_bytes(text.encode(encoding))
    return p


def one_line_error(fn, *args, **kw) -> str:
    """The message of the LensError ``fn`` raises; asserts it is one line."""
    with pytest.raises(LensError) as e:
        fn(*args, **kw)
    msg = str(e.value)
    assert "\n" not in msg and msg, msg
    return msg


def minimal(**over) -> dict:
    d = {"schema": "lens/v1",
         "surfaces": [{"radius": 50.0, "thickness": 4.0, "material": "N-BK7", "semi_diameter": 6.0},
                      {"radius": "inf", "thickness": 1.0, "stop": True, "semi_diameter": 5.0},
                      {"curvature": -0.02, "thickness": 45.0}],
         "aperture": {"epd": 10.0}}
    d.update(over)
    return d


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


@pytest.mark.property
def test_truncated_json(tmp_path):
    """property"""
    text = json.dumps(minimal())
    p = write(tmp_path, "lens.json", text[: len(text) // 2])
    msg = one_line_error(read_lens, p)
    assert msg.startswith(f"{p}: not valid JSON")


@pytest.mark.property
def test_unsupported_files(tmp_path):
    """property: unknown extension and unrecognised JSON name the file."""
    assert "unsupported lens file type '.txt'" in one_line_error(read_lens, write(tmp_path, "a.txt", "x"))
    assert "unrecognised JSON lens file" in one_line_error(read_lens, write(tmp_path, "a.json", "[1, 2]"))
    assert "cannot read" in one_line_error(read_lens, tmp_path / "missing.zmx")


@pytest.mark.property
@pytest.mark.parametrize("old, new, expect", [
    ("  TYPE EVENASPH", "  TYPE TOROIDAL",
     "surface 2: surface type 'TOROIDAL' is not supported (supported: STANDARD,"),
    ("  CURV -0.02 0", "  CURV abc 0", "surface 3: CURV must be a number, got 'abc'"),
    ("GLAS N-BK7", "GLAS N-BK77", "surface 2: GLAS: unknown material 'N-BK77'; did you mean N-BK7"),
    ("ENPD 10", "FLOA", None),
    ("  DISZ INFINITY", "  DISZ INFINITY\n  GLAS N-BK7", "surface 0: the object space is not air"),
    ("MODE SEQ", "MODE NSC", "MODE NSC is not a sequential lens"),
    ("ENPD 10", "OBNA 0.1", "aperture type OBNA"),
    ("FTYP 0 0 2", "FTYP 4 0 2", "field type 4"),
    ("  PARM 2 1e-05", "  PARM 9 1e-05", "surface 2: PARM 9 is not a EVENASPH coefficient"),
])
def test_bad_zmx_files(tmp_path, old, new, expect):
    """property: one line naming the file and the surface."""
    text = SINGLET_ZMX.replace(old, new, 1)
    if new == "FLOA":  # float by stop size without a stop: the aperture is undefined
        text = text.replace("  STOP\n", "")
        expect = "no aperture: the file has no FNUM or ENPD, and no STOP surface with a DIAM"
    p = write(tmp_path, "lens.zmx", text)
    msg = one_line_error(read_lens, p)
    assert msg.startswith(f"{p}: ") and expect in msg, msg


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
def test_bad_rayoptics_profile(tmp_path):
    """property: an unsupported rayoptics profile names the surface."""
    d = json.loads(data_file("lenses", "classic", "rayoptics_Sasian_Triplet.roa").read_text())
    om = d["optical_model"]["attributes"]
    pid = om["seq_model"]["attributes"]["ifcs"][2]["attributes"]["profile_id"]
    om["profile_dict"][pid]["__instance_type__"][1] = "YToroid"
    p = write(tmp_path, "t.roa", json.dumps(d))
    assert "surface 2: surface profile 'YToroid' is not supported" in one_line_error(read_lens, p)


# -- Zemax ------------------------------------------------------------------------

@pytest.mark.property
def test_zmx_singlet(tmp_path):
    """property: the prescription as written: numbering, PARM 2 = ρ⁴, GLAS, DIAM, STOP, field, wavelengths."""
    lens = read_lens(write(tmp_path, "s.zmx", SINGLET_ZMX))
    floating = read_lens(write(tmp_path, "f.zmx", SINGLET_ZMX.replace("ENPD 10", "FLOA")))
    assert floating.epd is None and floating.f_number is None and first_order(floating).epd == 10.0
    s1, s2, s3 = lens.surfaces
    assert s1.stop and s1.material == AIR and s1.thickness == 5.0 and s1.semi_diameter == 5.0
    assert s2.curvature == 0.02 and s2.asphere == ((4, 1e-5),) and s2.material == lookup("N-BK7")
    assert s3.thickness == 45.0 and lens.epd == 10.0 and lens.half_fov_deg == 10.0
    assert lens.wavelengths_nm == pytest.approx((486.1327, 587.5618, 656.2725))
    assert lens.primary_nm == pytest.approx(587.5618)


@pytest.mark.property
@pytest.mark.parametrize("encoding", ["utf-16", "utf-16-le", "utf-16-be", "utf-8-sig", "latin-1"])
def test_zmx_encodings(tmp_path, encoding):
    """property: UTF-16 with BOM (OpticStudio), without BOM, UTF-8 with BOM, Latin-1 all read alike."""
    ref = read_lens(write(tmp_path, "a.zmx", SINGLET_ZMX))
    assert read_zmx(write(tmp_path, "b.zmx", SINGLET_ZMX, encoding)) == ref


@pytest.mark.property
def test_zmx_extended_asphere_normalization(tmp_path):
    """property: XASPHERE A_i on (ρ/R_n)^(2i) equals the EVENASPH coefficient A_i/R_n^(2i); terms to ρ^20."""
    rn = 2.0
    x = SINGLET_ZMX.replace("  TYPE EVENASPH", "  TYPE XASPHERE").replace(
        "  PARM 1 0\n  PARM 2 1e-05\n",
        f"  XDAT 1 10 0 0 1 0 0 \"\"\n  XDAT 2 {rn} 0 0 1 0 0 \"\"\n  XDAT 3 0 0 0 1 0 0 \"\"\n"
        f"  XDAT 4 {1e-5 * rn ** 4!r} 0 0 1 0 0 \"\"\n  XDAT 12 {3e-14 * rn ** 20!r} 0 0 1 0 0 \"\"\n"
        f"  XDAT 13 5.0 0 0 1 0 0 \"\"\n")  # term 11 (ρ^22) lies beyond the term count: ignored
    s = read_lens(write(tmp_path, "x.zmx", x)).surfaces[1]
    assert [o for o, _ in s.asphere] == [4, 20]
    assert s.coefficient(4) == pytest.approx(1e-5, rel=1e-15)
    assert s.coefficient(20) == pytest.approx(3e-14, rel=1e-15)


@pytest.mark.property
def test_zmx_odd_aspheres(tmp_path):
    """property: ODDASPH PARM i is the ρ^i term; XOSPHERE XDAT 2+i is A_i/R_n^i on ρ^i."""
    odd = (SINGLET_ZMX.replace("  TYPE EVENASPH", "  TYPE ODDASPH")
           .replace("  PARM 1 0\n", "  PARM 1 0\n  PARM 3 -2e-4\n"))
    assert read_lens(write(tmp_path, "o.zmx", odd)).surfaces[1].asphere == ((2, 1e-5), (3, -2e-4))
    xo = SINGLET_ZMX.replace("  TYPE EVENASPH", "  TYPE XOSPHERE").replace(
        "  PARM 1 0\n  PARM 2 1e-05\n",
        "  XDAT 1 3 0 0 1 0 0 \"\"\n  XDAT 2 2 0 0 1 0 0 \"\"\n  XDAT 5 0.8 0 0 1 0 0 \"\"\n")
    assert read_lens(write(tmp_path, "x.zmx", xo)).surfaces[1].asphere == ((3, 0.1),)


@pytest.mark.property
def test_zmx_units_and_a2_term(tmp_path):
    """property: UNIT CM scales lengths, curvatures and coefficients; EVENASPH PARM 1 (ρ²) adds 2·α₁
    to the paraxial curvature."""
    mm = read_lens(write(tmp_path, "mm.zmx", SINGLET_ZMX))
    cm_text = (SINGLET_ZMX.replace("UNIT MM", "UNIT CM").replace("ENPD 10", "ENPD 1")
               .replace("DISZ 5\n", "DISZ 0.5\n").replace("DISZ 4\n", "DISZ 0.4\n")
               .replace("DISZ 45\n", "DISZ 4.5\n").replace("CURV 0.02 ", "CURV 0.2 ")
               .replace("CURV -0.02 ", "CURV -0.2 ").replace("PARM 2 1e-05", "PARM 2 0.01")
               .replace("DIAM 5 ", "DIAM 0.5 ").replace("DIAM 6 ", "DIAM 0.6 "))
    cm = read_lens(write(tmp_path, "cm.zmx", cm_text))
    for a, b in zip(mm.surfaces, cm.surfaces):
        assert b.curvature == pytest.approx(a.curvature, rel=1e-14) and b.thickness == pytest.approx(a.thickness)
        assert b.coefficient(4) == pytest.approx(a.coefficient(4), rel=1e-14)
    assert efl(cm) == pytest.approx(efl(mm), rel=1e-13)
    a2_text = SINGLET_ZMX.replace("CURV 0.02 ", "CURV 0.0 ").replace("PARM 1 0", "PARM 1 0.01")
    a2 = read_lens(write(tmp_path, "a2.zmx", a2_text))
    assert efl(a2) == pytest.approx(efl(mm), rel=1e-13)


@pytest.mark.property
def test_zmx_glass_catalogues_and_model_fallback(tmp_path):
    """property: GCAT orders the catalogues; unknown_glass='model' falls back to the line's nd/vd."""
    text = SINGLET_ZMX.replace("GLAS N-BK7 1 0 1.5168 64.17", "GLAS SK16 1 0 1.62041 60.3")
    assert read_zmx(write(tmp_path, "a.zmx", text)).surfaces[1].material == lookup("HIKARI:SK16")
    odd = SINGLET_ZMX.replace("GLAS N-BK7 1 0 1.5168 64.17", "GLAS S-FOO9 1 0 1.6 40")
    m = read_zmx(write(tmp_path, "b.zmx", odd), unknown_glass="model").surfaces[1].material
    assert (m.name, m.nd, m.vd, m.formula) == ("S-FOO9", 1.6, 40.0, "model")
    blank = SINGLET_ZMX.replace("GLAS N-BK7 1 0 1.5168 64.17", "GLAS ___BLANK 1 0 1.544 55.9")
    assert read_zmx(write(tmp_path, "c.zmx", blank)).surfaces[1].material == model_material(1.544, 55.9)


@pytest.mark.property
def test_zmx_image_height_field(tmp_path):
    """property: FTYP 2 (paraxial image height) becomes the angle of that chief-ray height on the image plane."""
    text = SINGLET_ZMX.replace("FTYP 0 0 2", "FTYP 2 0 2").replace("YFLN 0 10", "YFLN 0 8")
    lens = read_lens(write(tmp_path, "h.zmx", text))
    assert image_height(lens, lens.half_fov_deg) == pytest.approx(8.0, rel=1e-12)
    assert "field_conversion" in lens.metadata


@pytest.mark.published
def test_zmx_phone_lens_e9(e9_lens):
    """published: US-12210142-B2-e9 as converted — 7 plastic aspheres + IR filter, stop on the
    dummy surface 5, model glasses 1.544/55.9, 1.639/23.5, 1.53/55.8 and 1.517/64.2, half-FOV 36.8°,
    F/1.95, and the file's DIAM semi-diameters."""
    lens = e9_lens
    assert len(lens.surfaces) == 17 and lens.half_fov_deg == 36.8 and lens.f_number == 1.95
    stop = lens.surfaces[4]
    assert stop.stop and stop.material == AIR and stop.curvature == 0 and stop.semi_diameter == 1.11377933203941
    elements = lens.elements()
    assert len(elements) == 8
    plastic = [lens.surfaces[i].material for i, _ in elements[:7]]
    assert {m.name for m in plastic} == {"1.544/55.9", "1.639/23.5", "1.53/55.8"}
    first, last = elements[-1]
    assert lens.surfaces[first].material == model_material(1.517, 64.2)
    assert lens.surfaces[first].curvature == lens.surfaces[last].curvature == 0.0
    s1 = lens.surfaces[0]
    assert s1.curvature == 0.327332242225859 and s1.conic == -11.705
    assert s1.asphere == ((4, 0.0032982), (6, 0.011557), (8, -0.014484), (10, 0.005943),
                          (12, 0.0049135), (14, -0.0034688), (16, 0.00055356))
    assert lens.surfaces[-1].thickness == 0.402 and lens.primary_nm == pytest.approx(587.6)


# -- the other importers ------------------------------------------------------------

@pytest.mark.published
def test_optiland_cooke_materials_and_geometry():
    """published: optiland's Cooke triplet: SK16 from the HIKARI catalogue, F2 from SCHOTT, stop on
    surface 4, EPD 10, fields to 20°, primary 0.55 µm."""
    lens = read_optiland(data_file("lenses", "classic", "optiland_CookeTriplet.optiland.json"))
    keys = [s.material.key for s in lens.surfaces]
    assert keys == ["HIKARI:SK16", "air", "SCHOTT:F2", "air", "HIKARI:SK16", "air"]
    assert lens.stop_index == 3 and lens.epd == 10 and lens.half_fov_deg == 20.0 and lens.primary_nm == 550.0
    assert lens.surfaces[0].curvature == 1 / 22.01359 and lens.surfaces[-1].thickness == 42.20778


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

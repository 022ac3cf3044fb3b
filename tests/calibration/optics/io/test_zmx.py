"""The Zemax .zmx importer (calibration/optics/io/zmx.py).

Kinds (each test marked): property (the prescription as written, encodings,
aspheres, units, glass catalogues, image-height fields, one-line errors
naming the file and the surface) and published (the e9 phone lens's
prescription; see lenses/README.md).
"""

from __future__ import annotations


import pytest

from calibration.optics.io.read import read_lens
from calibration.optics.io.zmx import read_zmx
from calibration.optics.materials import AIR, lookup, model_material
from calibration.optics.paraxial import efl, first_order, image_height

from tests.helpers import one_line_lens_error as one_line_error
from tests.helpers import write_lens_file as write


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


# -- bad files ------------------------------------------------------------------

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

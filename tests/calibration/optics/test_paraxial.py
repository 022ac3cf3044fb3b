"""Paraxial optics: closed-form checks (kind: property — each against an
analytic formula of first-order optics, Kingslake & Johnson, Lens Design
Fundamentals, 2nd ed., ch. 3; Smith, Modern Optical Engineering, 4th ed.,
§2–4), and the published first-order figures of the shared lenses (kind:
published — lenses/README.md, measured with optiland 0.6.3 and rayoptics
0.9.8)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from calibration.optics.lens import Lens, LensError, Surface
from calibration.optics.io import read_lens
from calibration.optics.materials import model_material
from calibration.optics.paraxial import efl, entrance_pupil, field_angle, first_order, image_height

from tests.helpers import data_file, reference

GLASS = model_material(1.5168, 64.17)
D_NM = 587.5618


def singlet(c1, c2, t, n=1.5168, back=None, **kw):
    glass = model_material(n, 64.17)
    kw.setdefault("epd", 10.0)
    return Lens((Surface(curvature=c1, thickness=t, material=glass),
                 Surface(curvature=c2, thickness=100.0 if back is None else back)), **kw)


# -- closed forms -------------------------------------------------------------

@pytest.mark.property
@settings(max_examples=60, deadline=None)
@given(c1=st.floats(-0.05, 0.05), c2=st.floats(-0.05, 0.05), n=st.floats(1.4, 2.0))
def test_thin_lens_efl(c1, c2, n):
    """property: t = 0 gives 1/f = (n − 1)(c1 − c2) exactly."""
    if abs(c1 - c2) < 1e-4:
        return
    lens = singlet(c1, c2, 0.0, n)
    assert efl(lens, D_NM) == pytest.approx(1.0 / ((n - 1.0) * (c1 - c2)), rel=1e-12)


@pytest.mark.property
@settings(max_examples=60, deadline=None)
@given(c1=st.floats(-0.1, 0.1), c2=st.floats(-0.1, 0.1), t=st.floats(0.5, 20.0), n=st.floats(1.4, 2.0))
def test_thick_lens_lensmakers_formula(c1, c2, t, n):
    """property: 1/f = (n−1)[c1 − c2 + (n−1) t c1 c2 / n], BFL = f (1 − (n−1) t c1 / n)."""
    power = (n - 1.0) * (c1 - c2 + (n - 1.0) * t * c1 * c2 / n)
    if abs(power) < 1e-4:
        return
    lens = singlet(c1, c2, t, n)
    f = 1.0 / power
    fo = first_order(lens, D_NM)
    assert fo.efl == pytest.approx(f, rel=1e-10)
    assert fo.bfl == pytest.approx(f * (1.0 - (n - 1.0) * t * c1 / n), rel=1e-9, abs=1e-9)


@pytest.mark.property
@pytest.mark.parametrize("t, n", [(1.0, 1.5168), (5.0, 1.8), (0.21, 1.52)])
def test_plate_shifts_focus_by_t_1_minus_1_over_n(t, n):
    """property: a plane-parallel plate behind a lens moves the focus back by t(1 − 1/n)."""
    lens = singlet(0.02, -0.02, 3.0, back=20.0)
    plate = Lens(lens.surfaces[:1] + (lens.surfaces[1].replace(thickness=20.0),
                                      Surface(thickness=t, material=model_material(n, 64.0)),
                                      Surface(thickness=50.0)), epd=10.0)
    focus = first_order(lens, D_NM).paraxial_image_z
    shifted = first_order(plate, D_NM).paraxial_image_z
    assert shifted - focus == pytest.approx(t * (1.0 - 1.0 / n), rel=1e-11)
    assert efl(plate, D_NM) == pytest.approx(efl(lens, D_NM), rel=1e-13)


@pytest.mark.property
def test_quadratic_asphere_term_adds_2_A2_to_curvature():
    """property: sag A2 ρ² has the paraxial power of curvature 2·A2; higher orders and conic none."""
    a = singlet(0.02, -0.01, 3.0)
    b = Lens((Surface(curvature=0.0, asphere=((2, 0.01), (4, 3e-4), (6, -1e-5)), conic=-2.0,
                      thickness=3.0, material=a.surfaces[0].material),
              a.surfaces[1].replace(conic=5.0, asphere=((3, 1e-3), (8, 1e-7)))), epd=10.0)
    assert efl(b, D_NM) == pytest.approx(efl(a, D_NM), rel=1e-13)


@pytest.mark.property
def test_entrance_pupil_of_a_stop_behind_a_thin_lens():
    """property: stop d behind a thin lens of power φ: z_EP = d/(1 − dφ), EPD = 2 sd/(1 − dφ)."""
    c, n, d, sd = 0.02, 1.5, 10.0, 2.0
    phi = 2 * (n - 1) * c
    lens = Lens((Surface(curvature=c, thickness=0.0, material=model_material(n)),
                 Surface(curvature=-c, thickness=d),
                 Surface(thickness=40.0, stop=True, semi_diameter=sd)))
    z, dia = entrance_pupil(lens)
    assert z == pytest.approx(d / (1 - d * phi), rel=1e-12)
    assert dia == pytest.approx(2 * sd / (1 - d * phi), rel=1e-12)
    fo = first_order(lens)
    assert fo.f_number == pytest.approx((1 / phi) / dia, rel=1e-12)


@pytest.mark.property
def test_exit_pupil_of_a_stop_before_a_thin_lens():
    """property: stop d before a thin lens: XP at d/(dφ − 1) from the lens, XPD = 2 sd/|1 − dφ|."""
    c, n, d, sd = 0.02, 1.5, 10.0, 2.0
    phi = 2 * (n - 1) * c
    lens = Lens((Surface(thickness=d, stop=True, semi_diameter=sd),
                 Surface(curvature=c, thickness=0.0, material=model_material(n)),
                 Surface(curvature=-c, thickness=60.0)))
    fo = first_order(lens)
    assert fo.entrance_pupil_z == 0.0 and fo.epd == pytest.approx(2 * sd)
    assert fo.exit_pupil_z - d == pytest.approx(d / (d * phi - 1), rel=1e-12)
    assert fo.exit_pupil_diameter == pytest.approx(2 * sd / abs(1 - d * phi), rel=1e-12)
    assert fo.exit_pupil_to_image == pytest.approx(fo.exit_pupil_z - lens.total_track)


@pytest.mark.property
def test_finite_conjugates_working_f_number_and_magnification():
    """property: a thin lens at 2f–2f images at 2f with m = −1 and working F/# = 2·EFL/EPD."""
    c, n = 0.02, 1.5
    f = 1 / (2 * (n - 1) * c)
    lens = Lens((Surface(curvature=c, thickness=0.0, material=model_material(n)),
                 Surface(curvature=-c, thickness=2 * f)), epd=5.0, object_distance=2 * f)
    fo = first_order(lens)
    assert fo.bfl == pytest.approx(2 * f, rel=1e-12)
    assert fo.magnification == pytest.approx(-1.0, rel=1e-12)
    assert fo.working_f_number == pytest.approx(2 * f / 5.0, rel=1e-12)
    assert fo.f_number == pytest.approx(f / 5.0, rel=1e-12)


@pytest.mark.property
def test_image_height_and_field_angle_are_inverse():
    """property: h = f tan θ at focus; field_angle inverts image_height on either plane."""
    lens = singlet(0.02, -0.02, 3.0, back=95.0)
    f = efl(lens)
    assert image_height(lens, 20.0, at="focus") == pytest.approx(f * math.tan(math.radians(20.0)), rel=1e-12)
    for at in ("image", "focus"):
        h = image_height(lens, 17.0, at=at)
        assert field_angle(lens, h, at=at) == pytest.approx(17.0, rel=1e-12)


@pytest.mark.property
def test_stop_size_aperture_and_afocal_f_number_error():
    """property: "float by stop size" images the stop; an F-number on an afocal lens is refused."""
    lens = singlet(0.02, -0.02, 3.0).with_surface(0, stop=True, semi_diameter=4.0).replace(epd=None)
    assert first_order(lens).epd == pytest.approx(8.0)
    afocal = Lens((Surface(thickness=2.0, material=model_material(1.5)), Surface(thickness=10.0)),
                  f_number=2.0)  # a plane-parallel plate
    assert math.isinf(efl(afocal))
    with pytest.raises(LensError, match="afocal"):
        first_order(afocal)


# -- the shared lenses (published) --------------------------------------------

# (folder, file): (EFL mm, F/#, half-FOV deg, elements, stop surface, TTL mm), as printed
LENSES = {(r["folder"], r["file"]): (r["efl_mm"], r["f_number"], r["half_fov_deg"], r["elements"], r["stop_surface"],
                                     r["ttl_mm"]) for r in reference("lens_figures.json")["first_order"]}
E9 = reference("lens_figures.json")["e9"]


def _printed(value: float) -> float:
    """Half a unit in the last printed decimal of ``value`` (e.g. 3.96 → 0.005)."""
    text = repr(value)
    decimals = len(text.split(".")[1]) if "." in text else 0
    return 0.5 * 10.0 ** -decimals


@pytest.mark.published
@pytest.mark.parametrize("where", sorted(LENSES), ids=lambda w: w[1])
def test_published_first_order_figures(where):
    """published: EFL and F/# within 0.1 % (or the printed precision, if coarser), half-FOV to the
    printed precision, element count, stop surface and TTL of lenses/README.md, at each file's
    primary wavelength."""
    lens = read_lens(data_file("lenses", *where))
    efl_ref, fno_ref, hfov_ref, elements, stop, ttl = LENSES[where]
    fo = first_order(lens)
    assert abs(fo.efl - efl_ref) <= max(1e-3 * efl_ref, _printed(efl_ref))
    assert abs(fo.f_number - fno_ref) <= max(1e-3 * fno_ref, _printed(fno_ref))
    assert abs(lens.half_fov_deg - hfov_ref) <= _printed(hfov_ref) + 1e-9
    assert len(lens.elements()) == elements
    assert lens.stop_index + 1 == stop
    if ttl is not None:
        assert fo.ttl == pytest.approx(ttl, abs=_printed(ttl))


@pytest.mark.published
def test_e9_paraxial_efl_and_epd(e9_lens):
    """published: US-12210142-B2-e9 paraxial EFL 4.670371 (optiland) / 4.670368 (rayoptics) mm,
    EPD 2.395 mm."""
    fo = first_order(e9_lens)
    efl = sorted(E9["paraxial_efl_mm"].values())
    assert efl[0] - 5e-6 <= fo.efl <= efl[-1] + 5e-6
    assert fo.epd == pytest.approx(E9["epd_mm"], abs=5e-4)

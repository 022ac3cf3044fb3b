"""The spot diagram and focus (calibration.optics.spot).

Kinds, as marked on each test:

* property — the RMS radius about the centroid is the smallest over the
  references; plots; refocusing compensates a thickness error; the best
  focus of a perfect lens moved by +δ is −δ (a closed form);
* published — the on-axis RMS spot of the e9 phone lens against optiland
  0.6.3 and rayoptics 0.9.8 (``tests/data/reference/lens_figures.json``);
  it needs the shared data and skips with the reason otherwise.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.optics import paraxial
from calibration.optics import trace as tr
from calibration.optics.perturb import apply
from calibration.optics.spot import best_focus, refocus, spot, spot_diagram
from tests.helpers import one_surface, reference, small_lens

E9 = reference("lens_figures.json")["e9"]


@pytest.mark.property
def test_property_spot_rms_and_references():
    """property: rms_radius about the centroid is the smallest over
    references; the chief-ray reference includes the centroid offset
    (r_chief² = r_centroid² + |centroid − chief|²)."""
    lens = small_lens()
    sp = spot(lens, (0, 15), 4000, rng=np.random.default_rng(0))
    rc, rh = sp.rms_radius("centroid"), sp.rms_radius("chief")
    off = np.sum((sp.centroid - sp.chief) ** 2)
    assert rh >= rc
    assert math.isclose(rh ** 2, rc ** 2 + off, rel_tol=1e-9)
    assert 0 < sp.fraction_valid <= 1
    with pytest.raises(tr.TraceError, match="valid: 'centroid'"):
        sp.rms_radius("best")


@pytest.mark.property
def test_property_spot_diagram_plot(tmp_path):
    """property: the spot diagram plots one panel per field and saves."""
    import matplotlib

    matplotlib.use("Agg")
    lens = small_lens()
    spots = spot_diagram(lens, [(0, 0), (0, 10), (0, 20)], 500, (486.13, 587.56, 656.27))
    fig = tr_plot(spots)
    assert len(fig.axes) == 3
    fig.savefig(tmp_path / "spots.png")


def tr_plot(spots):
    from calibration.optics.spot import plot_spot_diagram

    return plot_spot_diagram(spots)


@pytest.mark.property
def test_analytic_best_focus_of_a_defocused_perfect_lens():
    """analytic: the Cartesian ellipsoid with its image plane moved by +δ has
    its best focus at −δ (the quadratic minimum is exact, 1e-9 mm)."""
    n, c, delta = 1.5, 0.2, 0.05
    lens = one_surface(c=c, k=-1 / n ** 2, n=n, t=n / ((n - 1) * c) + delta, epd=4.0)
    assert abs(best_focus(lens, n=2000) + delta) < 1e-9


@pytest.mark.property
def test_property_refocus_compensates_a_thickness_error():
    """property: refocus adds the last thickness as a compensator: the
    paraxial method shifts it by the change of the back focal length; the
    rms method brings the on-axis spot back near the nominal one."""
    lens = small_lens()
    lens = lens.with_surface(4, thickness=lens.surfaces[4].thickness + best_focus(lens))
    pl = apply(lens, {"s3.thickness": 0.02})
    rp = refocus(pl, "paraxial")
    name = f"s{len(lens.surfaces)}.thickness"
    shift = paraxial.first_order(pl.lens).bfl - paraxial.first_order(lens).bfl
    assert math.isclose(rp.perturbation.as_dict()[name], shift, rel_tol=1e-12)
    assert rp.perturbation.as_dict()["s3.thickness"] == 0.02
    r0 = spot(lens, (0, 0), 3000).rms_radius()
    r1 = spot(pl, (0, 0), 3000).rms_radius()
    r2 = spot(refocus(pl), (0, 0), 3000).rms_radius()
    assert r1 > 2 * r0 and r2 < 1.1 * r0
    with pytest.raises(tr.TraceError, match="valid: 'rms'"):
        refocus(pl, "magic")


@pytest.mark.published
def test_published_e9_on_axis_rms_spot(e9_lens):
    """published: ../shared/data/lenses/README.md, on-axis RMS spot radius of
    US-12210142-B2-e9 at 587.6 nm, centroid-referenced, ≥1e5 uniformly
    random pupil rays: 0.795 µm (optiland) / 0.799 µm (rayoptics). Within
    2 % of their mean 0.797 µm (Monte Carlo scatter with 2e5 rays ≈ 0.2 %)."""
    sp = spot(e9_lens, (0, 0), 200_000, 587.6, rng=np.random.default_rng(7))
    assert sp.fraction_valid == 1.0
    mean = np.mean([E9["on_axis_rms_spot_um"][tool] for tool in ("optiland", "rayoptics")])
    assert abs(sp.rms_radius() * 1e3 - mean) < 0.02 * mean

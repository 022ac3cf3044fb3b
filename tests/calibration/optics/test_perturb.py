"""Tests of calibration/optics/perturb.py: named perturbations, poses, the
parameter space, and their effect on traces.

Kind: property, of two sorts (named on each test):

* analytic — poses and indices against the formulas of the module
  docstring (paper eqs. 9–10, the Cauchy material model);
* property — invariants: zero perturbation is the nominal trace bit for
  bit; symmetric lenses image mirrored fields as mirror images and a
  tilt breaks that; a decentred element makes on-axis coma; a rigid
  rotation of the whole system rotates the trace; tilting by θ and back
  restores the nominal trace; vector ↔ names round trips; sampling stays
  within tolerance; errors name the bad parameter.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tests.helpers import small_lens

from calibration.optics import trace as tr
from calibration.optics.materials import LAMBDA_C, LAMBDA_D, LAMBDA_F, Material
from calibration.optics.perturb import (
    ParameterSpace,
    Perturbation,
    PerturbationError,
    Pose,
    apply,
    default_names,
    euler_rotation,
    parse_name,
    perturb_material,
)

pytestmark = pytest.mark.property

LAM = 587.5618


def trace_grid(lens, field=(0.0, 0.0), n=21, **kw):
    rays = tr.pupil_rays(lens, field, n, LAM, distribution="grid")
    return tr.trace_to_image(lens, rays, **kw)


# -- names, perturbations, space ------------------------------------------------

def test_property_parse_names_and_errors():
    """property: every documented form parses; a bad name lists the valid
    forms; duplicates and non-finite values are refused."""
    assert parse_name("s12.A20") == ("s", 12, "A20")
    assert parse_name("m3.vd") == ("m", 3, "vd")
    for bad in ("s3.radius", "e1.tilt", "x1.nd", "s0.conic", "s3.A0"):
        with pytest.raises(PerturbationError, match=r"s<i>\.curvature|start at 1|order"):
            parse_name(bad)
    with pytest.raises(PerturbationError, match="twice"):
        Perturbation(("s1.conic", "s1.conic"), (0.1, 0.2))
    with pytest.raises(PerturbationError, match="finite"):
        Perturbation(("s1.conic",), (math.nan,))
    with pytest.raises(PerturbationError, match="5 surfaces"):
        apply(small_lens(), {"s9.conic": 0.1})
    with pytest.raises(PerturbationError, match="2 elements"):
        apply(small_lens(), {"e3.decenter_x": 0.1})
    with pytest.raises(PerturbationError, match="2 solid media"):
        apply(small_lens(), {"m3.nd": 0.1})


def test_property_default_space_names_and_tolerances():
    """property: the default space of a 2-singlet lens perturbs both
    elements' surfaces, thicknesses (not the dummy stop gap nor the focus),
    decenters, x/y tilts and both media, with the documented tolerances."""
    lens = small_lens()
    names = default_names(lens)
    assert names == ["s2.curvature", "s2.conic", "s3.curvature", "s3.conic", "s4.curvature", "s4.conic",
                     "s5.curvature", "s5.conic", "s2.thickness", "s3.thickness", "s4.thickness",
                     "e1.decenter_x", "e1.decenter_y", "e1.tilt_zx", "e1.tilt_yz",
                     "e2.decenter_x", "e2.decenter_y", "e2.tilt_zx", "e2.tilt_yz",
                     "m1.nd", "m1.vd", "m2.nd", "m2.vd"]
    sp = ParameterSpace.default(lens)
    tol = dict(zip(sp.names, sp.tolerance))
    assert tol["s2.thickness"] == 0.005 and tol["e2.decenter_y"] == 0.002 and tol["e1.tilt_zx"] == 0.02
    assert tol["m1.nd"] == 0.001 and math.isclose(tol["m2.vd"], 0.008 * 23.5)
    # curvature: 2 fringes of power at 632.8 nm over the clear aperture; optionally ±0.5 %
    assert math.isclose(tol["s2.curvature"], 1 * 632.8e-6 / 1.0 ** 2)
    rel = ParameterSpace.default(lens, ["s2.curvature", "s5.curvature"], tolerances={"curvature_rel": 0.005})
    np.testing.assert_allclose(rel.tolerance, [max(0.005 * 0.5, 632.8e-6), max(0.005 * 0.25, 632.8e-6 / 1.69)])
    # conic: 0.5 µm of sag at the semi-diameter, at most ±1
    s = lens.surfaces[3]
    h = 1e-4
    dsag = (s.replace(conic=s.conic + h).sag(1.2) - s.replace(conic=s.conic - h).sag(1.2)) / (2 * h)
    assert math.isclose(tol["s4.conic"], min(0.3e-3 / abs(float(dsag)), 1.0), rel_tol=1e-6)
    np.testing.assert_array_equal(sp.upper, 2 * sp.tolerance)
    asph = default_names(lens, kinds=("asphere",))
    assert asph == ["s2.A4", "s4.A4", "s4.A6"]
    t = ParameterSpace.default(lens, asph).tolerance
    np.testing.assert_allclose(t, [0.3e-3 / 1.0 ** 4, 0.3e-3 / 1.2 ** 4, 0.3e-3 / 1.2 ** 6])
    with pytest.raises(PerturbationError, match="not in the space"):
        ParameterSpace.default(lens, ["s2.conic"], overrides={"s3.conic": 1.0})
    with pytest.raises(PerturbationError, match="valid"):
        default_names(lens, kinds=("wobble",))


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2 ** 32 - 1))
def test_property_vector_names_round_trip_and_sampling(seed):
    """property: vector → Perturbation → vector is the identity; samples lie
    within ± tolerance; nominal + delta = absolute."""
    sp = ParameterSpace.default(small_lens())
    rng = np.random.default_rng(seed)
    v = sp.sample(rng, 5)
    assert v.shape == (5, len(sp))
    assert np.all(np.abs(v) <= sp.tolerance)
    for row in v:
        p = sp.to_perturbation(row)
        assert p.names == sp.names
        np.testing.assert_array_equal(sp.to_vector(p), row)
        np.testing.assert_array_equal(sp.to_vector(p.as_dict()), row)
    np.testing.assert_array_equal(sp.absolute(v[0]), sp.nominal + v[0])
    assert np.all(sp.clip(10 * v[0]) <= sp.upper)


# -- poses and materials (analytic) ---------------------------------------------

def test_analytic_euler_rotation_is_eq9():
    """analytic: R = Rz(γ)·Rx(β)·Ry(α) with the matrices printed in eq. 9."""
    a, b, g = 0.3, -0.2, 0.1
    ra, rb, rg = (math.radians(t) for t in (a, b, g))
    rz = [[math.cos(rg), -math.sin(rg), 0], [math.sin(rg), math.cos(rg), 0], [0, 0, 1]]
    rx = [[1, 0, 0], [0, math.cos(rb), -math.sin(rb)], [0, math.sin(rb), math.cos(rb)]]
    ry = [[math.cos(ra), 0, -math.sin(ra)], [0, 1, 0], [math.sin(ra), 0, math.cos(ra)]]
    np.testing.assert_allclose(euler_rotation(a, b, g), np.array(rz) @ np.array(rx) @ np.array(ry), atol=1e-16)
    r = euler_rotation(a, b, g)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-15)


def test_analytic_poses_decenter_tilt_thickness():
    """analytic: thickness shifts every later vertex; decenter moves both
    surfaces of the element; tilt pivots about the element's first vertex
    (v_j = v_first + Rᵀ(0, 0, z_j − z_first)) and later elements keep the
    axis."""
    lens = small_lens()
    z = lens.vertex_z()
    pl = apply(lens, {"s2.thickness": 0.02, "e1.decenter_x": 0.003, "e1.decenter_y": -0.004,
                      "e1.tilt_yz": 0.1, "e2.decenter_y": 0.001})
    r = euler_rotation(0, 0.1, 0)
    v = [p.vertex for p in pl.poses]
    np.testing.assert_array_equal(v[0], [0, 0, 0])
    np.testing.assert_array_equal(v[1], [0.003, -0.004, z[1]])
    np.testing.assert_allclose(v[2], np.array([0.003, -0.004, z[1]]) + (z[2] + 0.02 - z[1]) * r.T @ [0, 0, 1],
                               atol=1e-15)
    assert pl.poses[1].rotation is pl.poses[2].rotation
    np.testing.assert_allclose(v[3], [0, 0.001, z[3] + 0.02], atol=1e-14)
    np.testing.assert_allclose(v[4], [0, 0.001, z[4] + 0.02], atol=1e-14)
    assert pl.poses[3].rotation is None
    np.testing.assert_allclose(pl.image_pose.vertex, [0, 0, z[5] + 0.02], atol=1e-14)
    assert math.isclose(pl.lens.surfaces[1].thickness, lens.surfaces[1].thickness + 0.02)
    t = apply(lens, {"e1.tilt_zx": 1.0, "e2.tilt_yz": 1.0})          # +α → +x, +β → +y
    assert t.poses[2].vertex[0] > 0 and t.poses[2].vertex[1] == 0
    assert t.poses[4].vertex[1] > 0 and t.poses[4].vertex[0] == 0
    p, d = pl.poses[2].to_local(np.array([[1.0, 2.0, 3.0]]), np.array([[0.0, 0.0, 1.0]]))
    q, e = pl.poses[2].to_global(p, d)
    np.testing.assert_allclose(q, [[1, 2, 3]], atol=1e-15)
    np.testing.assert_allclose(e, [[0, 0, 1]], atol=1e-15)


def test_analytic_shape_parameters():
    """analytic: curvature, conic and aspheric deltas add to the surface;
    a new aspheric order is inserted in order."""
    lens = small_lens()
    pl = apply(lens, {"s4.curvature": 0.01, "s4.conic": -0.2, "s4.A6": 1e-4, "s4.A10": 2e-6})
    s = pl.lens.surfaces[3]
    assert math.isclose(s.curvature, 0.31) and math.isclose(s.conic, -0.2)
    assert s.asphere == ((4, -0.02), (6, 0.003 + 1e-4), (10, 2e-6))


def test_analytic_material_perturbation():
    """analytic: m_j.nd shifts n(587.56) by Δ; m_j.vd sets (nd−1)/(nF−nC) to
    vd + Δ; a Sellmeier glass is shifted by Δnd + ΔB(1/λ² − 1/λd²) with the
    same result."""
    lens = small_lens()
    pl = apply(lens, {"m2.nd": 0.002, "m2.vd": -0.5})
    m = pl.lens.surfaces[3].material
    assert math.isclose(m.index(LAMBDA_D), 1.641, abs_tol=1e-12)
    assert math.isclose((m.index(LAMBDA_D) - 1) / (m.index(LAMBDA_F) - m.index(LAMBDA_C)), 23.0, rel_tol=1e-12)
    assert pl.lens.surfaces[1].material is lens.surfaces[1].material
    bk7 = Material("N-BK7", 1.5168, 64.17, "sellmeier",
                   (1.03961212, 0.00600069867, 0.231792344, 0.0200179144, 1.01046945, 103.560653))
    nd0 = bk7.index(LAMBDA_D)
    vd0 = (nd0 - 1) / (bk7.index(LAMBDA_F) - bk7.index(LAMBDA_C))
    p = perturb_material(bk7, 0.001, 0.7)
    assert math.isclose(p.index(LAMBDA_D), nd0 + 0.001, abs_tol=1e-13)
    assert math.isclose((p.index(LAMBDA_D) - 1) / (p.index(LAMBDA_F) - p.index(LAMBDA_C)), vd0 + 0.7, rel_tol=1e-11)
    assert not p.is_air
    with pytest.raises(PerturbationError, match="no dispersion"):
        perturb_material(Material("c", 1.5, math.inf, "constant"), 0.0, 1.0)


# -- traces (property) ----------------------------------------------------------------

def test_property_zero_perturbation_is_nominal_bit_for_bit():
    """property: the nominal lens, an empty perturbation and an all-zero
    vector over every parameter kind trace to identical bits."""
    lens = small_lens()
    sp = ParameterSpace.default(lens, default_names(lens, kinds=("curvature", "conic", "asphere", "thickness",
                                                                 "decenter", "tilt", "tilt_xy", "nd", "vd")))
    for field in ((0, 0), (3, 14)):
        rays = tr.pupil_rays(lens, field, 2000, LAM, rng=np.random.default_rng(0))
        a = tr.trace_to_image(lens, rays)
        for pl in (apply(lens), apply(lens, {}), sp.apply(np.zeros(len(sp)))):
            b = tr.trace_to_image(pl, rays)
            for x, y in ((a.position, b.position), (a.direction, b.direction), (a.opl, b.opl),
                         (a.valid, b.valid)):
                assert np.array_equal(x, y)
        # rays generated from the perturbed lens too
        rays2 = tr.pupil_rays(sp.apply(np.zeros(len(sp))), field, 2000, LAM, rng=np.random.default_rng(0))
        assert np.array_equal(rays.origin, rays2.origin) and np.array_equal(rays.opl, rays2.opl)


def test_property_decenter_makes_on_axis_coma():
    """property: decentring an element makes the on-axis spot asymmetric
    (centroid shift and a third moment along the decenter) where the
    nominal spot is centred and symmetric."""
    lens = small_lens()
    nom = trace_grid(lens, n=31)
    dec = trace_grid(apply(lens, {"e1.decenter_y": 0.01}), n=31)
    yn = nom.position[nom.valid, 1]
    yd = dec.position[dec.valid, 1]
    xd = dec.position[dec.valid, 0]
    assert abs(yn.mean()) < 1e-12
    assert abs(yd.mean()) > 1e-3                     # the spot moved (mm)
    skew_n = np.mean((yn - yn.mean()) ** 3)
    skew_d = np.mean((yd - yd.mean()) ** 3)
    assert abs(skew_d) > 1e3 * max(abs(skew_n), 1e-30)
    np.testing.assert_allclose(np.sort(xd), np.sort(-xd), atol=1e-12)  # still symmetric in x


def test_property_tilt_breaks_field_mirror_symmetry():
    """property: a tilted element (about x) breaks the ±y field mirror
    symmetry that the nominal lens has (test_trace checks the nominal)."""
    pl = apply(small_lens(), {"e2.tilt_yz": 0.2})
    pupil = tr.pupil_grid(15, "grid")
    a = tr.trace_to_image(pl, tr.pupil_rays(pl, (0, 12), pupil=pupil))
    b = tr.trace_to_image(pl, tr.pupil_rays(pl, (0, -12), pupil=pupil * [1, -1]))
    v = a.valid & b.valid
    err = np.abs(a.position[v] * [1, -1, 1] - b.position[v]).max()
    assert err > 1e-4


def test_property_tilt_then_untilt_restores_nominal():
    """property: tilting an element by θ about one axis and composing the
    pose with the tilt by −θ (a rotation that is the identity only up to
    rounding, so the general rotation code runs) restores the nominal trace
    to 1e-12 mm."""
    lens = small_lens()
    nom = trace_grid(lens, (1, 10))
    for name, axis in (("e1.tilt_zx", 0), ("e2.tilt_yz", 1), ("e2.tilt_xy", 2)):
        theta = 0.3
        pl = apply(lens, {name: theta})
        ang = [0.0, 0.0, 0.0]
        ang[axis] = -theta
        back = euler_rotation(*ang)
        first = lens.elements()[int(name[1]) - 1][0]
        pivot = pl.poses[first].vertex
        poses = []
        for p in pl.poses:
            if p.rotation is None:
                poses.append(p)
            else:
                rot = back @ p.rotation
                assert not np.array_equal(rot, np.eye(3)) or axis == 2
                e = p.rotation @ (p.vertex - pivot)          # (0, 0, z_j − z_first)
                poses.append(Pose(rot, pivot + rot.T @ e))
        undone = dataclasses.replace(pl, poses=tuple(poses))
        res = trace_grid(undone, (1, 10))
        assert np.array_equal(res.valid, nom.valid)
        np.testing.assert_allclose(res.position[nom.valid], nom.position[nom.valid], atol=1e-12, rtol=0)
        np.testing.assert_allclose(res.opl[nom.valid], nom.opl[nom.valid], atol=1e-12, rtol=0)


def test_property_rigid_rotation_of_the_whole_system():
    """property: rotating every surface, the image plane and the rays by
    the same R about the first vertex rotates the image points by R and
    leaves the OPL unchanged (1e-12): the pose algebra is a rigid motion."""
    lens = small_lens()
    r = euler_rotation(2.0, -1.5, 30.0)
    nom = tr.nominal(lens)
    poses = tuple(Pose(r, p.vertex @ r) for p in nom.poses)   # v' = Rᵀ v (row vectors: v @ R)
    image = Pose(r, nom.image_pose.vertex @ r)
    rotated = dataclasses.replace(nom, poses=poses, image_pose=image)
    rays = tr.pupil_rays(lens, (2, 8), 500, LAM, rng=np.random.default_rng(1))
    a = tr.trace_to_image(nom, rays, record=True)
    rays_r = tr.Rays(rays.origin @ r, rays.direction @ r, LAM, rays.opl)
    b = tr.trace_to_image(rotated, rays_r, record=True)
    np.testing.assert_allclose(b.surface_positions[:, a.valid], a.surface_positions[:, a.valid] @ r, atol=1e-12)
    assert np.array_equal(a.valid, b.valid)
    v = a.valid
    np.testing.assert_allclose(b.position[v], a.position[v] @ r, atol=1e-12)
    np.testing.assert_allclose(b.direction[v], a.direction[v] @ r, atol=1e-12)
    np.testing.assert_allclose(b.opl[v], a.opl[v], atol=1e-12)


def test_property_thickness_moves_focus_and_stop_keeps_size():
    """property: a thicker air gap moves the paraxial entrance pupil of a
    mid-stop lens but not the physical stop radius (the nominal's)."""
    lens = small_lens()
    s = list(lens.surfaces)
    s[0] = s[0].replace(stop=False, semi_diameter=None)
    s[2] = s[2].replace(stop=True)
    mid = lens.replace(surfaces=tuple(s))
    a = tr.stop_and_pupil(mid)
    b = tr.stop_and_pupil(apply(mid, {"s2.thickness": 0.05, "s2.curvature": 0.05}))
    assert b.stop_radius == a.stop_radius
    assert abs(b.z - a.z) > 1e-3 and abs(b.radius - a.radius) > 1e-4


def test_property_apply_refuses_a_perturbed_lens():
    """property: apply() takes the nominal lens (no silent double perturbation)."""
    pl = apply(small_lens(), {"s2.conic": 0.1})
    with pytest.raises(PerturbationError, match="nominal"):
        apply(pl, {"s2.conic": 0.1})


def test_property_default_space_sample_traces_cleanly():
    """property: Monte Carlo lenses drawn within the default tolerances
    trace without invalid rays on axis and stay near the nominal spot."""
    lens = small_lens()
    sp = ParameterSpace.default(lens)
    nom = trace_grid(lens, n=15)
    for v in sp.sample(np.random.default_rng(3), 4):
        res = trace_grid(sp.apply(v), n=15)
        assert res.valid.all()
        assert np.abs(res.position[:, :2] - nom.position[:, :2]).max() < 0.05

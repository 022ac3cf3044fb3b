"""Tests of calibration/optics/trace.py, the real-ray tracer.

Kinds, as marked on each test:

* property (analytic) — against closed forms (sphere intersection and refraction,
  Cartesian conics that focus perfectly, Snell's law) or an independent
  root finder (scipy's brentq) at 1e-12 mm;
* property — invariants (no NaN out, flags and reasons, symmetry, round
  trips between trace targets, aiming conventions);
* published — the vignetting of the e9 phone lens measured with optiland
  0.6.3 / rayoptics 0.9.8 (``tests/data/reference/lens_figures.json``):
  77 % / 46 % of the stop-filling rays pass at 0.7 / 1.0 field. It needs
  the shared data and skips with the reason otherwise.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from isp.runtime.executor import create_executor, shared_threads

from calibration.optics import trace as tr
from calibration.optics.lens import Lens, Surface
from calibration.optics.materials import Material
from calibration.optics.perturb import ParameterSpace
from calibration.optics.spot import best_focus, refocus, rms_radius, spot
from tests.helpers import one_surface, reference, small_lens

E9 = reference("lens_figures.json")["e9"]

GLASS = Material("1.5/60", 1.5, 60.0)
LAM = 587.5618


def collimated(heights_xy, z0=-1.0, direction=(0.0, 0.0, 1.0)):
    h = np.asarray(heights_xy, dtype=np.float64).reshape(-1, 2)
    o = np.column_stack([h, np.full(len(h), z0)])
    d = np.broadcast_to(np.asarray(direction, dtype=np.float64) / np.linalg.norm(direction), o.shape)
    return tr.Rays(o, d.copy(), LAM)


# -- analytic ----------------------------------------------------------------

@pytest.mark.property
def test_analytic_sphere_intersection_and_refraction():
    """analytic: sphere R = 10 mm into n = 1.5: hit point from the quadratic
    |o + s d − C|² = R², refracted direction from the unit-normal form of
    Snell's law; 1e-12."""
    rng = np.random.default_rng(1)
    m = 200
    h = rng.uniform(-4, 4, (m, 2))
    ang = rng.uniform(-0.2, 0.2, (m, 2))
    d = np.column_stack([np.tan(ang), np.ones(m)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.column_stack([h, np.full(m, -2.0)])
    lens = one_surface(c=0.1)
    res = tr.trace(lens, tr.Rays(o, d, LAM), to="exit")
    assert res.valid.all()
    R, n2 = 10.0, 1.5
    C = np.array([0.0, 0.0, R])
    b = np.einsum("ij,ij->i", d, o - C)
    cc = np.einsum("ij,ij->i", o - C, o - C) - R * R
    s = -b - np.sqrt(b * b - cc)
    p = o + s[:, None] * d
    np.testing.assert_allclose(res.position, p, atol=1e-12, rtol=0)
    nh = (C - p) / R
    cosi = np.einsum("ij,ij->i", d, nh)
    mu = 1.0 / n2
    cost = np.sqrt(1 - mu * mu * (1 - cosi ** 2))
    d2 = mu * d + (cost - mu * cosi)[:, None] * nh
    np.testing.assert_allclose(res.direction, d2, atol=1e-12, rtol=0)
    np.testing.assert_allclose(res.opl, np.full(m, 0.0) + s, atol=1e-12)


@pytest.mark.property
@pytest.mark.parametrize("newton", [False, True], ids=["closed_form", "newton"])
def test_analytic_cartesian_ellipsoid_focuses_perfectly(newton):
    """analytic: collimated light entering glass n through the ellipsoid
    k = −1/n² focuses at n/((n−1)c) without aberration (RMS < 1e-9 mm) and
    with equal optical paths (Fermat, 1e-12 mm). (A paraboloid, k = −1,
    does this only as a mirror; the refracting analogue is this Cartesian
    conic.) ``newton`` adds a negligible A20 term to force the iterative
    intersection."""
    n, c = 1.5, 0.2
    extra = ((20, 1e-30),) if newton else ()
    lens = one_surface(c=c, k=-1 / n ** 2, asphere=extra, n=n, t=n / ((n - 1) * c), epd=4.0)
    rays = tr.pupil_rays(lens, (0, 0), 5000, LAM, rng=np.random.default_rng(0))
    res = tr.trace_to_image(lens, rays)
    assert res.valid.all()
    assert rms_radius(res.position[:, :2], (0, 0)) < 1e-9
    assert np.ptp(res.opl) < 1e-12


@pytest.mark.property
def test_analytic_cartesian_hyperboloid_focuses_perfectly():
    """analytic: collimated light inside glass leaving through the
    hyperboloid k = −n² focuses at 1/((1−n)c) in air (RMS < 1e-9 mm)."""
    n, c = 1.6, -0.25
    glass = Material("g", n, math.inf, "constant")
    lens = Lens((Surface(0.0, thickness=3.0, material=glass, stop=True),
                 Surface(c, -n * n, (), 1 / ((1 - n) * c))), epd=3.0)
    res = tr.trace_to_image(lens, tr.pupil_rays(lens, (0, 0), 5000, LAM, rng=np.random.default_rng(0)))
    assert res.valid.all()
    assert rms_radius(res.position[:, :2], (0, 0)) < 1e-9


@pytest.mark.property
def test_analytic_paraboloid_sag_and_intersection():
    """analytic: k = −1 has sag cρ²/2; a ray parallel to the axis at height
    h hits it at z = c h²/2 (1e-14)."""
    c = 0.4
    lens = one_surface(c=c, k=-1.0)
    h = np.linspace(-3, 3, 13)
    res = tr.trace(lens, collimated(np.column_stack([h, 0 * h])), to="exit")
    np.testing.assert_allclose(res.position[:, 2], c * h * h / 2, atol=1e-14)


@pytest.mark.property
def test_analytic_asphere_sag_and_derivative():
    """analytic: the tracer's sag and g = (1/ρ) dsag/dρ (Horner in ρ², odd
    terms included) equal Surface.sag and a central finite difference of it."""
    s = Surface(0.3, -2.5, ((1, 0.001), (3, 0.002), (4, -0.01), (6, 0.004), (7, -1e-4), (8, -3e-4)))
    geo = tr._compile(tr.nominal(Lens((s.replace(thickness=5.0, stop=True),), epd=1.0)), LAM)[0]
    rho = np.linspace(0.05, 1.2, 50)
    sag, g = tr._sag_g(geo, rho * rho)
    np.testing.assert_allclose(sag, s.sag(rho), rtol=0, atol=1e-14)
    h = 1e-6
    fd = (s.sag(rho + h) - s.sag(rho - h)) / (2 * h)
    np.testing.assert_allclose(g * rho, fd, rtol=0, atol=1e-8)
    np.testing.assert_allclose(g * rho, s.sag_derivative(rho), rtol=0, atol=1e-13)


@pytest.mark.property
def test_analytic_asphere_intersection_vs_root_finder():
    """analytic: Newton–Raphson intersection with a strong asphere equals
    brentq's root of F(s) = z(s) − sag(ρ(s)) to 1e-12 mm."""
    s = Surface(0.35, -11.7, ((4, 0.0116), (6, -0.0145), (8, 0.0059), (10, 0.0049), (12, -0.0035)))
    lens = Lens((s.replace(thickness=5.0, material=GLASS, stop=True),), epd=2.0)
    rng = np.random.default_rng(3)
    m = 300
    o = np.column_stack([rng.uniform(-0.9, 0.9, (m, 2)), np.full(m, -1.0)])
    d = np.column_stack([rng.uniform(-0.2, 0.2, (m, 2)), np.ones(m)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    res = tr.trace(lens, tr.Rays(o, d, LAM), to="exit", clip=False)
    assert res.valid.all()
    for i in range(m):
        def f(t, o=o[i], d=d[i]):
            p = o + t * d
            return p[2] - float(s.sag(np.hypot(p[0], p[1])))
        t0 = -o[i, 2] / d[i, 2]
        t = brentq(f, t0 - 0.8, t0 + 0.8, xtol=1e-15, rtol=1e-15)
        np.testing.assert_allclose(res.position[i], o[i] + t * d[i], atol=1e-12, rtol=0)


@pytest.mark.property
def test_analytic_snell_vector_law():
    """analytic: n (D × N̂) = n' (D' × N̂) at every hit (paper eq. 7): the
    tangential component n sinθ is conserved and D, D', N̂ are coplanar."""
    s = Surface(0.3, -2.0, ((4, -0.02), (6, 0.005)), 5.0, Material("g", 1.7, math.inf, "constant"), stop=True)
    lens = Lens((s,), epd=2.0)
    rng = np.random.default_rng(5)
    m = 500
    o = np.column_stack([rng.uniform(-1.2, 1.2, (m, 2)), np.full(m, -1.0)])
    d = np.column_stack([rng.uniform(-0.4, 0.4, (m, 2)), np.ones(m)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    res = tr.trace(lens, tr.Rays(o, d, LAM), to="exit")
    assert res.valid.all()
    p, d2 = res.position, res.direction
    rho = np.hypot(p[:, 0], p[:, 1])
    slope = s.sag_derivative(rho) / rho
    nrm = np.column_stack([-slope * p[:, 0], -slope * p[:, 1], np.ones(m)])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    np.testing.assert_allclose(1.0 * np.cross(d, nrm), 1.7 * np.cross(d2, nrm), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(d2, axis=1), 1.0, atol=1e-14)
    sin_i = np.linalg.norm(np.cross(d, nrm), axis=1)
    sin_t = np.linalg.norm(np.cross(d2, nrm), axis=1)
    np.testing.assert_allclose(sin_i, 1.7 * sin_t, atol=1e-12)


# -- property: flags, reasons, no NaN -----------------------------------------

@pytest.mark.property
def test_property_tir_flagged():
    """property: rays meeting a glass–air surface beyond the critical angle
    are flagged TIR at that surface; the others pass."""
    glass = Material("g", 1.8, math.inf, "constant")
    lens = Lens((Surface(0.0, thickness=1.0, material=glass, stop=True),
                 Surface(0.5, thickness=3.0)), epd=3.0)
    res = tr.trace_to_image(lens, collimated([[0.0, 0.2], [0.0, 1.5], [1.5, 0.0]]))
    assert res.valid.tolist() == [True, False, False]
    assert res.status.tolist() == [tr.RayStatus.OK, tr.RayStatus.TIR, tr.RayStatus.TIR]
    assert res.surface.tolist() == [-1, 1, 1]


@pytest.mark.property
def test_property_vignetting_flagged():
    """property: rays beyond a semi-diameter are VIGNETTED at that surface;
    clip=False lets them through."""
    lens = Lens((Surface(0.0, thickness=1.0, material=GLASS, semi_diameter=2.0, stop=True),
                 Surface(-0.05, thickness=5.0, semi_diameter=1.0)), epd=2.0)
    rays = collimated([[0.0, 0.5], [0.0, 1.5], [0.0, 2.5]])
    res = tr.trace_to_image(lens, rays)
    assert res.status.tolist() == [0, tr.RayStatus.VIGNETTED, tr.RayStatus.VIGNETTED]
    assert res.surface.tolist() == [-1, 1, 0]
    assert tr.trace_to_image(lens, rays, clip=False).valid.all()


@pytest.mark.property
def test_property_no_nan_for_wild_rays():
    """property: rays that miss wildly (sideways, backwards, past a
    sphere's edge, outside a conic's domain, NaN input) come back invalid
    with finite placeholders, never NaN or inf, and no warning."""
    lens = Lens((Surface(0.5, 0.0, (), 2.0, GLASS, stop=True),
                 Surface(-0.5, 3.0, ((4, 0.1),), 5.0)), epd=1.0)
    o = np.array([[0.0, 0.0, -1.0],      # good
                  [1e3, 0.0, -1.0],      # far outside, parallel: misses the sphere
                  [0.0, 0.0, -1.0],      # sideways
                  [0.0, 0.0, -1.0],      # backwards
                  [np.nan, 0.0, -1.0],   # NaN
                  [0.0, 1.9, -1.0],      # beyond the sphere's radius (2 mm)
                  [0.0, 0.0, -1.0]])     # steep
    d = np.array([[0, 0, 1], [0, 0, 1], [1, 0, 0], [0, 0, -1], [0, 0, 1], [0, 0, 1],
                  [0, math.sin(1.5), math.cos(1.5)]], dtype=float)
    with np.errstate(all="raise"):
        for to in ("image", "exit"):
            res = tr.trace(lens, tr.Rays(o, d, LAM), to=to, record=True)
            for a in (res.position, res.direction, res.opl, res.surface_positions):
                assert np.all(np.isfinite(a))
            assert res.valid[0] and not res.valid[1:].any()
            assert res.status[4] == tr.RayStatus.INVALID_INPUT
            assert set(res.status[1:].tolist()) <= {1, 2, 3, 4, 5}
            assert np.array_equal(res.position[~res.valid], np.zeros((6, 3)))


@pytest.mark.property
def test_property_not_converged_flagged():
    """property: with max_iter=1 an asphere's rays are NOT_CONVERGED, and
    still finite."""
    lens = Lens((Surface(0.3, 0.0, ((4, 0.05),), 2.0, GLASS, stop=True),), epd=2.0)
    res = tr.trace_to_image(lens, collimated([[0.0, 0.9], [0.5, 0.5]]), max_iter=1)
    assert (res.status == tr.RayStatus.NOT_CONVERGED).all()
    assert np.all(np.isfinite(res.position))


@pytest.mark.property
def test_property_bad_input_refused():
    """property: wrong shapes, non-unit directions and bad wavelengths are
    errors at the boundary, naming the problem."""
    with pytest.raises(tr.TraceError, match="unit"):
        tr.Rays(np.zeros((2, 3)), np.ones((2, 3)), LAM)
    with pytest.raises(tr.TraceError, match=r"\(N, 3\)"):
        tr.Rays(np.zeros((2, 2)), np.ones((2, 2)), LAM)
    with pytest.raises(tr.TraceError, match="wavelength"):
        tr.Rays(np.zeros((1, 3)), np.array([[0, 0, 1.0]]), -5.0)
    with pytest.raises(tr.TraceError, match="valid: 'random'"):
        tr.pupil_grid(5, "spiral")
    with pytest.raises(tr.TraceError, match="valid: 'paraxial'"):
        tr.pupil_rays(small_lens(), (0, 0), 5, aiming="best")


@pytest.mark.property
def test_property_input_rays_not_modified():
    """property: tracing leaves the caller's arrays alone (also for N = 1)."""
    lens = small_lens()
    for n in (1, 50):
        rays = tr.pupil_rays(lens, (0, 5), n, distribution="random")
        o, d, opl = rays.origin.copy(), rays.direction.copy(), rays.opl.copy()
        tr.trace_to_image(lens, rays, chunk=7)
        assert np.array_equal(o, rays.origin) and np.array_equal(d, rays.direction)
        assert np.array_equal(opl, rays.opl)


@pytest.mark.property
def test_property_chunks_and_threads_do_not_change_results():
    """property: chunk size and thread count change nothing (bit for bit)."""
    lens = small_lens()
    rays = tr.pupil_rays(lens, (0, 15), 3000, rng=np.random.default_rng(2))
    a = tr.trace_to_image(lens, rays, chunk=100000, executor=create_executor("serial"))
    b = tr.trace_to_image(lens, rays, chunk=257, executor=shared_threads(2))
    for x, y in ((a.position, b.position), (a.direction, b.direction), (a.opl, b.opl), (a.status, b.status)):
        assert np.array_equal(x, y)


@pytest.mark.property
def test_property_trace_targets_agree():
    """property: trace_to_plane on the image plane = trace_to_image; the
    exit data continued by hand reaches the same points; the record holds
    every surface's hit."""
    lens = small_lens()
    rays = tr.pupil_rays(lens, (2, 10), 500, rng=np.random.default_rng(4))
    img = tr.trace_to_image(lens, rays, record=True)
    z_img = lens.vertex_z()[-1]
    pl = tr.trace_to_plane(lens, rays, (0, 0, z_img), (0, 0, 1))
    v = img.valid
    assert np.array_equal(v, pl.valid)
    np.testing.assert_allclose(pl.position[v], img.position[v], atol=1e-12)
    np.testing.assert_allclose(pl.opl[v], img.opl[v], atol=1e-12)
    ex = tr.trace_to_exit(lens, rays)
    np.testing.assert_allclose(ex.position[v], img.surface_positions[-2][v], atol=1e-13)
    assert img.surface_positions.shape == (len(lens.surfaces) + 1, len(rays), 3)
    np.testing.assert_allclose(img.surface_positions[-1][v], img.position[v], atol=1e-13)


@pytest.mark.property
def test_property_plane_wavefront_reference():
    """property: for an object at infinity the input OPL puts every ray on
    the plane wavefront through the entrance pupil centre."""
    lens = small_lens()
    rays = tr.pupil_rays(lens, (3, 12), 200, rng=np.random.default_rng(0))
    pp = tr.stop_and_pupil(lens)
    d = rays.direction[0]
    along = (rays.origin - [0, 0, pp.z]) @ d
    np.testing.assert_allclose(rays.opl, along, atol=1e-13)


@pytest.mark.property
def test_property_pupil_samplings():
    """property: the three pupil samplings lie in the unit disc with the
    documented counts; random is uniform in area (mean r² = 1/2)."""
    g = tr.pupil_grid(10, "grid")
    h = tr.pupil_grid(4, "hexapolar")
    r = tr.pupil_grid(20000, "random", np.random.default_rng(0))
    for p in (g, h, r):
        assert np.all(np.hypot(*p.T) <= 1 + 1e-15)
    assert len(h) == 1 + 3 * 4 * 5
    assert abs(np.mean(np.sum(r * r, axis=1)) - 0.5) < 0.01
    np.testing.assert_allclose(g.mean(axis=0), 0, atol=1e-15)


@pytest.mark.property
def test_property_real_aiming_fills_the_stop():
    """property: with real aiming the chief ray crosses the stop centre and
    pupil point p lands at r_stop·p on the stop (1e-9 mm), also off axis;
    paraxial aiming of the same rays misses those points."""
    lens = small_lens()
    # stop in the middle of the lens: surfaces before it matter
    s = list(lens.surfaces)
    s[0] = s[0].replace(stop=False, semi_diameter=None)
    s[2] = s[2].replace(stop=True)
    mid = lens.replace(surfaces=tuple(s), epd=1.0)
    pp = tr.stop_and_pupil(mid)
    pupil = np.array([[0, 0], [0, 1], [0, -1], [1, 0], [0.3, -0.4]], dtype=float)
    for aiming, tol in (("real", 1e-9), ("paraxial", None)):
        rays = tr.pupil_rays(mid, (0, 18), pupil=pupil, aiming=aiming)
        res = tr.trace_to_image(mid, rays, record=True, clip=False)
        hit = res.surface_positions[2][:, :2]
        err = np.abs(hit - pp.stop_radius * pupil).max()
        if tol:
            assert err < tol
        else:
            assert err > 1e-4


@pytest.mark.property
def test_property_nominal_spots_mirror_in_y():
    """property: a coaxial lens images field −θ as the mirror image of +θ,
    ray for ray (pupil grid mirrored in y), to 1e-12 mm."""
    lens = small_lens()
    pupil = tr.pupil_grid(15, "grid")
    a = tr.trace_to_image(lens, tr.pupil_rays(lens, (0, 12), pupil=pupil))
    b = tr.trace_to_image(lens, tr.pupil_rays(lens, (0, -12), pupil=pupil * [1, -1]))
    assert np.array_equal(a.valid, b.valid)
    np.testing.assert_allclose(a.position[a.valid] * [1, -1, 1], b.position[b.valid], atol=1e-12)


@pytest.mark.property
def test_property_finite_object():
    """property: a finite object sends every ray from one point (chief ray
    toward the entrance pupil centre at the field angle), with OPL 0 at the
    object; the spot of a near object focuses behind the infinity focus."""
    lens = small_lens().replace(object_distance=50.0)
    pp = tr.stop_and_pupil(lens)
    rays = tr.pupil_rays(lens, (0, 5), pupil=np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 0.0]]))
    assert np.allclose(rays.origin, rays.origin[0]) and rays.origin[0, 2] == -50.0
    assert rays.opl.tolist() == [0.0, 0.0, 0.0]
    t = (pp.z - rays.origin[:, 2]) / rays.direction[:, 2]
    at_ep = rays.origin + t[:, None] * rays.direction
    np.testing.assert_allclose(at_ep[:, :2], [[0, 0], [0, pp.radius], [pp.radius, 0]], atol=1e-12)
    chief = rays.direction[0]
    assert math.isclose(math.degrees(math.atan2(chief[1], chief[2])), 5.0, rel_tol=1e-12)
    assert best_focus(lens) > best_focus(small_lens()) + 1e-3


# -- the e9 phone lens -----------------------------------------------------------------

@pytest.mark.property
@pytest.mark.slow
def test_property_e9_monte_carlo_lenses_trace_cleanly(e9_lens):
    """property (slow): 20 e9 lenses drawn within the default tolerances
    trace with every on-axis ray valid and only vignetting at full field;
    refocused, their on-axis spot stays below 25 µm RMS."""
    sp = ParameterSpace.default(e9_lens)
    for v in sp.sample(np.random.default_rng(5), 20):
        pl = refocus(sp.apply(v))
        on = spot(pl, (0, 0), 5000, 587.6)
        assert on.fraction_valid == 1.0 and on.rms_radius() < 0.025
        full = tr.trace_to_image(pl, tr.pupil_rays(pl, (0, e9_lens.half_fov_deg), 5000, 587.6))
        assert set(np.unique(full.status).tolist()) <= {0, tr.RayStatus.VIGNETTED}


@pytest.mark.published
@pytest.mark.parametrize("frac,expected", [(v["field"], v["fraction"]) for v in E9["vignetting_pass_fraction"]])
def test_published_e9_vignetting(e9_lens, frac, expected):
    """published: README, "about 77 % of the stop-filling rays pass at 0.7
    field and 46 % at full field" with the file's semi-diameters. Real ray
    aiming (rays filling the stop) within ±2 percentage points: the figure
    is printed to 2 digits (±0.5), Monte Carlo scatter is ±0.2 at 1e5 rays,
    and the aiming/pupil convention of the reference is not stated. (We
    measure 77.5 % / 47.2 %; paraxial aiming gives 78.4 % / 48.5 %.)"""
    rays = tr.pupil_rays(e9_lens, (0, frac * e9_lens.half_fov_deg), 100_000, 587.6, aiming="real",
                         rng=np.random.default_rng(11))
    res = tr.trace_to_image(e9_lens, rays)
    assert abs(res.fraction_valid - expected) <= 0.02
    assert set(np.unique(res.status).tolist()) <= {0, tr.RayStatus.VIGNETTED}

"""Adobe's render curves (modules.common.dng_tone).

Kinds: published (the ACR3 default tone curve's table as the DNG SDK 1.7.1
states it in ``dng_render.cpp``, spot values at its printed five decimals;
the exposure ramp and tone's closed forms as ``dng_render.cpp`` defines
them) and property (continuity of the ramp's toe and of the exposure tone,
the natural spline's end conditions, the hue-preserving RGB tone against a
per-pixel transcription of the SDK's seven cases, table accuracy).
"""

from __future__ import annotations

import colorsys

import numpy as np
import pytest

from modules.common.dng_tone import (ACR3_DEFAULT_TONE_CURVE, acr3_default_tone_curve, apply_lut16,
                                     exposure_ramp, exposure_ramp_levels, exposure_tone, lut16,
                                     natural_spline, rgb_tone, rgb_tone_planes, table_lookup, tabulate)


# --------------------------------------------------------------------------
# published: the SDK's definitions

@pytest.mark.published
def test_acr3_table_spot_values():
    """``dng_tone_curve_acr3_default`` (DNG SDK 1.7.1, dng_render.cpp): 1025
    entries from 0 to 1; entries 1, 256, 512, 768 as printed there."""
    t = ACR3_DEFAULT_TONE_CURVE
    assert t.shape == (1025,) and t[0] == 0.0 and t[-1] == 1.0
    assert t[1] == pytest.approx(0.00078, abs=5e-6)
    assert t[256] == pytest.approx(0.52069, abs=5e-6)
    assert t[512] == pytest.approx(0.80486, abs=5e-6)
    assert t[768] == pytest.approx(0.93986, abs=5e-6)
    assert np.all(np.diff(t) > 0)


@pytest.mark.published
def test_acr3_interpolates_linearly_between_entries():
    x = (256 + 0.25) / 1024
    expected = 0.75 * ACR3_DEFAULT_TONE_CURVE[256] + 0.25 * ACR3_DEFAULT_TONE_CURVE[257]
    assert acr3_default_tone_curve(x) == pytest.approx(expected, abs=1e-12)
    assert acr3_default_tone_curve([-1.0, 2.0]).tolist() == [0.0, 1.0]


@pytest.mark.published
def test_ramp_levels_as_the_sdk_computes_them():
    """white = 2^−max(0, E); black = shadows · ShadowScale · 0.001, at most
    0.99 · white (dng_render_task::Start)."""
    assert exposure_ramp_levels(0.0) == (1.0, 0.005)
    assert exposure_ramp_levels(2.0) == (0.25, 0.005)
    assert exposure_ramp_levels(-1.0) == (1.0, 0.005)        # negative E: the tone darkens instead
    assert exposure_ramp_levels(0.0, shadows=0.0) == (1.0, 0.0)
    assert exposure_ramp_levels(0.0, shadows=5, shadow_scale=2.0) == (1.0, 0.01)
    w, b = exposure_ramp_levels(8.0, shadows=100)
    assert b == pytest.approx(0.99 * w)


@pytest.mark.published
def test_exposure_ramp_closed_form():
    """Linear (x − black)/(white − black) above the toe, 0 below it, the
    quadratic s (x − black + r)² / (4 r) inside, r = min(black/2, (white − black)/16)."""
    white, black = 1.0, 0.005
    s, r = 1 / (white - black), 0.0025
    x = np.array([0.0, black - r, black, black + r, 0.5, 1.0, 1.5])
    y = exposure_ramp(x, white, black)
    expected = [0.0, 0.0, s * r * r / (4 * r), r * s, (0.5 - black) * s, 1.0, 1.0]
    np.testing.assert_allclose(y, expected, rtol=1e-12, atol=1e-15)


# --------------------------------------------------------------------------
# properties

@pytest.mark.property
@pytest.mark.parametrize("white,black", [(1.0, 0.005), (0.25, 0.005), (1.0, 0.05), (1.0, 0.0)])
def test_ramp_toe_is_continuous_in_value_and_slope(white, black):
    x = np.linspace(0, 0.99 * white, 200001)     # below the clip at white (a kink by design)
    y = exposure_ramp(x, white, black)
    assert np.all(np.diff(y) >= 0)
    dy = np.diff(y) / np.diff(x)
    assert np.abs(np.diff(dy)).max() < 1e-2 * dy.max()       # no kink (a C¹ toe)


@pytest.mark.property
def test_exposure_tone_is_identity_for_positive_exposure_and_c1_otherwise():
    x = np.linspace(0, 1, 4001)
    np.testing.assert_array_equal(exposure_tone(x, 0.5), x)
    y = exposure_tone(x, -1.5)
    assert y[-1] == pytest.approx(1.0) and np.all(np.diff(y) > 0)
    k = 2 ** -1.5
    np.testing.assert_allclose(y[x <= 0.25], x[x <= 0.25] * k)
    dy = np.gradient(y, x)
    i = np.searchsorted(x, 0.25)
    assert dy[i + 2] == pytest.approx(k, rel=1e-2)           # slope continues past the crossover


@pytest.mark.property
def test_natural_spline_interpolates_with_zero_end_curvature():
    pts = np.array([[0, 0], [0.1, 0.05], [0.3, 0.35], [0.6, 0.75], [1, 1]])
    f = natural_spline(pts)
    np.testing.assert_allclose(f(pts[:, 0]), pts[:, 1], atol=1e-12)
    h = 1e-5
    for x0 in (h, 1 - h):
        second = (f(x0 + h) - 2 * f(x0) + f(x0 - h)) / h ** 2
        assert abs(second) < 1e-2
    # C²: second differences agree either side of an interior knot
    for xk in (0.1, 0.3, 0.6):
        left = (f(xk) - 2 * f(xk - h) + f(xk - 2 * h)) / h ** 2
        right = (f(xk + 2 * h) - 2 * f(xk + h) + f(xk)) / h ** 2
        assert left == pytest.approx(right, abs=0.05)
    assert f(np.array([-0.5, 1.5])).tolist() == [0.0, 1.0]
    # the same curve as scipy's natural cubic spline, an independent implementation
    from scipy.interpolate import CubicSpline

    x = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(f(x), CubicSpline(pts[:, 0], pts[:, 1], bc_type="natural")(x), atol=1e-12)


@pytest.mark.property
@pytest.mark.parametrize("pts", [[(0, 0)], [(0, 0), (0.5, 0.6), (0.4, 0.7), (1, 1)], [(0, 0), (1, 1.5)]])
def test_natural_spline_refuses_invalid_curves(pts):
    with pytest.raises(ValueError):
        natural_spline(pts)


@pytest.mark.property
def test_tables_follow_the_function():
    table = tabulate(acr3_default_tone_curve)
    x = np.linspace(0, 1, 100001)
    assert np.abs(table_lookup(table, x) - acr3_default_tone_curve(x)).max() < 1e-4
    lut = lut16(lambda v: table_lookup(table, v))
    assert np.abs(apply_lut16(x.astype(np.float32), lut) - table_lookup(table, x)).max() < 2e-4


def _rgb_tone_reference(rgb, curve):
    """RefBaselineRGBTone transcribed pixel by pixel: the seven orderings of
    R, G, B, the curve on the largest and smallest, the middle one placed
    in proportion."""
    out = np.empty_like(rgb)
    for i, (r, g, b) in enumerate(rgb):
        def tone(hi, mid, lo):
            t_hi, t_lo = curve(hi), curve(lo)
            return t_hi, t_lo + (t_hi - t_lo) * (mid - lo) / (hi - lo), t_lo
        if r >= g:
            if g > b:
                rr, gg, bb = tone(r, g, b)
            elif b > r:
                bb, rr, gg = tone(b, r, g)
            elif b > g:
                rr, bb, gg = tone(r, b, g)
            else:
                rr, gg = curve(r), curve(g)
                bb = gg
        else:
            if r >= b:
                gg, rr, bb = tone(g, r, b)
            elif b > g:
                bb, gg, rr = tone(b, g, r)
            else:
                gg, bb, rr = tone(g, b, r)
        out[i] = rr, gg, bb
    return out


@pytest.mark.property
def test_rgb_tone_matches_the_sdk_case_analysis_and_keeps_hue():
    rng = np.random.default_rng(0)
    rgb = rng.uniform(0, 1, (2000, 3)).astype(np.float32)
    rgb[:50] = rgb[:50, :1]                      # greys
    rgb[50:100, 1] = rgb[50:100, 2]              # two channels equal
    lut = lut16(acr3_default_tone_curve)

    def curve(v):
        return float(apply_lut16(np.float32(v), lut))

    ours = rgb_tone(rgb, lut)
    np.testing.assert_allclose(ours, _rgb_tone_reference(rgb.astype(np.float64), curve), atol=2e-6)
    chromatic = np.ptp(rgb, axis=1) > 0.05
    h_in = np.array([colorsys.rgb_to_hsv(*p)[0] for p in rgb[chromatic]])
    h_out = np.array([colorsys.rgb_to_hsv(*p)[0] for p in ours[chromatic]])
    d = np.abs(h_in - h_out)
    assert np.minimum(d, 1 - d).max() < 1e-4
    planes = rgb_tone_planes(*(np.ascontiguousarray(rgb[:, c]) for c in range(3)), lut)
    np.testing.assert_array_equal(np.stack(planes, axis=1), ours)

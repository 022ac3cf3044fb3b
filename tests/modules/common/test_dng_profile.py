"""Camera-profile tables (modules.common.dng_profile).

Kinds: property. HSV as the DNG SDK defines it against Python's
``colorsys`` (hue scaled to [0, 6)); the tag layouts (zero-saturation column
present or omitted, its value scale forced to 1); what a table does to a
colour (identity, a uniform hue shift, saturation and value scales, hue
wrapping between the last division and the first, the sRGB value
encoding); the interpolation of two tables by the white's temperature.
Agreement with Adobe's renderer on whole images is in
``tests/modules/test_dng_render.py`` (``dng_validate`` on DNGs with these
tables).
"""

from __future__ import annotations

import colorsys

import numpy as np
import pytest

from isp.meta import CameraMeta
from modules.common.dng_colour import xy_to_cct
from modules.common.dng_profile import (HueSatMap, apply_hue_sat_map, hsv_to_rgb, hue_sat_map_for_white,
                                        look_table, rgb_to_hsv)

pytestmark = pytest.mark.property


def _uniform(hues=6, sats=3, vals=1, shift=0.0, sat=1.0, val=1.0) -> HueSatMap:
    d = np.empty((vals, hues, sats, 3), np.float32)
    d[...] = (shift, sat, val)
    return HueSatMap(d)


def _colours(n=500, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.02, 1.0, (n, 3)).astype(np.float32)


def test_hsv_matches_colorsys():
    rgb = _colours()
    h, s, v = rgb_to_hsv(rgb)
    ref = np.array([colorsys.rgb_to_hsv(*p) for p in rgb.astype(np.float64)])
    np.testing.assert_allclose(h / 6.0, ref[:, 0], atol=1e-5)
    np.testing.assert_allclose(s, ref[:, 1], atol=1e-6)
    np.testing.assert_allclose(v, ref[:, 2], atol=1e-7)
    np.testing.assert_allclose(hsv_to_rgb(h, s, v), rgb, atol=2e-6)
    grey = rgb_to_hsv(np.full((2, 3), 0.3, np.float32))
    assert grey[0].tolist() == [0.0, 0.0] and grey[1].tolist() == [0.0, 0.0]


def test_from_tag_with_and_without_the_zero_saturation_column():
    full = HueSatMap.from_tag((2, 2, 1), [1, 2, 7, 3, 4, 5, 6, 7, 8, 9, 10, 11])
    assert full.deltas[0, 0, 0].tolist() == [1, 2, 1]          # value scale at s = 0 forced to 1
    assert full.deltas[0, 1, 1].tolist() == [9, 10, 11]
    short = HueSatMap.from_tag((2, 2, 1), [3, 4, 5, 9, 10, 11])
    assert short.deltas[0, 0, 0].tolist() == [3, 4, 1]         # copied from s = 1, value scale 1
    assert short.divisions == (2, 2, 1)
    with pytest.raises(ValueError):
        HueSatMap.from_tag((2, 2, 1), [1, 2, 3])


def test_identity_table_changes_nothing():
    rgb = _colours()
    for vals, encoding, tol in ((1, 0, 2e-6), (4, 0, 2e-6), (4, 1, 2e-3)):
        np.testing.assert_allclose(apply_hue_sat_map(rgb, _uniform(vals=vals), encoding), rgb, atol=tol)


def test_uniform_modifiers_shift_hue_and_scale_saturation_and_value():
    rgb = _colours()
    h, s, v = rgb_to_hsv(rgb)
    out = apply_hue_sat_map(rgb, _uniform(shift=30.0, sat=0.5, val=0.8))
    h2, s2, v2 = rgb_to_hsv(out)
    dh = (h2 - h) % 6.0
    np.testing.assert_allclose(dh, 0.5, atol=1e-4)              # 30° = 0.5 of the SDK's 6
    np.testing.assert_allclose(s2, 0.5 * s, atol=1e-5)
    np.testing.assert_allclose(v2, 0.8 * v, atol=1e-6)
    sat_up = apply_hue_sat_map(rgb, _uniform(sat=10.0))
    assert rgb_to_hsv(sat_up)[1].max() <= 1.0                   # saturation capped at 1


def test_hue_interpolation_wraps_from_the_last_division_to_the_first():
    d = np.zeros((1, 4, 2, 3), np.float32)
    d[..., 1:] = 1.0
    d[0, 3, :, 0] = 40.0                                        # shift at hue 270°
    table = HueSatMap(d)
    # hue 315°: halfway between division 3 (270°, +40°) and division 0 (0°, 0°)
    rgb = hsv_to_rgb(np.float32(315 / 60), np.float32(0.8), np.float32(0.6))
    out = apply_hue_sat_map(rgb[None], table)
    h = rgb_to_hsv(out)[0][0] * 60.0
    assert h == pytest.approx(335.0, abs=0.05)


def test_srgb_value_encoding_of_a_3d_table():
    """Value scale 0.5 on the sRGB-encoded value axis: the linear value
    becomes decode(0.5 · encode(v))."""
    from modules.gamma import srgb_eotf, srgb_oetf

    rgb = _colours()
    v = rgb_to_hsv(rgb)[2]
    out = apply_hue_sat_map(rgb, _uniform(vals=3, val=0.5), encoding=1)
    np.testing.assert_allclose(rgb_to_hsv(out)[2], srgb_eotf(0.5 * srgb_oetf(v)), atol=5e-4)
    two_d = apply_hue_sat_map(rgb, _uniform(vals=1, val=1.0), encoding=1)
    # the SDK decodes a 2.5-D table's value without having encoded it
    np.testing.assert_allclose(rgb_to_hsv(two_d)[2], srgb_eotf(v), atol=5e-4)


def test_two_tables_interpolated_by_the_white_temperature():
    t1 = np.tile(np.array([10.0, 1.0, 1.0], np.float32), (1, 2, 2, 1)).ravel()
    t2 = np.tile(np.array([30.0, 1.0, 1.0], np.float32), (1, 2, 2, 1)).ravel()
    meta = CameraMeta(calibration_illuminant_1=17, calibration_illuminant_2=21,
                      profile_hue_sat_map_dims=(2, 2, 1), profile_hue_sat_map_data_1=t1,
                      profile_hue_sat_map_data_2=t2)
    white = (0.3806, 0.3768)                                    # ≈ 4000 K
    table, note = hue_sat_map_for_white(meta, white)
    g = (1 / xy_to_cct(white) - 1 / 6500) / (1 / 2850 - 1 / 6500)
    assert table.deltas[0, 0, 0, 0] == pytest.approx(10 * g + 30 * (1 - g), abs=1e-4)
    assert "weight" in note
    a, _ = hue_sat_map_for_white(meta, (0.4862, 0.4147))       # ≈ 2400 K, below A: table 1 alone
    assert a.deltas[0, 0, 0, 0] == pytest.approx(10.0)
    only2 = meta.replace(profile_hue_sat_map_data_1=None)
    assert hue_sat_map_for_white(only2, white) == (None, "")    # the SDK ignores a lone table 2
    assert look_table(meta) is None

"""The DNG colour model (modules.common.dng_colour).

Kinds, as marked on each test:

* published — values printed in a standard, a paper or the DNG SDK source,
  at the precision they are printed with (tables in ``tests/data/reference``),
  and agreement with colour-hdri (``colour_hdri.models.dng``), an
  independent implementation of DNG spec chapter 6, given the same tags and
  the same calibration CCTs. colour-hdri is a test-only dependency. It
  omits two SDK normalisations that this module performs
  (NormalizeColorMatrix / NormalizeForwardMatrix, and the "neutral → Y = 1"
  scale of the ColorMatrix path); the tests feed it the normalised matrices
  and compare the ColorMatrix path up to that one scalar, saying so where
  they do;
* property — invariants (neutral stays neutral, weight limits, numpy/torch
  parity, validation).

Files come from ``<repo>/../shared/data/raw``; tests that need them skip with
the reason when the folder is absent.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from isp.meta import CameraMeta
from modules.common.dng_colour import (
    bradford_matrix,
    camera_neutral_to_xy,
    camera_to_linear_srgb,
    camera_to_xyz_d50,
    illuminant_to_cct,
    interpolation_weight,
    matrix_xyz_d50_to_linear_srgb,
    normalize_color_matrix,
    normalize_forward_matrix,
    xy_to_camera_neutral,
    xy_to_cct,
)
from tests.helpers import DUAL_ILLUMINANT_DNGS, canon_meta, dng_colour_meta, reference

CANON = reference("colour_hdri_canon_eos_5d_mark_ii.json")
CANON_CM_D65 = np.array(CANON["color_matrix_2"])
CANON_FM = np.array(CANON["forward_matrix"])
CANON_NEUTRAL = tuple(CANON["as_shot_neutral"])
DNG = reference("dng_illuminant_cct.json")
CIE = {v["name"]: v for v in reference("cie_15_2004.json")["illuminants"]}
LINDBLOOM = reference("lindbloom.json")


def hdri_args(meta: CameraMeta):
    """colour-hdri's arguments for ``meta``: calibrations ordered by CCT (its
    interpolation assumes CCT_1 < CCT_2, the SDK swaps likewise), matrices
    normalised as the SDK does."""
    eye = np.eye(3)
    cals = []
    for i in (1, 2):
        cm = getattr(meta, f"color_matrix_{i}")
        if cm is None:
            continue
        cc = getattr(meta, f"camera_calibration_{i}")
        fm = getattr(meta, f"forward_matrix_{i}")
        cals.append((illuminant_to_cct(getattr(meta, f"calibration_illuminant_{i}")),
                     normalize_color_matrix(cm), eye if cc is None else cc,
                     eye if fm is None else normalize_forward_matrix(fm)))
    cals.sort(key=lambda c: c[0])
    (t1, cm1, cc1, fm1), (t2, cm2, cc2, fm2) = cals
    ab = np.ones(3) if meta.analog_balance is None else np.asarray(meta.analog_balance)
    return dict(CCT_calibration_illuminant_1=t1, CCT_calibration_illuminant_2=t2,
                M_color_matrix_1=cm1, M_color_matrix_2=cm2,
                M_camera_calibration_1=cc1, M_camera_calibration_2=cc2,
                analog_balance=ab), (fm1, fm2)


# --------------------------------------------------------------------------
# oracle: colour-hdri

@pytest.mark.published
@pytest.mark.parametrize("name", DUAL_ILLUMINANT_DNGS)
def test_oracle_neutral_to_xy_matches_colour_hdri(name):
    """oracle: white xy from AsShotNeutral, ≤ 1e-4 (measured ≤ 1e-9)."""
    colour_hdri = pytest.importorskip("colour_hdri")
    meta = dng_colour_meta(name)
    args, _ = hdri_args(meta)
    expected = colour_hdri.camera_neutral_to_xy(np.asarray(meta.as_shot_neutral), **args)
    got = camera_neutral_to_xy(meta, meta.as_shot_neutral)
    np.testing.assert_allclose(got, expected, atol=1e-4, rtol=0)


@pytest.mark.published
@pytest.mark.parametrize("name", DUAL_ILLUMINANT_DNGS)
def test_oracle_camera_to_xyz_d50_forward_matrix_matches_colour_hdri(name):
    """oracle (the acceptance test): CameraToXYZ_D50 by the ForwardMatrix
    path, per element ≤ 1e-3 (measured ≤ 2e-8), colour-hdri given the
    normalised forward matrices and its own xy for the same neutral."""
    colour_hdri = pytest.importorskip("colour_hdri")
    meta = dng_colour_meta(name)
    args, (fm1, fm2) = hdri_args(meta)
    xy = colour_hdri.camera_neutral_to_xy(np.asarray(meta.as_shot_neutral), **args)
    expected = colour_hdri.matrix_camera_space_to_XYZ(
        xy, **args, M_forward_matrix_1=fm1, M_forward_matrix_2=fm2,
        chromatic_adaptation_transform="Bradford")
    got, notes = camera_to_xyz_d50(meta)
    assert notes[0].startswith("ForwardMatrix")
    np.testing.assert_allclose(got, expected, atol=1e-3, rtol=0)
    np.testing.assert_allclose(got, expected, atol=1e-6, rtol=0)  # regression guard


@pytest.mark.published
@pytest.mark.parametrize("name", DUAL_ILLUMINANT_DNGS)
def test_oracle_camera_to_xyz_d50_color_matrix_matches_colour_hdri(name):
    """oracle: CameraToXYZ_D50 by the ColorMatrix path (inverse + Bradford),
    ≤ 1e-6 after colour-hdri's matrix is given the SDK's scale (camera
    neutral with maximum 1 → Y = 1), which colour-hdri leaves out."""
    colour_hdri = pytest.importorskip("colour_hdri")
    meta = dng_colour_meta(name)
    args, _ = hdri_args(meta)
    xy = colour_hdri.camera_neutral_to_xy(np.asarray(meta.as_shot_neutral), **args)
    expected = colour_hdri.matrix_camera_space_to_XYZ(
        xy, **args, M_forward_matrix_1=np.eye(3), M_forward_matrix_2=np.eye(3),
        chromatic_adaptation_transform="Bradford")
    neutral = np.asarray(meta.as_shot_neutral) / max(meta.as_shot_neutral)
    expected = expected / (expected @ neutral)[1]
    got, notes = camera_to_xyz_d50(meta, source="color_matrix")
    assert notes[0].startswith("ColorMatrix")
    np.testing.assert_allclose(got, expected, atol=1e-6, rtol=0)


@pytest.mark.published
@pytest.mark.parametrize("name", DUAL_ILLUMINANT_DNGS)
def test_oracle_xy_to_camera_neutral_matches_colour_hdri(name):
    """oracle: camera neutral of a white xy (both scaled to G = 1)."""
    colour_hdri = pytest.importorskip("colour_hdri")
    meta = dng_colour_meta(name)
    args, _ = hdri_args(meta)
    for xy in ([0.3127, 0.3290], [0.4476, 0.4074], [0.3457, 0.3585]):
        expected = colour_hdri.xy_to_camera_neutral(np.array(xy), **args)
        got = xy_to_camera_neutral(meta, xy)
        np.testing.assert_allclose(got / got[1], expected, atol=1e-9, rtol=0)


@pytest.mark.published
def test_oracle_colour_hdri_documentation_example():
    """oracle: colour-hdri's printed example (Canon EOS 5D Mark II):
    camera_neutral_to_xy((0.413070, 1, 0.646465)) = (0.3281624, 0.3469816);
    CameraToXYZ with the forward matrices as printed there, to 1e-6."""
    meta = canon_meta()
    xy = camera_neutral_to_xy(meta, CANON_NEUTRAL)
    np.testing.assert_allclose(xy, CANON["neutral_xy"], atol=1e-6)
    # colour-hdri prints, for xy (0.32816244, 0.34698169), FM not normalised:
    printed = np.array(CANON["camera_to_xyz"])
    # Undo the one difference: colour-hdri neither normalises FM nor scales
    # the camera white to max 1 (it scales to G = 1, which is the max here).
    fm = normalize_forward_matrix(CANON_FM)
    scale = (fm @ np.ones(3)) / (CANON_FM @ np.ones(3))
    got, _ = camera_to_xyz_d50(meta, xy=CANON["camera_to_xyz_at_xy"])
    np.testing.assert_allclose(got, scale[:, None] * printed, atol=1e-6)


@pytest.mark.published
def test_oracle_single_matrix_tinydng_matches_colour_hdri():
    """oracle: tinydng_colorchart.dng has ColorMatrix1 and no
    CalibrationIlluminant: no interpolation, the notes say so, and the
    ColorMatrix path matches colour-hdri fed one matrix (its convention:
    identity for the absent ColorMatrix2), up to the SDK's scale."""
    colour_hdri = pytest.importorskip("colour_hdri")
    meta = dng_colour_meta("tinydng_colorchart.dng")
    assert meta.color_matrix_1 is not None and meta.calibration_illuminant_1 is None
    got, notes = camera_to_xyz_d50(meta)
    assert any("no interpolation" in n for n in notes), notes
    assert any("CalibrationIlluminant1 missing" in n for n in notes), notes
    eye = np.eye(3)
    cm = normalize_color_matrix(meta.color_matrix_1)
    ab = np.asarray(meta.analog_balance)
    n = np.asarray(meta.as_shot_neutral)
    args = dict(CCT_calibration_illuminant_1=2850, CCT_calibration_illuminant_2=6500,
                M_color_matrix_1=cm, M_color_matrix_2=eye,
                M_camera_calibration_1=eye, M_camera_calibration_2=eye, analog_balance=ab)
    xy = colour_hdri.camera_neutral_to_xy(n, **args)
    np.testing.assert_allclose(camera_neutral_to_xy(meta, n), xy, atol=1e-9)
    expected = colour_hdri.matrix_camera_space_to_XYZ(
        xy, **args, M_forward_matrix_1=eye, M_forward_matrix_2=eye)
    expected = expected / (expected @ (n / n.max()))[1]
    np.testing.assert_allclose(got, expected, atol=1e-6)


# --------------------------------------------------------------------------
# published values

@pytest.mark.published
@pytest.mark.parametrize("code, cct", [tuple(row) for row in DNG["illuminant_to_cct"]])
def test_published_illuminant_cct(code, cct):
    """published: DNG SDK 1.7 dng_camera_profile::IlluminantToTemperature."""
    assert illuminant_to_cct(code) == cct


@pytest.mark.published
def test_published_illuminant_other_uses_illuminant_data():
    """published: 255 "Other" takes the CCT of its IlluminantData xy; D65's
    xy gives ≈ 6504 K (CIE 15:2004)."""
    assert illuminant_to_cct(255, CIE["D65"]["xy"]) == pytest.approx(CIE["D65"]["cct_k"], abs=2)


@pytest.mark.published
@pytest.mark.parametrize("xy, cct", [(tuple(v["xy"]), v["cct_k"]) for v in CIE.values()], ids=list(CIE))
def test_published_robertson_cct(xy, cct):
    """published: CCT of CIE illuminants A (2856 K) and D65 (≈ 6504 K),
    CIE 15:2004 table T.1 / T.3; Robertson's table interpolation is good to
    ≈ 1 K."""
    assert xy_to_cct(xy) == pytest.approx(cct, abs=2.0)


@pytest.mark.published
def test_published_bradford_d50_to_d65():
    """published: Lindbloom, "Chromatic Adaptation", Bradford D50 → D65 with
    his whites D50 (0.96422, 1, 0.82521), D65 (0.95047, 1, 1.08883); 1e-4."""
    lindbloom = np.array(LINDBLOOM["bradford_d50_to_d65"])
    got = bradford_matrix(LINDBLOOM["white_d50_xyz"], LINDBLOOM["white_d65_xyz"])
    np.testing.assert_allclose(got, lindbloom, atol=1e-4, rtol=0)


@pytest.mark.published
def test_published_xyz_d50_to_srgb_maps_white_to_white():
    """published: the DNG PCS white (D50, xy 0.3457, 0.3585) is sRGB
    (1, 1, 1) after Bradford D50 → D65 and the sRGB primaries; 1e-4."""
    x, y = DNG["pcs_white_xy"]
    white = np.array([x / y, 1.0, (1 - x - y) / y])
    np.testing.assert_allclose(matrix_xyz_d50_to_linear_srgb() @ white, 1.0, atol=1e-4)


@pytest.mark.published
def test_published_xyz_d50_to_srgb_lindbloom():
    """published: Lindbloom's XYZ(D50) → sRGB (Bradford) matrix, to 1e-3:
    his D50/D65 XYZ (ASTM E308) differ from the DNG PCS D50 xy and the sRGB
    D65 xy in the fourth decimal, which moves elements by up to 5.2e-4."""
    lindbloom = np.array(LINDBLOOM["xyz_d50_to_linear_srgb_bradford"])
    np.testing.assert_allclose(matrix_xyz_d50_to_linear_srgb(), lindbloom, atol=1e-3, rtol=0)


@pytest.mark.property
def test_property_conversions_agree_with_colour_science():
    """parity: the module's own conversions (it imports no colour-science, so
    that a render does not pay its import) equal colour-science's, an
    independent implementation: Robertson CCT over the range of whites,
    Bradford, xy ↔ XYZ and the sRGB normalised primary matrix, to float64
    rounding."""
    import colour
    from colour.adaptation import matrix_chromatic_adaptation_VonKries
    from colour.temperature import uv_to_CCT_Robertson1968

    from modules.common.dng_colour import xy_to_xyz, xyz_to_xy

    rng = np.random.default_rng(28)
    whites = np.concatenate([rng.uniform([0.24, 0.24], [0.52, 0.44], (400, 2)),
                             [v["xy"] for v in CIE.values()]])
    for xy in whites:
        ref = float(uv_to_CCT_Robertson1968(colour.xy_to_UCS_uv(xy))[0])
        assert xy_to_cct(xy) == pytest.approx(ref, rel=1e-12), xy
    np.testing.assert_allclose(xy_to_xyz(whites), colour.xy_to_XYZ(whites), rtol=1e-14)
    xyz = rng.uniform(0.05, 1.5, (50, 3))
    np.testing.assert_allclose(xyz_to_xy(xyz), colour.XYZ_to_xy(xyz), rtol=1e-14)
    for src, dst in rng.uniform(0.5, 1.2, (20, 2, 3)):
        np.testing.assert_allclose(bradford_matrix(src, dst),
                                   matrix_chromatic_adaptation_VonKries(src, dst, "Bradford"), atol=1e-14)
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    pcs = colour.xy_to_XYZ(np.array(DNG["pcs_white_xy"]))
    npm = colour.models.normalised_primary_matrix(srgb.primaries, srgb.whitepoint)
    ref = np.linalg.inv(npm) @ matrix_chromatic_adaptation_VonKries(
        pcs, colour.xy_to_XYZ(srgb.whitepoint), "Bradford")
    np.testing.assert_allclose(matrix_xyz_d50_to_linear_srgb(), ref, atol=1e-12)


@pytest.mark.published
def test_published_normalize_forward_matrix_maps_ones_to_pcs_white():
    """published: NormalizeForwardMatrix makes FM·(1, 1, 1) the PCS white,
    XYZ of xy (0.3457, 0.3585) = (0.964296, 1, 0.825105)."""
    fm = normalize_forward_matrix(CANON_FM)
    np.testing.assert_allclose(fm @ np.ones(3), DNG["pcs_white_xyz"], atol=1e-6)


# --------------------------------------------------------------------------
# properties: interpolation weight

@pytest.mark.property
def test_property_interpolation_weight_limits():
    """property: 1 at CCT1, 0 at CCT2, clamped outside, both orders."""
    assert interpolation_weight(2850, 2850, 6500) == 1.0
    assert interpolation_weight(6500, 2850, 6500) == 0.0
    assert interpolation_weight(2000, 2850, 6500) == 1.0
    assert interpolation_weight(10000, 2850, 6500) == 0.0
    assert interpolation_weight(float("inf"), 2850, 6500) == 0.0
    assert interpolation_weight(6500, 6500, 2850) == 1.0
    assert interpolation_weight(2850, 6500, 2850) == 0.0
    assert interpolation_weight(5000, 5000, 5000) == 1.0
    with pytest.raises(ValueError, match="positive"):
        interpolation_weight(0, 2850, 6500)


@pytest.mark.property
@settings(max_examples=200, deadline=None)
@given(t1=st.floats(1500, 4000), t2=st.floats(4500, 12000),
       a=st.floats(1000, 20000), b=st.floats(1000, 20000))
def test_property_interpolation_weight_monotone(t1, t2, a, b):
    """property: weight of the lower-CCT calibration falls with CCT, stays in
    [0, 1], is linear in mired inside, and does not depend on the order."""
    lo, hi = min(a, b), max(a, b)
    g_lo, g_hi = interpolation_weight(lo, t1, t2), interpolation_weight(hi, t1, t2)
    assert 0.0 <= g_hi <= g_lo <= 1.0
    assert interpolation_weight(a, t2, t1) == pytest.approx(1 - interpolation_weight(a, t1, t2))
    if t1 < a < t2:
        expected = (1 / a - 1 / t2) / (1 / t1 - 1 / t2)
        assert interpolation_weight(a, t1, t2) == pytest.approx(expected, rel=1e-12)


# --------------------------------------------------------------------------
# properties: the colour model

@pytest.mark.property
@pytest.mark.parametrize("source", ["auto", "color_matrix", "color_matrix_1",
                                    "color_matrix_2", "forward_matrix"])
def test_property_neutral_maps_to_y_one(source):
    """property: the camera neutral scaled to maximum 1 maps to the D50 white
    with Y = 1, in every path (the SDK's normalisation)."""
    meta = canon_meta()
    n = np.asarray(CANON_NEUTRAL)
    m, _ = camera_to_xyz_d50(meta, source=source)
    xyz = m @ (n / n.max())
    np.testing.assert_allclose(xyz, [0.3457 / 0.3585, 1, (1 - 0.3457 - 0.3585) / 0.3585],
                               atol=1e-6)


@pytest.mark.property
@pytest.mark.parametrize("xy", [(0.3127, 0.3290), (0.4476, 0.4074), (0.38, 0.39), (0.29, 0.30)])
def test_property_xy_neutral_round_trip(xy):
    """property: xy → camera neutral → xy returns the xy (NeutralToXY
    converges to 1e-7 in |Δx| + |Δy|)."""
    meta = canon_meta()
    n = xy_to_camera_neutral(meta, xy)
    assert n.max() == 1.0
    np.testing.assert_allclose(camera_neutral_to_xy(meta, n), xy, atol=1e-6)


@pytest.mark.property
def test_property_white_xy_and_neutral_agree():
    """property: AsShotWhiteXY and the equivalent AsShotNeutral give the same
    matrix."""
    xy = (0.36, 0.37)
    meta = canon_meta(as_shot_neutral=None, as_shot_white_xy=xy)
    by_xy, notes = camera_to_xyz_d50(meta)
    assert "AsShotWhiteXY" in notes[1]
    by_neutral, _ = camera_to_xyz_d50(meta, neutral=xy_to_camera_neutral(meta, xy))
    np.testing.assert_allclose(by_xy, by_neutral, atol=1e-6)


@pytest.mark.property
def test_property_no_white_tag_uses_d55():
    """property: neither AsShotNeutral nor AsShotWhiteXY: the SDK's D55."""
    meta = canon_meta(as_shot_neutral=None)
    m, notes = camera_to_xyz_d50(meta)
    assert "D55" in notes[1]
    np.testing.assert_allclose(m, camera_to_xyz_d50(meta, xy=(0.3324, 0.3474))[0])


@pytest.mark.property
@pytest.mark.parametrize("source", ["auto", "color_matrix"])
def test_property_analog_balance_is_undone(source):
    """property: AnalogBalance a scales the stored raw values by a; the
    camera → XYZ matrix for the same scene absorbs exactly diag(1/a), up to
    the overall scale set by the neutral's maximum."""
    a = np.array([1.3, 1.0, 0.8])
    plain = canon_meta()
    gained = canon_meta(analog_balance=tuple(a),
                        as_shot_neutral=tuple(a * np.asarray(CANON_NEUTRAL)))
    m0, _ = camera_to_xyz_d50(plain, source=source)
    m1, _ = camera_to_xyz_d50(gained, source=source)
    ratio = (m1 @ np.diag(a)) / m0
    np.testing.assert_allclose(ratio, ratio[0, 0], rtol=1e-6)


@pytest.mark.property
def test_property_single_matrix_sources_agree_with_auto():
    """property: with one ColorMatrix, 'auto', 'color_matrix' and
    'color_matrix_1' are the same computation."""
    meta = CameraMeta(color_matrix_1=CANON_CM_D65, calibration_illuminant_1=21,
                      as_shot_neutral=CANON_NEUTRAL)
    ref, notes = camera_to_linear_srgb(meta, applied_neutral=CANON_NEUTRAL)
    assert "no interpolation" in notes[0]
    for source in ("color_matrix", "color_matrix_1"):
        got, _ = camera_to_linear_srgb(meta, applied_neutral=CANON_NEUTRAL, source=source)
        np.testing.assert_allclose(got, ref, atol=1e-12)


@pytest.mark.property
def test_property_single_matrix_sources_agree_with_auto_tinydng():
    """property: the same on tinydng_colorchart.dng (ColorMatrix1 only)."""
    meta = dng_colour_meta("tinydng_colorchart.dng")
    ref, _ = camera_to_linear_srgb(meta, applied_neutral=meta.as_shot_neutral)
    for source in ("color_matrix", "color_matrix_1"):
        got, _ = camera_to_linear_srgb(meta, applied_neutral=meta.as_shot_neutral, source=source)
        np.testing.assert_allclose(got, ref, atol=1e-12)


@pytest.mark.property
def test_property_one_calibration_without_temperature_is_not_interpolated():
    """property: two ColorMatrix tags but CalibrationIlluminant2 unknown (0):
    the SDK keeps calibration 1 alone; the notes say why."""
    meta = canon_meta(calibration_illuminant_2=0)
    m, notes = camera_to_xyz_d50(meta)
    assert "no interpolation" in notes[0] and "CalibrationIlluminant2 Unknown" in notes[0]
    only1 = canon_meta(color_matrix_2=None, forward_matrix_2=None, calibration_illuminant_2=None)
    np.testing.assert_allclose(m, camera_to_xyz_d50(only1)[0], atol=1e-12)


@pytest.mark.property
def test_property_color_matrix_3_is_reported():
    meta = canon_meta(color_matrix_3=CANON_CM_D65, calibration_illuminant_3=23)
    _, notes = camera_to_xyz_d50(meta)
    assert any("ColorMatrix3 ignored" in n for n in notes)


# --------------------------------------------------------------------------
# Adobe's render spaces: ProPhoto (ROMM) and sRGB through the D50 PCS

@pytest.mark.published
def test_render_space_matrices_are_the_published_colorants():
    """ROMM RGB's normalised primary matrix (ISO 22028-2, as colour-science
    derives it) and the sRGB primaries Bradford-adapted to D50, both at the
    four decimals the SDK and the ICC sRGB profile print."""
    import colour
    from colour import xy_to_XYZ

    from modules.common.dng_colour import PROPHOTO_TO_XYZ_D50, SRGB_TO_XYZ_D50, bradford_matrix

    romm = colour.RGB_COLOURSPACES["ProPhoto RGB"].matrix_RGB_to_XYZ
    np.testing.assert_allclose(PROPHOTO_TO_XYZ_D50, romm, atol=5e-5)
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    adapted = bradford_matrix(xy_to_XYZ(srgb.whitepoint), xy_to_XYZ(np.array((0.3457, 0.3585)))) \
        @ srgb.matrix_RGB_to_XYZ
    np.testing.assert_allclose(SRGB_TO_XYZ_D50, adapted, atol=1e-4)


@pytest.mark.property
def test_prophoto_to_srgb_keeps_white_and_camera_white_maps_to_prophoto_white():
    from modules.common.dng_colour import (camera_to_prophoto, matrix_prophoto_to_srgb,
                                           matrix_xyz_d50_to_linear_srgb, matrix_xyz_d50_to_prophoto)

    m = matrix_prophoto_to_srgb()
    np.testing.assert_allclose(m @ np.ones(3), 1.0, atol=1e-12)
    # the same conversion as through colour-science's Bradford, up to the colorants' rounding
    np.testing.assert_allclose(m, matrix_xyz_d50_to_linear_srgb() @ np.linalg.inv(matrix_xyz_d50_to_prophoto()),
                               atol=5e-4)
    meta = canon_meta()
    cam, white, xy, notes = camera_to_prophoto(meta)
    np.testing.assert_allclose(cam @ white, 1.0, atol=1e-9)
    assert white.max() == pytest.approx(1.0) and xy.shape == (2,) and notes
    xyz, _ = camera_to_xyz_d50(meta)
    np.testing.assert_allclose(cam, matrix_xyz_d50_to_prophoto() @ xyz, atol=1e-12)

"""Tests of :mod:`modules.demosaic`.

Kinds, as marked on each test:

* property — analytic facts any correct demosaic satisfies (constant colour,
  linear ramps, sampled values kept, no clipping, dtype, shapes);
* golden — CPSNR floors on a Kodak image, measured here (not published):
  ``python -m tests.modules.test_demosaic`` prints the values the floors were set
  from;
* published — Malvar et al.'s claimed gain over bilinear on Kodak, and
  parity with an independent implementation (colour-demosaicing's bilinear
  and Malvar 2004, scipy convolution in float64).
"""

from __future__ import annotations

import typing
from pathlib import Path

import cv2
import numpy as np
import pytest

from isp.errors import ConfigError, InputError
from isp.frame import CFA, Domain, Frame
from isp.meta import CameraMeta
from isp.registry import create_stage
from modules.demosaic import (
    METHODS, OPENCV_BAYER, Demosaic, Method, demosaic, demosaic_bilinear,
    demosaic_malvar2004, demosaic_opencv,
)

KODIM19 = Path("/work/shared/data/latent/Kodak24/kodim19.png")
LINEAR = {"bilinear": demosaic_bilinear, "malvar2004": demosaic_malvar2004}
OPENCV = ("opencv_ea", "opencv_vng")


def mosaic_of(rgb: np.ndarray, cfa: CFA) -> np.ndarray:
    """(H, W) float32 Bayer samples of an (H, W, 3) image."""
    m = np.empty(rgb.shape[:2], np.float32)
    for r in range(2):
        for c in range(2):
            m[r::2, c::2] = rgb[r::2, c::2, cfa.pattern[r, c]]
    return m


def sampled_mask(shape, cfa: CFA) -> np.ndarray:
    """(H, W, 3) bool: True where the mosaic sampled that channel."""
    mask = np.zeros(shape + (3,), bool)
    for r in range(2):
        for c in range(2):
            mask[r::2, c::2, cfa.pattern[r, c]] = True
    return mask


def opencv_step(variant: str, lo: float, hi: float) -> float:
    """Quantisation step Δ of demosaic_opencv for data in [lo, hi] (see its
    Notes): the range maps onto 3/4 of the integer codes."""
    q = 65535 if variant == "opencv_ea" else 255
    return (max(1.0, hi) - min(0.0, lo)) / (0.75 * q)


def cpsnr(a: np.ndarray, b: np.ndarray, border: int = 8) -> float:
    """Colour PSNR in dB (peak 1) over all three channels, ``border`` px
    excluded."""
    d = (a.astype(np.float64) - b)[border:-border, border:-border]
    return float(10 * np.log10(1.0 / np.mean(d ** 2)))


@pytest.fixture(scope="module")
def astronaut() -> np.ndarray:
    skimage_data = pytest.importorskip("skimage.data")
    return (skimage_data.astronaut()[100:356, 140:396] / 255).astype(np.float32)


@pytest.fixture(scope="module")
def kodim19() -> np.ndarray:
    if not KODIM19.exists():
        pytest.skip(f"Kodak image not found at {KODIM19}")
    return (cv2.imread(str(KODIM19))[..., ::-1] / 255).astype(np.float32)


# ---------------------------------------------------------------------------
# parity with colour-demosaicing


@pytest.mark.published
@pytest.mark.parametrize("cfa", list(CFA))
@pytest.mark.parametrize("ours, theirs", [
    (demosaic_bilinear, "demosaicing_CFA_Bayer_bilinear"),
    (demosaic_malvar2004, "demosaicing_CFA_Bayer_Malvar2004"),
])
def test_parity_with_colour_demosaicing(astronaut, cfa, ours, theirs):
    # property: an independent implementation (scipy convolution, float64).
    # It extends the border by mirroring about the pixel edge (scipy
    # "reflect"), which swaps the CFA phase outside the frame; ours mirrors
    # about the edge pixel. Hence the comparison away from a 4-px border.
    colour_demosaicing = pytest.importorskip("colour_demosaicing")
    m = mosaic_of(astronaut, cfa)
    expected = getattr(colour_demosaicing, theirs)(m.astype(np.float64), cfa.value)
    got = ours(m, cfa)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got[4:-4, 4:-4], expected[4:-4, 4:-4], rtol=0, atol=1e-5)


# ---------------------------------------------------------------------------
# analytic properties


@pytest.mark.property
@pytest.mark.parametrize("cfa", list(CFA))
@pytest.mark.parametrize("method", list(METHODS))
def test_constant_colour_is_reproduced(method, cfa):
    # property: every method reproduces a flat colour, border included;
    # with components above 1 and below 0, and an odd size. Dyadic values,
    # so the linear filters are exact to the bit; OpenCV's to half a
    # quantisation step.
    rgb = np.array([1.5, 0.5, -0.0625], np.float32)
    m = mosaic_of(np.broadcast_to(rgb, (9, 13, 3)), cfa)
    out = demosaic(m, cfa, method)
    assert out.shape == (9, 13, 3) and out.dtype == np.float32
    if method in LINEAR:
        np.testing.assert_array_equal(out, np.broadcast_to(rgb, out.shape))
    else:
        atol = 1e-6 if method == "menon2007" else 0.5 * opencv_step(method, -0.0625, 1.5) + 1e-6
        np.testing.assert_allclose(out, np.broadcast_to(rgb, out.shape), rtol=0, atol=atol)


@pytest.mark.property
@pytest.mark.parametrize("cfa", list(CFA))
@pytest.mark.parametrize("method", list(LINEAR))
def test_linear_ramp_is_reproduced_inside(method, cfa):
    # property: bilinear interpolation is exact for functions linear in x
    # and y; so is Malvar, whose Laplacian corrections vanish on them
    # (2 px from the border, where the mirror bends the ramp).
    y, x = np.mgrid[0:24, 0:31].astype(np.float32)
    rgb = np.stack([0.1 + 0.01 * x + 0.02 * y,
                    0.5 - 0.015 * x + 0.005 * y,
                    -0.2 + 0.03 * x - 0.01 * y], axis=-1)
    out = LINEAR[method](mosaic_of(rgb, cfa), cfa)
    np.testing.assert_allclose(out[2:-2, 2:-2], rgb[2:-2, 2:-2], rtol=0, atol=2e-6)


@pytest.mark.property
@pytest.mark.parametrize("cfa", list(CFA))
@pytest.mark.parametrize("method", list(LINEAR))
def test_sampled_values_are_kept(astronaut, method, cfa):
    # property: mosaicking with P and demosaicing with P returns each sample
    # bit for bit at its own site, border included: this pins the CFA phase.
    m = mosaic_of(astronaut, cfa)
    out = LINEAR[method](m, cfa)
    mask = sampled_mask(m.shape, cfa)
    np.testing.assert_array_equal(out[mask], astronaut[mask])


@pytest.mark.property
@pytest.mark.parametrize("cfa", list(CFA))
@pytest.mark.parametrize("method", OPENCV)
def test_opencv_phase_and_quantisation(astronaut, method, cfa):
    # property: OpenCV's methods keep sampled values to half a quantisation
    # step (inside; EA copies its outermost row and column from the inner
    # ones), which checks OPENCV_BAYER's naming, the RGB order and the
    # dequantisation at once.
    m = mosaic_of(astronaut, cfa)
    out = demosaic(m, cfa, method)
    step = opencv_step(method, float(m.min()), float(m.max()))
    inner = np.zeros(m.shape + (3,), bool)
    inner[1:-1, 1:-1] = True
    mask = sampled_mask(m.shape, cfa) & inner
    np.testing.assert_allclose(out[mask], astronaut[mask], rtol=0, atol=0.5 * step + 1e-6)


@pytest.mark.property
@pytest.mark.parametrize("cfa", list(CFA))
def test_opencv_four_letter_aliases_agree(cfa):
    # property: where OpenCV ships the sensor-order aliases (COLOR_BayerRGGB2RGB,
    # ...), they are the codes OPENCV_BAYER picks.
    alias = f"COLOR_Bayer{cfa.value}2RGB_EA"
    if not hasattr(cv2, alias):
        pytest.skip(f"OpenCV {cv2.__version__} has no {alias}")
    assert getattr(cv2, alias) == getattr(cv2, f"COLOR_Bayer{OPENCV_BAYER[cfa]}2RGB_EA")


@pytest.mark.property
@pytest.mark.parametrize("suffix, dtype", [("_EA", np.uint16), ("_VNG", np.uint8)])
def test_opencv_commutes_with_an_offset(astronaut, suffix, dtype):
    # property: what demosaic_opencv relies on to keep negative values
    # (it shifts the data up before quantising): OpenCV's EA and VNG give
    # exactly the same result, shifted, for an offset input.
    qmax = np.iinfo(dtype).max
    codes = np.rint(mosaic_of(astronaut, CFA.RGGB) * (0.6 * qmax) + 0.1 * qmax).astype(dtype)
    code = getattr(cv2, f"COLOR_BayerBG2RGB{suffix}")
    shift = int(0.2 * qmax)
    base = cv2.cvtColor(codes, code).astype(np.int64)
    shifted = cv2.cvtColor(codes + dtype(shift), code).astype(np.int64)
    np.testing.assert_array_equal(shifted - shift, base)


# ---------------------------------------------------------------------------
# the data convention: no clipping, float32, any size


@pytest.mark.property
@pytest.mark.parametrize("method", list(LINEAR))
def test_no_clipping(method):
    # property: values above 1 and below 0 survive, where sampled and in
    # the interpolated neighbours.
    rng = np.random.default_rng(7)
    m = rng.uniform(0.2, 0.8, (16, 20)).astype(np.float32)
    m[5, 7], m[10, 12] = 1.5, -0.01
    out = LINEAR[method](m, CFA.GRBG)
    mask = sampled_mask(m.shape, CFA.GRBG)
    assert out[5, 7][mask[5, 7]] == np.float32(1.5)
    assert out[10, 12][mask[10, 12]] == np.float32(-0.01)
    assert out.max() >= 1.5 - 1e-6 and out.min() <= -0.01 + 1e-6


@pytest.mark.property
@pytest.mark.parametrize("method", OPENCV)
def test_opencv_keeps_values_outside_0_1(method):
    # property: the quantisation range covers the data, so values above 1
    # and below 0 come back (to half a step) instead of being clipped.
    m = np.full((12, 14), 0.5, np.float32)
    m[0::2, 0::2] = 1.5     # RGGB: every R sample
    m[1::2, 1::2] = -0.01   # every B sample
    out = demosaic(m, CFA.RGGB, method)
    atol = 0.5 * opencv_step(method, -0.01, 1.5) + 1e-6
    np.testing.assert_allclose(out[..., 0], 1.5, rtol=0, atol=atol)
    np.testing.assert_allclose(out[..., 2], -0.01, rtol=0, atol=atol)


@pytest.mark.property
def test_opencv_vng_overshoot_is_kept(astronaut):
    # property: VNG overshoots at edges of natural images; the headroom left
    # in the 8-bit codes lets that through instead of saturating at 0 and 1.
    out = demosaic(mosaic_of(astronaut, CFA.RGGB), CFA.RGGB, "opencv_vng")
    assert out.min() < -0.02 and out.max() > 1.02


@pytest.mark.property
@pytest.mark.parametrize("shape", [(2, 2), (3, 5), (7, 4), (33, 17)])
@pytest.mark.parametrize("method", list(METHODS))
def test_sizes_and_dtype(method, shape):
    # property: odd and tiny sizes, float32 out for float32 and float64 in.
    if method in OPENCV and min(shape) < 3:
        with pytest.raises(ValueError, match=r"at least 3 x 3, got shape \(2, 2\)"):
            demosaic(np.zeros(shape, np.float32), CFA.BGGR, method)
        return
    rng = np.random.default_rng(1)
    for dtype in (np.float32, np.float64):
        out = demosaic(rng.random(shape).astype(dtype), CFA.BGGR, method)
        assert out.shape == shape + (3,) and out.dtype == np.float32
        assert np.isfinite(out).all()


@pytest.mark.property
def test_invalid_inputs_name_the_value():
    # property: errors at the boundary carry the offending value.
    with pytest.raises(ValueError, match=r"2-D \(H, W\) array, got shape \(4, 4, 3\)"):
        demosaic_bilinear(np.zeros((4, 4, 3), np.float32), CFA.RGGB)
    with pytest.raises(ValueError, match="got dtype uint16"):
        demosaic_malvar2004(np.zeros((4, 4), np.uint16), CFA.RGGB)
    with pytest.raises(ValueError, match="unknown CFA 'RGBG'"):
        demosaic_bilinear(np.zeros((4, 4), np.float32), "RGBG")
    with pytest.raises(ValueError, match="valid: bilinear, malvar2004, menon2007, opencv_ea, opencv_vng"):
        demosaic(np.zeros((4, 4), np.float32), CFA.RGGB, "ahd")
    with pytest.raises(ValueError, match="unknown OpenCV demosaic variant 'bilinear'; valid: ea, vng"):
        demosaic_opencv(np.zeros((4, 4), np.float32), CFA.RGGB, variant="bilinear")
    bad = np.zeros((4, 4), np.float32)
    bad[1, 1] = np.nan
    with pytest.raises(ValueError, match="must be finite"):
        demosaic_opencv(bad, CFA.RGGB)


@pytest.mark.property
def test_cfa_name_is_accepted():
    # property: the pattern may be given by name.
    m = np.random.default_rng(2).random((8, 8)).astype(np.float32)
    np.testing.assert_array_equal(demosaic_bilinear(m, "gbrg"), demosaic_bilinear(m, CFA.GBRG))


# ---------------------------------------------------------------------------
# quality on a natural image

#: CPSNR (dB) measured on kodim19 (500 × 500 sRGB-encoded values, 8-px border
#: excluded), RGGB / BGGR / GRBG / GBRG:
#:   bilinear    26.75 26.67 26.59 26.85
#:   malvar2004  32.25 32.26 32.32 32.23
#:   menon2007   39.60 39.61 39.64 39.50
#:   opencv_ea   27.00 26.91 26.82 27.10
#:   opencv_vng  29.76 29.61 29.52 29.86
#: Floors: about 1 dB under the lowest of the four.
CPSNR_FLOOR = {"bilinear": 25.6, "malvar2004": 31.2, "menon2007": 38.5,
               "opencv_ea": 25.8, "opencv_vng": 28.5}


@pytest.fixture(scope="module")
def kodim19_cpsnr(kodim19) -> dict[tuple[str, CFA], float]:
    return {(name, cfa): cpsnr(f(mosaic_of(kodim19, cfa), cfa), kodim19)
            for name, f in METHODS.items() for cfa in CFA}


@pytest.mark.golden
@pytest.mark.parametrize("cfa", list(CFA))
@pytest.mark.parametrize("method", list(METHODS))
def test_cpsnr_floor(kodim19_cpsnr, method, cfa):
    # golden: measured floors, see CPSNR_FLOOR.
    assert kodim19_cpsnr[method, cfa] >= CPSNR_FLOOR[method]


@pytest.mark.property
@pytest.mark.parametrize("cfa", list(CFA))
def test_cpsnr_ranking(kodim19_cpsnr, cfa):
    # property: the gradient correction helps (Malvar et al. report
    # +5.5 dB over bilinear on Kodak), and Menon's directional decision
    # beats the linear filters.
    q = {name: kodim19_cpsnr[name, cfa] for name in METHODS}
    assert q["bilinear"] < q["malvar2004"] < q["menon2007"]


@pytest.mark.published
def test_malvar_gain_over_bilinear_on_kodak():
    # published: Malvar et al. (2004), abstract: "an improvement in PSNR of
    # over 5.5 dB when compared to bilinear demosaicing" on the Kodak set.
    # Here: the 24 Kodak images as 500 x 500 centre crops (not the 768 x 512
    # originals), CPSNR, RGGB; measured mean gain 5.29 dB (per image 4.1 to
    # 6.5 dB), so the test holds the mean to the claim within 0.5 dB.
    paths = sorted(KODIM19.parent.glob("kodim*.png"))
    if len(paths) != 24:
        pytest.skip(f"the 24 Kodak images are not all in {KODIM19.parent} ({len(paths)} found)")
    gains = []
    for path in paths:
        image = (cv2.imread(str(path))[..., ::-1] / 255).astype(np.float32)
        m = mosaic_of(image, CFA.RGGB)
        gains.append(cpsnr(demosaic_malvar2004(m, CFA.RGGB), image)
                     - cpsnr(demosaic_bilinear(m, CFA.RGGB), image))
    assert np.mean(gains) > 5.5 - 0.5


# ---------------------------------------------------------------------------
# the stage


@pytest.mark.property
def test_method_names_are_one_list():
    # property: the stage's Literal and the METHODS mapping agree.
    assert typing.get_args(Method) == tuple(METHODS)
    hints = typing.get_type_hints(Demosaic)
    assert typing.get_args(hints["method"]) == tuple(METHODS) + ("auto",)


@pytest.mark.property
def test_stage_demosaics_a_mosaic():
    # property: (H, W) raw_linear → (H, W, 3) camera_rgb, method recorded.
    m = np.random.default_rng(3).random((10, 15)).astype(np.float32)
    frame = Frame(m, Domain.RAW_LINEAR, CameraMeta(cfa=CFA.GBRG))
    out = Demosaic(method="malvar2004")(frame)
    assert out.domain is Domain.CAMERA_RGB
    assert out.shape == (10, 15, 3) and out.data.dtype == np.float32
    np.testing.assert_array_equal(out.data, demosaic_malvar2004(m, CFA.GBRG))
    assert str(out.history[-1]) == "demosaic: malvar2004"


@pytest.mark.property
def test_stage_passes_linear_raw_through():
    # property: a linear DNG (already demosaiced) keeps its data.
    rgb = np.random.default_rng(4).random((6, 8, 3)).astype(np.float32)
    frame = Frame(rgb, Domain.RAW_LINEAR, CameraMeta(cfa=None))
    out = Demosaic()(frame)
    assert out.data is rgb and out.domain is Domain.CAMERA_RGB
    assert out.history[-1].note == "passed through: data already demosaiced (LinearRaw)"


@pytest.mark.property
def test_stage_refuses_a_mosaic_without_cfa():
    # property: the error names the file.
    frame = Frame(np.zeros((4, 4), np.float32), Domain.RAW_LINEAR,
                  CameraMeta(path="IMG_0001.dng", cfa=None))
    with pytest.raises(InputError, match="IMG_0001.dng: mosaic without a CFA pattern"):
        Demosaic()(frame)


@pytest.mark.property
def test_stage_refuses_other_domains():
    # property: consumes raw_linear only.
    frame = Frame(np.zeros((4, 4), np.float32), Domain.RAW, CameraMeta(cfa=CFA.RGGB))
    with pytest.raises(ConfigError, match="consumes raw_linear, got a frame in raw"):
        Demosaic()(frame)


@pytest.mark.property
def test_stage_from_registry():
    # property: registered through the isp.stages entry point; parameters
    # are validated there (Literal check → ConfigError) and in the class
    # itself (ValueError).
    stage = create_stage("demosaic", method="menon2007")
    assert isinstance(stage, Demosaic) and stage.method == "menon2007"
    assert create_stage("demosaic").method == "malvar2004"  # the default
    with pytest.raises(ConfigError, match="'nope'"):
        create_stage("demosaic", method="nope")
    with pytest.raises(ValueError, match="unknown demosaic method 'nope'; valid: bilinear"):
        Demosaic(method="nope")


if __name__ == "__main__":  # regenerates the CPSNR table above
    image = (cv2.imread(str(KODIM19))[..., ::-1] / 255).astype(np.float32)
    for name, f in METHODS.items():
        values = [cpsnr(f(mosaic_of(image, cfa), cfa), image) for cfa in CFA]
        print(f"{name:11s}", " ".join(f"{v:.2f}" for v in values))


@pytest.mark.property
@pytest.mark.parametrize("shape", [(37, 23), (64, 50), (9, 101)])
@pytest.mark.parametrize("cfa", list(CFA))
@pytest.mark.parametrize("method", ["bilinear", "malvar2004"])
def test_banded_filtering_equals_whole_mosaic(monkeypatch, method, cfa, shape):
    """The filters run a band of rows at a time; bands of 2 to 6 rows give
    exactly the values of one band over the whole mosaic (halo rows and the
    border extension as the whole-mosaic filter has them)."""
    import modules.demosaic as dm

    m = np.random.default_rng(3).normal(0.5, 0.3, shape).astype(np.float32)
    monkeypatch.setattr(dm, "_BAND_VALUES", 1 << 30)
    whole = demosaic(m, cfa, method)
    for rows in (2, 4, 6):
        monkeypatch.setattr(dm, "_BAND_VALUES", rows * shape[1])
        np.testing.assert_array_equal(demosaic(m, cfa, method), whole)


@pytest.mark.property
def test_auto_takes_the_profile_method_else_bilinear():
    """``method="auto"``: the demosaic a matching lens profile names (what its
    correction model was trained after), else bilinear (Adobe's SDK)."""
    from isp import CameraMeta
    from modules.demosaic import Demosaic

    stage = Demosaic(method="auto")
    assert stage.method_for(CameraMeta(lens="US-12210142-B2-e9"))[0] == "malvar2004"
    assert stage.method_for(CameraMeta(lens="GoPro fisheye"))[0] == "bilinear"
    assert Demosaic(method="menon2007").method_for(CameraMeta(lens="US-12210142-B2-e9"))[0] == "menon2007"

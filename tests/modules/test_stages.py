"""Built-in stages: black level, lens shading, white balance, luminance,
gamma (kinds: published / property / reference as labelled)."""

from __future__ import annotations

import numpy as np
import pytest

from isp import CFA, CameraMeta, Domain, Frame, create_stage
from isp.opcodes import AreaSpec, FixVignetteRadial, GainMap, MapPolynomial, parse_opcode_list
from modules.gamma import encode, srgb_eotf, srgb_oetf
from modules.luminance import adjust_luminance
from modules.common.mosaic import cfa_affine


def _frame(data, domain=Domain.RAW, **meta):
    return Frame(np.asarray(data, np.float32), domain, CameraMeta(**meta))


# -- black level ---------------------------------------------------------------
def test_black_level_per_cfa_position_and_deltas(rng):
    # property: y = (x - B(r,c) - dV(r) - dH(c)) / (W - B(r,c)), exactly
    h, w = 6, 9  # odd width and even/odd handling
    black = np.array([[[60.0], [64.0]], [[62.0], [70.0]]])
    x = rng.uniform(100, 1000, (h, w))
    dv, dh = rng.uniform(-2, 2, h), rng.uniform(-1, 1, w)
    f = _frame(x, cfa=CFA.RGGB, black_level=black, white_level=(1023.0,),
               black_level_delta_v=dv, black_level_delta_h=dh, active_area=(0, 0, h, w))
    out = create_stage("black_level")(f)
    b = np.tile(black[:, :, 0], (h // 2 + 1, w // 2 + 1))[:h, :w]
    expect = (x - b - dv[:, None] - dh[None, :]) / (1023.0 - b)
    assert out.domain is Domain.RAW_LINEAR
    assert np.allclose(out.data, expect, atol=2e-6)


def test_black_level_keeps_negative_noise():
    f = _frame([[60.0, 64.0], [64.0, 1023.0]], cfa=CFA.RGGB, black_level=np.full((1, 1, 1), 64.0),
               white_level=(1023.0,))
    out = create_stage("black_level")(f).data
    assert out[0, 0] < 0 and out[1, 1] == pytest.approx(1.0)   # not clipped


def test_linearisation_table_applied_unless_the_decoder_did():
    table = np.arange(16) ** 2
    x = np.array([[3.0, 15.0]])
    f = _frame(x, cfa=CFA.RGGB, white_level=(225.0,), linearization_table=table)
    assert np.allclose(create_stage("black_level")(f).data, [[9 / 225, 1.0]])
    done = f.meta.replace(applied_by_decoder=("LinearizationTable",))
    assert np.allclose(create_stage("black_level")(f.evolve(meta=done)).data, [[3 / 225, 15 / 225]])


def test_map_polynomial_opcode_applied_in_black_level():
    op = MapPolynomial(AreaSpec(0, 0, 2, 2, 0, 1, 1, 1), (0.0, 0.5, 0.5))  # y = x/2 + x^2/2
    f = _frame([[0.0, 512.0], [1024.0, 256.0]], cfa=CFA.RGGB, white_level=(1024.0,), opcodes={2: (op,)})
    out = create_stage("black_level")(f)
    x = np.array([[0.0, 0.5], [1.0, 0.25]])
    assert np.allclose(out.data, x / 2 + x ** 2 / 2)
    assert "MapPolynomial" in out.history[-1].note


def test_cfa_affine_matches_strided_reference(rng):
    for h, w in ((6, 8), (7, 9), (1, 5)):
        x = rng.normal(size=(h, w)).astype(np.float32)
        s, o = rng.uniform(0.5, 2, (2, 2)), rng.normal(size=(2, 2))
        ref = np.empty_like(x)
        for i in range(2):
            for j in range(2):
                ref[i::2, j::2] = x[i::2, j::2] * s[i, j] + o[i, j]
        assert np.allclose(cfa_affine(x, s, o), ref, atol=1e-6)


# -- lens shading ------------------------------------------------------------------
def test_fix_vignette_radial_applied():
    op = FixVignetteRadial(k=(0.5, 0.0, 0.0, 0.0, 0.0), center_x=0.5, center_y=0.5)
    f = _frame(np.ones((20, 30, 3)), Domain.RAW_LINEAR, opcodes={2: (op,)}, raw_size=(20, 30))
    out = create_stage("lens_shading")(f).data
    assert np.allclose(out[..., 0], op.evaluate(20, 30), atol=1e-6)
    assert out[10, 15, 0] == pytest.approx(1.0, abs=0.01) and out[0, 0, 0] > 1.4


def test_three_plane_gain_map_on_linear_rgb():
    """The real 3-plane GainMap blob (4056x3040 sensor): each colour plane of a
    3-channel frame takes its own map plane (reference: GainMap.evaluate)."""
    gm = parse_opcode_list(_blob())[0]
    h, w = 3040, 4056
    f = _frame(np.ones((h // 8, w // 8, 3)), Domain.RAW_LINEAR, opcodes={2: (gm,)},
               active_area=(0, 0, h, w), default_crop=(0, 0, w // 8, h // 8))
    out = create_stage("lens_shading")(f).data
    rows, cols = np.arange(h // 8), np.arange(w // 8)
    for p in range(3):
        assert np.allclose(out[..., p], gm.evaluate(rows, cols, h, w, map_plane=p), atol=1e-6)
    assert not np.allclose(out[..., 0], out[..., 2])   # colour shading differs per plane


def _blob():
    from tests.helpers import data_file

    return data_file("raw", "opcodes", "DngOpcodesEditor_GainMap.bin").read_bytes()


def test_opcodelist3_gain_map_applied_per_cfa_colour():
    """A 3-plane map in OpcodeList3 (after demosaic) applied before demosaic:
    every mosaic site takes the plane of its own colour."""
    gains = np.stack([np.full((2, 2), 2.0), np.full((2, 2), 3.0), np.full((2, 2), 5.0)], axis=2)
    gm = GainMap.spanning_image(gains.astype(np.float32), area=AreaSpec(0, 0, 4, 4, 0, 3, 1, 1))
    f = _frame(np.ones((4, 4)), Domain.RAW_LINEAR, cfa=CFA.GRBG, opcodes={3: (gm,)})
    out = create_stage("lens_shading")(f).data
    assert np.allclose(out, np.tile([[3.0, 2.0], [5.0, 3.0]], (2, 2)))


def test_cell_centred_sampling_moves_map_points():
    # a map that is 1 at its first point and 3 at its last
    g = np.array([[1.0, 3.0]], np.float32)[:, :, None].repeat(2, axis=0)
    gm = GainMap.spanning_image(g, area=AreaSpec(0, 0, 1, 4, 0, 1, 1, 1))
    f = _frame(np.ones((1, 4)), Domain.RAW_LINEAR, cfa=CFA.RGGB, opcodes={2: (gm,)})
    dng = create_stage("lens_shading")(f).data[0]
    cc = create_stage("lens_shading", sampling="cell_centred")(f).data[0]
    # pixel centres at 1/8, 3/8, 5/8, 7/8 of the width
    assert np.allclose(dng, 1 + 2 * np.array([1, 3, 5, 7]) / 8)
    assert np.allclose(cc, [1.0, 1.5, 2.5, 3.0])   # points at 1/4 and 3/4


# -- white balance ---------------------------------------------------------------
def test_white_balance_modes(rng):
    cast = np.array([0.5, 1.0, 0.7])
    grey = rng.uniform(0.1, 0.8, (64, 64, 1)) * cast      # a grey world seen through a cast
    f = _frame(grey, Domain.RAW_LINEAR, as_shot_neutral=tuple(cast))
    for mode in ("as_shot", "grey_world"):
        out = create_stage("white_balance", mode=mode)(f)
        assert np.allclose(out.neutral, cast, rtol=1e-3)
        assert np.allclose(out.data[..., 0], out.data[..., 1], rtol=1e-3)
    man = create_stage("white_balance", mode="manual", gains=(2.0, 1.0, 1.0 / 0.7))(f)
    assert np.allclose(man.data[..., 0], man.data[..., 1], rtol=1e-6)
    # no as-shot white in the file: grey world, and the history says so
    bare = create_stage("white_balance")(_frame(grey, Domain.RAW_LINEAR))
    assert "grey world (no as-shot white" in bare.history[-1].note


def test_white_balance_from_as_shot_white_xy():
    m = np.array([[0.7, -0.1, -0.05], [-0.4, 1.2, 0.2], [-0.1, 0.2, 0.6]])
    f = _frame(np.ones((4, 4)), Domain.RAW_LINEAR, cfa=CFA.RGGB, color_matrix_1=m,
               calibration_illuminant_1=21, as_shot_white_xy=(0.3127, 0.3290))
    out = create_stage("white_balance")(f)
    from modules.ccm import xy_to_camera_neutral

    n = xy_to_camera_neutral(f.meta, (0.3127, 0.3290))
    assert np.allclose(out.neutral, n / n[1])


def test_manual_white_balance_needs_gains():
    from isp import ConfigError
    with pytest.raises(ConfigError, match="needs gains"):
        create_stage("white_balance", mode="manual")


# -- luminance ------------------------------------------------------------------------
def test_luminance_exposure_and_baseline():
    f = _frame(np.full((2, 2, 3), 0.1), Domain.CAMERA_RGB, baseline_exposure=1.0)
    assert np.allclose(create_stage("luminance", exposure=1.0)(f).data, 0.4)
    assert np.allclose(create_stage("luminance", baseline=False)(f).data, 0.1)


@pytest.mark.parametrize("tone", ["reinhard", "aces"])
def test_tone_curve_preserves_chromaticity(tone, rng):
    x = rng.uniform(0.01, 3.0, (16, 16, 3)).astype(np.float32)
    y = adjust_luminance(x, 1.0, tone=tone)
    ratio = y / x
    assert np.allclose(ratio[..., 0], ratio[..., 1], rtol=1e-5)   # one gain per pixel
    assert np.allclose(ratio[..., 1], ratio[..., 2], rtol=1e-5)


def test_reinhard_maps_white_point_to_one():
    x = np.full((1, 1, 3), 4.0, np.float32)
    assert np.allclose(adjust_luminance(x, 1.0, tone="reinhard", white=4.0), 1.0)


def test_luminance_runs_on_torch():
    torch = pytest.importorskip("torch")
    x = np.random.default_rng(0).uniform(0, 2, (1, 3, 4, 5)).astype(np.float32)
    t = torch.tensor(x, requires_grad=True)
    y = adjust_luminance(t, 1.5, tone="reinhard", channel_axis=-3)
    ref = np.moveaxis(adjust_luminance(np.moveaxis(x[0], 0, -1), 1.5, tone="reinhard"), -1, 0)
    assert np.allclose(y.detach().numpy()[0], ref, atol=1e-5)
    y.sum().backward()
    assert torch.isfinite(t.grad).all()


# -- gamma ------------------------------------------------------------------------------
def test_srgb_published_values():
    # published: IEC 61966-2-1 — the breakpoint and 8-bit anchors
    assert float(srgb_oetf(np.array(0.0031308))) == pytest.approx(0.0404500, abs=1e-6)
    assert float(srgb_oetf(np.array(0.2158605))) == pytest.approx(128 / 255, abs=2e-6)
    assert float(srgb_oetf(np.array(1.0))) == pytest.approx(1.0)
    assert float(srgb_eotf(np.array(0.5))) == pytest.approx(0.2140411, abs=1e-6)


def test_gamma_table_matches_formula_and_clips(rng):
    x = rng.uniform(-0.1, 1.3, (300, 400, 3)).astype(np.float32)
    fast = encode(x)
    exact = srgb_oetf(x.astype(np.float64))
    assert np.abs(fast - exact).max() < 1e-4
    assert fast.min() >= 0 and fast.max() <= 1 and fast.dtype == np.float32


def test_gamma_on_torch_matches_numpy():
    torch = pytest.importorskip("torch")
    x = np.linspace(-0.1, 1.2, 101, dtype=np.float32)
    t = torch.tensor(x, requires_grad=True)
    y = srgb_oetf(t)
    assert np.allclose(y.detach().numpy(), srgb_oetf(x.astype(np.float64)), atol=1e-6)
    y.sum().backward()
    assert torch.isfinite(t.grad).all()

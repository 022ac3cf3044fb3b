"""The inverse colour chain of the correction slot (restoration/synth/colour.py).

Kind: property. sRGB → camera RGB is checked against the pipeline's own
stage objects (so the synthesised input is what the slot receives): the
Luminance, ColorCorrection and Gamma stages give the sRGB back; a grey is
darkened by the exposure and white-balanced; the Process of the loss runs
on torch as on numpy.
"""

from __future__ import annotations

import numpy as np
import pytest

from isp.frame import Domain, Frame

pytestmark = pytest.mark.property


# -- colour: the inverse of the stages after the slot -----------------------------------

@pytest.mark.parametrize("tone", ["none", "reinhard", "aces"])
def test_inverse_colour_chain_matches_the_pipeline_stages(cameras, tone):
    """srgb → camera RGB, then the pipeline's own Luminance, ColorCorrection
    and Gamma stages, gives the sRGB back (within the gamma LUT's 1e-4)."""
    from modules.ccm import ColorCorrection
    from modules.gamma import Gamma
    from modules.luminance import Luminance
    from restoration.synth.colour import (
        colour_table,
        draw_colour,
        process_after_slot,
        srgb_to_camera,
    )

    rng = np.random.default_rng(3)
    srgb = rng.uniform(0.0, 1.0, (16, 16, 3)).astype(np.float32)
    table = colour_table(list(cameras), (2850.0, 7500.0), 5)
    for _ in range(6):
        col = draw_colour(table, rng, exposure_ev=(0.0, 2.0))
        cam = srgb_to_camera(srgb, col, tone=tone)
        meta = cameras[col.camera].meta
        frame = Frame(cam, Domain.CAMERA_RGB, meta, neutral=tuple(float(v) for v in col.neutral))
        be = meta.baseline_exposure or 0.0
        out = Gamma()(ColorCorrection()(Luminance(exposure=col.exposure_ev - be, tone=tone)(frame)))
        np.testing.assert_allclose(out.data, srgb, atol=2e-4)
        # the numpy/torch Process of the loss is the same function
        np.testing.assert_allclose(process_after_slot(cam, col.ccm, col.exposure_ev, luma_weights=col.luma_weights,
                                                      tone=tone), srgb, atol=2e-5)


def test_compression_darkens_and_white_balances(cameras):
    """A grey at EV k becomes 2^-k darker; unbalanced it is the neutral."""
    from modules.gamma import srgb_eotf
    from restoration.synth.colour import colour_table, draw_colour, srgb_to_camera

    table = colour_table(list(cameras), (3000.0, 6500.0), 3)
    col = draw_colour(table, np.random.default_rng(0), exposure_ev=(1.5, 1.5))
    grey = srgb_to_camera(np.full((1, 1, 3), 0.6, np.float32), col)[0, 0]
    np.testing.assert_allclose(grey, srgb_eotf(np.float32(0.6)) / 2 ** 1.5, rtol=1e-5)
    assert col.neutral[1] == 1.0 and col.gain == pytest.approx(2 ** 1.5)


def test_process_runs_on_torch_like_numpy(cameras):
    """Training takes the loss after the same stage functions on torch."""
    torch = pytest.importorskip("torch")
    from restoration.synth.colour import colour_table, draw_colour, process_after_slot

    col = draw_colour(colour_table(list(cameras), (3000.0, 6000.0), 2), np.random.default_rng(1))
    x = np.random.default_rng(2).uniform(0, 0.5, (8, 8, 3)).astype(np.float32)
    want = process_after_slot(x, col.ccm, col.exposure_ev)
    t = torch.from_numpy(np.ascontiguousarray(np.moveaxis(x, -1, 0)))[None].requires_grad_(True)
    got = process_after_slot(t, col.ccm, col.exposure_ev, channel_axis=-3)
    got.sum().backward()
    np.testing.assert_allclose(np.moveaxis(got.detach().numpy()[0], 0, -1), want, atol=1e-6)
    assert torch.isfinite(t.grad).all()

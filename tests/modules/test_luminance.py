"""The luminance stage (modules.luminance), kind: property: exposure and
BaselineExposure, tone curves that keep chromaticity, and the same function
on torch with finite gradients."""

from __future__ import annotations

import numpy as np
import pytest

from isp import Domain, create_stage
from modules.luminance import adjust_luminance
from tests.helpers import make_frame

pytestmark = pytest.mark.property


def test_luminance_exposure_and_baseline():
    f = make_frame(np.full((2, 2, 3), 0.1), Domain.CAMERA_RGB, baseline_exposure=1.0)
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

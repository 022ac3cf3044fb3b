"""The classical deconvolution baseline of the evaluation
(restoration/evaluate/baseline.py).

Kind: property. Wiener deconvolution with a displaced-delta PSF undoes the
displacement (its kernel convention is the blur's); with the true
field-varying PSF, Wiener and Richardson–Lucy beat the uncorrected image
where the blur is strong (a physics check). PSF maps are small synthetic
ones (no optics computed).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from isp.runtime.executor import create_executor
from tests.helpers import EVAL_FRAME as FRAME
from tests.helpers import identity_model as identity
from tests.helpers import ring_psf_map as psf_map

pytestmark = pytest.mark.property


QUIET = create_executor("serial")          # the crops in this process, no progress bar


@pytest.mark.parametrize("method", ["wiener", "rl"])
def test_deconvolution_with_the_true_psf_helps_where_the_blur_is(make, method):
    """Physics: with the true (field-varying) PSF and little noise, the
    classical deconvolution raises PSNR and SSIM at FoV 0.9, where the
    blur is widest."""
    from restoration.evaluate.rings import evaluate_plan

    plan, es = make([psf_map()], baseline=method, noise_scale=(0.02, 0.02))
    r = evaluate_plan(plan, identity, es, executor=QUIET)["rings"]["0.9"]
    assert r["psnr_baseline"] > r["psnr_uncorrected"] + 1.0
    assert r["ssim_baseline"] > r["ssim_uncorrected"]


def test_wiener_inverts_a_shift():
    """The baseline's kernel convention is the blur's: Wiener with a
    displaced-delta PSF undoes the displacement (interior, no noise)."""
    from calibration.simulate.optical_image import KernelBank
    from restoration.evaluate.baseline import deconvolve
    from restoration.synth.optics import CropBlur

    m = psf_map("delta", shift=(2, -4))       # 1 px down, 2 px left
    rng = np.random.default_rng(1)
    img = cv2.GaussianBlur(rng.uniform(0, 1, (64, 80, 3)).astype(np.float32), (0, 0), 1.0)
    blurred = CropBlur(m)(img, (100, 200))
    out, rec = deconvolve(blurred, KernelBank.from_psf(m), (100, 200), FRAME, sigma2=np.zeros(3))
    assert rec.regions >= 1 and rec.balance == pytest.approx(0.003 + 1e-12, rel=1e-3)
    inner = (slice(12, -12), slice(12, -12))
    assert np.abs(blurred[inner] - img[inner]).max() > 0.1
    assert np.abs(out[inner] - img[inner]).max() < 0.05

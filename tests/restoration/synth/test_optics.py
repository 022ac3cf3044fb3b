"""The blur and the lenses of the synthesis (restoration/synth/optics.py).

Kind: property. The fast crop blur against the readable oracle
(calibration.simulate.capture.blur_image) and conservation laws; a crop's
context reaches as far as its PSFs; delta PSFs are the identity; the drawn
lenses keep the proxy first. PSF maps are small synthetic ones (Gaussians
varying over the field), so no optics is computed.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.helpers import field_gaussian_map as gaussian_map

pytestmark = pytest.mark.property


# -- blur ---------------------------------------------------------------------------------

def test_window_reach_is_the_half_diagonal_of_the_psf_window(rng):
    """A crop's context before the maps exist equals the map's own margin,
    and a point's blur stays inside it."""
    from restoration.synth.optics import CropBlur, map_margin_px, window_reach_px

    # 64 samples of 0.5 µm on 1 µm pixels: half-diagonal 16·√2 = 22.6 px (+1)
    assert window_reach_px(64, None, 1.0) == 24 and window_reach_px(32, 0.5, 1.0) == 13
    m = gaussian_map()
    k = map_margin_px(m)
    assert k == window_reach_px(m.n, m.pitch_um, m.sensor.pixel_pitch_um)
    pt = np.zeros((60, 60, 3), np.float32)
    pt[30, 30] = 1.0
    lit = np.argwhere(np.abs(CropBlur(m)(pt, (20, 30))).max(axis=2) > 1e-6)
    assert np.abs(lit - 30).max() <= k


def test_fast_blur_matches_the_oracle_and_conserves(rng):
    from calibration.simulate.capture import blur_image
    from restoration.synth.optics import CropBlur, map_margin_px

    m = gaussian_map()
    cb = CropBlur(m)
    k = map_margin_px(m)
    img = rng.uniform(0, 1, (40, 52, 3)).astype(np.float32)
    for origin in [(0, 0), (-5, 70), (30, 40), (60, 90)]:
        fast = cb(img, origin)
        ref = blur_image(img, m, origin=origin)
        np.testing.assert_allclose(fast[k:-k, k:-k], ref[k:-k, k:-k], atol=2e-6)
        # a constant scene stays constant (each kernel sums to 1)
        flat = cb(np.full_like(img, 0.3), origin)
        np.testing.assert_allclose(flat[k:-k, k:-k], 0.3, atol=1e-6)
    # a point's energy is conserved where the PSF is constant (beyond the
    # outermost region centres) ...
    pt = np.zeros((40, 40, 3), np.float32)
    pt[8, 8] = 1.0
    np.testing.assert_allclose(cb(pt, (-4, -4)).sum(axis=(0, 1)), 1.0, atol=1e-5)
    # ... and to first order in the PSF's change across its own width where
    # it varies (each output pixel's kernel sums to 1, not each input's)
    pt[8, 8], pt[20, 20] = 0.0, 1.0
    np.testing.assert_allclose(cb(pt, (25, 60)).sum(axis=(0, 1)), 1.0, atol=0.01)
    # the mean of a textured scene is kept
    k2 = 2 * k
    big = rng.uniform(0, 1, (80, 100, 3)).astype(np.float32)
    assert cb(big, (10, 20))[k2:-k2, k2:-k2].mean() == pytest.approx(big[k2:-k2, k2:-k2].mean(), abs=2e-3)
    # the blur varies over the field: the same point elsewhere spreads differently
    assert np.abs(cb(pt, (0, 0)) - cb(pt, (50, 80))).max() > 1e-2


def test_blur_of_a_crop_is_the_blur_of_the_frame_there(rng):
    """The PSFs a crop gets are those of its position on the sensor."""
    from calibration.simulate.capture import blur_image
    from restoration.synth.optics import CropBlur, map_margin_px

    m = gaussian_map()
    full = rng.uniform(0, 1, (96, 128, 3))
    ref = blur_image(full, m)
    k = map_margin_px(m)
    for r, c in [(10, 20), (33, 71), (50, 90)]:
        crop = CropBlur(m)(full[r:r + 40, c:c + 30].astype(np.float32), (r, c))
        np.testing.assert_allclose(crop[k:-k, k:-k], ref[r + k:r + 40 - k, c + k:c + 30 - k], atol=2e-6)


def test_delta_psfs_are_the_identity(rng):
    from restoration.synth.optics import CropBlur, map_margin_px

    m = gaussian_map(delta=True)
    img = rng.uniform(0, 1, (30, 30, 3)).astype(np.float32)
    k = map_margin_px(m)
    # a delta sampled at half-pixel pitch, area-rebinned to pixels, is a delta
    np.testing.assert_allclose(CropBlur(m)(img, (40, 50))[k:-k, k:-k], img[k:-k, k:-k], atol=1e-6)


# -- lenses -------------------------------------------------------------------------------

def test_drawn_lenses_keep_the_proxy_first(e9_zmx):
    from calibration.optics.perturb import apply
    from restoration.synth.optics import draw_lenses, load_lens

    lens = load_lens(e9_zmx)
    proxy = apply(lens.nominal, {"e1.decenter_x": 0.001})
    a = draw_lenses(proxy, 3, np.random.default_rng(1))
    b = draw_lenses(proxy, 3, np.random.default_rng(1))
    assert a[0] is proxy and len(a) == 3
    assert a[1].perturbation.as_dict() == b[1].perturbation.as_dict()          # deterministic
    d = a[1].perturbation.as_dict()
    assert abs(d["e1.decenter_x"] - 0.001) <= 0.002 + 1e-12                     # within tolerance of the proxy
    assert a[1].perturbation.as_dict() != a[2].perturbation.as_dict()

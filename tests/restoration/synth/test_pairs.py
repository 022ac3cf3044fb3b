"""Training pairs for the correction slot (restoration/synth/pairs.py).

Kind: property. Without optics and noise a pair's input, processed, is its
latent (to demosaicing; flat colour exactly); the plan samples the lens's
sensor at the pixel pitch asked for; synthesis never imports torch.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from isp.runtime.executor import create_executor
from tests.helpers import data_file, latent_png
from tests.helpers import make_synth_plan as make_plan

pytestmark = pytest.mark.property

S6 = ("raw", "SYNTHETIC_phone_S6meta_512x384.dng")


# -- the chain without optics and noise ----------------------------------------------------

def test_ideal_lens_no_noise_round_trip(tmp_path, cameras):
    """Ideal lens, no noise, no quantisation: Process(input) is the latent up
    to demosaicing (malvar2004 on this pattern, whose channels are out of
    phase: ≥ 25 dB, median error < 2.6 levels; flat colour is exact, next
    test)."""
    from restoration.synth.pairs import make_pair
    from restoration.synth.colour import process_after_slot

    plan = make_plan(tmp_path, cameras, [None], noise=False, quantise=False)
    for i in range(4):
        p = make_pair(plan, i)
        out = process_after_slot(p["input"], p["ccm"], p["exposure_ev"])
        target = p["target"] / 255.0
        psnr = -10 * np.log10(np.mean((out - target) ** 2))
        assert psnr > 25, (i, psnr)
        # most pixels are far from an edge and nearly exact
        err = np.abs(out - target).max(axis=2)
        assert np.median(err) < 0.01


def test_flat_colour_is_exact(tmp_path, cameras):
    from restoration.synth.pairs import make_pair
    from restoration.synth.colour import process_after_slot

    plan = make_plan(tmp_path, cameras, [None], noise=False, quantise=False)
    d = tmp_path / "flat"
    d.mkdir()
    cv2.imwrite(str(d / "flat.png"), np.full((80, 80, 3), (40, 120, 200), np.uint8))
    plan = dataclasses.replace(plan, latents=(str(d / "flat.png"),))
    for i in range(3):
        p = make_pair(plan, i)
        out = process_after_slot(p["input"], p["ccm"], p["exposure_ev"])
        np.testing.assert_allclose(out, p["target"] / 255.0, atol=1e-4)


def test_isp_and_synthesis_never_import_torch():
    import subprocess
    import sys

    code = ("import sys, isp.cli.main, restoration.synth.pairs, restoration.train.dataset, restoration.cli.synth; "
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "False"


def test_plan_pixel_um_samples_the_lens_sensor_at_that_pitch(tmp_path, cameras, e9_zmx):
    """property: ``pixel_um`` keeps the lens file's sensor area and sets the
    pairs' pitch: e9 (5614 × 4211 px of 1 µm) at 2 µm is 2807 × 2106 px, and
    the PSF map is sampled at half that pitch (1 µm), so a lens's blur
    spans half as many pixels as at the file's own pitch. Why it exists: a
    proxy fitted to a 2.8 µm capture carries that capture's sensor, and
    pairs made from it were 2.1 dB milder than the 1 µm device they were
    scored on."""
    from restoration.synth.pairs import SynthSettings, plan

    lens = e9_zmx
    kw = dict(latent_dir=latent_png(tmp_path, size=160), cameras=[data_file(*S6)], executor=create_executor("serial"),
              settings=SynthSettings(size=64),
              cache_dir=tmp_path / "psf")
    psf = {"grid": (1, 2), "channels": ("G",), "n_wavelengths": 1, "pupil_samples": 32}
    own = plan(str(lens), psf_options={**psf, "n": 32}, **kw).maps[0]            # 16 µm windows both
    half = plan(str(lens), pixel_um=2.0, psf_options={**psf, "n": 16}, **kw).maps[0]
    assert (own.sensor.width_px, own.sensor.pixel_pitch_um) == (5614, 1.0)
    assert (half.sensor.width_px, half.sensor.height_px, half.sensor.pixel_pitch_um) == (2807, 2106, 2.0)
    assert half.pitch_um == pytest.approx(1.0) and own.pitch_um == pytest.approx(0.5)
    # the same lens: the PSFs' second moments in µm agree, so in pixels they halve
    def width_um(m):
        p = m.psfs[0, 1, 0]
        x = (np.arange(p.shape[0]) - (p.shape[0] - 1) / 2) * m.pitch_um
        return float(np.sqrt((p.sum(0) * x ** 2).sum() / p.sum()))
    assert width_um(half) == pytest.approx(width_um(own), rel=0.1)
    # the default window is 32 µm at any pitch (64 samples of 0.5 µm on 1 µm pixels, 32 of 1.4 µm at 2.8 µm),
    # not 64 samples whatever the pixel, which at 2.8 µm had been 90 µm, past the pupil's replica period
    coarse = plan(str(lens), pixel_um=2.8, psf_options={**psf, "pupil_samples": 48}, **kw).maps[0]
    assert coarse.n == 32 and coarse.n * coarse.pitch_um >= 32.0


def test_radius_positions_give_the_outer_ring_its_width_share_not_its_area_share():
    """``positions="radius"``: a crop's centre radius is uniform up to the
    corner crop's (share of centres in [0.8, 0.9) of the half-diagonal:
    0.1 / r_max), every crop inside the frame; ``"frame"``: uniform over the
    frame, where the share of a ring is its area's (a Monte Carlo of the
    uniform frame, independent of the sampler, as the reference)."""
    from isp.errors import ConfigError
    from restoration.synth.pairs import SynthSettings, crop_origin

    full, n = (4211, 5614), 256
    hd = np.hypot(full[0] / 2, full[1] / 2)
    r_max = np.hypot(full[0] - n, full[1] - n) / 2 / hd

    def radii(positions, k=4000):
        rng = np.random.default_rng(1)
        o = np.array([crop_origin(full, n, rng, positions) for _ in range(k)])
        assert o.min() >= 0 and (o[:, 0] <= full[0] - n).all() and (o[:, 1] <= full[1] - n).all()
        return np.hypot(o[:, 0] + n / 2 - full[0] / 2, o[:, 1] + n / 2 - full[1] / 2) / hd

    r = radii("radius")
    assert np.mean((r >= 0.8) & (r < 0.9)) == pytest.approx(0.1 / r_max, abs=0.015)
    assert np.mean(r < 0.2) == pytest.approx(0.2 / r_max, abs=0.02)
    assert r.max() <= r_max + 1e-3
    u = np.random.default_rng(2).uniform(size=(200_000, 2)) * (np.array(full) - n) + n / 2
    area = np.hypot(u[:, 0] - full[0] / 2, u[:, 1] - full[1] / 2) / hd
    f = radii("frame")
    assert np.mean(f >= 0.8) == pytest.approx(np.mean(area >= 0.8), abs=0.015)
    assert np.mean(r >= 0.8) > 2 * np.mean(f >= 0.8)
    # the shares the docs quote for e9's sensor: outer ring 6–7 % against 16 %, beyond 0.9 under 1 % against 5 %
    assert 0.055 < np.mean(f >= 0.8) < 0.075 and np.mean(f >= 0.9) < 0.01
    assert 0.14 < np.mean(r >= 0.8) < 0.175 and 0.045 < np.mean(r >= 0.9) < 0.065
    with pytest.raises(ConfigError, match="positions"):
        SynthSettings(positions="corners")

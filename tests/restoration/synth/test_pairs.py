"""Data synthesis for the correction slot (restoration.synth.pairs*, `isp synth`).

Kind: property. The inverse colour chain is checked against the pipeline's
own stage objects (so the synthesised input is what the slot receives), the
blur against the readable oracle (calibration.simulate.capture.blur_image) and
conservation laws, the noise against the NoiseProfile it claims, and the
shards for determinism and provenance. PSF maps here are small synthetic
ones (Gaussians varying over the field), so no optics is computed.
"""

from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest
from tests.helpers import data_file, kernel_psf_map

from calibration.optics.psf.map import PSFMap
from isp.cli.main import main
from isp.frame import CFA, Domain, Frame
from isp.runtime.executor import create_executor

pytestmark = pytest.mark.property

S6 = ("raw", "SYNTHETIC_phone_S6meta_512x384.dng")
LG = ("raw", "skia_sample_1mp.dng")


# -- fixtures --------------------------------------------------------------------------

def gaussian_map(height=96, width=128, grid=(3, 4), n=16, pitch_um=0.5, sigmas=None, delta=False) -> PSFMap:
    """A PSF map of Gaussians whose width grows over the field (and differs
    per channel), or of deltas (an ideal lens)."""
    def kernel(r, c, ch, xx, yy):
        if delta:
            return (xx == 0) & (yy == 0)
        s = sigmas[r, c, ch] if sigmas is not None else 0.4 + 0.35 * (r + c) + 0.15 * ch
        return np.exp(-((xx - 0.2 * c) ** 2 + (yy - 0.1 * r) ** 2) / (2 * s * s))

    return kernel_psf_map(kernel, height=height, width=width, grid=grid, n=n, pitch_um=pitch_um)


def latent_png(tmp_path, size=96, seed=0):
    """A latent sRGB image with edges and texture (8-bit PNG)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size]
    img = np.stack([0.5 + 0.4 * np.sin(x / 6.0 + k) * np.cos(y / 9.0 - k) for k in range(3)], -1)
    img[size // 3:2 * size // 3, size // 4:size // 2] = rng.uniform(0.05, 0.95, 3)
    u8 = np.clip(np.rint(img * 255), 0, 255).astype(np.uint8)
    d = tmp_path / "latent"
    d.mkdir(exist_ok=True)
    cv2.imwrite(str(d / f"img{seed}.png"), u8[:, :, ::-1])
    return d


@pytest.fixture(scope="module")
def cameras():
    from restoration.synth.colour import read_camera

    return (read_camera(data_file(*S6)), read_camera(data_file(*LG)))


def make_plan(tmp_path, cameras, maps, *, seed=0, **settings):
    from restoration.synth.pairs import SynthPlan, SynthSettings, find_latents
    from restoration.synth.colour import colour_table

    st = SynthSettings(**{"size": 32, "cct_steps": 4, **settings})
    m0 = next((m for m in maps if m is not None), None)
    full = (m0.sensor.height_px, m0.sensor.width_px) if m0 is not None else (96, 128)
    lat = tuple(str(p) for p in find_latents(latent_png(tmp_path)))
    return SynthPlan(tuple(maps), cameras, colour_table(list(cameras), st.cct_k, st.cct_steps), lat, full,
                     seed, st, (4e-4, 1e-6))


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


def test_input_is_what_the_pipeline_hands_the_slot(cameras, rng):
    """develop() == the pipeline's WhiteBalance and Demosaic stages on the
    same mosaic, for every CFA phase of a crop origin."""
    from modules.demosaic import Demosaic
    from modules.white_balance import WhiteBalance
    from restoration.synth.sensor import develop

    meta0 = cameras[0].meta
    mos = rng.uniform(0, 1, (20, 24)).astype(np.float32)
    n = np.array([0.5, 1.0, 0.7])
    for origin in [(0, 0), (1, 0), (0, 1), (3, 5)]:
        cfa = meta0.cfa.shifted(*origin)
        meta = meta0.replace(cfa=cfa, as_shot_neutral=tuple(n), origin=(0, 0))
        fr = Demosaic()(WhiteBalance()(Frame(mos, Domain.RAW_LINEAR, meta)))
        np.testing.assert_array_equal(develop(mos, cfa, n, "malvar2004"), fr.data)


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


# -- noise --------------------------------------------------------------------------------

@pytest.mark.parametrize("quantise", [False, True])
def test_noise_variance_follows_the_noise_profile(quantise):
    from calibration.optics.lens import Sensor as Geo
    from isp.meta import CameraMeta
    from restoration.synth.sensor import capture_mosaic, sensor_model

    meta = CameraMeta(cfa=CFA.RGGB, white_level=(4095.0,), black_level=np.full((1, 1, 1), 256.0))
    prof = (2e-4, 4e-6)
    sensor = sensor_model(meta, Geo(1.0, 400, 400), prof)
    rng = np.random.default_rng(7)
    for level in (0.02, 0.2, 0.6):
        rgb = np.full((400, 400, 3), level)
        m = capture_mosaic(rgb, sensor, (0, 0), rng, noise=True, quantise=quantise)
        var = float(m.var())
        want = prof[0] * level + prof[1]
        # 160k samples: the variance estimate's relative s.d. is ~0.4 %
        assert var == pytest.approx(want, rel=0.03), (level, var, want)
        assert float(m.mean()) == pytest.approx(level, abs=5e-4)


# -- shards, determinism, loader ------------------------------------------------------------

def test_shards_are_deterministic_and_traceable(tmp_path, cameras):
    from restoration.train.dataset import SynthPairs, verify
    from restoration.synth.pairs import generate
    from restoration.synth.shards import file_sha256

    m = gaussian_map()
    plan = make_plan(tmp_path, cameras, [m, gaussian_map(sigmas=np.full((3, 4, 3), 1.2))], seed=5)
    serial = create_executor("serial")
    a = generate(plan, tmp_path / "a", 6, shard_size=4, executor=serial)
    b = generate(plan, tmp_path / "b", 6, shard_size=4, executor=create_executor("processes", 2))
    c = generate(dataclasses.replace(plan, seed=6), tmp_path / "c", 6, shard_size=4, executor=serial)
    assert [s["sha256"] for s in a["shards"]] == [s["sha256"] for s in b["shards"]]   # workers don't matter
    assert a["data_sha256"] == b["data_sha256"] != c["data_sha256"]                   # the seed does
    assert (tmp_path / "a" / "manifest.json").read_bytes() == (tmp_path / "b" / "manifest.json").read_bytes()
    assert verify(tmp_path / "a") == []
    man = json.loads((tmp_path / "a" / "manifest.json").read_text())
    assert man["schema"] == "isp-synth/v1" and man["seed"] == 5 and man["pairs"] == 6
    assert man["cameras"][0]["sha256"] == file_sha256(data_file(*S6))
    assert man["process"]["stages"] == ["luminance", "ccm", "gamma"]

    pairs = SynthPairs(tmp_path / "a")
    assert len(pairs) == 6
    lens_used = set()
    for i in range(6):
        p = pairs[i]
        assert p["input"].shape == (32, 32, 3) and p["target"].dtype == np.float32
        assert p["index"] == i
        lens_used.add(int(p["lens"]))
        # field coordinates: pixel (i, j) of the pair is sensor pixel origin + (i, j)
        r0, c0 = (int(v) for v in p["origin"])
        assert 0 <= r0 <= 96 - 32 and 0 <= c0 <= 128 - 32
        np.testing.assert_allclose(p["fov"][0, 5, 7], (c0 + 7 + 0.5) / 128 * 2 - 1, atol=1e-6)
        np.testing.assert_allclose(p["fov"][1, 5, 7], (r0 + 5 + 0.5) / 96 * 2 - 1, atol=1e-6)
        out = pairs.process(p["input"], p)
        assert -10 * np.log10(np.mean((out - p["target"]) ** 2)) > 15     # blurred, noisy, but the same picture
    assert lens_used == {0, 1}                                            # both lenses ("multiple samples")

    # a changed shard is caught
    shard = tmp_path / "a" / man["shards"][0]["file"]
    raw = bytearray(shard.read_bytes())
    raw[-100] ^= 0xFF
    shard.write_bytes(bytes(raw))
    assert len(verify(tmp_path / "a")) == 1
    with pytest.raises(Exception, match="previous set"):
        generate(plan, tmp_path / "a", 2, executor=create_executor("serial"))


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


# -- command line ------------------------------------------------------------------------------

def test_synth_help_and_errors(capsys, tmp_path, e9_zmx):
    with pytest.raises(SystemExit) as e:
        main(["synth", "--help"])
    assert e.value.code == 0
    assert "isp synth --lens" in capsys.readouterr().out
    assert main(["synth", "--lens", str(tmp_path / "no.zmx"), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "no.zmx" in err and len(err.strip().splitlines()) == 1
    zmx = e9_zmx
    assert main(["synth", "--lens", str(zmx), "-o", str(tmp_path / "o"), "--latent", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert "latent" in err and len(err.strip().splitlines()) == 1


def test_isp_and_synthesis_never_import_torch():
    import subprocess
    import sys

    code = ("import sys, isp.cli.main, restoration.synth.pairs, restoration.train.dataset, restoration.cli.synth; "
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "False"


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

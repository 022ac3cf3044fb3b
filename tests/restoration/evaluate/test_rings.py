"""Evaluation of a correction model by field ring (restoration/evaluate/rings.py).

Kind: property. Controlled cases whose answer is known: the field radius
and the crops placed for each ring; the evaluation's lenses are not the
training's; an identity model scores as the uncorrected pipeline; a model
that undoes a pure shift (a PSF that is a displaced delta, no noise)
scores as an ideal lens does; a model trained at another pixel pitch is
flagged. PSF maps are small synthetic ones (no optics computed); the frame
is 384 × 512 with 48-px crops, so all three field rings can be reached.
"""

from __future__ import annotations

import numpy as np
import pytest

from isp.runtime.executor import create_executor
from tests.helpers import identity_model as identity
from tests.helpers import onnx_select_rgb
from tests.helpers import ring_psf_map as psf_map

pytestmark = pytest.mark.property


QUIET = create_executor("serial")          # the crops in this process, no progress bar


# -- geometry ------------------------------------------------------------------------------

def test_field_radius_and_ring_placement():
    """Property: r = 0 at the centre, 1 at the corners; crops placed for a
    ring lie on the sensor with their centre inside the ring."""
    from restoration.evaluate.rings import RINGS, field_radius, ring_origin

    h, w = 4211, 5614
    r = field_radius(np.array([0, h // 2, h - 1]), np.array([0, w // 2, w - 1]), (h, w))
    assert r[0, 0] == pytest.approx(1.0, abs=1e-3) and r[2, 2] == pytest.approx(1.0, abs=1e-3)
    assert r[1, 1] == pytest.approx(0.0, abs=1e-3)
    rng = np.random.default_rng(0)
    for _ in range(20):
        for lo, hi in RINGS.values():
            r0, c0 = ring_origin((h, w), 320, 0.5 * (lo + hi), (lo, hi), rng)
            assert 0 <= r0 <= h - 320 and 0 <= c0 <= w - 320
            rr = field_radius(np.arange(r0, r0 + 320), np.arange(c0, c0 + 320), (h, w))
            assert lo <= rr[160, 160] <= hi and lo <= rr.min() and rr.max() <= hi


def test_unseen_lenses_are_not_the_training_draws(e9_zmx):
    """The evaluation's lenses come from another random stream than the
    training's (spawn key 2 vs 0), so none equals a training lens for the
    same seed, and the proxy is left out unless asked for."""
    from restoration.evaluate.rings import eval_lenses
    from restoration.synth.pairs import seeded_rng
    from restoration.synth.optics import draw_lenses, load_lens

    lens = load_lens(e9_zmx)
    train = draw_lenses(lens, 4, seeded_rng(0, 0))
    test = eval_lenses(lens, 3, 0)
    assert len(test) == 3
    key = lambda pl: tuple(sorted(pl.perturbation.as_dict().items()))
    assert not {key(t) for t in test} & {key(t) for t in train}
    assert key(eval_lenses(lens, 1, 0, with_proxy=True)[0]) == key(lens)
    assert [key(t) for t in eval_lenses(lens, 3, 0)] == [key(t) for t in test]   # deterministic


# -- controlled cases ------------------------------------------------------------------------

def test_identity_model_scores_as_uncorrected(make):
    """Property: corrected == uncorrected, ring by ring, for an identity model."""
    from restoration.evaluate.rings import evaluate_plan

    plan, es = make([psf_map()])
    res = evaluate_plan(plan, identity, es, executor=QUIET)
    assert set(res["rings"]) == {"0.1", "0.5", "0.9"}
    for ring in res["rings"].values():
        assert ring["crops"] == 2
        assert ring["psnr_corrected"] == ring["psnr_uncorrected"]
        assert ring["ssim_corrected"] == ring["ssim_uncorrected"]
    # the blur grows with the field: the uncorrected image gets worse outwards
    psnr = [res["rings"][k]["psnr_uncorrected"] for k in ("0.1", "0.5", "0.9")]
    assert psnr[0] > psnr[1] > psnr[2]


def test_exact_inverse_scores_as_an_ideal_lens(make):
    """Property: the blur is a shift by 2 px (a displaced delta: the CFA
    phase is kept), no noise, no quantisation; a model that shifts back
    gives exactly the input of an ideal lens, so its scores equal the ideal
    lens's uncorrected ones, far above the shifted image's."""
    from restoration.evaluate.rings import evaluate_plan

    def unshift(J, origin, full_size):
        return np.roll(J, -2, axis=1)          # the border it wraps is not scored

    kw = {"noise": False, "quantise": False, "baseline": "none"}
    shifted, es = make([psf_map("delta", shift=(0, 4))], **kw)
    ideal, _ = make([None], **kw)
    got = evaluate_plan(shifted, unshift, es, executor=QUIET)
    ref = evaluate_plan(ideal, identity, es, executor=QUIET)
    for k in ("0.1", "0.5", "0.9"):
        g, r = got["rings"][k], ref["rings"][k]
        assert g["psnr_corrected"] == pytest.approx(r["psnr_uncorrected"], abs=0.01)
        assert g["ssim_corrected"] == pytest.approx(r["ssim_uncorrected"], abs=1e-4)
        assert g["psnr_corrected"] > g["psnr_uncorrected"] + 5.0
        assert g["psnr_baseline"] is None and g["ssim_baseline"] is None


# -- a model trained at another pixel pitch ---------------------------------------------------

def test_a_model_trained_at_another_pixel_pitch_is_flagged(make, latent_dir, tmp_path, monkeypatch):
    """A model corrects blur in pixels: one whose training pairs were made
    at 2.807 µm pixels, scored on lenses whose sensor has 1 µm pixels,
    gets a warning naming both pitches and the option that makes pairs at
    the test's pitch; trained at the test's pitch, none."""
    import warnings

    import restoration.evaluate.rings as ev
    from restoration.evaluate.runner import load_runner

    plan, _ = make([psf_map()], baseline="none")
    plan.info["psf_map"] = {"sensor": {"pixel_pitch_um": 1.0, "width_px": 128, "height_px": 96}}
    monkeypatch.setattr(ev, "eval_plan", lambda lens, images_dir, **kw: plan)
    runner = load_runner(onnx_select_rgb(tmp_path / "sel.onnx"))
    kw = dict(images_dir=latent_dir, lens="lens.json",
              settings=ev.EvalSettings(samples=1, size=32, border=8, baseline="none"), executor=QUIET)
    for pitch, flagged in ((2.807, True), (1.0, False)):
        runner.info = {"metadata": {"training_sets": [{"psf_map": {"sensor": {"pixel_pitch_um": pitch}}}]}}
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            ev.evaluate(runner, **kw)
        hits = [str(w.message) for w in seen if "µm pixels" in str(w.message)]
        assert bool(hits) is flagged
        if flagged:
            assert "2.807 µm" in hits[0] and "1 µm" in hits[0] and "--pixel-um 1" in hits[0]

"""Tests of :mod:`calibration.sfr.esfr` — ISO 12233 e-SFR, sfrmat5 algorithm.

Each test is marked with its kind, ``property`` (the analytic and the
property tests below) or ``published`` (the reference tests):

* **analytic** — slanted edges rendered exactly (:mod:`calibration.sfr.synthetic`:
  Gaussian PSF ⊗ square pixel aperture, to ~1e-12) against the closed-form
  MTF ``exp(−2π²σ²f²)·|sinc(f cos θ)·sinc(f sin θ)|``;
* **reference** — the real edges of ``../shared/data/edges`` against the SFR
  curves of sfrmat3, sfrmat5 and MTF Mapper in ``edges/reference/*.json``
  (skipped without the shared data);
* **property** — invariances, uncertainty, round trips, bad input.

Targets: median MTF50 error ≤ 0.3 %, worst ≤ 2 % at
SNR ≥ 50, |SFR error| ≤ 0.01 up to Nyquist (SNR = step/σ_noise; the edges
here step 0.6 of the 0..1 range, so 1 % noise is SNR 60). Two methods:

* ``method="iso"`` (default) is sfrmat5 bit for bit. It meets the targets
  noise-free; with noise its error is the noise itself (at SNR 60 median
  0.4–0.8 %, worst 2.8–4.7 % for 100–400-row ROIs), checked against the
  bootstrap uncertainty.
* ``method="accurate"`` (binning correction, adaptive LSF window, exact
  derivative correction, refined edge fit) is unbiased to 0.03 % noise-free
  and meets the MTF50 targets at SNR 60 from **300 rows** (× 128 px) on.
  |SFR error| ≤ 0.01 holds noise-free and up to 0.25 % noise (SNR 240)
  from 200 rows, but not at SNR 60 at any practical size: the SFR's own
  noise, ≈ 2πf·(σ/step)·√(L/2R) for an LSF kept over L px and R rows,
  puts the largest |ΔSFR| of a sweep at ≈ 0.03 on 300–400 rows, falling
  as 1/√R (0.01 would take ≈ 2700 rows).

``benchmarks/sfr_accuracy.py`` measures the whole sweep for both methods;
``pytest -m slow -s`` prints it for the ROIs the tests use.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from tests.helpers import data_file

from calibration.sfr import edge as sfr_edge
from calibration.sfr.esfr import SfrError, SfrResult, lp_per_mm, measure_sfr, measure_sfr_bayer
from calibration.sfr.synthetic import edge_mtf, mtf50_of, render_slanted_edge
from isp.errors import IspError

SIGMAS = (0.5, 1.0, 2.0)
ANGLES = (2.0, 3.5, 5.0, 7.0, 9.0, 10.5, 12.0)  # avoids 14.04° and 26.57°
ROI = (100, 128)
LOW, HIGH = 0.2, 0.8


def quantise(img: np.ndarray, bits: int | None) -> np.ndarray:
    if bits is None:
        return img
    top = 2**bits - 1
    return np.round(np.clip(img, 0.0, 1.0) * top).astype(np.uint8 if bits == 8 else np.uint16)


def sfr_error(r: SfrResult, sigma: float, angle: float) -> float:
    """Largest |measured − true| SFR up to Nyquist (0.5 cycles/pixel)."""
    m = r.freq <= 0.5
    return float(np.abs(r.sfr[m] - edge_mtf(r.freq[m], sigma, angle)).max())


def edge(sigma=1.0, angle=5.0, shape=ROI, **kw) -> np.ndarray:
    return render_slanted_edge(shape, angle, sigma, low=kw.pop("low", LOW), high=kw.pop("high", HIGH), **kw)


# ------------------------------------------------------------------------------------ analytic


@pytest.mark.property
def test_renderer_is_exact():
    """analytic: the closed-form pixel integral equals ×64 supersampling (< 1e-4)."""
    from scipy.special import ndtr

    h, w, th, s = 12, 24, 7.0, 0.5
    img = render_slanted_edge((h, w), th, s, low=0.0, high=1.0)
    ss = 64
    yy, xx = np.mgrid[0 : h * ss, 0 : w * ss]
    x, y = (xx + 0.5) / ss - 0.5, (yy + 0.5) / ss - 0.5
    t = math.radians(th)
    d = (x - (w - 1) / 2) * math.cos(t) - (y - (h - 1) / 2) * math.sin(t)
    ref = ndtr(d / s).reshape(h, ss, w, ss).mean(axis=(1, 3))
    assert np.abs(img - ref).max() < 1e-4


@pytest.mark.published
def test_reference_truth_includes_the_pixel_aperture():
    """analytic: the README's "true MTF50 0.18007 cy/px" of a 5°, σ = 1 px edge
    is the Gaussian × pixel-sinc MTF (0.17996–0.18002 here, depending on
    whether the aperture is taken along the normal); the Gaussian alone
    (0.18739) is 4 % away. Our measurement lands within the tools' ±0.25 %."""
    assert mtf50_of(1.0, 5.0) == pytest.approx(0.18007, rel=1e-3)
    assert mtf50_of(1.0, pixel_aperture=False) == pytest.approx(0.18739, rel=1e-4)
    assert abs(mtf50_of(1.0, pixel_aperture=False) / 0.18007 - 1) > 0.03
    r = measure_sfr(edge(1.0, 5.0))
    assert r.mtf50 == pytest.approx(0.18007, rel=0.0025)


def _clean_sweep(bits_list):
    errs, sfr_errs = [], []
    for bits in bits_list:
        for s in SIGMAS:
            for i, a in enumerate(ANGLES):
                # sub-pixel edge positions vary with the case
                img = quantise(edge(s, a, center=((ROI[1] - 1) / 2 + 0.13 * i, (ROI[0] - 1) / 2)), bits)
                r = measure_sfr(img)
                assert r.warnings == (), (s, a, bits, r.warnings)
                errs.append(r.mtf50 / mtf50_of(s, a) - 1)
                sfr_errs.append(sfr_error(r, s, a))
    return np.abs(errs), np.array(sfr_errs)


@pytest.mark.property
@pytest.mark.parametrize("bits", [None, 16, 8], ids=["float", "16bit", "8bit"])
def test_analytic_noise_free_meets_targets(bits):
    """analytic: σ ∈ {0.5, 1, 2} px × angles 2–12°: median MTF50 error ≤ 0.3 %,
    worst ≤ 1 % (issue: 2 %), |SFR error| ≤ 0.01 up to Nyquist.

    The residual is the ¼-px binning (a sinc(f·Δ) the standard leaves in:
    −0.75 % at σ = 0.5) and the LSF window (+0.3 % at σ = 2 on 128 px)."""
    err, sfr_err = _clean_sweep([bits])
    assert np.median(err) <= 0.003
    assert err.max() <= 0.01
    assert sfr_err.max() <= 0.01


def _noisy_case(s, a, snr, bits, rng, boot=30):
    clean = edge(s, a)
    noisy = clean + rng.normal(0.0, (HIGH - LOW) / snr, clean.shape)
    r = measure_sfr(quantise(noisy, bits), bootstrap=boot, rng=rng)
    return r, r.mtf50 / mtf50_of(s, a) - 1, measure_sfr(clean).mtf50 / mtf50_of(s, a) - 1


@pytest.mark.property
@pytest.mark.parametrize("snr", [50, 100])
def test_analytic_noisy_errors_are_within_the_bootstrap_uncertainty(snr):
    """analytic: at SNR 50 and 100 (step/σ, 8-bit) every MTF50 error is within
    the noise-free bias plus 4 bootstrap standard deviations, and the SFR
    error up to Nyquist stays below 0.1."""
    rng = np.random.default_rng(snr)
    for s in SIGMAS:
        for a in (3.0, 8.0):
            r, err, bias = _noisy_case(s, a, snr, 8, rng)
            assert abs(err) <= abs(bias) + 4.0 * r.mtf50_std / r.mtf50, (s, a, err, r.mtf50_std)
            assert sfr_error(r, s, a) < 0.1


@pytest.mark.property
@pytest.mark.slow
def test_analytic_full_sweep_report():
    """analytic: the whole sweep — σ {0.5, 1, 2} × angles 2–12° × noise
    {0, SNR 100, SNR 50} × {float, 16-bit, 8-bit}; prints the table of the
    report; asserts the noise-free targets and the bootstrap consistency."""
    rng = np.random.default_rng(7)
    rows = []
    for snr in (None, 100, 50):
        for bits in (None, 16, 8):
            errs, sfr_errs = [], []
            for s in SIGMAS:
                for a in ANGLES:
                    clean = edge(s, a)
                    img = clean if snr is None else clean + rng.normal(0, (HIGH - LOW) / snr, clean.shape)
                    r = measure_sfr(quantise(img, bits))
                    errs.append(abs(r.mtf50 / mtf50_of(s, a) - 1))
                    sfr_errs.append(sfr_error(r, s, a))
            rows.append((snr, bits, np.median(errs), np.max(errs), np.max(sfr_errs)))
    print("\nSNR   bits   median|dMTF50|  worst|dMTF50|  max|dSFR|<=Nyq")
    for snr, bits, med, worst, se in rows:
        print(f"{snr or 'inf':>5} {bits or 'float':>6} {100 * med:12.3f} % {100 * worst:12.3f} % {se:12.4f}")
        if snr is None:
            assert med <= 0.003 and worst <= 0.01 and se <= 0.01


def _accurate_noise_free(bits):
    errs, sfr_errs, raw = [], [], []
    for s in SIGMAS:
        for i, a in enumerate(ANGLES):
            img = quantise(edge(s, a, center=((ROI[1] - 1) / 2 + 0.13 * i, (ROI[0] - 1) / 2)), bits)
            r = measure_sfr(img, method="accurate")
            errs.append(r.mtf50 / mtf50_of(s, a) - 1)
            sfr_errs.append(sfr_error(r, s, a))
            raw.append(measure_sfr(img, method="accurate", bin_correction=False))
    return np.abs(errs), np.array(sfr_errs), raw


@pytest.mark.property
@pytest.mark.parametrize("bits", [None, 16], ids=["float", "16bit"])
def test_analytic_binning_correction_removes_the_noise_free_bias(bits):
    """analytic: noise-free, σ ∈ {0.5, 1, 2} px × angles 2–12°, 100×128 px:
    ``method="accurate"`` has median and worst |ΔMTF50| ≤ 0.1 % (0.016 % and
    0.033 % here) and |ΔSFR| ≤ 0.002 up to Nyquist; without the binning
    correction the ¼-px bins take 0.6 % off MTF50 at σ = 0.5 px, and the
    correction is the measured ``1/binning_transfer``, 1/sinc(fΔ) within
    3e-4 (91 rows of a 5° edge hold 7.96 phase cycles, not exactly uniform).
    (8-bit codes of a noise-free edge add a deterministic ±0.1–0.25 %:
    quantisation without dither, the same in both methods.)"""
    err, sfr_err, raw = _accurate_noise_free(bits)
    assert np.median(err) <= 0.001 and err.max() <= 0.001, err
    assert sfr_err.max() <= 0.002
    sharp = [abs(r.mtf50 / mtf50_of(0.5, a) - 1) for r, a in zip(raw[: len(ANGLES)], ANGLES)]
    assert np.median(sharp) >= 0.005
    img = edge(1.0, 5.0)
    on, off = measure_sfr(img, method="accurate"), measure_sfr(img, method="accurate", bin_correction=False)
    m = on.freq <= 0.5
    delta = on.esf_step_px
    np.testing.assert_allclose(on.sfr[m] / off.sfr[m], 1 / np.sinc(on.freq[m] * delta), rtol=3e-4)


@pytest.mark.property
def test_binning_transfer_is_the_mean_phasor_of_the_offsets():
    """analytic: uniform offsets → sinc(fΔ); m equally spaced offsets → the
    Dirichlet kernel sin(πfΔ)/(m·sin(πfΔ/m)); one offset → 1 (a pure shift)."""
    os_, nn = 4, 400
    uc = (np.arange(nn) - nn / 2 + 0.5) / os_
    nu = np.arange(201) / nn
    m = 3
    u = uc[:, None] + ((np.arange(m) + 0.5) / m - 0.5)[None, :] / os_
    h = sfr_edge.binning_transfer(u, uc, os_, 201)
    np.testing.assert_allclose(h, np.abs(np.sinc(nu) / np.sinc(nu / m)), atol=1e-6)
    h1 = sfr_edge.binning_transfer(uc + 0.1 / os_, uc, os_, 201)
    np.testing.assert_allclose(h1, 1.0, atol=1e-12)
    hu = sfr_edge.binning_transfer(np.linspace(uc[0] - 0.125, uc[-1] + 0.125, 64001), uc, os_, 201)
    np.testing.assert_allclose(hu, np.sinc(nu) / np.sinc(nu / 160), atol=1e-7)  # 160 offsets per bin
    assert sfr_edge.binning_correction(u, uc, os_, 201).max() <= sfr_edge.MAX_DERIVATIVE_CORRECTION


@pytest.mark.property
@pytest.mark.parametrize("radius, amount", [(1.0, 1.0), (2.0, 0.8), (3.0, 0.6)])
def test_analytic_sharpened_edge_keeps_its_halo(radius, amount):
    """analytic: an unsharp-masked edge, ``I + k·(I − G_r ⊛ I)`` (σ = 1 px,
    5°, 200×128 px, noise-free), whose MTF is the edge's times
    ``1 + k·(1 − exp(−2π²r²f²))``: ``method="accurate"`` keeps the halo
    (its lobes stand above 1 % of the LSF peak, so the adaptive window's
    core covers them, and its faint tail gets the long taper): MTF50 within
    0.2 % (a short taper there reads the 3 px halo 0.28 % high), |ΔSFR| ≤
    0.005 up to Nyquist."""
    from scipy.ndimage import gaussian_filter

    big = edge(1.0, 5.0, shape=(300, 228))
    roi = (big + amount * (big - gaussian_filter(big, radius, mode="nearest")))[50:250, 50:178]
    r = measure_sfr(roi, method="accurate")

    def truth(f):
        return edge_mtf(f, 1.0, 5.0) * (1 + amount * (1 - np.exp(-2 * np.pi**2 * radius**2 * f**2)))

    f = np.linspace(0, 1, 100001)
    t50 = f[np.argmax(truth(f) < 0.5)]
    assert r.mtf50 == pytest.approx(t50, rel=0.002)
    m = r.freq <= 0.5
    assert np.abs(r.sfr[m] - truth(r.freq[m])).max() <= 0.005


ACCURATE_ROWS = 300  # the smallest ROI (× 128 px) on which method="accurate" meets the targets at SNR 60


def _noisy_sweep(rows, sigmas, angles, noise, nreal, seed, method="accurate"):
    """(|ΔMTF50|, max |ΔSFR| ≤ Nyquist) over σ × angle × realisations × {8, 16} bits."""
    rng = np.random.default_rng(seed)
    errs, sfr_errs = [], []
    for s in sigmas:
        for i, a in enumerate(angles):
            clean = edge(s, a, shape=(rows, 128), center=(63.5 + 0.13 * i, (rows - 1) / 2))
            for _ in range(nreal if noise else 1):
                noisy = clean + rng.normal(0.0, noise, clean.shape) if noise else clean
                for bits in (8, 16):
                    r = measure_sfr(quantise(noisy, bits), method=method)
                    errs.append(abs(r.mtf50 / mtf50_of(s, a) - 1))
                    sfr_errs.append(sfr_error(r, s, a))
    return np.array(errs), np.array(sfr_errs)


@pytest.mark.property
def test_analytic_accurate_meets_the_targets_at_snr_60_on_300_rows():
    """analytic: the issue's MTF50 targets at SNR 60 (1 % noise on a 0.6
    step), ``method="accurate"``, **300×128 px ROIs** — the smallest that
    meets them (benchmarks/sfr_accuracy.py: median 0.22 %, worst 1.1 % over
    the full sweep; 200 rows: median 0.32 %): σ ∈ {0.5, 1, 1.5, 2} px ×
    angles {2, 5, 9, 12}° × 3 noise images × 8/16 bit: median |ΔMTF50|
    ≤ 0.3 %, worst ≤ 2 %. |ΔSFR| up to Nyquist is the noise floor there
    (≈ 0.03, not the issue's 0.01 — see the module docstring): ≤ 0.05."""
    err, sfr_err = _noisy_sweep(ACCURATE_ROWS, (0.5, 1.0, 1.5, 2.0), (2.0, 5.0, 9.0, 12.0), 0.01, 3, 2)
    assert np.median(err) <= 0.003, np.median(err)
    assert err.max() <= 0.02, err.max()
    assert sfr_err.max() <= 0.05


@pytest.mark.property
@pytest.mark.slow
def test_analytic_accurate_full_sweep_on_300_rows(capsys):
    """analytic: the issue's sweep at 300×128 px, ``method="accurate"``:
    σ ∈ {0.5, 1, 1.5, 2} px × angles {2, 4, 5, 7, 9, 11, 12}° × noise
    {0, 0.25, 0.5, 1} % (SNR ∞, 240, 120, 60) × 3 realisations × 8/16 bit.
    At *every* noise level: median |ΔMTF50| ≤ 0.3 %, worst ≤ 2 %; |ΔSFR| ≤ 0.01
    up to Nyquist noise-free and at SNR 240 (at SNR 120 and 60 it is the
    noise floor, ≤ 0.05). Prints the table."""
    angles = (2.0, 4.0, 5.0, 7.0, 9.0, 11.0, 12.0)
    lines = ["\nmethod=accurate, 300x128 px   SNR   median|dMTF50|  worst   max|dSFR|"]
    for k, noise in enumerate((0.0, 0.0025, 0.005, 0.01)):
        err, sfr_err = _noisy_sweep(ACCURATE_ROWS, (0.5, 1.0, 1.5, 2.0), angles, noise, 3, 10 + k)
        snr = "inf" if noise == 0 else f"{0.6 / noise:.0f}"
        med, worst = 100 * np.median(err), 100 * err.max()
        lines.append(f"{'':30s}{snr:>5s} {med:12.3f} % {worst:6.2f} % {sfr_err.max():9.4f}")
        assert np.median(err) <= 0.003 and err.max() <= 0.02, (noise, np.median(err), err.max())
        assert sfr_err.max() <= (0.01 if noise <= 0.0025 else 0.05), (noise, sfr_err.max())
    with capsys.disabled():
        print("\n".join(lines))


# ------------------------------------------------------------------------------------ reference


def _reference(name):
    import tifffile

    img = tifffile.imread(data_file("edges", f"{name}.tif"))
    ref = json.loads(data_file("edges", "reference", f"{name}.json").read_text())
    return img, ref


def _curve_diff(r: SfrResult, tool: dict) -> tuple[float, float]:
    f = np.asarray(tool["freq_cy_per_px"])
    s = np.asarray(tool["sfr"])
    m = f <= 0.5
    d = np.interp(f[m], r.freq, r.sfr) - s[m]
    return float(np.sqrt(np.mean(d * d))), float(np.abs(d).max())


# The README says sfrmat5 ran with an order-5 fit; the stored curves are
# reproduced to 1e-15 by order 1 for the vertical edge and order 5 for the
# horizontal one (checked against a line-by-line port of sfrmat5).
SFRMAT5_ORDER = {"sfrmat3_v_edge_mono": 1, "sfrmat3_h_edge_mono": 5}


@pytest.mark.published
@pytest.mark.parametrize("name", sorted(SFRMAT5_ORDER))
def test_reference_sfrmat5_reproduced_exactly(name):
    """reference: sfrmat5's stored SFR and MTF50 reproduced to 1e-9 (whole
    image as ROI, Tukey window, its edge-fit order); SFRA to 1e-6 (the stored
    value interpolates the end point at 0.5 cy/px a little differently)."""
    img, ref = _reference(name)
    r = measure_sfr(img, edge_fit_order=SFRMAT5_ORDER[name], method="iso")
    t = ref["sfrmat5"]
    assert r.freq.size == len(t["freq_cy_per_px"])
    np.testing.assert_allclose(r.freq, t["freq_cy_per_px"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(r.sfr, t["sfr"], rtol=0, atol=1e-9)
    assert r.mtf50 == pytest.approx(t["mtf50"], abs=1e-9)
    assert r.sfra == pytest.approx(t["sfra_to_nyquist"], abs=1e-6)


@pytest.mark.published
@pytest.mark.parametrize("name", sorted(SFRMAT5_ORDER))
def test_reference_tools_order5(name, capsys):
    """reference: with the order-5 fit of the README, MTF50 within 2 % of
    sfrmat5 and SFR within 0.02 RMS of its curve up to Nyquist; sfrmat3 and
    MTF Mapper (which differ from sfrmat5 by up to 1 % and 1.2 % here) within
    the 3.5 % the tools differ by on real edges."""
    img, ref = _reference(name)
    r = measure_sfr(img, edge_fit_order=5, method="iso")
    lines = []
    for tool, lim in (("sfrmat5", 0.02), ("sfrmat3", 0.02), ("mtf_mapper_linear", 0.035)):
        t = ref[tool]
        rms, _ = _curve_diff(r, t)
        d50 = r.mtf50 / t["mtf50"] - 1
        dA = r.sfra / t["sfra_to_nyquist"] - 1
        lines.append(f"{name} {tool:18s} dMTF50 {100 * d50:+.2f} %  dSFRA {100 * dA:+.2f} %  rms {rms:.4f}")
        assert abs(d50) <= lim, (tool, d50)
        assert rms <= 0.02 if tool == "sfrmat5" else rms <= 0.03
    with capsys.disabled():
        print("\n" + "\n".join(lines))


@pytest.mark.published
@pytest.mark.parametrize("name", sorted(SFRMAT5_ORDER))
def test_reference_accurate_method_stays_near_the_tools(name):
    """reference: ``method="accurate"`` on the real edges (sfrmat5's fit
    order): MTF50 within 2 % of sfrmat5 (+0.8 % and +1.8 % here; each
    departure alone: binning +0.3 %, adaptive window +0.5/+1.0 %, exact
    derivative correction −0.1 %, edge refinement +0.0/+0.8 %) and within
    1 % of MTF Mapper (−0.3 %, −0.4 %), which does not apply a
    record-length window either; SFR within 0.01 RMS of sfrmat5 up to
    Nyquist."""
    img, ref = _reference(name)
    r = measure_sfr(img, edge_fit_order=SFRMAT5_ORDER[name], method="accurate")
    assert abs(r.mtf50 / ref["sfrmat5"]["mtf50"] - 1) <= 0.02
    assert abs(r.mtf50 / ref["mtf_mapper_linear"]["mtf50"] - 1) <= 0.01
    assert _curve_diff(r, ref["sfrmat5"])[0] <= 0.01
    assert r.settings["method"] == "accurate" and r.warnings == ()


# ------------------------------------------------------------------------------------ property


def _same(a: SfrResult, b: SfrResult, tol: float):
    n = min(a.freq.size, b.freq.size)
    np.testing.assert_allclose(a.freq[:n], b.freq[:n], rtol=1e-6)
    m = a.freq[:n] <= 0.5
    assert np.abs(a.sfr[:n][m] - b.sfr[:n][m]).max() <= tol
    assert a.mtf50 == pytest.approx(b.mtf50, rel=max(tol, 1e-9))


@pytest.mark.property
@pytest.mark.parametrize("method", ["iso", "accurate"])
def test_polarity_inversion_is_exact(method):
    """property: 1 − image (bright→dark) gives the identical SFR."""
    img = edge(1.0, 6.0) + np.random.default_rng(0).normal(0, 0.005, ROI)
    a, b = measure_sfr(img, method=method), measure_sfr(1.0 - img, method=method)
    assert a.polarity == "dark_to_bright" and b.polarity == "bright_to_dark"
    _same(a, b, 1e-12)


@pytest.mark.property
@pytest.mark.parametrize("method, tol", [("iso", 0.003), ("accurate", 1e-4)])
def test_mirrored_edge_gives_the_same_sfr(method, tol):
    """property: a left–right mirrored edge (other polarity and slope sign):
    same SFR within 0.003 (sfrmat's row trimming and window are not mirror
    symmetric); within 1e-4 with the accurate method, whose window follows
    the edge."""
    img = edge(1.0, 6.0)
    _same(measure_sfr(img, method=method), measure_sfr(img[:, ::-1], method=method), tol)


@pytest.mark.property
def test_horizontal_edge_is_rotated_back_exactly():
    """property: the edge turned 90° is measured as the original (sfrmat's
    rot90), and its transpose (a mirror image) within 0.003."""
    clean = edge(1.0, 6.0)
    img = clean + np.random.default_rng(1).normal(0, 0.005, ROI)
    a = measure_sfr(img)
    b = measure_sfr(np.rot90(img, -1))
    assert b.orientation == "horizontal" and a.orientation == "vertical"
    _same(a, b, 1e-12)
    _same(measure_sfr(clean), measure_sfr(clean.T), 0.003)
    assert b.angle_deg == pytest.approx(a.angle_deg)


@pytest.mark.property
def test_scale_and_offset_do_not_change_the_sfr():
    """property: a·image + b (a > 0): identical SFR; contrast follows."""
    img = edge(1.5, 4.0)
    a, b = measure_sfr(img), measure_sfr(3.7 * img + 12.0)
    _same(a, b, 1e-10)
    assert a.contrast == pytest.approx(0.6, abs=1e-3)
    assert b.contrast == pytest.approx((3.7 * 0.6) / (3.7 + 24.0), abs=1e-3)


@pytest.mark.property
def test_dtypes_agree():
    """property: float32/float64/uint16 of the same values give the same SFR."""
    codes = quantise(edge(1.0, 5.0), 16)
    r16 = measure_sfr(codes)
    _same(r16, measure_sfr(codes.astype(np.float64)), 1e-12)
    _same(r16, measure_sfr(codes.astype(np.float32)), 1e-6)
    assert r16.esf.dtype == np.float64


@pytest.mark.property
def test_angle_and_edge_fit_are_recovered():
    """property: angle and edge line of the rendering (centre (63.5, 49.5))."""
    r = measure_sfr(edge(1.0, 7.0))
    assert r.angle_deg == pytest.approx(7.0, abs=0.01)
    assert r.edge_fit_linear[1] == pytest.approx(math.tan(math.radians(7.0)), abs=2e-4)
    assert np.polynomial.polynomial.polyval(49.5, r.edge_fit) == pytest.approx(63.5, abs=0.05)
    assert r.edge_fit.size == 2 and measure_sfr(edge(1.0, 7.0), edge_fit_order=3).edge_fit.size == 4


@pytest.mark.property
def test_box_measures_the_roi_in_image_coordinates():
    """property: ``box`` = cropping, with the edge fit in image coordinates."""
    img = np.full((300, 400), 0.2)
    img[100:200, 150:278] = edge(1.0, 5.0)
    r = measure_sfr(img, box=(150, 100, 128, 100))
    c = measure_sfr(img[100:200, 150:278])
    _same(r, c, 1e-12)
    assert r.edge_fit[0] + r.edge_fit[1] * 149.5 == pytest.approx(150 + 63.5, abs=0.05)


@pytest.mark.property
def test_srgb_encoding_is_linearised():
    """property: sRGB-encoded 16-bit codes measured with encoding="srgb"
    agree with the linear edge; read as linear, the tone curve biases MTF50
    by 1.6 % (8-bit sRGB quantisation alone adds 0.8 %)."""
    lin = edge(1.0, 5.0)
    enc = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
    codes = quantise(enc, 16)
    ref = measure_sfr(lin)
    assert measure_sfr(codes, encoding="srgb").mtf50 == pytest.approx(ref.mtf50, rel=1e-4)
    assert measure_sfr(enc, encoding="srgb").mtf50 == pytest.approx(ref.mtf50, rel=1e-9)
    assert abs(measure_sfr(codes).mtf50 / ref.mtf50 - 1) > 0.01


@pytest.mark.property
def test_three_channels_need_a_channel():
    """property: RGB input: channel index or luminance; grey edge → same SFR."""
    g = edge(1.0, 5.0)
    rgb = np.dstack([g, g, g])
    r = measure_sfr(rgb, channel="luminance")
    _same(r, measure_sfr(g), 1e-9)
    _same(measure_sfr(rgb, channel=2), measure_sfr(g), 1e-12)


@pytest.mark.property
def test_metrics_units_and_serialisation():
    """property: mtf_at, Nyquist values, SFRA normalisation, lp/mm, to_dict."""
    r = measure_sfr(edge(1.0, 5.0), pixel_pitch_um=1.4)
    assert r.mtf_at(r.freq[7]) == pytest.approx(r.sfr[7])
    assert r.mtf_nyquist == pytest.approx(r.mtf_at(0.5)) and r.mtf_nyquist_half == pytest.approx(r.mtf_at(0.25))
    assert math.isnan(r.mtf_at(5.0))
    # SFRA of the true curve, in cycles/pixel (a perfect system: 0.5)
    f = np.linspace(0, 0.5, 2001)
    assert r.sfra == pytest.approx(np.trapezoid(edge_mtf(f, 1.0, 5.0), f), rel=0.005)
    assert r.lp_per_mm(r.mtf50) == pytest.approx(r.mtf50 * 1000 / 1.4)
    assert lp_per_mm(0.25, 2.0) == 125.0
    d = json.loads(json.dumps(r.to_dict(), allow_nan=False))
    assert d["mtf50_cy_per_px"] == pytest.approx(r.mtf50) and len(d["sfr"]) == r.sfr.size
    with pytest.raises(SfrError, match="pixel pitch"):
        measure_sfr(edge()).lp_per_mm()


@pytest.mark.property
def test_esf_step_and_noise_estimate():
    """property: ESF bins ¼ px along the rows (cos θ / 4 along the normal);
    noise = the added σ; contrast of the plateaus."""
    rng = np.random.default_rng(3)
    r = measure_sfr(edge(1.0, 8.0) + rng.normal(0, 0.01, ROI))
    assert r.esf_step_px == pytest.approx(math.cos(math.radians(8.0)) / 4, rel=1e-3)
    assert r.esf.size == 4 * ROI[1] == r.lsf.size
    assert r.noise == pytest.approx(0.01, rel=0.1)
    assert r.contrast == pytest.approx(0.6, abs=0.01)


@pytest.mark.property
@pytest.mark.parametrize("method", ["iso", "accurate"])
def test_bootstrap_std_matches_the_spread_over_noise_realisations(method):
    """property: on noisy edges (σ = 1 px, SNR 60) the bootstrap std of MTF50
    and SFRA is within a factor 2 of the empirical std over 30 independent
    noise realisations, in both methods (the bootstrap repeats the whole
    measurement, adaptive window and edge refinement included; over 50
    edges per σ ∈ {0.5, 1, 2} px on 100 and 300 rows the accurate method's
    MTF50 ratio was 0.90–1.09 and its ±1.96 std intervals held 92–98 %,
    as the iso method's: 0.89–1.11, 90–98 %)."""
    rng = np.random.default_rng(11)
    clean = edge(1.0, 5.0, shape=(100, 100))
    m50, area = [], []
    for _ in range(30):
        r = measure_sfr(clean + rng.normal(0, 0.01, clean.shape), method=method)
        m50.append(r.mtf50)
        area.append(r.sfra)
    emp_m, emp_a = np.std(m50, ddof=1), np.std(area, ddof=1)
    boot = [
        measure_sfr(clean + rng.normal(0, 0.01, clean.shape), bootstrap=60, rng=k, method=method)
        for k in range(3)
    ]
    bm = np.median([b.mtf50_std for b in boot])
    ba = np.median([b.sfra_std for b in boot])
    assert 0.5 <= bm / emp_m <= 2.0, (bm, emp_m)
    assert 0.5 <= ba / emp_a <= 2.0, (ba, emp_a)
    assert boot[0].bootstrap == 60 and measure_sfr(clean).mtf50_std is None


@pytest.mark.property
def test_bootstrap_is_reproducible_with_a_seed():
    """property: the same rng seed gives the same bootstrap std."""
    img = edge(1.0, 5.0) + np.random.default_rng(0).normal(0, 0.01, ROI)
    a = measure_sfr(img, bootstrap=10, rng=5)
    b = measure_sfr(img, bootstrap=10, rng=5)
    assert a.mtf50_std == b.mtf50_std and a.sfra_std == b.sfra_std


@pytest.mark.property
def test_method_presets_and_overrides():
    """property: the default is ``method="accurate"``, the four departures on;
    ``method="iso"`` is ISO 12233 (sfrmat5); an option passed explicitly
    overrides the preset and the settings then say "custom"."""
    img = edge(1.0, 5.0)
    assert measure_sfr(img).settings == measure_sfr(img, method="accurate").settings
    iso = measure_sfr(img, method="iso").settings
    assert iso["method"] == "iso" and iso["bin_correction"] is False and iso["lsf_window"] == "full"
    assert iso["derivative_correction"] == "sfrmat" and iso["refine_edge"] is False
    acc = measure_sfr(img, method="accurate").settings
    assert acc["method"] == "accurate" and acc["bin_correction"] and acc["lsf_window"] == "adaptive"
    assert acc["derivative_correction"] == "exact" and acc["refine_edge"]
    mix = measure_sfr(img, method="accurate", lsf_window="full")
    assert mix.settings["method"] == "custom" and mix.settings["lsf_window"] == "full"
    assert measure_sfr(img, method="iso", bin_correction=True).settings["method"] == "custom"
    assert json.loads(json.dumps(mix.to_dict()))["settings"]["bin_correction"] is True


# ------------------------------------------------------------------------------------ Bayer


def _mosaic_edge(sigma, horizontal=False):
    shape = (200, 128) if not horizontal else (128, 200)
    return render_slanted_edge(shape, 5.0, sigma, low=LOW, high=HIGH, horizontal=horizontal)


@pytest.mark.property
@pytest.mark.parametrize("method", ["iso", "accurate"])
@pytest.mark.parametrize("horizontal", [False, True], ids=["vertical", "horizontal"])
@pytest.mark.parametrize("sigma", [0.5, 1.0, 2.0])
def test_bayer_planes_agree_with_full_resolution(sigma, horizontal, method):
    """property: a grey edge in a mosaic: every CFA plane (frequencies in
    cycles per sensor pixel) and the green quincunx agree with the
    full-resolution SFR within 0.015 up to Nyquist and 1 % in MTF50, and the
    edge fit comes back in sensor coordinates — in both methods."""
    img = _mosaic_edge(sigma, horizontal)
    full = measure_sfr(img, method=method)
    planes = measure_sfr_bayer(img, "RGGB", "all", method=method)
    assert set(planes) == {"R", "Gr", "Gb", "B"}
    green = measure_sfr_bayer(img, "GRBG", "G", mode="green", method=method)
    assert green.settings["method"] == method
    for name, r in list(planes.items()) + [("green", green)]:
        m = r.freq <= 0.5
        d = np.abs(r.sfr[m] - np.interp(r.freq[m], full.freq, full.sfr)).max()
        assert d <= 0.015, (name, d)
        assert r.mtf50 == pytest.approx(full.mtf50, rel=0.01), name
        assert r.orientation == full.orientation
        np.testing.assert_allclose(r.edge_fit_linear, full.edge_fit_linear, atol=0.02)
        assert r.settings["freq_unit"] == "cycles/sensor pixel"


@pytest.mark.property
def test_bayer_green_plane_mean_and_options():
    """property: plane-mode "G" = mean of Gr and Gb; CFA as string or enum;
    box shifts the CFA phase; unknown names list the valid ones."""
    from isp.frame import CFA

    img = _mosaic_edge(1.0)
    g = measure_sfr_bayer(img, CFA.RGGB, "G")
    gr = measure_sfr_bayer(img, "rggb", "Gr")
    gb = measure_sfr_bayer(img, "RGGB", "Gb")
    np.testing.assert_allclose(g.sfr, 0.5 * (gr.sfr + np.interp(gr.freq, gb.freq, gb.sfr)), atol=1e-12)
    big = np.full((260, 180), 0.2)
    big[31:231, 27:155] = img
    # a box at odd offsets: the ROI starts on the other CFA phase
    r = measure_sfr_bayer(big, "RGGB", "R", box=(27, 31, 128, 200))
    ref = measure_sfr_bayer(img, CFA.RGGB.shifted(31, 27), "R")
    _same(r, ref, 1e-12)
    with pytest.raises(SfrError, match="valid: R, Gr, Gb, B, G, all"):
        measure_sfr_bayer(img, "RGGB", "Y")
    with pytest.raises(SfrError, match="valid: plane, green"):
        measure_sfr_bayer(img, "RGGB", "G", mode="quincunx")
    with pytest.raises(SfrError, match="unknown CFA"):
        measure_sfr_bayer(img, "RGBW", "G")
    with pytest.raises(SfrError, match="'G' only"):
        measure_sfr_bayer(img, "RGGB", "R", mode="green")


# ------------------------------------------------------------------------------------ bad input


@pytest.mark.property
def test_sfr_error_is_an_isp_error_and_a_value_error():
    """property: one exception root."""
    assert issubclass(SfrError, IspError) and issubclass(SfrError, ValueError)


@pytest.mark.property
def test_edge_too_short():
    """property: < 8 rows along the edge: error; < 20: warning."""
    with pytest.raises(SfrError, match="edge too short"):
        measure_sfr(edge(shape=(6, 60)))
    r = measure_sfr(edge(1.0, 8.0, shape=(15, 60)))
    assert any("short edge" in w for w in r.warnings)


@pytest.mark.property
def test_angle_checks():
    """property: no whole phase cycle (≈ 0°) and ≈ 45° or 26.57° (too few
    phases): errors; below 2°, above 40°, near 14°/26.6°: warnings."""
    with pytest.raises(SfrError, match="phase cycle"):
        measure_sfr(edge(1.0, 1.0, shape=(40, 60)))
    with pytest.raises(SfrError, match="phase cycle"):
        measure_sfr(edge(1.0, 0.0))
    with pytest.raises(SfrError, match="too few phases"):
        measure_sfr(edge(1.0, 45.0, shape=(100, 100)))
    with pytest.raises(SfrError, match="too few phases"):
        measure_sfr(edge(1.0, math.degrees(math.atan(0.5)), shape=(100, 100)))
    cases = {1.5: "below 2", 42.0: "near 45", 14.5: "near 14.0", 26.0: "near 26.6"}
    for angle, msg in cases.items():
        r = measure_sfr(edge(1.0, angle, shape=(200, 160)))
        assert any(msg in w for w in r.warnings), (angle, r.warnings)


@pytest.mark.property
def test_low_contrast_warns():
    """property: contrast below 20 %: warning."""
    r = measure_sfr(edge(1.0, 5.0, low=0.5, high=0.6))
    assert r.contrast == pytest.approx(0.0909, abs=1e-3)
    assert any("low contrast" in w for w in r.warnings)


@pytest.mark.property
def test_clipped_plateau_warns():
    """property: a plateau at the maximum code (8-bit 255, or ``saturation``
    for float data): warning."""
    codes = quantise(edge(1.0, 5.0, low=0.2, high=1.3), 8)
    assert any("clipped" in w and "255" in w for w in measure_sfr(codes).warnings)
    flt = np.minimum(edge(1.0, 5.0, low=0.2, high=1.3), 1.0)
    assert not any("clipped" in w for w in measure_sfr(flt).warnings)
    assert any("clipped" in w for w in measure_sfr(flt, saturation=1.0).warnings)


@pytest.mark.property
def test_uniform_and_edgeless_images_raise():
    """property: a uniform ROI, or noise without an edge: errors."""
    with pytest.raises(SfrError, match="uniform ROI"):
        measure_sfr(np.full((50, 50), 0.3))
    with pytest.raises(SfrError, match="no edge"):
        measure_sfr(0.5 + np.random.default_rng(0).normal(0, 0.01, (50, 50)))


@pytest.mark.property
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_pixels_raise(bad):
    """property: NaN/inf pixels: error naming the first one (rows are not
    masked: that would break the phase sampling)."""
    img = edge()
    img[10, 20] = bad
    with pytest.raises(SfrError, match=r"NaN/inf pixel\(s\) \(first at row, col \(10, 20\)\)"):
        measure_sfr(img)


@pytest.mark.property
def test_box_outside_the_image_raises():
    """property: a box reaching outside the image: error with the box."""
    with pytest.raises(SfrError, match=r"box \(x=50, y=50, w=60, h=40\) lies outside the 100×100"):
        measure_sfr(edge(shape=(100, 100)), box=(50, 50, 60, 40))
    with pytest.raises(SfrError, match="box must be"):
        measure_sfr(edge(), box=(1, 2))


@pytest.mark.property
def test_edge_near_the_border_warns():
    """property: an edge too close to the ROI border: warning."""
    r = measure_sfr(edge(1.0, 5.0, center=(5.0, 50.0)))
    assert any("ROI border" in w for w in r.warnings)


@pytest.mark.property
@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"edge_fit_order": 7}, "edge_fit_order must be an integer 1–5"),
        ({"window": "hann"}, "valid: tukey, hamming"),
        ({"oversampling": 0}, "oversampling"),
        ({"encoding": "gamma"}, "valid: linear, srgb"),
        ({"bootstrap": -1}, "bootstrap"),
        ({"channel": 1}, "single-channel"),
        ({"method": "fast"}, "valid: iso, accurate"),
        ({"lsf_window": "hann"}, "valid: full, adaptive"),
        ({"bin_correction": "yes"}, "bin_correction must be True or False"),
        ({"refine_edge": 1}, "refine_edge must be True or False"),
        ({"derivative_correction": "fir"}, "valid: sfrmat, exact"),
    ],
)
def test_bad_options_raise(kwargs, match):
    """property: wrong options name the valid ones."""
    with pytest.raises(SfrError, match=match):
        measure_sfr(edge(), **kwargs)


@pytest.mark.property
def test_bad_arrays_raise():
    """property: wrong shapes and dtypes."""
    with pytest.raises(SfrError, match="3-channel roi"):
        measure_sfr(np.dstack([edge()] * 3))
    with pytest.raises(SfrError, match="valid: 0, 1, 2, 'luminance'"):
        measure_sfr(np.dstack([edge()] * 3), channel="green")
    with pytest.raises(SfrError, match="dtype bool"):
        measure_sfr(np.zeros((50, 50), bool))
    with pytest.raises(SfrError, match=r"\(H, W\) or \(H, W, 3\)"):
        measure_sfr(np.zeros((4, 50, 50)))


@pytest.mark.property
@pytest.mark.parametrize("shape", [(32, 42), (150, 100)])
def test_the_noise_estimate_is_unbiased_on_short_rois(shape):
    """The pixel noise is read from neighbouring rows' differences on the
    plateaus: on a 32-row ROI, where an ESF bin holds a handful of samples
    and residuals about the binned ESF read low by the bin's own noise, the
    mean estimate over 40 draws is the added σ within 3 %."""
    rng = np.random.default_rng(11)
    clean = render_slanted_edge(shape, 5.0, 1.0)
    est = [measure_sfr(clean + rng.normal(0, 0.005, shape)).noise for _ in range(40)]
    assert np.mean(est) == pytest.approx(0.005, rel=0.03)


@pytest.mark.property
def test_the_core_helpers_equal_their_direct_forms():
    """parity, bit for bit: the edge-finding windows read from the table of
    Tukey windows against sfrmat5's ``tukey2`` formula, and the median and
    the Horner sums against numpy's."""
    rng = np.random.default_rng(2)
    for m in (9, 64, 117):
        mid = np.concatenate([rng.uniform(-m, 2 * m, 40), [0.0, m / 2.0, (m + 1) / 2.0, m]])[:, None]
        i = np.arange(1, m + 1, dtype=np.float64)[None, :]
        n2 = sfr_edge.mround(2.0 * np.maximum(mid, m - mid))
        j = np.where(mid >= m / 2.0, i - 1.0, i - 1.0 + n2 - m)
        direct = 0.95 * (0.5 - 0.5 * np.cos(2.0 * np.pi * j / np.maximum(n2 - 1, 1))) + 0.05
        assert np.array_equal(sfr_edge._edge_window(m, mid, "tukey"), direct)
    for n in (16, 17, 300):
        x = rng.normal(size=n)
        assert sfr_edge._median(x) == np.median(x)
    coef = rng.normal(size=4)
    x = rng.normal(size=50)
    assert np.array_equal(sfr_edge.polyval(coef, x), np.polynomial.polynomial.polyval(x, coef))


@pytest.mark.property
def test_the_lsf_window_tapers_briefly_after_a_compact_lsf_and_long_after_a_tail():
    """The adaptive window's taper: ``max(0.75·w, 1 px)`` on a side whose
    significant structure ends inside the least flat top ``max(w, 1 px)``,
    ``max(w, 2 px)`` on a side whose structure reaches past it (it fades
    out there below the threshold: a halo's tail). Closed form: the raised
    cosine is ½ half-way down its taper."""
    os_, w, c = 4, 4.0, 100.0            # 4 bins a px, a 1 px rise: flat 4 bins, tapers 4 and 8 bins
    win = sfr_edge.adaptive_window(201, c, w, os_, extent=(2.0, 12.0))
    assert win[int(c) - 4] == 1.0 and win[int(c) - 6] == pytest.approx(0.5) and win[int(c) - 8] == 0.0
    assert win[int(c) + 12] == 1.0 and win[int(c) + 16] == pytest.approx(0.5) and win[int(c) + 20] == 0.0

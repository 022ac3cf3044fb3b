"""A simulated raw capture measured back: how far the SFR model stands from
the simulator's own capture chain, and what the fits can reach.

The device is ``isp calib simulate LENS --perturb random --seed SEED --size
W,H`` at its default exposure (all perturbations drawn within tolerance, refocused; the same
device the CLI draws). It is captured twice, with two noise seeds, and
both DNGs are measured as ``isp calib loop``/``fit`` measure a capture
(chart edges on the mosaic's green plane). Printed:

* **noise repeat**: RMS over the edges both captures hold of the SFRA
  difference, over √2: what one edge's SFRA scatters by from noise alone;
  for each SFR method of ``--methods`` (the same two captures measured
  each way; the first method's figures are also the top-level ones, and
  the fits use it);
* **the device's own lens** through :class:`calibration.fit.forward_model.SfrModel`
  (measurement bias included): SFRA RMS error against the first capture.
  No fit can be expected to beat it by much;
* with ``--fit N [N ...]``: ``fit_proxy`` on SFRA over the ``N`` perturbations
  that :class:`calibration.loop.base.LensBase` screens (the loop's base
  parameters; focus is left to the loop's ``focus_shift`` effect), with
  its coarse stage and restarts: SFRA RMS error and whether a restart was
  kept.

Prints a line per figure and one JSON object as the LAST line. Usage::

    python -m benchmarks.capture_roundtrip [--seed 3] [--size 2000 1500] [--methods accurate iso] [--fit 12 24]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # one BLAS thread per fit worker, set before numpy loads
    _harness.pin_threads(2, blas=1)

import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = _harness.ROOT

from calibration.optics.io import read_lens  # noqa: E402
from calibration.simulate.device import device_lens  # noqa: E402
from calibration.simulate.capture import simulate_capture, write_capture  # noqa: E402
from calibration.simulate.chart import slanted_square_chart  # noqa: E402
from calibration.optics.lens import Sensor  # noqa: E402
from calibration.fit.measurements import load_measured, match_sensor  # noqa: E402
from calibration.fit.proxy import ProxyFitSettings, fit_proxy, residual_bias  # noqa: E402
from isp.runtime.executor import pool_executor  # noqa: E402
from calibration.fit.forward_model import FAST_JACOBIAN, ModelSettings, SfrModel, band_means  # noqa: E402
from calibration.sfr.asymmetry import odd_sigma  # noqa: E402
from calibration.sfr.esfr import DEFAULT_METHOD  # noqa: E402

LENS = ROOT.parent / "shared" / "data" / "lenses" / "phone" / "US-12210142-B2-e9.zmx"


def _rms(a) -> np.ndarray:
    return np.sqrt(np.nanmean(np.asarray(a, float) ** 2, axis=0))


def fidelity(nominal, pair, device, executor, settings: ModelSettings | None = None) -> dict:
    """The device lens's residual through the model (``settings``, default
    the fitter's) against the noise of two captures ``pair``: SFRA, the four
    SFR bands and the LSF's asymmetry, each as RMS residual over RMS noise
    (``benchmarks/forward_fidelity.py`` explains the figures)."""
    first, second = pair
    i0, i1 = common_edges(first, second)
    model = SfrModel(nominal, first, settings)
    pred = model.predict(device)
    bias = residual_bias(model, device, "shape", executor)
    out = {"edges": len(first), "edges_in_both": len(i0)}
    # SFRA
    noise = two_capture_noise(first, second)
    resid = first.sfra - pred.sfra - bias.sfra
    out["sfra"] = {"noise": noise, "residual": float(_rms(resid)), "ratio": float(_rms(resid) / noise)}
    # the noise the model's own renders show (the loop's σ comes from it): against the captures'
    if bias.noise is not None:
        out["sfra"]["model_noise"] = float(_rms(bias.noise[:, 0]))
        out["sfra"]["model_noise_ratio"] = float(_rms(bias.noise[:, 0]) / noise)
    # the four SFR bands
    b0, b1 = band_means(first.freq, first.sfr), band_means(second.freq, second.sfr)
    noise_b = _rms((b0[i0] - b1[i1]) / np.sqrt(2))
    resid_b = bias.measured_bands - band_means(first.freq, pred.sfr) - bias.bands
    out["bands"] = {"noise": noise_b.tolist(), "residual": _rms(resid_b).tolist(),
                    "ratio": (_rms(resid_b) / noise_b).tolist()}
    # the LSF's asymmetry bands
    if first.odd is not None and second.odd is not None:
        noise_o = _rms((first.odd[i0] - second.odd[i1]) / np.sqrt(2))
        resid_o = first.odd - model.predict_odd(device) - bias.odd
        out["odd"] = {"noise": noise_o.tolist(), "residual": _rms(resid_o).tolist(),
                      "chi2_per_term": float(np.nanmean((resid_o / noise_o) ** 2)),
                      "chi2_per_term_fitter": float(np.nanmean((resid_o / odd_sigma(first.odd_std)) ** 2))}
    return out


def capture_pair(lens_path, seed: int, size, exposure: float, methods, log=lambda m: None):
    """The device ``isp calib simulate LENS --perturb random --seed SEED
    --size W,H`` draws, captured twice (noise seeds ``seed`` and ``seed +
    1000``) and measured as ``isp calib fit`` measures a capture, with each
    SFR method: ``(device, what, nominal, {method: [obs0, obs1]})``, the
    nominal lens matched to the capture's sensor."""
    lens = read_lens(lens_path)
    w, h = size
    lens = lens.replace(sensor=Sensor(pixel_pitch_um=lens.sensor.pixel_pitch_um * lens.sensor.width_px / w,
                                      width_px=w, height_px=h))
    device, what = device_lens(lens, "random", seed=seed)
    chart = slanted_square_chart(h, w)
    obs = {m: [] for m in methods}
    nominal = None
    with tempfile.TemporaryDirectory() as tmp:
        for noise_seed in (seed, seed + 1000):
            log(f"capture, noise seed {noise_seed} ...")
            dng = write_capture(Path(tmp) / f"c{noise_seed}.dng",
                                capture=simulate_capture(device, chart, exposure=exposure, rng=noise_seed))
            for m in methods:
                o, _ = load_measured(str(dng), method=m)
                nominal, o = match_sensor(read_lens(lens_path), o)
                obs[m].append(o)
    return device, what, nominal, obs


def two_capture_noise(first, second) -> float:
    """One edge's SFRA noise, cycles/pixel: the RMS of two captures' SFRA
    difference over √2, on the edges both hold (:func:`common_edges`)."""
    i0, i1 = common_edges(first, second)
    return float(_rms((first.sfra[i0] - second.sfra[i1]) / np.sqrt(2)))


def common_edges(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Indices into two measurements of the same chart of the edges both
    hold (matched by position to a pixel and normal to a degree)."""
    def key(o):
        return {(round(x), round(y), round(n)): i for i, (x, y, n) in enumerate(zip(o.x_px, o.y_px, o.normal_deg))}

    ka, kb = key(a), key(b)
    both = sorted(set(ka) & set(kb))
    return np.array([ka[c] for c in both], dtype=int), np.array([kb[c] for c in both], dtype=int)


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--lens", default=str(LENS))
    ap.add_argument("--seed", type=int, default=3, help="the device (isp calib simulate --seed)")
    ap.add_argument("--size", type=int, nargs=2, default=[2000, 1500], metavar=("W", "H"))
    ap.add_argument("--exposure", type=float, default=0.8, help="chart white level (isp calib simulate's default)")
    ap.add_argument("--fit", type=int, nargs="*", default=[], metavar="N",
                    help="fit_proxy over the loop base's N screened perturbations, for each N")
    ap.add_argument("--methods", nargs="+", default=[DEFAULT_METHOD, "iso"], choices=("accurate", "iso"),
                    help="SFR methods to measure the captures with (the first is the fits')")
    args = ap.parse_args(argv)

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    device, what, nominal, obs = capture_pair(args.lens, args.seed, args.size, args.exposure, args.methods, log)
    w, h = args.size

    by_method = {}
    for m in args.methods:
        with pool_executor(2) as ex:
            f = fidelity(nominal, obs[m], device, ex)
        rec = {"edges": f["edges"], "edges_in_both": f["edges_in_both"], "noise_repeat_sfra": f["sfra"]["noise"],
               "device_lens_sfra_rms": f["sfra"]["residual"]}
        log(f"{m}: noise repeat SFRA {rec['noise_repeat_sfra']:.4f} per edge over {rec['edges_in_both']} edges")
        log(f"{m}: the device's own lens: SFRA RMS {rec['device_lens_sfra_rms']:.4f}")
        by_method[m] = rec
    first = args.methods[0]
    obs = obs[first]
    out = {"lens": Path(args.lens).stem, "device": what, "size": [w, h],
           "pixel_pitch_um": round(float(obs[0].sensor.pixel_pitch_um), 4), "method": first, **by_method[first],
           "by_method": by_method}

    out["fits"] = []
    for n in args.fit:
        from calibration.loop.base import LensBase

        def fit_one(n=n):
            base = LensBase(nominal, obs[0], n_params=n)
            with pool_executor(None) as ex:
                return fit_proxy(nominal, obs[0], ProxyFitSettings(residuals="sfra", jacobian_model=FAST_JACOBIAN),
                                 names=list(base.names), executor=ex)

        fit, seconds = _harness.timed(fit_one)
        rec = {"n_params": n, "sfra_rms": fit.errors()["after"]["sfra_rms"],
               "restart_kept": any(t.get("kept") for t in fit.restarts), "seconds": round(seconds, 1)}
        out["fits"].append(rec)
        log(f"fit_proxy over the loop base's {n}: SFRA RMS {rec['sfra_rms']:.4f}, restart kept "
            f"{rec['restart_kept']}, {rec['seconds']} s")
    return _harness.publish("capture_roundtrip", out, args, argv)


if __name__ == "__main__":
    main()

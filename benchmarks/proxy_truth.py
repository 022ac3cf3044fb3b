"""Fitted proxy cameras of a simulated device scored against its true lens.

For a chart capture of a simulated device (``isp calib simulate ... --save-lens
truth.json``) and proxies fitted to it (``isp calib fit``), prints:

* ``truth``: how the device's own lens scores through the fit's forward model
  (χ² per edge with the measurement bias at the nominal lens, as the fit
  computes it; the share of edges beyond 4.6 σ with the bias at the true lens,
  and χ² without them) — what a perfect fit could reach;
* per proxy: the RMS error of its noise-free SFR (0–0.5 cycles/pixel) against
  the true lens's, per field ring (0.1 / 0.5 / 0.9: radius 0–0.2, 0.4–0.6,
  0.8–1 of the half-diagonal) and over all regions, at the capture's sampling;
* with ``--unstable K``: for the K edges worst off the true lens, the SFRA
  the ISO measurement gives on the model's render of that edge with 1× and
  1.5× its measured noise (mean ± sd of six draws): whether the edge's
  measurement is stable.

The last line is one JSON object with all of it.

    python -m benchmarks.proxy_truth --lens e9.zmx --measured dev3_full.dng --truth truth.json \\
        --proxy fit/proxy.json fit_boot/proxy.json --unstable 3
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # one BLAS thread per worker process; before numpy loads
    _harness.pin_threads(2, blas=1)

import numpy as np  # noqa: E402

RINGS = {"0.1": (0.0, 0.2), "0.5": (0.4, 0.6), "0.9": (0.8, 1.01)}
OUTLIER_Z = 4.6


def ring_masks(obs) -> dict:
    w, h = obs.sensor.width_px, obs.sensor.height_px
    r = np.hypot((obs.x_px - w / 2) / (w / 2), (obs.y_px - h / 2) / (h / 2)) / np.sqrt(2)
    return {k: (r >= lo) & (r < hi) for k, (lo, hi) in RINGS.items()} | {"all": np.ones(len(obs), bool)}


def sfr_error(model, lens, truth_sfr, masks) -> dict:
    """RMS SFR error (0–0.5 cycles/pixel) of ``lens`` against the truth's, per ring."""
    band = model.obs.freq <= 0.5
    mse = np.nanmean((model.predict(lens).sfr[:, band] - truth_sfr[:, band]) ** 2, axis=1)
    return {k: round(float(np.sqrt(np.mean(mse[m]))), 4) for k, m in masks.items() if m.any()}


def truth_merit(model, nominal, truth, workers: int) -> tuple[dict, np.ndarray]:
    from calibration.fit.proxy import residual_bias
    from isp.runtime.executor import pool_executor

    obs = model.obs
    pred = model.predict(truth).sfra
    with pool_executor(workers) as ex:
        at_nominal = residual_bias(model, nominal, "sfra", ex).sfra
        at_truth = residual_bias(model, truth, "sfra", ex).sfra
    z_nom = (obs.sfra - pred - at_nominal) / obs.sfra_std
    z = (obs.sfra - pred - at_truth) / obs.sfra_std
    keep = np.abs(z) <= OUTLIER_Z
    return {"chi2_bias_at_nominal": round(float(np.mean(z_nom ** 2)), 2),
            "beyond_4.6_sigma": round(float(np.mean(~keep)), 4),
            "chi2_without_them": round(float(np.mean(z[keep] ** 2)), 2)}, z


def stability(model, truth, worst, draws: int = 6, seed: int = 0) -> list:
    """Measured SFRA of the model's render of each edge at 1× and 1.5× its noise."""
    from calibration.sfr.esfr import SfrError
    from calibration.fit.forward_model import measure_like, render_observation

    obs, rng = model.obs, np.random.default_rng(seed)
    psfs = model.observation_psfs(truth)
    out = []
    for i in worst:
        clean = render_observation(psfs[i], model.pitch_um, obs.sensor.pixel_pitch_um, obs, i,
                                   model.settings.aperture_px)
        measure = measure_like(obs, i)
        row = {"edge": int(i), "measured": round(float(obs.sfra[i]), 4)}
        for k in (1.0, 1.5):
            v = []
            for _ in range(draws):
                try:
                    v.append(measure(clean + rng.normal(0.0, k * obs.noise[i], clean.shape)).sfra)
                except SfrError:
                    v.append(np.nan)
            row[f"render_{k:g}x"] = [round(float(np.nanmean(v)), 3), round(float(np.nanstd(v)), 3)]
        out.append(row)
    return out


def main(argv=None) -> dict:
    from calibration.fit.measurements import load_measured, match_sensor
    from calibration.optics.io import read_lens
    from calibration.fit.proxy import load_proxy
    from calibration.fit.forward_model import SfrModel

    ap = _harness.parser(__doc__)
    ap.add_argument("--lens", required=True, help="the nominal lens file")
    ap.add_argument("--measured", required=True, help="the device's chart capture (or observations JSON)")
    ap.add_argument("--truth", required=True, help="the device's true lens (isp calib simulate --save-lens)")
    ap.add_argument("--proxy", nargs="*", default=[], help="fitted proxy files (isp calib fit's proxy.json)")
    ap.add_argument("--unstable", type=int, default=0, metavar="K", help="test the K worst edges' stability")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)

    obs, _ = load_measured(args.measured, channel="G")
    nominal, obs = match_sensor(read_lens(args.lens), obs)
    model = SfrModel(nominal, obs)
    truth = load_proxy(args.truth)
    masks = ring_masks(obs)
    merit, z = truth_merit(model, nominal, truth, args.workers)
    print(f"truth through the model: {merit}", flush=True)
    truth_sfr = model.predict(truth).sfr
    proxies = {}
    for p in args.proxy:
        proxies[p] = sfr_error(model, load_proxy(p), truth_sfr, masks)
        print(f"{p}: RMS SFR error against the true lens {proxies[p]}", flush=True)
    out = {"measured": args.measured, "edges": len(obs), "truth": merit, "sfr_error": proxies}
    if args.unstable:
        out["unstable"] = stability(model, truth, np.argsort(-np.abs(z))[:args.unstable])
        for row in out["unstable"]:
            print(f"edge {row}")
    return _harness.publish("proxy_truth", out, args, argv)


if __name__ == "__main__":
    main()

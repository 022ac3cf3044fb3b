"""How much of a device's PSFs, and of what knowing them is worth, the
``device/v1`` descriptor keeps.

The descriptor (:mod:`calibration.fit.device`) is a device's PSF map on a
5 × 7 grid of field regions projected on the principal components of the
design's PSFs over its tolerances. This script learns the basis from
``--train`` lenses drawn within tolerance (seed 0) and measures it on
``--test`` other draws (seed 1), never seen by the PCA:

* **variance held**: the share of the held-out devices' PSF deviations from
  the design's mean PSF that ``k`` components reconstruct, for the file's
  basis (each region's own span, aligned to the pooled directions) and, as
  the alternative, one basis pooled over the regions (1/35 of the basis, the
  same descriptor size);
* **gain kept**: what the knowledge is worth to a restoration that uses it,
  without a network in the way. Each region's PSF (R, G, B) blurs a crop of
  a Kodak image (linear, the crop's own channel), Gaussian noise is added
  (σ ``--noise`` of the 0..1 range), and a Wiener filter deconvolves it
  with: the device's true PSF (the bound), the PSF the descriptor
  reconstructs with ``k`` components, the design's mean PSF over the draws
  (what a model that knows only the design can know), and the nominal
  lens's PSF. Every filter uses the same noise-to-signal spectrum (the
  crop's radially averaged power), so they differ only in the kernel. The
  gain kept is ``(PSNR_k − PSNR_mean) / (PSNR_true − PSNR_mean)``, pooled
  over devices, regions and channels, and per field ring;
* **the alternative descriptor**: sagittal and tangential MTF at 8
  frequencies (0.05–0.4 cycles/pixel) per region and channel (48 numbers per
  region, three times the 16-component file), from which a PSF is estimated
  as the mean of the 3 training lenses nearest in those numbers, region by
  region, and scored by the same Wiener gain;
* **size**: bytes of the ``device/v1`` file for each ``k``;
* with ``--proxy-results benchmarks/results/proxy_parts/*.log``, **the fitted
  descriptors**: each device of the proxy-fit benchmark of this lens, its
  descriptor from the proxy fitted to its simulated capture (``ours_shape``)
  against its true lens's, as the same Wiener gain kept (the descriptor's
  own fitting error). Those devices are drawn uniformly within ±1 tolerance
  without refocusing, wider than the basis's refocused draws.

PSF maps are cached on disk (``~/.cache/phone-isp/psf``): a second run costs
seconds. Usage::

    python -m benchmarks.device_descriptor [--lens e9] [--train 120] [--test 24]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":
    _harness.pin_threads(2, blas=1)

import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.forward_fidelity import LENSES, PHONE  # noqa: E402

KS = (1, 2, 4, 8, 16, 32)
CROP = 128
RINGS = {"0.1": (0.0, 0.3), "0.5": (0.3, 0.7), "0.9": (0.7, 1.01)}


def pooled_basis(train: np.ndarray, k: int):
    """Alternative: one PCA pooled over the regions, ``(k, D)`` components."""
    n = train.shape[0]
    mean = train.mean(axis=0)
    dev = (train - mean).reshape(n * train.shape[1] * train.shape[2], -1)
    _, _, vt = np.linalg.svd(dev, full_matrices=False)
    return mean, vt[:k]


MTF_FREQS = np.linspace(0.05, 0.4, 8)


def mtf_samples(psfs: np.ndarray, sensor, grid) -> np.ndarray:
    """Sagittal and tangential MTF of pixel PSFs ``(..., rows, cols, 3, m,
    m)`` at :data:`MTF_FREQS`: ``(..., rows, cols, 48)``. By the
    projection-slice theorem the MTF along a direction ``n`` is ``|Σ_p h(p)
    exp(−2πi f p·n)|``; ``n`` is the region centre's radial direction
    (sagittal) and its normal (tangential)."""
    from calibration.optics.psf.map import region_centers_mm

    m = psfs.shape[-1]
    o = np.arange(m) - m // 2
    yy, xx = np.meshgrid(o, o, indexing="ij")
    centres = region_centers_mm(sensor, grid)
    out = np.empty(psfs.shape[:-3] + (2 * 3 * len(MTF_FREQS),))
    for r in range(grid[0]):
        for c in range(grid[1]):
            th = math.atan2(centres[r, c, 1], centres[r, c, 0]) if np.any(centres[r, c]) else 0.0
            feats = []
            for a in (th, th + math.pi / 2):
                u = xx * math.cos(a) + yy * math.sin(a)
                basis = np.exp(-2j * math.pi * MTF_FREQS[:, None, None] * u[None])      # (F, m, m)
                h = psfs[..., r, c, :, :, :]                                          # (..., 3, m, m)
                feats.append(np.abs(np.einsum("...kij,fij->...kf", h, basis)))
            out[..., r, c, :] = np.concatenate(feats, axis=-1).reshape(psfs.shape[:-5] + (-1,))
    return out


def mtf_knn(train, test, sensor, grid, k: int = 3) -> np.ndarray:
    """Each test region's PSF as the mean of the ``k`` training lenses
    nearest in that region's MTF samples."""
    ft, fs = mtf_samples(train, sensor, grid), mtf_samples(test, sensor, grid)
    est = np.empty_like(test)
    for r in range(grid[0]):
        for c in range(grid[1]):
            d = np.linalg.norm(fs[:, None, r, c] - ft[None, :, r, c], axis=-1)   # (test, train)
            near = np.argsort(d, axis=1)[:, :k]
            est[:, r, c] = train[near, r, c].mean(axis=1)
    return est


def held_variance(test, mean, recon) -> float:
    """Share of the deviations' energy reconstructed."""
    d = test - mean
    return float(1.0 - np.sum((test - recon) ** 2) / np.sum(d ** 2))


def crops(n: int, rng) -> np.ndarray:
    """``n`` linear RGB crops ``(n, 3, CROP, CROP)`` of the Kodak images."""
    from restoration.synth.pairs import find_latents, read_latent

    files = find_latents(_harness.ROOT.parent / "shared" / "data" / "latent" / "Kodak24")
    out = np.empty((n, 3, CROP, CROP))
    for i in range(n):
        img = read_latent(str(files[rng.integers(len(files))])).astype(np.float64) / 255.0
        y, x = rng.integers(0, img.shape[0] - CROP), rng.integers(0, img.shape[1] - CROP)
        srgb = img[y:y + CROP, x:x + CROP]
        lin = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
        out[i] = lin.transpose(2, 0, 1)
    return out


def otf(psf: np.ndarray) -> np.ndarray:
    """The kernel's transfer function on the crop, its centre sample at the origin."""
    m = psf.shape[-1]
    k = np.zeros(psf.shape[:-2] + (CROP, CROP))
    k[..., :m, :m] = psf
    k = np.roll(k, (-(m // 2), -(m // 2)), axis=(-2, -1))
    return np.fft.rfft2(k)


def wiener_psnr(x, y_f, h_est, nsr) -> np.ndarray:
    """PSNR (dB, peak 1) of the Wiener estimate of ``x`` from the blurred,
    noisy spectrum ``y_f`` with the estimated transfer ``h_est``."""
    est = np.fft.irfft2(np.conj(h_est) * y_f / (np.abs(h_est) ** 2 + nsr), s=(CROP, CROP))
    b = 16   # the circular wrap's border
    mse = np.mean((est - x)[..., b:-b, b:-b] ** 2, axis=(-2, -1))
    return 10 * np.log10(1.0 / mse)


def radial_power(x: np.ndarray) -> np.ndarray:
    """Each crop's power spectrum averaged over rings of |f| (rfft2 layout)."""
    f = np.abs(np.fft.rfft2(x)) ** 2
    fy = np.fft.fftfreq(CROP)[:, None]
    fx = np.fft.rfftfreq(CROP)[None, :]
    r = np.minimum((np.hypot(fy, fx) * CROP).astype(int), CROP // 2)
    out = np.empty_like(f)
    for idx in np.ndindex(f.shape[:-2]):
        tot = np.bincount(r.ravel(), f[idx].ravel(), minlength=CROP // 2 + 1)
        cnt = np.bincount(r.ravel(), minlength=CROP // 2 + 1)
        out[idx] = (tot / np.maximum(cnt, 1))[r]
    return out


def gain_study(true_psfs, estimates: dict, sensor, grid, noise: float, seed: int) -> dict:
    """PSNR of Wiener with each estimate, per ring; ``true_psfs`` ``(n, rows,
    cols, 3, m, m)``, each estimate the same shape (or broadcastable)."""
    rng = np.random.default_rng(seed)
    n, r, c = true_psfs.shape[:3]
    from calibration.optics.psf.map import region_centers_mm

    centres = region_centers_mm(sensor, grid)
    half_diag = 0.5 * np.hypot(sensor.width_px, sensor.height_px) * sensor.pixel_pitch_um * 1e-3
    radius = np.hypot(centres[..., 0], centres[..., 1]) / half_diag
    if {"uncorrected", "true"} & set(estimates):
        raise ValueError("'uncorrected' and 'true' name the study's own rows, not estimates")
    psnr = {name: np.empty((n, r, c, 3)) for name in ("uncorrected", "true", *estimates)}
    for i in range(n):
        x = crops(r * c, rng).reshape(r, c, 3, CROP, CROP)
        h = otf(true_psfs[i])
        y = np.fft.irfft2(np.fft.rfft2(x) * h, s=(CROP, CROP)) + rng.normal(0, noise, x.shape)
        y_f = np.fft.rfft2(y)
        nsr = noise ** 2 * CROP * CROP / np.maximum(radial_power(x), 1e-12)
        b = 16
        psnr["uncorrected"][i] = 10 * np.log10(1.0 / np.mean((y - x)[..., b:-b, b:-b] ** 2, axis=(-2, -1)))
        psnr["true"][i] = wiener_psnr(x, y_f, h, nsr)
        for name, est in estimates.items():
            e = est[i] if est.ndim == true_psfs.ndim else est
            psnr[name][i] = wiener_psnr(x, y_f, otf(e), nsr)
    out = {}
    for ring, (lo, hi) in {"all": (0.0, 2.0), **RINGS}.items():
        sel = (radius >= lo) & (radius < hi)
        mean = {k: float(v[:, sel].mean()) for k, v in psnr.items()}
        span = mean["true"] - mean["mean"]
        out[ring] = {"psnr_db": {k: round(v, 3) for k, v in mean.items()},
                     "gain_kept": {k: round((v - mean["mean"]) / span, 3) if span > 0 else None
                                   for k, v in mean.items() if k not in ("true", "mean", "uncorrected")}}
    return out


def proxy_devices(paths, lens_name: str, lens):
    """(device, true lens, fitted lens) of the proxy benchmark's devices of
    ``lens``, from its results files (``proxy.json``, or the logs of
    ``--only`` runs, whose last line is the record)."""
    from calibration.fit.proxy import parameter_space
    from calibration.optics.perturb import default_names

    cases = []
    for path in paths:
        lines = [ln for ln in open(path).read().splitlines() if ln.startswith("{")]
        if lines:
            cases += json.loads(lines[-1])["results"]["cases"]
    out = []
    for case in cases:
        if case["lens"] != lens_name or "ours_shape" not in case["methods"]:
            continue
        space = parameter_space(lens, case.get("all_names") or default_names(lens))
        truth = space.apply(np.asarray(case["u_true"]) * space.tolerance)
        rec = case["methods"]["ours_shape"]
        sub = parameter_space(lens, rec.get("names", case["names"]))
        out.append((case["device"], truth, sub.apply(np.asarray(rec["u"]) * sub.tolerance)))
    return out


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--lens", default="e9", choices=list(LENSES))
    ap.add_argument("--train", type=int, default=120, help="lenses the basis is learned from (seed 0)")
    ap.add_argument("--test", type=int, default=24, help="held-out lenses (seed 1)")
    ap.add_argument("--noise", type=float, default=0.01, help="σ of the Wiener study's noise (0..1 range)")
    ap.add_argument("--proxy-results", nargs="+", metavar="FILE",
                    help="results of benchmarks/proxy.py (proxy.json or its --only logs): its fitted devices too")
    args = ap.parse_args(argv)

    from calibration.fit.device import (DEFAULT_COMPONENTS, DEFAULT_GRID, DeviceCalibration, basis_from_psfs,
                                        design_key, psf_stack)
    from calibration.optics.perturb import nominal
    from isp.runtime.executor import pool_executor
    from calibration.simulate.device import draw_lenses
    from restoration.synth.optics import load_lens

    t0 = time.perf_counter()
    lens_path = PHONE / f"{LENSES[args.lens]}.zmx"
    pl = nominal(load_lens(lens_path))
    grid = DEFAULT_GRID
    sensor = pl.lens.sensor
    with pool_executor(None) as ex:
        train = psf_stack(draw_lenses(pl, args.train + 1, np.random.default_rng(0))[1:], grid, executor=ex)
        test = psf_stack(draw_lenses(pl, args.test + 1, np.random.default_rng(1))[1:], grid, executor=ex)
        nom = psf_stack([pl], grid, executor=ex)[0]
    print(f"{args.lens}: {len(train)} + {len(test)} PSF maps ({time.perf_counter() - t0:.0f} s)", flush=True)
    basis = basis_from_psfs(train, lens=pl.nominal.name, design=design_key(pl), grid=grid,
                            channels=("R", "G", "B"), components=max(KS), sensor=sensor)
    r, c = grid

    held = {"file": {}, "pooled": {}}
    estimates = {"mean": basis.mean, "nominal": nom, "mtf_knn": mtf_knn(train, test, sensor, grid)}
    for k in KS:
        sub = basis_from_psfs(train, lens=basis.lens, design=basis.design, grid=grid, channels=basis.channels,
                              components=k, sensor=sensor)
        rec = np.stack([sub.reconstruct(sub.project(t)) for t in test])
        held["file"][k] = round(held_variance(test, sub.mean, rec), 4)
        estimates[f"file_k{k}"] = rec
        mean, comps = pooled_basis(train, k)
        dev = (test - mean).reshape(len(test), r * c, -1)
        rec2 = mean + ((dev @ comps.T) @ comps).reshape(test.shape)
        held["pooled"][k] = round(held_variance(test, mean, rec2), 4)
        if k in (8, 16, 32):
            estimates[f"pooled_k{k}"] = rec2
    print("variance held (file's per-region basis / one pooled basis): "
          + ", ".join(f"k={k} {held['file'][k]:.3f} / {held['pooled'][k]:.3f}" for k in KS), flush=True)
    gains = gain_study(test, estimates, sensor, grid, args.noise, seed=7)
    for ring, g in gains.items():
        print(f"  ring {ring}: PSNR true {g['psnr_db']['true']:.2f}, mean {g['psnr_db']['mean']:.2f}, "
              f"uncorrected {g['psnr_db']['uncorrected']:.2f} dB; kept: "
              + ", ".join(f"{k} {v:.2f}" for k, v in g["gain_kept"].items() if v is not None), flush=True)
    basis = basis_from_psfs(train, lens=basis.lens, design=basis.design, grid=grid, channels=basis.channels,
                            components=DEFAULT_COMPONENTS, sensor=sensor)
    sizes = {}
    for k in (4, 8, 16):
        cal = DeviceCalibration(basis.lens, basis.design, basis.key, basis.project(test[0], k),
                                fit={"sfra_rms_before": 0.05, "sfra_rms_after": 0.005, "chi2_per_obs": 1.2,
                                     "parameters": 24},
                                source={"measured": "capture.dng", "sha256": "0" * 64})
        sizes[k] = len(json.dumps(cal.to_dict(), separators=(",", ":")))
    print("device.json bytes: " + ", ".join(f"k={k} {v}" for k, v in sizes.items()), flush=True)

    fitted = None
    if args.proxy_results:
        from calibration.optics.io import read_lens

        devs = proxy_devices(args.proxy_results, LENSES[args.lens], read_lens(lens_path))
        if devs:
            with pool_executor(None) as ex:
                true_s = psf_stack([t for _, t, _ in devs], grid, sensor=sensor, executor=ex)
                fit_s = psf_stack([f for _, _, f in devs], grid, sensor=sensor, executor=ex)
            est = {"mean": basis.mean,
                   "fitted_descriptor": np.stack([basis.reconstruct(basis.project(f)) for f in fit_s]),
                   "true_descriptor": np.stack([basis.reconstruct(basis.project(t)) for t in true_s]),
                   "fitted_lens": fit_s}
            dist = [float(np.sqrt(np.mean((basis.project(f) - basis.project(t)) ** 2)))
                    for f, t in zip(fit_s, true_s)]
            fitted = {"devices": [d for d, _, _ in devs], "descriptor_rms": [round(v, 3) for v in dist],
                      "descriptor_spread": [round(float(np.sqrt(np.mean(basis.project(t) ** 2))), 3)
                                            for t in true_s],
                      "gain": gain_study(true_s, est, sensor, grid, args.noise, seed=11)}
            g = fitted["gain"]["all"]
            print(f"fitted proxies ({len(devs)} devices): descriptor RMS error (k={basis.size}) "
                  f"{np.mean(dist):.2f} spreads; kept: "
                  + ", ".join(f"{k} {v:.2f}" for k, v in g["gain_kept"].items() if v is not None), flush=True)
        else:
            print(f"{args.proxy_results}: no ours_shape case of {LENSES[args.lens]}")

    results = {"lens": LENSES[args.lens], "grid": list(grid), "train": len(train), "test": len(test),
               "noise": args.noise, "components": basis.size,
               "explained_train": [round(float(v), 4) for v in basis.explained],
               "variance_held": held, "wiener": gains, "device_json_bytes": sizes, "fitted": fitted,
               "seconds": round(time.perf_counter() - t0, 1)}
    return _harness.publish("device_descriptor", results, args, argv)


if __name__ == "__main__":
    main()

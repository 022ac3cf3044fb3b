"""How much of a device's PSFs, and of what knowing them is worth, the
``device/v1`` descriptor keeps.

The descriptor (:mod:`calibration.fit.device`) is a device's PSF map on a
5 × 7 grid of field regions projected on the principal components of the
design's PSFs over its tolerances. This script learns the basis from
``--train`` lenses drawn within tolerance (seed 0) and measures it on
``--test`` other draws (seed 1), never seen by the PCA:

* **variance held**: the share of the held-out devices' PSF deviations from
  the design's mean PSF that ``k`` components reconstruct, for the basis
  pooled over the regions (the file's) and, as the alternative, one basis
  per region (35 × more basis, the same descriptor size);
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
* **size**: bytes of the ``device/v1`` file for each ``k``;
* with ``--proxy-results benchmarks/results/proxy.json``, **the fitted
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
import time  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.forward_fidelity import LENSES, PHONE  # noqa: E402

KS = (1, 2, 4, 8, 16, 32)
CROP = 128
RINGS = {"0.1": (0.0, 0.3), "0.5": (0.3, 0.7), "0.9": (0.7, 1.01)}


def stack_of(lenses, grid, sensor=None, executor=None):
    """Pixel PSFs ``(n, rows, cols, 3, m, m)`` of lenses (cached maps)."""
    from calibration.fit.device import descriptor_map_settings, pixel_psfs
    from calibration.optics.psf.map import psf_map

    s = descriptor_map_settings(grid)
    return np.stack([pixel_psfs(psf_map(pl, s, sensor=sensor, executor=executor)) for pl in lenses])


def per_region_basis(train: np.ndarray, k: int):
    """Alternative: one PCA per region, ``(rows, cols, k, D)`` components."""
    n, r, c = train.shape[:3]
    mean = train.mean(axis=0)
    dev = (train - mean).reshape(n, r, c, -1)
    comps = np.zeros((r, c, k, dev.shape[-1]))
    for i in range(r):
        for j in range(c):
            _, _, vt = np.linalg.svd(dev[:, i, j], full_matrices=False)
            comps[i, j, :min(k, len(vt))] = vt[:k]
    return mean, comps


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


def proxy_devices(path, lens_name: str, lens):
    """(true, fitted) lenses of the proxy benchmark's devices of ``lens``."""
    from calibration.fit.proxy import parameter_space
    from calibration.optics.perturb import default_names

    doc = json.loads(open(path).read())
    out = []
    for case in doc["results"]["cases"]:
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
    ap.add_argument("--proxy-results", help="proxy.json of benchmarks/proxy.py: its fitted devices too")
    args = ap.parse_args(argv)

    from calibration.fit.device import (DEFAULT_GRID, DeviceCalibration, basis_from_psfs, design_key)
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
        train = stack_of(draw_lenses(pl, args.train + 1, np.random.default_rng(0))[1:], grid, executor=ex)
        test = stack_of(draw_lenses(pl, args.test + 1, np.random.default_rng(1))[1:], grid, executor=ex)
        nom = stack_of([pl], grid, executor=ex)[0]
    print(f"{args.lens}: {len(train)} + {len(test)} PSF maps ({time.perf_counter() - t0:.0f} s)", flush=True)
    basis = basis_from_psfs(train, lens=pl.nominal.name, design=design_key(pl), grid=grid,
                            channels=("R", "G", "B"), components=max(KS), sensor=sensor)
    r, c = grid

    held = {"pooled": {}, "per_region": {}}
    estimates = {"mean": basis.mean, "nominal": nom}
    for k in KS:
        rec = np.stack([basis.reconstruct(basis.project(t, k)) for t in test])
        held["pooled"][k] = round(held_variance(test, basis.mean, rec), 4)
        estimates[f"pooled_k{k}"] = rec
        mean, comps = per_region_basis(train, k)
        dev = (test - mean).reshape(len(test), r, c, -1)
        coef = np.einsum("nrcd,rckd->nrck", dev, comps)
        rec2 = mean + np.einsum("nrck,rckd->nrcd", coef, comps).reshape(test.shape)
        held["per_region"][k] = round(held_variance(test, mean, rec2), 4)
        if k in (4, 8, 16):
            estimates[f"per_region_k{k}"] = rec2
    print("variance held (pooled / per region): "
          + ", ".join(f"k={k} {held['pooled'][k]:.3f} / {held['per_region'][k]:.3f}" for k in KS), flush=True)
    gains = gain_study(test, estimates, sensor, grid, args.noise, seed=7)
    for ring, g in gains.items():
        print(f"  ring {ring}: PSNR true {g['psnr_db']['true']:.2f}, mean {g['psnr_db']['mean']:.2f}, "
              f"uncorrected {g['psnr_db']['uncorrected']:.2f} dB; kept: "
              + ", ".join(f"{k} {v:.2f}" for k, v in g["gain_kept"].items() if v is not None), flush=True)
    sizes = {}
    for k in (4, 8, 16, 32):
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
                true_s = stack_of([t for _, t, _ in devs], grid, sensor=sensor, executor=ex)
                fit_s = stack_of([f for _, _, f in devs], grid, sensor=sensor, executor=ex)
            est = {"mean": basis.mean}
            for k in (8, 16, 32):
                est[f"fitted_k{k}"] = np.stack([basis.reconstruct(basis.project(f, k)) for f in fit_s])
                est[f"true_k{k}"] = np.stack([basis.reconstruct(basis.project(t, k)) for t in true_s])
            est["fitted_full"] = fit_s
            dist = [float(np.sqrt(np.mean((basis.project(f, 16) - basis.project(t, 16)) ** 2)))
                    for f, t in zip(fit_s, true_s)]
            fitted = {"devices": [d for d, _, _ in devs], "descriptor_rms_k16": [round(v, 3) for v in dist],
                      "descriptor_spread_k16": [round(float(np.sqrt(np.mean(basis.project(t, 16) ** 2))), 3)
                                                for t in true_s],
                      "gain": gain_study(true_s, est, sensor, grid, args.noise, seed=11)}
            g = fitted["gain"]["all"]
            print(f"fitted proxies ({len(devs)} devices): descriptor RMS error (k=16) "
                  f"{np.mean(dist):.2f} spreads; kept: "
                  + ", ".join(f"{k} {v:.2f}" for k, v in g["gain_kept"].items() if v is not None), flush=True)
        else:
            print(f"{args.proxy_results}: no ours_shape case of {LENSES[args.lens]}")

    results = {"lens": LENSES[args.lens], "grid": list(grid), "train": len(train), "test": len(test),
               "noise": args.noise, "explained_train": [round(float(v), 4) for v in basis.explained],
               "variance_held": held, "wiener": gains, "device_json_bytes": sizes, "fitted": fitted,
               "seconds": round(time.perf_counter() - t0, 1)}
    return _harness.publish("device_descriptor", results, args, argv)


if __name__ == "__main__":
    main()

"""Speed of data synthesis, and the error of the blur's shortcuts
(:mod:`restoration.synth`).

* Speed: ``--pairs`` (default 1,000) pairs of 256 × 256 from one proxy
  camera (the e9 lens of ../shared/data/lenses/phone, single sample) with
  2 worker processes, PSF map cached (the plan is built once before timing,
  so the first run computes and caches the map: ≈ 15 s). Target ≤ 5 min.
* Shortcut error: the synthesis blurs a crop with the 15 × 20 region PSFs
  interpolated bilinearly between region centres (``bilinear``, computed by
  FFT in float32: :class:`restoration.synth.optics.CropBlur`). Against a
  per-pixel-varying reference — PSFs computed with the map's own settings
  on a 4-px lattice over a 48 × 48 window and interpolated between its
  nodes (the reference's own convergence is checked against an 8-px
  lattice) — on a crop of kodim05 in linear RGB, at two windows that
  straddle region borders: near the corner and at 0.7 of the field. Also
  measured: ``nearest`` (the paper's one PSF per region), ``crop`` (one
  PSF, the region of the crop's centre, for the whole 256-px crop), and
  the FFT path against the direct-convolution oracle
  (:func:`calibration.simulate.capture.blur_image`).
* Blur per 256² crop (``blur_per_crop``): each path, one warm-up, then the
  median of 5 crops at other positions (with the fastest and slowest).

  Errors are RMS over the window in % of the RMS of the blur itself
  (reference − sharp), and max |Δ| on the 0..1 scale.

Reference PSFs are cached in ``$ISP_CACHE/synth-bench`` (else
``~/.cache/phone-isp/synth-bench``). The machine may be shared: the load
average is printed. Prints progress, then one JSON object as its last line.

Usage: python -m benchmarks.synth [--pairs 1000] [--workers 2] [--skip-speed] [--skip-error]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # one BLAS thread per worker process; before numpy loads
    _harness.pin_threads(2, blas=1)

import hashlib  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = _harness.ROOT
DATA = ROOT.parent / "shared" / "data"

LENS = DATA / "lenses" / "phone" / "US-12210142-B2-e9.zmx"
CAMERAS = [DATA / "raw" / "SYNTHETIC_phone_S6meta_512x384.dng", DATA / "raw" / "skia_sample_1mp.dng"]
WINDOW = 48
#: inner windows (row, col) on the 4211 × 5614 sensor: each straddles a region corner
#: (region borders every 280.7 px): near the sensor corner, and at 0.7 of the field
WINDOWS = {"corner": (257, 257), "field_0.7": (3344, 4467)}


def say(*a):
    print(*a, file=sys.stderr, flush=True)


def _cache_dir() -> Path:
    env = os.environ.get("ISP_CACHE")
    return (Path(env) if env else Path.home() / ".cache" / "phone-isp") / "synth-bench"


def _psf_task(args):
    from calibration.optics.psf.map import region_task

    return region_task(args)[0]


def reference_map(pl, psfmap, origin, size, step, workers):
    """A PSF map over a ``size``-px window at sensor ``origin`` with one PSF
    every ``step`` px, computed exactly as :func:`calibration.optics.psf.map.psf_map`
    computes a region's (same settings, its private per-region task), so
    that bilinear blending between these nodes is a per-pixel-varying blur."""
    from concurrent.futures import ProcessPoolExecutor

    from calibration.optics.lens import Sensor
    from calibration.optics.psf.map import PSFMap, chief_ray_fields, sensor_to_image
    from calibration.optics.psf.spectral import channel_quadrature

    st = psfmap.settings
    k = size // step
    key = hashlib.sha256(json.dumps([psfmap.key, origin, size, step]).encode()).hexdigest()[:24]
    path = _cache_dir() / f"{key}.npz"
    centers_px = (np.arange(k) + 0.5) * size / k - 0.5                 # KernelBank's region centres
    ys, xs = np.meshgrid(origin[0] + centers_px, origin[1] + centers_px, indexing="ij")
    x_mm, y_mm = sensor_to_image(xs, ys, psfmap.sensor)
    centers = np.stack([x_mm, y_mm], axis=-1)
    if path.exists():
        psfs = np.load(path)["psfs"]
    else:
        nodes, weights = channel_quadrature(tuple(st["channels"]), st["n_wavelengths"], st["camera"], st["illuminant"])
        fields = chief_ray_fields(pl, centers.reshape(-1, 2))
        tasks = [(pl, fields[i], centers.reshape(-1, 2)[i], nodes, weights, st["method"], st["pupil_samples"],
                  st["n"], st["pitch_um"], st["aiming"], st["aim_each_wavelength"], 1) for i in range(k * k)]
        t = time.perf_counter()
        with ProcessPoolExecutor(max_workers=workers) as ex:
            data = list(ex.map(_psf_task, tasks, chunksize=4))
        say(f"  reference {k}×{k} PSFs at {origin}: {time.perf_counter() - t:.0f} s")
        psfs = np.stack(data).reshape(k, k, 3, st["n"], st["n"]).astype(np.float32)
        psfs /= psfs.sum(axis=(3, 4), keepdims=True)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, psfs=psfs)
    sensor = Sensor(pixel_pitch_um=psfmap.sensor.pixel_pitch_um, width_px=size, height_px=size)
    return PSFMap(psfs, psfmap.pitch_um, centers, np.zeros_like(centers), psfmap.channels, sensor)


def shortcut_errors(pl, psfmap, workers, dense_maps) -> dict:
    import cv2

    from calibration.simulate.capture import blur_image
    from modules.gamma import srgb_eotf
    from restoration.synth.optics import CropBlur, map_margin_px

    m = map_margin_px(psfmap)
    img = cv2.imread(str(DATA / "latent" / "Kodak24" / "kodim05.png"))[:, :, ::-1]
    lin = srgb_eotf(img.astype(np.float32) / 255.0)
    work = np.ascontiguousarray(lin[100:100 + WINDOW + 2 * m, 150:150 + WINDOW + 2 * m])
    inner = (slice(m, m + WINDOW), slice(m, m + WINDOW))
    size = (psfmap.sensor.height_px, psfmap.sensor.width_px)
    out = {}
    for name, (r0, c0) in WINDOWS.items():
        wo = (r0 - m, c0 - m)
        ref4 = blur_image(work, reference_map(pl, psfmap, (r0, c0), WINDOW, 4, workers), size_px=(WINDOW, WINDOW),
                          origin=(-m, -m))[inner]
        sharp = work[inner]
        blur_rms = float(np.sqrt(np.mean((ref4 - sharp) ** 2)))

        def err(x, ref4=ref4, blur_rms=blur_rms):
            d = x - ref4
            return {"rms_pct_of_blur": round(100 * float(np.sqrt(np.mean(d ** 2))) / blur_rms, 3),
                    "max_abs": float(np.abs(d).max()),
                    "psnr_db": round(float(-10 * np.log10(np.mean(d ** 2))), 2)}

        res = {"blur_rms": blur_rms}
        res["bilinear_fft (default)"] = err(CropBlur(psfmap, "bilinear")(work, wo)[inner])
        res["bilinear_direct"] = err(blur_image(work, psfmap, size_px=size, origin=wo)[inner])
        res["nearest (paper)"] = err(CropBlur(psfmap, "nearest")(work, wo)[inner])
        # one PSF for a whole 256-px crop: the map interpolated at the crop's centre, which lies
        # between 0 (window at the crop's centre) and 128·√2 px (window at its corner) away
        from calibration.simulate.optical_image import KernelBank, convolve

        bank = KernelBank.from_psf(psfmap)
        for label, shift in (("one PSF per 256 crop, window at its centre", 0),
                             ("one PSF per 256 crop, window at its corner", 128 - WINDOW // 2)):
            cy, cx = r0 + WINDOW / 2 - 0.5 + shift, c0 + WINDOW / 2 - 0.5 + shift
            one = np.zeros(work.shape)
            for ri, wy in bank.axis_weights(0, np.array([cy]), "bilinear", size):
                for ci, wx in bank.axis_weights(1, np.array([cx]), "bilinear", size):
                    for ch in range(3):
                        one[:, :, ch] += wy[0] * wx[0] * convolve(work[:, :, ch].astype(np.float64),
                                                                  bank.resampled((ri, ci), ch, 1.0))
            res[label] = err(one[inner])
        for grid, dense in dense_maps.items():
            res[f"bilinear, {grid} map"] = err(CropBlur(dense, "bilinear")(work, wo)[inner])
        if name == "corner":
            ref8 = blur_image(work, reference_map(pl, psfmap, (r0, c0), WINDOW, 8, workers),
                              size_px=(WINDOW, WINDOW), origin=(-m, -m))[inner]
            res["reference 8-px lattice vs 4-px (reference's own error)"] = err(ref8)
        out[name] = res
        say(f"  {name}: " + json.dumps(res))
    return out


def blur_speed(psfmap) -> dict:
    from calibration.simulate.capture import blur_image
    from restoration.synth.optics import CropBlur, map_margin_px

    m = map_margin_px(psfmap)
    img = np.random.default_rng(0).random((256 + 2 * m, 256 + 2 * m, 3)).astype(np.float32)
    size = (psfmap.sensor.height_px, psfmap.sensor.width_px)
    out = {}
    for label, fn in (("bilinear_fft", lambda o: CropBlur(psfmap)(img, o)),
                      ("nearest_fft", lambda o: CropBlur(psfmap, "nearest")(img, o)),
                      ("bilinear_direct", lambda o: blur_image(img, psfmap, size_px=size, origin=o))):
        origins = iter([(2000, 3000)] + [(2000 + 37 * i, 3000 + 53 * i) for i in range(5)])
        t = _harness.measure(lambda fn=fn, origins=origins: fn(next(origins)), runs=5, warmup=1)
        out[label + "_ms"] = t.map(lambda s: 1000 * s).as_dict(1)
    return out


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--pairs", type=int, default=1000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--skip-error", action="store_true")
    ap.add_argument("--dense-grid", metavar="ROWS,COLS", action="append", default=[],
                    help="also measure bilinear interpolation of a denser PSF map (e.g. 30,40; computed once, cached)")
    args = ap.parse_args(argv)

    from restoration.synth.pairs import generate, plan
    from restoration.synth.optics import load_lens

    out = {"lens": LENS.name}
    t = time.perf_counter()
    pl = load_lens(LENS)
    from isp.runtime.executor import pool_executor

    p = plan(pl, latent_dir=DATA / "latent", cameras=CAMERAS, executor=pool_executor(args.workers))
    out["plan_s"] = round(time.perf_counter() - t, 1)
    say(f"plan (PSF map from cache or computed): {out['plan_s']} s")
    psfmap = p.maps[0]
    out["blur_per_crop"] = blur_speed(psfmap)
    say("blur per 256² crop:", out["blur_per_crop"])

    if not args.skip_speed:
        tmp = Path(tempfile.mkdtemp(prefix="synth-bench-"))
        try:
            m = generate(p, tmp / "pairs", args.pairs, executor=pool_executor(args.workers, progress=True))
            s = m["_seconds"]
            out["speed"] = {"pairs": args.pairs, "size": 256, "workers": args.workers, "seconds": round(s, 1),
                            "pairs_per_s": round(args.pairs / s, 2),
                            "seconds_per_1000": round(1000 * s / args.pairs, 1),
                            "target_s_per_1000": 300,
                            "bytes_on_disk": sum(f.stat().st_size for f in (tmp / "pairs").iterdir())}
            say(f"{args.pairs} pairs: {s:.1f} s ({args.pairs / s:.2f} pairs/s; load {os.getloadavg()})")
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    if not args.skip_error:
        from restoration.synth.optics import psf_maps

        dense = {}
        for g in args.dense_grid:
            rows, cols = (int(v) for v in g.split(","))
            t = time.perf_counter()
            with pool_executor(args.workers) as ex:
                dense[f"{rows}x{cols}"] = psf_maps([pl], executor=ex, grid=(rows, cols))[0]
            say(f"PSF map {rows}×{cols}: {time.perf_counter() - t:.0f} s")
        out["shortcut_error"] = shortcut_errors(pl, psfmap, args.workers, dense)
    return _harness.publish("synth", out, args, argv)


if __name__ == "__main__":
    main()

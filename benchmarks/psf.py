"""Speed and accuracy of the PSFs (:mod:`calibration.optics.psf`, :mod:`calibration.optics.psf.map`).

On US-12210142-B2-e9 (../shared/data/lenses/phone) and an aberration-free
singlet:

* single PSFs at 0.7 field, 587.6 nm, one warm-up then the median of
  ``--runs`` (with the fastest and slowest): Huygens (64 pupil rays across,
  128² samples) and FFT (128 across, 256²), Debye (64, 128²), and the three
  at the map's setting (64, 32² at 0.5 µm); the peer in the same run:
  optiland's ``HuygensPSF`` and ``FFTPSF`` at the same settings on the same
  lens file (``pip install -e .[bench]``; left out, with the reason in the
  JSON, where optiland is absent or with ``--no-peer``);
* the 15 × 20 × 3 PSF map with the map defaults (Debye, 64 pupil samples,
  32² PSFs at half the 1 µm pixel, 3 Gauss wavelengths per channel, D65 ×
  Nikon 5100, aimed once per region), nominal lens (quadrant symmetry) and
  a perturbed one (all 300 regions), with 1 and 2 worker processes;
* accuracy: Airy first zero and Strehl of the perfect singlet; Huygens ↔
  FFT and Huygens ↔ Debye on axis, at 0.7 and 1.0 field; the map settings
  and cheaper ones against a reference setting (Huygens, 96 pupil samples,
  4 wavelengths per channel, aimed at each) on 6 regions along the diagonal
  and the edges — NCC, max |Δ| / peak, encircled energy at 1 µm;
* with ``--quadrature``: Gauss nodes per channel (1–4) against the dense
  5 nm sum (Debye PSFs 48² at 0.25 µm on axis, 0.7 and 1.0 field).

The machine may be shared: the load average is printed with the timings.
Prints progress, then one JSON object as its last line. Usage::

    python -m benchmarks.psf [--runs 3] [--quadrature] [--skip-map] [--skip-accuracy] [--no-peer] [--plot map.png]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import json  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = _harness.ROOT
DATA = ROOT.parent / "shared" / "data" / "lenses" / "phone"

LAM = 587.6


def timing(runs, fn) -> dict:
    """One warm-up call of ``fn``, then ``runs`` timed: seconds, median and range."""
    return _harness.measure(fn, runs=runs, warmup=1).as_dict(4)


def optiland_psfs(path: Path, runs: int, field: float = 0.7) -> dict:
    """optiland's Huygens (64 rays, 128²) and FFT (128 rays, 256²) PSFs of
    the lens file ``path`` at ``field`` of its maximum, 587.6 nm, timed as
    :func:`timing` times ours; ``{"available": False, "reason"}`` without optiland."""
    try:
        from importlib.metadata import version

        from optiland.fileio import load_zemax_file
        from optiland.psf import FFTPSF, HuygensPSF
    except ImportError as e:
        return {"available": False, "reason": f"optiland not installed ({e.name}): pip install -e .[bench]"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")     # numba's compile-time notes
        optic = load_zemax_file(str(path))
        out = {"huygens_64_128": timing(runs, lambda: HuygensPSF(optic, (0.0, field), LAM * 1e-3, num_rays=64,
                                                                   image_size=128)),
               "fft_128_256": timing(runs, lambda: FFTPSF(optic, (0.0, field), LAM * 1e-3, num_rays=128,
                                                           grid_size=256))}
    return {"available": True, "version": version("optiland"), **out}


def say(*a):
    print(*a, file=sys.stderr, flush=True)


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--runs", type=int, default=3, help="timed runs of each single PSF (median; default 3)")
    ap.add_argument("--no-peer", action="store_true", help="leave optiland out")
    ap.add_argument("--quadrature", action="store_true")
    ap.add_argument("--skip-map", action="store_true")
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--plot", type=Path, default=None, help="write the perturbed map's G mosaic here (.png)")
    args = ap.parse_args(argv)

    from tests.calibration.optics.psf.helpers import first_zero_um, perfect_lens, real_working_f_number

    import calibration.optics.psf as P
    from calibration.optics.psf import map as M
    from calibration.optics.io import read_lens
    from calibration.optics.perturb import apply
    from isp.runtime.executor import pool_executor

    e9 = read_lens(DATA / "US-12210142-B2-e9.zmx")
    out: dict = {"load_average": os.getloadavg(), "cpus": os.cpu_count()}
    f07 = (0.0, 0.7 * e9.half_fov_deg)

    # -- single PSFs ------------------------------------------------------------------
    P.fft_psf(e9, f07, LAM, pupil_samples=32, n=16)          # imports, warm caches
    small = {"pupil_samples": 64, "n": 32, "pitch_um": 0.5}
    out["single_psf_s"] = {
        "huygens_64_128": timing(args.runs, lambda: P.huygens_psf(e9, f07, LAM, pupil_samples=64, n=128)),
        "fft_128_256": timing(args.runs, lambda: P.fft_psf(e9, f07, LAM, pupil_samples=128, n=256)),
        "debye_64_128": timing(args.runs, lambda: P.debye_psf(e9, f07, LAM, pupil_samples=64, n=128)),
        "huygens_64_32": timing(args.runs, lambda: P.huygens_psf(e9, f07, LAM, **small)),
        "fft_64_32": timing(args.runs, lambda: P.fft_psf(e9, f07, LAM, **small)),
        "debye_64_32": timing(args.runs, lambda: P.debye_psf(e9, f07, LAM, **small))}
    say("single PSF (s):", out["single_psf_s"], "load", os.getloadavg())
    peer = ({"available": False, "reason": "--no-peer"} if args.no_peer
            else optiland_psfs(DATA / "US-12210142-B2-e9.zmx", args.runs))
    out["optiland_single_psf_s"] = peer
    if peer["available"]:
        out["speedup_vs_optiland"] = {k: round(peer[k]["median"] / out["single_psf_s"][k]["median"], 2)
                                      for k in ("huygens_64_128", "fft_128_256")}
        say("optiland single PSF (s):", peer, "; ours faster by", out["speedup_vs_optiland"])
    else:
        say(f"optiland not compared: {peer['reason']}")

    if not args.skip_accuracy:
        # -- accuracy: perfect lens ------------------------------------------------------------
        lens = perfect_lens()
        n_w = real_working_f_number(lens)
        acc = {"perfect_lens_working_f_number": n_w}
        for m, fn in (("huygens", P.huygens_psf), ("fft", P.fft_psf), ("debye", P.debye_psf)):
            p = fn(lens, 0.0, LAM, pupil_samples=64, n=65, pitch_um=LAM * 1e-3 * 4.0 / 8)
            acc[f"airy_zero_ratio_{m}"] = first_zero_um(p) / (1.22 * LAM * 1e-3 * n_w)
            acc[f"strehl_perfect_{m}"] = P.strehl_ratio(lens, 0.0, LAM, method=m, pupil_samples=64)
        # -- accuracy: Huygens vs FFT on e9 --------------------------------------------------------
        for frac in (0.0, 0.7, 1.0):
            fld = (0.0, frac * e9.half_fov_deg)
            kw = {"pupil_samples": 64, "n": 64, "pitch_um": 0.25}
            a, b, d = P.huygens_psf(e9, fld, LAM, **kw), P.fft_psf(e9, fld, LAM, **kw), P.debye_psf(e9, fld, LAM, **kw)
            acc[f"ncc_huygens_fft_{frac}"] = P.ncc(a.data, b.data)
            acc[f"maxdiff_over_peak_huygens_fft_{frac}"] = float(np.abs(a.data - b.data).max() / a.data.max())
            acc[f"maxdiff_over_peak_huygens_debye_{frac}"] = float(np.abs(a.data - d.data).max() / a.data.max())
            acc[f"strehl_e9_{frac}"] = {m: P.strehl_ratio(e9, fld, LAM, method=m, pupil_samples=64) for m in P.METHODS}
            acc[f"window_energy_e9_{frac}"] = {"huygens": a.window_energy, "fft": b.window_energy}
        out["accuracy"] = acc
        say("accuracy:", json.dumps(acc, indent=1))

        # -- accuracy of the map settings against a reference ------------------------------------------
        regions = [(7, 10), (10, 13), (13, 17), (14, 19), (7, 19), (0, 10)]
        centers = M.region_centers_mm(e9.sensor, (15, 20))
        pts = np.array([centers[r, c] for r, c in regions])
        fields = M.chief_ray_fields(e9, pts)
        primary = {"aim_each_wavelength": False}
        variants = {
            "reference_huygens_96_4wl": {"method": "huygens", "pupil_samples": 96, "n_wavelengths": 4},
            "map_default_debye_64_3wl_aim_primary": dict(method="debye", pupil_samples=64, n_wavelengths=3, **primary),
            "debye_64_3wl_aim_each": {"method": "debye", "pupil_samples": 64, "n_wavelengths": 3},
            "huygens_64_3wl_aim_each": {"method": "huygens", "pupil_samples": 64, "n_wavelengths": 3},
            "fft_64_3wl_aim_primary": dict(method="fft", pupil_samples=64, n_wavelengths=3, **primary),
            "debye_48_3wl_aim_primary": dict(method="debye", pupil_samples=48, n_wavelengths=3, **primary),
            "debye_32_3wl_aim_primary": dict(method="debye", pupil_samples=32, n_wavelengths=3, **primary),
            "debye_64_2wl_aim_primary": dict(method="debye", pupil_samples=64, n_wavelengths=2, **primary),
            "debye_64_1wl_aim_primary": dict(method="debye", pupil_samples=64, n_wavelengths=1, **primary),
        }
        got = {}
        for name, v in variants.items():
            t = time.perf_counter()
            got[name] = [[P.polychromatic_psf(e9, tuple(fl), ch, n=32, pitch_um=0.5, center=tuple(pt), **v)
                          for ch in "RGB"] for fl, pt in zip(fields, pts)]
            say(f"  {name}: {time.perf_counter() - t:.1f} s")
        ref = got["reference_huygens_96_4wl"]
        cost = {}
        for name, psfs in got.items():
            if name.startswith("reference"):
                continue
            nccs, maxd, dee = [], [], []
            for row_r, row in zip(ref, psfs):
                for a, b in zip(row_r, row):
                    nccs.append(P.ncc(a.data, b.data))
                    maxd.append(float(np.abs(a.data - b.data).max() / a.data.max()))
                    dee.append(abs(float(a.encircled_energy(1.0)) - float(b.encircled_energy(1.0))))
            cost[name] = {"min_ncc": min(nccs), "max_abs_diff_over_peak": max(maxd), "max_ee1um_error": max(dee)}
        out["map_settings_vs_reference"] = {"regions": regions, "fields_deg": fields.tolist(), **cost}
        say("settings vs reference:", json.dumps(cost, indent=1))

    # -- quadrature ---------------------------------------------------------------------------------
    if args.quadrature:
        q = {}
        for frac in (0.0, 0.7, 1.0):
            for ch in "RGB":
                wl, c = P.spectral_response(ch)
                keep = c > 1e-3 * c.max()
                kw = {"method": "debye", "pupil_samples": 64, "n": 48, "pitch_um": 0.25}
                dense = P.polychromatic_psf(e9, frac * e9.half_fov_deg, (wl[keep], c[keep]), **kw)
                for m in (1, 2, 3, 4):
                    g = P.polychromatic_psf(e9, frac * e9.half_fov_deg, ch, n_wavelengths=m, **kw)
                    q[f"{frac}_{ch}_{m}"] = {"max_abs_diff_over_peak": float(np.abs(g.data - dense.data).max()
                                                                             / dense.data.max()),
                                             "ncc": P.ncc(g.data, dense.data)}
        out["quadrature_vs_dense"] = q
        say("quadrature:", json.dumps(q, indent=1))

    # -- the map ---------------------------------------------------------------------------------------
    if not args.skip_map:
        maps = {}
        pert = apply(e9, {"e1.decenter_y": 0.003, "e2.tilt_zx": 0.03, "s3.thickness": 0.005})
        for label, ln in (("nominal", e9), ("perturbed", pert)):
            for workers in (1, 2):
                with pool_executor(workers) as ex:   # "serial" for 1; the pool's start counts, as a user pays it
                    mp, dt = _harness.timed(lambda ln=ln, ex=ex: M.psf_map(ln, cache=False, executor=ex))
                maps[f"{label}_workers{workers}"] = {"s": dt, "load_average": os.getloadavg(),
                                                      "wavelengths_nm": list(mp.wavelengths_nm),
                                                      "min_window_energy": float(mp.window_energy.min())}
                say(f"map {label} workers={workers}: {dt:.1f} s (load {os.getloadavg()})")
        out["map_15x20x3_s"] = maps
        if args.plot:
            M.plot_psf_map(mp, args.plot, channel="G")
    return _harness.publish("psf", out, args, argv)


if __name__ == "__main__":
    main()

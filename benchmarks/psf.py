"""Speed and accuracy of the PSFs (calibration/optics/psf/core.py, calibration/optics/psf/map.py).

On US-12210142-B2-e9 (../shared/data/lenses/phone) and an aberration-free
singlet:

* single PSFs at 0.7 field, 587.6 nm, best of ``--runs``: Huygens (64 pupil
  rays across, 128² samples) and FFT (128 across, 256²) — the settings of the
  optiland figures quoted in the data README (≈ 1.5 s and ≈ 0.15 s there,
  not re-measured: optiland is not installed) — Debye (64, 128²), and the
  three at the map's setting (64, 32² at 0.5 µm);
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
Prints progress, then one JSON object as its last line. Usage:
python benchmarks/psf.py [--runs 3] [--quadrature] [--skip-map] [--skip-accuracy] [--plot map.png]
"""

from __future__ import annotations

import os

THREADS = "2"
for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[var] = THREADS

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "lenses" / "phone"
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

LAM = 587.6


def best_of(runs, fn):
    ts = []
    out = None
    for _ in range(runs):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    return min(ts), out


def say(*a):
    print(*a, file=sys.stderr, flush=True)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--quadrature", action="store_true")
    ap.add_argument("--skip-map", action="store_true")
    ap.add_argument("--skip-accuracy", action="store_true")
    ap.add_argument("--plot", type=Path, default=None, help="write the perturbed map's G mosaic here (.png)")
    args = ap.parse_args(argv)

    from test_psf import first_zero_um, perfect_lens, real_working_f_number

    from calibration.optics.psf import core as P
    from calibration.optics.psf import map as M
    from calibration.optics.io.lens_json import read_lens
    from calibration.optics.perturb import apply

    e9 = read_lens(DATA / "US-12210142-B2-e9.zmx")
    out: dict = {"load_average": os.getloadavg(), "cpus": os.cpu_count()}
    f07 = (0.0, 0.7 * e9.half_fov_deg)

    # -- single PSFs ------------------------------------------------------------------
    P.fft_psf(e9, f07, LAM, pupil_samples=32, n=16)          # imports, warm caches
    t_h, _ = best_of(args.runs, lambda: P.huygens_psf(e9, f07, LAM, pupil_samples=64, n=128))
    t_f, _ = best_of(args.runs, lambda: P.fft_psf(e9, f07, LAM, pupil_samples=128, n=256))
    t_d, _ = best_of(args.runs, lambda: P.debye_psf(e9, f07, LAM, pupil_samples=64, n=128))
    small = {"pupil_samples": 64, "n": 32, "pitch_um": 0.5}
    t_h32, _ = best_of(args.runs, lambda: P.huygens_psf(e9, f07, LAM, **small))
    t_f32, _ = best_of(args.runs, lambda: P.fft_psf(e9, f07, LAM, **small))
    t_d32, _ = best_of(args.runs, lambda: P.debye_psf(e9, f07, LAM, **small))
    out["single_psf_s"] = {"huygens_64_128": t_h, "fft_128_256": t_f, "debye_64_128": t_d,
                           "huygens_64_32": t_h32, "fft_64_32": t_f32, "debye_64_32": t_d32}
    say("single PSF (s):", out["single_psf_s"], "load", os.getloadavg())

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
                t = time.perf_counter()
                mp = M.psf_map(ln, cache=False, progress=False, workers=workers)
                dt = time.perf_counter() - t
                maps[f"{label}_workers{workers}"] = {"s": dt, "load_average": os.getloadavg(),
                                                      "wavelengths_nm": list(mp.wavelengths_nm),
                                                      "min_window_energy": float(mp.window_energy.min())}
                say(f"map {label} workers={workers}: {dt:.1f} s (load {os.getloadavg()})")
        out["map_15x20x3_s"] = maps
        if args.plot:
            M.plot_psf_map(mp, args.plot, channel="G")
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()

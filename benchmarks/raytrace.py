"""Speed of the real-ray tracer, and its agreement with the published
figures of the e9 phone lens.

Traces 1,000,000 uniformly random pupil rays (paraxial aiming, 587.6 nm) at
0.7 field through US-12210142-B2-e9 (7 plastic aspheres + IR filter, 17
surfaces) on 2 threads, best of ``--runs``; also times ray generation with
real aiming. The peer figure (optiland 0.6.3, numpy backend, ≈ 80k rays/s on
2 cores, 12.4 s per 1e6 rays) is quoted from ``../shared/data/lenses/README.md``;
optiland is not installed here, so it is not re-measured.

Also reports the on-axis RMS spot radius (centroid-referenced, 2e5 random
rays) and the vignetted fractions at 0.7 and 1.0 field, against the
README's 0.795 µm (optiland) / 0.799 µm (rayoptics) and 77 % / 46 %.

Prints progress, then one JSON object as its last line. Usage:
python benchmarks/raytrace.py [--rays 1000000] [--runs 3] [--threads 2]
"""

from __future__ import annotations

import os

THREADS = "2"
for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[var] = THREADS

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "lenses" / "phone"
sys.path.insert(0, str(ROOT))


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--chunk", type=int, default=None)
    args = ap.parse_args(argv)

    from calibration.optics import trace as tr
    from calibration.optics.io.formats import read_zmx
    from calibration.optics.spot import spot

    lens = read_zmx(DATA / "US-12210142-B2-e9.zmx")
    lam = 587.6
    field = (0.0, 0.7 * lens.half_fov_deg)
    rng = np.random.default_rng(1)
    t = time.perf_counter()
    rays = tr.pupil_rays(lens, field, args.rays, lam, distribution="random", rng=rng)
    gen_paraxial_s = time.perf_counter() - t
    kw = {"workers": args.threads}
    if args.chunk:
        kw["chunk"] = args.chunk
    tr.trace_to_image(lens, rays, **kw)  # warm-up
    times = []
    for i in range(args.runs):
        t = time.perf_counter()
        res = tr.trace_to_image(lens, rays, **kw)
        times.append(time.perf_counter() - t)
        print(f"run {i + 1}: {times[-1]:.3f} s, {args.rays / times[-1]:,.0f} rays/s", file=sys.stderr)
    best = min(times)
    one = []
    for i in range(2):
        t = time.perf_counter()
        tr.trace_to_image(lens, rays, workers=1)
        one.append(time.perf_counter() - t)
    n_aim = 100_000
    t = time.perf_counter()
    tr.pupil_rays(lens, field, n_aim, lam, distribution="random", aiming="real", rng=rng)
    aim_s = time.perf_counter() - t

    on_axis = spot(lens, (0.0, 0.0), 200_000, lam, rng=np.random.default_rng(2))
    vig = {}
    for f in (0.7, 1.0):
        fld = (0.0, f * lens.half_fov_deg)
        for aiming in ("paraxial", "real"):
            r = tr.trace_to_image(lens, tr.pupil_rays(lens, fld, 100_000, lam, aiming=aiming,
                                                      rng=np.random.default_rng(3)))
            vig[f"pass_{f:.1f}_{aiming}"] = round(r.fraction_valid, 4)
    out = {
        "lens": lens.name or "US-12210142-B2-e9",
        "surfaces": len(lens.surfaces),
        "rays": args.rays,
        "threads": args.threads,
        "field_deg": field[1],
        "trace_s": round(best, 4),
        "rays_per_s": round(args.rays / best),
        "rays_per_s_1_thread": round(args.rays / min(one)),
        "ns_per_ray_surface_1_thread": round(min(one) / args.rays / (len(lens.surfaces) + 1) * 1e9, 1),
        "valid_fraction": round(res.fraction_valid, 4),
        "generate_paraxial_s": round(gen_paraxial_s, 4),
        "generate_real_aiming_rays_per_s": round(n_aim / aim_s),
        "peer_optiland_rays_per_s": 80_000,
        "speedup_vs_optiland": round(args.rays / best / 80_000, 2),
        "rms_on_axis_um": round(on_axis.rms_radius() * 1e3, 4),
        "rms_on_axis_ref_um": [0.795, 0.799],
        **vig,
        "pass_ref": {"0.7": 0.77, "1.0": 0.46},
    }
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()

"""Speed of the real-ray tracer against optiland, and its agreement with the
published figures of the e9 phone lens.

Traces ``--rays`` (default 1,000,000) uniformly random pupil rays
(paraxial aiming, 587.6 nm) at 0.7 field through US-12210142-B2-e9 (7
plastic aspheres + IR filter, 17 surfaces) on ``--threads`` threads: one
warm-up, then the median of ``--runs``; also on one thread, and ray
generation with real aiming.

The peer runs in the same process on the same lens file, field, wavelength
and ray count: optiland (``pip install -e .[bench]``), its numpy backend
with the numba-compiled surface kernels, warm (the first trace compiles
them), median of ``--runs``. ``speedup_vs_optiland`` is the ratio of the
two medians. Without optiland installed the comparison is left out and
the JSON says why.

Also reports the on-axis RMS spot radius (centroid-referenced, 2e5 random
rays) and the vignetted fractions at 0.7 and 1.0 field, against the
lens README's 0.795 µm (optiland) / 0.799 µm (rayoptics) and 77 % / 46 %.

Prints progress, then one JSON object as its last line. Usage::

    python -m benchmarks.raytrace [--rays 1000000] [--runs 3] [--threads 2] [--no-peer]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import sys  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = _harness.ROOT
DATA = ROOT.parent / "shared" / "data" / "lenses" / "phone"
LENS = DATA / "US-12210142-B2-e9.zmx"
LAMBDA_NM = 587.6
FIELD = 0.7


def optiland_trace(path: Path, rays: int, runs: int, field: float = FIELD, wavelength_nm: float = LAMBDA_NM) -> dict:
    """Time optiland tracing ``rays`` random pupil rays at ``field`` (of its
    maximum field) through the lens file ``path``: a warm-up trace, then
    the median of ``runs``. ``{"available": False, "reason"}`` without
    optiland."""
    try:
        from importlib.metadata import version

        import optiland.backend as be
        from optiland.fileio import load_zemax_file
    except ImportError as e:
        return {"available": False, "reason": f"optiland not installed ({e.name}): pip install -e .[bench]"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")     # numba's compile-time notes
        optic = load_zemax_file(str(path))

        def trace():
            return optic.trace(0.0, field, wavelength_nm * 1e-3, rays, distribution="random", record=False)

        t = _harness.measure(trace, runs=runs, warmup=1, label="optiland")
    return {"available": True, "version": version("optiland"), "backend": be.get_backend(),
            "trace_s": t.as_dict(4), "rays_per_s": t.map(lambda s: rays / s).as_dict(0)}


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--runs", type=int, default=3, help="timed runs of each tracer (median; default 3)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--chunk", type=int, default=None)
    ap.add_argument("--no-peer", action="store_true", help="leave optiland out")
    args = ap.parse_args(argv)
    _harness.pin_threads(args.threads)

    from calibration.optics import trace as tr
    from calibration.optics.io import read_lens
    from calibration.optics.spot import spot
    from isp.runtime.executor import shared_threads

    lens = read_lens(LENS)
    field = (0.0, FIELD * lens.half_fov_deg)
    rng = np.random.default_rng(1)
    rays, gen_s = _harness.timed(lambda: tr.pupil_rays(lens, field, args.rays, LAMBDA_NM, distribution="random",
                                                       rng=rng))
    kw = {"executor": shared_threads(args.threads)}
    if args.chunk:
        kw["chunk"] = args.chunk
    res = tr.trace_to_image(lens, rays, **kw)
    ours = _harness.measure(lambda: tr.trace_to_image(lens, rays, **kw), runs=args.runs, label="ours")
    one = _harness.measure(lambda: tr.trace_to_image(lens, rays, executor=shared_threads(1)), runs=args.runs, label="ours, 1 thread")
    n_aim = 100_000
    _, aim_s = _harness.timed(lambda: tr.pupil_rays(lens, field, n_aim, LAMBDA_NM, distribution="random",
                                                    aiming="real", rng=rng))
    peer = ({"available": False, "reason": "--no-peer"} if args.no_peer
            else optiland_trace(LENS, args.rays, args.runs))

    on_axis = spot(lens, (0.0, 0.0), 200_000, LAMBDA_NM, rng=np.random.default_rng(2))
    vig = {}
    for f in (0.7, 1.0):
        fld = (0.0, f * lens.half_fov_deg)
        for aiming in ("paraxial", "real"):
            r = tr.trace_to_image(lens, tr.pupil_rays(lens, fld, 100_000, LAMBDA_NM, aiming=aiming,
                                                      rng=np.random.default_rng(3)))
            vig[f"pass_{f:.1f}_{aiming}"] = round(r.fraction_valid, 4)
    rate = ours.map(lambda s: args.rays / s)
    out = {
        "lens": lens.name or LENS.stem,
        "surfaces": len(lens.surfaces),
        "rays": args.rays,
        "runs": args.runs,
        "threads": args.threads,
        "field_deg": field[1],
        "trace_s": ours.as_dict(4),
        "rays_per_s": rate.as_dict(0),
        "rays_per_s_1_thread": one.map(lambda s: args.rays / s).as_dict(0),
        "ns_per_ray_surface_1_thread": round(one.median / args.rays / (len(lens.surfaces) + 1) * 1e9, 1),
        "valid_fraction": round(res.fraction_valid, 4),
        "generate_paraxial_s": round(gen_s, 4),
        "generate_real_aiming_rays_per_s": round(n_aim / aim_s),
        "optiland": peer,
        "speedup_vs_optiland": (round(peer["trace_s"]["median"] / ours.median, 2) if peer["available"] else None),
        "rms_on_axis_um": round(on_axis.rms_radius() * 1e3, 4),
        "rms_on_axis_ref_um": [0.795, 0.799],
        **vig,
        "pass_ref": {"0.7": 0.77, "1.0": 0.46},
    }
    print(f"ours: {rate} rays/s on {args.threads} threads", file=sys.stderr)
    if peer["available"]:
        print(f"optiland {peer['version']} ({peer['backend']} backend): {peer['rays_per_s']['median']:,.0f} rays/s; "
              f"ours {out['speedup_vs_optiland']}× faster")
    else:
        print(f"optiland not compared: {peer['reason']}")
    print(f"ours: {out['rays_per_s']['median']:,.0f} rays/s ({args.threads} threads), "
          f"{out['rays_per_s_1_thread']['median']:,.0f} on one")
    return _harness.publish("raytrace", out, args, argv)


if __name__ == "__main__":
    main()

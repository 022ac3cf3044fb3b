"""What the forward model's PSF window costs in accuracy, and in time.

:class:`calibration.fit.forward_model.SfrModel` computes each region's PSF on an
``psf_n`` × ``psf_n`` window at half the pixel pitch and normalises it to
unit mass *inside the window*. Light the aberrations throw further out is
dropped, and the SFR, normalised at zero frequency, comes out too high at
low and middle frequencies. A perturbed phone lens throws a lot further out
than its nominal design: the corners' coma and astigmatism tails reach
10–20 µm (``--help``'s table, measured below).

For each phone lens (``../shared/data/lenses/phone``) the nominal design
and ``--devices`` devices (every :func:`calibration.fit.proxy.default_names`
parameter uniform within ±1 tolerance, seeded as ``benchmarks/proxy.py``
seeds them), on a 5 × 7 field grid with a vertical and a horizontal edge
at every region centre (green channel):

* **energy outside**: the fraction of the PSF's energy (reference window)
  outside the central ``n`` × ``n`` samples, the worst region;
* **SFR error**: RMS difference (0..0.5 cycles/pixel) between the model's
  SFR at that window and at the reference, over all observations and over
  the worst observation near FoV 0.9 (radius ≥ 0.8);
* **SFRA error**: largest absolute difference of SFRA (cycles/pixel);
* **predict**: CPU seconds per :meth:`SfrModel.predict` call (median over
  the lenses, with the fastest and slowest).

The reference is ``psf_n=128`` with ``pupil_samples=96`` (a 64 µm window;
the sampled pupil's replica period λ·N·P is ≥ 94 µm for these lenses);
each candidate window keeps that period above the window (``pupil`` 48 up
to 32 µm, 64 beyond).

Prints a line per lens × window and one JSON object as the LAST line::

    python -m benchmarks.psf_window [--lenses e9 e2] [--devices 3] [--windows 32 48 64 96]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # one BLAS thread, as in a fit's worker processes; before numpy loads
    _harness.pin_threads(2, blas=1)

import time  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.lens_eval import observations  # noqa: E402
from benchmarks.proxy import pick_lenses  # noqa: E402
from calibration.optics.io import read_lens  # noqa: E402
from calibration.fit.proxy import default_names, parameter_space  # noqa: E402
from calibration.fit.forward_model import ModelSettings, SfrModel  # noqa: E402

GRID = (5, 7)
REFERENCE = ModelSettings(psf_n=128, pupil_samples=96)
#: window side (samples at half the pixel pitch) → pupil samples keeping the replica period outside it
PUPIL_FOR = {32: 48, 48: 48, 64: 48, 96: 64}


def outside_fraction(psfs: np.ndarray, n: int) -> np.ndarray:
    """Per PSF (…, m, m), the mass outside the central n × n samples."""
    m = psfs.shape[-1]
    a = (m - n) // 2
    inside = psfs[..., a:a + n, a:a + n].sum(axis=(-1, -2))
    return 1.0 - inside / psfs.sum(axis=(-1, -2))


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--lenses", nargs="*", default=None, help="lens tokens (e1 e2 e9 e11); default all")
    ap.add_argument("--devices", type=int, default=3, help="perturbed devices per lens (default 3)")
    ap.add_argument("--windows", type=int, nargs="+", default=[32, 48, 64, 96],
                    help=f"psf_n to measure (one of {sorted(PUPIL_FOR)})")
    ap.add_argument("--seed", type=int, default=2024, help="as benchmarks/proxy.py (devices [seed, lens, d])")
    args = ap.parse_args(argv)
    out = {"grid": list(GRID), "reference": {"psf_n": REFERENCE.psf_n, "pupil_samples": REFERENCE.pupil_samples},
           "devices": args.devices, "lenses": {}}
    for li, path in enumerate(pick_lenses(args.lenses)):
        lens = read_lens(path)
        names = default_names(lens)
        space = parameter_space(lens, names)
        obs = observations(lens.sensor, GRID)
        corner = obs.radius >= 0.8
        band = obs.freq <= 0.5 + 1e-12
        lenses = [("nominal", lens)] + [
            (f"device {d}", space.apply(np.random.default_rng([args.seed, li, d]).uniform(-1, 1, len(names))
                                        * space.tolerance)) for d in range(args.devices)]
        ref_model = SfrModel(lens, obs, REFERENCE)
        refs = []
        for _, L in lenses:
            p = ref_model.predict(L)
            refs.append((p.sfr, p.sfra, ref_model.observation_psfs(L).copy()))
        rows = {}
        for n in args.windows:
            model = SfrModel(lens, obs, ModelSettings(psf_n=n, pupil_samples=PUPIL_FOR[n]))
            cpu, rec = [], {"outside": [], "sfr_rms": [], "sfr_rms_corner": [], "sfra_max": []}
            for (label, L), (sfr_ref, sfra_ref, psf_ref) in zip(lenses, refs):
                c0 = time.process_time()
                p = model.predict(L)
                cpu.append(time.process_time() - c0)
                d = (p.sfr - sfr_ref)[:, band]
                rec["outside"].append(float(outside_fraction(psf_ref, n).max()))
                rec["sfr_rms"].append(float(np.sqrt(np.nanmean(d ** 2))))
                rec["sfr_rms_corner"].append(float(np.sqrt(np.nanmean(d[corner] ** 2, axis=1)).max()))
                rec["sfra_max"].append(float(np.nanmax(np.abs(p.sfra - sfra_ref))))
            row = {"pupil_samples": PUPIL_FOR[n], "window_um": n * model.pitch_um,
                   "predict_cpu_s": _harness.spread(cpu).as_dict(3),
                   "nominal": {k: round(v[0], 5) for k, v in rec.items()},
                   "devices_worst": {k: round(max(v[1:]), 5) for k, v in rec.items()} if len(lenses) > 1 else None}
            rows[str(n)] = row
            w = row["devices_worst"] or row["nominal"]
            print(f"{path.stem:22s} n={n:3d} ({row['window_um']:4.0f} µm): outside nominal {row['nominal']['outside']:.3f}"
                  f" devices ≤ {w['outside']:.3f} | SFR RMS ≤ {w['sfr_rms']:.4f}, corner ≤ {w['sfr_rms_corner']:.4f}"
                  f" | SFRA ≤ {w['sfra_max']:.4f} c/px | predict {row['predict_cpu_s']['median']:.2f} s CPU", flush=True)
        out["lenses"][path.stem] = rows
    return _harness.publish("psf_window", out, args, argv)


if __name__ == "__main__":
    main()

"""How well the fitting forward model reproduces the simulator: each
device's TRUE lens through the model, against the noise between two
captures of that device.

For each phone lens of ``--lenses``, the device ``isp calib simulate LENS
--perturb random --seed SEED --size W,H`` draws (every tolerance drawn,
refocused) is captured twice with two noise seeds and measured as ``isp
calib fit`` measures a capture (``benchmarks.capture_roundtrip.capture_pair``); the comparison is
``benchmarks.capture_roundtrip.fidelity``.
The device's own lens goes through :class:`calibration.fit.forward_model.SfrModel`
with the measurement's bias (``residual_bias``, ``shape``: SFRA, the four
SFR bands and the LSF's asymmetry bands), and its residual against the first
capture is set against the noise, measured as the difference of the two
captures over √2 on the edges both hold:

* **SFRA**: the residual's RMS over the noise's (1.0 for a perfect model);
* **bands**: the same for the mean SFR in each of the four frequency
  bands (0.02–0.125, –0.25, –0.375, –0.5 cycles/pixel);
* **asymmetry**: the LSF's odd part in its bands, χ² per term with the
  noise's σ per band (1.0 for a perfect model), and with the σ the fitter
  divides by (``odd_sigma``: the measurement's own estimate with the model's
  floor in quadrature).

A model that matched the simulator exactly would score 1 on each; the gap
is the model's own error, the floor under any fit and under every effect the
loop tries to detect. ``--window-um``, ``--pupil-samples``, ``--wavelengths``
(or ``--psf-map``, the three as the capture's PSF map has them) and
``--noise-realisations`` set the model's PSF window, pupil grid, Gauss nodes
per channel and the noisy renders of its bias (default: the fitter's), so
that what each difference from the simulator costs can be measured.

Results are kept per model (``--label``, default "fitter") and lens in
``benchmarks/results/forward_fidelity.json``; a lens measured with the same
settings is not measured again (``--redo`` measures the lenses named
again), so the run can go in parts. The SFRA record also holds the noise
the model's own noisy renders show (``model_noise``, whence the loop's σ)
over the captures' (``model_noise_ratio``, 1.0 for a right noise model).
Prints one JSON object as the last line. Usage::

    python -m benchmarks.forward_fidelity [--lenses e1 e2 e9 e11] [--seed 5] [--size 2000 1500]
    python -m benchmarks.forward_fidelity --label simulator_psf --window-um 45 --wavelengths 3
    python -m benchmarks.forward_fidelity --label psf_map --psf-map [--full-size]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # one BLAS thread per worker, set before numpy loads
    _harness.pin_threads(2, blas=1)

import dataclasses  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402


from benchmarks.capture_roundtrip import capture_pair, fidelity  # noqa: E402
from calibration.fit.forward_model import ModelSettings  # noqa: E402
from calibration.loop.base import psf_map_model  # noqa: E402
from calibration.sfr.esfr import DEFAULT_METHOD  # noqa: E402
from isp.runtime.executor import pool_executor  # noqa: E402

PHONE = _harness.ROOT.parent / "shared" / "data" / "lenses" / "phone"
#: short names of the phone lenses → their prescriptions
LENSES = {"e1": "US-11906710-B2-e1", "e2": "US-12210142-B2-e2", "e9": "US-12210142-B2-e9",
          "e11": "US-11933948-B2-e11"}


def full_size(path) -> tuple[int, int]:
    """``(width, height)`` of the sensor a prescription names, pixels."""
    from calibration.optics.io import read_lens

    s = read_lens(path).sensor
    return int(s.width_px), int(s.height_px)


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--lenses", nargs="+", default=list(LENSES), choices=list(LENSES))
    ap.add_argument("--seed", type=int, default=5, help="the device of each lens (isp calib simulate --seed)")
    ap.add_argument("--size", type=int, nargs=2, default=[2000, 1500], metavar=("W", "H"))
    ap.add_argument("--full-size", action="store_true", help="each lens at its own sensor's size instead of --size")
    ap.add_argument("--exposure", type=float, default=0.8, help="chart white level (isp calib simulate's default)")
    ap.add_argument("--method", default=DEFAULT_METHOD, choices=("accurate", "iso"))
    ap.add_argument("--window-um", type=float, help="the model's PSF window, µm (default the fitter's)")
    ap.add_argument("--psf-map", action="store_true",
                    help="the model sampling the PSF as the capture's PSF map does (window, pupil grid, "
                         "wavelengths; calibration.loop.base.psf_map_model)")
    ap.add_argument("--wavelengths", type=int, help="the model's Gauss nodes per channel (default the fitter's)")
    ap.add_argument("--pupil-samples", type=int,
                    help="the model's pupil grid (default the fitter's, grown with a wider window)")
    ap.add_argument("--noise-realisations", type=int, help="noisy renders per edge of the bias (default the fitter's)")
    ap.add_argument("--label", default="fitter", help="the model's name in the results (default fitter)")
    ap.add_argument("--redo", action="store_true", help="measure the lenses again even where recorded")
    args = ap.parse_args(argv)

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    model = ModelSettings()
    if args.window_um:
        model = model.with_window(args.window_um)
    if args.wavelengths:
        model = dataclasses.replace(model, n_wavelengths=args.wavelengths)
    if args.noise_realisations:
        model = dataclasses.replace(model, noise_realisations=args.noise_realisations)
    if args.pupil_samples:
        model = dataclasses.replace(model, pupil_samples=args.pupil_samples)
    if args.psf_map and (args.window_um or args.wavelengths or args.pupil_samples):
        ap.error("--psf-map sets the window, the wavelengths and the pupil grid")
    settings = {"seed": args.seed, "size": "full" if args.full_size else list(args.size), "exposure": args.exposure,
                "method": args.method,
                "model": {"noise_realisations": model.noise_realisations, **(
                    {"psf_map": True} if args.psf_map else
                    {"window_um": model.window_um, "pupil_samples": model.pupil_samples,
                     "n_wavelengths": model.n_wavelengths})}}
    path = _harness.results_dir(args) / "forward_fidelity.json"
    models = json.loads(path.read_text()).get("results", {}).get("models", {}) if path.is_file() else {}
    mine = models.get(args.label, {})
    done = mine.get("lenses", {}) if mine.get("settings") == settings else {}
    for name in args.lenses:
        if name in done and not args.redo:
            log(f"{name}: recorded, skipped (--redo to measure again)")
            continue
        t0 = time.perf_counter()
        log(f"{name}: capturing the device twice ...")
        lens_path = PHONE / f"{LENSES[name]}.zmx"
        size = full_size(lens_path) if args.full_size else args.size
        device, what, nominal, obs = capture_pair(lens_path, args.seed, size,
                                                  args.exposure, [args.method], log)
        used = (dataclasses.replace(psf_map_model(nominal.sensor), noise_realisations=model.noise_realisations)
                if args.psf_map else model)
        with pool_executor(2) as ex:
            rec = fidelity(nominal, obs[args.method], device, ex, used)
        rec.update(window_um=round(used.window_um, 2), pupil_samples=used.pupil_samples,
                   n_wavelengths=used.n_wavelengths, size=list(size), lens=LENSES[name], device=what,
                   seconds=round(time.perf_counter() - t0, 1))
        done[name] = rec
        odd = rec.get("odd", {})
        log(f"{name}: SFRA ratio {rec['sfra']['ratio']:.2f} (residual {rec['sfra']['residual']:.4f}, noise "
            f"{rec['sfra']['noise']:.4f}); bands " + " ".join(f"{r:.2f}" for r in rec["bands"]["ratio"])
            + (f"; asymmetry chi2/term {odd['chi2_per_term']:.2f}" if odd else "") + f" ({rec['seconds']} s)")
        # each lens is kept as it finishes: the run can stop and go on
        models[args.label] = {"settings": settings, "lenses": done}
        _harness.publish("forward_fidelity", {"models": models}, args, argv)
    models[args.label] = {"settings": settings, "lenses": done}
    return _harness.publish("forward_fidelity", {"models": models}, args, argv)


if __name__ == "__main__":
    main()

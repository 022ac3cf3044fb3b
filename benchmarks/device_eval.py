"""The device-aware correction evaluated as a production line would run it.

For each of ``--devices`` modules of a lens design, drawn within tolerance and
refocused as the evaluation draws its unseen lenses
(:func:`restoration.evaluate.rings.eval_lenses`, disjoint from training's
draws), the line's steps are run and scored:

1. the module's true lens file and its true descriptor
   (:func:`calibration.fit.device.device_calibration` on ``--basis``);
2. its chart capture simulated (``isp calib simulate --size 2000,1500``) and
   its proxy fitted with the descriptor written (``isp calib fit --basis``):
   the fitted ``device.json`` and the fit's time;
3. ``isp eval`` on the held-out images through the module's true lens, at
   the default light and at a bright one (0–0.5 EV, 0.25–0.5× the noise):
   the blind model, the conditioned model with the fitted file and with the
   true one, Wiener deconvolution with the true PSF (the evaluation's
   baseline) and, with ``--per-device-model DIR``, a model trained on that
   module alone (``DIR/LENS_DEV/model.pt``, the bound; trained elsewhere).

Each module's record is kept in ``benchmarks/results/device_eval_parts/``
(a finished step is not run again), and the summary, per field ring and
light, is the mean gain over uncorrected across modules, against the
targets: at FoV 0.9 the fitted-file model keeps ≥ 90 % of the per-device
model's gain (≥ +1.5 dB at the default light) and ≥ 2× the blind model's;
at the default light it beats Wiener at every ring; at no ring of any module,
at either light, is it below uncorrected.

Usage::

    python -m benchmarks.device_eval --model out/e9_device48/model.pt --basis out/e9_basis.npz \\
        [--blind modules/models/e9_default.int8.onnx] [--devices 6] [--lens e9]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":
    _harness.pin_threads(2, blas=1)

import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.correction_quality import PACKAGED, held_out_folder  # noqa: E402
from benchmarks.forward_fidelity import LENSES, PHONE  # noqa: E402

PARTS = _harness.ROOT / "benchmarks" / "results" / "device_eval_parts"
#: the lights: (exposure EV range, noise-scale range); None: the training's
LIGHTS = {"default": (None, None), "bright": ((0.0, 0.5), (0.25, 0.5))}
RINGS = ("0.1", "0.5", "0.9")


def _save(path: Path, rec: dict) -> None:
    from isp.io.files import write_bytes_atomic

    write_bytes_atomic(path, (json.dumps(rec, indent=1) + "\n").encode())


def prepare(rec: dict, work: Path, lens_path: Path, pl, basis_path: Path, size: str, fit_args: list) -> dict:
    """Steps 1 and 2 for one module (skipped where ``rec`` has them)."""
    from calibration.fit.device import device_calibration, load_basis
    from calibration.fit.proxy import save_proxy
    from isp.cli.main import main as isp

    work.mkdir(parents=True, exist_ok=True)
    true_lens, true_dev = work / "lens.json", work / "true_device.json"
    if not true_dev.is_file():
        save_proxy(true_lens, pl.nominal, pl.perturbation)
        device_calibration(pl, load_basis(basis_path, pl), source={"measured": "the module's true lens"}).save(true_dev)
    cap, fit = work / "capture.dng", work / "fit"
    if "fit" not in rec and (fit / "device.json").is_file():    # fitted by an earlier run into this work folder
        f = json.loads((fit / "fit.json").read_text())
        rec["fit"] = {"seconds": None, "fit_seconds": f["seconds"], "sfra_rms_before": f["errors"]["before"]["sfra_rms"],
                      "sfra_rms_after": f["errors"]["after"]["sfra_rms"]}
    if "fit" not in rec:
        t0 = time.perf_counter()
        if not cap.is_file() and isp(["calib", "simulate", str(true_lens), "-o", str(cap), "--size", size]) != 0:
            raise RuntimeError(f"{cap}: the simulation failed")
        if isp(["calib", "fit", "--lens", str(lens_path), "--measured", str(cap), "--basis", str(basis_path),
                "-o", str(fit), *fit_args]) != 0:
            raise RuntimeError(f"{fit}: the fit failed")
        f = json.loads((fit / "fit.json").read_text())
        rec["fit"] = {"seconds": round(time.perf_counter() - t0, 1), "fit_seconds": f["seconds"],
                      "sfra_rms_before": f["errors"]["before"]["sfra_rms"],
                      "sfra_rms_after": f["errors"]["after"]["sfra_rms"]}
    return {"true_lens": true_lens, "true": true_dev, "fitted": fit / "device.json"}


def score(model, images: Path, lens_file: Path, light: str, positions: int, device=None) -> dict:
    """Per ring: PSNR uncorrected, corrected, Wiener (dB), and the crops."""
    from isp.io.device import DeviceCalibration
    from isp.runtime.executor import create_executor
    from restoration.evaluate.rings import EvalSettings, evaluate

    ev, ns = LIGHTS[light]
    settings = EvalSettings(samples=0, with_proxy=True, positions=positions, exposure_ev=ev, noise_scale=ns)
    cal = DeviceCalibration.load(device) if device is not None else None
    rep = evaluate(str(model), images, str(lens_file), settings, device=cal,
                   executor=create_executor("serial", progress=False))
    return {r: {k: rep["rings"][r][k] for k in ("psnr_uncorrected", "psnr_corrected", "psnr_baseline", "crops")}
            for r in RINGS}


def summarise(records: list[dict]) -> dict:
    """Mean gain over uncorrected per light, arm and ring; the targets."""
    out = {}
    for light in LIGHTS:
        arms = {}
        for arm in ("blind", "fitted", "true", "per_device", "wiener"):
            per = []
            for rec in records:
                s = rec.get("scores", {}).get(light, {})
                src = s.get("blind") if arm == "wiener" else s.get(arm)
                if src is None:
                    continue
                key = "psnr_baseline" if arm == "wiener" else "psnr_corrected"
                per.append([src[r][key] - src[r]["psnr_uncorrected"] for r in RINGS])
            if per:
                a = np.asarray(per)
                arms[arm] = {"devices": len(per), "mean_gain_db": dict(zip(RINGS, a.mean(0).round(3).tolist())),
                             "min_gain_db": dict(zip(RINGS, a.min(0).round(3).tolist()))}
        out[light] = arms
    d = out.get("default", {})
    g = {k: v["mean_gain_db"] for k, v in d.items()}
    targets = {}
    if "fitted" in g:
        f9 = g["fitted"]["0.9"]
        targets["fitted_0.9_at_least_1.5_db"] = f9 >= 1.5
        if "blind" in g:
            targets["fitted_0.9_twice_blind"] = f9 >= 2 * g["blind"]["0.9"]
        if "per_device" in g:
            targets["fitted_0.9_90pct_of_per_device"] = f9 >= 0.9 * g["per_device"]["0.9"]
        if "wiener" in g:
            targets["fitted_beats_wiener_every_ring"] = all(g["fitted"][r] > g["wiener"][r] for r in RINGS)
        targets["fitted_never_below_uncorrected"] = all(
            out[light]["fitted"]["min_gain_db"][r] >= 0 for light in out if "fitted" in out[light] for r in RINGS)
    out["targets"] = targets
    return out


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--model", required=True, help="the conditioned model (checkpoint or ONNX)")
    ap.add_argument("--basis", required=True, help="the design's descriptor basis (isp calib basis)")
    ap.add_argument("--blind", default=str(PACKAGED), help="the blind model (default: the packaged one)")
    ap.add_argument("--per-device-model", metavar="DIR", help="DIR/LENS_DEV/model.pt: a model per module")
    ap.add_argument("--lens", default="e9", choices=list(LENSES))
    ap.add_argument("--devices", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0, help="of the modules' draws (the evaluation's lens seed)")
    ap.add_argument("--positions", type=int, default=2, help="places per ring and image (default 2)")
    ap.add_argument("--size", default="2000,1500", help="the chart capture's W,H (default 2000,1500)")
    ap.add_argument("--fit-args", default="", help="extra `isp calib fit` options, one string")
    ap.add_argument("--work", default="out/device_eval", help="captures, fits and lens files (default out/device_eval)")
    ap.add_argument("--redo", action="store_true", help="score the modules again (the fits are kept)")
    ap.add_argument("--parts", default=str(PARTS), help=f"per-module records (default {PARTS.relative_to(_harness.ROOT)})")
    args = ap.parse_args(argv)

    from restoration.evaluate.rings import eval_lenses
    from restoration.synth.optics import load_lens

    lens_path = PHONE / f"{LENSES[args.lens]}.zmx"
    lenses = eval_lenses(load_lens(lens_path), args.devices, args.seed)
    parts = Path(args.parts)
    parts.mkdir(parents=True, exist_ok=True)
    records = []
    with tempfile.TemporaryDirectory() as tmp:
        images = held_out_folder(Path(tmp))
        for d, pl in enumerate(lenses):
            part = parts / f"{args.lens}_{args.seed}_{d}.json"
            rec = json.loads(part.read_text()) if part.is_file() else {"lens": LENSES[args.lens], "device": d}
            if args.redo:
                rec.pop("scores", None)
            files = prepare(rec, Path(args.work) / f"{args.lens}_{args.seed}_{d}", lens_path, pl, Path(args.basis),
                            args.size, args.fit_args.split())
            _save(part, rec)
            scores = rec.setdefault("scores", {})
            arms = {"blind": (args.blind, None), "fitted": (args.model, files["fitted"]),
                    "true": (args.model, files["true"])}
            if args.per_device_model:
                own = Path(args.per_device_model) / f"{args.lens}_{args.seed}_{d}" / "model.pt"
                if own.is_file():
                    arms["per_device"] = (own, None)
            for light in LIGHTS:
                for arm, (model, dev) in arms.items():
                    if arm in scores.get(light, {}):
                        continue
                    scores.setdefault(light, {})[arm] = score(model, images, files["true_lens"], light,
                                                              args.positions, dev)
                    _save(part, rec)
            g = {a: round(s["0.9"]["psnr_corrected"] - s["0.9"]["psnr_uncorrected"], 2)
                 for a, s in scores["default"].items()}
            print(f"{args.lens} module {d}: gain at FoV 0.9, default light: {g}", flush=True)
            records.append(rec)
    summary = summarise(records)
    for light in LIGHTS:
        for arm, v in summary[light].items():
            print(f"{light:>7} {arm:>10}: " + ", ".join(f"{r} {v['mean_gain_db'][r]:+.2f}" for r in RINGS)
                  + f" dB (min {v['min_gain_db']['0.9']:+.2f} at 0.9; {v['devices']} modules)")
    print("targets: " + ", ".join(f"{k} {'met' if v else 'NOT met'}" for k, v in summary["targets"].items()))
    return _harness.publish("device_eval", {"lens": LENSES[args.lens], "modules": len(records),
                                            "summary": summary, "records": records}, args, argv)


if __name__ == "__main__":
    main()

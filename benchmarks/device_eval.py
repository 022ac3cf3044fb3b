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
   module alone (``DIR/LENS_DEV/model.pt``, the bound; trained elsewhere);
4. with ``--wrong``, the conditioned model given a wrong calibration: the
   next module's fitted file (``other``) and the design's nominal lens's
   (``nominal``). A file for another lens design never gets this far: the
   correction stage refuses it (tests/restoration/train/test_device_training.py);
5. with ``--quick``, the module calibrated as a line in a hurry would:
   ``isp calib fit --fine-iter 0`` (the coarse 5 × 7 sub-grid's fit, the
   descriptor's own regions), its time (``fit_quick``) and its score (``quick``);
6. with ``--skimage``, blind, fitted and true once more on scikit-image's
   photographs, which the project never trained or tuned on (``skimage``,
   the default light);
7. with ``--extra NAME=MODEL``, other conditioned models (a variant, a longer
   training) with each module's fitted file, as arm ``NAME`` (the
   conditioned design's ablations, :mod:`benchmarks.ablations`).

Each module's record is kept in ``benchmarks/results/device_eval_parts/``
(a finished step is not run again), and the summary, per field ring and
light, is the mean gain over uncorrected across modules, against the
targets: at FoV 0.9 the fitted-file model keeps ≥ 90 % of the per-device
model's gain (≥ +1.5 dB at the default light) and ≥ 2× the blind model's;
at the default light it beats Wiener at every ring; at no ring of any module,
at either light, is it below uncorrected.

Usage::

    python -m benchmarks.device_eval --model out/e9_device48/model.pt --basis out/e9_basis.npz \\
        [--blind modules/models/e9_default.int8.onnx] [--devices 6] [--lens e9] \\
        [--per-device-model out/per_device] [--quick] [--wrong] [--skimage]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":
    _harness.pin_threads(2, blas=1)

import json  # noqa: E402
import shlex  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from benchmarks.correction_quality import PACKAGED, held_out_folder  # noqa: E402
from benchmarks.forward_fidelity import LENSES, PHONE  # noqa: E402

PARTS = _harness.ROOT / "benchmarks" / "results" / "device_eval_parts"
#: the lights: (exposure EV range, noise-scale range); None: the training's
LIGHTS = {"default": (None, None), "bright": ((0.0, 0.5), (0.25, 0.5)), "skimage": (None, None)}
#: the lights the targets are judged at
TARGET_LIGHTS = ("default", "bright")
#: scikit-image's colour photographs (never used by the project), scored as ``skimage`` at the default light
SKIMAGE = ("astronaut", "coffee", "rocket", "chelsea")
#: the arms scored on scikit-image's images (the study's end, not its every arm)
SKIMAGE_ARMS = ("blind", "fitted", "true")
RINGS = ("0.1", "0.5", "0.9")
#: arms in the order the tables and the plot show them, and their labels (``--extra`` arms follow)
ARMS = {"blind": "blind model", "fitted": "conditioned, fitted file", "quick": "conditioned, quick fit",
        "true": "conditioned, true descriptor", "per_device": "per-device model (bound)",
        "other": "conditioned, another module's file", "nominal": "conditioned, the nominal lens's file",
        "wiener": "Wiener, true PSF"}


def skimage_folder(into: Path) -> Path:
    """scikit-image's colour photographs (:data:`SKIMAGE`) as PNG files in ``into``."""
    import cv2
    import skimage.data

    into.mkdir(parents=True, exist_ok=True)
    for name in SKIMAGE:
        cv2.imwrite(str(into / f"skimage_{name}.png"), getattr(skimage.data, name)()[..., ::-1])
    return into


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
    cap = work / "capture.dng"
    if "fit" not in rec and not (work / "fit" / "device.json").is_file():
        t0 = time.perf_counter()
        if not cap.is_file() and isp(["calib", "simulate", str(true_lens), "-o", str(cap), "--size", size]) != 0:
            raise RuntimeError(f"{cap}: the simulation failed")
        fit_module(rec, "fit", work, lens_path, basis_path, fit_args, t0)
    elif "fit" not in rec:          # fitted by an earlier run into this work folder: its time is unknown
        fit_module(rec, "fit", work, lens_path, basis_path, fit_args, None)
    return {"true_lens": true_lens, "true": true_dev, "fitted": work / "fit" / "device.json"}


def fit_module(rec: dict, key: str, work: Path, lens_path: Path, basis_path: Path, fit_args: list,
               t0: float | None = 0.0) -> Path:
    """``isp calib fit --basis`` on the module's capture into ``work/KEY``
    (the full fit, ``"fit"``; the line's quick one, ``"fit_quick"``:
    ``--fine-iter 0``, the coarse sub-grid's fit alone), and its summary in
    ``rec[key]``: seconds since ``t0`` (0: from now; None: not run here,
    the folder's earlier fit is read), the fit's own seconds and SFRA
    errors. Its ``device.json``."""
    from isp.cli.main import main as isp

    fit = work / key
    if t0 is not None:
        t0 = t0 or time.perf_counter()
        quick = ["--fine-iter", "0"] if key == "fit_quick" else []
        if isp(["calib", "fit", "--lens", str(lens_path), "--measured", str(work / "capture.dng"), "--basis",
                str(basis_path), *quick, "-o", str(fit), *fit_args]) != 0:
            raise RuntimeError(f"{fit}: the fit failed")
    f = json.loads((fit / "fit.json").read_text())
    rec[key] = {"seconds": None if t0 is None else round(time.perf_counter() - t0, 1), "fit_seconds": f["seconds"],
                "sfra_rms_before": f["errors"]["before"]["sfra_rms"], "sfra_rms_after": f["errors"]["after"]["sfra_rms"]}
    return fit / "device.json"


def nominal_file(work: Path, lens_path: Path, basis_path: Path) -> Path:
    """The design's nominal lens as a device file (a wrong calibration for
    every module that is not exactly nominal)."""
    from calibration.fit.device import device_calibration, load_basis
    from restoration.synth.optics import load_lens

    out = work / "nominal_device.json"
    if not out.is_file():
        lens = load_lens(lens_path)
        device_calibration(lens, load_basis(basis_path, lens), source={"measured": "the design's nominal lens"}).save(out)
    return out


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
        for arm in arm_names(records):
            per = [[gain(rec.get("scores", {}).get(light, {}), arm, r) for r in RINGS] for rec in records]
            per = [p for p in per if None not in p]
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
        if "per_device" in g:   # on the modules that have a per-device model
            pairs = [(gain(sc, "fitted", "0.9"), gain(sc, "per_device", "0.9"))
                     for sc in (rec.get("scores", {}).get("default", {}) for rec in records)]
            both = [pr for pr in pairs if None not in pr]
            f, b = np.mean(both, axis=0)
            out["fitted_share_of_per_device_0.9"] = {"modules": len(both), "fitted_db": round(float(f), 3),
                                                     "per_device_db": round(float(b), 3),
                                                     "share": round(float(f / b), 3)}
            targets["fitted_0.9_90pct_of_per_device"] = bool(f >= 0.9 * b)
        if "wiener" in g:
            targets["fitted_beats_wiener_every_ring"] = all(g["fitted"][r] > g["wiener"][r] for r in RINGS)
        targets["fitted_never_below_uncorrected"] = all(
            out[light]["fitted"]["min_gain_db"][r] >= 0 for light in TARGET_LIGHTS if "fitted" in out[light]
            for r in RINGS)
    for arm in ("other", "nominal"):    # a wrong calibration loses at most 0.2 dB against uncorrected
        if any(arm in out[light] for light in TARGET_LIGHTS):
            targets[f"{arm}_loses_at_most_0.2_db"] = all(
                out[light][arm]["min_gain_db"][r] >= -0.2 for light in TARGET_LIGHTS if arm in out[light]
                for r in RINGS)
    out["targets"] = targets
    return out


def arm_names(records: list[dict]) -> list[str]:
    """The arms scored in ``records`` (``wiener`` wherever ``blind`` is, its
    baseline): :data:`ARMS`'s in its order, then the others (``--extra``'s)
    in the order first met."""
    scored = list(dict.fromkeys(a for rec in records for light in rec.get("scores", {}).values() for a in light))
    if "blind" in scored:
        scored.append("wiener")
    return [a for a in ARMS if a in scored] + [a for a in scored if a not in ARMS]


def gain(scores: dict, arm: str, ring: str) -> float | None:
    """One module's gain over uncorrected (dB) for an arm at a ring; None where not scored."""
    src = scores.get("blind") if arm == "wiener" else scores.get(arm)
    if src is None:
        return None
    return round(src[ring]["psnr_baseline" if arm == "wiener" else "psnr_corrected"] - src[ring]["psnr_uncorrected"], 3)


def per_module(records: list[dict], light: str, ring: str = "0.9") -> list[dict]:
    """One row per module at ``ring``: uncorrected PSNR and every arm's gain."""
    rows = []
    for rec in records:
        s = rec.get("scores", {}).get(light, {})
        if "blind" not in s:
            continue
        row = {"module": rec["device"], "uncorrected_db": round(s["blind"][ring]["psnr_uncorrected"], 2)}
        for arm in arm_names(records):
            g = gain(s, arm, ring)
            if g is not None:
                row[arm] = round(g, 2)
        rows.append(row)
    return rows


def plot(records: list[dict], path: Path, lens: str) -> Path:
    """Per module and ring, each arm's gain over uncorrected at every light
    scored (PNG, written atomically); the ``--extra`` variants are left out."""
    import io

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from isp.io.files import write_bytes_atomic

    lights = [k for k in LIGHTS if any(k in r.get("scores", {}) for r in records)]
    fig, axes = plt.subplots(len(lights), len(RINGS), figsize=(4.2 * len(RINGS), 3.2 * len(lights)),
                             sharey="row", squeeze=False)
    names = [a for a in arm_names(records) if a in ARMS]    # the variants (--extra) are the tables' to show
    colours = dict(zip(names, plt.get_cmap("tab10").colors))
    for i, light in enumerate(lights):
        for j, ring in enumerate(RINGS):
            ax = axes[i, j]
            shown = [a for a in names if any(gain(r.get("scores", {}).get(light, {}), a, ring) is not None
                                            for r in records)]
            width = 0.8 / max(len(shown), 1)
            for k, arm in enumerate(shown):
                xs, ys = [], []
                for m, rec in enumerate(records):
                    g = gain(rec.get("scores", {}).get(light, {}), arm, ring)
                    if g is not None:
                        xs.append(m + (k - (len(shown) - 1) / 2) * width)
                        ys.append(g)
                ax.bar(xs, ys, width, color=colours[arm], label=ARMS.get(arm, arm))
            ax.axhline(0, color="k", lw=0.6)
            ax.set_xticks(range(len(records)), [str(r["device"]) for r in records], fontsize=7)
            ax.set_title(f"{'scikit-image photos, default' if light == 'skimage' else light} light, FoV {ring}",
                         fontsize=9)
            ax.grid(axis="y", alpha=0.3)
            ax.tick_params(labelsize=7)
            if j == 0:
                ax.set_ylabel("gain over uncorrected (dB)", fontsize=8)
            if i == len(lights) - 1:
                ax.set_xlabel(f"{lens} module", fontsize=8)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 4), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=96)
    plt.close(fig)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_bytes_atomic(path, buf.getvalue())


def line_arguments(ap, devices: int, seed: int) -> None:
    """The options a production line's benchmark shares: the conditioned
    model, the design's basis, the lens, how many modules from which seed,
    and the chart capture's size."""
    ap.add_argument("--model", required=True, help="the conditioned model (checkpoint or ONNX; INT8 as shipped)")
    ap.add_argument("--basis", required=True, help="the design's descriptor basis (isp calib basis)")
    ap.add_argument("--lens", default="e9", choices=list(LENSES))
    ap.add_argument("--devices", type=int, default=devices, help=f"modules (default {devices})")
    ap.add_argument("--seed", type=int, default=seed, help=f"of the modules' draws (default {seed})")
    ap.add_argument("--size", default="2000,1500", help="the chart capture's W,H (default 2000,1500)")


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    line_arguments(ap, devices=6, seed=0)
    ap.add_argument("--blind", default=str(PACKAGED), help="the blind model (default: the packaged one)")
    ap.add_argument("--per-device-model", metavar="DIR", help="DIR/LENS_DEV/model.pt: a model per module")
    ap.add_argument("--positions", type=int, default=2, help="places per ring and image (default 2)")
    ap.add_argument("--fit-args", default="", help="extra `isp calib fit` options, one string")
    ap.add_argument("--work", default="out/device_eval", help="captures, fits and lens files (default out/device_eval)")
    ap.add_argument("--redo", action="store_true", help="score the modules again (the fits are kept)")
    ap.add_argument("--wrong", action="store_true",
                    help="also score wrong calibrations: the next module's file and the nominal lens's")
    ap.add_argument("--quick", action="store_true",
                    help="also calibrate each module with the line's quick fit (--fine-iter 0) and score it")
    ap.add_argument("--figure", help="the per-module plot (default docs/results/device_eval_LENS.png)")
    ap.add_argument("--no-plot", action="store_true", help="write no plot")
    ap.add_argument("--extra", nargs="+", default=[], metavar="NAME=MODEL",
                    help="other conditioned models scored with each module's fitted file (arm NAME; with --wrong "
                         "also another module's file, arm NAME_other)")
    ap.add_argument("--lights", nargs="+", choices=list(LIGHTS), default=list(LIGHTS),
                    help="the lights to score (default all; skimage needs --skimage)")
    ap.add_argument("--skimage", action="store_true",
                    help="also score blind, fitted and true on scikit-image's photographs (default light)")
    ap.add_argument("--fit-only", action="store_true", help="simulate and fit the modules, score nothing")
    ap.add_argument("--parts", default=str(PARTS), help=f"per-module records (default {PARTS.relative_to(_harness.ROOT)})")
    ap.add_argument("--label", help="publish as device_eval_LABEL.json (another model's run beside the recorded one; "
                                    "give it its own --parts)")
    args = ap.parse_args(argv)

    from restoration.evaluate.rings import eval_lenses
    from restoration.synth.optics import load_lens

    lens_path = PHONE / f"{LENSES[args.lens]}.zmx"
    lenses = eval_lenses(load_lens(lens_path), args.devices, args.seed)
    extra = dict(a.split("=", 1) for a in args.extra)
    lights = [k for k in args.lights if k != "skimage" or args.skimage]
    parts = Path(args.parts)
    parts.mkdir(parents=True, exist_ok=True)
    records = []
    with tempfile.TemporaryDirectory() as tmp:
        folders = {"held_out": held_out_folder(Path(tmp)), "skimage": skimage_folder(Path(tmp) / "skimage")}
        work = [Path(args.work) / f"{args.lens}_{args.seed}_{d}" for d in range(len(lenses))]
        # every module is fitted before any is scored: the wrong-file arms read the next module's file
        prepared, fit_args = [], shlex.split(args.fit_args)
        for d, pl in enumerate(lenses):
            part = parts / f"{args.lens}_{args.seed}_{d}.json"
            rec = json.loads(part.read_text()) if part.is_file() else {"lens": LENSES[args.lens], "device": d}
            if args.redo:
                rec.pop("scores", None)
            files = prepare(rec, work[d], lens_path, pl, Path(args.basis), args.size, fit_args)
            _harness.write_record(part, rec)
            if args.quick:
                files["quick"] = work[d] / "fit_quick" / "device.json"
                if "fit_quick" not in rec or not files["quick"].is_file():
                    fit_module(rec, "fit_quick", work[d], lens_path, Path(args.basis), fit_args)
                    _harness.write_record(part, rec)
            prepared.append((part, rec, files))
        for d, (part, rec, files) in enumerate(prepared):
            if args.fit_only:
                break
            scores = rec.setdefault("scores", {})
            arms = {"blind": (args.blind, None), "fitted": (args.model, files["fitted"]),
                    "true": (args.model, files["true"])}
            if args.per_device_model:
                own = Path(args.per_device_model) / f"{args.lens}_{args.seed}_{d}" / "model.pt"
                if own.is_file():
                    arms["per_device"] = (own, None)
            if args.quick:
                arms["quick"] = (args.model, files["quick"])
            other = work[(d + 1) % len(lenses)] / "fit" / "device.json"
            for name, model in extra.items():    # other models, each with the fitted file (and a wrong one)
                arms[name] = (model, files["fitted"])
                if args.wrong and other.is_file():
                    arms[f"{name}_other"] = (model, other)
            if args.wrong:
                if other.is_file():
                    arms["other"] = (args.model, other)
                arms["nominal"] = (args.model, nominal_file(Path(args.work), lens_path, Path(args.basis)))
            for light in lights:
                images = folders["skimage" if light == "skimage" else "held_out"]
                for arm, (model, dev) in arms.items():
                    if arm in scores.get(light, {}) or (light == "skimage" and arm not in SKIMAGE_ARMS):
                        continue
                    scores.setdefault(light, {})[arm] = score(model, images, files["true_lens"], light,
                                                              args.positions, dev)
                    _harness.write_record(part, rec)
            g = {a: round(gain(scores["default"], a, "0.9"), 2) for a in scores["default"]}
            print(f"{args.lens} module {d}: gain at FoV 0.9, default light: {g}", flush=True)
            records.append(rec)
    if args.fit_only:
        return {}
    summary = summarise(records)
    suffix = f"_{args.label}" if args.label and args.label != args.lens else ""
    figure = Path(args.figure or _harness.ROOT / "docs" / "results" / f"device_eval_{args.lens}{suffix}.png")
    if not args.no_plot:
        print(f"wrote {plot(records, figure, LENSES[args.lens])}")
    for light in LIGHTS:
        for arm, v in summary.get(light, {}).items():
            print(f"{light:>7} {arm:>10}: " + ", ".join(f"{r} {v['mean_gain_db'][r]:+.2f}" for r in RINGS)
                  + f" dB (min {v['min_gain_db']['0.9']:+.2f} at 0.9; {v['devices']} modules)")
    print("targets: " + ", ".join(f"{k} {'met' if v else 'NOT met'}" for k, v in summary["targets"].items()))
    return _harness.publish("device_eval",
                            {"lens": LENSES[args.lens], "modules": len(records), "summary": summary,
                             "per_module_0.9": {light: per_module(records, light) for light in LIGHTS},
                             "records": records}, args, argv, label=args.label)


if __name__ == "__main__":
    main()

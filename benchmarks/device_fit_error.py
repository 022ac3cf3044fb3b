"""How far a fitted ``device/v1`` file is from its module's truth, and what
decides it.

``benchmarks/device_eval.py`` leaves, per module of its ``--work`` folder,
the module's true descriptor (``true_device.json``: its true lens's PSF map
on the design's basis) and the file the line's fit wrote from the module's
simulated chart capture (``fit/device.json``, beside the fit's
``fit.json``). This script reads those folders and reports, per module:

* the **descriptor error**: RMS over regions and components of fitted −
  true, in units of each component's spread over the design's tolerances
  (the unit the descriptor is stored in, :mod:`isp.io.device`; the true
  descriptors themselves are about 1 RMS, so an all-zero file, the
  design's mean PSFs, is about 1 from the truth), and the correlation of
  the two descriptors;
* the fit's **χ² per observation** at its end (the noise floor is about 1;
  the true lens through the fitting model scores about 2–3,
  ``benchmarks/forward_fidelity.py``) and its SFRA RMS error;
* the parameters it fitted and the restarts it probed.

Per folder: the mean error, the median χ²; pooled over every folder: the
correlation between χ² and the descriptor error. Nothing is fitted here:
the folders are what ``device_eval.py`` (its ``--fit-args``) left.

``--best-into DIR`` also assembles, per module, the fit of the lowest χ² per
observation among the folders (a choice the line can make: χ² needs no
truth; ``isp calib fit --try`` makes it within one run) into a work folder of
its own, which ``device_eval.py --work DIR`` then scores as any other (it
finds every module fitted). Usage::

    python -m benchmarks.device_fit_error --work e9=out/device_eval_packaged e2=out/device_eval_e2_auto
    python -m benchmarks.device_fit_error --work np48=out/device_eval_e2_np48 all_kinds=out/device_eval_e2_all \
        --best-into out/device_eval_e2_best2 --label e2_best2
"""

from __future__ import annotations

from benchmarks import _harness

import json  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


def module_error(folder: Path, fit: str = "fit") -> dict | None:
    """One module's fitted file against its truth (None where either is missing)."""
    from isp.io.device import DeviceCalibration

    true_path, fit_path = folder / "true_device.json", folder / fit / "device.json"
    if not (true_path.is_file() and fit_path.is_file()):
        return None
    t = np.asarray(DeviceCalibration.load(true_path).descriptor, float)
    f = np.asarray(DeviceCalibration.load(fit_path).descriptor, float)
    rec = json.loads((folder / fit / "fit.json").read_text())
    return {"module": folder.name, "descriptor_rms_error": round(float(np.sqrt(np.mean((f - t) ** 2))), 4),
            "descriptor_rms_true": round(float(np.sqrt(np.mean(t ** 2))), 4),
            "correlation": round(float(np.corrcoef(t.ravel(), f.ravel())[0, 1]), 3),
            "chi2_per_obs": round(float(rec["errors"]["after"]["chi2_per_obs"]), 2),
            "sfra_rms": round(float(rec["errors"]["after"]["sfra_rms"]), 5),
            "n_params": len(rec.get("parameters", {})) or None,
            "restarts": sum(isinstance(start.get("start"), int) for start in rec.get("restarts", [])),
            "fit_seconds": rec.get("seconds")}


def best_of(folders: dict, into: Path, fit: str = "fit") -> dict:
    """Copy, per module, the module folder (capture, true lens and
    descriptor) with the fit of the lowest χ² per observation among
    ``folders`` (name → device_eval work folder) into ``into``; returns
    ``{module: name of the folder chosen}``. A module already in ``into``
    is left as it is (its choice read back from ``into/chosen.json``)."""
    import shutil

    into.mkdir(parents=True, exist_ok=True)
    record = into / "chosen.json"
    chosen = json.loads(record.read_text()) if record.is_file() else {}
    modules = sorted({d.name for w in folders.values() for d in Path(w).glob("*_*_*")
                      if (d / fit / "fit.json").is_file()})
    for m in modules:
        if (into / m / fit / "fit.json").is_file() and m in chosen:
            continue
        chi2 = {name: json.loads((Path(w) / m / fit / "fit.json").read_text())["errors"]["after"]["chi2_per_obs"]
                for name, w in folders.items() if (Path(w) / m / fit / "fit.json").is_file()}
        name = min(chi2, key=chi2.get)
        if (into / m).exists():
            shutil.rmtree(into / m)
        shutil.copytree(Path(folders[name]) / m, into / m)
        chosen[m] = name
    for n in Path(next(iter(folders.values()))).glob("nominal_device.json"):
        shutil.copy2(n, into / n.name)
    record.write_text(json.dumps(chosen, indent=1))
    return chosen


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--work", nargs="+", required=True, metavar="NAME=DIR",
                    help="device_eval work folders, each named")
    ap.add_argument("--fit", default="fit", help="the fit's subfolder in each module (default fit; fit_quick)")
    ap.add_argument("--label", help="publish as device_fit_error_LABEL.json")
    ap.add_argument("--best-into", metavar="DIR",
                    help="also copy each module's lowest-χ² fit among the folders into DIR (reported as 'best')")
    args = ap.parse_args(argv)
    given = {}
    for spec in args.work:
        name, _, where = spec.partition("=")
        if not where:
            ap.error(f"--work {spec!r}: give NAME=DIR")
        given[name] = where
    chosen = best_of(given, Path(args.best_into), args.fit) if args.best_into else None
    folders, pooled = {}, []
    for name, where in {**given, **({"best": args.best_into} if chosen is not None else {})}.items():
        rows = [r for d in sorted(Path(where).glob("*_*_*")) if d.is_dir()
                for r in [module_error(d, args.fit)] if r is not None]
        if not rows:
            raise SystemExit(f"device_fit_error: {where}: no module with a true and a fitted file")
        folders[name] = {"work": where, "modules": rows,
                         "mean_descriptor_error": round(float(np.mean([r["descriptor_rms_error"] for r in rows])), 3),
                         "median_chi2_per_obs": round(float(np.median([r["chi2_per_obs"] for r in rows])), 2)}
        if name in given:   # the chosen fits are copies of the others: pooled once
            pooled += rows
        print(f"{name} ({where}):")
        for r in rows:
            print(f"  {r['module']}: χ²/obs {r['chi2_per_obs']:6.1f}, SFRA {r['sfra_rms']:.4f}, "
                  f"descriptor error {r['descriptor_rms_error']:.3f} (correlation {r['correlation']:.2f}), "
                  f"{r['n_params']} parameters")
        print(f"  mean error {folders[name]['mean_descriptor_error']:.3f}, "
              f"median χ²/obs {folders[name]['median_chi2_per_obs']:.1f}")
    if chosen is not None:
        print("lowest χ² per module: " + ", ".join(f"{m} from {n}" for m, n in chosen.items()))
    chi2 = np.array([r["chi2_per_obs"] for r in pooled])
    err = np.array([r["descriptor_rms_error"] for r in pooled])
    corr = float(np.corrcoef(chi2, err)[0, 1]) if len(pooled) > 2 else None
    if corr is not None:
        print(f"pooled over {len(pooled)} fits: correlation of χ²/obs and descriptor error {corr:.2f}")
    return _harness.publish("device_fit_error", {"folders": folders, "fits": len(pooled), "chosen": chosen,
                                                 "chi2_error_correlation": None if corr is None else round(corr, 3)},
                            args, argv, label=args.label)


if __name__ == "__main__":
    main()

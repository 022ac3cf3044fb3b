"""``isp calib loop``: close the loop on a measurement from the command line.

``isp calib loop --lens LENS --measured MEAS -o REPORT_DIR`` turns the
measurement into :class:`calibration.fit.observations.Observations`, builds the
base model (:mod:`calibration.loop.base`), runs
:func:`calibration.loop.closure.close_loop` and writes its report
(:func:`calibration.loop.closure.write_report`) plus a figure of the measured and
modelled SFR curves.

The measurement (``MEAS``: a capture, the JSON of ``isp calib sfr``, or
an ``sfr-observations/v1`` file) is read by
:func:`calibration.fit.measurements.load_measured`, whose module says how
edges are found, how few edges are split into segments, and what sensor
geometry is assumed.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from calibration.sfr.esfr import DEFAULT_METHOD
from isp.errors import ConfigError
from isp.runtime.executor import create_executor

EPILOG = """\
examples:
  isp calib loop --lens parametric --measured edge.tif --encoding linear
  isp calib loop --lens parametric --measured photo.jpg --encoding srgb --channel all -o photo_loop/
  isp calib loop --lens e9.json --measured capture.dng -o dev3_loop/ --max-effects 2
  isp calib sfr chart.png --chart --json chart.json && isp calib loop --lens parametric --measured chart.json
  isp calib loop --lens parametric --measured chart.png --effects sharpening,focus_shift,veiling_glare

what it does:
  fits the base model (a lens and its perturbations, or a parametric optical
  MTF: diffraction at F/N x Gaussian aberration blur x pixel aperture),
  estimates the noise floor from the data, tries every effect of the
  registry (sensor tilt, focus shift, field curvature, crosstalk, lateral
  colour, sharpening, glare; `--effects` to choose) by cross-validation over
  field regions, keeps the best while it explains held-out data, and writes
  REPORT_DIR/report.json, report.md, residual_maps.png and sfr_curves.png.
  A single-edge image is split along the edge into segments (see
  `calibration/fit/measurements.py`).
"""


# -- the command ---------------------------------------------------------------------------

def _effect_names(text: str | None) -> list[str] | None:
    from calibration.loop.effects import list_effects

    if not text:
        return None
    names = [n.strip() for n in text.split(",") if n.strip()]
    known = list_effects()
    bad = [n for n in names if n not in known]
    if bad:
        raise ConfigError(f"--effects: unknown effect {bad[0]!r}; registered: {', '.join(known)}")
    return names


def _n_params(text: str) -> int | None:
    """``--n-params``: a positive count, or "all" (None)."""
    if text.strip().lower() == "all":
        return None
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a count or 'all': {text!r}") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {n}")
    return n


def _check_args(args) -> None:
    if args.f_number not in (None, "fit"):
        try:
            n = float(args.f_number)
        except ValueError:
            raise ConfigError(f"--f-number {args.f_number!r}: a number (e.g. 2.8) or `fit`") from None
        if not 0.5 <= n <= 64:
            raise ConfigError(f"--f-number {n:g}: outside 0.5–64")
    if args.folds < 2:
        raise ConfigError(f"--folds {args.folds}: at least 2")
    if args.max_effects < 0:
        raise ConfigError(f"--max-effects {args.max_effects}: 0 or more")
    if not 8 <= args.min_edge <= 10000:
        raise ConfigError(f"--min-edge {args.min_edge:g}: outside 8–10000 px")
    if args.components < 1:
        raise ConfigError(f"--components {args.components}: at least 1")
    if args.pixel_um is not None and not 0.1 <= args.pixel_um <= 100:
        raise ConfigError(f"--pixel-um {args.pixel_um:g}: outside 0.1–100 µm")


def run(args: argparse.Namespace) -> int:
    """Measure, build the base model, close the loop, write the report folder."""
    import time

    from calibration.fit.measurements import load_measured
    from calibration.loop.base import make_base
    from calibration.loop.closure import close_loop, summary, write_report
    from calibration.report import check_output_folder, staged_folder

    t0 = time.perf_counter()
    _check_args(args)
    out = Path(args.output)
    check_output_folder(out)
    effects = _effect_names(args.effects)
    if args.lens != "parametric":
        from calibration.optics.io import read_lens

        read_lens(args.lens)                    # a bad lens file fails before any measurement
    obs, notes = load_measured(args.measured, channel=args.channel, encoding=args.encoding,
                               pixel_um=args.pixel_um, method=args.method, min_edge=args.min_edge,
                               executor=create_executor("serial", progress=True))
    regions = len({tuple(r) for r in obs.region})
    if args.lens == "parametric" and not (args.pixel_um or (obs.meta or {}).get("pixel_pitch_um")):
        notes.append(f"pixel pitch unknown: {obs.sensor.pixel_pitch_um:g} µm assumed (--pixel-um); only "
                     "λN/pitch is identified")
    if regions < 2:
        hint = ("pass the capture itself, whose edges are then split into segments"
                if Path(args.measured).suffix.lower() == ".json" else "a longer edge or a chart is needed")
        notes.append("one field region: effects cannot be cross-validated (none will be added) and the noise "
                     f"floor cannot be fitted from the data; {hint}")
    for n in notes:
        print(f"note: {n}")
    print(f"{args.measured}: {len(obs)} observations in {regions} field region(s)")
    if args.lens != "parametric":
        print("loop: tracing the lens and screening its perturbations (a few minutes on 2 cores)", flush=True)
    from calibration.fit.device import BASIS_WORDS, resolve_basis

    basis = None
    if args.lens == "parametric":
        if args.basis.lower() not in BASIS_WORDS:
            raise ConfigError("--basis: a device calibration needs a lens file, not --lens parametric")
    else:
        from calibration.optics.io import read_lens

        basis = resolve_basis(args.basis, read_lens(args.lens))
    base = make_base(args.lens, obs, f_number=args.f_number, n_params=args.n_params, pixel_um=args.pixel_um)
    obs = base.obs
    folds = max(2, min(args.folds, regions))
    if folds != args.folds:
        print(f"note: {folds} folds (the observations cover {regions} field region(s))")
    rep = close_loop(base, obs, effects=effects, folds=folds, max_effects=args.max_effects, seed=args.seed)
    with staged_folder(out) as tmp:
        write_report(rep, obs, tmp)
        _curves(base, rep, obs, tmp / "sfr_curves.png", args)
        if basis is not None:
            _device_file(base, rep, basis, args, tmp / "device.json")
    print(summary(rep))
    print(f"wrote {out}/report.json, report.md, residual_maps.png, sfr_curves.png"
          f"{', device.json' if basis is not None else ''} ({time.perf_counter() - t0:.0f} s)")
    return 0


def _device_file(base, rep, basis, args, path) -> None:
    """The device's ``device/v1`` calibration: the loop's final lens on the
    design's basis, and the effects it kept with their fitted values."""
    from calibration.fit.device import device_calibration, measurement_source

    effects = rep.kept_effects()
    fit = {"sfra_rms_before": rep.error_before.get("sfra_rms"), "sfra_rms_after": rep.error_after.get("sfra_rms"),
           "noise_floor": rep.noise_floor, "unexplained": list(rep.unexplained)}
    device_calibration(base.lens(rep.base_x), basis, min(args.components, basis.size), fit=fit,
                       effects=effects, source=measurement_source(args.measured)).save(path)


def _curves(base, rep, obs, path, args) -> None:
    """The SFR figure: measured, base model before, model after."""
    from calibration.loop.closure import model_sfr, plot_sfr_curves

    try:
        before = model_sfr(base, rep.base_x_before, {})
        after = model_sfr(base, rep.base_x, rep.effect_values)
        plot_sfr_curves(obs, before, after, path, title=Path(args.measured).name)
    except Exception as e:                     # a figure must not lose the report
        print(f"loop: SFR curve plot skipped ({e})")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp calib loop``."""
    import textwrap

    from calibration.fit.device import DEFAULT_COMPONENTS
    from calibration.fit.measurements import DEFAULT_PIXEL_UM
    from calibration.loop.effects import list_effects

    description = textwrap.fill(
        "Close the loop on a measurement: fit a base model (a lens file and its perturbations, or `parametric`: "
        "diffraction at F/N x aberration blur x pixel aperture) to the slanted-edge SFRs of a capture, estimate "
        "the noise floor from the data, decompose the residual (field position, orientation, channel, "
        "frequency), add the registry effect that best explains held-out data, refit, and repeat until the "
        "residual is at the noise floor or nothing helps.", 79)
    p.description = description
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("--lens", required=True, metavar="LENS",
                   help="lens file (lens/v1 .json, Zemax .zmx, ...) or `parametric` for an unknown lens")
    p.add_argument("--measured", required=True, metavar="MEAS",
                   help="chart capture (DNG/raw, PNG/TIFF/JPEG/BMP), SFR JSON of `isp calib sfr`, or "
                        "sfr-observations/v1 JSON")
    p.add_argument("-o", "--output", default="loop_report", metavar="REPORT_DIR",
                   help="report folder (default loop_report/)")
    p.add_argument("--effects", metavar="A,B,...",
                   help=f"registry effects to try (default all: {', '.join(list_effects())})")
    p.add_argument("--max-effects", type=int, default=3, help="most effects to add (default 3)")
    p.add_argument("--folds", type=int, default=3, help="cross-validation folds over field regions (default 3)")
    p.add_argument("--channel", help="R, G, B, L (luminance of an RGB image) or all (default G; grey images: L)")
    p.add_argument("--encoding", choices=("linear", "srgb"), default="linear",
                   help="how an image's codes relate to light (default linear; JPEGs are usually srgb)")
    p.add_argument("--method", choices=("accurate", "iso"), default=DEFAULT_METHOD,
                   help=f"SFR method (isp calib sfr; default {DEFAULT_METHOD})")
    p.add_argument("--min-edge", type=float, default=40.0, metavar="PX",
                   help="shortest chart edge used, pixels (default 40; shorter edges are noisier)")
    p.add_argument("--f-number", default="fit", metavar="N|fit",
                   help="parametric base: F-number held at N, or fitted from 2.0 (default fit)")
    p.add_argument("--pixel-um", type=float, metavar="UM",
                   help=f"pixel pitch, µm (default: the raw file's, else {DEFAULT_PIXEL_UM:g})")
    p.add_argument("--n-params", type=_n_params, default=None, metavar="N|all",
                   help="lens base: the N most sensitive perturbations, or all of them (default all: every "
                        "toleranced kind and focus, which a device with every tolerance drawn needs to reach the "
                        "noise floor: docs/results/loop.md)")
    p.add_argument("--seed", type=int, default=0, help="seed of the fold split and noise renders")
    p.add_argument("--basis", metavar="BASIS.npz", default="auto",
                   help="the design's descriptor basis (`isp calib basis`) to write device.json on, the device's "
                        "calibration (the final lens's descriptor and the kept effects); 'auto' (default): the "
                        "basis a lens profile ships for this design (the packaged e9's), none for other designs; "
                        "'none': no device.json")
    p.add_argument("--components", type=int, default=DEFAULT_COMPONENTS,
                   help=f"descriptor components in device.json (default {DEFAULT_COMPONENTS}, at most the basis's)")

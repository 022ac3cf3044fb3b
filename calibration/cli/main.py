"""``isp calib``: the calibration toolkit's command line.

Reached from ``isp calib ...``; imported only then, so the ISP's own
commands never load the optics code. Sub-commands:

``lens``
    Read a lens file (lens/v1 JSON, Zemax .zmx, optiland, DeepLens,
    rayoptics), print first-order data, vignetting and spot sizes over the
    field; optionally convert it to lens/v1.
``spot``
    Spot diagrams over the field (PNG).
``psf``
    A polychromatic PSF at one field, or the PSF map over the sensor
    (cached), with a plot.
``simulate``
    A simulated capture (slanted-edge chart) through a nominal or perturbed
    lens, written as a DNG that ``isp process`` reads like a real one.
``sfr``
    ISO 12233 slanted-edge SFR of an image, an ROI or a whole chart.
``fit``
    Fit a proxy camera to a measurement: lens/v1 + fitted perturbation, and
    a report (:mod:`calibration.cli.fit`).
``loop``
    Close the loop on a measurement: fit, find the effects the model lacks,
    refit, report before/after (:mod:`calibration.cli.loop`).

Errors print one line and exit with code 2, like the rest of ``isp``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from isp.errors import IspError

EPILOG = """\
examples:
  isp calib lens phone.zmx                       # first-order data, vignetting, spots
  isp calib lens phone.zmx --save phone.json     # convert to lens/v1
  isp calib spot phone.json --plot spots.png
  isp calib psf phone.json --field 0,25 --plot psf.png
  isp calib psf phone.json --map --plot psf_map.png
  isp calib simulate phone.json -o capture.dng --perturb random --seed 3
  isp calib sfr capture.png --chart --json sfr.json --plot sfr.png
  isp calib fit --lens phone.zmx --measured capture.dng -o proxy/  # proxy camera (paper Alg. 1)
  isp calib loop --lens parametric --measured edge.jpg --encoding srgb -o edge_loop/
"""


def _floats(text: str, n: int | None = None) -> tuple[float, ...]:
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise IspError(f"expected comma-separated numbers, got {text!r}") from None
    if n is not None and len(vals) != n:
        raise IspError(f"expected {n} numbers, got {text!r}")
    return vals


def _load(path: str):
    from calibration.optics.lens import LensError
    from calibration.optics.io.lens_json import read_lens

    try:
        return read_lens(path)
    except LensError as e:
        msg = str(e)
        raise IspError(msg if str(path) in msg else f"{path}: {msg}") from None
    except FileNotFoundError:
        raise IspError(f"{path}: no such file") from None


def lens_report(lens) -> dict:
    """First-order data, vignetting and RMS spot radii over the field (JSON-ready)."""
    from calibration.optics.paraxial import first_order
    from calibration.optics.spot import spot

    fo = first_order(lens)
    fields = []
    for frac in (0.0, 0.5, 0.7, 1.0):
        theta = frac * lens.half_fov_deg
        sp = spot(lens, (0.0, theta), n=4000, aiming="real")
        fields.append({"field": frac, "angle_deg": round(theta, 4),
                       "transmitted": round(sp.fraction_valid, 4),
                       "rms_spot_um": round(sp.rms_radius("centroid") * 1e3, 4),
                       "chief_y_mm": None if sp.chief is None else round(float(sp.chief[1]), 5)})
    return {
        "name": lens.name,
        "surfaces": len(lens.surfaces),
        "elements": len(lens.elements()),
        "stop_surface": lens.stop_index + 1,
        "efl_mm": fo.efl, "bfl_mm": fo.bfl, "f_number": fo.f_number,
        "working_f_number": fo.working_f_number, "epd_mm": fo.epd,
        "entrance_pupil_z_mm": fo.entrance_pupil_z, "exit_pupil_z_mm": fo.exit_pupil_z,
        "exit_pupil_diameter_mm": fo.exit_pupil_diameter, "ttl_mm": fo.ttl,
        "total_track_mm": fo.total_track, "half_fov_deg": lens.half_fov_deg,
        "paraxial_image_height_mm": fo.image_height,
        "primary_wavelength_nm": lens.primary_nm,
        "sensor": {"pixel_pitch_um": lens.sensor.pixel_pitch_um, "width_px": lens.sensor.width_px,
                   "height_px": lens.sensor.height_px},
        "fields": fields,
    }


def cmd_lens(args) -> int:
    lens = _load(args.lens)
    if args.save:
        from calibration.optics.io.lens_json import save_lens

        save_lens(lens, args.save)
        print(f"wrote {args.save} (lens/v1)")
    rep = lens_report(lens)
    if args.json:
        print(json.dumps(rep, indent=2))
        return 0
    print(f"{rep['name'] or args.lens}: {rep['surfaces']} surfaces, {rep['elements']} elements, "
          f"stop at surface {rep['stop_surface']}")
    print(f"  EFL {rep['efl_mm']:.4f} mm   BFL {rep['bfl_mm']:.4f} mm   F/{rep['f_number']:.3f} "
          f"(working F/{rep['working_f_number']:.3f})   EPD {rep['epd_mm']:.4f} mm")
    print(f"  TTL {rep['ttl_mm']:.3f} mm   half-FOV {rep['half_fov_deg']:.2f}°   "
          f"image height {rep['paraxial_image_height_mm']:.4f} mm   at {rep['primary_wavelength_nm']:.1f} nm")
    print("  field   angle    transmitted   RMS spot (centroid)")
    for f in rep["fields"]:
        tr = f"{100 * f['transmitted']:6.1f} %"
        print(f"  {f['field']:4.2f}   {f['angle_deg']:6.2f}°   {tr:>11s}   {f['rms_spot_um']:8.3f} µm")
    return 0


def cmd_spot(args) -> int:
    from calibration.optics.spot import plot_spot_diagram, spot

    lens = _load(args.lens)
    fracs = _floats(args.fields)
    spots = [spot(lens, (0.0, f * lens.half_fov_deg), n=args.rays, aiming="real") for f in fracs]
    for f, sp in zip(fracs, spots):
        print(f"field {f:4.2f}: RMS {sp.rms_radius('centroid') * 1e3:.3f} µm (centroid), "
              f"{sp.rms_radius('chief') * 1e3:.3f} µm (chief)")
    if args.plot:
        save_figure(plot_spot_diagram(spots), args.plot)
        print(f"wrote {args.plot}")
    return 0


def save_figure(fig, path) -> None:
    """Save a matplotlib figure atomically (PNG/PDF/SVG by suffix)."""
    import io

    import matplotlib.pyplot as plt

    from isp.io.files import write_bytes_atomic

    buf = io.BytesIO()
    fig.savefig(buf, format=Path(path).suffix.lstrip(".") or "png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())


# -- perturbations shared by psf and simulate -----------------------------------
def _perturbed(lens, args):
    """The nominal lens, a random device within tolerance (--perturb random
    --seed N), or the perturbation in a JSON file of {name: value}."""
    from calibration.optics.perturb import ParameterSpace, Perturbation, apply
    from calibration.optics.spot import refocus

    spec = getattr(args, "perturb", None)
    if not spec and lens.metadata.get("perturbation"):  # a proxy lens file
        return apply(lens, Perturbation.from_dict(lens.metadata["perturbation"])), "proxy (fitted perturbation)"
    if not spec or spec == "none":
        return lens, "nominal"
    if spec == "random":
        space = ParameterSpace.default(lens)
        rng = np.random.default_rng(args.seed)
        p = space.to_perturbation(space.sample(rng, 1)[0])
        # assembly sets focus: the device is refocused, not left defocused
        return refocus(apply(lens, p)), f"random device within tolerance, refocused (seed {args.seed})"
    path = Path(spec)
    try:
        values = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise IspError(f"{spec}: not a perturbation JSON file ({e})") from None
    try:
        return apply(lens, Perturbation.from_dict(values)), f"perturbation from {spec}"
    except ValueError as e:
        raise IspError(f"{spec}: {e}") from None


def cmd_psf(args) -> int:
    from calibration.optics.psf.core import polychromatic_psf
    from calibration.optics.psf.map import plot_psf_map, psf_map

    lens = _load(args.lens)
    model, what = _perturbed(lens, args)
    if args.map:
        m = psf_map(model, grid=(args.rows, args.cols), method=args.method, n=args.n,
                    pupil_samples=args.pupil_samples, cache_dir=args.cache)
        print(f"PSF map {args.rows}x{args.cols}x{len(m.channels)} ({what}), {m.n}x{m.n} samples at "
              f"{m.pitch_um:.3f} µm; cache key {m.key[:12]}")
        if args.npz:
            m.to_npz(args.npz)
            print(f"wrote {args.npz}")
        if args.plot:
            plot_psf_map(m, args.plot, channel=args.channel)
            print(f"wrote {args.plot}")
        return 0
    field = _floats(args.field, 2) if "," in args.field else (0.0, float(args.field))
    response = args.channel if args.wavelength is None else ([args.wavelength], [1.0])
    psf = polychromatic_psf(model, field, response, method=args.method, n=args.n,
                            pupil_samples=args.pupil_samples)
    ee = psf.encircled_energy(2.0 * lens.sensor.pixel_pitch_um) if hasattr(psf, "encircled_energy") else None
    print(f"PSF at field {field} deg ({what}), {args.method}, {psf.data.shape[0]}² at {psf.pitch_um:.3f} µm: "
          f"centroid {tuple(round(v, 3) for v in psf.centroid_um)} µm"
          + (f", energy within 2 px {ee:.3f}" if ee is not None else ""))
    if args.plot:
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(4.2, 4.0))
        half = psf.data.shape[0] * psf.pitch_um / 2
        ax.imshow(np.sqrt(psf.data / psf.data.max()), cmap="inferno", extent=(-half, half, half, -half))
        ax.set(xlabel="x (µm)", ylabel="y (µm, down the sensor)",
               title=f"PSF {args.channel if args.wavelength is None else f'{args.wavelength:g} nm'} "
                     f"at {field} deg (sqrt scale)")
        save_figure(fig, args.plot)
        print(f"wrote {args.plot}")
    return 0


def cmd_simulate(args) -> int:
    from calibration.simulate.capture import simulate_capture, write_capture
    from calibration.simulate.chart import slanted_square_chart

    lens = given = _load(args.lens)
    if args.pixel_pitch or args.size:
        from calibration.optics.lens import Sensor

        w, h = (_floats(args.size, 2) if args.size else (lens.sensor.width_px, lens.sensor.height_px))
        pitch = args.pixel_pitch or lens.sensor.pixel_pitch_um * lens.sensor.width_px / w
        lens = lens.replace(sensor=Sensor(pixel_pitch_um=pitch, width_px=int(w), height_px=int(h)))
    model, what = _perturbed(lens, args)
    sensor = lens.sensor
    chart = slanted_square_chart(sensor.height_px, sensor.width_px, colorchecker=args.colorchecker)
    capture = simulate_capture(model, chart, exposure=args.exposure, rng=args.seed,
                               psf_map_options={"cache_dir": args.cache} if args.cache else None)
    out = write_capture(args.output, capture=capture)
    print(f"wrote {out}: {sensor.width_px}x{sensor.height_px} at {sensor.pixel_pitch_um:.3f} µm, {what}; "
          f"process it with `isp process {out} -o capture.jpg`, measure it with "
          f"`isp calib sfr {out} --roi ...`")
    if args.save_lens:
        from calibration.fit.proxy import save_proxy

        # the prescription's own sensor: --size and --pixel-pitch set the capture, not the lens
        path = save_proxy(args.save_lens, given, getattr(model, "perturbation", None))
        print(f"wrote {path}: the device's true lens (a proxy lens file: `isp eval --lens {path} "
              f"--samples 0 --with-proxy` scores a correction on this device)")
    return 0


# -- sfr -----------------------------------------------------------------------
_RAW_SUFFIXES = {".dng", ".nef", ".cr2", ".cr3", ".arw", ".raf", ".orf", ".rw2", ".pef", ".srw", ".kdc"}


def load_image(path: str):
    """(array, kind, meta): an RGB/grey image file (8/16-bit kept) or a raw
    file as a black-level-corrected linear mosaic (kind "raw")."""
    p = Path(path)
    if not p.exists():
        raise IspError(f"{path}: no such file")
    if p.suffix.lower() in _RAW_SUFFIXES:
        from isp import Pipeline
        from isp.io.read import read_raw

        frame = Pipeline.from_names(["black_level"]).run(read_raw(p))
        if frame.data.ndim != 2:
            raise IspError(f"{path}: a linear (demosaiced) DNG; SFR of raw data needs a Bayer mosaic")
        return frame.data, "raw", frame.meta
    import cv2

    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise IspError(f"{path}: not an image OpenCV can read")
    if img.ndim == 3:
        img = img[..., :3][..., ::-1]  # BGR(A) → RGB
    return img, "image", None


def _sfr_row(roi_box, res, field=None, orientation=None) -> dict:
    from calibration.sfr.chart import esf_step

    r = res.to_dict()
    return {"freq": r["freq_cy_per_px"], "sfr": r["sfr"], "mtf50": r["mtf50_cy_per_px"],
            "sfra": r["sfra_to_nyquist"], "angle_deg": r["angle_deg"], "roi": list(roi_box),
            "field": field, "orientation": orientation, "direction": r["orientation"],
            "edge_fit_linear": r["edge_fit_linear"], "step": esf_step(res),
            "mtf_nyquist_half": r["mtf_nyquist_half"], "mtf_nyquist": r["mtf_nyquist"],
            "contrast": r["contrast"], "noise": r["noise"],
            "mtf50_std": r.get("mtf50_std"), "sfra_std": r.get("sfra_std"),
            "lp_per_mm": r.get("lp_per_mm"), "warnings": r["warnings"]}


def cmd_sfr(args) -> int:
    from calibration.sfr.esfr import SfrError, measure_sfr, measure_sfr_bayer
    from calibration.sfr.chart import field_position, measure_chart, plot_chart

    img, kind, meta = load_image(args.image)
    h, w = img.shape[:2]
    notes = []
    if kind == "image" and img.dtype == np.uint8 and args.encoding == "linear":
        notes.append("8-bit image measured as linear codes; pass --encoding srgb if it is sRGB-encoded")
    try:
        if args.chart:
            if kind == "raw":
                from calibration.sfr.chart import measure_chart_bayer

                channel = args.channel or "G"
                if channel == "all":
                    raise IspError("--chart on raw data measures one colour at a time: --channel R, G, B, Gr or Gb")
                res = measure_chart_bayer(img, meta.cfa, channel=channel, mode=args.bayer_mode,
                                          edge_fit_order=args.edge_fit_order, pixel_pitch_um=args.pixel_pitch,
                                          method=args.method, progress=True)
            else:
                res = measure_chart(img, channel=_channel(args, img), encoding=args.encoding,
                                    edge_fit_order=args.edge_fit_order, pixel_pitch_um=args.pixel_pitch,
                                    method=args.method, progress=True)
            out = res.to_dict()
            fig = plot_chart(res, img if kind == "image" else None) if args.plot else None
            summary = f"{len(res.edges)} edges measured, {len(res.skipped)} skipped"
        else:
            box = _floats(args.roi, 4) if args.roi else (0, 0, w, h)
            box = tuple(int(round(v)) for v in box)
            common = dict(edge_fit_order=args.edge_fit_order, pixel_pitch_um=args.pixel_pitch,
                          bootstrap=args.bootstrap, box=box, method=args.method)
            if kind == "raw":
                r = measure_sfr_bayer(img, meta.cfa, channel=args.channel or "G", mode=args.bayer_mode,
                                      **common)
                results = r if isinstance(r, dict) else {args.channel or "G": r}
            else:
                results = {"": measure_sfr(img, channel=_channel(args, img), encoding=args.encoding,
                                           **common)}
            radius, angle = field_position(box[0] + box[2] / 2, box[1] + box[3] / 2, (w / 2, h / 2),
                                           0.5 * float(np.hypot(w, h)))
            edges = []
            for name, r in results.items():
                row = _sfr_row(box, r, {"radius": round(radius, 5), "angle_deg": round(angle, 3)})
                if name:
                    row["channel"] = name
                edges.append(row)
            out = {"edges": edges}
            fig = _plot_sfr(results) if args.plot else None
            first = next(iter(results.values()))
            summary = (f"MTF50 {first.mtf50:.4f} cy/px, SFRA {first.sfra:.4f}, "
                       f"angle {first.angle_deg:.2f}°, contrast {first.contrast:.2f}")
    except SfrError as e:
        raise IspError(f"{args.image}: {e}") from None
    out = {"image": str(args.image), "size": [w, h], "kind": kind, "encoding": args.encoding,
           "notes": notes, **out}
    if args.json:
        from isp.io.files import write_bytes_atomic

        write_bytes_atomic(args.json, json.dumps(out, indent=1).encode())
    if fig is not None:
        save_figure(fig, args.plot)
    for n in notes:
        print(f"note: {n}")
    print(f"{args.image}: {summary}" + (f"; wrote {args.json}" if args.json else "")
          + (f", {args.plot}" if args.plot else ""))
    return 0


def _channel(args, img):
    if img.ndim != 3:
        return None
    c = (args.channel or "luminance").lower()
    named = {"r": 0, "g": 1, "b": 2, "luminance": "luminance", "y": "luminance"}
    if c not in named:
        raise IspError(f"--channel {args.channel!r}: valid for colour images: R, G, B, luminance")
    return named[c]


def _plot_sfr(results: dict):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for name, r in results.items():
        axes[0].plot(r.freq, r.sfr, label=f"{name or 'SFR'}: MTF50 {r.mtf50:.3f}")
        x = np.arange(r.esf.size) * r.esf_step_px
        axes[1].plot(x - x.mean(), r.esf, label=name or "ESF")
    axes[0].axhline(0.5, color="gray", lw=0.6, ls=":")
    axes[0].set(xlim=(0, 0.5), ylim=(0, 1.1), xlabel="cycles / pixel", ylabel="SFR", title="e-SFR (ISO 12233)")
    axes[1].set(xlabel="pixels across the edge", ylabel="ESF", title="edge spread")
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def make_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="isp calib",
        description="Calibration toolkit: lens models, ray tracing, PSFs, simulated captures, "
                    "slanted-edge SFR.",
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    sp = sub.add_parser("lens", help="first-order data, vignetting and spots of a lens file",
                        description="Read a lens (lens/v1 .json, Zemax .zmx, optiland .json, DeepLens "
                                    ".json, rayoptics .roa) and report EFL, BFL, F/#, pupils, TTL, "
                                    "and, at 0/0.5/0.7/1.0 field, the transmitted ray fraction and the "
                                    "RMS spot radius (real ray aiming, primary wavelength).",
                        epilog="examples:\n  isp calib lens US-12210142-B2-e9.zmx\n"
                               "  isp calib lens US-12210142-B2-e9.zmx --save e9.json --json",
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    sp.add_argument("lens")
    sp.add_argument("--save", metavar="OUT.json", help="also write the lens as lens/v1 JSON")
    sp.add_argument("--json", action="store_true", help="print the report as JSON")
    sp.set_defaults(func=cmd_lens)

    sp = sub.add_parser("spot", help="spot diagrams over the field",
                        description="Spot diagrams at fractions of the half field of view.",
                        epilog="example:\n  isp calib spot e9.json --fields 0,0.5,0.7,1 --plot spots.png",
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    sp.add_argument("lens")
    sp.add_argument("--fields", default="0,0.5,0.7,1", help="fractions of the half-FOV (default 0,0.5,0.7,1)")
    sp.add_argument("--rays", type=int, default=10000, help="rays per field (default 10000)")
    sp.add_argument("--plot", metavar="OUT.png")
    sp.set_defaults(func=cmd_spot)

    def perturb_args(sp):
        sp.add_argument("--perturb", metavar="random|FILE.json",
                        help="a device: 'random' within the default tolerances, or {name: value} JSON "
                             "(e.g. {\"e1.decenter_x\": 0.003})")
        sp.add_argument("--seed", type=int, default=0, help="seed for --perturb random and noise")
        sp.add_argument("--cache", metavar="DIR", help="PSF cache folder (default $ISP_CACHE or ~/.cache)")

    sp = sub.add_parser("psf", help="a polychromatic PSF, or the PSF map over the sensor",
                        description="Diffraction PSF (Huygens, Debye or FFT) of a sensor channel through "
                                    "the camera's spectral response, at one field or over the paper's "
                                    "15 x 20 sensor regions (cached on disk).",
                        epilog="examples:\n  isp calib psf e9.json --field 0,25 --channel G --plot psf.png\n"
                               "  isp calib psf e9.json --field 20 --wavelength 550 --method huygens\n"
                               "  isp calib psf e9.json --map --plot map.png --npz map.npz\n"
                               "  isp calib psf e9.json --map --perturb random --seed 7 --plot dev7.png",
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    sp.add_argument("lens")
    sp.add_argument("--field", default="0", help="θy or θx,θy in degrees (default 0)")
    sp.add_argument("--channel", default="G", help="R, G or B through the camera response (default G)")
    sp.add_argument("--wavelength", type=float, help="a single wavelength in nm instead of a channel")
    sp.add_argument("--method", choices=("huygens", "debye", "fft"), default="debye")
    sp.add_argument("--n", type=int, default=64, help="PSF samples per side")
    sp.add_argument("--pupil-samples", type=int, default=64)
    sp.add_argument("--map", action="store_true", help="the whole sensor (15 x 20 regions)")
    sp.add_argument("--rows", type=int, default=15)
    sp.add_argument("--cols", type=int, default=20)
    sp.add_argument("--npz", metavar="OUT.npz", help="save the map")
    sp.add_argument("--plot", metavar="OUT.png")
    perturb_args(sp)
    sp.set_defaults(func=cmd_psf)

    sp = sub.add_parser("simulate", help="a simulated chart capture written as DNG",
                        description="Render a slanted-square chart (one square per PSF region) through the "
                                    "lens's PSF map, with relative illumination, Bayer sampling, "
                                    "Poisson-Gaussian noise and GainMap lens-shading opcodes, and write "
                                    "it as a DNG that `isp process` and `isp calib sfr` read like a real "
                                    "capture.",
                        epilog="examples:\n  isp calib simulate e9.json -o nominal.dng --size 2000,1500\n"
                               "  isp calib simulate e9.json -o dev3.dng --perturb random --seed 3\n"
                               "  isp calib simulate e9.json -o dev3.dng --perturb random --seed 3 --save-lens dev3.json",
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    sp.add_argument("lens")
    sp.add_argument("-o", "--output", required=True, help="output .dng")
    sp.add_argument("--size", metavar="W,H", help="sensor size in pixels (keeps the sensor's width in mm)")
    sp.add_argument("--pixel-pitch", type=float, metavar="UM", help="pixel pitch in µm")
    sp.add_argument("--exposure", type=float, default=0.8, help="white level reached by the chart's white")
    sp.add_argument("--colorchecker", action="store_true", help="add ColorChecker patches in the middle")
    sp.add_argument("--save-lens", metavar="FILE.json",
                    help="also write the device's true lens (the prescription with the device's perturbation, "
                         "a proxy lens file), to score a correction or a fit against")
    perturb_args(sp)
    sp.set_defaults(func=cmd_simulate)

    sp = sub.add_parser("sfr", help="ISO 12233 slanted-edge SFR of an image, ROI or chart",
                        description="e-SFR per ISO 12233 (the sfrmat lineage) of a slanted edge: the whole "
                                    "image, an ROI, or every edge found on a chart (--chart), with MTF50, "
                                    "SFRA and field maps. Image files are measured as linear codes unless "
                                    "--encoding srgb declares them sRGB (linearised first); raw files "
                                    "(DNG, ...) are measured on the Bayer mosaic per colour.",
                        epilog="examples:\n  isp calib sfr edge.tif --json sfr.json --plot sfr.png\n"
                               "  isp calib sfr photo.jpg --encoding srgb --roi 820,410,120,200 --json e.json\n"
                               "  isp calib sfr chart.png --chart --json chart.json --plot chart.png\n"
                               "  isp calib sfr capture.dng --roi 900,600,80,160 --channel all --json raw.json",
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    sp.add_argument("image", help="image file (PNG/TIFF/JPEG/BMP, 8 or 16 bit) or raw file")
    sp.add_argument("--roi", metavar="X,Y,W,H", help="region of one edge, pixels (default: whole image)")
    sp.add_argument("--chart", action="store_true", help="find every slanted edge and map SFR over the field")
    sp.add_argument("--channel", help="R, G, B or luminance (colour images); R, G, B, Gr, Gb or all (raw)")
    sp.add_argument("--bayer-mode", choices=("plane", "green"), default="plane",
                    help="raw: measure each CFA plane, or both greens at full resolution")
    sp.add_argument("--encoding", choices=("linear", "srgb"), default="linear",
                    help="how the image's codes relate to light (default linear)")
    sp.add_argument("--edge-fit-order", type=int, default=1, help="polynomial order of the edge fit (1-5)")
    sp.add_argument("--method", choices=("iso", "accurate"), default="iso",
                    help="iso: ISO 12233 / sfrmat5 exactly; accurate: with the binning and derivative "
                         "corrections, an adaptive LSF window and a refined edge (less bias and noise)")
    sp.add_argument("--pixel-pitch", type=float, metavar="UM", help="pixel pitch in µm (adds lp/mm)")
    sp.add_argument("--bootstrap", type=int, default=0, help="resamples for MTF50/SFRA uncertainty")
    sp.add_argument("--json", metavar="OUT.json", help="write the results as JSON")
    sp.add_argument("--plot", metavar="OUT.png", help="write a plot")
    sp.set_defaults(func=cmd_sfr)

    from calibration.cli.fit import add_parser as add_fit_parser
    from calibration.cli.loop import add_parser as add_loop_parser

    add_fit_parser(sub)
    add_loop_parser(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    parser = make_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    return int(args.func(args) or 0)

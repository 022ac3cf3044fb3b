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

Errors print one line and exit with code 2, like the rest of ``isp``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

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
    from .lens import LensError
    from .lens_io import read_lens

    try:
        return read_lens(path)
    except LensError as e:
        msg = str(e)
        raise IspError(msg if str(path) in msg else f"{path}: {msg}") from None
    except FileNotFoundError:
        raise IspError(f"{path}: no such file") from None


def lens_report(lens) -> dict:
    """First-order data, vignetting and RMS spot radii over the field (JSON-ready)."""
    from .paraxial import first_order
    from .spot import spot

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
        from .lens_io import save_lens

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
    from .spot import plot_spot_diagram, spot

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

    from isp.io import write_bytes_atomic

    buf = io.BytesIO()
    fig.savefig(buf, format=Path(path).suffix.lstrip(".") or "png", dpi=120, bbox_inches="tight")
    plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())


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
    return p


def main(argv: list[str] | None = None) -> int:
    parser = make_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    return int(args.func(args) or 0)

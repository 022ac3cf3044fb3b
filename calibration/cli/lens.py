"""``isp calib lens``: a lens file's first-order data, vignetting and spot sizes over the field;
conversion to lens/v1."""

from __future__ import annotations

import argparse
import json


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp calib lens``."""
    p.description = ("Read a lens (lens/v1 .json, Zemax .zmx, optiland .json, DeepLens "
                     ".json, rayoptics .roa) and report EFL, BFL, F/#, pupils, TTL, "
                     "and, at 0/0.5/0.7/1.0 field, the transmitted ray fraction and the "
                     "RMS spot radius (real ray aiming, primary wavelength).")
    p.epilog = ("examples:\n  isp calib lens US-12210142-B2-e9.zmx\n"
                "  isp calib lens US-12210142-B2-e9.zmx --save e9.json --json")
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("lens")
    p.add_argument("--save", metavar="OUT.json", help="also write the lens as lens/v1 JSON")
    p.add_argument("--json", action="store_true", help="print the report as JSON")


def run(args: argparse.Namespace) -> int:
    """Read the lens; print (or ``--json``) its report; ``--save`` it as lens/v1."""
    from calibration.optics.io import read_lens
    from calibration.optics.spot import lens_report

    lens = read_lens(args.lens)
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

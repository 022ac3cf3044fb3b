"""``isp export``: a restoration checkpoint → ONNX for the ``correction``
stage (FP32, optionally a static INT8 copy), with a JSON report.

Reached from ``isp export ...`` and imported only then; torch is imported
when it runs, so importing this module is cheap: :data:`EXPORT`, the
command's record, is here (the ``isp.commands`` entry point names it).
Errors print one line and exit with code 2, like the rest of ``isp``
(:mod:`isp.cli.run`).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from isp.cli.commands import Command
from isp.errors import ConfigError

EXPORT = Command("export", "checkpoint -> ONNX (FP32, static INT8) for the correction stage, with parity checks",
                 module="export.cli")

EPILOG = """\
examples:
  isp export out/e9_default/model.pt -o e9.onnx
  isp export out/e9_default/model.pt -o e9.onnx --int8 --calib 64 --calib-data out/synth/e9_default
  isp export model.pt -o m.onnx --tile-size 384 --overlap 32        # fixed margin, no measurement
  isp process photo.dng -o photo.jpg --set correction.model=e9.int8.onnx

The UNet is exported packed 2×2 to depth (its stem and head reindexed, the
same function): the stage packs each tile as it reads it, and ONNX Runtime
skips a strided full-resolution conv and a DepthToSpace (INT8 ≈ 10 % faster).

Writes MODEL.onnx (FP32), with --int8 MODEL.int8.onnx (or --int8-output), and
MODEL.export.json: nodes per op type, torch vs ONNX max abs error, the measured
tile overlap, convs quantised after ORT's optimisation, INT8 vs FP32 PSNR on
held-out synth pairs, and what onnxruntime's mobile-usability checker says.
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp export``."""
    p.description = ("Export a restoration checkpoint to ONNX for the correction stage "
                     "(opset ≥ 17, dynamic H/W, metadata the stage checks).")
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("checkpoint", help="restoration checkpoint (.pt) written by `isp train`")
    p.add_argument("-o", "--output", required=True, help="the FP32 .onnx file to write")
    p.add_argument("--opset", type=int, default=17, help="ONNX opset, ≥ 17 (default 17)")
    p.add_argument("--tile-size", type=int, default=512,
                   help="tile side the stage uses, margins included, px (default 512; 0: whole frames)")
    p.add_argument("--overlap", type=int, help="tile margin per side (px) to write instead of measuring it")
    p.add_argument("--planar", action="store_true",
                   help="export the UNet on full-resolution planes instead of its space-to-depth form "
                        "(the same function; the packed form runs faster, see `isp export --help`)")
    p.add_argument("--no-measure-overlap", action="store_true",
                   help="skip the overlap measurement (the stage then uses receptive_radius)")
    q = p.add_argument_group("INT8")
    q.add_argument("--int8", action="store_true", help="also write a static INT8 (QDQ) copy")
    q.add_argument("--int8-output", help="its path (default: OUTPUT with .int8.onnx)")
    q.add_argument("--calib", type=int, default=32, metavar="N", help="calibration crops (default 32)")
    q.add_argument("--calib-data", metavar="DIR", help="`isp synth` folder to take them from (required with --int8)")
    q.add_argument("--calib-crop", type=int, default=128, help="calibration crop side, px (default 128)")
    q.add_argument("--eval-pairs", type=int, default=16,
                   help="held-out synth pairs (the last ones) for the INT8 vs FP32 PSNR (default 16; 0: skip)")
    p.add_argument("--no-mobile-check", action="store_true", help="skip onnxruntime's mobile-usability checker")
    # SUPPRESS: not given here, `isp --debug export ...` keeps its value
    p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                   help="show tracebacks of internal errors")


def _summary_line(text: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1].removeprefix("INFO:").strip() if lines else ""


def run(args: argparse.Namespace) -> int:
    """Export FP32 (and INT8), check them, write the JSON report."""
    from export.onnx_export import export_onnx

    out = Path(args.output)
    if out.suffix != ".onnx":
        raise ConfigError(f"-o {out}: the output must end in .onnx")
    if args.int8 and not args.calib_data:
        raise ConfigError("--int8 needs calibration data: --calib-data DIR (an `isp synth` folder)")
    if args.calib < 1:
        raise ConfigError(f"--calib {args.calib}: at least 1 crop")
    if args.calib_data and not (Path(args.calib_data) / "manifest.json").is_file():
        raise ConfigError(f"--calib-data {args.calib_data}: not an `isp synth` folder (no manifest.json)")
    report = {"checkpoint": str(args.checkpoint)}
    fp32 = export_onnx(args.checkpoint, out, opset=args.opset, tile_size=args.tile_size,
                       measure_overlap=not args.no_measure_overlap, overlap=args.overlap,
                       packed=not args.planar)
    report["fp32"] = fp32
    meta = fp32["metadata"]
    print(f"{out}: {fp32['convs']} convs, torch vs ONNX max abs {fp32['parity_max_abs']:.2g}, "
          f"tile {meta['tile_size']} px, overlap {meta.get('tile_overlap', meta['receptive_radius'])} px")
    if args.int8:
        from export.quantize import SynthCalibration, int8_psnr, quantize_int8

        q8 = Path(args.int8_output) if args.int8_output else out.with_suffix(".int8.onnx")
        reader = SynthCalibration(args.calib_data, args.calib, crop=args.calib_crop,
                                  fov=meta["fov_encoding"] == "xy", device=int(meta.get("device_components", 0)))
        r = quantize_int8(out, q8, reader)
        report["int8"] = r
        print(f"{q8}: {r['int8_quantized_conv']}/{r['fp32_conv']} convs quantised after optimisation "
              f"({r['int8_float_conv']} float), {args.calib} calibration crops")
        if not args.no_measure_overlap and args.overlap is None:
            from export.onnx_export import remeasure_overlap

            # INT8 rounding turns small context changes into whole steps: its own margin, at least
            # its receptive radius (its tiles then exact); the border context stays the float model's
            r["overlap"] = ov = remeasure_overlap(q8)
            if ov.get("overlap") is not None:
                used = ov.get("overlap_int8", ov["overlap"])
                why = (f"{ov['overlap']} measured on the INT8 model, raised to its receptive radius: tiles exact"
                       if used != ov["overlap"] else "measured on the INT8 model, at least its receptive radius")
                print(f"{q8}: tile overlap {used} px ({why}); border context "
                      f"{meta.get('border_context', meta.get('tile_overlap'))} px (the float model's)")
        if args.eval_pairs:
            ps = int8_psnr(out, q8, args.calib_data, args.eval_pairs)
            r["psnr"] = ps
            flag = "" if ps["drop_db"] <= ps["limit_db"] else f"  (above the {ps['limit_db']} dB limit)"
            print(f"PSNR on {ps['pairs']} held-out pairs: FP32 {ps['fp32_psnr_db']:.2f} dB, "
                  f"INT8 {ps['int8_psnr_db']:.2f} dB, drop {ps['drop_db']:.3f} dB{flag}")
    if not args.no_mobile_check:
        from export.quantize import mobile_usability

        report["mobile_usability"] = {}
        for key, path in (("fp32", out), ("int8", report.get("int8", {}).get("path"))):
            if path:
                m = mobile_usability(path)
                report["mobile_usability"][key] = m
                print(f"mobile check ({key}): {_summary_line(m['output'])}")
    rep = out.with_suffix(".export.json")
    from isp.io.files import atomic_path

    with atomic_path(rep) as tmp:
        Path(tmp).write_text(json.dumps(report, indent=1, default=str) + "\n")
    print(f"report: {rep}")
    return 0


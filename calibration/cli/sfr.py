"""``isp calib sfr``: ISO 12233 slanted-edge SFR of an image, an ROI or a whole chart."""

from __future__ import annotations

import argparse
import json

import numpy as np

from calibration.sfr.esfr import DEFAULT_METHOD
from isp.cli.arguments import numbers
from isp.errors import ConfigError, InputError


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp calib sfr``."""
    p.description = ("e-SFR per ISO 12233 (the sfrmat lineage) of a slanted edge: the whole "
                     "image, an ROI, or every edge found on a chart (--chart), with MTF50, "
                     "SFRA and field maps. Image files are measured as linear codes unless "
                     "--encoding srgb declares them sRGB (linearised first); raw files "
                     "(DNG, ...) are measured on the Bayer mosaic per colour.")
    p.epilog = ("examples:\n  isp calib sfr edge.tif --json sfr.json --plot sfr.png\n"
                "  isp calib sfr photo.jpg --encoding srgb --roi 820,410,120,200 --json e.json\n"
                "  isp calib sfr chart.png --chart --json chart.json --plot chart.png\n"
                "  isp calib sfr capture.dng --roi 900,600,80,160 --channel all --json raw.json")
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("image", help="image file (PNG/TIFF/JPEG/BMP, 8 or 16 bit) or raw file")
    p.add_argument("--roi", metavar="X,Y,W,H", help="region of one edge, pixels (default: whole image)")
    p.add_argument("--chart", action="store_true",
                   help="find every slanted edge and map SFR over the field; the chart's layout (ISO 12233:2023 "
                        "e-SFR, ISO 12233:2000, slanted-square grid or target) is named in the summary and JSON")
    p.add_argument("--channel", help="R, G, B or luminance (colour images); R, G, B, Gr, Gb or all (raw)")
    p.add_argument("--bayer-mode", choices=("plane", "green"), default="plane",
                   help="raw: measure each CFA plane, or both greens at full resolution")
    p.add_argument("--encoding", choices=("linear", "srgb"), default="linear",
                   help="how the image's codes relate to light (default linear)")
    p.add_argument("--edge-fit-order", type=int, default=1, help="polynomial order of the edge fit (1-5)")
    p.add_argument("--method", choices=("accurate", "iso"), default=DEFAULT_METHOD,
                   help="iso: ISO 12233 / sfrmat5 exactly; accurate: with the binning and derivative "
                        "corrections, an adaptive LSF window and a refined edge (less bias and noise)")
    p.add_argument("--pixel-pitch", type=float, metavar="UM", help="pixel pitch in µm (adds lp/mm)")
    p.add_argument("--bootstrap", type=int, default=0, help="resamples for MTF50/SFRA uncertainty")
    p.add_argument("--workers", type=int, default=2, metavar="N",
                   help="--chart: processes measuring the edges, images and raw (default 2; 1 measures in this process)")
    p.add_argument("--json", metavar="OUT.json", help="write the results as JSON")
    p.add_argument("--plot", metavar="OUT.png",
                   help="write a figure: the SFR; with --chart the chart annotated (each edge coloured and labelled "
                        "with its MTF50, each skipped candidate boxed with its reason), the curves and the field map")


def run(args: argparse.Namespace) -> int:
    """Measure the edge(s); print a summary; ``--json`` the results, ``--plot`` them."""
    from calibration.sfr.esfr import SfrError, measure_sfr, measure_sfr_bayer
    from calibration.report import save_figure
    from calibration.sfr.chart import edge_record, field_position, measure_chart, plot_chart, plot_sfr
    from calibration.sfr.images import load_image

    img, kind, meta = load_image(args.image)
    h, w = img.shape[:2]
    notes = []
    if kind == "image" and img.dtype == np.uint8 and args.encoding == "linear":
        notes.append("8-bit image measured as linear codes; pass --encoding srgb if it is sRGB-encoded")
    try:
        if args.chart:
            from isp.runtime.executor import create_executor

            if args.workers < 1:
                raise ConfigError(f"--workers must be at least 1, got {args.workers}")
            kind_ = "processes" if args.workers > 1 else "serial"
            if kind == "raw":
                from calibration.sfr.chart import measure_chart_bayer

                channel = args.channel or "G"
                if channel == "all":
                    raise ConfigError("--chart on raw data measures one colour at a time: --channel R, G, B, Gr or Gb")
                with create_executor(kind_, workers=args.workers, progress=True) as ex:
                    res = measure_chart_bayer(img, meta.cfa, channel=channel, mode=args.bayer_mode,
                                              edge_fit_order=args.edge_fit_order, pixel_pitch_um=args.pixel_pitch,
                                              method=args.method, executor=ex)
            else:
                with create_executor(kind_, workers=args.workers, progress=True) as ex:
                    res = measure_chart(img, channel=_channel(args, img), encoding=args.encoding,
                                        edge_fit_order=args.edge_fit_order, pixel_pitch_um=args.pixel_pitch,
                                        method=args.method, executor=ex)
            out = res.to_dict()
            fig = plot_chart(res, img if kind == "image" else None) if args.plot else None
            summary = f"{len(res.edges)} edges measured, {len(res.skipped)} skipped"
            if res.layout is not None and res.layout.name != "unknown":
                summary = f"{res.layout.title}; {summary}"
        else:
            box = numbers(args.roi, 4) if args.roi else (0, 0, w, h)
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
                row = edge_record(box, r, {"radius": round(radius, 5), "angle_deg": round(angle, 3)})
                if name:
                    row["channel"] = name
                edges.append(row)
            out = {"edges": edges}
            fig = plot_sfr(results) if args.plot else None
            first = next(iter(results.values()))
            summary = (f"MTF50 {first.mtf50:.4f} cy/px, SFRA {first.sfra:.4f}, "
                       f"angle {first.angle_deg:.2f}°, contrast {first.contrast:.2f}")
    except SfrError as e:
        raise InputError(args.image, str(e)) from None
    out = {"image": str(args.image), "size": [w, h], "kind": kind, "encoding": args.encoding,
           "notes": notes, **out}
    if args.json:
        from isp.io.files import write_bytes_atomic

        # a chart's JSON (hundreds of curves) is written compact: the indented
        # form goes through json's pure-Python encoder, 0.25 s for 468 edges
        write_bytes_atomic(args.json, json.dumps(out, indent=None if args.chart else 1).encode())
    if fig is not None:
        save_figure(fig, args.plot, dpi=200 if args.chart else 120)
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
        raise ConfigError(f"--channel {args.channel!r}: valid for colour images: R, G, B, luminance")
    return named[c]

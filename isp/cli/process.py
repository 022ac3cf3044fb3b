"""``isp process``: one raw file through the pipeline to a JPEG (or PNG/TIFF)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from isp.cli.arguments import add_headerless_arguments, headerless, pipeline_from_args

EPILOG = """\
examples:
  isp process photo.dng -o photo.jpg
  isp process photo.dng -o before.jpg --no-correction      # without the optical correction
  isp process photo.dng -o photo.jpg --set correction.model=my_lens.int8.onnx
  isp process photo.dng -o photo.jpg --set white_balance.mode=grey_world --set jpeg.quality=90
  isp process photo.dng -o photo.png --config my_pipeline.toml --save-stages stages/
  isp process dump.RAW -o dump.jpg --width 1920 --height 1080 --bits 10 --pattern RGGB

A pipeline file is a list of [[stage]] tables (name + parameters), e.g.:
  [[stage]]
  name = "black_level"
  [[stage]]
  name = "demosaic"
  method = "malvar2004"
See `isp stages` for every stage and its parameters.
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp process``."""
    p.description = ("Process one raw file through the pipeline (default: black level, lens shading, "
                     "white balance, demosaic, correction, luminance, colour, gamma, JPEG).")
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("input", help="raw file (DNG, a camera raw LibRaw reads, or a headerless dump)")
    p.add_argument("-o", "--output", required=True, help="output .jpg (or .png/.tif if the "
                                                         "pipeline ends before the jpeg stage)")
    p.add_argument("--config", help="pipeline TOML file ([[stage]] tables)")
    p.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE",
                   help="override a stage parameter (repeatable), e.g. jpeg.quality=90")
    p.add_argument("--save-stages", metavar="DIR",
                   help="write every intermediate as NN_stage.png (viewable) and .npy (exact)")
    p.add_argument("-v", "--verbose", action="store_true", help="print each stage's decision and time")
    p.add_argument("--no-correction", action="store_true",
                   help="run the correction stage without a model (identity); by default it runs "
                        "the packaged model of the default phone lens (see `isp info`)")
    add_headerless_arguments(p)


def run(args: argparse.Namespace) -> int:
    """Read, run the pipeline, write; with ``-v``, each stage's decision and time."""
    from isp.io.files import save_stage, write_output
    from isp.io.read import read_raw
    from isp.runtime.threads import tune_allocator

    tune_allocator()
    _, pipeline = pipeline_from_args(args)
    out = Path(args.output)
    t0 = time.perf_counter()
    frame = read_raw(args.input, headerless=headerless(args))
    t_read = time.perf_counter() - t0
    timings = []

    def on_step(i, stage, fr, dt):
        if stage is not None:
            timings.append((stage.name, dt))
        if args.save_stages:
            save_stage(args.save_stages, i + 1, "input" if stage is None else stage.name, fr)

    result = pipeline.run(frame, on_step=on_step)
    write_output(result, out)
    total = time.perf_counter() - t0
    if args.verbose:
        print(f"read {args.input}: {frame.shape} {frame.meta.cfa.value if frame.meta.cfa else 'linear'} "
              f"({t_read * 1000:.0f} ms)")
        for step, (name, dt) in zip(result.history, timings):
            print(f"  {name:<14s} {dt * 1000:7.0f} ms  {step.note}")
        for note in frame.meta.notes:
            print(f"  note: {note}")
    print(f"wrote {out} ({total:.2f} s)")
    return 0

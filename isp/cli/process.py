"""``isp process``: one raw file through the pipeline to a JPEG (or PNG/TIFF)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from isp.cli.arguments import (add_correction_arguments, add_headerless_arguments, add_look_argument,
                               headerless, pipeline_from_args)

EPILOG = """\
examples:
  isp process photo.dng -o photo.jpg
  isp process photo.dng -o before.jpg --correction none    # without the optical correction
  isp process photo.dng -o photo.jpg --correction my_lens.int8.onnx   # this model, whatever the lens
  isp process photo.dng -o photo.jpg --set white_balance.mode=grey_world --set jpeg.quality=90
  isp process photo.dng -o photo.png --config my_pipeline.toml --save-stages stages/
  isp process photo.dng -o photo.png --set png.bits=16      # 16-bit PNG
  isp process photo.dng -o photo.tif                        # 16-bit TIFF
  isp process photo.dng -o scene.tif --look linear --set tiff.bits=32   # float, scene-linear
  isp process dump.RAW -o dump.jpg --width 1920 --height 1080 --bits 10 --pattern RGGB

The optical correction runs the model of the lens profile that matches the
file's lens (UniqueCameraModel, Make, Model, LensModel), and nothing where no
profile matches; -v says which profile matched, or why none did. `isp profiles`
lists the profiles.

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
    p.description = ("Process one raw file through the pipeline (default, the 'adobe' look: black level, "
                     "lens shading, white balance, demosaic, correction, Adobe's render, JPEG; "
                     "--look linear for the scene-referred render).")
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("input", help="raw file (DNG, a camera raw LibRaw reads, or a headerless dump)")
    p.add_argument("-o", "--output", required=True,
                   help="output file; its extension chooses the encoding stage: .jpg/.jpeg (JPEG), "
                        ".png (PNG, 8 bit; png.bits=16), .tif/.tiff (TIFF, 16 bit; tiff.bits=32: float). "
                        "Each carries the sRGB ICC profile and EXIF")
    p.add_argument("--config", help="pipeline TOML file ([[stage]] tables)")
    p.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE",
                   help="override a stage parameter (repeatable), e.g. jpeg.quality=90")
    p.add_argument("--save-stages", metavar="DIR",
                   help="write every intermediate as NN_stage.png (viewable) and .npy (exact)")
    p.add_argument("-v", "--verbose", action="store_true", help="print each stage's decision and time")
    add_correction_arguments(p)
    add_look_argument(p)
    add_headerless_arguments(p)


def run(args: argparse.Namespace) -> int:
    """Read, run the pipeline, write; with ``-v``, each stage's decision and time."""
    from isp.io.files import save_stage, write_output
    from isp.io.read import read_raw

    # glibc's allocator is left as it is (no isp.runtime.threads.tune_allocator):
    # one frame per process has nothing to reuse across runs, and heap-kept
    # arrays would add their fragments to the peak (455 MB against 370 MB at 12 MP)
    _, pipeline = pipeline_from_args(args, args.output)
    out = Path(args.output)
    t0 = time.perf_counter()
    frame = read_raw(args.input, headerless=headerless(args))
    t_read = time.perf_counter() - t0
    read_line = f"read {args.input}: {frame.shape} {frame.meta.cfa.value if frame.meta.cfa else 'linear'} " \
                f"({t_read * 1000:.0f} ms)"
    notes = frame.meta.notes
    timings = []

    def on_step(i, stage, fr, dt):
        if stage is not None:
            timings.append((stage.name, dt))
        if args.save_stages:
            save_stage(args.save_stages, i + 1, "input" if stage is None else stage.name, fr)

    # the pipeline holds the only reference to the raw frame, so that its
    # data is freed once the first stages have replaced it
    inputs = [frame]
    del frame
    result = pipeline.run(inputs.pop(), on_step=on_step)
    write_output(result, out)
    total = time.perf_counter() - t0
    if args.verbose:
        print(read_line)
        for step, (name, dt) in zip(result.history, timings):
            print(f"  {name:<14s} {dt * 1000:7.0f} ms  {step.note}")
        for note in notes:
            print(f"  note: {note}")
    print(f"wrote {out} ({total:.2f} s)")
    return 0

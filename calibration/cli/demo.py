"""``isp demo``: a synthetic phone capture written as a DNG and processed (:mod:`calibration.demo`)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp demo``."""
    p.description = ("Synthesise a phone capture (colour chart, slanted edges, lens shading stored as "
                     "GainMap opcodes, sensor noise), write it as a DNG with the project's own writer, "
                     "process it and report.")
    p.epilog = "example:\n  isp demo -o demo/"
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("-o", "--output", default="isp-demo", help="output folder (default isp-demo)")
    p.add_argument("--width", type=int, default=2000)
    p.add_argument("--height", type=int, default=1500)
    p.add_argument("--seed", type=int, default=0)


def run(args: argparse.Namespace) -> int:
    """Run :func:`calibration.demo.run_demo`."""
    from isp.runtime.threads import tune_allocator

    from calibration.demo import run_demo

    tune_allocator()
    return run_demo(Path(args.output), size=(args.height, args.width), seed=args.seed)

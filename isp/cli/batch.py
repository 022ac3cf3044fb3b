"""``isp batch``: every raw file of a folder through the pipeline, in parallel."""

from __future__ import annotations

import argparse
from pathlib import Path

from isp.runtime.executor import add_executor_argument
from isp.cli.arguments import (add_correction_arguments, add_headerless_arguments, add_look_argument,
                               headerless, pipeline_from_args)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp batch``."""
    p.description = ("Process every raw file in DIR (by extension) into OUTDIR, in parallel, with a "
                     "progress bar. The summary lists every file not processed and why (failed, or not "
                     "taken: not a raw file by its extension); the exit code is 1 if any failed.")
    p.epilog = ("examples:\n  isp batch captures/ -o jpegs/ --workers 2\n"
                "  isp batch captures/ -o pngs/ --format .png --set png.bits=16\n"
                "  isp batch captures/ -o jpegs/ --executor ray://head:10001   # on a Ray cluster (every node "
                "reads captures/ and writes jpegs/)")
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("input", help="folder of raw files")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes (default 2), or files in flight on Ray (default its CPUs)")
    add_executor_argument(p)
    p.add_argument("--config", help="pipeline TOML file")
    p.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE")
    add_correction_arguments(p)
    add_look_argument(p)
    p.add_argument("--format", default=".jpg",
                   help="output extension, which chooses the encoding stage: .jpg (default), .png or .tif")
    add_headerless_arguments(p)


def run(args: argparse.Namespace) -> int:
    """Run :func:`isp.runtime.batch.run_batch`; 1 if any file failed."""
    from isp.runtime.batch import batch_executor, find_inputs, run_batch
    from isp.runtime.threads import tune_allocator

    tune_allocator()
    suffix = args.format if args.format.startswith(".") else f".{args.format}"
    config, _ = pipeline_from_args(args, f"--format {suffix}")  # refuse a bad config before any work
    with batch_executor(args.workers, len(find_inputs(Path(args.input))), executor=args.executor) as executor:
        return run_batch(Path(args.input), Path(args.output), config, executor=executor,
                         headerless=headerless(args), suffix=suffix)

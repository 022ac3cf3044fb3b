"""The ``isp`` command line.

Sub-commands of this package (process, info, stages, batch, demo) are
defined here; those of the other packages (calibration, data synthesis,
training, export)
are imported only when called, so ``isp process`` never imports torch.

Exit codes: 0 success; 1 a batch finished with failures; 2 bad input or
configuration (one line on stderr naming the file and the problem);
3 an internal error (a bug: rerun with ``--debug`` for the traceback).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import tomllib
from pathlib import Path

from isp.errors import ConfigError, IspError

EPILOG_PROCESS = """\
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


def _add_headerless(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("headerless dumps (files with no raw header)")
    g.add_argument("--width", type=int, help="pixels per row")
    g.add_argument("--height", type=int, help="rows")
    g.add_argument("--bits", type=int, help="significant bits per sample (8: bytes, 9-16: 16-bit words)")
    g.add_argument("--pattern", help="CFA pattern: RGGB, BGGR, GRBG or GBRG")
    g.add_argument("--black", type=float, default=0.0, help="black level in DN (default 0)")


def _headerless(args):
    fields = [args.width, args.height, args.bits, args.pattern]
    if all(v is None for v in fields):
        return None
    if any(v is None for v in fields):
        raise ConfigError("headerless input needs all of --width, --height, --bits and --pattern")
    from isp.io.read import Headerless

    try:
        return Headerless(args.width, args.height, args.bits, args.pattern, args.black)
    except ValueError as e:
        raise ConfigError(f"headerless geometry: {e}") from None


def _parse_set(items: list[str]) -> list[tuple[str, str, object]]:
    out = []
    for item in items or []:
        if "=" not in item or "." not in item.split("=", 1)[0]:
            raise ConfigError(f"--set {item!r}: expected STAGE.PARAM=VALUE, e.g. jpeg.quality=90")
        key, raw = item.split("=", 1)
        stage, param = key.split(".", 1)
        try:
            value = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw  # a bare word is a string
        out.append((stage.strip(), param.strip(), value))
    return out


def build_config(config_path: str | None, sets: list[str] | None, *, no_correction: bool = False) -> dict:
    """The pipeline config (as a TOML document dict) from ``--config`` and
    ``--set`` options; the default pipeline when no file is given.
    ``no_correction``: every ``correction`` stage runs without a model
    (the identity), whatever the file or ``--set`` say."""
    from isp.pipeline import DEFAULT_STAGES

    if config_path:
        p = Path(config_path)
        try:
            config = tomllib.loads(p.read_text())
        except OSError as e:
            raise ConfigError(f"{p}: cannot read config: {e.strerror or e}") from None
        except tomllib.TOMLDecodeError as e:
            raise ConfigError(f"{p}: not valid TOML: {e}") from None
    else:
        config = {"stage": [{"name": n} for n in DEFAULT_STAGES]}
    stages = config.get("stage", [])
    for stage, param, value in _parse_set(sets):
        hits = [e for e in stages if isinstance(e, dict) and e.get("name") == stage]
        if not hits:
            names = ", ".join(str(e.get("name")) for e in stages if isinstance(e, dict))
            raise ConfigError(f"--set {stage}.{param}: no stage {stage!r} in the pipeline ({names})")
        for e in hits:
            e[param] = value
    if no_correction:
        for e in stages:
            if isinstance(e, dict) and e.get("name") == "correction":
                e["model"] = "none"
    return config


def build_pipeline(config: dict, where: str | None = None):
    from isp.pipeline import Pipeline

    try:
        return Pipeline.from_config(config)
    except ConfigError as e:
        if where:
            raise ConfigError(f"{where}: {e}") from None
        raise


# -- process ----------------------------------------------------------------
def cmd_process(args) -> int:
    from isp.io.files import save_stage, write_output
    from isp.io.read import read_raw

    config = build_config(args.config, args.set, no_correction=args.no_correction)
    pipeline = build_pipeline(config, args.config)
    out = Path(args.output)
    t0 = time.perf_counter()
    frame = read_raw(args.input, headerless=_headerless(args))
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


# -- info --------------------------------------------------------------------
def cmd_info(args) -> int:
    from isp.io.opcode_plan import opcode_plan
    from isp.io.read import read_raw

    frame = read_raw(args.input, headerless=_headerless(args))
    meta = frame.meta
    info = {
        "file": str(args.input),
        "data": {"shape": list(frame.shape), "kind": "linear RGB" if meta.linear_raw else "Bayer mosaic"},
        **meta.summary(),
        "opcode_plan": [p.as_dict() for p in opcode_plan(meta)],
        "skipped": [f"OpcodeList{p.list_no}[{p.index}] {p.name}: {p.reason}"
                    for p in opcode_plan(meta) if p.action == "skipped"],
    }
    info.pop("path", None)
    info["correction"] = _correction_summary(args)
    text = json.dumps(info, indent=2, default=str)
    if args.json:
        from isp.io.files import write_bytes_atomic

        write_bytes_atomic(args.json, text.encode())
    print(text)
    return 0


def _correction_summary(args) -> list[dict] | dict:
    """The correction model(s) the pipeline of ``--config``/``--set``/
    ``--no-correction`` would run (the default pipeline's packaged model
    when none is given)."""
    config = build_config(args.config, args.set, no_correction=args.no_correction)
    stages = [s for s in build_pipeline(config, args.config).stages if s.name == "correction"]
    if not stages:
        return {"model": None, "note": "the pipeline has no correction stage"}
    out = [s.summary() if hasattr(s, "summary") else {"model": "?"} for s in stages]
    return out[0] if len(out) == 1 else out


# -- stages ------------------------------------------------------------------
def cmd_stages(args) -> int:
    import dataclasses
    import typing

    from isp.registry import broken_stages, get_stage_class, list_stages, stage_origin

    if args.name:
        cls = get_stage_class(args.name)
        doc = (cls.__doc__ or "").strip()
        print(f"{args.name}  ({stage_origin(args.name)})")
        print(f"  consumes: {', '.join(d.value for d in cls.consumes)}")
        print(f"  produces: {cls.produces.value if getattr(cls, 'produces', None) else 'same as input'}")
        if dataclasses.is_dataclass(cls):
            hints = typing.get_type_hints(cls)
            print("  parameters:")
            for f in dataclasses.fields(cls):
                default = f.default if f.default is not dataclasses.MISSING else "(required)"
                tp = str(hints.get(f.name, "")).replace("typing.", "")
                print(f"    {f.name} = {default!r}   [{tp}]")
        print()
        print(doc)
        return 0
    stages = list_stages()
    for name, cls in stages.items():
        summary = (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""
        cons = "|".join(d.value for d in getattr(cls, "consumes", ()))
        prod = cls.produces.value if getattr(cls, "produces", None) else "same"
        print(f"{name:<15s} {cons} -> {prod}")
        print(f"{'':<15s} {summary}  [{stage_origin(name)}]")
    for name, err in broken_stages().items():
        print(f"{name:<15s} FAILED TO LOAD: {err}")
    return 0


# -- batch -------------------------------------------------------------------
def cmd_batch(args) -> int:
    from isp.runtime.batch import run_batch

    config = build_config(args.config, args.set, no_correction=args.no_correction)
    build_pipeline(config, args.config)  # refuse a bad config before any work
    return run_batch(Path(args.input), Path(args.output), config, workers=args.workers,
                     headerless=_headerless(args), suffix=args.format)


# -- demo --------------------------------------------------------------------
def cmd_demo(args) -> int:
    from calibration.demo import run_demo

    return run_demo(Path(args.output), size=(args.height, args.width), seed=args.seed)


# -- other packages' commands (imported only when called) ----------------------
EXTERNAL = {
    "calib": ("calibration.cli.main", "lens files, ray tracing, PSFs, simulated captures, SFR"),
    "synth": ("restoration.cli.synth", "training pairs from latent images through a proxy camera"),
    "train": ("restoration.cli.train", "train the optical-correction network on synthesised pairs"),
    "eval": ("restoration.cli.eval", "PSNR/SSIM per field ring of a correction model on unseen proxy cameras"),
    "export": ("export.cli", "checkpoint -> ONNX (FP32, static INT8) for the correction stage, with parity checks"),
}


def run_external(name: str, argv: list[str]) -> int:
    import importlib

    module = importlib.import_module(EXTERNAL[name][0])
    return int(module.main(argv) or 0)


def make_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="isp",
        description="A reference raw ISP for phone cameras: DNG in, JPEG out, every stage "
                    "swappable and inspectable.",
        epilog="Start with `isp demo`, then `isp process YOUR.dng -o out.jpg`. "
               "`isp COMMAND --help` explains each command.",
    )
    p.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    sp = sub.add_parser("process", help="raw file -> JPEG (or PNG/TIFF) through the pipeline",
                        description="Process one raw file through the pipeline (default: "
                                    "black level, lens shading, white balance, demosaic, "
                                    "correction, luminance, colour, gamma, JPEG).",
                        epilog=EPILOG_PROCESS, formatter_class=argparse.RawDescriptionHelpFormatter)
    sp.add_argument("input", help="raw file (DNG, a camera raw LibRaw reads, or a headerless dump)")
    sp.add_argument("-o", "--output", required=True, help="output .jpg (or .png/.tif if the "
                                                          "pipeline ends before the jpeg stage)")
    sp.add_argument("--config", help="pipeline TOML file ([[stage]] tables)")
    sp.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE",
                    help="override a stage parameter (repeatable), e.g. jpeg.quality=90")
    sp.add_argument("--save-stages", metavar="DIR",
                    help="write every intermediate as NN_stage.png (viewable) and .npy (exact)")
    sp.add_argument("-v", "--verbose", action="store_true", help="print each stage's decision and time")
    sp.add_argument("--no-correction", action="store_true",
                    help="run the correction stage without a model (identity); by default it runs "
                         "the packaged model of the default phone lens (see `isp info`)")
    _add_headerless(sp)
    sp.set_defaults(func=cmd_process)

    sp = sub.add_parser("info", help="print a raw file's metadata as JSON",
                        description="Print what the reader found in a raw file as JSON: geometry, "
                                    "CFA, levels, colour matrices and illuminants, opcodes and what "
                                    "the pipeline will apply or skip (and why), and the reader's notes.",
                        epilog="example:\n  isp info photo.dng | less",
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    sp.add_argument("input")
    sp.add_argument("--json", metavar="OUT", help="also write the JSON to a file")
    sp.add_argument("--config", help="pipeline TOML file whose correction model to report")
    sp.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE",
                    help="override a stage parameter, e.g. correction.model=my.onnx")
    sp.add_argument("--no-correction", action="store_true", help="report the pipeline without a model")
    _add_headerless(sp)
    sp.set_defaults(func=cmd_info)

    sp = sub.add_parser("stages", help="list the registered stages (built-in and plug-ins)",
                        description="List every stage the registry knows: built-in ones and those "
                                    "other installed packages add through the 'isp.stages' entry "
                                    "point group. With a NAME, show its parameters and documentation.",
                        epilog="examples:\n  isp stages\n  isp stages demosaic",
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    sp.add_argument("name", nargs="?", help="a stage to describe")
    sp.set_defaults(func=cmd_stages)

    sp = sub.add_parser("batch", help="process every raw file in a folder",
                        description="Process every raw file in DIR (by extension) into OUTDIR, "
                                    "in parallel, with a progress bar. Bad files are reported and "
                                    "skipped; the exit code is 1 if any failed.",
                        epilog="example:\n  isp batch captures/ -o jpegs/ --workers 2",
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    sp.add_argument("input", help="folder of raw files")
    sp.add_argument("-o", "--output", required=True, help="output folder")
    sp.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    sp.add_argument("--config", help="pipeline TOML file")
    sp.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE")
    sp.add_argument("--no-correction", action="store_true", help="correction stage without a model")
    sp.add_argument("--format", default=".jpg", help="output suffix (default .jpg)")
    _add_headerless(sp)
    sp.set_defaults(func=cmd_batch)

    sp = sub.add_parser("demo", help="write a synthetic phone capture (DNG) and process it",
                        description="Synthesise a phone capture (colour chart, slanted edges, lens "
                                    "shading stored as GainMap opcodes, sensor noise), write it as a "
                                    "DNG with the project's own writer, process it and report.",
                        epilog="example:\n  isp demo -o demo/",
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    sp.add_argument("-o", "--output", default="isp-demo", help="output folder (default isp-demo)")
    sp.add_argument("--width", type=int, default=2000)
    sp.add_argument("--height", type=int, default=1500)
    sp.add_argument("--seed", type=int, default=0)
    sp.set_defaults(func=cmd_demo)

    for name, (_, help_text) in EXTERNAL.items():
        sp = sub.add_parser(name, help=help_text, add_help=False,
                            description=f"{help_text} (`isp {name} --help` for its commands)")
        sp.add_argument("rest", nargs=argparse.REMAINDER)
        sp.set_defaults(func=None, external=name)
    return p


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in EXTERNAL:  # hand the whole command line over, --help included
        return _guarded(lambda: run_external(argv[0], argv[1:]), debug="--debug" in argv, where="")
    parser = make_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    from isp.runtime.threads import tune_allocator

    tune_allocator()
    if getattr(args, "external", None):  # e.g. `isp --debug calib ...`
        return _guarded(lambda: run_external(args.external, args.rest), debug=args.debug, where="")
    return _guarded(lambda: args.func(args), debug=args.debug, where=getattr(args, "input", ""))


def _guarded(fn, debug: bool, where) -> int:
    """Run a command: one line and exit 2 for an IspError, one line and
    exit 3 for a bug (traceback with --debug)."""
    try:
        return int(fn() or 0)
    except IspError as e:
        print(f"isp: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("isp: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # a bug: still one line, unless --debug
        if debug:
            raise
        print(f"isp: internal error{' on ' + str(where) if where else ''}: {type(e).__name__}: {e} "
              "(rerun with --debug for the traceback)", file=sys.stderr)
        return 3


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""``isp info``: what the reader found in a raw file, as JSON."""

from __future__ import annotations

import argparse
import inspect
import json

from isp.cli.arguments import (add_correction_arguments, add_headerless_arguments, headerless,
                               pipeline_from_args)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp info``."""
    p.description = ("Print what the reader found in a raw file as JSON: geometry, CFA, levels, colour "
                     "matrices and illuminants, opcodes and what the pipeline will apply or skip (and "
                     "why), the correction model its lens profile gives (or why none), and the "
                     "reader's notes.")
    p.epilog = "example:\n  isp info photo.dng | less"
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("input")
    p.add_argument("--json", metavar="OUT", help="also write the JSON to a file")
    p.add_argument("--config", help="pipeline TOML file whose correction model to report")
    p.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE",
                   help="override a stage parameter, e.g. correction.model=my.onnx")
    add_correction_arguments(p)
    add_headerless_arguments(p)


def run(args: argparse.Namespace) -> int:
    """Print the file's metadata, opcode plan and correction model as JSON."""
    from isp.io.opcode_plan import opcode_plan
    from isp.io.read import read_raw

    frame = read_raw(args.input, headerless=headerless(args))
    meta = frame.meta
    plan = opcode_plan(meta)
    info = {
        "file": str(args.input),
        "data": {"shape": list(frame.shape), "kind": "linear RGB" if meta.linear_raw else "Bayer mosaic"},
        **meta.summary(),
        "opcode_plan": [p.as_dict() for p in plan],
        "skipped": [f"OpcodeList{p.list_no}[{p.index}] {p.name}: {p.reason}"
                    for p in plan if p.action == "skipped"],
    }
    info.pop("path", None)
    info["correction"] = _correction(args, meta)
    text = json.dumps(info, indent=2, default=str)
    if args.json:
        from isp.io.files import write_bytes_atomic

        write_bytes_atomic(args.json, text.encode())
    print(text)
    return 0


def _correction(args, meta) -> list[dict] | dict:
    """The correction model(s) the pipeline of ``--config``/``--set``/
    ``--correction`` would run on this file: by default the model of the
    lens profile matching ``meta``, or none and why (:mod:`isp.profiles`).
    Only the correction stages are built: the others' modules stay
    unimported."""
    from isp.errors import ConfigError
    from isp.registry import create_stage

    config, _ = pipeline_from_args(args, build=False)
    entries = [e for e in config.get("stage", []) if isinstance(e, dict) and e.get("name") == "correction"]
    if not entries:
        return {"model": None, "note": "the pipeline has no correction stage"}
    try:
        stages = [create_stage("correction", **{k: v for k, v in e.items() if k != "name"}) for e in entries]
    except ConfigError as e:
        if args.config:
            raise ConfigError(f"{args.config}: {e}") from None
        raise

    def summary(stage):
        if not hasattr(stage, "summary"):
            return {"model": "?"}
        # the built-in stage reports the model of the file's profile; a plug-in's may take no metadata
        takes_meta = bool(inspect.signature(stage.summary).parameters)
        return stage.summary(meta) if takes_meta else stage.summary()

    out = [summary(s) for s in stages]
    return out[0] if len(out) == 1 else out

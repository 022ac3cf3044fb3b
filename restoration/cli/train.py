"""``isp train``: train the correction network on synthesised pairs.

Reached from ``isp train ...`` and imported only then; the configuration is
read and checked before torch is imported, so ``--help`` and a bad config
answer at once. Errors print one line and exit with code 2, like the rest
of ``isp`` (:mod:`isp.cli.run`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from isp.errors import ConfigError

EPILOG = """\
examples:
  isp train --config configs/e9_default.toml                  # synthesise (if needed), then train
  isp train --config configs/e9_default.toml --steps 50 --out out/try   # a short trial run
  isp train --config configs/e9_default.toml --resume out/e9_default/last.pt
  isp train --resume out/e9_default/last.pt --steps 6000      # continue with the checkpoint's config
  isp train --config configs/e9_default.toml --lens fit/proxy.json --out out/dev3   # for one device

--lens trains for one device (the paper's "single sample"): the pairs come from
that lens file alone -- the proxy camera `isp calib fit` fitted to the device --
into OUT/pairs. A proxy file carries the sensor of the capture it was fitted
to; --pixel-um makes the pairs at the pitch the model will correct instead
(docs/guide/correction.md, "A model for one device").

The config (TOML or JSON) has sections [data], [synth], [model], [optim],
[temperature] and [run]; every key and its default is listed in the docstring
of restoration/train/trainer.py (python -c "import restoration.train.trainer as t; help(t)").
Without [synth], data.dirs must name existing `isp synth` output folders.

Output folder (run.out or --out): checkpoints/step_NNNNNNN.pt, last.pt, model.pt
(the final model), train_log.json and loss.png. Ctrl-C saves last.pt first.
A CUDA GPU is used when present (run.device = "auto").
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``isp train``."""
    p.description = ("Train the optical-correction network: loss on Process(Model(J)) against the sRGB "
                     "target, Process being the pipeline's own stages after the slot (paper, eq. 24).")
    p.epilog = EPILOG
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.add_argument("--config", help="training config (.toml or .json); optional with --resume")
    p.add_argument("--resume", metavar="CKPT", help="continue from a checkpoint (e.g. OUT/last.pt)")
    p.add_argument("--out", help="output folder (overrides run.out)")
    p.add_argument("--steps", type=int, help="total optimiser steps (overrides run.steps)")
    p.add_argument("--seconds", type=float, metavar="S",
                   help="wall-clock budget of the steps (overrides run.seconds): the run measures its "
                        "step time and ends within S seconds, at most run.steps steps")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), help="overrides run.device")
    p.add_argument("--threads", type=int, help="torch CPU threads (overrides run.threads)")
    p.add_argument("--lens", metavar="PROXY",
                   help="train for one device: the pairs from this lens file alone (synth.lens = PROXY, "
                        "synth.samples = 1, synth.out = OUT/pairs)")
    p.add_argument("--pixel-um", type=float, metavar="UM",
                   help="the pairs' pixel pitch, µm (overrides synth.pixel_um): e.g. 1.0 to train the "
                        "full-resolution mode from a proxy fitted to a binned capture")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    """Read the config (or the checkpoint's), apply the options, train."""
    from restoration.train.config import TrainConfig, for_one_device, load_config

    if args.config is None and args.resume is None:
        raise ConfigError("give --config FILE (or --resume CKPT to continue with the checkpoint's config)")
    if args.resume is not None and not Path(args.resume).is_file():
        raise ConfigError(f"--resume {args.resume}: no such checkpoint")
    if args.config is not None:
        config = load_config(args.config)
    else:
        from restoration.nn.checkpoint import load_checkpoint

        saved = load_checkpoint(args.resume).get("config")
        if not saved:
            raise ConfigError(f"{args.resume}: the checkpoint holds no config; give --config")
        config = TrainConfig.from_dict(saved, where=f"{args.resume} (config)")
    changes = {k: v for k, v in (("out", args.out), ("steps", args.steps), ("device", args.device),
                                                    ("threads", args.threads),
                                                    ("seconds", args.seconds)) if v is not None}
    if changes:
        config = config.replace("run", **changes)
    if args.lens is not None:
        config = for_one_device(config, args.lens)
    if args.pixel_um is not None:
        if config.synth is None:
            raise ConfigError("--pixel-um needs a config whose pairs come from its [synth] section")
        config = config.replace("synth", pixel_um=float(args.pixel_um))
    from restoration.train.trainer import synth_executor, train

    train(config, resume=args.resume, executor=synth_executor(config, progress=not args.quiet))
    return 0


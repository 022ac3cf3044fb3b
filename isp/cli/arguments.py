"""Argument helpers the commands share: argparse types, option groups, and their parsing.

``float_range`` and ``int_grid`` are argparse ``type=`` functions (a bad
value is argparse's usage error, exit code 2); :func:`numbers` reads a
comma-separated option in a command's ``run`` (a bad value is a
ConfigError, exit code 2); the rest serve the commands that run the
pipeline (``process``, ``info``, ``batch``): the headerless dump options
and ``--set STAGE.PARAM=VALUE``.
"""

from __future__ import annotations

import argparse
import tomllib

from isp.errors import ConfigError


def float_range(text: str) -> tuple[float, float]:
    """``"LOW,HIGH"`` → ``(low, high)`` floats (an argparse ``type=``).

    >>> float_range("0,2")
    (0.0, 2.0)
    """
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LOW,HIGH (two numbers), got {text!r}") from None
    return lo, hi


def int_grid(text: str) -> tuple[int, int]:
    """``"ROWS,COLS"`` → ``(rows, cols)``, each at least 1 (an argparse ``type=``).

    >>> int_grid("15,20")
    (15, 20)
    """
    try:
        rows, cols = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected ROWS,COLS (two integers), got {text!r}") from None
    if rows < 1 or cols < 1:
        raise argparse.ArgumentTypeError(f"the grid needs at least 1 row and 1 column, got {text!r}")
    return rows, cols


def numbers(text: str, n: int | None = None) -> tuple[float, ...]:
    """``"A,B,..."`` → floats; exactly ``n`` of them unless ``n`` is None
    (ConfigError otherwise, naming the text).

    >>> numbers("0,0.5,1")
    (0.0, 0.5, 1.0)
    """
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ConfigError(f"expected comma-separated numbers, got {text!r}") from None
    if n is not None and len(vals) != n:
        raise ConfigError(f"expected {n} numbers, got {text!r}")
    return vals


def add_headerless_arguments(parser: argparse.ArgumentParser) -> None:
    """The options that describe a headerless dump (a file with no raw header)."""
    g = parser.add_argument_group("headerless dumps (files with no raw header)")
    g.add_argument("--width", type=int, help="pixels per row")
    g.add_argument("--height", type=int, help="rows")
    g.add_argument("--bits", type=int, help="significant bits per sample (8: bytes, 9-16: 16-bit words)")
    g.add_argument("--pattern", help="CFA pattern: RGGB, BGGR, GRBG or GBRG")
    g.add_argument("--black", type=float, default=0.0, help="black level in DN (default 0)")


def headerless(args: argparse.Namespace):
    """The :class:`isp.io.read.Headerless` geometry of the options of
    :func:`add_headerless_arguments`, or None when none is given
    (ConfigError when only some are)."""
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


def parse_overrides(items: list[str] | None) -> list[tuple[str, str, object]]:
    """``--set STAGE.PARAM=VALUE`` options → ``(stage, param, value)``; the
    value is read as TOML (``90``, ``true``, ``[1, 2]``), a bare word as a
    string.

    >>> parse_overrides(["jpeg.quality=90", "white_balance.mode=grey_world"])
    [('jpeg', 'quality', 90), ('white_balance', 'mode', 'grey_world')]
    """
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


def pipeline_from_args(args: argparse.Namespace):
    """``(config, pipeline)`` of the ``--config``, ``--set`` and
    ``--no-correction`` options, the pipeline built (and so checked) before
    any pixel is read; a config error names the ``--config`` file."""
    from isp.pipeline import Pipeline, pipeline_config

    config = pipeline_config(args.config, parse_overrides(args.set), no_correction=args.no_correction)
    try:
        return config, Pipeline.from_config(config)
    except ConfigError as e:
        if args.config:
            raise ConfigError(f"{args.config}: {e}") from None
        raise

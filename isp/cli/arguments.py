"""Argument helpers the commands share: argparse types, option groups, and their parsing.

``float_range`` and ``int_grid`` are argparse ``type=`` functions (a bad
value is argparse's usage error, exit code 2); :func:`numbers` reads a
comma-separated option in a command's ``run`` (a bad value is a
ConfigError, exit code 2); the rest serve the commands that run the
pipeline (``process``, ``info``, ``batch``): the headerless dump options,
``--set STAGE.PARAM=VALUE`` and ``--correction FILE|none``.
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


def add_correction_arguments(parser: argparse.ArgumentParser) -> None:
    """``--correction FILE|none`` (and ``--no-correction``, the same as
    ``--correction none``): the correction stage's model, whatever the lens
    profiles say (by default the model of the profile matching each file's
    lens, none where no profile matches: :mod:`isp.profiles`)."""
    parser.add_argument("--correction", metavar="FILE|none",
                        help="correction model to run on every file: an ONNX file, 'default' (the packaged "
                             "model of the default phone lens) or 'none'; by default ('auto') the model of "
                             "the lens profile matching the file (`isp profiles`), none where no profile matches")
    parser.add_argument("--no-correction", dest="correction", action="store_const", const="none",
                        help="the same as --correction none")
    parser.add_argument("--device", metavar="FILE",
                        help="the camera module's calibration (device/v1 JSON, `isp calib fit --basis`) for a "
                             "correction model shared by every module of its lens design")


def add_look_argument(parser: argparse.ArgumentParser) -> None:
    """``--look NAME``: which built-in pipeline renders the file
    (:data:`isp.pipeline.LOOKS`)."""
    parser.add_argument("--look", choices=("adobe", "linear"),
                        help="built-in pipeline: 'adobe' (default; renders as Adobe's DNG SDK: camera "
                             "profile, exposure ramp, tone curve, neutral highlights) or 'linear' (the "
                             "scene-referred render: exposure, colour matrix, sRGB encoding, no tone "
                             "curve; the correction models are trained on it)")


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


def choose_encoder(config: dict, output: str, overrides: list[tuple[str, str, object]]) -> dict:
    """End ``config`` in the encoding stage of ``output``'s extension
    (:func:`isp.io.files.encoder_for`) and apply the ``--set`` overrides of
    the encoding stages (``jpeg``, ``png``, ``tiff``).

    A final encoding stage of another format is replaced (its parameters
    dropped); a pipeline that ends before any encoding stage gets one. A
    32-bit float TIFF (``tiff.bits=32``) right after a ``gamma`` stage
    leaves that stage out, so the file holds the linear values.

    >>> c = {"stage": [{"name": "gamma"}, {"name": "jpeg", "quality": 90}]}
    >>> choose_encoder(c, "x.png", [("png", "bits", 16)])["stage"]
    [{'name': 'gamma'}, {'name': 'png', 'bits': 16}]
    >>> choose_encoder(c, "x.tif", [("tiff", "bits", 32)])["stage"]
    [{'name': 'tiff', 'bits': 32}]
    """
    from isp.io.files import ENCODERS, encoder_for

    encoder = encoder_for(output)
    stages = [e for e in config.get("stage", []) if isinstance(e, dict)]
    last = stages[-1] if stages else None
    if last is not None and last.get("name") in ENCODERS.values():
        if last["name"] != encoder:
            stages[-1] = {"name": encoder}
    else:
        stages.append({"name": encoder})
    for stage, param, value in overrides:
        if stage != encoder:
            raise ConfigError(f"--set {stage}.{param}: {output} is written by the {encoder!r} stage "
                              f"(the output's extension chooses it), not {stage!r}")
        stages[-1][param] = value
    if encoder == "tiff" and stages[-1].get("bits") == 32 and len(stages) > 1 \
            and stages[-2].get("name") == "gamma":
        del stages[-2]
    return {**config, "stage": stages}


def pipeline_from_args(args: argparse.Namespace, output: str | None = None, *, build: bool = True):
    """``(config, pipeline)`` of the ``--config``, ``--set`` and
    ``--correction`` options, the pipeline built (and so checked) before
    any pixel is read; a config error names the ``--config`` file.
    ``--correction`` sets the model of every correction stage (ConfigError
    when the pipeline has none). With ``output`` (a file name, or just its
    extension), the pipeline ends in that format's encoding stage
    (:func:`choose_encoder`). With ``build=False`` the pipeline is None:
    the config alone, no stage module imported."""
    from isp.io.files import ENCODERS
    from isp.pipeline import Pipeline, pipeline_config

    overrides = parse_overrides(args.set)
    encoding = [o for o in overrides if o[0] in ENCODERS.values()] if output is not None else []
    config = pipeline_config(args.config, [o for o in overrides if o not in encoding],
                             look=getattr(args, "look", None))
    if output is not None:
        config = choose_encoder(config, output, encoding)
    # --correction FILE|none and --device FILE set every correction stage of the pipeline
    for option, key, value in (("--correction", "model", getattr(args, "correction", None)),
                               ("--device", "device", getattr(args, "device", None))):
        if value is None:
            continue
        slots = [e for e in config.get("stage", []) if isinstance(e, dict) and e.get("name") == "correction"]
        if not slots:
            raise ConfigError(f"{option} {value}: the pipeline has no correction stage")
        for e in slots:
            e[key] = value
    if not build:
        return config, None
    try:
        return config, Pipeline.from_config(config)
    except ConfigError as e:
        if args.config:
            raise ConfigError(f"{args.config}: {e}") from None
        raise

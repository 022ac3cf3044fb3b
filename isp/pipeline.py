"""Pipelines: an ordered list of stages, checked when built, run on frames.

A pipeline is built from code (a list of stage objects) or from a TOML file::

    # my_pipeline.toml
    [[stage]]
    name = "black_level"

    [[stage]]
    name = "white_balance"
    mode = "grey_world"

    [[stage]]
    name = "demosaic"
    method = "malvar2004"

Building checks, before any pixel is read, that every stage exists, that its
parameters are known and of the right type, and that each stage consumes the
domain its predecessor produces; each error names the stage (and its
position). Stages with placement rules (the correction slot) check them here
too.
"""

from __future__ import annotations

import time
import tomllib
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from isp.errors import ConfigError
from isp.frame import Domain, Frame
from isp.registry import create_stage
from isp.stage import Stage

#: The built-in pipelines ("looks"), by stage name (the stages live in
#: ``modules``). Both share the stages up to the correction slot:
#:
#: * ``adobe`` (the default) renders as the DNG specification's reference
#:   implementation, the Adobe DNG SDK, does: camera profile (matrices,
#:   HueSatMap, LookTable), exposure ramp, ProfileToneCurve or Adobe's default
#:   curve, sRGB, clipped highlights neutral (``dng_render``);
#: * ``linear`` is the scene-referred render: exposure from BaselineExposure
#:   without a tone curve (``luminance``), the colour matrix to linear sRGB
#:   (``ccm``), the sRGB encoding (``gamma``); the correction models are
#:   trained and evaluated on it.
_BEFORE_RENDER = ("opcode_list1", "black_level", "opcode_list2", "lens_shading", "white_balance",
                  "demosaic", "opcode_list3", "correction")
LOOKS: dict[str, tuple[str, ...]] = {
    "adobe": _BEFORE_RENDER + ("highlights", "dng_render", "jpeg"),
    "linear": _BEFORE_RENDER + ("luminance", "ccm", "gamma", "jpeg"),
}

#: Parameters a look sets on its stages (user overrides win). The ``adobe``
#: look demosaics as the Adobe DNG SDK does (bilinear, ``dng_mosaic_info``),
#: so that its render matches Adobe's to a mean CIEDE2000 below 0.1 on the
#: reference captures (``benchmarks/adobe_parity.py``); Malvar–He–Cutler
#: (the stage's own default) moves edges by about 1 ΔE00 on average. Where
#: a lens profile matches, ``"auto"`` takes the method its correction model
#: was trained after instead (the profile's ``demosaic``), so that the
#: correction sees the input it learnt from.
LOOK_PARAMS: dict[str, dict[str, dict[str, Any]]] = {
    "adobe": {"demosaic": {"method": "auto"}},
    "linear": {},
}

#: The look :meth:`Pipeline.default` and ``isp process`` use.
DEFAULT_LOOK = "adobe"

#: The default pipeline, by stage name: the stages of :data:`DEFAULT_LOOK`.
DEFAULT_STAGES: tuple[str, ...] = LOOKS[DEFAULT_LOOK]


def look_stages(look: str = DEFAULT_LOOK) -> tuple[str, ...]:
    """The stage names of a look (:data:`LOOKS`).

    Raises
    ------
    ConfigError
        Unknown look; the message lists the valid ones.

    >>> look_stages("linear")[-4:]
    ('luminance', 'ccm', 'gamma', 'jpeg')
    """
    try:
        return LOOKS[look]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown look {look!r}; valid: {', '.join(LOOKS)}") from None


def _label(index: int, stage_name: str) -> str:
    return f"stage #{index + 1} {stage_name!r}"


class Pipeline:
    """An ordered, validated list of stages.

    Parameters
    ----------
    stages : sequence of Stage
        Stage objects, in order.
    start : Domain or str
        Domain of the frames the pipeline accepts (``raw`` for a reader's
        output).

    Raises
    ------
    ConfigError
        If a stage does not consume what its predecessor produces, or a stage's
        own build-time check fails.
    """

    def __init__(self, stages: Sequence[Stage], start: Domain | str = Domain.RAW):
        self.stages: tuple[Stage, ...] = tuple(stages)
        self.start = Domain.parse(start)
        self.domains = self._validate()

    # -- building -----------------------------------------------------------
    def _validate(self) -> tuple[Domain, ...]:
        """Domains before each stage and after the last (len = n + 1)."""
        domain = self.start
        domains = [domain]
        prev = "the input"
        for i, st in enumerate(self.stages):
            if not isinstance(st, Stage):
                raise ConfigError(f"{_label(i, type(st).__name__)} is not a stage "
                                  "(needs name, consumes, output_domain, check, __call__)")
            label = _label(i, st.name)
            if domain not in st.consumes:
                valid = ", ".join(d.value for d in st.consumes)
                raise ConfigError(
                    f"{label} consumes {valid} but {prev} produces {domain.value}")
            try:
                st.check(domain)
            except ConfigError as e:
                raise type(e)(f"{label}: {e}") from None
            domain = st.output_domain(domain)
            domains.append(domain)
            prev = f"{label}"
        return tuple(domains)

    @classmethod
    def from_config(cls, config: dict[str, Any]) -> "Pipeline":
        """Build from a parsed TOML document: ``{"start": ..., "stage": [{...}]}``,
        or ``{"look": "linear"}`` for a built-in look (:data:`LOOKS`)."""
        if not isinstance(config, dict):
            raise ConfigError("pipeline config must be a table")
        unknown = set(config) - {"start", "stage", "look"}
        if unknown:
            raise ConfigError(f"pipeline config: unknown key(s) {sorted(unknown)}; "
                              "valid: start, stage, look")
        if "look" in config:
            config = _expand_look(config)
        entries = config.get("stage", [])
        if not isinstance(entries, list) or not entries:
            raise ConfigError("pipeline config needs at least one [[stage]] table")
        stages = []
        for i, entry in enumerate(entries):
            if not isinstance(entry, dict) or "name" not in entry:
                raise ConfigError(f"stage #{i + 1}: a [[stage]] table needs a 'name'")
            params = {k: v for k, v in entry.items() if k != "name"}
            name = entry["name"]
            stages.append(create_stage(name, label=_label(i, name), **params))
        return cls(stages, start=config.get("start", Domain.RAW))

    @classmethod
    def from_toml(cls, source: str | Path) -> "Pipeline":
        """Build from a TOML file path, or from TOML text."""
        text, where = None, "pipeline config"
        if isinstance(source, Path) or (isinstance(source, str) and "\n" not in source
                                        and source.endswith(".toml")):
            path = Path(source)
            where = str(path)
            try:
                text = path.read_text()
            except OSError as e:
                raise ConfigError(f"{path}: cannot read config: {e.strerror or e}") from None
        else:
            text = str(source)
        try:
            config = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise ConfigError(f"{where}: not valid TOML: {e}") from None
        try:
            return cls.from_config(config)
        except ConfigError as e:
            if where != "pipeline config":
                raise ConfigError(f"{where}: {e}") from None
            raise

    @classmethod
    def from_names(cls, names: Iterable[str] = DEFAULT_STAGES, overrides: dict[str, dict] | None = None,
                   start: Domain | str = Domain.RAW) -> "Pipeline":
        """Build from stage names, with optional parameters per name."""
        overrides = overrides or {}
        stages = [create_stage(n, label=_label(i, n), **overrides.get(n, {}))
                  for i, n in enumerate(names)]
        return cls(stages, start=start)

    @classmethod
    def default(cls, look: str = DEFAULT_LOOK, **overrides: dict) -> "Pipeline":
        """A built-in pipeline: the stages of ``look`` (:data:`LOOKS`;
        ``"adobe"`` by default, ``"linear"`` for the scene-referred render),
        with optional parameters per stage name, e.g.
        ``default(jpeg={"quality": 90})``."""
        stages = look_stages(look)
        params = {name: {**p, **overrides.get(name, {})} for name, p in LOOK_PARAMS[look].items()}
        return cls.from_names(stages, {**overrides, **params})

    # -- inspecting ---------------------------------------------------------
    @property
    def output_domain(self) -> Domain:
        return self.domains[-1]

    def without(self, *names: str) -> "Pipeline":
        """The same pipeline with the named stages removed (revalidated)."""
        return Pipeline([s for s in self.stages if s.name not in names], start=self.start)

    def until(self, domain: Domain | str) -> "Pipeline":
        """The leading stages up to (and including) the last that produces
        ``domain``."""
        domain = Domain.parse(domain)
        keep = [s for s, d in zip(self.stages, self.domains[1:]) if d.order <= domain.order]
        return Pipeline(keep, start=self.start)

    def to_toml(self) -> str:
        """The pipeline as TOML text that :meth:`from_toml` reads back."""
        lines = [f'start = "{self.start.value}"', ""]
        for st in self.stages:
            lines.append("[[stage]]")
            lines.append(f'name = "{st.name}"')
            params = st.params() if hasattr(st, "params") else {}
            for k, v in params.items():
                if v is None:
                    continue
                lines.append(f"{k} = {_toml_value(v)}")
            lines.append("")
        return "\n".join(lines)

    def describe(self) -> str:
        """One line per stage: domain in → out and parameters."""
        out = []
        for i, (st, din, dout) in enumerate(zip(self.stages, self.domains, self.domains[1:])):
            params = st.params() if hasattr(st, "params") else {}
            ps = ", ".join(f"{k}={v!r}" for k, v in params.items())
            out.append(f"{i + 1:2d}. {st.name:<14s} {din.value} -> {dout.value}  {ps}")
        return "\n".join(out)

    def __repr__(self) -> str:
        return f"Pipeline([{', '.join(s.name for s in self.stages)}])"

    # -- running ------------------------------------------------------------
    def run(self, frame: Frame,
            on_step: Callable[[int, Stage, Frame, float], None] | None = None) -> Frame:
        """Run every stage on ``frame`` and return the last frame.

        Each stage with a ``prepare(frame)`` method is handed the input
        first, to start slow set-up of its own in the background (a
        model's session: :meth:`modules.correction.Correction.prepare`).

        ``on_step(index, stage, output, seconds)`` is called after each stage
        (index -1 with the input frame first); use it to save or time the
        intermediates. Only the current frame is kept otherwise.
        """
        if frame.domain is not self.start:
            raise ConfigError(
                f"pipeline starts at {self.start.value} but the frame is in {frame.domain.value}")
        if on_step is not None:
            on_step(-1, None, frame, 0.0)
        for st in self.stages:   # slow set-up (a model's session) starts now, in the background
            prepare = getattr(st, "prepare", None)
            if prepare is not None:
                prepare(frame)
        for i, st in enumerate(self.stages):
            t0 = time.perf_counter()
            frame = st(frame)
            dt = time.perf_counter() - t0
            if on_step is not None:
                on_step(i, st, frame, dt)
        return frame


def _expand_look(config: dict[str, Any]) -> dict[str, Any]:
    """``config`` with ``look = NAME`` replaced by that look's ``[[stage]]``
    tables; no look and no stages: the default look."""
    if "look" in config and config.get("stage"):
        raise ConfigError("pipeline config: give either look = \"NAME\" or [[stage]] tables, not both")
    if config.get("stage"):
        return config
    look = config.get("look", DEFAULT_LOOK)
    out = {k: v for k, v in config.items() if k != "look"}
    out["stage"] = [{"name": n, **LOOK_PARAMS[look].get(n, {})} for n in look_stages(look)]
    return out


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + "}"
    s = str(v).replace("\\", "\\\\").replace('"', '\\"')
    return f'"{s}"'


def pipeline_config(path: str | Path | None = None, overrides: Iterable[tuple[str, str, Any]] = (), *,
                    no_correction: bool = False, look: str | None = None) -> dict[str, Any]:
    """A pipeline config (a parsed TOML document) with parameter overrides.

    Parameters
    ----------
    path : str or Path, optional
        A pipeline TOML file (``[[stage]]`` tables, or ``look = "NAME"``);
        none: the stages of ``look``.
    look : str, optional
        A built-in look (:data:`LOOKS`; ``isp process --look``); default
        :data:`DEFAULT_LOOK`. ConfigError with a file that lists its own
        stages.
    overrides : iterable of (stage, parameter, value)
        Set ``parameter`` of every stage named ``stage`` to ``value``
        (``isp process --set STAGE.PARAM=VALUE``).
    no_correction : bool
        Every ``correction`` stage runs without a model (the identity),
        whatever the file or the overrides say.

    Returns
    -------
    dict
        For :meth:`Pipeline.from_config`; not checked yet.

    Raises
    ------
    ConfigError
        The file cannot be read or is not TOML; an override names a stage
        the pipeline does not have (the message lists those it has).

    >>> pipeline_config(overrides=[("jpeg", "quality", 90)])["stage"][-1]
    {'name': 'jpeg', 'quality': 90}
    """
    if path:
        p = Path(path)
        try:
            config = tomllib.loads(p.read_text())
        except OSError as e:
            raise ConfigError(f"{p}: cannot read config: {e.strerror or e}") from None
        except tomllib.TOMLDecodeError as e:
            raise ConfigError(f"{p}: not valid TOML: {e}") from None
    else:
        config = {}
    if look is not None:
        if config.get("stage"):
            raise ConfigError(f"--look {look}: {path} lists its own [[stage]] tables; "
                              "give either a look or a pipeline file")
        config["look"] = look
    if not path or "look" in config:
        config = _expand_look(config)
    stages = config.get("stage", [])
    for stage, param, value in overrides:
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

"""The Stage protocol and the base class built-in stages use.

A stage is a pure function of a frame plus a thin wrapper holding its
parameters in a frozen dataclass. The wrapper declares which domains it
consumes and which it produces, so a :class:`~isp.pipeline.Pipeline` can
refuse a chain that does not fit before any pixel is touched.

Example
-------
>>> from dataclasses import dataclass
>>> from isp import Domain, StageBase, register_stage
>>> @register_stage
... @dataclass(frozen=True)
... class Invert(StageBase):
...     '''Invert display values (a toy, for the docs).'''
...     name = "invert_doc_example"
...     consumes = (Domain.DISPLAY_RGB,)
...     strength: float = 1.0
...     def process(self, frame):
...         return frame.evolve(1.0 - self.strength * frame.data, stage=self.name)
>>> Invert(strength=0.5).params()
{'strength': 0.5}
"""

from __future__ import annotations

import dataclasses
import numbers
import types
import typing
from pathlib import Path
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from isp.errors import ConfigError
from isp.frame import Domain, Frame


@runtime_checkable
class Stage(Protocol):
    """What the pipeline needs of a stage."""

    name: str
    consumes: tuple[Domain, ...]

    def output_domain(self, domain: Domain) -> Domain:
        """Domain of the output for an input in ``domain``."""

    def check(self, domain: Domain) -> None:
        """Build-time checks beyond the domain chain (raise ConfigError)."""

    def __call__(self, frame: Frame) -> Frame:
        """Process one frame."""


class StageBase:
    """Convenience base: subclass it as a frozen dataclass of parameters and
    implement :meth:`process`. Parameters are validated by type when the
    stage is created through the registry or a config file."""

    name: ClassVar[str] = ""
    consumes: ClassVar[tuple[Domain, ...]] = ()
    #: output domain; None means "same as the input"
    produces: ClassVar[Domain | None] = None

    def output_domain(self, domain: Domain) -> Domain:
        return self.produces if self.produces is not None else domain

    def check(self, domain: Domain) -> None:
        return None

    def prepare(self, frame: Frame) -> None:
        """Optional: start slow set-up in the background (loading a model)
        when the pipeline receives its input ``frame``; must not raise (the
        stage's run reports errors). The pipeline calls it on any stage
        that has it."""
        return None

    def process(self, frame: Frame) -> Frame:  # pragma: no cover - abstract
        raise NotImplementedError

    def __call__(self, frame: Frame) -> Frame:
        if frame.domain not in self.consumes:
            valid = ", ".join(d.value for d in self.consumes)
            raise ConfigError(
                f"stage {self.name!r} consumes {valid}, got a frame in {frame.domain.value}")
        return self.process(frame)

    def params(self) -> dict[str, Any]:
        """The stage's parameters as a plain dict (what a TOML table holds)."""
        if dataclasses.is_dataclass(self):
            return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.init}
        return {}


def _type_name(tp) -> str:
    if isinstance(tp, type):
        return tp.__name__
    return str(tp).replace("typing.", "")


def coerce_param(value: Any, tp: Any) -> Any:
    """``value`` checked against the annotation ``tp`` (and converted where the
    conversion loses nothing: int → float, list → tuple, str → Path).

    Raises TypeError with what was expected and what came."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        errors = []
        for a in args:
            if a is type(None):
                if value is None:
                    return None
                continue
            try:
                return coerce_param(value, a)
            except TypeError as e:
                errors.append(str(e))
        raise TypeError(f"expected {_type_name(tp)}, got {value!r}")
    if origin is typing.Literal:
        if value in args:
            return value
        raise TypeError(f"expected one of {', '.join(repr(a) for a in args)}, got {value!r}")
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise TypeError(f"expected a list ({_type_name(tp)}), got {value!r}")
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(args) != len(value):
                raise TypeError(f"expected {len(args)} values ({_type_name(tp)}), got {value!r}")
            items = [coerce_param(v, a) for v, a in zip(value, args)]
        else:
            elem = args[0] if args else Any
            items = [coerce_param(v, elem) for v in value]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(value, dict):
            raise TypeError(f"expected a table, got {value!r}")
        return dict(value)
    if tp is float:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            raise TypeError(f"expected a number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
            raise TypeError(f"expected an integer, got {value!r}")
        return int(value)
    if tp is bool:
        if not isinstance(value, bool):
            raise TypeError(f"expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise TypeError(f"expected a string, got {value!r}")
        return value
    if tp is Path:
        if not isinstance(value, (str, Path)):
            raise TypeError(f"expected a path, got {value!r}")
        return Path(value)
    if isinstance(tp, type):
        if isinstance(value, tp):
            return value
        raise TypeError(f"expected {tp.__name__}, got {value!r}")
    return value


def build_stage(cls: type, params: dict[str, Any], label: str) -> Stage:
    """Instantiate ``cls`` with ``params`` validated against its dataclass
    fields; errors name ``label`` (the stage and its position)."""
    if not dataclasses.is_dataclass(cls):
        try:
            return cls(**params)
        except TypeError as e:
            raise ConfigError(f"{label}: {e}") from None
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(params) - set(fields))
    if unknown:
        valid = ", ".join(sorted(fields)) or "none"
        raise ConfigError(f"{label}: unknown parameter {', '.join(map(repr, unknown))}; valid: {valid}")
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for k, v in params.items():
        try:
            kwargs[k] = coerce_param(v, hints.get(k, Any))
        except TypeError as e:
            raise ConfigError(f"{label}: parameter {k!r}: {e}") from None
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{label}: {e}") from None


def stage_parameters(cls: type) -> list[tuple[str, Any, str]] | None:
    """``(name, default, type)`` of each field of a dataclass stage class
    (the default ``"(required)"`` where there is none; the type as written,
    without ``typing.``), for ``isp stages NAME``; None for a class that is
    not a dataclass.

    >>> import dataclasses
    >>> @dataclasses.dataclass
    ... class Gain:
    ...     factor: float = 1.0
    >>> stage_parameters(Gain)
    [('factor', 1.0, "<class 'float'>")]
    """
    if not dataclasses.is_dataclass(cls):
        return None
    hints = typing.get_type_hints(cls)
    return [(f.name, f.default if f.default is not dataclasses.MISSING else "(required)",
             str(hints.get(f.name, "")).replace("typing.", "")) for f in dataclasses.fields(cls)]

"""The stage registry: one dict of stage classes by name.

Stages arrive two ways:

* ``@register_stage`` on a class (in code, a notebook or a test);
* the entry-point group ``isp.stages`` of any installed distribution, e.g. in
  its ``pyproject.toml``::

      [project.entry-points."isp.stages"]
      denoise = "my_package.denoise:Denoise"

  The built-in stages of :mod:`modules` are registered exactly this way, which
  is how :mod:`isp` uses them without importing them.

Entry points are loaded lazily, the first time a name is looked up or the
list is asked for. ``create_stage(name, **params)`` builds any of them (the
``timm.create_model`` pattern).
"""

from __future__ import annotations

from importlib import metadata
from typing import Any

from isp.errors import ConfigError
from isp.stage import Stage, build_stage

ENTRY_POINT_GROUP = "isp.stages"

_REGISTRY: dict[str, type] = {}
_ORIGIN: dict[str, str] = {}
_entry_points_loaded = False
_entry_point_errors: dict[str, str] = {}


def register_stage(cls=None, *, name: str | None = None, origin: str = "code"):
    """Class decorator: register a stage class under ``name`` (default: its
    ``name`` attribute). Re-registering a name replaces the entry."""

    def deco(c):
        key = name or getattr(c, "name", "")
        if not key:
            raise ConfigError(f"stage class {c.__qualname__} has no name")
        _REGISTRY[key] = c
        _ORIGIN.setdefault(key, origin)
        return c

    return deco(cls) if cls is not None else deco


def _load_entry_points() -> None:
    global _entry_points_loaded
    if _entry_points_loaded:
        return
    _entry_points_loaded = True
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        if ep.name in _REGISTRY:
            continue
        try:
            cls = ep.load()
        except Exception as e:  # a broken plug-in must not break the others
            _entry_point_errors[ep.name] = f"{ep.value}: {type(e).__name__}: {e}"
            continue
        _REGISTRY[ep.name] = cls
        dist = getattr(ep, "dist", None)
        _ORIGIN[ep.name] = f"{dist.name if dist else '?'} ({ep.value})"


def reload_entry_points() -> None:
    """Forget what entry points gave and read them again (after installing a
    plug-in in a running process)."""
    global _entry_points_loaded
    for k in [k for k, o in _ORIGIN.items() if o != "code"]:
        _REGISTRY.pop(k, None)
        _ORIGIN.pop(k, None)
    _entry_point_errors.clear()
    _entry_points_loaded = False


def list_stages() -> dict[str, type]:
    """All registered stage classes by name, sorted."""
    _load_entry_points()
    return dict(sorted(_REGISTRY.items()))


def stage_origin(name: str) -> str:
    """Where a stage came from: ``code`` or ``distribution (module:Class)``."""
    _load_entry_points()
    return _ORIGIN.get(name, "?")


def broken_stages() -> dict[str, str]:
    """Entry points that failed to load, with the reason."""
    _load_entry_points()
    return dict(_entry_point_errors)


def get_stage_class(name: str, label: str | None = None) -> type:
    """The class registered as ``name``; the error lists the valid names."""
    _load_entry_points()
    try:
        return _REGISTRY[name]
    except KeyError:
        where = f"{label}: " if label else ""
        if name in _entry_point_errors:
            raise ConfigError(f"{where}stage {name!r} failed to load: {_entry_point_errors[name]}") from None
        valid = ", ".join(sorted(_REGISTRY)) or "none (is the package installed?)"
        raise ConfigError(f"{where}unknown stage {name!r}; valid: {valid}") from None


def create_stage(name: str, *, label: str | None = None, **params: Any) -> Stage:
    """Build the stage registered as ``name`` with validated ``params``.

    >>> create_stage("no_such_stage")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    isp.errors.ConfigError: unknown stage 'no_such_stage'; valid: ...
    """
    cls = get_stage_class(name, label)
    return build_stage(cls, params, label or f"stage {name!r}")

"""Registries: named entries from code and from an entry-point group, and
the stage registry built on one.

:class:`Registry` is the one implementation behind every plug-in point of
the project: stages (``isp.stages``, here), commands (``isp.commands``,
:mod:`isp.cli.commands`) and the loop's physical effects (``calib.effects``,
:mod:`calibration.loop.effects`). Entries arrive two ways: registered in
code (a decorator, a notebook, a test), or from the entry-point group of any
installed distribution, found the first time a name is looked up or the
list is asked for, and imported one by one: looking up a name imports that
entry point alone (``isp process`` imports the modules of its own stages,
not every stage's), listing them imports them all. A plug-in that fails to load is recorded with the
reason and never breaks the others; looking it up names the reason, and an
unknown name lists the valid ones.

Stages arrive two ways:

* ``@register_stage`` on a class (in code, a notebook or a test);
* the entry-point group ``isp.stages`` of any installed distribution, e.g. in
  its ``pyproject.toml``::

      [project.entry-points."isp.stages"]
      denoise = "my_package.denoise:Denoise"

  The built-in stages of :mod:`modules` are registered exactly this way, which
  is how :mod:`isp` uses them without importing them.

``create_stage(name, **params)`` builds any of them (the
``timm.create_model`` pattern).
"""

from __future__ import annotations

from importlib import metadata
from typing import Any, Callable

from isp.errors import ConfigError
from isp.stage import Stage, build_stage

class Registry:
    """Named entries from code and from one entry-point group.

    Parameters
    ----------
    kind : str
        What an entry is, for messages ("stage", "command", "effect").
    group : str
        The entry-point group plug-ins register in.
    check : callable, optional
        ``check(name, obj) -> obj``, applied to what an entry point loads:
        returns the entry to keep, or raises (the plug-in is then recorded
        as broken, with the reason).
    first : tuple of str
        Names listed first, in this order; the others follow sorted.

    Examples
    --------
    >>> shapes = Registry("shape", "example.shapes")
    >>> shapes.add("square", 4)
    4
    >>> shapes.get("square"), shapes.origin("square")
    (4, 'code')
    >>> shapes.get("circle")
    Traceback (most recent call last):
    ...
    isp.errors.ConfigError: unknown shape 'circle'; valid: square
    """

    def __init__(self, kind: str, group: str, *, check: Callable[[str, Any], Any] | None = None,
                 first: tuple[str, ...] = ()):
        self.kind, self.group, self._check, self._first = kind, group, check, tuple(first)
        self._entries: dict[str, Any] = {}
        self._origin: dict[str, Any] = {}   # a string, or the entry point it came from
        self._errors: dict[str, str] = {}
        self._plugged: set[str] = set()     # names an entry point gave
        self._pending: dict[str, Any] = {}  # entry points found but not imported yet, by name
        self._loaded = False

    def add(self, name: str, obj: Any, origin: str = "code") -> Any:
        """Register ``obj`` as ``name`` (re-registering replaces the entry);
        returns ``obj``, so that it serves as a decorator's body."""
        if not name:
            raise ConfigError(f"a {self.kind} needs a name ({obj!r})")
        self._entries[name] = obj
        self._origin[name] = origin
        self._errors.pop(name, None)
        self._pending.pop(name, None)
        return obj

    def remove(self, name: str) -> None:
        """Forget ``name`` (no error if it is not registered)."""
        self._entries.pop(name, None)
        self._origin.pop(name, None)
        self._pending.pop(name, None)

    def _load(self) -> None:
        """Find the group's entry points (reading the installed
        distributions' metadata, importing nothing)."""
        if self._loaded:
            return
        self._loaded = True
        for ep in metadata.entry_points(group=self.group):
            if ep.name not in self._entries and ep.name not in self._pending:
                self._pending[ep.name] = ep

    def _resolve(self, name: str) -> None:
        """Import the entry point ``name`` if it is still pending (a name
        registered in code needs no look at the entry points: it wins)."""
        if name in self._entries:
            return
        self._load()
        ep = self._pending.pop(name, None)
        if ep is None:
            return
        try:
            obj = ep.load()
            if self._check is not None:
                obj = self._check(ep.name, obj)
        except Exception as e:  # a broken plug-in must not break the others
            self._errors[ep.name] = f"{ep.value}: {type(e).__name__}: {e}"
            return
        self.add(ep.name, obj, ep)   # the origin's distribution name is read when asked for
        self._plugged.add(ep.name)

    def _resolve_all(self) -> None:
        self._load()
        for name in list(self._pending):
            self._resolve(name)

    def reload(self) -> None:
        """Forget what entry points gave and read them again (after
        installing a plug-in in a running process, or after a test changed
        what ``importlib.metadata.entry_points`` returns)."""
        for k in self._plugged:
            self.remove(k)
        self._plugged.clear()
        self._pending.clear()
        self._errors.clear()
        self._loaded = False

    def entries(self) -> dict[str, Any]:
        """Every entry by name: those named ``first``, then the others sorted."""
        self._resolve_all()
        order = [n for n in self._first if n in self._entries]
        order += sorted(n for n in self._entries if n not in self._first)
        return {n: self._entries[n] for n in order}

    def origin(self, name: str) -> str:
        """Where an entry came from: ``code`` (or the origin it was added
        with) or ``distribution (module:object)``."""
        self._resolve(name)
        origin = self._origin.get(name, "?")
        if isinstance(origin, metadata.EntryPoint):
            dist = getattr(origin, "dist", None)
            origin = self._origin[name] = f"{dist.name if dist else '?'} ({origin.value})"
        return origin

    def broken(self) -> dict[str, str]:
        """Entry points that failed to load, with the reason."""
        self._resolve_all()
        return dict(self._errors)

    def get(self, name: str, label: str | None = None) -> Any:
        """The entry registered as ``name``; the error lists the valid names,
        or says why a plug-in of that name failed to load."""
        self._resolve(name)
        try:
            return self._entries[name]
        except KeyError:
            where = f"{label}: " if label else ""
            if name in self._errors:
                raise ConfigError(f"{where}{self.kind} {name!r} failed to load: {self._errors[name]}") from None
            valid = ", ".join(self.entries()) or "none (is the package installed?)"
            raise ConfigError(f"{where}unknown {self.kind} {name!r}; valid: {valid}") from None

    def __contains__(self, name: str) -> bool:
        self._resolve(name)
        return name in self._entries

    def copy(self) -> "Registry":
        """An independent registry with the same entries (tests restore it)."""
        other = Registry(self.kind, self.group, check=self._check, first=self._first)
        other._entries, other._origin = dict(self._entries), dict(self._origin)
        other._errors, other._loaded = dict(self._errors), self._loaded
        other._plugged, other._pending = set(self._plugged), dict(self._pending)
        return other


ENTRY_POINT_GROUP = "isp.stages"

#: the stage classes by name
STAGES = Registry("stage", ENTRY_POINT_GROUP)


def register_stage(cls=None, *, name: str | None = None, origin: str = "code"):
    """Class decorator: register a stage class under ``name`` (default: its
    ``name`` attribute). Re-registering a name replaces the entry."""

    def deco(c):
        key = name or getattr(c, "name", "")
        if not key:
            raise ConfigError(f"stage class {c.__qualname__} has no name")
        return STAGES.add(key, c, origin)

    return deco(cls) if cls is not None else deco


def reload_entry_points() -> None:
    """Forget what entry points gave and read them again (after installing a
    plug-in in a running process)."""
    STAGES.reload()


def list_stages() -> dict[str, type]:
    """All registered stage classes by name, sorted."""
    return STAGES.entries()


def stage_origin(name: str) -> str:
    """Where a stage came from: ``code`` or ``distribution (module:Class)``."""
    return STAGES.origin(name)


def broken_stages() -> dict[str, str]:
    """Entry points that failed to load, with the reason."""
    return STAGES.broken()


def get_stage_class(name: str, label: str | None = None) -> type:
    """The class registered as ``name``; the error lists the valid names."""
    return STAGES.get(name, label)


def create_stage(name: str, *, label: str | None = None, **params: Any) -> Stage:
    """Build the stage registered as ``name`` with validated ``params``.

    >>> create_stage("no_such_stage")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    isp.errors.ConfigError: unknown stage 'no_such_stage'; valid: ...
    """
    cls = get_stage_class(name, label)
    return build_stage(cls, params, label or f"stage {name!r}")

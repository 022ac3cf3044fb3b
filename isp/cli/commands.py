"""The command registry: one dict of ``isp`` sub-commands by name.

A command is a :class:`Command` record: its name, the one line
``isp --help`` shows for it, and the module that parses its arguments
(``add_arguments(parser)``) and runs it (``run(args)``), imported only when
the command runs. Commands arrive as stages do (:mod:`isp.registry`):

* the ISP's own (``process``, ``info``, ``stages``, ``batch``), listed here;
* the entry-point group ``isp.commands`` of any installed distribution, e.g.
  in its ``pyproject.toml``::

      [project.entry-points."isp.commands"]
      hello = "my_package.cli:HELLO"

  where ``my_package/cli/__init__.py`` holds
  ``HELLO = Command("hello", "say hello", module="my_package.cli.hello")``.
  This project's other packages add ``calib``, ``demo``, ``synth``,
  ``train``, ``eval`` and ``export`` exactly this way, so :mod:`isp` runs
  them without importing them;
* :func:`register_command` in code (a test, a notebook).

Loading an entry point imports only the small module that holds the record
(it must import nothing heavy at its top level), so ``isp --help`` lists
every command cheaply, and ``isp process`` never imports the optics or
torch that other commands need.

A command module has the shape every command shares::

    def add_arguments(parser: argparse.ArgumentParser) -> None:
        ...   # options, and parser.description / parser.epilog

    def run(args: argparse.Namespace) -> int:
        ...   # call library functions; raise isp.errors.InputError / ConfigError

Its exit code follows :mod:`isp.cli.run`.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from importlib import metadata
from typing import Callable

from isp.errors import ConfigError

ENTRY_POINT_GROUP = "isp.commands"


@dataclass(frozen=True)
class Command:
    """One ``isp`` sub-command.

    Attributes
    ----------
    name : str
        What follows ``isp`` on the command line.
    help : str
        One line for ``isp --help``.
    module : str, optional
        Dotted name of the module holding ``add_arguments(parser)`` and
        ``run(args)``, imported when the command runs. Give either this or
        ``run``.
    run : callable, optional
        ``run(args) -> int``, for a command defined in code.
    add_arguments : callable, optional
        ``add_arguments(parser)``, with ``run``; none: the command takes no
        arguments.
    """

    name: str
    help: str
    module: str | None = None
    run: Callable | None = None
    add_arguments: Callable | None = None

    def __post_init__(self):
        if not self.name or self.name.startswith("-") or " " in self.name:
            raise ConfigError(f"command name {self.name!r}: one word, not starting with '-'")
        if (self.module is None) == (self.run is None):
            raise ConfigError(f"command {self.name!r}: give either module or run")

    def load(self) -> tuple[Callable, Callable]:
        """``(add_arguments, run)``, importing :attr:`module` if the command
        has one (ConfigError if it lacks either function)."""
        if self.module is None:
            return self.add_arguments or (lambda parser: None), self.run
        mod = importlib.import_module(self.module)
        missing = [f for f in ("add_arguments", "run") if not callable(getattr(mod, f, None))]
        if missing:
            raise ConfigError(f"command {self.name!r}: module {self.module} has no "
                              + " or ".join(f"{f}()" for f in missing))
        return mod.add_arguments, mod.run


#: The ISP's own commands, in the order ``isp --help`` lists them.
BUILTIN = (
    Command("process", "raw file -> JPEG (or PNG/TIFF) through the pipeline", module="isp.cli.process"),
    Command("info", "print a raw file's metadata as JSON", module="isp.cli.info"),
    Command("stages", "list the registered stages (built-in and plug-ins)", module="isp.cli.stages"),
    Command("batch", "process every raw file in a folder", module="isp.cli.batch"),
)

_REGISTRY: dict[str, Command] = {c.name: c for c in BUILTIN}
_ORIGIN: dict[str, str] = {c.name: "isp" for c in BUILTIN}
_entry_points_loaded = False
_entry_point_errors: dict[str, str] = {}


def register_command(name: str | Command, *, help: str | None = None, add_arguments: Callable | None = None):
    """Register a command.

    ``register_command(Command(...))`` registers a record;
    ``@register_command("hello", help="say hello", add_arguments=f)`` on a
    function ``run(args) -> int`` registers it as the command ``hello``.
    Re-registering a name replaces the entry.

    >>> @register_command("hello", help="say hello")
    ... def hello(args):
    ...     print("hello")
    ...     return 0
    >>> get_command("hello").help
    'say hello'
    """
    if isinstance(name, Command):
        _REGISTRY[name.name] = name
        _ORIGIN[name.name] = "code"
        return name

    def deco(fn):
        register_command(Command(name, help or "", run=fn, add_arguments=add_arguments))
        return fn

    return deco


def _load_entry_points() -> None:
    global _entry_points_loaded
    if _entry_points_loaded:
        return
    _entry_points_loaded = True
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        if ep.name in _REGISTRY:
            continue
        try:
            cmd = ep.load()
            if not isinstance(cmd, Command):
                raise TypeError(f"{type(cmd).__name__}, not an isp.cli.commands.Command")
        except Exception as e:  # a broken plug-in must not break the other commands
            _entry_point_errors[ep.name] = f"{ep.value}: {type(e).__name__}: {e}"
            continue
        if cmd.name != ep.name:
            cmd = Command(ep.name, cmd.help, cmd.module, cmd.run, cmd.add_arguments)
        _REGISTRY[ep.name] = cmd
        dist = getattr(ep, "dist", None)
        _ORIGIN[ep.name] = f"{dist.name if dist else '?'} ({ep.value})"


def list_commands() -> dict[str, Command]:
    """Every command by name: the ISP's own first, then the others by name."""
    _load_entry_points()
    own = {c.name: _REGISTRY[c.name] for c in BUILTIN if c.name in _REGISTRY}
    return own | {k: _REGISTRY[k] for k in sorted(_REGISTRY) if k not in own}


def command_origin(name: str) -> str:
    """Where a command came from: ``isp``, ``code`` or ``distribution (module:object)``."""
    _load_entry_points()
    return _ORIGIN.get(name, "?")


def broken_commands() -> dict[str, str]:
    """Entry points of the ``isp.commands`` group that failed to load, with the reason."""
    _load_entry_points()
    return dict(_entry_point_errors)


def get_command(name: str) -> Command:
    """The command registered as ``name``; the error lists the valid names."""
    _load_entry_points()
    try:
        return _REGISTRY[name]
    except KeyError:
        if name in _entry_point_errors:
            raise ConfigError(f"command {name!r} failed to load: {_entry_point_errors[name]}") from None
        raise ConfigError(f"unknown command {name!r}; valid: {', '.join(list_commands())}") from None

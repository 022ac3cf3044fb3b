"""The command registry: one dict of ``isp`` sub-commands by name.

A command is a :class:`Command` record: its name, the one line
``isp --help`` shows for it, and the module that parses its arguments
(``add_arguments(parser)``) and runs it (``run(args)``), imported only when
the command runs. Commands arrive as stages do (:mod:`isp.registry`):

* the ISP's own (``process``, ``info``, ``stages``, ``batch``, ``profiles``),
  listed here;
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
from typing import Callable

from isp.errors import ConfigError
from isp.registry import Registry

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
    Command("profiles", "list the lens profiles: which correction model runs on which lens",
            module="isp.cli.profiles"),
)



def add_subcommands(parser, commands, *, dest: str = "command") -> None:
    """Sub-commands of ``parser`` (e.g. ``isp calib sfr``) from
    :class:`Command` records, each listed with its one-line help and
    its module imported, its options added, only when the command line
    chooses it: ``isp calib sfr`` imports neither the fitter nor the
    tracer that ``isp calib fit`` needs. The chosen command's ``run``
    becomes the namespace's ``func``.

    >>> import argparse
    >>> p = argparse.ArgumentParser(prog="demo")
    >>> add_subcommands(p, [Command("hi", "say hi", run=lambda a: 0)])
    >>> p.parse_args(["hi"]).command
    'hi'
    """
    import argparse

    records = {c.name: c for c in commands}

    class _Lazy(argparse._SubParsersAction):
        def __call__(self, parser_, namespace, values, option_string=None):
            cmd = records.get(values[0])
            chosen = self._name_parser_map.get(values[0])
            if cmd is not None and chosen is not None and not getattr(chosen, "_isp_loaded", False):
                add, run = cmd.load()
                add(chosen)
                chosen.set_defaults(func=run)
                chosen._isp_loaded = True
            super().__call__(parser_, namespace, values, option_string)

    parser.register("action", "isp_lazy_parsers", _Lazy)
    sub = parser.add_subparsers(dest=dest, metavar="COMMAND", action="isp_lazy_parsers")
    for cmd in records.values():
        sub.add_parser(cmd.name, help=cmd.help, description=cmd.help)


def _check_entry(name: str, obj) -> Command:
    """What an ``isp.commands`` entry point must give: a :class:`Command`
    (renamed to its entry point's name)."""
    if not isinstance(obj, Command):
        raise TypeError(f"{type(obj).__name__}, not an isp.cli.commands.Command")
    return obj if obj.name == name else Command(name, obj.help, obj.module, obj.run, obj.add_arguments)


#: the commands by name
COMMANDS = Registry("command", ENTRY_POINT_GROUP, check=_check_entry, first=tuple(c.name for c in BUILTIN))
for _c in BUILTIN:
    COMMANDS.add(_c.name, _c, "isp")


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
        return COMMANDS.add(name.name, name)

    def deco(fn):
        register_command(Command(name, help or "", run=fn, add_arguments=add_arguments))
        return fn

    return deco


def list_commands() -> dict[str, Command]:
    """Every command by name: the ISP's own first, then the others by name."""
    return COMMANDS.entries()


def command_origin(name: str) -> str:
    """Where a command came from: ``isp``, ``code`` or ``distribution (module:object)``."""
    return COMMANDS.origin(name)


def broken_commands() -> dict[str, str]:
    """Entry points of the ``isp.commands`` group that failed to load, with the reason."""
    return COMMANDS.broken()


def get_command(name: str) -> Command:
    """The command registered as ``name``; the error lists the valid names."""
    return COMMANDS.get(name)

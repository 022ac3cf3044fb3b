"""The ``isp`` command line: the parser and the dispatch to a registered command.

Every command is a :class:`~isp.cli.commands.Command` of the registry
(:mod:`isp.cli.commands`): the ISP's own (``process``, ``info``, ``stages``,
``batch``) and those other packages add through the ``isp.commands`` entry
points (``calib``, ``demo``, ``synth``, ``train``, ``eval``, ``export``). Only
the command on the command line is imported, so ``isp process`` never
imports the optics or torch, and ``isp --help`` lists every command from
the registry's one-line help without importing any.

Exit codes (:mod:`isp.cli.run`): 0 success; 1 a batch finished with
failures; 2 bad input or configuration (one line on stderr naming the file
and the problem); 3 an internal error (a bug: rerun with ``--debug`` for the
traceback); 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys

from isp.cli.commands import BUILTIN, get_command, list_commands
from isp.cli.run import BAD_INPUT, run_command


def _command_name(argv: list[str]) -> str | None:
    """The command on a command line: its first word that is not an option
    (``isp`` itself takes only ``--debug`` and ``--help``)."""
    return next((a for a in argv if not a.startswith("-")), None)


def make_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``isp`` parser: every registered command listed with its one-line
    help, and ``command``'s own options added (its module imported; its
    ``run`` the sub-parser's default ``isp_run``)."""
    p = argparse.ArgumentParser(
        prog="isp",
        description="A reference raw ISP for phone cameras: DNG in, JPEG out, every stage "
                    "swappable and inspectable.",
        epilog="Start with `isp demo`, then `isp process YOUR.dng -o out.jpg`. "
               "`isp COMMAND --help` explains each command.",
    )
    p.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    sub = p.add_subparsers(dest="isp_command", metavar="COMMAND")
    # one of the ISP's own commands needs no other: the plug-ins' entry points stay unread
    own = command is not None and command in {c.name for c in BUILTIN}
    for name, cmd in ({command: get_command(command)} if own else list_commands()).items():
        sp = sub.add_parser(name, help=cmd.help, description=cmd.help)
        if name == command:
            add_arguments, run = cmd.load()
            add_arguments(sp)
            sp.set_defaults(isp_run=run)
    return p


def main(argv: list[str] | None = None) -> int:
    """Run ``isp`` with ``argv`` (default ``sys.argv[1:]``); returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    name = _command_name(argv)
    built: list[argparse.ArgumentParser] = []
    # a command whose module fails to import: one line, exit 3 (--debug: the traceback)
    code = run_command(lambda: built.append(make_parser(name)), debug="--debug" in argv)
    if not built:
        return code
    parser = built[0]
    parsed: list[argparse.Namespace] = []
    # parsing imports a nested command's module (`isp calib sfr`): its failure is reported as above
    code = run_command(lambda: parsed.append(parser.parse_args(argv)), debug="--debug" in argv)
    if not parsed:
        return code
    args = parsed[0]
    if not args.isp_command:
        parser.print_help()
        return BAD_INPUT
    return run_command(lambda: args.isp_run(args), debug=args.debug, where=getattr(args, "input", ""))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

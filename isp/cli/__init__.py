"""The ``isp`` command line: the command registry, the exit-code contract, and the ISP's own commands.

* :mod:`.main`: the parser and the dispatch (``isp``, ``python -m isp``);
* :mod:`.commands`: the registry of commands (the ISP's own and the
  ``isp.commands`` entry points of other packages), imported lazily;
* :mod:`.run`: :func:`~isp.cli.run.run_command`, the exit codes every
  command keeps (0 / 1 batch failures / 2 bad input / 3 internal / 130);
* :mod:`.arguments`: argument types and option groups the commands share;
* :mod:`.process`, :mod:`.info`, :mod:`.stages`, :mod:`.batch`: one module
  per command, each ``add_arguments(parser)`` and ``run(args)``, parsing
  arguments and calling library functions only.

May import: everything in ``isp``; other packages only through the command
registry (their modules are named as strings, imported when the command runs).
"""

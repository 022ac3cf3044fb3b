"""The exit-code contract of every ``isp`` command, and :func:`run_command`, which keeps it.

=====  ==================================================================
code   meaning
=====  ==================================================================
0      success
1      a batch finished, and some of its items failed (each reported)
2      bad input or configuration: one line on stderr naming the file or
       the option and the problem, no traceback (an :class:`~isp.errors.IspError`,
       or argparse refusing the command line)
3      an internal error, i.e. a bug: one line on stderr; ``--debug`` shows
       the traceback
130    interrupted (Ctrl-C)
=====  ==================================================================

Every command runs through :func:`run_command`, whichever package it comes
from: a command signals bad input by raising the specific
:class:`~isp.errors.IspError` subclass (:class:`~isp.errors.InputError` for
a file, :class:`~isp.errors.ConfigError` for an option or value), and
returns 0 or :data:`BATCH_FAILURES` itself.
"""

from __future__ import annotations

import sys
from typing import Callable

from isp.errors import IspError

#: Success.
OK = 0
#: A batch finished with failures (the command returns it).
BATCH_FAILURES = 1
#: Bad input or configuration (an :class:`~isp.errors.IspError`).
BAD_INPUT = 2
#: An internal error: a bug.
INTERNAL_ERROR = 3
#: Interrupted by the user (128 + SIGINT).
INTERRUPTED = 130


def run_command(fn: Callable[[], int | None], *, debug: bool = False, where: object = "") -> int:
    """Run one command and turn what happens into its exit code.

    Parameters
    ----------
    fn : callable
        The command, called with no arguments; returns its exit code (None
        counts as 0).
    debug : bool
        Re-raise internal errors (any exception that is not an
        :class:`~isp.errors.IspError`) with their traceback instead of
        reporting them in one line.
    where : str or path, optional
        What the command was working on (e.g. its input file), named in
        the one-line report of an internal error.

    Returns
    -------
    int
        ``fn``'s code; :data:`BAD_INPUT` for an ``IspError`` (its message on
        stderr after ``isp: error:``), :data:`INTERRUPTED` for Ctrl-C,
        :data:`INTERNAL_ERROR` for anything else.

    Examples
    --------
    >>> from isp.errors import ConfigError
    >>> def bad():
    ...     raise ConfigError("--workers 0: at least 1")
    >>> run_command(bad)      # prints "isp: error: --workers 0: at least 1" on stderr
    2
    >>> run_command(lambda: None)
    0
    """
    try:
        return int(fn() or OK)
    except IspError as e:
        print(f"isp: error: {e}", file=sys.stderr)
        return BAD_INPUT
    except KeyboardInterrupt:
        print("isp: interrupted", file=sys.stderr)
        return INTERRUPTED
    except Exception as e:  # a bug: still one line, unless --debug
        if debug:
            raise
        print(f"isp: internal error{' on ' + str(where) if where else ''}: {type(e).__name__}: {e} "
              "(rerun with --debug for the traceback)", file=sys.stderr)
        return INTERNAL_ERROR

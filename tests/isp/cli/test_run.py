"""The exit-code contract (:func:`isp.cli.run.run_command`): 0 success, 1 a
batch with failures, 2 bad input in one line, 3 an internal error in one
line (the traceback with ``debug``), 130 interrupted (kind: property)."""

from __future__ import annotations

import pytest

from isp.cli.run import BAD_INPUT, BATCH_FAILURES, INTERNAL_ERROR, INTERRUPTED, OK, run_command
from isp.errors import ConfigError, InputError

pytestmark = pytest.mark.property


def _raise(exc):
    def fn():
        raise exc

    return fn


def test_codes(capsys):
    assert (OK, BATCH_FAILURES, BAD_INPUT, INTERNAL_ERROR, INTERRUPTED) == (0, 1, 2, 3, 130)
    assert run_command(lambda: None) == 0
    assert run_command(lambda: BATCH_FAILURES) == 1
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("error", [InputError("a.dng", "truncated"), ConfigError("--workers 0: at least 1")])
def test_bad_input_is_one_line_and_exit_2(capsys, error):
    assert run_command(_raise(error)) == 2
    err = capsys.readouterr().err
    assert err == f"isp: error: {error}\n" and "Traceback" not in err


def test_a_bug_is_one_line_and_exit_3_unless_debug(capsys):
    assert run_command(_raise(ZeroDivisionError("division by zero")), where="a.dng") == 3
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert "internal error on a.dng: ZeroDivisionError" in err and "--debug" in err
    with pytest.raises(ZeroDivisionError):
        run_command(_raise(ZeroDivisionError("division by zero")), debug=True)


def test_interrupted_is_130(capsys):
    assert run_command(_raise(KeyboardInterrupt())) == 130
    assert capsys.readouterr().err == "isp: interrupted\n"

"""The command registry (:mod:`isp.cli.commands`): the ISP's own commands
and the other packages' through the ``isp.commands`` entry points, each
with one line of help; commands added in code; a broken plug-in reported,
not fatal; and the lazy import that keeps ``isp process`` free of the optics
and torch (kind: property)."""

from __future__ import annotations

import os
import subprocess
import sys
from importlib import metadata

import pytest

import isp.cli.commands as commands
import isp.registry
from isp.cli.commands import Command, get_command, list_commands, register_command
from isp.errors import ConfigError

pytestmark = pytest.mark.property

#: every command of this project, in the order `isp --help` lists them
EVERY = ["process", "info", "stages", "batch", "calib", "demo", "eval", "export", "synth", "train"]


@pytest.fixture
def registry(monkeypatch):
    """The registry, restored after the test."""
    monkeypatch.setattr(commands, "COMMANDS", commands.COMMANDS.copy())
    return commands


def test_every_command_is_registered_with_one_line_of_help():
    cmds = list_commands()
    assert [n for n in cmds if n in EVERY] == EVERY
    for name, cmd in cmds.items():
        assert cmd.help and "\n" not in cmd.help, name
    assert commands.command_origin("process") == "isp"
    assert "calibration.cli:CALIB" in commands.command_origin("calib")
    assert not commands.broken_commands()


def test_help_lists_every_command_without_importing_them():
    code = ("import sys\nfrom isp.cli.main import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('calibration', 'restoration', 'export', 'torch', 'modules')))")
    env = {**os.environ, "COLUMNS": "200"}  # one line per command
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert out.returncode == 0, out.stderr
    *text, loaded = out.stdout.strip().splitlines()
    text = "\n".join(text)
    for name, cmd in list_commands().items():
        assert f"    {name:<9s} {cmd.help}" in text, name
    # only the packages' small command records: no command module, no library module
    assert eval(loaded) == ["calibration", "calibration.cli", "export", "export.cli", "restoration",
                            "restoration.cli"]


@pytest.mark.parametrize("command", ["process", "info"])
def test_process_and_info_import_no_optics_and_no_torch(tmp_path, raw_file, command):
    dng = str(raw_file("SYNTHETIC_phone_S6meta_512x384.dng"))
    argv = [command, dng] + (["-o", str(tmp_path / "o.jpg")] if command == "process" else [])
    code = ("import sys\nfrom isp.cli.main import main\n"
            f"assert main({argv!r}) == 0\n"
            "print(sorted(m for m in sys.modules if m.startswith(('calibration.', 'restoration.', 'export.', "
            "'torch'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    # one of the ISP's own commands reads no plug-in's entry point: not even the packages' command records
    assert eval(out.stdout.strip().splitlines()[-1]) == []


def test_a_command_registered_in_code_runs_through_the_contract(registry, cli):
    def add_arguments(parser):
        parser.add_argument("who")
        parser.add_argument("--fail", action="store_true")

    @register_command("hello", help="say hello", add_arguments=add_arguments)
    def hello(args):
        if args.fail:
            raise ConfigError(f"--fail: {args.who} refused")
        print(f"hello {args.who}")
        return 0

    assert get_command("hello").help == "say hello" and registry.command_origin("hello") == "code"
    assert cli("hello", "world") == (0, "hello world\n", "")
    assert cli("hello", "world", "--fail") == (2, "", "isp: error: --fail: world refused\n")
    with pytest.raises(SystemExit) as e:  # argparse: usage error, exit 2
        cli("hello")
    assert e.value.code == 2


def test_an_unknown_command_lists_the_valid_ones():
    with pytest.raises(ConfigError, match="unknown command 'nope'; valid: process, info"):
        get_command("nope")


def test_a_broken_plug_in_is_reported_and_the_others_run(registry, monkeypatch, cli):
    eps = [metadata.EntryPoint("broken", "no_such_package.cli:COMMAND", commands.ENTRY_POINT_GROUP),
           metadata.EntryPoint("notacommand", "isp.cli.run:run_command", commands.ENTRY_POINT_GROUP)]
    real = metadata.entry_points  # the stage registry reads the same function: only this group changes
    monkeypatch.setattr(isp.registry.metadata, "entry_points",
                        lambda group: eps if group == commands.ENTRY_POINT_GROUP else real(group=group))
    registry.COMMANDS.reload()
    broken = registry.broken_commands()
    assert "ModuleNotFoundError" in broken["broken"] and "not an isp.cli.commands.Command" in broken["notacommand"]
    with pytest.raises(ConfigError, match="command 'broken' failed to load"):
        get_command("broken")
    code, out, _ = cli("stages")
    assert code == 0 and "demosaic" in out


def test_a_command_module_without_its_functions_is_refused(registry, cli):
    register_command(Command("half", "a module without add_arguments", module="isp.cli.run"))
    code, _, err = cli("half")
    assert code == 2 and "module isp.cli.run has no add_arguments() or run()" in err


def test_a_command_record_is_checked():
    with pytest.raises(ConfigError, match="either module or run"):
        Command("x", "neither")
    with pytest.raises(ConfigError, match="one word"):
        Command("two words", "bad name", module="x")

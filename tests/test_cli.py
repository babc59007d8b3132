"""The console command: every subcommand has --help; errors are reported, not raised."""

import json
import subprocess
import sys

import pytest

from hexgym.cli import build_parser, main

SUBCOMMANDS = sorted(build_parser()._subparsers._group_actions[0].choices)


@pytest.mark.parametrize("command", [[], *[[c] for c in SUBCOMMANDS]])
def test_help(command, capsys):
    with pytest.raises(SystemExit) as exc:
        main([*command, "--help"])
    assert exc.value.code == 0
    assert "usage: hexgym" in capsys.readouterr().out


def test_model_json(capsys):
    assert main(["model", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert 26500 < summary["operating_mass_kg"] < 27500
    assert 9.5 < summary["max_reach_m"] < 11.5
    assert 6.5 < summary["max_dig_depth_m"] < 8.0


def test_console_script_is_installed():
    result = subprocess.run(
        [sys.executable, "-c", "from hexgym.cli import main; raise SystemExit(main(['--help']))"],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0 and "demo" in result.stdout

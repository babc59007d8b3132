"""The console command: every subcommand has --help; errors are reported, not raised."""

import json
import subprocess
import sys

import pytest

from hexgym_lab.cli import build_parser, main

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
        [sys.executable, "-c", "from hexgym_lab.cli import main; raise SystemExit(main(['--help']))"],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0 and "demo" in result.stdout


def test_simulate_reference_writes_the_trajectory(tmp_path, capsys):
    log = tmp_path / "log.csv"
    log.write_text("t,swing,boom,stick,bucket\n0,0,0,0,0\n0.1,11,5,-3,2\n0.3,0,0,0,0\n")
    out = tmp_path / "traj.csv"
    assert main(["simulate", "--model", "reference", "--commands", str(log), "--out", str(out)]) == 0
    lines = out.read_text().splitlines()
    header = lines[0].split(",")
    assert header[:12] == [
        "t", "q_swing_rad", "q_boom_rad", "q_stick_rad", "q_bucket_rad",
        "qd_swing_radps", "qd_boom_radps", "qd_stick_radps", "qd_bucket_radps", "tip_x_m", "tip_y_m", "tip_z_m",
    ]  # fmt: skip
    for column in ("pump1_pressure_pa", "pump2_pressure_pa", "pump1_flow_m3s", "pump_power_w", "fuel_rate_l_per_h"):
        assert column in header
    assert len(lines) == 1 + 7  # 0 .. 0.3 s every 0.05 s
    assert float(lines[-1].split(",")[5]) > 0.0  # the swing turned


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("t,swing,boom,stick\n0,0,0,0\n", "bucket"),
        ("t,swing,boom,stick,bucket\n0,0,0,0,0\n0.2,0,0,0,0\n0.1,0,0,0,0\n", "row 3"),
        ("t,swing,boom,stick,bucket\n0,0,nan,0,0\n", "boom"),
        ("t,swing,boom,stick,bucket\n0,0,0,12,0\n", "stick"),
    ],
)
def test_simulate_refuses_a_malformed_log(tmp_path, capsys, body, message):
    log, out = tmp_path / "log.csv", tmp_path / "traj.csv"
    log.write_text(body)
    assert main(["simulate", "--commands", str(log), "--out", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists() and list(tmp_path.iterdir()) == [log]


def test_loader_settings_are_checked_before_any_episode(tmp_path, capsys):
    bad = tmp_path / "loader.json"
    bad.write_text('{"full_fraction": 2.0}')
    assert main(["scripted", "--loader-settings", str(bad)]) == 2
    assert f"{bad}: loader setting full_fraction=2.0 must be a number" in capsys.readouterr().err
    good = tmp_path / "good.json"
    good.write_text('{"full_fraction": 0.7}')
    assert main(["evaluate", "--policy", "shipped", "--loader-settings", str(good), "--episodes", "1"]) == 2
    assert "only for the scripted policy" in capsys.readouterr().err
    assert main(["tune-loader", "--out", str(tmp_path / "t.json"), "--seeds", "5-2"]) == 2
    assert "--seeds must be A-B with 0 <= A <= B, got '5-2'" in capsys.readouterr().err
    assert not (tmp_path / "t.json").exists()

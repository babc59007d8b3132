"""``hexgym simulate`` with machine logs: the reference's run written as one (rate, jitter, noise, seed), a replay that
starts at given angles or at a log's first pose on every model, and ``hexgym compare``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hexgym.machine import kinematics
from hexgym.model.commandlog import read_trajectory_csv
from hexgym_lab.cli import main
from hexgym_lab.compare import compare_logs
from hexgym_lab.machine_logs import read_machine_log
from hexgym_lab.machine_logs import signals as s
from hexgym_lab.machine_logs.csv_log import write_csv_log
from hexgym_lab.machine_logs.signals import MachineLog

LOG = "t,swing,boom,stick,bucket\n0,6,11,-6,5\n0.5,-6,-8,6,-5\n1,0,0,0,0\n"
POSE = (0.4, 0.2, 1.0, 0.6)


@pytest.fixture
def commands(tmp_path):
    path = tmp_path / "log.csv"
    path.write_text(LOG)
    return str(path)


def _simulate(commands, *extra: str) -> int:
    return main(["simulate", "--commands", commands, *extra])


def test_the_reference_writes_its_run_as_a_machine_log(commands, tmp_path, capsys):
    traj, ml = str(tmp_path / "t.csv"), str(tmp_path / "ml.csv")
    assert _simulate(commands, "--out", traj, "--machine-log", ml, "--rate", "50", "--seed", "4") == 0
    assert f"wrote {ml} (the run as a machine log at 50 Hz)" in capsys.readouterr().err
    log = read_machine_log(ml)
    assert np.allclose(log.t, np.arange(51) / 50) and set(s.CHAMBER_PRESSURES + s.PUMP_PRESSURES) <= set(log.signals)
    rows = read_trajectory_csv(traj)
    noise = log.signals["q_boom_rad"][::5] - rows["q_boom_rad"][::2]  # every 0.1 s: both have a sample there
    assert 0.3 * np.radians(0.1) < np.std(noise) < 3 * np.radians(0.1)
    assert _simulate(commands, "--out", str(tmp_path / "alone.csv")) == 0
    assert (tmp_path / "alone.csv").read_bytes() == (tmp_path / "t.csv").read_bytes()  # the trajectory is unchanged


def test_the_machine_log_is_seeded_and_jittered(commands, tmp_path):
    paths = [str(tmp_path / f"{k}.csv") for k in range(3)]
    for path, seed in zip(paths, (1, 1, 2), strict=True):
        assert _simulate(commands, "--machine-log", path, "--jitter", "0.5", "--seed", str(seed)) == 0
    assert (tmp_path / "0.csv").read_bytes() == (tmp_path / "1.csv").read_bytes()
    assert (tmp_path / "0.csv").read_bytes() != (tmp_path / "2.csv").read_bytes()
    t = read_machine_log(paths[0]).t
    assert np.all(np.diff(t) > 0) and 0 < np.max(np.abs(t - np.arange(len(t)) / 100)) <= 0.25 / 100 + 1e-9
    clean, traj = str(tmp_path / "clean.csv"), str(tmp_path / "t.csv")
    assert _simulate(commands, "--machine-log", clean, "--sensor-noise", "off", "--out", traj) == 0
    log, rows = read_machine_log(clean), read_trajectory_csv(traj)
    for name in (*s.JOINT_ANGLES, "pump1_pressure_pa", "stick_rod_pressure_pa", "boom_spool_mm"):
        assert np.allclose(log.signals[name][::5], rows[name], rtol=1e-8, atol=1e-9), name  # noise off: the run


@pytest.mark.parametrize(
    "extra,message",
    [
        (["--rate", "50"], r"--rate \(the machine log's\) does not apply without --machine-log"),
        (["--seed", "3"], r"--seed \(the machine log's\) does not apply without --machine-log"),
        (["--machine-log", "m.csv", "--jitter", "1.5"], r"--jitter must be from 0 to below 1"),
        (["--machine-log", "m.csv", "--sensor-noise", "loud"], r"--sensor-noise 'loud': 'loud' is not kind=sigma"),
        (["--machine-log", "m.csv", "--model", "learned"], r"--machine-log .* does not apply with --model learned"),
        (["--start", "0,2,0,0"], r"--start 0,2,0,0: boom 2 rad is outside its range -0\.\d+ to 0\.\d+ rad"),
        (["--start", "0,0.1,0.5"], r"--start must be a keyframe name or four angles"),
        (["--start", "0,0,0,0", "--start-from", "x.csv"], r"--start and --start-from: give one of them"),
    ],
)
def test_bad_options_are_one_line(commands, tmp_path, capsys, monkeypatch, extra, message):
    import re

    monkeypatch.chdir(tmp_path)
    (tmp_path / "x.csv").write_text("t,q_swing_rad\n0,0\n")
    assert _simulate(commands, "--out", "t.csv", *extra) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(message, err), err
    assert not (tmp_path / "t.csv").exists()


@pytest.mark.parametrize("model", [["--model", "reference"], ["--model", "learned", "--backend", "python"]])
def test_the_start_pose_is_honoured_on_every_model(commands, tmp_path, model):
    out = tmp_path / "t.csv"
    assert _simulate(commands, "--out", str(out), "--start", ",".join(map(str, POSE)), *model) == 0
    first = read_trajectory_csv(out)[0]
    assert np.allclose([first[n] for n in s.JOINT_ANGLES], POSE, atol=1e-6)
    log = tmp_path / "machine.csv"
    t = np.array([3.0, 3.01, 3.02])
    pose = np.array([[np.nan, 0.1, 0.8, 0.4], [-0.3, 0.1, 0.8, 0.4], [-0.31, 0.1, 0.8, 0.4]])
    write_csv_log(log, t, dict(zip(s.JOINT_ANGLES, pose.T, strict=True)))
    assert _simulate(commands, "--out", str(out), "--start-from", str(log), *model) == 0
    first = read_trajectory_csv(out)[0]
    assert np.allclose([first[n] for n in s.JOINT_ANGLES], pose[1], atol=1e-6)  # the first complete pose


def test_start_from_a_log_with_strokes_and_one_out_of_range(commands, tmp_path, capsys):
    ext = np.array([[kinematics.cylinder_length(c, q) - kinematics.p.CYLINDERS[c].retracted_length
                     for c, q in zip(kinematics.FRONT_CYLINDERS, POSE[1:], strict=True)]])  # fmt: skip
    log = tmp_path / "strokes.csv"
    write_csv_log(
        log, np.array([0.0]), {s.JOINT_ANGLES[0]: np.array([POSE[0]])} | dict(zip(s.EXTENSIONS, ext.T, strict=True))
    )
    out = tmp_path / "t.csv"
    assert _simulate(commands, "--out", str(out), "--start-from", str(log)) == 0
    first = read_trajectory_csv(out)[0]
    assert np.allclose([first[n] for n in s.JOINT_ANGLES], POSE, atol=1e-5)
    write_csv_log(log, np.array([0.0]), dict(zip(s.JOINT_ANGLES, np.array([[0.0, 0.1, 0.8, 9.0]]).T, strict=True)))
    assert _simulate(commands, "--out", str(out), "--start-from", str(log)) == 2
    err = capsys.readouterr().err
    assert f"--start-from {log} (its pose at t 0 s): bucket 9 rad is outside its range" in err


# -- compare ------------------------------------------------------------------------------------------------------
def _angles_log(name: str, t: np.ndarray, q: np.ndarray) -> MachineLog:
    return MachineLog(name, t, dict(zip(s.JOINT_ANGLES, q.T, strict=True)))


def _motion(t: np.ndarray) -> np.ndarray:
    return np.column_stack([0.5 * np.sin(t), 0.2 + 0.3 * np.sin(0.7 * t), 0.8 + 0.3 * np.cos(t), 0.5 + 0.2 * t / t[-1]])


def test_a_run_compared_with_itself_has_no_error_and_with_a_shifted_copy_the_shift():
    t = np.linspace(0, 10, 501)
    q = _motion(t)
    same = compare_logs(_angles_log("a", t, q), _angles_log("b", t, q))
    assert same["tip_error_max_m"] == 0.0 and all(j["max_rad"] == 0.0 for j in same["joints"].values())
    shifted = q + np.array([0.0, 0.05, 0.0, 0.0])
    result = compare_logs(_angles_log("a", t, q), _angles_log("b", t + 0.0, shifted))
    assert result["joints"]["boom"]["rms_rad"] == pytest.approx(0.05) and result["joints"]["stick"]["max_rad"] == 0
    tips = np.array([np.linalg.norm(kinematics.tip_position(a) - kinematics.tip_position(b)) for a, b in
                     zip(q, shifted, strict=True)])  # fmt: skip
    assert result["tip_error_mean_m"] == pytest.approx(tips.mean(), rel=1e-6)
    assert result["tip_error_max_m"] == pytest.approx(tips.max(), rel=1e-6)


def test_compare_resamples_onto_the_overlap_and_takes_the_swing_the_short_way():
    t = np.linspace(0, 10, 1001)
    q = _motion(t)
    wrapped = q.copy()
    wrapped[:, 0] = (q[:, 0] + 2 * np.pi + np.pi) % (2 * np.pi) - np.pi + 0.02  # another turn, and 0.02 rad
    t_b = np.linspace(4, 14, 337)  # another rate, half overlapping
    b = _angles_log("b", t_b, np.column_stack([np.interp(t_b, t, wrapped[:, j]) for j in range(4)]))
    result = compare_logs(_angles_log("a", t, q), b)
    assert result["t0_s"] == pytest.approx(4.0) and result["t1_s"] == pytest.approx(10.0)
    assert result["joints"]["swing"]["rms_rad"] == pytest.approx(0.02, abs=2e-4)
    with pytest.raises(ValueError, match=r"a \(t 0-10 s\) and c \(t 11-12 s\) do not overlap in time"):
        compare_logs(_angles_log("a", t, q), _angles_log("c", np.array([11.0, 12.0]), q[:2]))


def test_compare_command_scores_a_trajectory_against_a_machine_log(commands, tmp_path, capsys):
    traj, ml = str(tmp_path / "t.csv"), str(tmp_path / "ml.csv")
    assert _simulate(commands, "--out", traj, "--machine-log", ml, "--sensor-noise", "angle_rad=0") == 0
    capsys.readouterr()
    plot = tmp_path / "cmp.png"
    assert main(["compare", traj, ml, "--json", "--out", str(plot)]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["tip_error_max_m"] < 0.02 and result["samples"] >= 100  # linear interpolation of the same run
    assert plot.stat().st_size > 1000
    far = tmp_path / "far.csv"
    write_csv_log(far, np.array([50.0, 51.0]), dict(zip(s.JOINT_ANGLES, np.zeros((4, 2)), strict=True)))
    assert main(["compare", traj, str(far)]) == 2
    assert "do not overlap in time" in capsys.readouterr().err

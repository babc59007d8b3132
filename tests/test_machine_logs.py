"""Machine logs: the format, the readers, and every check on a clean reference log and on logs with a fault injected
(each fault found, its finding naming the log, the signal and the time range; the clean log trusted)."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from hexgym.hydraulics.reference import ReferenceModel
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.model.commandlog import CommandLog
from hexgym.model.replay import replay
from hexgym_lab.cli import main
from hexgym_lab.machine_logs import read_machine_log
from hexgym_lab.machine_logs import signals as s
from hexgym_lab.machine_logs.checks import ERROR, Finding, check_log, trusted
from hexgym_lab.machine_logs.csv_log import write_csv_log
from hexgym_lab.machine_logs.signals import MachineLog, angles_from_extensions, spools_from_pilots
from hexgym_lab.machine_logs.synthetic import machine_log_of, parse_noise

# every function both ways, the machine moving throughout (s, mm): a few seconds of the reference
COMMANDS = CommandLog(
    np.array([0.0, 2.0, 4.0, 6.0, 8.0, 10.0]),
    np.array([[6, 9, -9, 8], [-6, -7, 9, -8], [7, 8, -8, 7], [-7, -6, 8, -7], [6, 7, -7, 7], [0, 0, 0, 0]], float),
)


@pytest.fixture(scope="module")
def rows() -> np.ndarray:
    return replay(ReferenceModel(), COMMANDS, dt_out=0.002)


@pytest.fixture(scope="module")
def clean(rows) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    return machine_log_of(rows, rate_hz=100.0, jitter=0.2, seed=3)


def _log(clean, name="run.csv", **changes) -> MachineLog:
    t, signals = clean
    signals = {k: v.copy() for k, v in signals.items()} | changes
    return MachineLog(name, t.copy(), signals)


def _errors(log: MachineLog) -> list[Finding]:
    return [f for f in check_log(log) if f.severity == ERROR]


def _only(findings: list[Finding], signal: str, words: str) -> Finding:
    hits = [f for f in findings if f.signal == signal and words in f.what]
    assert len(hits) >= 1, [f.line() for f in findings]
    return hits[0]


def test_the_format_reuses_the_trajectory_names():
    from hexgym.machine import trajectory

    assert set(trajectory.JOINT_ANGLES + trajectory.SPOOLS + trajectory.CYLINDER_EXTENSIONS) < set(s.SIGNALS)
    assert s.PUMP_PRESSURES == ("pump1_pressure_pa", "pump2_pressure_pa")
    assert len(s.CHAMBER_PRESSURES) == 8 and "boom_rod_pressure_pa" in s.ROD_PRESSURES
    assert s.SWING_PRESSURES == ("swing_a_pressure_pa", "swing_b_pressure_pa")


def test_a_clean_reference_log_is_trusted_and_round_trips_through_csv(clean, tmp_path):
    t, signals = clean
    path = write_csv_log(tmp_path / "clean.csv", t, signals)
    log = read_machine_log(path)
    assert np.allclose(log.t, t, rtol=0, atol=1e-6) and set(log.signals) == set(signals)
    findings = check_log(log)
    assert trusted(findings), [f.line() for f in findings if f.severity == ERROR]
    assert all(f.severity != "note" or "ignored" not in f.what for f in findings)


def test_a_gap_in_time_is_found_with_its_range(clean):
    log = _log(clean)
    keep = (log.t < 3.0) | (log.t > 4.0)
    log = MachineLog("gap.csv", log.t[keep], {k: v[keep] for k, v in log.signals.items()})
    f = _only(_errors(log), "t", "gap of")
    assert f.log == "gap.csv" and 2.95 < f.t0 < 3.0 and 4.0 < f.t1 < 4.05
    assert f.line().startswith("gap.csv: error: t, t 2.9")


def test_a_clock_jumping_backwards_is_found(clean):
    log = _log(clean, "jump.csv")
    k = int(np.searchsorted(log.t, 5.0))
    log.t[k:] -= 0.5
    f = _only(_errors(log), "t", "clock jumps backwards")
    assert abs(f.t0 - 5.0) < 0.02 and f.t1 < f.t0


def test_a_stuck_pressure_sensor_is_found_while_the_machine_moves(clean):
    log = _log(clean)
    run = (log.t > 2.5) & (log.t < 5.5)
    log.signals["boom_head_pressure_pa"][run] = 12.5e6
    f = _only(_errors(log), "boom_head_pressure_pa", "stuck sensor")
    assert abs(f.t0 - 2.5) < 0.02 and abs(f.t1 - 5.5) < 0.02


def test_a_saturated_sensor_is_named_saturated(clean):
    log = _log(clean)
    top = float(np.nanmax(log.signals["pump1_pressure_pa"]))
    log.signals["pump1_pressure_pa"][(log.t > 6.0) & (log.t < 9.0)] = top
    assert "saturated" in _only(_errors(log), "pump1_pressure_pa", "stuck sensor").what


def test_a_nan_run_is_found_with_its_range_and_a_lone_nan_is_a_warning(clean):
    log = _log(clean)
    log.signals["stick_rod_pressure_pa"][(log.t > 5.0) & (log.t < 5.5)] = np.nan
    log.signals["q_bucket_rad"][100] = np.nan
    f = _only(_errors(log), "stick_rod_pressure_pa", "NaN")
    assert 5.0 < f.t0 < 5.02 and 5.48 < f.t1 < 5.52
    lone = _only(check_log(log), "q_bucket_rad", "missing samples")
    assert lone.severity == "warning"


def test_pressures_in_bar_are_found(clean):
    log = _log(clean)
    log.signals["pump1_pressure_pa"] = log.signals["pump1_pressure_pa"] / 1e5
    assert "bar" in _only(_errors(log), "pump1_pressure_pa", "largest value").what


def test_angles_in_degrees_are_found(clean):
    log = _log(clean)
    log.signals["q_boom_rad"] = np.degrees(log.signals["q_boom_rad"])
    log.signals["q_swing_rad"] = np.degrees(log.signals["q_swing_rad"])
    errors = _errors(log)
    assert "degrees?" in _only(errors, "q_boom_rad", "leave the joint's range").what
    assert "degrees, not radians" in _only(errors, "q_swing_rad", "turns at").what


def test_time_in_ms_and_engine_speed_in_rad_per_s_are_found(clean):
    log = _log(clean)
    log.signals[s.ENGINE_SPEED] = log.signals[s.ENGINE_SPEED] * 2 * np.pi / 60
    assert "engine speed is in rpm" in _only(_errors(log), s.ENGINE_SPEED, "median").what
    log = _log(clean)
    log.t = log.t * 1e3
    assert _only(check_log(log), "t", "sampled at 0.0999 Hz").severity == "warning"


def test_a_flipped_sign_convention_is_found(clean):
    log = _log(clean)
    log.signals["stick_spool_mm"] = -log.signals["stick_spool_mm"]
    f = _only(_errors(log), "q_stick_rad vs stick_spool_mm", "sign convention flipped")
    assert f.t0 < 1.0 and f.t1 > 8.0
    assert not [x for x in _errors(_log(clean)) if "sign" in x.what]


def test_too_little_motion_to_learn_a_passage_is_a_warning(clean):
    log = _log(clean)
    log.signals["bucket_spool_mm"] = np.zeros_like(log.t)
    log.signals["q_bucket_rad"] = np.full_like(log.t, 0.3) + 0.001 * np.sin(log.t)
    f = _only(check_log(log), "bucket_spool_mm", "too little motion to learn bucket_pa")
    assert f.severity == "warning" and "0 s extending" in f.what


@pytest.mark.parametrize(
    "drop,words,severity",
    [
        (s.ROD_PRESSURES, "rod-side passages (P->b, and b->T", "warning"),
        (s.PUMP_PRESSURES, "pressure-flow regulator", "warning"),
        (s.JOINT_ANGLES, "nothing can be learned (no motion", "error"),
        (s.SPOOLS, "nothing can be learned (the valve", "error"),
    ],
)
def test_a_missing_signal_says_what_cannot_be_learned(clean, drop, words, severity):
    log = _log(clean)
    for name in drop:
        del log.signals[name]
    hits = [f for f in check_log(log) if words in f.what]
    assert len(hits) == 1 and hits[0].severity == severity, [f.line() for f in check_log(log)]


def test_strokes_and_pilots_stand_in_for_angles_and_spools(rows):
    q = np.column_stack([rows[n] for n in s.JOINT_ANGLES])[::100]
    ranges = np.array([kinematics.joint_range(c) for c in kinematics.FRONT_CYLINDERS])
    q = q[np.all((q[:, 1:] > ranges[:, 0]) & (q[:, 1:] < ranges[:, 1]), axis=1)]  # not pressed past a stroke end
    ext = extensions_of(q[:, 1:])
    assert np.allclose(angles_from_extensions(ext), q[:, 1:], atol=1e-5)
    assert np.isnan(angles_from_extensions(np.array([[5.0, 0.1, 0.1]]))[0, 0])  # beyond the stroke
    u = spools_from_pilots(np.array([3.0e6, 1.75e6, 0.0, 0.3e6]), np.array([0.0, 0.0, 3.5e6, 0.0]))
    assert np.allclose(u, [11.0, 5.5, -11.0, 0.0])
    log = MachineLog(
        "x", np.arange(len(q)) * 0.2, {s.JOINT_ANGLES[0]: q[:, 0]} | dict(zip(s.EXTENSIONS, ext.T, strict=True))
    )
    assert np.allclose(log.angles(), q, atol=1e-5)
    pilots = {f"{j}_pilot_{side}_pa": np.full(len(log.t), 1.75e6 if side == "extend" else 0.0)
              for j in kinematics.JOINTS for side in ("extend", "retract")}  # fmt: skip
    log.signals |= pilots
    assert np.allclose(log.spools_mm(), 5.5)


def extensions_of(front: np.ndarray) -> np.ndarray:
    """Extensions (m) of front joint angles (rad): the kinematics' own cylinder lengths."""
    return np.array([[kinematics.cylinder_length(c, a) - p.CYLINDERS[c].retracted_length
                      for c, a in zip(kinematics.FRONT_CYLINDERS, row, strict=True)] for row in front])  # fmt: skip


def test_the_noise_spec_is_read_and_refused_in_one_line():
    assert parse_noise("off").pressure_pa == 0.0
    assert parse_noise("angle_rad=0.01").angle_rad == 0.01 and parse_noise("angle_rad=0.01").pressure_pa == 0.2e6
    with pytest.raises(ValueError, match=r"--sensor-noise 'pressure=1': 'pressure=1' is not kind=sigma"):
        parse_noise("pressure=1")
    with pytest.raises(ValueError, match=r"pressure_pa must be a finite number >= 0, got '-1'"):
        parse_noise("pressure_pa=-1")


def test_check_log_prints_findings_and_exits_1_for_a_log_it_cannot_trust(clean, tmp_path, capsys):
    t, signals = clean
    good = write_csv_log(tmp_path / "good.csv", t, signals)
    bad_signals = dict(signals) | {"pump2_pressure_pa": signals["pump2_pressure_pa"] / 1e5}
    bad = write_csv_log(tmp_path / "bad.csv", t, bad_signals)
    assert main(["check-log", str(good)]) == 0
    assert f"{good}: trusted:" in capsys.readouterr().out
    assert main(["check-log", str(good), str(bad)]) == 1
    out = capsys.readouterr().out
    assert f"{bad}: error: pump2_pressure_pa, t 0.00-10.00 s: largest value" in out
    assert main(["check-log", str(bad), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert report[0]["trusted"] is False and {"log", "signal", "t0", "t1", "what"} <= set(report[0]["findings"][0])
    (tmp_path / "garbage.csv").write_text("t,q_boom_rad\n0,abc\n")
    assert main(["check-log", str(tmp_path / "garbage.csv")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "garbage.csv: row 1, column 'q_boom_rad': 'abc' is not a number" in err


def test_a_csv_log_without_time_or_with_ragged_rows_is_refused(tmp_path):
    (tmp_path / "a.csv").write_text("q_boom_rad\n0.1\n")
    with pytest.raises(ValueError, match=r"a\.csv: no time column 't'"):
        read_machine_log(tmp_path / "a.csv")
    (tmp_path / "b.csv").write_text("t,q_boom_rad\n0,0.1\n0.01\n")
    with pytest.raises(ValueError, match=r"b\.csv: row 2: 1 values for 2 columns"):
        read_machine_log(tmp_path / "b.csv")
    with pytest.raises(ValueError, match=r"needs a mapping file"):
        read_machine_log(tmp_path / "c.mcap")


def test_empty_cells_read_as_nan_and_unknown_columns_are_listed(tmp_path):
    (tmp_path / "a.csv").write_text("t,q_swing,q_boom_rad,oil_temp_c\n0,0.1,,40\n0.01,,0.2,40\n0.02,nan,0.3,41\n")
    log = read_machine_log(tmp_path / "a.csv")
    assert np.array_equal(log.t, [0, 0.01, 0.02]) and log.ignored == ("oil_temp_c",)
    assert np.isnan(log.signals["q_boom_rad"][0]) and np.isnan(log.signals["q_swing_rad"][1:]).all()
    assert "ignored: oil_temp_c" in _only(check_log(log), "log", "columns not in the format").what


# -- MCAP (ROS 2) -----------------------------------------------------------------------------------------------
MAPPING = """\
clock: /joints
signals:
  q_swing_rad: {topic: /joints, field: "position[0]"}
  q_boom_rad: {topic: /joints, field: "position[1]"}
  q_stick_rad: {topic: /joints, field: "position[2]"}
  q_bucket_rad: {topic: /joints, field: "position[3]"}
  boom_head_pressure_pa: {topic: /pressures, field: boom_head, scale: 1.0e5}
"""


def _write_mcap(path, t, signals, gap=(None, None), back_at=None) -> None:
    writer_module = pytest.importorskip("mcap_ros2.writer")
    with open(path, "wb") as f:
        writer = writer_module.Writer(f)
        joints = writer.register_msgdef("test_msgs/Joints", "float64[] position")
        pressures = writer.register_msgdef("test_msgs/Pressures", "float64 boom_head")
        q = np.column_stack([signals[n] for n in s.JOINT_ANGLES])
        for k, time in enumerate(t):
            ns = int(round(time * 1e9))
            writer.write_message("/joints", joints, {"position": q[k].tolist()}, log_time=ns, publish_time=ns)
            if k % 2 == 0 and not (gap[0] is not None and gap[0] < time < gap[1]):  # half the rate, in bar
                bar = {"boom_head": float(signals["boom_head_pressure_pa"][k] / 1e5)}
                ns -= int(0.3e9) if back_at is not None and time > back_at else 0  # this topic's clock set back
                writer.write_message("/pressures", pressures, bar, log_time=ns, publish_time=ns)
        writer.finish()


def test_an_mcap_log_reads_through_its_mapping_and_a_topic_gap_is_a_nan_run(clean, tmp_path):
    t, signals = clean
    (tmp_path / "map.yaml").write_text(MAPPING)
    _write_mcap(tmp_path / "run.mcap", t, signals, gap=(6.0, 7.0))
    log = read_machine_log(tmp_path / "run.mcap", tmp_path / "map.yaml")
    assert np.allclose(log.t, t, atol=1e-9) and np.allclose(log.signals["q_boom_rad"], signals["q_boom_rad"])
    pressure = log.signals["boom_head_pressure_pa"]
    ok = np.isfinite(pressure)
    assert np.allclose(pressure[ok][::2], signals["boom_head_pressure_pa"][ok][::2], rtol=1e-9, atol=1e-3)
    f = _only(_errors(log), "boom_head_pressure_pa", "NaN")
    assert 5.9 < f.t0 < 6.05 and 6.95 < f.t1 < 7.1
    assert f.log == str(tmp_path / "run.mcap")


def test_a_topic_whose_clock_jumps_back_is_named(clean, tmp_path):
    t, signals = clean
    (tmp_path / "map.yaml").write_text(MAPPING)
    _write_mcap(tmp_path / "run.mcap", t, signals, back_at=4.0)
    findings = _errors(read_machine_log(tmp_path / "run.mcap", tmp_path / "map.yaml"))
    f = _only(findings, "clock /pressures", "clock jumps backwards by 0.2")
    assert 3.98 < f.t0 < 4.05 and not [x for x in findings if x.signal in ("t", "clock /joints")]


def test_a_bad_mapping_is_refused_naming_the_key(tmp_path):
    from hexgym_lab.machine_logs.mcap_log import read_mapping

    pytest.importorskip("yaml")
    (tmp_path / "m.yaml").write_text("signals:\n  q_bom_rad: {topic: /j, field: x}\n")
    with pytest.raises(ValueError, match=r"m\.yaml: signals\.q_bom_rad: not a signal of the machine-log format"):
        read_mapping(tmp_path / "m.yaml")
    (tmp_path / "m.yaml").write_text("signals:\n  q_boom_rad: {topic: /j, field: x, scale: big}\n")
    with pytest.raises(ValueError, match=r"signals\.q_boom_rad\.scale must be a finite number, got 'big'"):
        read_mapping(tmp_path / "m.yaml")


def test_without_the_logs_extra_an_mcap_log_is_one_line(tmp_path, monkeypatch, capsys):
    (tmp_path / "map.yaml").write_text(MAPPING)
    (tmp_path / "run.mcap").write_bytes(b"\x89MCAP0\r\n")
    monkeypatch.setitem(sys.modules, "mcap", None)
    monkeypatch.setitem(sys.modules, "mcap.reader", None)
    assert main(["check-log", str(tmp_path / "run.mcap"), "--mapping", str(tmp_path / "map.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "run.mcap: reading MCAP needs the optional extra: pip install 'hexgym[logs]'" in err


def test_a_file_that_is_not_mcap_is_one_line(tmp_path, capsys):
    pytest.importorskip("mcap_ros2")
    (tmp_path / "map.yaml").write_text(MAPPING)
    (tmp_path / "run.mcap").write_text("t,q_boom_rad\n0,0\n")
    assert main(["check-log", str(tmp_path / "run.mcap"), "--mapping", str(tmp_path / "map.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "run.mcap: not a readable MCAP file" in err


def test_compare_plot_without_matplotlib_is_one_line_before_any_work(tmp_path, monkeypatch, capsys):
    write_csv_log(tmp_path / "a.csv", np.array([0.0, 1.0]), dict(zip(s.JOINT_ANGLES, np.zeros((4, 2)), strict=True)))
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    assert main(["compare", str(tmp_path / "a.csv"), str(tmp_path / "a.csv"), "--out", str(tmp_path / "p.png")]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and "--out: plotting needs matplotlib: pip install 'hexgym[plots]'" in captured.err


def test_fit_reads_mcap_logs_through_the_mapping_and_names_one_without_it(clean, tmp_path, capsys):
    """``fit --logs`` takes MCAP logs beside CSV ones: without ``--mapping`` each is left out in one line; with it the
    log is read (this one maps no spools, which the fit then names)."""
    from hexgym_lab.cli import main

    t, signals = clean
    (tmp_path / "map.yaml").write_text(MAPPING)
    (tmp_path / "logs").mkdir()
    _write_mcap(tmp_path / "logs" / "run.mcap", t, signals)
    argv = ["fit", "--logs", str(tmp_path / "logs"), "--out", str(tmp_path / "model")]
    assert main(argv) == 2
    assert "run.mcap: not used: an MCAP log needs a mapping file" in capsys.readouterr().out
    assert main([*argv, "--mapping", str(tmp_path / "map.yaml")]) == 2
    out = capsys.readouterr().out
    assert "run.mcap: error: spools" in out and "run.mcap: not used: cannot be trusted" in out
    assert not (tmp_path / "model").exists()

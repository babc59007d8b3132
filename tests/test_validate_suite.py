"""The generalisation suite of ``hexgym validate``: the operator-like log generator and the summary's blocks."""

import json

import numpy as np
import pytest

from hexgym.machine import kinematics
from hexgym.mbl.schema import DEFAULT_TABLE_SET
from hexgym_lab.cli import main
from hexgym_lab.mbl import operator_logs as ol
from hexgym_lab.validate import INTERACTIONS, interaction_cases, run_validation

LOGS = [ol.suite_log(7, i) for i in range(50)]


def test_each_log_is_reproducible_on_its_own():
    again = ol.suite_log(7, 3)
    assert np.array_equal(again.spools_mm, LOGS[3].spools_mm)
    assert np.array_equal(again.start_pose, LOGS[3].start_pose) and again.payload_kg == LOGS[3].payload_kg
    assert not np.array_equal(ol.suite_log(8, 3).spools_mm[:200], LOGS[3].spools_mm[:200])


@pytest.mark.parametrize("drawn", LOGS[:10])
def test_log_shape(drawn):
    t, u = drawn.t, drawn.spools_mm
    assert 30.0 <= drawn.duration <= 60.0
    assert np.allclose(np.diff(t), 0.05)
    assert np.abs(u).max() <= 11.0
    assert (np.count_nonzero(u, axis=1) <= 3).all()
    assert np.abs(u[0]).max() == 0.0 and np.abs(u[-1]).max() == 0.0  # starts and ends in neutral
    assert np.abs(np.diff(u, axis=0)).max() <= 11.0 * 0.05 / 0.2 + 0.01  # no ramp faster than 0.2 s
    for s in drawn.strokes:
        assert 0.2 - 1e-9 <= s.ramp_up_s <= 0.6 + 1e-9 and 0.2 - 1e-9 <= s.ramp_down_s <= 0.6 + 1e-9
        assert 3.0 - 1e-9 <= abs(s.level_mm) <= 11.0
        low, high = ol.SWING_HOLD_S if s.function == "swing" else ol.HOLD_S
        assert low - 0.03 <= s.hold_s <= high + 0.03  # on the 0.05 s grid
    for q, name in zip(drawn.start_pose[1:], kinematics.FRONT_CYLINDERS, strict=True):
        low, high = kinematics.joint_range(name)
        assert low < q < high


def test_rows_are_the_strokes():
    drawn = LOGS[0]
    t = drawn.t
    for s in drawn.strokes:
        column = drawn.spools_mm[:, kinematics.JOINTS.index(s.function)]
        inside = (t >= s.start_s) & (t <= s.end_s)
        assert np.allclose(column[inside], s.spool_mm(t[inside]), atol=0.01)
        hold = (t >= s.start_s + s.ramp_up_s - 1e-9) & (t <= s.end_s - s.ramp_down_s + 1e-9)
        assert np.allclose(column[hold], s.level_mm, atol=0.01)


def test_over_fifty_logs_every_direction_payload_and_phase_kind_occurs():
    moves, payloads, phases = set(), set(), {1: 0, 2: 0, 3: 0}
    swing_alone = swing_with_stick = 0
    for drawn in LOGS:
        moves |= set(drawn.describe()["moves"])
        payloads.add(drawn.payload_kg)
        active = np.count_nonzero(drawn.spools_mm, axis=1)
        for k in phases:
            phases[k] += int((active == k).any())
        for s in drawn.strokes:
            if s.function == "swing" and s.hold_s >= 3.0:
                others = [o for o in drawn.strokes if o is not s and o.start_s < s.end_s and o.end_s > s.start_s]
                swing_alone += not others
                swing_with_stick += any(o.function == "stick" for o in others)
    assert moves == {f"{j}{d}" for j in kinematics.JOINTS for d in "+-"}
    assert payloads == {0.0, 1000.0, 2000.0}
    assert all(n >= 10 for n in phases.values())
    assert swing_alone >= 10 and swing_with_stick >= 10


def _bucket_stick_phases(drawn: ol.OperatorLog) -> list[tuple[ol.Stroke, ol.Stroke]]:
    """(bucket stroke at full spool, stick stroke overlapping it) pairs of a log."""
    return [
        (b, s)
        for b in drawn.strokes
        if b.function == "bucket" and abs(b.level_mm) == 11.0
        for s in drawn.strokes
        if s.function == "stick" and abs(s.start_s - b.start_s) <= 0.5 + 1e-9
    ]


def test_operator_logs_hold_the_bucket_at_full_spool_while_the_stick_moves():
    pairs = [pair for drawn in LOGS for pair in _bucket_stick_phases(drawn)]
    assert len(pairs) >= 25
    assert {np.sign(b.level_mm) for b, _ in pairs} == {-1.0, 1.0}  # curl and dump
    assert {np.sign(s.level_mm) for _, s in pairs} == {-1.0, 1.0}  # stick in and out
    loaded = {drawn.payload_kg > 0 for drawn in LOGS if _bucket_stick_phases(drawn)}
    assert loaded == {False, True}


def test_the_bucket_stick_style_draws_only_that_motion():
    drawn = [ol.suite_log(3, i, style="bucket_stick") for i in range(5)]
    for log in drawn:
        buckets = [s for s in log.strokes if s.function == "bucket"]
        assert buckets and all(abs(s.level_mm) == 11.0 for s in buckets)
        assert len(_bucket_stick_phases(log)) == len(buckets)
        assert {s.function for s in log.strokes} <= {"boom", "stick", "bucket"}
    assert np.mean([_driven_at_a_stroke_end(log) for log in drawn]) > 0.05  # stops are reached


def test_the_sweep_style_has_no_bucket_stick_phases():
    assert ol.STYLES["sweep"].p_bucket_stick == 0.0


def _driven_at_a_stroke_end(drawn: ol.OperatorLog) -> float:
    """Share of the time a cylinder's spool is open that it is at an end, at the nominal full-spool speeds."""
    driven = at_end = 0
    for k, name in enumerate(kinematics.FRONT_CYLINDERS, start=1):
        stroke = ol.p.CYLINDERS[name].stroke
        f = (kinematics.cylinder_length(name, drawn.start_pose[k]) - ol.p.CYLINDERS[name].retracted_length) / stroke
        for u in drawn.spools_mm[:, k] / 11.0:
            f = min(1.0, max(0.0, f + ol.NOMINAL_SPEED_MPS[name][0 if u > 0 else 1] * u * 0.05 / stroke))
            driven += u != 0.0
            at_end += u != 0.0 and f in (0.0, 1.0)
    return at_end / driven


def test_cylinders_stay_mostly_inside_their_strokes():
    shares = [_driven_at_a_stroke_end(drawn) for drawn in LOGS]
    assert np.mean(shares) < 0.15
    assert max(shares) > 0.0  # an end is reached now and then


def test_interaction_cases_move_both_ways_with_and_without_payload():
    cases = interaction_cases()
    assert len(cases) == 8
    signs = {name: np.sign(log.spools_mm.sum(axis=0)) for name, (log, _, _) in cases.items()}
    assert (signs["swing_with_stick_in_0t"] == [1, 0, 1, 0]).all()
    assert (signs["swing_with_stick_out_2t"] == [1, 0, -1, 0]).all()
    assert (signs["boom_with_bucket_curl_0t"] == [0, 1, 0, 1]).all()
    assert (signs["boom_with_bucket_dump_2t"] == [0, 1, 0, -1]).all()
    assert {payload for _, _, payload in cases.values()} == {0.0, 2000.0}
    assert all(log.duration == 8.0 for log, _, _ in cases.values())


def _check_suite_block(suite: dict, n: int, seed: int) -> None:
    assert suite["seed"] == seed and suite["n"] == n and len(suite["per_log"]) == n
    means = [entry["mean_tip_error_m"] for entry in suite["per_log"]]
    assert suite["median_mean_tip_error_m"] == pytest.approx(float(np.median(means)))
    assert suite["worst_mean_tip_error_m"] == max(means) == means[suite["worst_index"]]
    for i, entry in enumerate(suite["per_log"]):
        assert entry["index"] == i and entry["seed"] == seed
        assert set(entry) >= {"duration_s", "payload_kg", "start_pose_rad", "functions", "moves", "max_tip_error_m"}
        assert 0.0 <= entry["mean_tip_error_m"] <= entry["max_tip_error_m"]
        assert set(entry["mean_tip_error_from_m"]) == set(entry["mean_joint_error_rad"]) == set(kinematics.JOINTS)


def test_suite_block_on_a_short_real_run(tmp_path):
    """One 6 s log replayed on both models, in this process."""
    summary = run_validation(tmp_path, suite=1, suite_seed=5, workers=1, suite_only=True, suite_duration_s=6.0)
    assert list(summary) == ["tables", "model", "payload_kg", "suite"] and summary["tables"] == DEFAULT_TABLE_SET
    assert summary["payload_kg"] is None and summary["model"]["table_set"] == DEFAULT_TABLE_SET
    assert summary["model"]["tables_dir"] == "packaged" and len(summary["model"]["tables_sha256"]) == 64
    _check_suite_block(summary["suite"], 1, 5)
    assert summary["suite"]["per_log"][0]["duration_s"] == 6.0
    assert summary["suite"]["per_log"][0]["payload_kg"] == ol.suite_log(5, 0, 6.0).payload_kg  # as drawn
    assert json.loads((tmp_path / "summary.json").read_text()) == summary
    assert (tmp_path / "suite_worst.png").stat().st_size > 0


def test_payload_goes_into_every_suite_log_in_worker_processes(tmp_path):
    """``payload_kg`` replaces each suite log's drawn payload; two workers build their own circuit model."""
    summary = run_validation(
        tmp_path,
        suite=2,
        suite_seed=5,
        workers=2,
        suite_only=True,
        suite_duration_s=4.0,
        payload_kg=1500.0,
        suite_style="bucket_stick",
    )
    assert summary["payload_kg"] == 1500.0 and summary["suite"]["style"] == "bucket_stick"
    assert [entry["payload_kg"] for entry in summary["suite"]["per_log"]] == [1500.0, 1500.0]
    assert json.loads((tmp_path / "summary.json").read_text())["payload_kg"] == 1500.0


def test_interaction_cases_at_one_payload():
    cases = interaction_cases((2000.0,))
    assert sorted(cases) == sorted(f"{name}_2t" for name in INTERACTIONS)
    assert {payload for _, _, payload in cases.values()} == {2000.0}


@pytest.mark.parametrize("payload", ["-1", "nan", "inf", "2500"])
def test_validate_refuses_a_bad_payload_in_one_line(tmp_path, capsys, payload):
    assert main(["validate", "--out", str(tmp_path), "--payload-kg", payload]) == 2
    err = capsys.readouterr().err.strip()
    assert "--payload-kg" in err and len(err.splitlines()) == 1


@pytest.mark.parametrize("payload", [-1.0, float("nan"), 1e4])
def test_run_validation_refuses_a_bad_payload(tmp_path, payload):
    with pytest.raises(ValueError, match="payload_kg"):
        run_validation(tmp_path, suite=1, suite_only=True, payload_kg=payload)


def test_validate_refuses_bad_suite_arguments(tmp_path, capsys):
    assert main(["validate", "--out", str(tmp_path), "--suite", "-1"]) == 2
    assert main(["validate", "--out", str(tmp_path), "--suite-only"]) == 2
    assert main(["validate", "--out", str(tmp_path), "--suite", "1", "--workers", "0"]) == 2
    with pytest.raises(SystemExit):  # argparse's choices
        main(["validate", "--out", str(tmp_path), "--suite", "1", "--suite-style", "sweep"])
    assert "error" in capsys.readouterr().err


@pytest.mark.slow
def test_full_validation_with_two_suite_logs(tmp_path, capsys):
    """``hexgym validate --suite 2``: the tests, the interactions and two full-length logs, in workers."""
    assert main(["validate", "--out", str(tmp_path), "--suite", "2", "--suite-seed", "1", "--workers", "2"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    tests = {"test1", "test2", "test3"}
    assert set(summary) == {"tables", "model", "payload_kg", *tests, "speed", "interactions", "suite"}
    assert set(summary["interactions"]) == set(interaction_cases())
    _check_suite_block(summary["suite"], 2, 1)
    for name in ("test1", "test2", "test3", "interactions", "suite_worst"):
        assert (tmp_path / f"{name}.png").is_file()

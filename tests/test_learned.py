"""The learned model (MuJoCo linkage + the packaged MBL tables)."""

import numpy as np
import pytest

from hexgym.machine import kinematics
from hexgym.model.commandlog import CommandLog
from hexgym.model.python_backend import LearnedModel
from hexgym.model.replay import replay
from hexgym_lab.reference_report import POSE_LOW
from hexgym_lab.validate import scenarios, tip_errors

FULL = 0.011


@pytest.fixture(scope="module")
def model() -> LearnedModel:
    return LearnedModel()


def periods(model: LearnedModel, seconds: float) -> int:
    """Control periods in ``seconds``."""
    return int(round(seconds / model.control_period))


def test_closed_spools_hold_a_full_bucket(model):
    model.reset(POSE_LOW, payload_kg=2000.0)
    model.step(np.zeros(4), n=periods(model, 3.0))
    np.testing.assert_allclose(model.physics.joint_positions(), POSE_LOW, atol=5e-3)
    assert np.abs(model.physics.joint_velocities()).max() < 1e-3


def test_full_boom_spool_runs_at_both_pumps_speed(model):
    model.reset(POSE_LOW)
    model.step(np.array([0.0, FULL, 0.0, 0.0]), n=periods(model, 1.5))
    assert model.physics.cylinder_velocities()[0] == pytest.approx(0.276, rel=0.15)  # reference: 0.276 m/s


def test_bucket_takes_pump_1_until_it_stalls(model):
    model.reset(POSE_LOW)
    model.step(np.array([0.0, FULL, 0.0, FULL]), n=periods(model, 1.5))
    boom, _, bucket = model.physics.cylinder_velocities()
    assert bucket > 0.2 and 0.1 < boom < 0.2  # the bucket takes pump 1, the boom rises on pump 2's boom 2
    model.step(np.array([0.0, FULL, 0.0, FULL]), n=periods(model, 3.5))  # the bucket reaches its stroke end
    boom, _, bucket = model.physics.cylinder_velocities()
    assert abs(bucket) < 0.01 and boom > 0.2


def test_loads_follow_payload_and_tip_force(model):
    model.reset(POSE_LOW)
    empty = model.cylinder_loads()
    model.reset(POSE_LOW, payload_kg=2000.0)
    full = model.cylinder_loads()
    assert full[0] > empty[0] + 20e3  # the boom cylinders carry the material
    model.reset(POSE_LOW)
    model.physics.apply_tip_force(np.array([0.0, 0.0, 50e3]))  # pushing the tip up unloads the boom
    model.step(np.zeros(4))
    assert model.cylinder_loads()[0] < empty[0] - 20e3


@pytest.mark.parametrize("spools", [[0, np.nan, 0, 0], [0, 0, 0.012, 0], [0, 0, 0]])
def test_bad_spools_are_refused(model, spools):
    with pytest.raises(ValueError):
        model.step(np.array(spools, dtype=float))


def test_replay_gives_the_common_columns_and_zero_error_against_itself(model):
    log = CommandLog(np.array([0.0, 0.2, 0.5]), np.array([[0, 0, 0, 0], [8, 5, -5, 3], [0, 0, 0, 0]], float))
    traj = replay(model, log, start=POSE_LOW)
    for column in (
        "t",
        *(f"q_{j}_rad" for j in kinematics.JOINTS),
        *(f"qd_{j}_radps" for j in kinematics.JOINTS),
        "tip_x_m",
    ):
        assert column in traj.dtype.names
    errors = tip_errors(traj, traj)
    assert np.all(errors["tip_error"] == 0) and np.all(errors["joint_contribution"] == 0)
    assert np.all(errors["foot_to_tip"] > 1.0)


def test_test3_is_an_operator_like_cycle_of_about_50_s():
    log, _ = scenarios()["test3"]
    assert 45 <= log.duration <= 55
    assert np.abs(log.spools_mm).max() <= 11.0


def test_swing_never_outruns_its_table(model):
    """A long full swing levels off at the reference's top speed (11.39 rpm, 1.19 rad/s), never beyond the
    table's fastest swing rate."""
    model.reset(POSE_LOW)
    model.step(np.array([FULL, 0.0, 0.0, 0.0]), n=periods(model, 8.0))
    fastest = model.tables["swing"].axes[-1][-1]
    assert 0.9 * 1.19 < model.physics.joint_velocities()[0] <= min(1.1 * 1.19, fastest + 1e-9)


def test_a_stroke_end_stop_carries_its_load_not_the_oil(model):
    """At a joint limit (the cylinder's end stop) the stop's force is not read as cylinder load."""
    hi = kinematics.joint_range("stick")[1]
    inside, beyond = (np.array([0.0, -0.45, hi + d, -0.9]) for d in (-0.003, 0.003))
    model.reset(inside)
    free = model.cylinder_loads()[1]
    model.reset(beyond)  # 3 mrad into the stop: the limit pushes back
    limit = model.physics._limit_forces()[model._dofs[2]]
    assert abs(limit) > 0.2 * abs(free)
    assert model.cylinder_loads()[1] == pytest.approx(free, rel=0.02)

"""HexLoading-v0 on the reference model: the same task and keys on the analytical circuit, clear errors."""

import gymnasium as gym
import numpy as np
import pytest

import hexgym  # noqa: F401  (registers the environments)
from hexgym.agents.scripted import ScriptedLoader
from hexgym.envs.loading import HexLoadingEnv
from hexgym.envs.reference_machine import CONTROL_PERIOD, ReferenceMachine
from hexgym_lab import cli
from hexgym_lab.agents.evaluate import METRIC_KEYS, evaluate


@pytest.fixture(scope="module")
def reference_env():
    env = gym.make("HexLoading-v0", model="reference")
    yield env
    env.close()


def test_the_reference_runs_the_same_task_with_the_same_keys(reference_env):
    learned = gym.make("HexLoading-v0", backend="python")
    obs_ref, info_ref = reference_env.reset(seed=3)
    obs_learned, info_learned = learned.reset(seed=3)
    assert isinstance(reference_env.unwrapped.machine, ReferenceMachine)
    assert reference_env.unwrapped.machine.control_period == CONTROL_PERIOD
    # the same site and start from the same seed: the same first observation (the holding loads within
    # 2 kN: the full machine's cylinder bodies carry a little mass the lean machine lumps elsewhere)
    np.testing.assert_allclose(obs_ref, obs_learned, atol=2e-3)
    assert set(info_ref) == set(info_learned)
    _, _, _, _, info_ref = reference_env.step(np.array([0.0, 1.0, 0.0, 0.0], np.float32))
    _, _, _, _, info_learned = learned.step(np.array([0.0, 1.0, 0.0, 0.0], np.float32))
    assert set(info_ref) == set(info_learned)
    assert info_ref["time_s"] == pytest.approx(0.1)
    assert info_ref["fuel_l"] > 0.0
    learned.close()


def test_the_scripted_loader_digs_on_the_reference(reference_env):
    env = reference_env.unwrapped
    env.reset(seed=0)
    loader = ScriptedLoader()
    loader.reset()
    bucket = 0.0
    for _ in range(150):  # 15 s: the loader reaches the pile and fills the bucket within ~12 s
        _, _, terminated, truncated, info = reference_env.step(loader.act(env))
        bucket = max(bucket, info["bucket_kg"])
        assert not (terminated or truncated)
    assert bucket > 1000.0  # the digging force, the fill and the payload act on the reference machine
    q = env.physics.joint_positions()
    assert np.all(np.isfinite(q))


def test_evaluate_reports_the_same_keys_on_the_reference(tmp_path):
    result = evaluate("scripted", episodes=1, seed=0, env_kwargs={"model": "reference", "time_limit": 3.0})
    assert result["model"] == "reference"
    for key in METRIC_KEYS:
        assert key in result
    assert cli.main(["evaluate", "--policy", "scripted", "--episodes", "1", "--seconds", "1",
                     "--model", "reference"]) == 0  # fmt: skip


def test_video_on_the_reference(tmp_path):
    out = tmp_path / "ref.mp4"
    assert cli.main(["video", "--policy", "scripted", "--out", str(out), "--seconds", "0.5", "--width", "160",
                     "--height", "96", "--model", "reference"]) == 0  # fmt: skip
    assert out.stat().st_size > 1000


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"model": "real"}, "model must be one of"),
        ({"model": "reference", "backend": "native"}, "backend='native' does not apply to model='reference'"),
        ({"model": "reference", "tables": "paper"}, "tables='paper' does not apply to model='reference'"),
    ],
)
def test_bad_model_options_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        HexLoadingEnv(**kwargs)


def test_the_batched_environment_refuses_the_reference():
    with pytest.raises(ValueError, match="runs the learned model only"):
        gym.make_vec("HexLoading-v0", num_envs=2, model="reference")


def test_the_loads_observation_means_the_same_on_the_reference(reference_env):
    """Observation entries 9-11 are the holding loads of the machine's state on every model, not the reference's
    oil forces, which also carry the links' acceleration and the circuit's transients (a policy learned on the
    fast model never saw those)."""
    learned = gym.make("HexLoading-v0", backend="python")
    reference_env.reset(seed=3)
    learned.reset(seed=3)
    machine = reference_env.unwrapped.machine
    raise_and_reach = np.array([0.0, 1.0, -1.0, 0.0], np.float32)
    observed_gap, oil_gap = [], []
    for _ in range(8):
        obs_ref, *_ = reference_env.step(raise_and_reach)
        obs_learned, *_ = learned.step(raise_and_reach)
        oil = machine.reference.joint_torques()[1:] / machine.physics.moment_arms() / 1e6
        observed_gap.append(np.abs(obs_ref[9:12] - obs_learned[9:12]).max())
        oil_gap.append(np.abs(oil - obs_learned[9:12]).max())
    learned.close()
    assert max(observed_gap) < 0.05  # MN: the two machines' motions differ a little
    assert max(oil_gap) > 0.1  # the oil's force at the start of the move is another quantity


def test_the_fuel_on_the_reference_is_its_engines(reference_env, monkeypatch):
    """The reference's fuel is its engine's (the pumps' pressures and flows through the BSFC map, at each control
    period's end for the period), not the learned model's estimate from the motion."""
    from hexgym.hydraulics.reference import ReferenceModel

    machine = reference_env.unwrapped.machine
    reference_env.reset(seed=4)
    machine.step(np.array([0.0, 5e-3, 0.0, 0.0]))  # the reference's own rate, as its trajectory rows report it
    assert machine.reference.fuel_rate_l_per_h() == pytest.approx(machine.reference.observe()["fuel_rate_l_per_h"])
    assert machine.take_fuel_l() == pytest.approx(machine.reference.fuel_rate_l_per_h() * CONTROL_PERIOD / 3600.0)
    assert machine.take_fuel_l() == 0.0  # taken
    reference_env.reset(seed=4)
    monkeypatch.setattr(ReferenceModel, "fuel_rate_l_per_h", lambda self: 36.0)
    swing = np.array([1.0, 0.0, 0.0, 0.0], np.float32)  # full swing from rest: the estimate would say little
    for _ in range(3):
        _, _, _, _, info = reference_env.step(swing)
        assert info["fuel_l_step"] == pytest.approx(36.0 * 0.1 / 3600.0, rel=1e-12)
    assert info["fuel_l"] == pytest.approx(3 * 36.0 * 0.1 / 3600.0, rel=1e-12)

"""HexReach-v0: Gymnasium's contract, reachable targets, the reward's terms, clear errors."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import hexgym  # noqa: F401  (registers the environments)
from hexgym.envs.reach import MIN_TARGET_DISTANCE_M, TARGET_FLOOR_M, HexReachEnv
from hexgym.machine import kinematics


@pytest.fixture(scope="module")
def env():
    env = gym.make("HexReach-v0", backend="python")
    yield env
    env.close()


def test_gymnasium_contract():
    check_env(gym.make("HexReach-v0", backend="python").unwrapped)


def test_targets_are_reachable_high_enough_and_far_enough(env):
    for seed in range(20):
        obs, info = env.reset(seed=seed)
        u = env.unwrapped
        assert u.target[2] >= TARGET_FLOOR_M
        assert info["distance_m"] >= MIN_TARGET_DISTANCE_M
        np.testing.assert_allclose(obs[12:15], u.physics.tip_position() - u.target, atol=1e-5)
        assert env.observation_space.contains(obs)
    first = env.reset(seed=7)[0]
    np.testing.assert_array_equal(first, env.reset(seed=7)[0])  # seeded


def test_progress_sums_to_the_distance_covered_and_arrival_terminates(env):
    obs, info = env.reset(seed=3)
    u = env.unwrapped
    start = info["distance_m"]
    progress = 0.0
    for _ in range(5):
        obs, reward, terminated, truncated, info = env.step(np.array([0.5, 0.5, -0.5, 0.0], np.float32))
        progress += info["reward_progress"]
        assert reward == pytest.approx(info["reward_progress"] + info["reward_time"] + info["reward_success"])
    assert progress == pytest.approx(start - info["distance_m"])
    # put the target at the teeth: the next still step arrives, with the bonus, and ends the episode
    u.target = u.physics.tip_position().copy()
    u._distance = 0.0
    for _ in range(20):  # until the machine has settled below the arrival speed
        obs, reward, terminated, truncated, info = env.step(np.zeros(4, np.float32))
        if terminated:
            break
    assert terminated and info["is_success"] and info["reward_success"] == 5.0


def test_time_limit_truncates(env):
    short = gym.make("HexReach-v0", backend="python", time_limit=0.3)
    short.reset(seed=0)
    ends = [short.step(np.zeros(4, np.float32))[3] for _ in range(3)]
    assert ends == [False, False, True]


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"time_limit": 0.0}, "time_limit must be a finite number > 0"),
        ({"tolerance_m": float("nan")}, "tolerance_m must be a finite number > 0"),
        ({"success_reward": -1.0}, "success weight must be a finite number >= 0"),
        ({"tables": "other"}, "tables must be one of"),
        ({"render_mode": "rgb_array"}, "does not render"),
    ],
)
def test_bad_arguments_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        HexReachEnv(backend="python", **kwargs)


def test_bad_actions_are_refused(env):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match=r"entries \[2\]"):
        env.step(np.array([0.0, 0.0, np.nan, 0.0]))


def test_kinematic_and_simulated_teeth_agree(env):
    env.reset(seed=5)
    ph = env.unwrapped.physics
    np.testing.assert_allclose(kinematics.tip_position(ph.joint_positions()), ph.tip_position(), atol=1e-6)


def test_shipped_hyperparameters_for_ppo_and_sac():
    from hexgym_lab.agents.hyperparams import load_hyperparams
    from hexgym_lab.agents.training import check_hyperparams

    for algo in ("ppo", "sac"):
        hp = load_hyperparams(algo, "HexReach-v0")
        check_hyperparams(algo, hp, "HexReach-v0")
        assert hp["normalize"]["norm_obs"] is True


def test_a_trained_model_is_evaluated_by_its_success(tmp_path):
    import yaml

    from hexgym_lab import cli
    from hexgym_lab.agents.evaluate import evaluate_success
    from hexgym_lab.agents.training import train

    tiny = {
        "HexReach-v0": {"n_timesteps": 128, "policy": "MlpPolicy", "normalize": "dict(norm_obs=True)", "n_steps": 64,
                        "batch_size": 64, "n_epochs": 1, "env_kwargs": {"time_limit": 2.0}}
    }  # fmt: skip
    hyperparams = tmp_path / "tiny.yml"
    hyperparams.write_text(yaml.safe_dump(tiny))
    path = train("ppo", "HexReach-v0", timesteps=128, log_dir=tmp_path, hyperparams=hyperparams, n_envs=1,
                 checkpoint_every=128, progress_bar=False, report=False)  # fmt: skip
    result = evaluate_success(path, "HexReach-v0", episodes=2, seed=1000, env_kwargs={"time_limit": 1.0})
    assert result["episodes"] == 2 and 0.0 <= result["success_rate"] <= 1.0 and np.isfinite(result["mean_return"])
    out = tmp_path / "reach.json"
    assert cli.main(["evaluate", "--env", "HexReach-v0", "--policy", str(path), "--episodes", "1", "--seconds", "1",
                     "--json", str(out)]) == 0  # fmt: skip
    assert out.is_file()
    assert cli.main(["evaluate", "--env", "HexReach-v0", "--policy", "shipped"]) == 2  # HexLoading-v0's policy

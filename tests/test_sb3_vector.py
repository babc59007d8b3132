"""SB3 on the batched HexLoading-v0: the same episodes as single environments, in SB3's episode convention."""

import gymnasium as gym
import numpy as np
import pytest

import hexgym  # noqa: F401 - registers the tasks
from hexgym.envs.task import REWARD_TERMS
from hexgym_lab.agents.sb3_vector import SB3VectorEnv, site_infos
from hexgym_lab.agents.training import batched, make_vec_env, train

SEED, STEPS = 11, 5  # 0.5 s episodes: each site's first episode ends at its fifth step


def test_ended_episodes_restart_in_the_same_step_as_single_envs_do():
    venv = SB3VectorEnv(gym.make_vec("HexLoading-v0", num_envs=2, time_limit=0.1 * STEPS))
    singles = [gym.make("HexLoading-v0", time_limit=0.1 * STEPS) for _ in range(2)]
    try:
        venv.seed(SEED)
        obs = venv.reset()
        for i, env in enumerate(singles):
            np.testing.assert_array_equal(obs[i], env.reset(seed=SEED + i)[0])
        action = np.array([[0.6, -0.4, 0.3, 0.2], [-0.5, 0.5, -0.2, 0.1]], np.float32)
        for step in range(1, STEPS + 2):
            venv.step_async(action)
            obs, rewards, dones, infos = venv.step_wait()
            for i, env in enumerate(singles):
                single_obs, reward, terminated, truncated, info = env.step(action[i])
                assert rewards[i] == np.float32(reward) and dones[i] == (terminated or truncated)
                assert infos[i]["truck_kg"] == info["truck_kg"]
                assert all(infos[i][f"reward_{t}"] == info[f"reward_{t}"] for t in REWARD_TERMS)
                if step == STEPS:  # ended: the final observation in the info, the next episode's first returned
                    assert dones[i] and infos[i]["TimeLimit.truncated"] and not terminated
                    np.testing.assert_array_equal(infos[i]["terminal_observation"], single_obs)
                    first, start_info = env.reset()
                    np.testing.assert_array_equal(obs[i], first)
                    assert venv.reset_infos[i]["bucket_kg"] == start_info["bucket_kg"]
                else:
                    assert "terminal_observation" not in infos[i]
                    np.testing.assert_array_equal(obs[i], single_obs)
    finally:
        venv.close()
        for env in singles:
            env.close()


def test_site_infos_keep_only_the_masked_in_entries():
    info = {"a": np.array([1.0, 2.0, 3.0]), "_a": np.array([True, False, True]), "b": np.array([4, 5, 6])}
    assert site_infos(info, 3) == [{"a": 1.0, "b": 4}, {"b": 5}, {"a": 3.0, "b": 6}]
    assert isinstance(site_infos(info, 3)[0]["a"], float)  # Python scalars, as single environments give


def test_a_short_run_on_the_batch_learns_from_its_episodes(tmp_path):
    venv = make_vec_env("HexLoading-v0", 4, seed=0, env_kwargs={"time_limit": 0.4}, batch=True)
    try:
        from stable_baselines3 import PPO

        model = PPO("MlpPolicy", venv, n_steps=16, batch_size=32, n_epochs=1, seed=0)
        model.learn(64)
        assert len(model.ep_info_buffer) == 4 * 4  # 16 steps of each of 4 sites: four 4-step episodes each (VecMonitor)
        assert {e["l"] for e in model.ep_info_buffer} == {4}
    finally:
        venv.close()


def test_the_batch_is_used_where_there_is_one_and_refused_where_not(tmp_path):
    assert batched("HexLoading-v0", "auto") and not batched("HexLoading-v0", "subproc")
    assert not batched("HexReach-v0", "auto")
    assert not batched("HexLoading-v0", "auto", wrapper="hexgym.wrappers.PreviousActionWrapper")
    with pytest.raises(ValueError, match="HexReach-v0 has no batched vector environment"):
        batched("HexReach-v0", "batch")
    with pytest.raises(ValueError, match="env_wrapper"):
        batched("HexLoading-v0", "batch", wrapper="hexgym.wrappers.PreviousActionWrapper")
    with pytest.raises(ValueError, match="vec_env must be one of"):
        train("ppo", timesteps=64, log_dir=tmp_path, vec_env="threads")

"""HexDig-v0: Gymnasium's contract, the start over the pile, the reward's terms, success, clear errors."""

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import hexgym  # noqa: F401  (registers the environments)
from hexgym.agents.scripted import ScriptedLoader
from hexgym.envs.dig import DIG_REWARD_TERMS, HexDigEnv
from hexgym.envs.loading import (
    AT_TRUCK_RADIUS,
    AT_TRUCK_SWING,
    DIG_START_HEIGHT,
    DIG_START_RADIUS_NOISE,
    LOADED_START_PAYLOAD_KG,
    OBSERVATION_NAMES,
    HexLoadingEnv,
)
from hexgym.envs.world import entry_radius
from hexgym.machine import parameters as p

ABOVE_PILE = OBSERVATION_NAMES.index("tip_above_pile")


@pytest.fixture(scope="module")
def env():
    env = gym.make("HexDig-v0")
    yield env
    env.close()


def test_gymnasium_contract():
    check_env(HexDigEnv(), skip_render_check=True)


def test_starts_with_the_teeth_over_the_cut_entry_and_is_seeded(env):
    for seed in range(10):
        obs, info = env.reset(seed=seed)
        u = env.unwrapped
        tip, lay = u.physics.tip_position(), u.layout
        assert abs(math.hypot(tip[0], tip[1]) - entry_radius(lay)) <= DIG_START_RADIUS_NOISE + 0.05
        assert DIG_START_HEIGHT[0] - 0.05 <= tip[2] - lay.pile_height <= DIG_START_HEIGHT[1] + 0.05
        assert obs[ABOVE_PILE] > 0.2 and info["bucket_kg"] == 0.0 and not info["is_success"]
        assert env.observation_space.contains(obs)
    np.testing.assert_array_equal(env.reset(seed=4)[0], env.reset(seed=4)[0])


def test_the_scripted_dig_succeeds_and_the_shaping_sums_to_what_the_bucket_holds(env):
    """The scripted loader's dig (push in, drag, curl, lift) ends the episode with success; the load and
    lift terms, potential-based, sum to the bucket's tonnes and their lift at the end."""
    obs, info = env.reset(seed=11)
    loader, sums = ScriptedLoader(), dict.fromkeys(DIG_REWARD_TERMS, 0.0)
    for _ in range(200):
        obs, reward, terminated, truncated, info = env.step(loader.act(env.unwrapped))
        assert reward == pytest.approx(sum(info[f"reward_{t}"] for t in DIG_REWARD_TERMS))
        for t in DIG_REWARD_TERMS:
            sums[t] += info[f"reward_{t}"]
        if terminated or truncated:
            break
    assert terminated and not truncated and info["is_success"] and info["time_s"] < 10.0
    assert info["bucket_kg"] >= env.unwrapped.config.fill_kg and obs[ABOVE_PILE] >= env.unwrapped.config.lift_m
    assert sums["load"] == pytest.approx(obs[OBSERVATION_NAMES.index("payload")], abs=1e-6)
    assert sums["lift"] == pytest.approx(obs[OBSERVATION_NAMES.index("payload")], abs=1e-6)  # lifted lift_m or more
    assert sums["success"] == 5.0 and "truck_kg" not in info


def test_doing_nothing_fails_by_truncation():
    short = gym.make("HexDig-v0", time_limit=1.0)
    short.reset(seed=0)
    for _ in range(10):
        _, reward, terminated, truncated, info = short.step(np.zeros(4, np.float32))
    assert truncated and not terminated and not info["is_success"] and info["bucket_kg"] == 0.0
    assert reward == pytest.approx(-0.01)  # the time term alone


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"fill_kg": 0.0}, "fill_kg must be > 0"),
        ({"fill_kg": 5000.0}, "at most the heaped bucket"),
        ({"lift_m": float("nan")}, "lift_m must be a finite number"),
        ({"success_reward": -1.0}, "success weight must be a finite number >= 0"),
        ({"delivery_weight": 1.0}, "no argument 'delivery_weight'"),
    ],
)
def test_bad_arguments_are_named(kwargs, message):
    with pytest.raises((ValueError, TypeError), match=message):
        HexDigEnv(**kwargs)


def test_evaluate_scores_the_scripted_dig_and_refuses_it_elsewhere():
    from hexgym_lab.agents.evaluate import evaluate_success

    result = evaluate_success("scripted", "HexDig-v0", episodes=2, seed=1000)
    assert result["success_rate"] == 1.0 and 4.0 < result["mean_time_to_success_s"] < 10.0
    with pytest.raises(ValueError, match="the scripted loader acts on the loading site"):
        evaluate_success("scripted", "HexReach-v0", episodes=1)


def test_video_films_the_dig(tmp_path):
    from hexgym_lab.agents.video import record_video

    result = record_video("scripted", tmp_path / "dig.mp4", seconds=1.0, width=96, height=64, env_id="HexDig-v0")
    assert result["frames"] == 10 and result["episodes"][0]["success"] is False and result["video"].stat().st_size
    with pytest.raises(ValueError, match="the shipped agent loads trucks"):
        record_video("shipped", tmp_path / "x.mp4", env_id="HexDig-v0")


def test_the_loading_task_can_start_some_episodes_at_the_dig():
    """``dig_start_share``: that share of HexLoading-v0's episodes start as HexDig-v0's do; 0 leaves it as it was."""
    plain, mixed = HexLoadingEnv(), HexLoadingEnv(dig_start_share=0.5)
    over_pile = []
    for seed in range(12):
        obs_plain = plain.reset(seed=seed)[0]
        np.testing.assert_array_equal(obs_plain, HexLoadingEnv().reset(seed=seed)[0])  # the default draws as before
        mixed.reset(seed=seed)
        tip = mixed.physics.tip_position()
        over_pile.append(abs(math.hypot(tip[0], tip[1]) - entry_radius(mixed.layout)) <= DIG_START_RADIUS_NOISE + 0.05)
        assert mixed.layout == plain.layout  # the same site either way
    assert 2 <= sum(over_pile) <= 10
    with pytest.raises(ValueError, match="dig_start_share must be a number from 0 to 1"):
        HexLoadingEnv(dig_start_share=1.5)


def test_the_loading_task_can_start_some_episodes_loaded_on_the_way_to_the_truck():
    """``loaded_start_share``: that share starts with material in the bucket, lifted clear of pile and truck: curled,
    between them, or reached out over the bed, tilted; the material is the bucket's and the machine's payload, and
    stays in while the machine rests."""
    env = HexLoadingEnv(loaded_start_share=0.7, dig_start_share=0.1)
    kinds = {"carry": 0, "at_truck": 0}
    for seed in range(24):
        obs, info = env.reset(seed=seed)
        assert obs[OBSERVATION_NAMES.index("payload")] == pytest.approx(info["bucket_kg"] / 1000.0, abs=1e-6)
        assert env.physics.payload_kg == pytest.approx(info["bucket_kg"])
        if info["bucket_kg"] == 0.0:
            continue
        tilt, above_rim, across, swing_to_pile, swing_to_truck = (
            obs[OBSERVATION_NAMES.index(name)]
            for name in ("bucket_tilt", "tip_above_rim", "tip_truck_across", "swing_to_pile", "swing_to_truck")
        )
        if math.hypot(*env.physics.tip_position()[:2]) > AT_TRUCK_RADIUS[0] - 0.1:  # reached out to the truck
            kinds["at_truck"] += 1
            assert abs(swing_to_truck) <= AT_TRUCK_SWING + 1e-6 and abs(across) < p.TRUCK_BED_WIDTH / 2 + 0.5
            assert above_rim > 1.1 and tilt < 0.8
        else:
            kinds["carry"] += 1
            assert LOADED_START_PAYLOAD_KG[0] <= info["bucket_kg"] <= LOADED_START_PAYLOAD_KG[1]
            assert tilt < 0.4 and above_rim > 1.3
            assert abs(swing_to_pile) + abs(swing_to_truck) == pytest.approx(
                abs(swing_to_pile - swing_to_truck), abs=1e-5
            )
        for _ in range(5):  # at rest, spools closed: nothing spills, nothing touches
            obs, _, _, _, info = env.step(np.zeros(4, np.float32))
            assert info["spilled_kg"] == 0.0 and info["reward_contact"] == 0.0
    assert kinds["carry"] >= 4 and kinds["at_truck"] >= 4, kinds
    for shares, message in (
        ({"loaded_start_share": -0.1}, "loaded_start_share must be a number from 0 to 1"),
        ({"loaded_start_share": 0.7, "dig_start_share": 0.5}, r"dig_start_share \+ loaded_start_share must be at most"),
    ):
        with pytest.raises(ValueError, match=message):
            HexLoadingEnv(**shares)

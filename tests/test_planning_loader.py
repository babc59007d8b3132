"""The planning loader: the scripted dig with dumps and returns planned online, and its figures."""

import gymnasium as gym
import numpy as np
import pytest

import hexgym  # noqa: F401  (registers HexLoading-v0)
from hexgym.machine import parameters as p
from hexgym.model import plugin

pytestmark = pytest.mark.skipif(plugin.plugin_library() is None, reason="native plugin not built")


def test_the_planning_loader_executes_its_plans_and_counts_them():
    """The loader plans its moves from the measured state and executes a plan's spools for the time since it was
    made; the scripted loader digs; the episode's plans are counted."""
    from hexgym.agents.planning_loader import PlanningLoader

    env = gym.make("HexLoading-v0")
    loader = PlanningLoader(budget=150)
    obs, _ = env.reset(seed=1)
    loader.reset()
    planned_steps, scripted_steps = 0, 0
    try:
        for _ in range(900):
            action = loader.act(obs, env.unwrapped)
            plan = loader._plan
            if loader._move is None:
                scripted_steps += 1
            elif plan is not None and loader._period_now(env.unwrapped) < len(plan.spools_m):
                k = loader._period_now(env.unwrapped)
                np.testing.assert_array_equal(action, (plan.spools_m[k] / p.SPOOL_STROKE).astype(np.float32))
                planned_steps += 1
            obs, *_ = env.step(action)
            if planned_steps >= 10 and scripted_steps >= 10:
                break
        figures = loader.episode_figures()
    finally:
        env.close()
        loader.close()
    assert scripted_steps >= 10 and planned_steps >= 10
    assert figures["plan_walls_s"] and all(w > 0 for w in figures["plan_walls_s"])


def test_the_planner_policy_is_loaded_by_name_for_the_loading_task_only():
    from hexgym.agents.planning_loader import PlanningLoader
    from hexgym.agents.policies import load_policy
    from hexgym.envs import DIG_ENV_ID

    assert isinstance(load_policy("planner"), PlanningLoader)
    with pytest.raises(ValueError, match="the planning loader loads trucks"):
        load_policy("planner", DIG_ENV_ID)
    with pytest.raises(ValueError, match="budget must be an integer >= 1"):
        PlanningLoader(budget=0)


def test_evaluation_states_a_planning_policys_plan_times_and_fallbacks():
    from hexgym_lab.agents.evaluate import Episode, aggregate

    def episode(seed, walls, fallbacks):
        e = Episode(seed=seed, time_s=[0.1, 0.2], truck_kg=[0.0, 1500.0])
        e.planner = {"plan_walls_s": walls, "fallbacks": fallbacks, "replans": 1}
        return e

    figures = aggregate([episode(0, [1.0, 2.0], 0), episode(1, [3.0], 2)])["planner"]
    assert figures["plans"] == 3 and figures["fallbacks"] == 2 and figures["replans"] == 2
    assert figures["plan_wall_s_median"] == 2.0 and figures["plan_wall_s_max"] == 3.0
    assert "planner" not in aggregate([Episode(seed=0, time_s=[0.1], truck_kg=[0.0])])

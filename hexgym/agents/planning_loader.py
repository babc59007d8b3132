"""A loader that plans its own moves: digs as the scripted loader does, plans each dump and return online.

:class:`PlanningLoader` runs the scripted loader (:class:`hexgym.agents.scripted.ScriptedLoader`) through the
dig, and takes over its two free-space moves, each planned from the measured state on the environment's own learned
model (:func:`hexgym.planning.planner.plan_motion` on batched native rollouts, :mod:`hexgym.planning`):

- ``dump``: once the loaded bucket has left the pile (the scripted ``to_truck`` phase, :func:`out_of_the_pile`:
  the rollouts have no digging force), to the mouth over the bed
  (:func:`hexgym.planning.goals.dump_goal`);
- ``return``: once the bucket is emptied (the scripted ``to_pile`` phase), to the scripted loader's dig start
  (:func:`hexgym.planning.goals.return_goal`).

Each search starts from the last move of its kind (the executed actions averaged per knot; the first one from a
heuristic move, and after a fallback from the scripted loader's move), its horizon 1 s longer than that move took.
Each step executes the plan's spools for the time since it was made (the environment holds an action for its 0.1 s
step: the spools at the step's start).
Closed loop, not a replay: when the teeth stray more than ``REPLAN_M`` from where the plan predicted them, the move
is planned again from the state there (at most ``MAX_REPLANS`` times a move). When the plan has run out, the
scripted loader finishes the phase by its own rules (its dump opens the bucket; its dig starts where it sees the
pile). A move whose plan finds no collision-free motion (none deeper than a contact it starts in: a bucket scraping
the ground at the pile's foot) or none that reaches the goal falls back to the scripted loader's move for that
phase and is counted (``fallbacks``). :meth:`episode_figures` gives an episode's plan times and counts.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from hexgym.agents.scripted import LoaderState, ScriptedLoader, load_settings
from hexgym.envs.loading import STEP_PERIOD
from hexgym.machine import parameters as p
from hexgym.machine.names import BUCKET_BODY, GROUND_GEOM
from hexgym.planning.goals import Goal, dump_goal, return_goal
from hexgym.planning.planner import BUDGET, KNOT_S, Plan, knot_means, plan_motion
from hexgym.planning.rollouts import PAIRS, MachineState, RolloutModel

CLEAR_OF_PILE_M = 0.3  # m: a dump is planned once the teeth are this far above the pile's surface ...
CLEAR_OF_GROUND_M = 0.1  # m: ... and the bucket this far above the ground (the rollouts have no digging force)
REPLAN_M = 0.3  # m the teeth may stray from the plan's prediction before the move is planned again
MAX_REPLANS = 2  # plans made again per move at most (then the plan runs out as it is)
HORIZON_S = {"dump": 7.0, "return": 6.0}  # s a plan may take (the scripted moves take 3-6 s out of the pile) ...
MIN_HORIZON_S = 3.0  # s: ... at most 1 s more than the last move of its kind took, and at least this
MOVES = {"to_truck": "dump", "to_pile": "return"}  # the scripted phase a planned move replaces


def out_of_the_pile(env: Any, model: RolloutModel) -> bool:
    """Whether the loaded bucket has left the pile: its teeth ``CLEAR_OF_PILE_M`` above the pile's surface and the
    bucket ``CLEAR_OF_GROUND_M`` above the ground (where a dump's plan starts: the rollouts have no digging force,
    and a move from a contact with the ground could not be clear)."""
    if LoaderState.of(env).above_pile < CLEAR_OF_PILE_M:
        return False
    clearance = model.at_angles(env.physics.joint_positions()[None], env.layout).clearance[0]
    return bool(clearance[PAIRS.index((BUCKET_BODY, GROUND_GEOM))] >= CLEAR_OF_GROUND_M)


class PlanningLoader:
    """The scripted dig with planned dumps and returns (see the module docstring).

    Args:
        budget: rollouts per plan (>= 1).
        settings_path: the scripted loader's settings (JSON; default the hand-set ones).
        seed: the plans' search seed.
    """

    def __init__(self, budget: int = BUDGET, settings_path: str | None = None, seed: int = 0) -> None:
        if isinstance(budget, bool) or not isinstance(budget, int) or budget < 1:
            raise ValueError(f"planner budget must be an integer >= 1 rollouts, got {budget!r}")
        self.budget, self.seed = budget, seed
        self.loader = ScriptedLoader(load_settings(settings_path))
        self._model: RolloutModel | None = None
        self._tables: str | None = None
        self._initial: dict[str, np.ndarray] = {}  # per move, the last one done (knot means): the next search's start
        self._last_s: dict[str, float] = {}  # per move, how long the last one took (s)
        self.reset()

    def reset(self) -> None:
        """Start a new episode: the plans' counts and times start over."""
        self.loader.reset()
        self.plan_walls_s: list[float] = []
        self.fallbacks = self.replans = 0
        self._move: str | None = None  # the move being planned or executed
        self._plan: Plan | None = None
        self._started = 0.0  # env time the plan starts at
        self._replanned = 0
        self._fallen_back = False
        self._done: list[np.ndarray] = []  # the actions of the move under way

    def model(self, env: Any) -> RolloutModel:
        """The rollout model on the environment's learned tables (built on first use)."""
        tables = env.config.tables
        if self._model is None or self._tables != tables:
            self._model, self._tables = RolloutModel(table_set=tables, nthread=2, contacts=False), tables
        return self._model

    def act(self, obs: np.ndarray, env: Any) -> np.ndarray:
        """The planned spools (fractions) while a planned move runs, else the scripted loader's action."""
        env = getattr(env, "unwrapped", env)
        scripted = self.loader.act(env)
        move = self._move_now(env)
        if move != self._move:  # a new phase: the last move's actions start the next search of its kind
            if self._move is not None and self._done:
                self._initial[self._move] = knot_means(np.array(self._done), round(KNOT_S / STEP_PERIOD))
                self._last_s[self._move] = len(self._done) * STEP_PERIOD
            self._move, self._plan, self._replanned, self._fallen_back, self._done = move, None, 0, False, []
        action = scripted if move is None or self._fallen_back else self._planned_action(env, move, scripted)
        if move is not None:
            self._done.append(np.asarray(action, float))
        return action

    def _planned_action(self, env: Any, move: str, scripted: np.ndarray) -> np.ndarray:
        """The plan's action now: planned (again) first where there is none or the machine strayed from it."""
        if self._plan is None or self._strayed(env):
            if self._plan is not None:
                if self._replanned >= MAX_REPLANS:
                    return self._planned(env, scripted)
                self._replanned += 1
                self.replans += 1
            self._make_plan(env, move)
            if self._fallen_back:
                return scripted
        return self._planned(env, scripted)

    def _move_now(self, env: Any) -> str | None:
        """The planned move the scripted phase calls for now (None: the scripted loader's own phase)."""
        move = MOVES.get(self.loader.phase)
        if move == "dump" and self._move != "dump" and not out_of_the_pile(env, self.model(env)):
            return None  # still pulling the bucket out of the pile
        return move

    def _goal(self, env: Any, move: str) -> Goal:
        return dump_goal(env.layout) if move == "dump" else return_goal(env.layout, env.fullest_cut_direction())

    def _make_plan(self, env: Any, move: str) -> None:
        """Plan ``move`` from the environment's state; a plan that is not clear or does not reach the goal falls
        back to the scripted move."""
        start = time.perf_counter()
        state, model = MachineState.from_env(env), self.model(env)
        horizon_s = min(HORIZON_S[move], max(MIN_HORIZON_S, self._last_s.get(move, math.inf) + 1.0))
        plan = plan_motion(state, self._goal(env, move), model, budget=self.budget, horizon_s=horizon_s,
                           seed=self.seed, initial=self._initial.get(move))  # fmt: skip
        self.plan_walls_s.append(time.perf_counter() - start)
        # a move out of a contact (the bucket scraping the ground at the pile's foot) may start there, no deeper
        allowed = min(0.0, float(model.clearance_at(model.initial_state(state)).min()))
        if not (plan.reached and plan.min_clearance_m >= allowed):
            self._fallen_back, self._plan = True, None
            self.fallbacks += 1
            return
        self._plan, self._started = plan, env.elapsed

    def _period_now(self, env: Any) -> int:
        assert self._plan is not None
        return round((env.elapsed - self._started) / self.model(env).control_period)

    def _strayed(self, env: Any) -> bool:
        """Whether the teeth are more than ``REPLAN_M`` from where the plan predicted them now."""
        assert self._plan is not None
        k = self._period_now(env) - 1
        if k < 0 or k >= len(self._plan.tip):
            return False
        return bool(np.linalg.norm(env.physics.tip_position() - self._plan.tip[k]) > REPLAN_M)

    def _planned(self, env: Any, scripted: np.ndarray) -> np.ndarray:
        """The plan's spools at this step's start; the scripted action once the plan has run out."""
        assert self._plan is not None
        k = self._period_now(env)
        if k >= len(self._plan.spools_m):
            return scripted
        return (self._plan.spools_m[k] / p.SPOOL_STROKE).astype(np.float32)

    def episode_figures(self) -> dict[str, Any]:
        """This episode's plans: their wall times (s), how many moves fell back to the scripted loader's, how many
        plans were made again after the machine strayed."""
        return {"plan_walls_s": list(self.plan_walls_s), "fallbacks": self.fallbacks, "replans": self.replans}

    def close(self) -> None:
        """Shut the rollout threads down."""
        if self._model is not None:
            self._model.close()

"""Gymnasium wrappers for ``HexLoading-v0``.

:class:`PreviousActionWrapper` gives a policy its last action. :class:`CollisionShield` simulates each proposed
action on the fast learned model before it is executed (:mod:`hexgym.planning`) and replaces one that would drive
the bucket or the stick hard into the truck or the ground.
"""

from __future__ import annotations

import itertools
import math
import time
from typing import Any

import gymnasium as gym
import numpy as np

from hexgym.envs.loading import STEP_PERIOD
from hexgym.machine import parameters as p
from hexgym.planning.rollouts import MachineState, RolloutModel

# Candidate replacements: the proposed action with each subset of its spools closed (15 non-empty subsets)
_MASKS = np.array([m for m in itertools.product((1.0, 0.0), repeat=4) if 0.0 in m])
CANDIDATE_BATCH = 3  # candidates simulated per batch (fewer: less work when an early one is safe)
DEFAULT_ALLOWED_DEPTH_M = 0.002  # m of predicted penetration tolerated (the env counts hard contact from ~2.5 mm
# on each of a mesh's four contact points: HARD_CONTACT_FORCE / CONTACT_STIFFNESS = 10 mm summed over them)


class CollisionShield(gym.Wrapper):
    """Replace an action that leads to a hard contact of bucket or stick with truck or ground.

    Each step, the proposed action held for one step (0.1 s) and followed by a stop (all spools closed)
    is simulated over ``horizon_s`` on the native learned model from the environment's present state
    (:class:`hexgym.planning.rollouts.RolloutModel`). If its predicted penetration of bucket or stick
    into truck or ground exceeds ``allowed_depth_m`` (or the present one, when already touching: an
    action that does not press deeper is let through), the 15 actions with a subset of its spools
    closed are simulated (a few at a time, in order of their L1 change) and the least-changed one that
    stays within it is executed; if none does, the one that presses least (ties: the least changed).

    ``info`` gains ``shield_intervened`` (bool), ``shield_action`` (the action executed),
    ``shield_min_clearance_m`` (its predicted least clearance; negative = penetration) and
    ``shield_ms`` (the shield's wall time this step).

    What it cannot see: the digging force (the pile is no collision geom: a bucket cutting the pile is
    predicted as if in air) and a payload change within the horizon.

    Args:
        env: a ``HexLoading-v0`` environment (possibly wrapped).
        horizon_s: prediction horizon, s (> 0).
        allowed_depth_m: predicted penetration tolerated, m (>= 0).
    """

    def __init__(self, env: gym.Env, horizon_s: float = 1.5, allowed_depth_m: float = DEFAULT_ALLOWED_DEPTH_M) -> None:
        super().__init__(env)
        if not (isinstance(horizon_s, int | float) and math.isfinite(horizon_s) and horizon_s > 0):
            raise ValueError(f"horizon_s must be finite and > 0, got {horizon_s!r}")
        if horizon_s > 60.0:
            raise ValueError(f"horizon_s must be at most 60 s (a step's prediction), got {horizon_s!r}")
        if not (isinstance(allowed_depth_m, int | float) and math.isfinite(allowed_depth_m) and allowed_depth_m >= 0):
            raise ValueError(f"allowed_depth_m must be finite and >= 0, got {allowed_depth_m!r}")
        if not all(hasattr(env.unwrapped, name) for name in ("physics", "layout", "config")):
            raise TypeError(f"CollisionShield wraps a HexLoading-v0 environment, got {env.unwrapped!r}")
        self.horizon_s, self.allowed_depth_m = float(horizon_s), float(allowed_depth_m)
        self._model: RolloutModel | None = None
        self.interventions = 0
        self.steps = 0
        self.shield_seconds = 0.0

    @property
    def model(self) -> RolloutModel:
        """The rollout model (built on first use, and again after unpickling)."""
        if self._model is None:
            # predicted on the environment's own learned model
            self._model = RolloutModel(table_set=self.env.unwrapped.config.tables)
        return self._model

    def _sequences(self, actions: np.ndarray) -> np.ndarray:
        """(B, T, 4) spools (m) per control period: each action for one step, then closed."""
        model = self.model
        step = max(1, round(STEP_PERIOD / model.control_period))
        periods = max(step, math.ceil(self.horizon_s / model.control_period - 1e-9))
        sequences = np.zeros((len(actions), periods, 4))
        sequences[:, :step] = np.clip(actions, -1.0, 1.0)[:, None, :] * p.SPOOL_STROKE
        return sequences

    def shield(self, action: np.ndarray) -> tuple[np.ndarray, bool, float]:
        """The action to execute instead of ``action``, whether it differs, its predicted least clearance (m)."""
        action = np.asarray(action, dtype=np.float64).reshape(4)
        state = MachineState.from_env(self.env)
        model = self.model
        proposed = model.rollout(state, self._sequences(action[None]), self.horizon_s)
        clearance = float(proposed.min_clearance_m[0])
        if clearance >= -self.allowed_depth_m:
            return action, False, clearance
        allowed = max(self.allowed_depth_m, -float(model.clearance_at(model.initial_state(state)).min()))  # now
        if clearance >= -allowed:
            return action, False, clearance
        # the candidates in order of change, a few per batch: the first safe one is the least changed
        candidates = action[None, :] * _MASKS
        change = np.abs(candidates - action).sum(axis=1)
        order = np.argsort(change, kind="stable")
        candidates, change = candidates[order], change[order]
        depth = np.full(len(candidates), np.inf)
        for start in range(0, len(candidates), CANDIDATE_BATCH):
            chunk = slice(start, start + CANDIDATE_BATCH)
            batch = model.rollout(state, self._sequences(candidates[chunk]), self.horizon_s)
            depth[chunk] = -batch.min_clearance_m
            safe = np.flatnonzero(depth[chunk] <= allowed)
            if len(safe):
                best = start + int(safe[0])
                return candidates[best].astype(np.float32), True, float(-depth[best])
        best = int(np.lexsort((change, depth))[0])  # none stays within: the one that presses least
        return candidates[best].astype(np.float32), True, float(-depth[best])

    def step(self, action: np.ndarray) -> tuple[Any, float, bool, bool, dict]:
        """Shield the action, then step the environment with it."""
        start = time.perf_counter()
        executed, intervened, clearance = self.shield(action)
        elapsed = time.perf_counter() - start
        self.steps += 1
        self.interventions += int(intervened)
        self.shield_seconds += elapsed
        obs, reward, terminated, truncated, info = self.env.step(executed.astype(np.float32) if intervened else action)
        info = {
            **info, "shield_intervened": intervened, "shield_action": np.asarray(executed, np.float32),
            "shield_min_clearance_m": clearance, "shield_ms": elapsed * 1e3,
        }  # fmt: skip
        return obs, reward, terminated, truncated, info

    def close(self) -> None:
        """Close the rollout threads and the environment."""
        if self._model is not None:
            self._model.close()
        super().close()

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_model"] = None
        return state


class PreviousActionWrapper(gym.Wrapper):
    """Appends the previous action (4 spools, zeros after a reset) to the observation.

    For policies that need a memory of what they were doing (rl-zoo3: ``env_wrapper:
    hexgym.wrappers.PreviousActionWrapper``). The shipped PPO settings do not use it: the scripted loader acts on
    the state alone, and clones given their last action tended to repeat it.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        space = env.observation_space
        n = env.action_space.shape[0]
        low = np.concatenate([space.low, -np.ones(n, np.float32)])
        high = np.concatenate([space.high, np.ones(n, np.float32)])
        self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)
        self._zeros = np.zeros(n, np.float32)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        obs, info = self.env.reset(**kwargs)
        return np.concatenate([obs, self._zeros]), info

    def step(self, action: np.ndarray) -> tuple:
        obs, reward, terminated, truncated, info = self.env.step(action)
        executed = np.clip(np.asarray(action, np.float32), -1.0, 1.0)
        return np.concatenate([obs, executed]), reward, terminated, truncated, info

"""``HexReach-v0``: bring the bucket teeth to a target point through the machine's hydraulics.

The first rung of hexgym's tasks for learning: no pile, no truck, only the learned machine model
(the same as ``HexLoading-v0``'s) with a random payload, so an agent learns how the four spools move
the teeth — flow sharing on each pump, the engine's power limit, the swing's inertia and braking —
before it learns to dig and load.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from hexgym.envs import REACH_ENV_ID
from hexgym.envs.base import check_open, is_number, make_config, spools_from_action
from hexgym.envs.task import STEP_PERIOD  # 10 Hz control, as HexLoading-v0
from hexgym.machine import kinematics
from hexgym.mbl.schema import DEFAULT_TABLE_SET
from hexgym.mbl.table import resolve_tables
from hexgym.model.backend import make_learned_model

TARGET_FLOOR_M = 0.5  # targets and starts keep the teeth this high above the ground
MIN_TARGET_DISTANCE_M = 2.0  # a target at least this far from the start
MAX_PAYLOAD_KG = 2000.0
SETTLED_SPEED_MPS = 0.3  # the teeth count as arrived when slower than this within the tolerance
_START_NOISE = 0.3  # rad, on boom, stick and bucket around the machine's `home` keyframe
_OBS_BOUND = np.array(
    [np.pi] * 3 + [1.0] * 2 + [10.0] * 4 + [10.0] * 3 + [30.0] * 3 + [30.0] * 2 + [1.0, 5.0], dtype=np.float32
)


@dataclass(frozen=True)
class ReachConfig:
    """``HexReach-v0``'s configuration (see :class:`HexReachEnv`'s Arguments). Frozen; checked once when made.

    No site, so not a :class:`hexgym.envs.base.SiteConfig`: the machine alone, on the learned model's own scene.
    """

    time_limit: float = 15.0
    tolerance_m: float = 0.3
    progress_weight: float = 1.0
    time_weight: float = 0.01
    success_reward: float = 5.0
    backend: str = "auto"
    tables: str = DEFAULT_TABLE_SET
    render_mode: str | None = None

    def __post_init__(self) -> None:
        if self.render_mode is not None:
            raise ValueError(f"HexReach-v0 does not render (render_mode {self.render_mode!r}): render HexLoading-v0")
        for name in ("time_limit", "tolerance_m"):
            value = getattr(self, name)
            if not is_number(value) or not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
            object.__setattr__(self, name, float(value))  # (frozen: stored once, as checked)
        for term, weight in self.weights.items():
            if not is_number(weight) or not (math.isfinite(weight) and weight >= 0):
                raise ValueError(f"{term} weight must be a finite number >= 0, got {weight!r}")
        resolve_tables(self.tables)  # a set's name or a fitted model's directory; else refused in one line

    @property
    def weights(self) -> dict[str, float]:
        """The weights of the terms ``progress``, ``time``, ``success``."""
        return {"progress": self.progress_weight, "time": self.time_weight, "success": self.success_reward}


class HexReachEnv(gym.Env):
    """Bring the bucket teeth within ``tolerance_m`` of a target point and hold them there.

    ## Description
    The machine (the learned model of a CAT 325-class excavator) starts at rest near its home pose
    with a random payload in the bucket (0-2 t) and its swing anywhere; a target point is drawn in
    its reach, at least 2 m from the teeth, 0.5 m or more above the ground, within ±90° of swing.
    Reaching it fast needs the hydraulics' interactions: two functions on one pump share its flow,
    the pumps share the engine's power, the upper structure's inertia must be braked in time.

    ## Action Space
    ``Box(-1, 1, (4,), float32)``: the swing, boom, stick and bucket spools as fractions of their
    stroke (±11 mm; positive extends the cylinder, turns the swing counter-clockwise), held 0.1 s.

    ## Observation Space
    ``Box(low, high, (19,), float32)``:

    | Num | Observation | Unit |
    |-----|-------------|------|
    | 0-2 | boom, stick, bucket joint angles | rad |
    | 3-4 | sine and cosine of the swing angle minus the target's azimuth | 1 |
    | 5-8 | swing, boom, stick, bucket joint rates | rad/s |
    | 9-11 | boom, stick, bucket cylinder force loads (+ = the cylinder pushes) | MN |
    | 12-14 | teeth minus target, world frame | m |
    | 15-16 | target's horizontal distance from the swing axis and its height | m |
    | 17 | time left: fraction of the time budget | 1 |
    | 18 | payload | t |

    ## Rewards
    Per step: ``progress_weight`` × metres the teeth came closer to the target, − ``time_weight``,
    and ``success_reward`` on arrival (teeth within ``tolerance_m`` and slower than 0.3 m/s). The
    progress term is potential-based shaping: over an episode it sums to the distance covered, so it
    cannot be farmed by moving back and forth. ``info`` has each term (``reward_progress``,
    ``reward_time``, ``reward_success``), ``distance_m`` and ``is_success`` (SB3's success counter).

    ## Episode End
    Terminates on arrival; truncates after ``time_limit`` s.

    ## Arguments
    Keyword arguments (``gymnasium.make("HexReach-v0", **kwargs)``) or a :class:`ReachConfig` with overrides:

    | argument | default | meaning |
    |----------|---------|---------|
    | time_limit | 15.0 | episode length, s |
    | tolerance_m | 0.3 | arrival radius, m |
    | progress_weight | 1.0 | per metre closer |
    | time_weight | 0.01 | per step |
    | success_reward | 5.0 | on arrival |
    | backend | ``"auto"`` | the learned model's backend: ``"native"``, ``"python"``, ``"auto"`` |
    | tables | ``"circuit"`` | the learned model's table set (:mod:`hexgym.mbl.schema`) or a fitted model's directory |

    No rendering (``render_mode`` None only): render ``HexLoading-v0`` to watch the machine.
    """

    metadata = {"render_modes": [], "render_fps": round(1.0 / STEP_PERIOD)}
    closed = False  # set by close()

    def __init__(self, config: ReachConfig | None = None, **overrides: Any) -> None:
        self.config = c = make_config(ReachConfig, REACH_ENV_ID, config, overrides)
        self.render_mode = None
        table_set, tables_dir = resolve_tables(c.tables)
        self.machine = make_learned_model(c.backend, tables_dir=tables_dir, table_set=table_set)
        self.physics = self.machine.physics
        self.machine.reset("home")
        self._home = self.physics.joint_positions()
        self._periods = max(1, round(STEP_PERIOD / self.machine.control_period))
        self._step_s = self._periods * self.machine.control_period  # what a step advances, s
        self.observation_space = spaces.Box(-_OBS_BOUND, _OBS_BOUND, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (4,), np.float32)
        self.target = np.zeros(3)
        self._distance, self._elapsed = 0.0, 0.0

    @property
    def time_limit(self) -> float:
        """Episode length, s."""
        return self.config.time_limit

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """A new start pose, payload and target (see the class docstring)."""
        check_open(REACH_ENV_ID, self.closed)
        super().reset(seed=seed)
        rng = self.np_random
        start = self._draw_pose(rng, self._home, _START_NOISE, math.pi)
        payload = float(rng.uniform(0.0, MAX_PAYLOAD_KG))
        self.machine.reset(start, payload_kg=payload)
        tip = self.physics.tip_position()
        while True:  # a reachable target: the teeth of a random pose, far enough from the start
            pose = self._draw_pose(rng, None, 0.0, math.pi / 2, start[0])
            self.target = kinematics.tip_position(pose)
            if np.linalg.norm(self.target - tip) >= MIN_TARGET_DISTANCE_M:
                break
        self._distance, self._elapsed = float(np.linalg.norm(tip - self.target)), 0.0
        return self._observe(), self._info(0.0, 0.0, 0.0, False)

    @staticmethod
    def _draw_pose(
        rng: np.random.Generator, centre: np.ndarray | None, noise: float, swing_span: float, swing_centre: float = 0.0
    ) -> np.ndarray:
        """Joint angles with the teeth ``TARGET_FLOOR_M`` or more above the ground: around ``centre``
        (± ``noise``) or, without one, anywhere in the inner 80 % of each joint's range."""
        while True:
            q = np.empty(4)
            q[0] = swing_centre + rng.uniform(-swing_span, swing_span)
            for i, name in enumerate(kinematics.JOINTS[1:], start=1):
                lo, hi = kinematics.joint_range(name)
                if centre is None:
                    q[i] = rng.uniform(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo))
                else:
                    q[i] = np.clip(centre[i] + rng.uniform(-noise, noise), lo, hi)
            if kinematics.tip_position(q)[2] >= TARGET_FLOOR_M:
                return q

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Hold the spools for 0.1 s."""
        check_open(REACH_ENV_ID, self.closed)
        spools = spools_from_action(action)
        before = self.physics.tip_position()
        self.machine.step(spools, n=self._periods)
        self._elapsed += self._step_s
        tip = self.physics.tip_position()
        distance = float(np.linalg.norm(tip - self.target))
        speed = float(np.linalg.norm(tip - before)) / self._step_s
        c = self.config
        arrived = distance <= c.tolerance_m and speed < SETTLED_SPEED_MPS
        progress = c.progress_weight * (self._distance - distance)
        success = c.success_reward if arrived else 0.0
        time_term = -c.time_weight
        self._distance = distance
        truncated = not arrived and self._elapsed >= c.time_limit - 1e-9
        return (
            self._observe(),
            progress + time_term + success,
            arrived,
            truncated,
            self._info(progress, time_term, success, arrived),
        )

    def close(self) -> None:
        """Nothing to release; ``step`` and ``reset`` are refused after it (closing again is harmless)."""
        self.closed = True

    def _observe(self) -> np.ndarray:
        ph = self.physics
        q, qd = ph.joint_positions(), ph.joint_velocities()
        azimuth = math.atan2(self.target[1], self.target[0])
        obs = np.concatenate((
            q[1:], [math.sin(q[0] - azimuth), math.cos(q[0] - azimuth)], qd,
            self.machine.cylinder_loads() / 1e6, ph.tip_position() - self.target,
            [math.hypot(self.target[0], self.target[1]), self.target[2]],
            [max(0.0, 1.0 - self._elapsed / self.config.time_limit), ph.payload_kg / 1000.0],
        ))  # fmt: skip
        return np.clip(obs, -_OBS_BOUND, _OBS_BOUND).astype(np.float32)

    def _info(self, progress: float, time_term: float, success: float, arrived: bool) -> dict[str, Any]:
        return {
            "reward_progress": progress, "reward_time": time_term, "reward_success": success,
            "distance_m": self._distance, "is_success": bool(arrived), "time_s": self._elapsed,
        }  # fmt: skip

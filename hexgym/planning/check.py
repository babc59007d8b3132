"""Checking a plan on the accurate model before it is executed: the paper's predictive simulation, at two fidelities.

The planner searches thousands of candidates on the fast native model, whose paper tables miss how the
hydraulic functions share the pumps: a loaded boom rising while the swing turns comes up slower on the
machine than the tables say, and a plan with 0.2 m of predicted clearance meets the truck's wall. The
circuit model (:mod:`hexgym.model.circuit_model`: the open-centre circuit with the learned valve) follows
the reference within centimetres but runs in Python, ~200x real time: too slow to search with, fast
enough to check one plan (a 4 s move in ~30 ms). :class:`PlanCheck` replays a plan's spools on it from
the plan's start state and measures it on the site's geometry as the planner does: the least clearance
of bucket and stick to truck and ground, the goal error where the machine comes to rest, the time to
the goal.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import numpy as np

from hexgym.model.backend import python_learned_model
from hexgym.model.commandlog import CommandLog
from hexgym.model.replay import replay
from hexgym.planning.rollouts import MachineState, RolloutModel

if TYPE_CHECKING:
    from hexgym.planning.planner import Goal

SETTLE_S = 1.5  # s the check runs on with the spools closed after the plan (the swing coasts to rest)
ROW_S = 0.05  # s between the check's rows (two control periods)


@dataclasses.dataclass(frozen=True)
class CheckResult:
    """A plan replayed on the circuit model: ``min_clearance_m`` (negative = contact) to the plan's end,
    ``goal_error_m`` where it comes to rest, ``time_s`` to the goal with the swing at rest (None: never)."""

    min_clearance_m: float
    goal_error_m: float
    time_s: float | None

    @property
    def collision_free(self) -> bool:
        """Whether bucket and stick stay clear of truck and ground."""
        return self.min_clearance_m >= 0.0


class PlanCheck:
    """Replays plans on the circuit model, measured on the site by ``model``'s geometry (``at_angles``)."""

    def __init__(self, model: RolloutModel) -> None:
        self.model = model
        self.machine = python_learned_model("circuit")

    def __call__(self, spools_m: np.ndarray, state: MachineState, goal: Goal) -> CheckResult:
        """The plan's spools (T, 4) per control period from ``state`` (at rest), then ``SETTLE_S`` closed, towards
        ``goal``."""
        period = self.model.control_period
        n = len(spools_m)
        t = np.arange(n + 1) * period
        log = CommandLog(t, np.vstack([np.asarray(spools_m) * 1e3, np.zeros((1, 4))]))
        planned = math.ceil(n * period / ROW_S - 1e-9)  # rows to the plan's end
        rows = replay(self.machine, log, start=state.q, payload_kg=state.payload_kg, dt_out=ROW_S,
                      duration=(planned + round(SETTLE_S / ROW_S)) * ROW_S)  # fmt: skip
        q = np.column_stack([rows[f"q_{j}"] for j in ("swing", "boom", "stick", "bucket")])
        tips, mouths, clearance = self.model.at_angles(q, state.layout)
        error = goal.error_m(mouths, tips)
        at = (error <= (0.0 if goal.task == "dump" else goal.tolerance_m)) & (np.abs(rows["qd_swing"]) < 0.1)
        return CheckResult(
            min_clearance_m=float(clearance[: planned + 1].min()),
            goal_error_m=float(error[-1]),
            time_s=float(rows["t"][np.argmax(at)]) if at.any() else None,
        )

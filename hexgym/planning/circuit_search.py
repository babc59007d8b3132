"""Searching a plan on the circuit model itself: offline plans, where the 2 s budget does not apply.

The fast native model misses how the hydraulic functions share the pumps (a loaded boom lifts more slowly on the
machine while the swing turns), so a plan searched on it keeps a wide margin from truck and ground (0.8 m loaded)
and is checked and trimmed on the circuit model afterwards (:mod:`hexgym.planning.check`). A plan made ahead of
time (a site's loading cycle, computed once and executed many times, as the paper's optimal motions are) can
search on the circuit model directly: :class:`CircuitRolloutModel` gives the planner the circuit model's rollouts,
each candidate replayed in Python (~25 ms for a 5 s move: 2,000 candidates in about a minute on one core),
measured on the site's geometry as the native rollouts are, with the fuel the circuit's pumps draw. Its error is
centimetres, so the plan keeps ``CIRCUIT_MARGIN_M`` instead of the fast model's margins.
"""

from __future__ import annotations

import math

import numpy as np

from hexgym.envs.world import Layout
from hexgym.machine import kinematics
from hexgym.model.backend import python_learned_model
from hexgym.model.base import MachineModel
from hexgym.model.replay import replay
from hexgym.parallel import LocalPool
from hexgym.planning.check import plan_log
from hexgym.planning.rollouts import MachineState, RolloutBatch, RolloutModel, SitePoses, spool_batch

CIRCUIT_MARGIN_M = 0.2  # m kept from truck and ground: the circuit model follows the reference within ~0.1 m
REST_RATE = 1e-6  # rad/s: a start state faster than this is not at rest (a replay starts from rest)


class CircuitRolloutModel:
    """The planner's rollouts on the circuit model (see the module docstring): :meth:`rollout` as
    :meth:`RolloutModel.rollout`, from a state at rest. ``geometry``: the native site model whose geometry measures
    the replays (teeth, mouth, tilt, clearances) and whose control period they use; ``machine``: the circuit model
    to replay on (default: a new one); ``workers``: processes a batch's candidates are split over (each with its own
    circuit model and site geometry; the same figures to the digit). :meth:`close` ends them."""

    def __init__(self, geometry: RolloutModel, machine: MachineModel | None = None, workers: int = 1) -> None:
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
        self.geometry = geometry
        self.machine = python_learned_model("circuit") if machine is None else machine
        self.control_period = geometry.control_period
        self.detection_m = geometry.detection_m
        self.workers = workers
        self._pool: LocalPool | None = None

    def rollout(self, state: MachineState, spools_m: np.ndarray, horizon_s: float) -> RolloutBatch:
        """Replay each spool sequence (see :func:`~hexgym.planning.rollouts.spool_batch`) from ``state`` for
        ``horizon_s`` seconds: the state at the end of each control period, and the engine's fuel rate there."""
        if np.abs(state.qd).max() > REST_RATE:
            raise ValueError(f"the circuit model's rollouts start at rest; the state's rates are {state.qd.round(4)}")
        spools = spool_batch(spools_m, horizon_s, self.control_period)
        nbatch, periods = spools.shape[:2]
        if self.workers > 1 and nbatch >= 2 * self.workers:
            if self._pool is None:
                self._pool = LocalPool(self.workers, _start_worker, (self.geometry.table_set, self.detection_m))
            chunks = np.array_split(spools, self.workers)
            parts = self._pool.map(_worker_replays, [(state, chunk) for chunk in chunks])
            figures = {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}
        else:
            figures = _replays(self.machine, self.geometry, state, spools)
        return RolloutBatch(
            (np.arange(periods) + 1) * self.control_period, figures["q"], figures["tip"], figures["clearance"],
            np.empty((nbatch, periods, 0)), self.detection_m, figures["qd"], figures["mouth"], figures["tilt"],
            np.full((nbatch, periods), math.nan), figures["fuel"],
        )  # fmt: skip

    def at_angles(self, q: np.ndarray, layout: Layout) -> SitePoses:
        """:meth:`RolloutModel.at_angles` of the site's geometry."""
        return self.geometry.at_angles(q, layout)

    def close(self) -> None:
        """End the worker processes (if any)."""
        if self._pool is not None:
            self._pool.close()
            self._pool = None


def _replays(machine: MachineModel, geometry: RolloutModel, state: MachineState, spools: np.ndarray) -> dict:
    """The circuit model's replays of spools (B, T, 4) from ``state``, measured on ``geometry``: per candidate and
    control period its joint angles and rates, fuel rate, teeth, mouth, clearances and tilt."""
    nbatch, periods = spools.shape[:2]
    period = geometry.control_period
    q, qd = np.empty((nbatch, periods, 4)), np.empty((nbatch, periods, 4))
    fuel = np.empty((nbatch, periods))
    for b in range(nbatch):  # each replay's rows at the end of each period (its first row is the start)
        rows = replay(machine, plan_log(spools[b], period), start=state.q, payload_kg=state.payload_kg,
                      dt_out=period, duration=periods * period)[1:]  # fmt: skip
        q[b] = np.column_stack([rows[f"q_{j}_rad"] for j in kinematics.JOINTS])
        qd[b] = np.column_stack([rows[f"qd_{j}_radps"] for j in kinematics.JOINTS])
        fuel[b] = rows["fuel_rate_l_per_h"]
    poses = geometry.at_angles(q.reshape(-1, 4), state.layout)
    return {
        "q": q, "qd": qd, "fuel": fuel, "tip": poses.tip.reshape(nbatch, periods, 3),
        "mouth": poses.mouth.reshape(nbatch, periods, 3), "clearance": poses.clearance.reshape(nbatch, periods, -1),
        "tilt": poses.tilt.reshape(nbatch, periods),
    }  # fmt: skip


_WORKER: tuple[MachineModel, RolloutModel] | None = None  # a worker process's circuit model and site geometry


def _start_worker(table_set: str, detection_m: float) -> None:
    global _WORKER
    _WORKER = (python_learned_model("circuit"), RolloutModel(table_set, detection_m=detection_m, contacts=False))


def _worker_replays(job: tuple[MachineState, np.ndarray]) -> dict:
    assert _WORKER is not None, "the worker was not started"
    return _replays(*_WORKER, *job)

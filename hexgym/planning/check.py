"""Checking a plan on the circuit model in Python before it is executed: where it comes to rest, what it touches.

The planner's candidates are the native rollouts' (by default the circuit model's law, batched). A plan is
searched to the moment it reaches its goal, at 0.5 s knots; :class:`PlanCheck` replays its spools on the circuit
model (:mod:`hexgym.model.circuit_model`) from the plan's start state, at rest, and runs on ``SETTLE_S`` with the
spools closed, measuring it on the site's geometry as the planner does: the least clearance of bucket and stick to
truck and ground, the goal error where the machine comes to rest, the time from which it stays at the goal, the
fuel (a 4-5 s move in 33-38 ms). :meth:`PlanCheck.correct` trims a plan so that the machine comes to rest at the
goal, :meth:`PlanCheck.fit_swing` fits a fastest turn's switch. On the selection seeds the check, trims and mends
take a return's goal error within 0.3 m on 10 of 10 against 5 of 10 without (docs/planning.md); on dumps the
plans without them were as good.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.model.backend import python_learned_model
from hexgym.model.commandlog import CommandLog
from hexgym.model.replay import replay
from hexgym.planning.rollouts import MachineState, RolloutModel, bang_bang, off_the_toe

if TYPE_CHECKING:
    from hexgym.model.base import MachineModel
    from hexgym.planning.goals import Goal

TRIM_S = 1.5  # s: the plan's last stretch whose spools a correction offsets
TRIM_PROBE = 0.25  # spool fraction each joint's offset is probed with (beyond the valves' dead bands)
TRIM_ITERATIONS = 6  # Newton steps at most after the probes (each one replay)
TRIM_CLOSE_M = 0.1  # m: a correction ending this close to the point stops
TRIM_INSET_M = 0.3  # m: a dump is aimed this far inside its box (the circuit-reference gap: up to ~0.3 m)
TRIM_MAX_STEP = 0.6  # spool fraction a Newton step changes an offset by at most
SETTLE_S = 1.5  # s a replay runs on with the spools closed after the plan (the swing coasts to rest)
FIT_TAIL_S = 0.5  # s a plan with a fitted swing runs on after its end (see PlanCheck.fit_swing)
SWING_STOPPED = 0.02  # rad/s: a braking swing this slow has stopped
FIT_FROM = (0, 4)  # control periods after the rollouts' switch: the circuit model's first two tried
FIT_REPLAYS = 6  # circuit replays a swing's fit makes at most
ROW_S = 0.05  # s between a replay's rows (two control periods, and a multiple of the reference's 2 ms step)
# m: the clearance a plan keeps on the circuit model to count as clear of truck and ground: the circuit model's
# clearances were within 0.034 m of the reference's on the selection seeds' checked plans (20-29, dumps and returns)
CHECK_MARGIN_M = 0.05
STOP_TOLERANCE_M = 0.005  # m from a stroke end: a cylinder there is at its stop (its cushion's last millimetres)


@dataclasses.dataclass(frozen=True)
class PlanReplay:
    """A plan's spools replayed on a machine model: its ``rows`` (:func:`hexgym.model.replay.replay`), the teeth
    and the mouth's centre (N, 3), the pairs' ``clearance`` (N, 4, m) and the goal ``error`` (N, m) per row, ``at``
    (N,): at the goal with the swing at rest, and ``planned``: the row of the plan's end."""

    rows: np.ndarray
    tips: np.ndarray
    mouths: np.ndarray
    clearance: np.ndarray
    error: np.ndarray
    at: np.ndarray
    planned: int

    @property
    def time_s(self) -> float | None:
        """The time from which the machine stays at the goal with the swing at rest to the replay's end (None: it
        does not end there; a move that passes through the goal and comes to rest beyond it has not reached it)."""
        stays = np.logical_and.accumulate(self.at[::-1])[::-1]  # at the goal from each row on
        return float(self.rows["t"][np.argmax(stays)]) if stays[-1] else None

    @property
    def fuel_l(self) -> float | None:
        """Diesel (L) to the plan's end, from the rows' fuel rate (None: a model that reports none)."""
        if "fuel_rate_l_per_h" not in self.rows.dtype.names:
            return None
        return float(np.sum(self.rows["fuel_rate_l_per_h"][1 : self.planned + 1]) * ROW_S / 3600.0)


def plan_log(spools_m: np.ndarray, period: float) -> CommandLog:
    """A plan's spools (T, 4, m) held one control period ``period`` each, then closed, as a command log (mm)."""
    return CommandLog(np.arange(len(spools_m) + 1) * period, np.vstack([np.asarray(spools_m) * 1e3, np.zeros((1, 4))]))


def replay_plan(
    machine: MachineModel, spools_m: np.ndarray, state: MachineState, goal: Goal, model: RolloutModel
) -> PlanReplay:
    """The plan's spools (T, 4) per control period on ``machine`` from ``state`` (at rest), then ``SETTLE_S`` with
    the spools closed, measured on the site by ``model``'s geometry (:meth:`RolloutModel.at_angles`)."""
    period = model.control_period
    n = len(spools_m)
    log = plan_log(spools_m, period)
    planned = math.ceil(n * period / ROW_S - 1e-9)  # rows to the plan's end
    rows = replay(machine, log, start=state.q, payload_kg=state.payload_kg, dt_out=ROW_S,
                  duration=(planned + round(SETTLE_S / ROW_S)) * ROW_S)  # fmt: skip
    q = np.column_stack([rows[f"q_{j}_rad"] for j in ("swing", "boom", "stick", "bucket")])
    poses = model.at_angles(q, state.layout)
    error = goal.error_m(poses.mouth, poses.tip)
    at = (error <= (0.0 if goal.task == "dump" else goal.tolerance_m)) & (np.abs(rows["qd_swing_radps"]) < 0.1)
    return PlanReplay(rows, poses.tip, poses.mouth, poses.clearance, error, at, planned)


def release_at_stops(spools_m: np.ndarray, run: PlanReplay, period: float) -> np.ndarray:
    """The plan's spools (T, 4) with each front spool closed in the control periods where the replay ``run``
    finds its cylinder at a stroke end (within ``STOP_TOLERANCE_M``) and the spool driving it further in: there
    the pump's flow can only go over the relief, at full pressure (a loaded bucket held curled at its stop
    kept pump 1 at 35 MPa for a second). The cylinder stays where it is (its oil is locked in); the pump's flow
    goes to the functions still moving, or back through the open centre. Returns ``spools_m`` itself when no
    spool drives a cylinder into its stop."""
    spools = np.asarray(spools_m)
    rows = np.minimum(np.arange(len(spools)) * period / ROW_S + 1e-9, len(run.rows) - 1).astype(int)
    out = spools.copy()
    for col, name in enumerate(kinematics.FRONT_CYLINDERS, start=1):  # spool columns 1-3 (swing is column 0)
        extension = run.rows[f"{name}_extension_m"][rows]
        pushing_out = (extension >= p.CYLINDERS[name].stroke - STOP_TOLERANCE_M) & (spools[:, col] > p.SPOOL_DEAD_BAND)
        pulling_in = (extension <= STOP_TOLERANCE_M) & (spools[:, col] < -p.SPOOL_DEAD_BAND)
        out[pushing_out | pulling_in, col] = 0.0
    return spools if np.array_equal(out, spools) else out


@dataclasses.dataclass(frozen=True)
class CheckResult:
    """A plan replayed on the circuit model: ``min_clearance_m`` (negative = contact) until it comes to rest,
    ``goal_error_m`` where it does, ``time_s`` to the goal with the swing at rest (None: never), ``fuel_l`` to the
    plan's end (from the circuit's pump pressures and flows, as the reference accounts it); ``replay``: the
    replay itself (not compared), which :meth:`PlanCheck.correct` starts from."""

    min_clearance_m: float
    goal_error_m: float
    time_s: float | None
    fuel_l: float | None = None
    replay: PlanReplay | None = dataclasses.field(default=None, compare=False, repr=False)

    @property
    def collision_free(self) -> bool:
        """Whether bucket and stick stay off truck and ground on the accurate model."""
        return self.min_clearance_m >= 0.0

    @property
    def clear(self) -> bool:
        """Whether bucket and stick keep :data:`CHECK_MARGIN_M` from truck and ground on the accurate model (what
        the machine it stands for needs to stay off them)."""
        return self.min_clearance_m >= CHECK_MARGIN_M

    @property
    def message(self) -> str:
        """What the check found, in words (a plan that touches truck or ground on the accurate model says so)."""
        if not self.collision_free:
            return (f"no collision-free motion found: on the accurate model the plan's clearance is "
                    f"{self.min_clearance_m:.3f} m")  # fmt: skip
        if not self.clear:
            return (f"no motion found that stays {CHECK_MARGIN_M} m clear: on the accurate model the plan's "
                    f"clearance is {self.min_clearance_m:.3f} m")  # fmt: skip
        if self.time_s is None:
            return f"on the accurate model the plan comes to rest {self.goal_error_m:.2f} m from the goal"
        return f"on the accurate model: at the goal in {self.time_s:.2f} s, clearance {self.min_clearance_m:.2f} m"


def _result(run: PlanReplay) -> CheckResult:
    """A replay's check: clearance until it comes to rest (the swing coasts on after the plan), goal error there,
    time to the goal."""
    return CheckResult(
        min_clearance_m=float(run.clearance.min()), goal_error_m=float(run.error[-1]), time_s=run.time_s,
        fuel_l=run.fuel_l, replay=run,
    )  # fmt: skip


class PlanCheck:
    """Replays plans on the circuit model, measured on the site by ``model``'s geometry (:func:`replay_plan`)."""

    def __init__(self, model: RolloutModel) -> None:
        self.model = model
        self.machine = python_learned_model("circuit")
        # one period now: its compiled steps load from numba's disk cache (or compile, ~10 s, on a fresh install)
        # here rather than within the first plan's time
        self.machine.reset()
        self.machine.step(np.zeros(4))

    def __call__(self, spools_m: np.ndarray, state: MachineState, goal: Goal) -> CheckResult:
        """The plan's spools (T, 4) per control period from ``state`` (at rest), then ``SETTLE_S`` closed, towards
        ``goal``."""
        return _result(replay_plan(self.machine, spools_m, state, goal, self.model))

    def fit_swing(self, spools_m: np.ndarray, state: MachineState, target_rad: float, near: int) -> np.ndarray:
        """The plan's spools (T, 4) with the swing's replaced by the circuit model's quickest swing to ``target_rad``
        under the plan's other spools: full spool, then closed (the crossover reliefs brake it; a full counter-spool
        stops it barely sooner, with the pump at full pressure and more fuel). The switch (a control period) is
        found by the secant method on where the swing stops, from two switches ``FIT_FROM`` periods after ``near``
        (the rollouts' switch for the swing alone: the plan's other spools share the pumps with it); of the switches
        tried (at most ``FIT_REPLAYS``), the one that stops the swing nearest the target. It runs on
        ``FIT_TAIL_S`` with the other spools closed after the plan's end or the swing's stop, whichever is later:
        time for :meth:`correct` to finish the front."""
        sign = 1.0 if target_rad >= state.q[0] else -1.0
        period = self.model.control_period
        spools = np.vstack([spools_m, np.zeros((round(SETTLE_S / period), 4))])
        tried: dict[int, tuple[float, int]] = {}

        def miss(switch: int) -> float:
            """How far (rad, signed towards the turn) past the target the swing stops with this switch."""
            if switch not in tried:
                tried[switch] = self._swing_stop(spools, state, sign, switch)
            return sign * (tried[switch][0] - target_rad)

        last = len(spools) - 1
        a, b = (min(max(near + k, 1), last) for k in FIT_FROM)
        for _ in range(FIT_REPLAYS - 2):
            fa, fb = miss(a), miss(b)
            if fa == fb or not math.isfinite(fa - fb):
                break
            guess = min(max(round(b - fb * (b - a) / (fb - fa)), 1), last)
            if guess in tried:
                break
            a, b = b, guess
        miss(b)
        switch = min(tried, key=lambda k: abs(tried[k][0] - target_rad))
        end = tried[switch][1]
        out = spools[: min(len(spools), max(len(spools_m), end + 1) + round(FIT_TAIL_S / period))].copy()
        out[:, 0] = bang_bang(sign, switch, switch, len(out))
        return out

    def _swing_stop(self, spools: np.ndarray, state: MachineState, sign: float, switch: int) -> tuple[float, int]:
        """Where (rad) and when (period) the circuit model's swing stops under ``spools`` (T, 4) with the swing full
        towards ``sign`` until ``switch``, then closed (the swing still turning at the end: its last angle, then).
        Replayed to twice the switch and 1 s first (a braking swing has stopped by then), to the end if not."""
        period = self.model.control_period
        trial = spools.copy()
        trial[:, 0] = bang_bang(sign, switch, switch, len(trial))
        log = plan_log(trial, period)
        first = math.ceil(switch * period / ROW_S)
        for rows_to in (min(2 * first + round(1.0 / ROW_S), len(trial) * period / ROW_S), len(trial) * period / ROW_S):
            rows = replay(self.machine, log, start=state.q, payload_kg=state.payload_kg, dt_out=ROW_S,
                          duration=math.floor(rows_to) * ROW_S)  # fmt: skip
            stopped = np.nonzero(sign * rows["qd_swing_radps"][first:] <= SWING_STOPPED)[0]
            if len(stopped):
                row = first + stopped[0]
                return float(rows["q_swing_rad"][row]), round(rows["t"][row] / period)
        return float(rows["q_swing_rad"][-1]), len(trial)

    def correct(
        self, spools_m: np.ndarray, state: MachineState, goal: Goal, checked: CheckResult | None = None
    ) -> tuple[np.ndarray, CheckResult, int]:
        """The plan's spools trimmed so that on the circuit model the machine comes to rest at the goal: the teeth at a
        point goal's point, the mouth ``TRIM_INSET_M`` inside a dump goal's box (so that the machine it stands for,
        centimetres away, is inside too). One offset per joint is added to the spools of the plan's last ``TRIM_S``,
        found by Newton's method on the replays (least-norm steps: three coordinates, four offsets; the offsets' effect
        probed on the fast model in one batch, then updated by Broyden's rule). Returns the best spools found
        (:data:`CHECK_MARGIN_M` clear of truck and ground until the machine rests first; of the others, the least short
        of it to the centimetre; then the closest; ``spools_m`` itself when none ranks better), their check and the
        replays made. ``checked``: the check of ``spools_m`` already made (its replay is not made again)."""
        window = min(len(spools_m), round(TRIM_S / self.model.control_period))
        inset = TRIM_INSET_M if goal.task == "dump" else 0.0

        def trimmed(offsets: np.ndarray) -> np.ndarray:
            out = np.array(spools_m, float)
            trim = np.clip(out[-window:] + offsets * p.SPOOL_STROKE, -p.SPOOL_STROKE, p.SPOOL_STROKE)
            out[-window:] = off_the_toe(trim)  # no trim into a valve's toe
            return out

        def replayed(offsets: np.ndarray) -> tuple[np.ndarray, PlanReplay]:
            run = replay_plan(self.machine, trimmed(offsets), state, goal, self.model)
            return goal.miss(run.mouths[-1], run.tips[-1], inset), run

        def rank(run: PlanReplay, residual: np.ndarray) -> tuple[bool, float, float]:
            """Clear first; too close, less short of the margin to the centimetre first; then closer to the aim."""
            short = max(CHECK_MARGIN_M - float(run.clearance.min()), 0.0)
            return (short > 0.0, round(short, 2), float(np.linalg.norm(residual)))

        offsets = np.zeros(4)
        if checked is not None and checked.replay is not None:
            base, replays = checked.replay, 0
            residual = goal.miss(base.mouths[-1], base.tips[-1], inset)
        else:
            (residual, base), replays = replayed(offsets), 1
        best, best_run, best_rank = spools_m, base, rank(base, residual)
        jacobian = None
        for _ in range(TRIM_ITERATIONS):
            if np.linalg.norm(residual) < TRIM_CLOSE_M:
                break
            if jacobian is None:
                jacobian = self._fast_jacobian(trimmed, state, goal)
            step = np.clip(-np.linalg.lstsq(jacobian, residual, rcond=1e-3)[0], -TRIM_MAX_STEP, TRIM_MAX_STEP)
            new_offsets = np.clip(offsets + step, -2.0, 2.0)  # beyond +-2 every spool is at its stop either way
            new_residual, run = replayed(new_offsets)
            replays += 1
            moved = new_offsets - offsets
            if moved @ moved > 0:  # Broyden's update of the offsets' effect
                jacobian += np.outer(new_residual - residual - jacobian @ moved, moved) / (moved @ moved)
            offsets, residual = new_offsets, new_residual
            if rank(run, residual) < best_rank:
                best, best_run, best_rank = trimmed(offsets), run, rank(run, residual)
        return best, _result(best_run), replays

    def _fast_jacobian(
        self, trimmed: Callable[[np.ndarray], np.ndarray], state: MachineState, goal: Goal
    ) -> np.ndarray:
        """How the place the machine rests at (the mouth for ``dump``, else the teeth) moves per unit of each joint's
        offset (3, 4), on the fast model: the plan and its four probes in one batch of rollouts, each run on
        ``SETTLE_S`` with the spools closed."""
        probes = np.vstack([np.zeros((1, 4)), np.eye(4) * TRIM_PROBE])
        closed = round(SETTLE_S / self.model.control_period)
        spools = np.stack([np.vstack([trimmed(offsets), np.zeros((closed, 4))]) for offsets in probes])
        batch = self.model.rollout(state, spools, spools.shape[1] * self.model.control_period)
        ends = (batch.mouth if goal.task == "dump" else batch.tip)[:, -1]
        return (ends[1:] - ends[0]).T / TRIM_PROBE

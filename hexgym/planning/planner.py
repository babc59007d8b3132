"""Time-and-fuel motion planning on batched rollouts of the native learned model (the paper's first use of it).

:func:`plan_motion` searches spool sequences held piecewise constant between knots (every ``knot_s``,
0.5 s by default) that bring the machine from a :class:`~hexgym.planning.rollouts.MachineState` to a
:class:`Goal` in least ``time + w_fuel x fuel``, with no contact of bucket or stick with truck or ground
(clearance >= ``margin_m``) and, while loaded, as little spilled as the time it saves is worth (the bucket holds
less the more its mouth tilts from facing up: a heaped load starts to run out at once). Candidates are rolled out
in batches on the native model (:class:`RolloutModel`: by default the circuit model, which shares the pumps and the
engine's power as the machine does) and improved by the cross-entropy method (a Gaussian per knot refitted to the
best tenth, seeded with a heuristic move towards the goal or a given one).
Fuel is the engine's for the circuit's pump pressures and flows (:attr:`RolloutBatch.fuel_l_per_h`), every
candidate's; on a table model, which has no pumps, the environment's account (the actuators' power from the joint
loads, a forward pass per sample: only each batch's best few are re-ranked with it, the power sampled every
``FUEL_SAMPLE_S``).

Goals and the margins a plan keeps are the planning vocabulary of :mod:`hexgym.planning.goals`.

A move can instead turn the swing as fast as it can (:func:`plan_checked`'s ``fit_swing``): the search holds the
swing at its model's quickest turn alone (full spool, then closed: the crossover reliefs brake it), the search finds
the rest, and the switch is refitted on the circuit model's replays under the other spools (they share the pumps).

A plan that found no collision-free motion says so (:attr:`Plan.collision_free` False, its clearance):
it is never reported as safe.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from hexgym.envs.earthwork import retained_volumes
from hexgym.envs.loading import STEP_PERIOD
from hexgym.hydraulics import fuel
from hexgym.machine import parameters as p
from hexgym.planning.check import SETTLE_S, SWING_STOPPED, CheckResult, release_at_stops
from hexgym.planning.goals import MARGIN_M, Goal, margin_for
from hexgym.planning.rollouts import MachineState, RolloutBatch, RolloutModel, bang_bang, off_the_toe

FUEL_SAMPLE_S = 1.0  # s between power samples when ranking candidates by fuel (the final plan: every 0.1 s)
MAX_HORIZON_S = 30.0  # s: a longer move is no single loading motion
HORIZON_S = 8.0  # s: the default horizon of a plan
# rollouts per plan and per batch of the search: chosen on the selection seeds 20-29 (budget 600 / 800, populations
# 30 / 50 / 100: docs/planning.md); 600 rollouts of a 5 s move take ~1.3 s on 2 cores
BUDGET = 600
POPULATION = 30
KNOT_S = 0.5  # s: the default spacing of a plan's spool knots
_UNREACHED_S = 10.0  # s added to the cost of a rollout that does not reach the goal, plus 5 s per metre short
_SHORTFALL_COST = 20.0  # s per metre-second of clearance short of the margin
_CONTACT_COST = 100.0  # s per metre of penetration
# s per kg the bucket's tilt would spill (the excess over what it retains at the most tilt so far): a scripted cycle
# takes ~18 s per ~1,600 kg, so a kilogram spilled costs about this much loading time to dig again
_SPILL_S_PER_KG = 18.0 / 1600.0
# s: a checked plan that touches or misses the goal is tried with its swing started this much later (the loaded boom
# rises slower on the machine than on the fast model: later, the bucket comes to the truck higher)
MEND_DELAYS_S = (0.15, 0.3, 0.45)
NOISE_M = 20e-6  # m: the spool error per control period a plan's goal figure is checked under (noise_spread)
NOISE_COPIES = 16  # noisy executions of a plan noise_spread makes


@dataclasses.dataclass(frozen=True)
class Plan:
    """A planned move. ``spools_m`` (T, 4): per 25 ms control period up to the goal (then closed);
    predicted ``time_s`` (to the goal; the horizon when not reached), ``fuel_l``, ``min_clearance_m``,
    ``goal_error_m`` (at the end); ``reached``, ``collision_free`` (clearance >= 0), ``spill_free``;
    ``rollouts`` simulated, ``wall_s`` spent; the predicted ``tip``, ``mouth`` (T, 3) and ``q`` (T, 4);
    ``fast_swing_switch``: for a swing held at the fast model's fastest turn (:func:`swing_bang_bang`), the
    control period its full spool ended at (else None)."""

    spools_m: np.ndarray
    time_s: float
    fuel_l: float
    min_clearance_m: float
    goal_error_m: float
    reached: bool
    collision_free: bool
    spill_free: bool
    rollouts: int
    wall_s: float
    tip: np.ndarray
    mouth: np.ndarray
    q: np.ndarray
    fast_swing_switch: int | None = None

    @property
    def message(self) -> str:
        """What the plan is, in words (a plan that is not collision-free says so)."""
        if not self.collision_free:
            return f"no collision-free motion found: the best plan's clearance is {self.min_clearance_m:.3f} m"
        if not self.reached:
            return f"goal not reached within the horizon: {self.goal_error_m:.2f} m short"
        return (
            f"reaches the goal in {self.time_s:.2f} s with {self.fuel_l:.3f} L, clearance {self.min_clearance_m:.2f} m"
        )


def _knot_spools(params: np.ndarray, periods_per_knot: int, periods: int) -> np.ndarray:
    """(B, K*4) knot fractions -> (B, T, 4) spools (m) per control period."""
    knots = off_the_toe(np.clip(params, -1.0, 1.0).reshape(len(params), -1, 4) * p.SPOOL_STROKE)
    return np.repeat(knots, periods_per_knot, axis=1)[:, :periods]


@functools.cache
def _idle_litres_per_second() -> float:
    """The engine's fuel rate at no actuator power (L/s): the least any move burns per second."""
    return float(fuel.fuel_litres_many(np.zeros(1), np.ones(1))[0])


def _with_swing(spools: np.ndarray, swing_m: np.ndarray | None) -> np.ndarray:
    """(B, T, 4) spools with the swing's replaced by ``swing_m`` (T',) per control period (closed after it)."""
    if swing_m is None:
        return spools
    fixed = np.zeros(spools.shape[1])
    fixed[: min(len(swing_m), len(fixed))] = swing_m[: len(fixed)]
    spools[:, :, 0] = fixed
    return spools


def evaluate(batch: RolloutBatch, goal: Goal, payload_kg: float, margin_m: float = MARGIN_M) -> dict[str, np.ndarray]:
    """Per rollout: cost without fuel (time + penalties), time (s), clearance (m), goal error (m) up to the goal
    (or the horizon), the kilograms of ``payload_kg`` the bucket's tilt would spill (``spill``: what it cannot retain
    at its most tilt so far; the environment lets that excess run out over about a second), and the period it ends
    at."""
    reached = goal.reached(batch)
    nbatch, nper = reached.shape
    dt = batch.times_s[0]
    hit = reached.any(axis=1)
    end = np.where(hit, reached.argmax(axis=1), nper - 1)
    upto = np.arange(nper)[None, :] <= end[:, None]
    least = batch.clearance_m.min(axis=2)  # (B, T)
    clearance = np.where(upto, least, np.inf).min(axis=1)
    # every period short of the margin costs (not only the least: a start near the ground must not make the
    # rest of the move free to pass close), a contact much more
    shortfall = np.where(upto, np.maximum(margin_m - least, 0.0), 0.0).sum(axis=1) * dt
    most_tilt = np.maximum.accumulate(np.where(upto, batch.tilt, -np.inf), axis=1)[:, -1]
    spill = np.maximum(payload_kg - retained_volumes(most_tilt) * p.MATERIAL_DENSITY, 0.0)
    error = goal.error_m(batch.mouth, batch.tip)[np.arange(nbatch), end]
    time_s = batch.times_s[end]
    cost = time_s + _SHORTFALL_COST * shortfall + _CONTACT_COST * np.maximum(-clearance, 0.0) + _SPILL_S_PER_KG * spill
    cost = cost + np.where(hit, 0.0, _UNREACHED_S + 5.0 * error)
    return {"cost": cost, "time_s": time_s, "clearance_m": clearance, "error_m": error, "reached": hit,
            "spill": spill, "end": end}  # fmt: skip


def batch_fuel_l(batch: RolloutBatch, end: np.ndarray) -> np.ndarray:
    """(B,) diesel (L) of each rollout up to its period ``end`` (B,), from the fuel rates its model reports."""
    assert batch.fuel_l_per_h is not None
    upto = np.arange(batch.fuel_l_per_h.shape[1]) <= np.asarray(end)[:, None]
    return (batch.fuel_l_per_h * upto).sum(axis=1) * float(batch.times_s[0]) / 3600.0


def move_fuel_l(model: RolloutModel, batch: RolloutBatch, index: int, end: int, sample_s: float = STEP_PERIOD) -> float:
    """Diesel (L) of rollout ``index`` up to period ``end``: the fuel rate its model reports for each period, else
    its power sampled every ``sample_s`` (as the environment accounts it: the power at the end of each interval,
    held over it)."""
    dt = float(batch.times_s[0])
    if batch.fuel_l_per_h is not None:
        return float(batch.fuel_l_per_h[index, : end + 1].sum() * dt / 3600.0)
    every = max(1, round(sample_s / dt))
    ends = np.arange(every - 1, end + 1, every)
    if not len(ends):
        ends = np.array([end])
    seconds = np.diff(np.concatenate([[-1], ends])) * dt
    power = model.actuator_power(batch.states[index, ends])
    return float(fuel.fuel_litres_many(power, seconds).sum())


def swing_target(state: MachineState, goal: Goal, model: RolloutModel) -> float:
    """The swing angle (rad, unwrapped from the start's) that turns the teeth towards the goal's point: its bearing
    less the teeth's bearing off the swing angle at the start (the arm's plane need not pass through the axis)."""
    tips = model.at_angles(state.q[None], state.layout).tip
    off_axis = math.atan2(tips[0, 1], tips[0, 0]) - state.q[0]
    bearing = math.atan2(goal.point[1], goal.point[0]) - off_axis
    return float(state.q[0] + (bearing - state.q[0] + math.pi) % (2 * math.pi) - math.pi)


def swing_bang_bang(
    model: RolloutModel, state: MachineState, target_rad: float, horizon_s: float
) -> tuple[np.ndarray, int, int, int]:
    """The rollouts' quickest swing alone to ``target_rad``: full spool, then closed (the crossover reliefs brake it,
    as on the machine: a full counter-spool stops it barely sooner, with the pump at full pressure), the switch
    (each control period of the horizon's first two thirds, one batch of rollouts) the one that stops it nearest
    the target. Returns its spools (T,) per control period over ``horizon_s``, the switch (period), the period it
    has stopped by (``SWING_STOPPED``; the horizon's end if it has not) and the rollouts made."""
    sign = 1.0 if target_rad >= state.q[0] else -1.0
    periods = _periods_of(horizon_s, model)
    switches = np.arange(1, max(2, 2 * periods // 3))
    spools = np.zeros((len(switches), periods, 4))
    for i, k in enumerate(switches):
        spools[i, :, 0] = bang_bang(sign, k, k, periods)
    batch = model.rollout(state, spools, horizon_s)
    best = (math.inf, periods, periods)
    for i, k in enumerate(switches):
        stopped = np.nonzero(sign * batch.qd[i, k:, 0] <= SWING_STOPPED)[0]
        if len(stopped):
            end = int(k + stopped[0])
            best = min(best, (abs(batch.q[i, end, 0] - target_rad), int(k), end + 1))
    return bang_bang(sign, best[1], best[1], periods), best[1], best[2], len(switches)


def _periods_of(horizon_s: float, model: RolloutModel) -> int:
    """Control periods in ``horizon_s`` (rounded up)."""
    return math.ceil(horizon_s / model.control_period - 1e-9)


def _initial_mean(state: MachineState, goal: Goal, knots: int) -> np.ndarray:
    """A heuristic move: swing towards the goal (braking half way), the boom up (dump) or down (return)."""
    target = math.atan2(goal.point[1], goal.point[0])
    turn = (target - state.q[0] + math.pi) % (2 * math.pi) - math.pi
    mean = np.zeros((knots, 4))
    swing_knots = max(1, min(knots - 1, round(abs(turn) / 0.5)))
    mean[:swing_knots, 0] = np.sign(turn)
    mean[swing_knots : swing_knots + 1, 0] = -0.5 * np.sign(turn)
    if goal.task == "dump":
        mean[: knots // 2, 1] = 1.0
        mean[:, 3] = 0.2
    else:
        mean[: knots // 2, 1] = -0.3
        mean[: knots // 2, 2] = -0.5
        mean[: knots // 2, 3] = -0.5
    return mean.ravel()


def plan_motion(
    state: MachineState,
    goal: Goal,
    model: RolloutModel,
    w_fuel: float = 1.0,
    budget: int = BUDGET,
    horizon_s: float = HORIZON_S,
    knot_s: float = KNOT_S,
    population: int = POPULATION,
    seed: int = 0,
    margin_m: float | None = None,
    initial: np.ndarray | None = None,
    swing_m: np.ndarray | None = None,
) -> Plan:
    """Plan a move from ``state`` to ``goal`` with at most ``budget`` rollouts (see the module docstring).

    ``initial``: spool fractions per knot (K, 4) to start the search from (e.g. another controller's move;
    default: a heuristic move towards the goal). ``swing_m``: the swing's spools (m) per control period, held
    fixed (closed after them; e.g. :func:`swing_bang_bang`'s); the search then finds the other spools.

    Raises ValueError for a budget < 1, a horizon <= 0 or beyond ``MAX_HORIZON_S``, a knot spacing not a
    whole number of control periods, a negative ``w_fuel``.
    """
    if isinstance(budget, bool) or not isinstance(budget, int | np.integer) or budget < 1:
        raise ValueError(f"planner budget must be an integer >= 1 rollouts, got {budget!r}")
    if not (isinstance(horizon_s, int | float) and math.isfinite(horizon_s) and 0 < horizon_s <= MAX_HORIZON_S):
        raise ValueError(f"horizon_s must be > 0 and at most {MAX_HORIZON_S} s, got {horizon_s!r}")
    if not (math.isfinite(w_fuel) and w_fuel >= 0):
        raise ValueError(f"w_fuel must be finite and >= 0, got {w_fuel!r}")
    periods_per_knot = round(knot_s / model.control_period)
    if periods_per_knot < 1 or abs(periods_per_knot * model.control_period - knot_s) > 1e-9:
        raise ValueError(f"knot_s must be a whole number of {model.control_period} s control periods, got {knot_s}")
    start = time.perf_counter()
    margin_m = margin_for(state) if margin_m is None else margin_m
    periods = _periods_of(horizon_s, model)
    knots = math.ceil(periods / periods_per_knot)
    rng = np.random.default_rng(seed)
    if initial is not None:
        initial = np.asarray(initial, float)
        if initial.ndim != 2 or initial.shape[1] != 4 or not np.isfinite(initial).all():
            raise ValueError(f"initial must be (K, 4) finite spool fractions per knot, got shape {initial.shape}")
        start_mean = np.zeros((knots, 4))
        start_mean[: min(knots, len(initial))] = np.clip(initial[:knots], -1.0, 1.0)
        mean = start_mean.ravel()
    else:
        mean = _initial_mean(state, goal, knots)
    std = np.full(knots * 4, 0.5)
    population = max(2, min(population, budget))
    elites = max(1, population // 10)
    best: tuple[float, np.ndarray] | None = None
    used = 0
    simulated = periods
    while used < budget:
        n = min(population, budget - used)
        params = np.clip(mean + std * rng.standard_normal((n, knots * 4)), -1.0, 1.0)
        params[0] = np.clip(mean, -1.0, 1.0)  # the mean itself
        if best is not None and n > 1:
            params[1] = best[1]  # and the best so far (elitism)
        if best is not None:  # a move's cost is at least its time and w_fuel x its idle fuel: none reaching the
            # goal later than that allows wins
            latest = best[0] / (1.0 + w_fuel * _idle_litres_per_second())
            simulated = min(periods, math.ceil(latest / model.control_period) + 1)
        spools = _with_swing(_knot_spools(params, periods_per_knot, simulated), swing_m)
        batch = model.rollout(state, spools, simulated * model.control_period)
        used += n
        figures = evaluate(batch, goal, state.payload_kg, margin_m)
        scores = figures["cost"]
        order = np.argsort(scores)
        if w_fuel > 0 and batch.fuel_l_per_h is not None:  # the model's own fuel rates: every rollout's fuel
            scores = scores + w_fuel * batch_fuel_l(batch, figures["end"])
            order = np.argsort(scores)
        elif w_fuel > 0:  # the fuel (a forward pass per sample) only for the best few: re-ranked with it
            few = order[: 2 * elites]
            scores = scores.copy()
            for i in few:
                scores[i] += w_fuel * move_fuel_l(model, batch, int(i), int(figures["end"][i]), FUEL_SAMPLE_S)
            order = few[np.argsort(scores[few])]
        if best is None or scores[order[0]] < best[0]:
            best = (float(scores[order[0]]), params[order[0]].copy())
        top = params[order[:elites]]
        mean = 0.3 * mean + 0.7 * top.mean(axis=0)
        std = np.maximum(0.3 * std + 0.7 * top.std(axis=0), 0.05)
    assert best is not None
    spools = _with_swing(_knot_spools(best[1][None], periods_per_knot, periods), swing_m)[0]
    return _plan_of(spools, state, goal, model, margin_m, used + 1, start)


def _plan_of(
    spools_m: np.ndarray, state: MachineState, goal: Goal, model: RolloutModel, margin_m: float, rollouts: int,
    start: float, truncate: bool = True,
) -> Plan:  # fmt: skip
    """The :class:`Plan` of spools (T, 4) per control period: their rollout's figures on the fast model, up to the
    goal (``truncate``: the spools too; else all of them), with ``rollouts`` and the wall time since ``start``."""
    final = model.rollout(state, spools_m[None], len(spools_m) * model.control_period)
    figures = evaluate(final, goal, state.payload_kg, margin_m)
    end = int(figures["end"][0])
    kept = end + 1 if truncate else len(spools_m)
    clearance = float(figures["clearance_m"][0])
    return Plan(
        spools_m=spools_m[:kept], time_s=float(figures["time_s"][0]), fuel_l=move_fuel_l(model, final, 0, end),
        min_clearance_m=clearance, goal_error_m=float(figures["error_m"][0]), reached=bool(figures["reached"][0]),
        collision_free=clearance >= 0.0, spill_free=float(figures["spill"][0]) == 0.0,
        rollouts=rollouts,
        wall_s=time.perf_counter() - start, tip=final.tip[0, :kept], mouth=final.mouth[0, :kept], q=final.q[0, :kept],
    )  # fmt: skip


def plan_checked(
    state: MachineState,
    goal: Goal,
    model: RolloutModel,
    check: Callable[[np.ndarray, MachineState, Goal], CheckResult],
    budget: int = BUDGET,
    margin_m: float | None = None,
    initial: np.ndarray | None = None,
    correct: Callable[[np.ndarray, MachineState, Goal, CheckResult], tuple[np.ndarray, CheckResult, int]] | None = None,
    fit_swing: Callable[[np.ndarray, MachineState, float, int], np.ndarray] | None = None,
    **search: Any,
) -> tuple[Plan, CheckResult]:
    """:func:`plan_motion` in two rounds of half the ``budget``, each plan checked on the accurate model (``check``,
    e.g. :class:`hexgym.planning.check.PlanCheck`): by as much as the check finds the first plan closer to truck or
    ground than the fast model predicted, the second round keeps more clearance, starting from the first plan. The
    better checked plan is returned (clear by the check's margin first: ``CheckResult.clear``; then at the goal at less
    time + ``w_fuel`` x fuel as the accurate model measures them, else closer to it) with its check; its ``rollouts``
    and ``wall_s`` count both rounds and the checks. ``correct`` (e.g. :meth:`PlanCheck.correct`) then trims that plan
    on the accurate model; a trimmed plan that ranks better there is returned with its figures on the fast model (not
    cut at the fast model's goal: the trim acts last). A plan that still comes closer than the check's margin to truck
    or ground or misses the goal there is tried with its swing started later (``MEND_DELAYS_S``, each checked and
    trimmed) until one is clear and at the goal; the best ranked is returned. Last, its spools that push a cylinder into
    a stroke end on the accurate model are closed there (:func:`~hexgym.planning.check.release_at_stops`), kept when
    that ranks better.

    ``fit_swing`` (e.g. :meth:`PlanCheck.fit_swing`): the swing is not searched but turns as fast as it can to the
    goal's bearing (:func:`swing_target`). The search holds it at the rollouts' own fastest turn alone (full spool,
    then closed: :func:`swing_bang_bang`) and finds the other spools; each round's plan then gets the swing
    ``fit_swing`` fits on the circuit model's replays under them (they share the pumps with it) before it is checked.
    The plan's predicted figures are the rollouts' with their own swing. ``search``: :func:`plan_motion`'s other
    options."""
    if isinstance(budget, bool) or not isinstance(budget, int | np.integer) or budget < 2:
        raise ValueError(f"planner budget must be an integer >= 2 rollouts (two rounds), got {budget!r}")
    start = time.perf_counter()
    margin_m = margin_for(state) if margin_m is None else margin_m
    swing_m, switch, rollouts = None, None, 0
    if fit_swing is not None:
        target = swing_target(state, goal, model)
        swing_m, switch, _, rollouts = swing_bang_bang(model, state, target, search.get("horizon_s", HORIZON_S))

    def for_machine(plan: Plan) -> Plan:
        """The plan with the swing the accurate model needs (when the swing is fitted)."""
        if fit_swing is None:
            return plan
        return dataclasses.replace(plan, spools_m=fit_swing(plan.spools_m, state, target, switch))

    first = for_machine(plan_motion(state, goal, model, budget=budget // 2, margin_m=margin_m, initial=initial,
                                    swing_m=swing_m, **search))  # fmt: skip
    first_check = check(first.spools_m, state, goal)
    overstated = max(first.min_clearance_m - first_check.min_clearance_m, 0.0)
    per_knot = round(search.get("knot_s", KNOT_S) / model.control_period)
    second = for_machine(plan_motion(state, goal, model, budget=budget - budget // 2, margin_m=margin_m + overstated,
                                     initial=knot_means(first.spools_m / p.SPOOL_STROKE, per_knot), swing_m=swing_m,
                                     **search))  # fmt: skip
    second_check = check(second.spools_m, state, goal)
    w_fuel = search.get("w_fuel", 1.0)
    plan, checked = min(((first, first_check), (second, second_check)), key=lambda pc: _check_rank(pc[1], w_fuel))
    rollouts += first.rollouts + second.rollouts

    def adopt(spools: np.ndarray, checked: CheckResult) -> tuple[Plan, CheckResult]:
        """The plan with ``spools`` that rank better on the accurate model: with a fitted swing the prediction stays
        the fast model's with its own swing, else the new spools' figures on the fast model."""
        nonlocal rollouts
        if fit_swing is not None:
            return dataclasses.replace(plan, spools_m=spools), checked
        rollouts += 1
        return _plan_of(spools, state, goal, model, margin_m, rollouts, start, truncate=False), checked

    if correct is not None:
        spools, corrected, _ = correct(plan.spools_m, state, goal, checked)
        if spools is not plan.spools_m:  # trimmed: it ranks better on the accurate model
            plan, checked = adopt(spools, corrected)
    base = plan.spools_m
    for delay_s in MEND_DELAYS_S:  # touches or misses on the accurate model: the swing later, the lift ahead of it
        if checked.clear and checked.time_s is not None:
            break
        spools = delay_swing(base, round(delay_s / model.control_period))
        mended = check(spools, state, goal)
        if correct is not None:
            spools, mended, _ = correct(spools, state, goal, mended)
        if _check_rank(mended, w_fuel) < _check_rank(checked, w_fuel):
            plan, checked = adopt(spools, mended)
    if checked.replay is not None:  # spools held against a stroke end only push oil over a relief
        spools = release_at_stops(plan.spools_m, checked.replay, model.control_period)
        if spools is not plan.spools_m:
            released = check(spools, state, goal)
            if _check_rank(released, w_fuel) < _check_rank(checked, w_fuel):
                plan, checked = adopt(spools, released)
    wall_s = time.perf_counter() - start
    return dataclasses.replace(plan, rollouts=rollouts, wall_s=wall_s, fast_swing_switch=switch), checked


def noise_spread(
    plan: Plan, state: MachineState, goal: Goal, model: RolloutModel, sigma_m: float = NOISE_M,
    copies: int = NOISE_COPIES, seed: int = 0,
) -> np.ndarray:  # fmt: skip
    """Goal errors (m, ``copies``) where the machine comes to rest when the plan's spools are executed with a
    Gaussian error of ``sigma_m`` on every spool every control period (a valve's servo is no better), each copy run on
    ``SETTLE_S`` with the spools closed, on ``model``: whether the plan's goal figure holds under small spool noise
    (a plan trimmed into a valve's toe would not)."""
    rng = np.random.default_rng(seed)
    settle = np.zeros((round(SETTLE_S / model.control_period), 4))
    spools = np.vstack([plan.spools_m, settle])
    noisy = spools + sigma_m * rng.standard_normal((copies, *spools.shape))
    noisy[:, len(plan.spools_m) :] = 0.0
    batch = model.rollout(state, np.clip(noisy, -p.SPOOL_STROKE, p.SPOOL_STROKE), len(spools) * model.control_period)
    return goal.error_m(batch.mouth[:, -1], batch.tip[:, -1])


def delay_swing(spools_m: np.ndarray, periods: int) -> np.ndarray:
    """Spools (T, 4) with the swing's started ``periods`` control periods later, the others as they were, closed
    for as long at the end."""
    out = np.vstack([spools_m, np.zeros((periods, 4))])
    out[:, 0] = 0.0
    out[periods:, 0] = spools_m[:, 0]
    return out


def knot_means(per_step: np.ndarray, steps_per_knot: int) -> np.ndarray:
    """Spool fractions (T, 4) per step -> per knot of ``steps_per_knot`` steps (K, 4): their means, the last knot
    padded with closed spools."""
    knots = -(-len(per_step) // steps_per_knot)
    padded = np.zeros((knots * steps_per_knot, 4))
    padded[: len(per_step)] = per_step
    return padded.reshape(knots, steps_per_knot, 4).mean(axis=1)


def _check_rank(checked: CheckResult, w_fuel: float) -> tuple[bool, bool, float]:
    """Order of checked plans: clear (:attr:`CheckResult.clear`) first, then at the goal at less time + ``w_fuel`` x
    fuel (the search's objective, as the accurate model measures it), else closer to it."""
    if checked.time_s is None:
        return not checked.clear, True, checked.goal_error_m
    return not checked.clear, False, checked.time_s + w_fuel * (checked.fuel_l or 0.0)

"""``hexgym plan``: plan a loading move on the native learned model, replay it on the reference, compare with the
scripted loader.

For a seed of ``HexLoading-v0``'s layout, the scripted loader runs its first cycle to find the two
start states: ``dump``, the loaded, curled bucket once it has left the pile (in the scripted ``to_truck``
phase, :func:`hexgym.agents.planning_loader.out_of_the_pile`, as the planning loader plans its dumps: the plans'
model has no digging force, and the scripted loader spends its phase's first 2-3 s pulling the bucket out);
``return``, the emptied bucket over the truck (its ``to_pile`` phase begins). The move starts from rest at those
angles. Then:

- the planner (:func:`hexgym.planning.planner.plan_motion`) plans on the native learned model (the circuit model's
  batched rollouts by default), its search started from the scripted loader's move (``warm_start``):
  ``predicted_*`` are its final rollout's figures; ``target_margin_m`` is the clearance from truck and ground the
  search aims to keep (every period closer costs: a target, not a bound), ``predicted_margin_kept``
  whether the final rollout kept it (its least clearance is ``predicted_min_clearance_m``);
- by default the plan is checked, trimmed and if need be mended on the circuit model
  (:func:`~hexgym.planning.planner.plan_checked`): ``checked_*`` are the check's figures (time to the goal,
  clearance, goal error, fuel to the plan's end);
- the planned spools are replayed in the environment (the learned model with the environment's fuel
  account, 0.1 s steps): ``learned_time_s``, ``learned_fuel_l`` (the figures compared with the scripted's);
- the planned spools are replayed on the reference model (:mod:`hexgym.hydraulics.reference`, the
  stand-in for the real machine; machine alone, its clearances from its joint angles on the site), then
  ``SETTLE_S`` with the spools closed: ``reference_time_s`` (the time from which it stays at the goal with the
  swing at rest, null if it does not settle there), ``reference_fuel_l`` (to the plan's end),
  ``reference_goal_error_m`` (where it settles; ``reference_goal_error_at_plan_end_m`` at the plan's end),
  ``reference_min_clearance_m``;
- the scripted loader does the same move from the same rest state on the learned model (the
  environment): ``scripted_time_s``, ``scripted_fuel_l`` (to its first step at the goal; 0.1 s steps; for
  ``return`` its teeth within the tolerance or its ``penetrate`` phase begun, moving or not: in its favour),
  and on the reference (``HexLoading-v0`` with ``model="reference"``): ``scripted_reference_time_s``,
  ``scripted_reference_fuel_l``, which the plan's ``reference_*`` compare with (the same machine).

:func:`plan_video` films one seed's planned move and then the scripted loader's in the environment.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from hexgym.agents.planning_loader import out_of_the_pile
from hexgym.agents.scripted import ScriptedLoader
from hexgym.envs.loading import STEP_PERIOD, HexLoadingEnv
from hexgym.files import save_figure, write_json
from hexgym.machine import parameters as p
from hexgym.parallel import executor
from hexgym.planning.check import ROW_S, PlanCheck, replay_plan
from hexgym.planning.goals import Goal, dump_goal, margin_for, return_goal
from hexgym.planning.planner import (
    BUDGET,
    HORIZON_S,
    KNOT_S,
    POPULATION,
    Plan,
    knot_means,
    noise_spread,
    plan_checked,
    plan_motion,
    swing_bang_bang,
    swing_target,
)
from hexgym.planning.rollouts import MachineState, RolloutModel
from hexgym_lab.progress import track

TASKS = ("dump", "return")
SWINGS = ("knots", "bang-bang")
DEFAULT_SWING = {"dump": "knots", "return": "bang-bang"}  # loaded, a fastest swing reaches the truck before the lift
_SCRIPTED_LIMIT_S = 30.0  # s: the scripted move's limit
_CYCLE_LIMIT_S = 120.0  # s: the scripted first cycle's limit (to find the start states)


def start_states(seed: int, model: RolloutModel | None = None) -> dict[str, tuple[MachineState, Goal]]:
    """The ``dump`` and ``return`` start states (at rest) and goals of seed ``seed`` (see the module docstring);
    ``model`` measures the bucket's clearance (default: one made here)."""
    own = model is None
    model = RolloutModel(contacts=False) if model is None else model
    env = HexLoadingEnv(backend="native")
    env.reset(seed=seed)
    loader = ScriptedLoader()
    out: dict[str, tuple[MachineState, Goal]] = {}
    dumped = False
    while env.elapsed < _CYCLE_LIMIT_S and len(out) < 2:
        action = loader.act(env)
        phase = loader.phase
        q, payload = env.physics.joint_positions().copy(), float(env.earth.bucket_kg)
        if phase == "to_truck" and "dump" not in out and out_of_the_pile(env, model):
            out["dump"] = (MachineState(q, np.zeros(4), payload, env.layout), dump_goal(env.layout))
        if phase == "dump":
            dumped = True
        if dumped and phase == "to_pile" and "return" not in out:
            state = MachineState(q, np.zeros(4), payload, env.layout)
            out["return"] = (state, return_goal(env.layout, env.fullest_cut_direction()))
        env.step(action)
    env.close()
    if own:
        model.close()
    if len(out) < 2:
        raise RuntimeError(f"seed {seed}: the scripted loader did not finish a cycle in {_CYCLE_LIMIT_S:.0f} s")
    return out


def env_at(seed: int, state: MachineState, machine: str = "learned", **env_kwargs: Any) -> HexLoadingEnv:
    """The environment on seed ``seed``'s site with the machine at rest in ``state``, its bucket holding the state's
    payload: where a move is replayed, run by the scripted loader or filmed. ``machine``: ``"learned"`` (the native
    backend) or ``"reference"``."""
    backend = "native" if machine == "learned" else "auto"
    env = HexLoadingEnv(model=machine, backend=backend, **env_kwargs)
    env.reset(seed=seed)
    env.start_machine(state.q, state.layout)
    env.earth.bucket_kg = state.payload_kg
    env.physics.set_payload(state.payload_kg)
    return env


def scripted_move(
    seed: int, state: MachineState, goal: Goal, model: RolloutModel, machine: str = "learned"
) -> dict[str, Any]:
    """The scripted loader from ``state`` (at rest) on seed ``seed``'s site until at ``goal``: time, fuel, clearance;
    ``machine``: on the learned model or the reference."""
    env = env_at(seed, state, machine)
    loader = ScriptedLoader()
    qs, actions, reached_at = [], [], None
    while env.elapsed < _SCRIPTED_LIMIT_S:
        actions.append(loader.act(env))
        env.step(actions[-1])
        tip, mouth = env.physics.tip_position(), env.mouth_position()
        qs.append(env.physics.joint_positions().copy())
        at = goal.error_m(mouth, tip) <= (0.0 if goal.task == "dump" else goal.tolerance_m)
        # the scripted loader does not stop at the dig start: its penetrate phase (or the point, moving) counts
        if (at and abs(env.physics.joint_velocities()[0]) < 0.1) or (
            goal.task != "dump" and (at or loader.phase == "penetrate")
        ):
            reached_at = env.elapsed
            break
    fuel_l = env.fuel_l
    env.close()
    poses = model.at_angles(np.array(qs), state.layout)
    return {"time_s": reached_at, "fuel_l": fuel_l, "min_clearance_m": float(poses.clearance.min()),
            "steps": len(qs), "actions": np.array(actions), "tip": poses.tip}  # fmt: skip


def learned_replay(seed: int, state: MachineState, goal: Goal, plan: Plan, model: RolloutModel) -> dict[str, Any]:
    """The plan's spools in the environment (the learned model with its fuel account) from ``state`` (at rest): the
    time to the goal (0.1 s steps; each holds the spools of its start), fuel to then (or the plan's end)."""
    env = env_at(seed, state)
    per_step = round(STEP_PERIOD / model.control_period)
    qs, reached_at = [], None
    for k in range(0, len(plan.spools_m), per_step):
        env.step((plan.spools_m[k] / p.SPOOL_STROKE).astype(np.float32))
        qs.append(env.physics.joint_positions().copy())
        at = goal.error_m(env.mouth_position(), env.physics.tip_position()) <= (
            0.0 if goal.task == "dump" else goal.tolerance_m
        )
        if at and abs(env.physics.joint_velocities()[0]) < 0.1:
            reached_at = env.elapsed
            break
    fuel_l = env.fuel_l
    env.close()
    clearance = model.at_angles(np.array(qs), state.layout).clearance
    return {"time_s": reached_at, "fuel_l": fuel_l, "min_clearance_m": float(clearance.min())}


def scripted_knots(actions: np.ndarray, knot_s: float = KNOT_S) -> np.ndarray:
    """The scripted move's actions (one per 0.1 s step) as knots every ``knot_s``: their means."""
    return knot_means(actions, max(1, round(knot_s / STEP_PERIOD)))


def reference_replay(plan: Plan, state: MachineState, goal: Goal, model: RolloutModel) -> dict[str, Any]:
    """The plan's spools on the reference model from ``state`` (at rest), then ``SETTLE_S`` with the spools closed
    (:func:`hexgym.planning.check.replay_plan`): the time from which it stays at the goal with the swing at rest, the
    fuel to the plan's end, the goal error where the machine settles (and at the plan's end), the least clearance."""
    from hexgym.hydraulics.reference import ReferenceModel

    run = replay_plan(ReferenceModel(), plan.spools_m, state, goal, model)
    return {
        "time_s": run.time_s, "fuel_l": run.fuel_l,
        "goal_error_m": float(run.error[-1]), "goal_error_at_plan_end_m": float(run.error[run.planned]),
        "min_clearance_m": float(run.clearance.min()), "tip": run.tips[: run.planned + 1],
    }  # fmt: skip


def plan_task(
    task: str,
    seed: int,
    w_fuel: float = 1.0,
    budget: int = BUDGET,
    nthread: int = 2,
    horizon_s: float = HORIZON_S,
    warm_start: bool = True,
    margin_m: float | None = None,
    check: bool = True,
    swing: str | None = None,
    population: int = POPULATION,
) -> dict[str, Any]:
    """Plan ``task`` on seed ``seed``, replay it on the reference and in the environment, run the scripted loader:
    the figures. ``warm_start``: start the search from the scripted loader's move (its actions averaged per knot).
    ``check``: plan in two rounds, each plan checked on the circuit model (:func:`plan_checked`; ``checked_*``);
    else in one (:func:`plan_motion`). ``swing``: ``knots`` (searched per knot as the other spools) or
    ``bang-bang`` (the fastest turn to the goal's bearing, fitted to the circuit model: ``plan_checked``'s
    ``fit_swing``; without the check, the search model's own); default :data:`DEFAULT_SWING`. ``population``:
    candidates per batch of the search. The horizon is
    ``horizon_s`` or, shorter, the scripted move's time plus 0.5 s (rounded up to 0.5 s, >= 3 s)."""
    swing = _swing_of(task, swing)
    model = RolloutModel(nthread=nthread, contacts=False)  # the plans reject every contact
    try:
        state, goal = start_states(seed, model)[task]
        if margin_m is None:
            margin_m = margin_for(state)
        scripted = scripted_move(seed, state, goal, model)
        scripted_reference = scripted_move(seed, state, goal, model, "reference")
        initial = scripted_knots(scripted["actions"]) if warm_start else None
        if scripted["time_s"] is not None:  # no longer than the scripted move and a margin: less to simulate
            horizon_s = min(horizon_s, max(3.0, math.ceil(2.0 * (scripted["time_s"] + 0.5)) / 2.0))
        options = {"w_fuel": w_fuel, "budget": budget, "horizon_s": horizon_s, "seed": seed, "initial": initial,
                   "margin_m": margin_m, "population": population}  # fmt: skip
        checked = None
        if check:
            check_model = PlanCheck(model)
            fit_swing = check_model.fit_swing if swing == "bang-bang" else None
            plan, checked = plan_checked(state, goal, model, check_model, correct=check_model.correct,
                                         fit_swing=fit_swing, **options)  # fmt: skip
        elif swing == "bang-bang":  # the search model's own fastest turn, not fitted
            swing_m, switch, _, _ = swing_bang_bang(model, state, swing_target(state, goal, model), horizon_s)
            plan = dataclasses.replace(plan_motion(state, goal, model, swing_m=swing_m, **options),
                                       fast_swing_switch=switch)  # fmt: skip
        else:
            plan = plan_motion(state, goal, model, **options)
        noisy = noise_spread(plan, state, goal, model)
        stop = swing_bang_bang(model, state, swing_target(state, goal, model), horizon_s)[2]
        swing_limit_s = float(stop * model.control_period)  # the swing's quickest turn alone
        reference = reference_replay(plan, state, goal, model)
        learned = learned_replay(seed, state, goal, plan, model)
    finally:
        model.close()
    return {
        "task": task, "seed": seed, "w_fuel": w_fuel, "horizon_s": horizon_s, "swing": swing,
        "target_margin_m": margin_m, "predicted_margin_kept": bool(plan.min_clearance_m >= margin_m),
        "tables": model.table_set,
        "plan_message": checked.message if checked else plan.message, "plan_wall_s": plan.wall_s,
        "rollouts": plan.rollouts, "predicted_reached": plan.reached, "predicted_time_s": plan.time_s,
        "predicted_fuel_l": plan.fuel_l, "predicted_min_clearance_m": plan.min_clearance_m,
        "predicted_collision_free": plan.collision_free, "predicted_spill_free": plan.spill_free, "check": check,
        "checked_time_s": checked.time_s if checked else None,
        "checked_fuel_l": checked.fuel_l if checked else None,
        "checked_min_clearance_m": checked.min_clearance_m if checked else None,
        "checked_goal_error_m": checked.goal_error_m if checked else None,
        "checked_collision_free": checked.collision_free if checked else None,
        "checked_clear": checked.clear if checked else None,
        "learned_time_s": learned["time_s"], "learned_fuel_l": learned["fuel_l"],
        "learned_min_clearance_m": learned["min_clearance_m"], "warm_start": warm_start,
        "swing_limit_s": swing_limit_s, "noise_goal_error_m": float(noisy.max()),
        "noise_goal_error_median_m": float(np.median(noisy)),
        "reference_time_s": reference["time_s"], "reference_fuel_l": reference["fuel_l"],
        "reference_goal_error_m": reference["goal_error_m"],
        "reference_goal_error_at_plan_end_m": reference["goal_error_at_plan_end_m"],
        "reference_min_clearance_m": reference["min_clearance_m"],
        "scripted_time_s": scripted["time_s"], "scripted_fuel_l": scripted["fuel_l"],
        "scripted_min_clearance_m": scripted["min_clearance_m"], "payload_kg": state.payload_kg,
        "scripted_reference_time_s": scripted_reference["time_s"],
        "scripted_reference_fuel_l": scripted_reference["fuel_l"],
        "scripted_reference_min_clearance_m": scripted_reference["min_clearance_m"],
        "swing_switch_s": _swing_switches(plan, model.control_period),
        "planned_spools_mm": (plan.spools_m * 1e3).round(3).tolist(),
        "scripted_spools_mm": (scripted["actions"] * p.SPOOL_STROKE * 1e3).round(3).tolist(),
        "paths": {"planned_tip": plan.tip.round(3).tolist(), "reference_tip": reference["tip"].round(3).tolist(),
                  "scripted_tip": scripted["tip"].round(3).tolist()},
    }  # fmt: skip


def _swing_of(task: str, swing: str | None) -> str:
    """The swing planning of ``task``: ``swing``, or the task's default (:data:`DEFAULT_SWING`); checks both."""
    if task not in TASKS:
        raise ValueError(f"--task must be one of {TASKS}, got {task!r}")
    swing = DEFAULT_SWING[task] if swing is None else swing
    if swing not in SWINGS:
        raise ValueError(f"--swing must be one of {SWINGS}, got {swing!r}")
    return swing


def _swing_switches(plan: Plan, period: float) -> dict | None:
    """When a fastest-turn swing leaves full spool (s): the rollouts' own turn's alone (:func:`swing_bang_bang`) and
    the plan's (refitted on the circuit model under the plan's other spools when checked), per move. None
    for a swing searched per knot."""
    if plan.fast_swing_switch is None:
        return None
    swing = plan.spools_m[:, 0]
    full = swing * np.sign(swing[0]) >= p.SPOOL_STROKE - 1e-12  # towards the turn (not the counter-spool after it)
    planned = int(np.argmin(full)) if not full.all() else len(full)
    return {"fast_model": plan.fast_swing_switch * period, "plan": planned * period}


def _ratio(a: float | None, b: float | None) -> float | None:
    return a / b if a is not None and b else None


def summarise(results: list[dict[str, Any]]) -> dict[str, Any]:
    """Medians and target hit rates over seeds."""

    def median(values: list[float | None]) -> float | None:
        kept = [v for v in values if v is not None]
        return float(np.median(kept)) if kept else None

    def rel(a: float | None, b: float | None) -> float | None:
        return abs(a / b - 1.0) if a is not None and b else None

    faster = [_ratio(r["learned_time_s"], r["scripted_time_s"]) for r in results]
    fuel = [_ratio(r["learned_fuel_l"], r["scripted_fuel_l"]) for r in results]
    faster_ref = [_ratio(r["reference_time_s"], r["scripted_reference_time_s"]) for r in results]
    fuel_ref = [_ratio(r["reference_fuel_l"], r["scripted_reference_fuel_l"]) for r in results]
    out = {
        "seeds": [r["seed"] for r in results],
        "median_plan_wall_s": median([r["plan_wall_s"] for r in results]),
        "median_rollouts": median([r["rollouts"] for r in results]),
        "median_time_vs_scripted": median(faster), "median_fuel_vs_scripted": median(fuel),
        "median_predicted_time_vs_scripted": median([_ratio(r["predicted_time_s"], r["scripted_time_s"])
                                                     for r in results]),
        "learned_reached": sum(r["learned_time_s"] is not None for r in results),
        "median_reference_goal_error_m": median([r["reference_goal_error_m"] for r in results]),
        "reference_contacts": sum(r["reference_min_clearance_m"] < 0 for r in results),
        "median_time_prediction_error": median([rel(r["predicted_time_s"], r["reference_time_s"]) for r in results]),
        "median_checked_time_error": median([rel(r["checked_time_s"], r["reference_time_s"]) for r in results]),
        "median_checked_fuel_error": median([rel(r["checked_fuel_l"], r["reference_fuel_l"]) for r in results]),
        "median_reference_time_vs_scripted": median([_ratio(r["reference_time_s"], r["scripted_time_s"])
                                                     for r in results]),
        "median_reference_time_vs_scripted_reference": median(faster_ref),
        "median_reference_fuel_vs_scripted_reference": median(fuel_ref),
        "median_fuel_prediction_error": median([rel(r["predicted_fuel_l"], r["reference_fuel_l"]) for r in results]),
        "planned_reached": sum(bool(r["predicted_reached"]) for r in results),
        "planned_margin_kept": sum(bool(r.get("predicted_margin_kept")) for r in results),
        "reference_reached": sum(r["reference_time_s"] is not None for r in results),
        "median_swing_switch_later_s": median([r["swing_switch_s"]["plan"] - r["swing_switch_s"]["fast_model"]
                                               for r in results if r.get("swing_switch_s")]),
    }  # fmt: skip
    targets = {
        "plan_wall_le_2s": sum(r["plan_wall_s"] <= 2.0 for r in results),
        "faster_15pct_no_more_fuel": sum(
            (t is not None and t <= 0.85) and (f is not None and f <= 1.0) for t, f in zip(faster, fuel, strict=True)
        ),
        "reference_faster_15pct_no_more_fuel": sum(
            (t is not None and t <= 0.85) and (f is not None and f <= 1.0)
            for t, f in zip(faster_ref, fuel_ref, strict=True)
        ),
        "less_fuel_15pct_no_more_time": sum(
            (t is not None and t <= 1.0) and (f is not None and f <= 0.85) for t, f in zip(faster, fuel, strict=True)
        ),
        "reference_less_fuel_15pct_no_more_time": sum(
            (t is not None and t <= 1.0) and (f is not None and f <= 0.85)
            for t, f in zip(faster_ref, fuel_ref, strict=True)
        ),
        "reference_goal_error_le_0.3m": sum(r["reference_goal_error_m"] <= 0.3 for r in results),
        "reference_no_contact": sum(r["reference_min_clearance_m"] >= 0 for r in results),
        "noise_goal_error_le_0.3m": sum(r["noise_goal_error_m"] <= 0.3 for r in results),
        # seeds whose scripted move on the reference is within 1/0.85 of the swing's quickest turn alone
        "swing_limited": sum(
            r["scripted_reference_time_s"] is not None and r["scripted_reference_time_s"] * 0.85 < r["swing_limit_s"]
            for r in results
        ),
    }
    return out | {"targets_met_of": len(results), "targets": targets}


def run_plan(
    task: str,
    seeds: list[int],
    w_fuel: float = 1.0,
    budget: int = BUDGET,
    nthread: int = 2,
    json_out: str | Path | None = None,
    margin_m: float | None = None,
    ray: str | None = None,
    check: bool = True,
    swing: str | None = None,
    workers: int = 1,
    population: int = POPULATION,
) -> dict[str, Any]:
    """Plan on each seed; one seed's figures, or with several a summary and the per-seed figures.

    ``workers``: seeds planned at once, each in its own process (the same figures; plans sharing cores take longer
    than the 2 s wall allows, so 1 for the fast planner's timings). ``ray``: the seeds as Ray tasks of ``nthread``
    cores each ("local" or a cluster's address, :mod:`hexgym.parallel`); the same figures but the wall times."""
    if not (math.isfinite(w_fuel) and w_fuel >= 0):
        raise ValueError(f"--w-fuel must be finite and >= 0, got {w_fuel}")
    if budget < (2 if check else 1):
        raise ValueError(f"--budget must be >= {2 if check else 1} rollouts, got {budget}")
    if nthread < 1:
        raise ValueError(f"--threads must be >= 1, got {nthread}")
    if workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    if margin_m is not None and not (math.isfinite(margin_m) and 0 <= margin_m <= 2.0):
        raise ValueError(f"--margin must be within 0 and 2 m, got {margin_m}")
    _swing_of(task, swing)  # before any seed runs
    start = time.perf_counter()
    if population < 2:
        raise ValueError(f"--population must be >= 2 candidates, got {population}")
    jobs = [(task, s, w_fuel, budget, nthread, margin_m, check, swing, population) for s in seeds]
    with executor(workers, ray, cpus_per_task=nthread) as pool:  # as they finish (the progress), then in seed order
        done = track(pool.map_unordered(_plan_job, jobs), f"plan {task}", "seed", total=len(jobs))
        results = sorted(done, key=lambda result: seeds.index(result["seed"]))
    out: dict[str, Any] = results[0] if len(results) == 1 else {
        "task": task, "w_fuel": w_fuel, "summary": summarise(results), "per_seed": results,
    }  # fmt: skip
    out["wall_s"] = time.perf_counter() - start
    if json_out is not None:
        write_json(json_out, out)
    return out


def _plan_job(job: tuple[str, int, float, int, int, float | None, bool, str | None, int]) -> dict[str, Any]:
    task, seed, w_fuel, budget, nthread, margin_m, check, swing, population = job
    return plan_task(task, seed, w_fuel, budget, nthread, margin_m=margin_m, check=check, swing=swing,
                     population=population)  # fmt: skip


def plot_plan(result: dict[str, Any], out: str | Path) -> Path:
    """One seed's plan as a PNG: teeth paths from above and their heights (planned, on the reference, scripted),
    the planned and the scripted spools, and the time and fuel of each."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = {k: np.array(v) for k, v in result["paths"].items()}
    planned_dt, reference_dt, scripted_dt = 0.025, ROW_S, STEP_PERIOD
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5))
    styles = (("planned_tip", "planned (learned model)", planned_dt, "C0"),
              ("reference_tip", "planned, on the reference", reference_dt, "C3"),
              ("scripted_tip", "scripted loader", scripted_dt, "C2"))  # fmt: skip
    for key, label, dt, colour in styles:
        path = paths[key]
        axes[0, 0].plot(path[:, 0], path[:, 1], color=colour, label=label)
        axes[0, 1].plot(np.arange(len(path)) * dt + (dt if key != "reference_tip" else 0.0), path[:, 2], color=colour)
    axes[0, 0].set(xlabel="x (m)", ylabel="y (m)", title=f"teeth from above: {result['task']}, seed {result['seed']}")
    axes[0, 0].axis("equal")
    axes[0, 0].legend(fontsize=8)
    axes[0, 1].set(xlabel="t (s)", ylabel="teeth height (m)", title="teeth height")
    names = ("swing", "boom", "stick", "bucket")
    for spools, ax, dt, title in ((np.array(result["planned_spools_mm"]), axes[1, 0], planned_dt, "planned spools"),
                                  (np.array(result["scripted_spools_mm"]), axes[1, 1], scripted_dt,
                                   "scripted loader's spools")):  # fmt: skip
        for j, name in enumerate(names):
            ax.step(np.arange(len(spools)) * dt, spools[:, j], where="post", label=name)
        ax.set(xlabel="t (s)", ylabel="spool (mm)", title=title, ylim=(-12, 12))
        ax.legend(fontsize=8, ncol=4)

    def seconds(key: str) -> str:
        return "goal not reached" if result.get(key) is None else f"{result[key]:.1f} s"

    title = (
        f"learned model: planned {seconds('learned_time_s')}, {result['learned_fuel_l']:.4f} L; scripted "
        f"{seconds('scripted_time_s')}, {result['scripted_fuel_l']:.4f} L\nreference: planned "
        f"{seconds('reference_time_s')}, {result['reference_fuel_l']:.4f} L, goal error "
        f"{result['reference_goal_error_m']:.2f} m"
    )
    if result.get("scripted_reference_fuel_l") is not None:
        title += f"; scripted {seconds('scripted_reference_time_s')}, {result['scripted_reference_fuel_l']:.4f} L"
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save_figure(fig, out)


def plan_video(result: dict[str, Any], out: str | Path, width: int = 640, height: int = 384) -> Path:
    """One seed's planned move (its whole horizon) and then the scripted loader's same move, each from the start
    state at rest, in the environment (the learned model) from the chase camera: an MP4 at 10 frames/s, each frame
    with the films' caption (:func:`hexgym_lab.agents.film.film_frame`), the task and the mover first."""
    from hexgym.machine.render import check_frame_memory, write_mp4
    from hexgym_lab.agents.film import film_frame

    state, _ = start_states(result["seed"])[result["task"]]
    planned = np.asarray(result["planned_spools_mm"]) / 1e3 / p.SPOOL_STROKE  # one row per control period
    scripted = np.asarray(result["scripted_spools_mm"]) / 1e3 / p.SPOOL_STROKE  # one row per 0.1 s step
    frames: list[np.ndarray] = []
    for label, actions in (("plan", planned), ("scripted loader", scripted)):
        env = env_at(result["seed"], state, render_mode="rgb_array", width=width, height=height)
        if label == "plan":  # the plan's spools per control period: a step holds those of its start
            actions = actions[:: round(STEP_PERIOD / env.machine.control_period)]
        check_frame_memory(len(frames) + len(actions), width, height)
        try:
            for action in actions:
                info = env.step(action.astype(np.float32))[-1]
                frames.append(film_frame(env, info, label=f"{result['task']}: {label}"))
        finally:
            env.close()
    return write_mp4(frames, out, fps=1.0 / STEP_PERIOD)

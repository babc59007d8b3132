"""The learned model against the reference model on the paper's three tests: ``hexgym validate``.

The tests' command logs are :mod:`hexgym_lab.scenarios`. Test 1 moves boom and bucket together
(their flow sharing on pump 1), Test 2 swing and stick together (pump 2), Test 3 is an
operator-like loading cycle of about 50 s (three dig, swing, dump, return cycles, spools ramped
as a joystick would move them). For each test both models replay the same command log from the
same pose; the plots follow the paper's Figs 5-11: joint responses with the commands, the
tip-position error each joint contributes through the Jacobian, and the overall tip error beside
the boom-foot-to-tip distance. ``summary.json`` holds per test ``mean_tip_error_m`` and
``max_tip_error_m``, and ``speed``: simulated seconds per wall second of each model on Test 3
(one core; the learned model on its native plugin when built, its Python path beside it) and
their ratio.

Beyond the paper: ``interactions`` holds the actuator interactions in both directions, each
with an empty bucket and with 2 t (8 s logs, ``interactions.png``): the swing slowed by the
stick moving in and moving out (pump 2), the boom held back by the bucket curling and dumping
(pump 1). With ``suite=N`` the ``suite`` block holds the generalisation suite: N seeded random
operator-like logs (:mod:`hexgym_lab.mbl.operator_logs`, 30-60 s, start poses and payloads
varied) that no table was tuned on, each log's tip errors, their median and worst; the worst
log is plotted as Test 3 (``suite_worst.png``). ``suite_style="bucket_stick"`` draws a suite of
only the bucket at full spool with the stick moving (the motion a learned model's bucket is most
sensitive in). The reference runs at only a few times real
time, so the interactions and the suite run in worker processes.

``payload_kg`` puts that much material in the bucket for every run of both models: Tests 1-3,
the interactions (then at that payload only) and every suite log (in place of its drawn
payload). Left at ``None``, the tests run empty, the interactions at 0 and 2 t and each suite
log with its drawn payload. ``summary.json`` records it (``payload_kg``, ``null`` for the
drawn payloads) and the learned model (``model``: its table set, whether its circuit steps
run natively, where its tables came from and their content hashes' digest).
"""

from __future__ import annotations

import hashlib
import math
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from hexgym.files import save_figure, staged_dir, write_json
from hexgym.hydraulics.reference import ReferenceModel
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.physics import MAX_PAYLOAD_KG
from hexgym.mbl.schema import CIRCUIT_TABLE_SETS, DEFAULT_TABLE_SET, NATIVE_TABLE_SETS, VALVE_OF_TABLE_SET
from hexgym.model.backend import make_learned_model
from hexgym.model.circuit_model import CircuitModel
from hexgym.model.commandlog import CommandLog
from hexgym.model.python_backend import LearnedModel
from hexgym.model.replay import replay
from hexgym.parallel import executor
from hexgym_lab.mbl.operator_logs import STYLES, pose_from_fractions, suite_log
from hexgym_lab.progress import track
from hexgym_lab.scenarios import POSE_CYCLE, ramped_log, scenarios  # noqa: F401 (POSE_CYCLE: re-exported)

DT_OUT = 0.05  # s
# Interaction cases: name -> (slowed joint, partner joint, partner spool sign, start stroke fractions
# of boom, stick, bucket); the slowed function and its partner both at full spool from 0.5 to 6 s
INTERACTIONS = {
    "swing_with_stick_in": ("swing", "stick", 1.0, (0.5, 0.1, 0.5)),
    "swing_with_stick_out": ("swing", "stick", -1.0, (0.5, 0.9, 0.5)),
    "boom_with_bucket_curl": ("boom", "bucket", 1.0, (0.1, 0.5, 0.1)),
    "boom_with_bucket_dump": ("boom", "bucket", -1.0, (0.1, 0.5, 0.9)),
}
INTERACTION_PAYLOADS_KG = (0.0, 2000.0)
INTERACTION_WINDOW_S = (1.0, 6.0)  # both spools fully open


def interaction_cases(
    payloads_kg: tuple[float, ...] = INTERACTION_PAYLOADS_KG,
) -> dict[str, tuple[CommandLog, np.ndarray, float]]:
    """Case name (``<interaction>_<payload>t``) -> (command log, start pose, payload kg), each interaction at
    each of ``payloads_kg``."""
    full = p.SPOOL_STROKE * 1e3
    cases = {}
    for name, (slowed, partner, sign, fractions) in INTERACTIONS.items():
        spools = np.zeros(4)
        spools[kinematics.JOINTS.index(slowed)] = full
        spools[kinematics.JOINTS.index(partner)] = sign * full
        log = ramped_log([(0.0, 0, 0, 0, 0), (0.5, *spools), (6.0, 0, 0, 0, 0), (8.0, 0, 0, 0, 0)], ramp=0.3)
        for payload in payloads_kg:
            cases[f"{name}_{payload / 1000:g}t"] = (log, pose_from_fractions(0.0, np.array(fractions)), payload)
    return cases


def tip_errors(reference: np.ndarray, learned: np.ndarray) -> dict[str, np.ndarray]:
    """Overall tip error, each joint's contribution through the Jacobian, boom-foot-to-tip distance."""
    q_ref = np.column_stack([reference[f"q_{j}_rad"] for j in kinematics.JOINTS])
    q_learned = np.column_stack([learned[f"q_{j}_rad"] for j in kinematics.JOINTS])
    tip_ref = np.column_stack([reference[c] for c in ("tip_x_m", "tip_y_m", "tip_z_m")])
    tip_learned = np.column_stack([learned[c] for c in ("tip_x_m", "tip_y_m", "tip_z_m")])
    contributions = np.array(
        [np.linalg.norm(kinematics.tip_jacobian(q) * (ql - q), axis=0) for q, ql in zip(q_ref, q_learned, strict=True)]
    )
    swing, (foot_x, foot_z) = q_ref[:, 0], p.BOOM_FOOT  # the boom foot turns with the swing
    foot = np.column_stack([foot_x * np.cos(swing), foot_x * np.sin(swing), np.full(len(swing), foot_z)])
    foot[:, 2] += p.SWING_BEARING_HEIGHT
    return {
        "tip_error": np.linalg.norm(tip_learned - tip_ref, axis=1),
        "joint_contribution": contributions,
        "foot_to_tip": np.linalg.norm(tip_ref - foot, axis=1),
    }


def run_test(
    name: str,
    log: CommandLog,
    pose: np.ndarray,
    reference: ReferenceModel,
    learned: LearnedModel,
    payload_kg: float = 0.0,
) -> dict[str, object]:
    """Both models on one scenario, with their wall times."""
    start = time.perf_counter()
    traj_ref = replay(reference, log, start=pose, payload_kg=payload_kg, dt_out=DT_OUT)
    wall_ref = time.perf_counter() - start
    start = time.perf_counter()
    traj_learned = replay(learned, log, start=pose, payload_kg=payload_kg, dt_out=DT_OUT)
    wall_learned = time.perf_counter() - start
    return {
        "name": name,
        "reference": traj_ref,
        "learned": traj_learned,
        "errors": tip_errors(traj_ref, traj_learned),
        "wall": (wall_ref, wall_learned),
        "duration": log.duration,
        "payload_kg": payload_kg,
    }


def plot_test(result: dict[str, object], path: Path, error_panels: bool | None = None) -> Path:
    """Joint responses of both models with the commands (Figs 5-9); with ``error_panels`` (default:
    for Test 3) also the tip error by joint and overall (Figs 10-11)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ref, lrn, err = result["reference"], result["learned"], result["errors"]
    extra = 2 if (result["name"] == "test3" if error_panels is None else error_panels) else 0
    fig, axes = plt.subplots(4 + extra, 1, figsize=(11, 2.3 * (4 + extra)), sharex=True)
    t = ref["t"]
    for ax, joint in zip(axes[:4], kinematics.JOINTS, strict=True):
        ax.plot(t, ref[f"qd_{joint}_radps"], label="reference", color="k")
        ax.plot(t, lrn[f"qd_{joint}_radps"], "--", label="learned", color="tab:orange")
        ax.set_ylabel(f"{joint} rate (rad/s)")
        cmd = ax.twinx()
        cmd.step(t, ref[f"{joint}_spool_mm"], where="post", color="tab:blue", alpha=0.35)
        cmd.set_ylabel("spool (mm)", color="tab:blue")
        cmd.set_ylim(-12, 12)
    axes[0].legend(loc="upper right")
    payload = f", {result['payload_kg'] / 1000:g} t payload" if result.get("payload_kg") else ""
    axes[0].set_title(f"{result['name']}: reference vs learned model{payload}")
    if extra:
        for j, joint in enumerate(kinematics.JOINTS):
            axes[4].plot(t, err["joint_contribution"][:, j], label=joint)
        axes[4].set_ylabel("tip error from joint (m)")
        axes[4].legend(loc="upper right", ncols=4)
        axes[5].plot(t, err["tip_error"], label="tip position error", color="tab:red")
        axes[5].plot(t, err["foot_to_tip"], label="boom foot to tip", color="tab:gray")
        axes[5].set_ylabel("m")
        axes[5].legend(loc="upper right")
    axes[-1].set_xlabel("t (s)")
    fig.tight_layout()
    return save_figure(fig, path, dpi=80)


def _speed(test3: dict[str, object], table_set: str) -> dict[str, float]:
    """Real-time factors on Test 3 (one core): the reference's replay, the learned model's fastest path.

    The learned model's figure is the native plugin's (Test 3's spools through ``mujoco.rollout``,
    one thread, :func:`hexgym_lab.bench.native_rollout_realtime_factor`) when it is built and runs
    ``table_set``, else the Python path's (this run's replay of Test 3).
    """
    from hexgym.model.plugin import native_available
    from hexgym_lab.bench import native_rollout_realtime_factor

    wall_ref, wall_python = test3["wall"]
    duration = float(test3["duration"])
    python = duration / wall_python
    native = native_available() and table_set in NATIVE_TABLE_SETS
    learned = native_rollout_realtime_factor(seconds=3.0, table_set=table_set) if native else python
    reference = duration / wall_ref
    return {
        "simulated_s": duration,
        "reference_realtime_factor": reference,
        "learned_realtime_factor": learned,
        "learned_backend": "native" if native else "python",
        "learned_realtime_factor_python": python,
        "speedup": learned / reference,
    }


def plot_interactions(
    results: dict[str, dict[str, object]], path: Path, payloads_kg: tuple[float, ...] = INTERACTION_PAYLOADS_KG
) -> Path:
    """Each interaction case at each of ``payloads_kg``: the slowed function's and its partner's joint rates,
    reference vs learned."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    payloads = payloads_kg
    size = (6 * len(payloads), 2.6 * len(INTERACTIONS))
    fig, axes = plt.subplots(len(INTERACTIONS), len(payloads), figsize=size, sharex=True, squeeze=False)
    for row, (name, (slowed, partner, _, _)) in enumerate(INTERACTIONS.items()):
        for col, payload in enumerate(payloads):
            result, ax = results[f"{name}_{payload / 1000:g}t"], axes[row, col]
            t = result["reference"]["t"]
            for joint, color in ((slowed, "k"), (partner, "tab:green")):
                ax.plot(t, result["reference"][f"qd_{joint}_radps"], color=color, label=f"{joint}, reference")
                ax.plot(t, result["learned"][f"qd_{joint}_radps"], "--", color=color, label=f"{joint}, learned")
            error = result["errors"]["tip_error"].mean()
            ax.set_title(f"{name.replace('_', ' ')}, {payload / 1000:g} t: mean tip error {error:.2f} m", fontsize=9)
            ax.set_ylabel("joint rate (rad/s)")
            ax.legend(loc="best", fontsize=7, ncols=2)
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    fig.tight_layout()
    return save_figure(fig, path, dpi=80)


def _tip_error_figures(result: dict[str, object]) -> dict[str, float]:
    errors = result["errors"]["tip_error"]
    return {"mean_tip_error_m": float(errors.mean()), "max_tip_error_m": float(errors.max())}


def _interaction_summary(name: str, result: dict[str, object]) -> dict[str, object]:
    """Tip errors and the slowed function's mean rate while both spools are open, on both models."""
    slowed = INTERACTIONS[name.rsplit("_", 1)[0]][0]
    t = result["reference"]["t"]
    window = (t >= INTERACTION_WINDOW_S[0]) & (t <= INTERACTION_WINDOW_S[1])
    rates = {model: float(result[model][f"qd_{slowed}_radps"][window].mean()) for model in ("reference", "learned")}
    return {**_tip_error_figures(result), f"{slowed}_mean_rate_rad_s": rates}


_worker_models: dict[str, object] = {}


def _worker_recipe(learned: LearnedModel | None) -> object:
    """What a worker process needs to build ``learned`` itself: a circuit model's tables, control period and
    substeps (its native kernel is a library handle, which cannot be pickled); any other model as it is."""
    if isinstance(learned, CircuitModel):
        return ("circuit", learned.tables, learned.control_period, learned.substeps, learned.table_set)
    return learned


def _init_worker(recipe: object) -> None:
    """Build this process's reference model, and build or take its learned model (once per worker) from
    :func:`_worker_recipe`'s recipe (``None``: the packaged default tables' model)."""
    if recipe is None:
        _worker_models["learned"] = make_learned_model("python")
    elif isinstance(recipe, tuple) and recipe[0] == "circuit":
        _, tables, control_period, substeps, table_set = recipe
        _worker_models["learned"] = CircuitModel(
            tables, control_period=control_period, substeps=substeps, table_set=table_set
        )
    else:
        _worker_models["learned"] = recipe
    _worker_models["reference"] = ReferenceModel(valve=VALVE_OF_TABLE_SET[_worker_models["learned"].table_set])


def _run_job(job: tuple[str, CommandLog, np.ndarray, float]) -> dict[str, object]:
    """One (name, log, start pose, payload kg) on this process's two models: :func:`run_test`."""
    name, log, pose, payload_kg = job
    return run_test(name, log, pose, _worker_models["reference"], _worker_models["learned"], payload_kg)


def run_jobs(
    jobs: list[tuple[str, CommandLog, np.ndarray, float]],
    learned: LearnedModel | None = None,
    workers: int = 1,
    ray: str | None = None,
) -> dict[str, dict[str, object]]:
    """:func:`run_test` on each (name, log, start pose, payload kg), keyed by name.

    ``workers`` > 1: in that many spawned processes, the longest logs first; each process builds
    its reference model and gets a copy of ``learned`` (default: the packaged tables' model).
    ``ray``: as Ray tasks instead (:mod:`hexgym.parallel`: "local" or a cluster's address).
    """
    jobs = sorted(jobs, key=lambda job: -job[1].duration)
    recipe = _worker_recipe(learned)
    with executor(min(workers, max(len(jobs), 1)), ray, initializer=_init_worker, initargs=(recipe,)) as pool:
        runs = track(pool.map_unordered(_run_job, jobs), "validate: interactions and suite", "run", total=len(jobs))
        return {result["name"]: result for result in runs}


def _suite_entry(result: dict[str, object], description: dict[str, object]) -> dict[str, object]:
    """A suite log's description, tip errors, each joint's share (through the Jacobian: a linearisation,
    it overstates a swing error of a radian or more) and each joint's mean angle error."""
    contributions = result["errors"]["joint_contribution"].mean(axis=0)
    ref, learned = result["reference"], result["learned"]
    return {
        **description,
        **_tip_error_figures(result),
        "mean_tip_error_from_m": {j: round(float(c), 4) for j, c in zip(kinematics.JOINTS, contributions, strict=True)},
        "mean_joint_error_rad": {
            j: round(float(np.abs(learned[f"q_{j}_rad"] - ref[f"q_{j}_rad"]).mean()), 4) for j in kinematics.JOINTS
        },
    }


def check_payload(payload_kg: float | None) -> None:
    """Refuse a payload that is not a finite mass from 0 to a heaped bucket (``None``: the drawn payloads)."""
    if payload_kg is not None and not (
        isinstance(payload_kg, int | float) and math.isfinite(payload_kg) and 0.0 <= payload_kg <= MAX_PAYLOAD_KG
    ):
        raise ValueError(
            f"payload_kg must be a finite mass from 0 to {MAX_PAYLOAD_KG:.0f} kg (a heaped bucket), got {payload_kg!r}"
        )


def model_record(learned: LearnedModel, tables_dir: str | Path | None = None) -> dict[str, object]:
    """The learned model a report was made with: its table set, whether its circuit steps ran natively (the
    circuit model), where its tables came from and a digest of their content hashes (sorted by name)."""
    tables = getattr(learned, "tables", {}) or {}
    digest = hashlib.sha256("".join(f"{n}:{t.content_hash()};" for n, t in sorted(tables.items())).encode())
    record: dict[str, object] = {
        "table_set": learned.table_set,
        "class": type(learned).__name__,
        "tables_dir": str(tables_dir) if tables_dir is not None else "packaged",
        "tables_sha256": digest.hexdigest(),
    }
    if learned.table_set in CIRCUIT_TABLE_SETS:
        record["circuit_kernel"] = "native" if getattr(learned, "_kernel", None) is not None else "python"
    return record


REPORT_FILES = ("test1.png", "test2.png", "test3.png", "interactions.png", "suite_worst.png", "summary.json")


def run_validation(
    out_dir: str | Path,
    learned: LearnedModel | None = None,
    suite: int = 0,
    suite_seed: int = 0,
    workers: int | None = None,
    suite_only: bool = False,
    suite_duration_s: float | None = None,
    table_set: str = DEFAULT_TABLE_SET,
    tables_dir: str | Path | None = None,
    ray: str | None = None,
    payload_kg: float | None = None,
    suite_style: str = "operator",
) -> dict[str, object]:
    """The three tests, the interactions and ``suite`` random operator logs; plots and ``summary.json``
    in ``out_dir``; returns the summary.

    ``suite_seed``: log ``i`` is :func:`hexgym_lab.mbl.operator_logs.suite_log` ``(suite_seed, i)``;
    ``workers``: processes for the interactions and the suite (default: one per CPU);
    ``suite_only``: the suite alone; ``suite_duration_s``: every suite log this long (default 30-60 s);
    ``table_set``, ``tables_dir``: the learned model's tables (default: the packaged ones of the set), unless
    ``learned`` is given; ``ray``: the interactions and the suite as Ray tasks ("local" or a cluster's address);
    ``payload_kg``: material in the bucket for every run (default ``None``: the tests empty, the interactions at
    0 and 2 t, each suite log its drawn payload); ``suite_style``: how the suite's logs move the joysticks (a key
    of :data:`hexgym_lab.mbl.operator_logs.STYLES`: "operator", or "bucket_stick" for the bucket at full spool with
    the stick moving in every phase).
    """
    check_payload(payload_kg)
    if suite_style not in STYLES:
        raise ValueError(f"suite_style must be one of {tuple(STYLES)}, got {suite_style!r}")
    if suite < 0 or (suite_only and suite == 0):
        raise ValueError(f"suite must be a number of logs >= 0 (> 0 with suite_only), got {suite}")
    workers = (os.cpu_count() or 1) if workers is None else workers
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if tables_dir is not None and not Path(tables_dir).is_dir():
        raise FileNotFoundError(f"input directory --tables-dir {tables_dir} does not exist")
    learned = learned or make_learned_model("python", tables_dir, table_set=table_set)  # before any output
    # the report (plots and summary) is replaced as a whole: an interrupted run leaves the previous one
    with staged_dir(Path(out_dir)) as staging:
        out_dir = staging
        for old in REPORT_FILES:  # an earlier report's files go: the new report is one run's, whole
            (out_dir / old).unlink(missing_ok=True)
        summary: dict[str, object] = {
            "tables": learned.table_set,
            "model": model_record(learned, tables_dir),
            "payload_kg": payload_kg,
        }
        test_payload = 0.0 if payload_kg is None else float(payload_kg)
        if not suite_only:
            reference = ReferenceModel(valve=VALVE_OF_TABLE_SET[learned.table_set])
            for name, (log, pose) in track(scenarios().items(), "validate: the paper's tests", "test"):
                result = run_test(name, log, pose, reference, learned, test_payload)
                plot_test(result, out_dir / f"{name}.png")
                summary[name] = {**_tip_error_figures(result), "payload_kg": test_payload}
                if name == "test3":
                    summary["speed"] = _speed(result, learned.table_set)
        interaction_payloads = INTERACTION_PAYLOADS_KG if payload_kg is None else (float(payload_kg),)
        interactions = {} if suite_only else interaction_cases(interaction_payloads)
        logs = {
            f"suite log {i} (seed {suite_seed})": suite_log(suite_seed, i, suite_duration_s, suite_style)
            for i in range(suite)
        }
        if payload_kg is not None:
            logs = {name: replace(o, payload_kg=float(payload_kg)) for name, o in logs.items()}
        jobs = [(name, *case) for name, case in interactions.items()]
        jobs += [(name, CommandLog(o.t, o.spools_mm), o.start_pose, o.payload_kg) for name, o in logs.items()]
        results = run_jobs(jobs, learned, workers, ray)
        if interactions:
            summary["interactions"] = {name: _interaction_summary(name, results[name]) for name in interactions}
            plot_interactions(results, out_dir / "interactions.png", interaction_payloads)
        if suite:
            per_log = [
                _suite_entry(results[name], {"index": i, "seed": suite_seed, **o.describe()})
                for i, (name, o) in enumerate(logs.items())
            ]
            means = [entry["mean_tip_error_m"] for entry in per_log]
            worst = int(np.argmax(means))
            summary["suite"] = {
                "seed": suite_seed,
                "style": suite_style,
                "n": suite,
                "median_mean_tip_error_m": float(np.median(means)),
                "worst_mean_tip_error_m": means[worst],
                "worst_index": worst,
                "per_log": per_log,
            }
            plot_test(results[list(logs)[worst]], out_dir / "suite_worst.png", error_panels=True)
        write_json(out_dir / "summary.json", summary)
    return summary

"""The learned model against the reference model on the paper's three tests: ``hexgym validate``.

Test 1 moves boom and bucket together (their flow sharing on pump 1), Test 2 swing and stick
together (pump 2), Test 3 is an operator-like loading cycle of about 50 s (three dig, swing,
dump, return cycles, spools ramped as a joystick would move them). For each test both models
replay the same command log from the same pose; the plots follow the paper's Figs 5-11: joint
responses with the commands, the tip-position error each joint contributes through the Jacobian,
and the overall tip error beside the boom-foot-to-tip distance. ``summary.json`` holds per test
``mean_tip_error_m`` and ``max_tip_error_m``, and ``speed``: simulated seconds per wall second of
each model on Test 3 (one core; the learned model on its native plugin when built, its Python
path beside it) and their ratio.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from hexgym.files import save_figure, write_json
from hexgym.hydraulics.reference import ReferenceModel
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.model.commandlog import CommandLog
from hexgym.model.python_backend import LearnedModel
from hexgym.model.replay import replay
from hexgym.tools.reference_report import POSE_LOW, POSE_SWING

DT_OUT = 0.05  # s
POSE_CYCLE = np.array([0.0, 0.2, 0.4, 0.3])


def _ramped_log(
    keys: list[tuple[float, float, float, float, float]], ramp: float = 0.4, dt: float = 0.05
) -> CommandLog:
    """A command log through the key rows (t, 4 spools in mm), each change ramped over ``ramp`` s."""
    t_keys = np.array([k[0] for k in keys])
    u_keys = np.array([k[1:] for k in keys], dtype=float)
    t = np.arange(0.0, t_keys[-1] + dt / 2, dt)
    u = np.empty((len(t), 4))
    for i, ti in enumerate(t):
        k = int(np.searchsorted(t_keys, ti, side="right")) - 1
        previous = u_keys[max(k - 1, 0)]
        frac = min(1.0, (ti - t_keys[k]) / ramp) if k > 0 else 1.0
        u[i] = np.round(previous + frac * (u_keys[k] - previous), 1)
    return CommandLog(t, u)


def scenarios() -> dict[str, tuple[CommandLog, np.ndarray]]:
    """Test name -> (command log, start pose)."""
    full = p.SPOOL_STROKE * 1e3
    test1 = _ramped_log([(0.0, 0, 0, 0, 0), (0.5, 0, full, 0, full), (7.0, 0, 0, 0, 0), (8.0, 0, 0, 0, 0)], ramp=0.2)
    test2 = _ramped_log([(0.0, 0, 0, 0, 0), (0.5, full, 0, full, 0), (7.0, 0, 0, 0, 0), (9.0, 0, 0, 0, 0)], ramp=0.2)
    cycle = [  # (duration, swing, boom, stick, bucket) of one loading cycle, mm
        (2.0, 0, -5, -8, -9),  # reach out and lower
        (3.0, 0, 0, 10, 7),  # dig: crowd and curl
        (3.5, 7, 9, 0, 0),  # lift and swing to the truck
        (2.0, 0, 0, -8, -11),  # dump
        (3.5, -7, -4, 0, 3),  # swing back and lower
        (1.5, 0, 0, 0, 0),
    ]
    keys, t = [(0.0, 0.0, 0.0, 0.0, 0.0)], 0.5
    for _ in range(3):
        for duration, *spools in cycle:
            keys.append((t, *spools))
            t += duration
    keys.append((t, 0, 0, 0, 0))
    keys.append((t + 1.0, 0, 0, 0, 0))
    return {"test1": (test1, POSE_LOW), "test2": (test2, POSE_SWING), "test3": (_ramped_log(keys), POSE_CYCLE)}


def tip_errors(reference: np.ndarray, learned: np.ndarray) -> dict[str, np.ndarray]:
    """Overall tip error, each joint's contribution through the Jacobian, boom-foot-to-tip distance."""
    q_ref = np.column_stack([reference[f"q_{j}"] for j in kinematics.JOINTS])
    q_learned = np.column_stack([learned[f"q_{j}"] for j in kinematics.JOINTS])
    tip_ref = np.column_stack([reference[c] for c in ("tip_x", "tip_y", "tip_z")])
    tip_learned = np.column_stack([learned[c] for c in ("tip_x", "tip_y", "tip_z")])
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
    name: str, log: CommandLog, pose: np.ndarray, reference: ReferenceModel, learned: LearnedModel
) -> dict[str, object]:
    """Both models on one scenario, with their wall times."""
    start = time.perf_counter()
    traj_ref = replay(reference, log, start=pose, dt_out=DT_OUT)
    wall_ref = time.perf_counter() - start
    start = time.perf_counter()
    traj_learned = replay(learned, log, start=pose, dt_out=DT_OUT)
    wall_learned = time.perf_counter() - start
    return {
        "name": name,
        "reference": traj_ref,
        "learned": traj_learned,
        "errors": tip_errors(traj_ref, traj_learned),
        "wall": (wall_ref, wall_learned),
        "duration": log.duration,
    }


def plot_test(result: dict[str, object], path: Path) -> Path:
    """Joint responses of both models with the commands (Figs 5-9); for Test 3 also Figs 10-11."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ref, lrn, err = result["reference"], result["learned"], result["errors"]
    extra = 2 if result["name"] == "test3" else 0
    fig, axes = plt.subplots(4 + extra, 1, figsize=(11, 2.3 * (4 + extra)), sharex=True)
    t = ref["t"]
    for ax, joint in zip(axes[:4], kinematics.JOINTS, strict=True):
        ax.plot(t, ref[f"qd_{joint}"], label="reference", color="k")
        ax.plot(t, lrn[f"qd_{joint}"], "--", label="learned", color="tab:orange")
        ax.set_ylabel(f"{joint} rate (rad/s)")
        cmd = ax.twinx()
        cmd.step(t, ref[f"{joint}_spool_mm"], where="post", color="tab:blue", alpha=0.35)
        cmd.set_ylabel("spool (mm)", color="tab:blue")
        cmd.set_ylim(-12, 12)
    axes[0].legend(loc="upper right")
    axes[0].set_title(f"{result['name']}: reference vs learned model")
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


def _speed(test3: dict[str, object]) -> dict[str, float]:
    """Real-time factors on Test 3 (one core): the reference's replay, the learned model's fastest path.

    The learned model's figure is the native plugin's (Test 3's spools through ``mujoco.rollout``,
    one thread, :func:`hexgym.model.native_backend.native_rollout_realtime_factor`) when it is built, else the
    Python path's (this run's replay of Test 3).
    """
    from hexgym.model.native_backend import native_available, native_rollout_realtime_factor

    wall_ref, wall_python = test3["wall"]
    duration = float(test3["duration"])
    python = duration / wall_python
    native = native_available()
    learned = native_rollout_realtime_factor(seconds=3.0) if native else python
    reference = duration / wall_ref
    return {
        "simulated_s": duration,
        "reference_realtime_factor": reference,
        "learned_realtime_factor": learned,
        "learned_backend": "native" if native else "python",
        "learned_realtime_factor_python": python,
        "speedup": learned / reference,
    }


def run_validation(out_dir: str | Path, learned: LearnedModel | None = None) -> dict[str, object]:
    """All three tests, plots and ``summary.json`` in ``out_dir``; returns the summary."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    reference, learned = ReferenceModel(), learned or LearnedModel()
    summary: dict[str, object] = {}
    for name, (log, pose) in scenarios().items():
        result = run_test(name, log, pose, reference, learned)
        plot_test(result, out_dir / f"{name}.png")
        errors = result["errors"]["tip_error"]
        summary[name] = {"mean_tip_error_m": float(errors.mean()), "max_tip_error_m": float(errors.max())}
        if name == "test3":
            summary["speed"] = _speed(result)
    write_json(out_dir / "summary.json", summary)
    return summary

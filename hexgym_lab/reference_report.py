"""The reference model's behaviour in numbers and plots: ``hexgym reference-report``.

Single functions at full spool (cylinder speeds, swing rpm), the paper's two interaction tests
(boom + bucket on pump 1, swing + stick on pump 2, each against the function alone) and the
model's speed as computing time per simulated second. Writes ``summary.json`` and
``interactions.png``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from hexgym.files import save_figure, write_json
from hexgym.hydraulics.reference import ReferenceModel
from hexgym.model.commandlog import CommandLog
from hexgym.model.replay import replay
from hexgym_lab.scenarios import POSE_LOW, POSE_SWING

FULL = 11.0  # mm
# Start poses (swing, boom, stick, bucket; rad) that leave the tested strokes room to run.
POSE_HIGH = np.array([0.0, 0.6, -0.4, 0.9])  # boom high, stick out, bucket curled


def _log(rows: list[tuple[float, float, float, float, float]]) -> CommandLog:
    table = np.array(rows, dtype=float)
    return CommandLog(table[:, 0], table[:, 1:])


def _step_log(spools: tuple[float, float, float, float], start: float = 0.5, end: float = 6.0) -> CommandLog:
    """Neutral, then ``spools`` (mm) from ``start`` to ``end``, then neutral for a second."""
    return _log([(0.0, 0, 0, 0, 0), (start, *spools), (end, 0, 0, 0, 0), (end + 1.0, 0, 0, 0, 0)])


def _steady(traj: np.ndarray, column: str, t0: float, t1: float) -> float:
    window = (traj["t"] >= t0) & (traj["t"] <= t1)
    return float(np.mean(traj[column][window]))


def single_function_speeds(sim: ReferenceModel) -> dict[str, float]:
    """Cylinder speeds (m/s) and swing speed (rpm) at full spool, one function at a time, empty bucket."""
    cases = {
        "boom_up_mps": ((0, FULL, 0, 0), POSE_LOW, "boom_velocity_mps"),
        "boom_down_mps": ((0, -FULL, 0, 0), POSE_HIGH, "boom_velocity_mps"),
        "stick_in_mps": ((0, 0, FULL, 0), POSE_HIGH, "stick_velocity_mps"),
        "stick_out_mps": ((0, 0, -FULL, 0), POSE_LOW + [0, 0.5, 0.9, 0], "stick_velocity_mps"),
        "bucket_curl_mps": ((0, 0, 0, FULL), POSE_LOW, "bucket_velocity_mps"),
        "bucket_open_mps": ((0, 0, 0, -FULL), POSE_HIGH, "bucket_velocity_mps"),
    }
    out = {}
    for name, (spools, pose, column) in cases.items():
        traj = replay(sim, _step_log(spools, end=3.0), start=pose)
        out[name] = round(_steady(traj, column, 1.5, 2.5), 4)
    traj = replay(sim, _step_log((FULL, 0, 0, 0), end=8.0), start=POSE_SWING)
    out["swing_rpm"] = round(_steady(traj, "qd_swing", 6.0, 8.0) * 60 / (2 * np.pi), 2)
    out["swing_seconds_to_90deg"] = round(float(traj["t"][np.argmax(traj["q_swing"] >= np.pi / 2)] - 0.5), 2)
    idle = replay(sim, _log([(0.0, 0, 0, 0, 0), (1.0, 0, 0, 0, 0)]))
    out["idle_flow_l_per_min"] = round(float(idle["pump1_flow_m3s"][-1]) * 60000, 1)
    return out


def interaction_tests(sim: ReferenceModel) -> dict[str, dict[str, np.ndarray]]:
    """The paper's Tests 1 and 2 (Figs 5-8), each with the slowed function also run alone."""
    return {
        "test1_boom_bucket": {
            "together": replay(sim, _step_log((0, FULL, 0, FULL), end=7.0), start=POSE_LOW),
            "alone": replay(sim, _step_log((0, FULL, 0, 0), end=7.0), start=POSE_LOW),
        },
        "test2_swing_stick": {
            "together": replay(sim, _step_log((FULL, 0, FULL, 0), end=7.0), start=POSE_SWING),
            "alone": replay(sim, _step_log((FULL, 0, 0, 0), end=7.0), start=POSE_SWING),
        },
    }


def interaction_figures(tests: dict[str, dict[str, np.ndarray]]) -> dict[str, float]:
    """Mean speed of the slowed function while the other moves, together vs alone."""
    t1, t2 = tests["test1_boom_bucket"], tests["test2_swing_stick"]
    bucket_moving = np.abs(t1["together"]["bucket_velocity_mps"]) > 0.02
    stick_moving = np.abs(t2["together"]["stick_velocity_mps"]) > 0.02

    def mean(traj: np.ndarray, column: str, mask: np.ndarray) -> float:
        return round(float(np.mean(traj[column][mask])), 4)

    return {
        "test1_boom_mps_while_bucket_moves": mean(t1["together"], "boom_velocity_mps", bucket_moving),
        "test1_boom_mps_alone_same_time": mean(t1["alone"], "boom_velocity_mps", bucket_moving),
        "test1_bucket_stops_at_s": round(float(t1["together"]["t"][bucket_moving][-1]), 2),
        "test2_swing_rad_s_while_stick_moves": mean(t2["together"], "qd_swing", stick_moving),
        "test2_swing_rad_s_alone_same_time": mean(t2["alone"], "qd_swing", stick_moving),
        "test2_stick_stops_at_s": round(float(t2["together"]["t"][stick_moving][-1]), 2),
    }


def plot_interactions(tests: dict[str, dict[str, np.ndarray]], path: Path) -> Path:
    """Figs 5-8 of the paper for the reference model: commands and responses, with and without the partner."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 2, figsize=(12, 9), sharex="col")
    panels = [
        ("test1_boom_bucket", "Test 1: boom + bucket (pump 1)", "boom", "bucket"),
        ("test2_swing_stick", "Test 2: swing + stick (pump 2)", "swing", "stick"),
    ]
    for col, (key, title, slowed, partner) in enumerate(panels):
        together, alone = tests[key]["together"], tests[key]["alone"]
        ax = axes[0, col]
        for name in (slowed, partner):
            ax.step(together["t"], together[f"{name}_spool_mm"], where="post", label=f"{name} spool")
        ax.set(title=title, ylabel="spool (mm)")
        ax.legend(loc="lower right")
        slowed_col = "qd_swing" if slowed == "swing" else f"{slowed}_velocity_mps"
        unit = "rad/s" if slowed == "swing" else "m/s"
        ax = axes[1, col]
        ax.plot(together["t"], together[slowed_col], label=f"{slowed}, with {partner}")
        ax.plot(alone["t"], alone[slowed_col], "--", label=f"{slowed} alone")
        ax.set(ylabel=f"{slowed} speed ({unit})")
        ax.legend(loc="lower right")
        ax = axes[2, col]
        ax.plot(together["t"], together[f"{partner}_velocity_mps"], label=f"{partner} cylinder (m/s)")
        pump = "pump1" if col == 0 else "pump2"
        ax2 = ax.twinx()
        ax2.plot(together["t"], together[f"{pump}_pressure_pa"] / 1e6, "k:", label=f"{pump} pressure")
        ax2.set_ylabel("pressure (MPa)")
        ax.set(xlabel="t (s)", ylabel=f"{partner} cylinder speed (m/s)")
        ax.legend(loc="upper left")
        ax2.legend(loc="upper right")
    fig.tight_layout()
    return save_figure(fig, path, dpi=90)


def benchmark(sim: ReferenceModel, seconds: float = 10.0) -> dict[str, float]:
    """Computing time per simulated second on one core, over a log that moves every function."""
    log = _log(
        [
            (0.0, 0, 0, 0, 0),
            (0.5, 0, -8, -11, -11),
            (2.5, 0, 0, 11, 9),
            (4.5, 11, 11, 0, 5),
            (7.0, 0, 0, -7, -11),
            (8.0, -11, -9, 0, 6),
            (seconds, 0, 0, 0, 0),
        ]
    )
    start = time.perf_counter()
    replay(sim, log)
    wall = time.perf_counter() - start
    return {
        "simulated_s": seconds,
        "wall_s": round(wall, 3),
        "runtime_to_simulated_ratio": round(wall / seconds, 4),
        "realtime_factor": round(seconds / wall, 2),
        "timestep_s": sim.timestep,
    }


def run_report(out_dir: str | Path) -> dict[str, object]:
    """Run everything, write ``summary.json`` and ``interactions.png`` to ``out_dir``; return the summary."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    sim = ReferenceModel()
    tests = interaction_tests(sim)
    summary = {
        "single_function": single_function_speeds(sim),
        "interactions": interaction_figures(tests),
        "speed": benchmark(sim),
    }
    plot_interactions(tests, out_dir / "interactions.png")
    write_json(out_dir / "summary.json", summary)
    return summary

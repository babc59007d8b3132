"""The reference model's behaviour in numbers and plots: ``hexgym reference-report``.

Single functions at full spool (cylinder speeds, swing rpm), the paper's two interaction tests
(boom + bucket on pump 1, swing + stick on pump 2, each against the function alone) and a third where
a two-pump valve shares its combined flow (boom raise + stick in), the published acceptance figures
beside the model's (:mod:`hexgym_lab.published_figures`) and the model's speed as computing time per
simulated second. Writes ``summary.json`` and ``interactions.png``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from hexgym.files import save_figure, write_json
from hexgym.hydraulics.circuit import DEFAULT_VALVE
from hexgym.hydraulics.reference import ReferenceModel
from hexgym.model.commandlog import CommandLog
from hexgym.model.replay import replay
from hexgym_lab.progress import Progress
from hexgym_lab.published_figures import published_figures
from hexgym_lab.scenarios import POSE_LOW, POSE_SWING

FULL = 11.0  # mm
# Start poses (swing, boom, stick, bucket; rad) that leave the tested strokes room to run.
POSE_HIGH = np.array([0.0, 0.6, -0.4, 0.9])  # boom high, stick out, bucket curled
POSE_STICK_OUT = np.array([0.0, -0.45, -0.4, 0.0])  # boom low, stick out: room to raise the boom and pull in


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
    out["swing_rpm"] = round(_steady(traj, "qd_swing_radps", 6.0, 8.0) * 60 / (2 * np.pi), 2)
    out["swing_seconds_to_90deg"] = round(float(traj["t"][np.argmax(traj["q_swing_rad"] >= np.pi / 2)] - 0.5), 2)
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
        "test3_boom_stick": {
            "together": replay(sim, _step_log((0, FULL, FULL, 0), end=4.0), start=POSE_STICK_OUT),
            "alone": replay(sim, _step_log((0, FULL, 0, 0), end=4.0), start=POSE_STICK_OUT),
        },
    }


def interaction_figures(tests: dict[str, dict[str, np.ndarray]]) -> dict[str, float]:
    """Mean speed of the slowed function while the other moves, together vs alone."""
    t1, t2, t3 = tests["test1_boom_bucket"], tests["test2_swing_stick"], tests["test3_boom_stick"]
    bucket_moving = np.abs(t1["together"]["bucket_velocity_mps"]) > 0.02
    stick_moving = np.abs(t2["together"]["stick_velocity_mps"]) > 0.02
    boom_stick = (t3["together"]["t"] > 1.0) & (t3["together"]["t"] < 2.0)

    def mean(traj: np.ndarray, column: str, mask: np.ndarray) -> float:
        return round(float(np.mean(traj[column][mask])), 4)

    return {
        "test1_boom_mps_while_bucket_moves": mean(t1["together"], "boom_velocity_mps", bucket_moving),
        "test1_boom_mps_alone_same_time": mean(t1["alone"], "boom_velocity_mps", bucket_moving),
        "test1_bucket_stops_at_s": round(float(t1["together"]["t"][bucket_moving][-1]), 2),
        "test2_swing_rad_s_while_stick_moves": mean(t2["together"], "qd_swing_radps", stick_moving),
        "test2_swing_rad_s_alone_same_time": mean(t2["alone"], "qd_swing_radps", stick_moving),
        "test2_stick_stops_at_s": round(float(t2["together"]["t"][stick_moving][-1]), 2),
        "test3_boom_mps_with_stick_in": mean(t3["together"], "boom_velocity_mps", boom_stick),
        "test3_boom_mps_alone": mean(t3["alone"], "boom_velocity_mps", boom_stick),
        "test3_stick_mps_with_boom_up": mean(t3["together"], "stick_velocity_mps", boom_stick),
    }


def plot_interactions(tests: dict[str, dict[str, np.ndarray]], path: Path) -> Path:
    """Figs 5-8 of the paper for the reference model: commands and responses, with and without the partner."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 3, figsize=(17, 9), sharex="col")
    panels = [
        ("test1_boom_bucket", "Test 1: boom + bucket", "boom", "bucket"),
        ("test2_swing_stick", "Test 2: swing + stick", "swing", "stick"),
        ("test3_boom_stick", "boom raise + stick in", "boom", "stick"),
    ]
    for col, (key, title, slowed, partner) in enumerate(panels):
        together, alone = tests[key]["together"], tests[key]["alone"]
        ax = axes[0, col]
        for name in (slowed, partner):
            ax.step(together["t"], together[f"{name}_spool_mm"], where="post", label=f"{name} spool")
        ax.set(title=title, ylabel="spool (mm)")
        ax.legend(loc="lower right")
        slowed_col = "qd_swing_radps" if slowed == "swing" else f"{slowed}_velocity_mps"
        unit = "rad/s" if slowed == "swing" else "m/s"
        ax = axes[1, col]
        ax.plot(together["t"], together[slowed_col], label=f"{slowed}, with {partner}")
        ax.plot(alone["t"], alone[slowed_col], "--", label=f"{slowed} alone")
        ax.set(ylabel=f"{slowed} speed ({unit})")
        ax.legend(loc="lower right")
        ax = axes[2, col]
        ax.plot(together["t"], together[f"{partner}_velocity_mps"], label=f"{partner} cylinder (m/s)")
        ax2 = ax.twinx()
        for pump, style in (("pump1", "k:"), ("pump2", "k--")):
            ax2.plot(together["t"], together[f"{pump}_pressure_pa"] / 1e6, style, lw=0.8, label=f"{pump} pressure")
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


def run_report(out_dir: str | Path, valve: str = DEFAULT_VALVE) -> dict[str, object]:
    """Run everything on the reference model with valve layout ``valve``, write ``summary.json`` and
    ``interactions.png`` to ``out_dir``; return the summary."""
    out_dir = Path(out_dir)
    sim = ReferenceModel(valve=valve)  # refuses an unknown layout before anything is written
    out_dir.mkdir(parents=True, exist_ok=True)
    with Progress(3, "reference-report", "part") as progress:
        tests = interaction_tests(sim)
        progress.update()
        summary = {"valve": valve, "single_function": single_function_speeds(sim)}
        progress.update()
        summary |= {"interactions": interaction_figures(tests), "published_figures": published_figures(valve),
                    "speed": benchmark(sim)}  # fmt: skip
        progress.update()
    plot_interactions(tests, out_dir / "interactions.png")
    write_json(out_dir / "summary.json", summary)
    return summary


def figures_table(figures: dict) -> str:
    """The published figures beside the model's, one line each (:func:`published_figures`' dict)."""
    lines = [f"published figures, valve {figures['valve']!r} (model / published, within +-20 %):"]
    rows = figures["cylinder_times_s"] | {f"swing_{k}": v for k, v in figures["swing"].items()}
    for name, row in rows.items():
        mark = "yes" if row["within"] else "NO"
        lines.append(f"  {name:20s} {row['model']:6.2f} / {row['published']:5.1f}  ratio {row['ratio']:.2f}  {mark}")
    for name, row in figures["relief_settings_mpa"].items():
        low, high = row["published"]
        lines.append(
            f"  {name + ' relief':20s} {row['model']:6.1f} MPa in {low:g}-{high:g}  {'yes' if row['within'] else 'NO'}"
        )
    return "\n".join(lines)

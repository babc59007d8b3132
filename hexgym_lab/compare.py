"""``hexgym compare``: two runs scored against each other — trajectories, machine logs, or one of each.

Both are read as machine logs (:func:`hexgym_lab.machine_logs.read_machine_log`: a trajectory CSV is one, its
columns the format's), so a run needs only its joint angles (or the swing angle and the cylinder strokes). Over the
time both cover, both are interpolated (linearly) onto a common time base at the finer of their two sample periods;
the tip (the bucket teeth) of each comes from the angles through :func:`hexgym.machine.kinematics.tip_position`.
Reported: the tip error's mean and worst (and when), each joint's RMS and worst error (the swing's taken the short
way round the circle), and, with ``--out``, a plot of the tip error and the joints over time (matplotlib).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hexgym.machine import kinematics
from hexgym_lab.machine_logs.signals import MachineLog
from hexgym_lab.progress import track

MAX_SAMPLES = 1_000_000  # the common time base's length (memory: a few arrays of this many rows)


def _angles(log: MachineLog) -> tuple[np.ndarray, np.ndarray]:
    """The log's finite time stamps and angles (n, 4), ascending in time, the swing unwrapped."""
    q = log.angles()
    if q is None:
        raise ValueError(f"{log.name}: no joint angles (q_<joint>_rad) nor swing angle and cylinder strokes to compare")
    good = np.isfinite(log.t) & np.all(np.isfinite(q), axis=1)
    t, q = log.t[good], q[good]
    order = np.argsort(t, kind="stable")
    t, q = t[order], q[order]
    if len(t) < 2:
        raise ValueError(f"{log.name}: fewer than two samples with every joint angle")
    q[:, 0] = np.unwrap(q[:, 0])
    return t, q


def _period(t: np.ndarray) -> float:
    dt = np.diff(t)
    return float(np.median(dt[dt > 0]))


def tip_positions(q: np.ndarray, what: str = "tips") -> np.ndarray:
    """(n, 3) tip positions (m, world frame) of (n, 4) joint angles, through the kinematics' own law (about 45 µs a
    sample: an hour at 200 Hz takes half a minute, with progress shown)."""
    return np.array([kinematics.tip_position(row) for row in track(q, what, "sample")]).reshape(-1, 3)


def compare_logs(a: MachineLog, b: MachineLog) -> dict:
    """``a`` against ``b`` over their overlap (see the module): a JSON-ready summary and, under ``"series"``, the
    common time base, both runs' angles and the tip error (arrays, for the plot)."""
    ta, qa = _angles(a)
    tb, qb = _angles(b)
    t0, t1 = max(ta[0], tb[0]), min(ta[-1], tb[-1])
    if not t1 > t0:
        raise ValueError(f"{a.name} (t {ta[0]:g}-{ta[-1]:g} s) and {b.name} (t {tb[0]:g}-{tb[-1]:g} s) do not "
                         "overlap in time: nothing to compare")  # fmt: skip
    step = min(_period(ta), _period(tb))
    n = int(np.floor((t1 - t0) / step + 1e-9)) + 1
    if n > MAX_SAMPLES:
        raise ValueError(f"{a.name}, {b.name}: {n} common samples over {t1 - t0:g} s; at most {MAX_SAMPLES}")
    t = t0 + step * np.arange(n)
    ja = np.column_stack([np.interp(t, ta, qa[:, j]) for j in range(4)])
    jb = np.column_stack([np.interp(t, tb, qb[:, j]) for j in range(4)])
    error = ja - jb
    error[:, 0] = (error[:, 0] + np.pi) % (2 * np.pi) - np.pi  # the swing the short way round
    tip = np.linalg.norm(tip_positions(ja, "compare: A's tips") - tip_positions(jb, "compare: B's tips"), axis=1)
    worst = int(np.argmax(tip))
    rms, top = np.sqrt(np.mean(error**2, axis=0)), np.max(np.abs(error), axis=0)
    joints = {name: {"rms_rad": float(rms[j]), "max_rad": float(top[j])} for j, name in enumerate(kinematics.JOINTS)}
    return {
        "a": a.name,
        "b": b.name,
        "t0_s": float(t0),
        "t1_s": float(t1),
        "samples": n,
        "tip_error_mean_m": float(np.mean(tip)),
        "tip_error_max_m": float(tip[worst]),
        "tip_error_max_at_s": float(t[worst]),
        "joints": joints,
        "series": {"t": t, "a": ja, "b": jb, "tip_error_m": tip},
    }


def summary_text(result: dict) -> str:
    """The comparison as a few lines of text."""
    lines = [
        f"{result['a']} vs {result['b']}: t {result['t0_s']:g}-{result['t1_s']:g} s, {result['samples']} samples",
        f"tip error: mean {result['tip_error_mean_m']:.4f} m, worst {result['tip_error_max_m']:.4f} m "
        f"at t {result['tip_error_max_at_s']:.2f} s",
    ]
    for name, e in result["joints"].items():
        lines.append(f"  {name:6s} RMS {e['rms_rad']:.4f} rad, worst {e['max_rad']:.4f} rad")
    return "\n".join(lines)


def require_plotting() -> None:
    """ValueError, one line, where matplotlib (``hexgym[plots]``) is not installed: checked before any work."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise ValueError("--out: plotting needs matplotlib: pip install 'hexgym[plots]'") from None


def plot_comparison(result: dict, path: str | Path) -> Path:
    """The tip error and the four joints of both runs over time, to a PNG (needs matplotlib: ``hexgym[plots]``)."""
    require_plotting()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hexgym.files import save_figure

    series = result["series"]
    fig, axes = plt.subplots(5, 1, figsize=(8, 10), sharex=True)
    axes[0].plot(series["t"], series["tip_error_m"], color="C3")
    axes[0].set_ylabel("tip error, m")
    for j, name in enumerate(kinematics.JOINTS):
        axes[j + 1].plot(series["t"], series["a"][:, j], label=Path(result["a"]).name)
        axes[j + 1].plot(series["t"], series["b"][:, j], "--", label=Path(result["b"]).name)
        axes[j + 1].set_ylabel(f"{name}, rad")
    axes[1].legend(loc="best", fontsize="small")
    axes[-1].set_xlabel("t, s")
    fig.tight_layout()
    return save_figure(fig, path)

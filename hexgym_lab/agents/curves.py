"""Learning curves over training seeds: the ``curve.csv`` of ``hexgym train`` runs, as a figure and a summary.

Each run directory (``<log-dir>/<algo>_<env>``, or the file itself) holds one row per rollout (steps, wall
seconds, episodes ended, their mean return and success rate, tonnes delivered). The runs' curves are put on
common step counts (each run's value at a step is its last rollout's at or before it) and drawn as the mean
over runs with the band from the lowest to the highest.
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from hexgym_lab.agents.training import CURVE_COLUMNS

CURVE_FILE = "curve.csv"
SMOOTHING_ROLLOUTS = 5  # a run's curve is the mean of its last this many rollouts (one holds 10-50 episodes)
FIGURE_PANELS = ("success_rate", "mean_return", "delivered_t")


MAX_CURVE_BYTES = 64 * 2**20  # a curve.csv (a row per rollout: ~50 bytes; a long run has thousands)


def read_curve(path: str | Path) -> dict[str, np.ndarray]:
    """One run's ``curve.csv`` (a run directory or the file) as columns (NaN where a rollout had no value);
    ValueError naming the file, and the row and column, if it is not one: a truncated or damaged file, a
    number not written as ``hexgym train`` writes them (``1_0``, ``0x1``, ``nan``), steps that do not increase."""
    from hexgym.checks import parse_float
    from hexgym.files import check_input_file

    path = Path(path)
    if path.is_dir():
        path = path / CURVE_FILE
    if not os.path.lexists(path):
        raise ValueError(f"{path}: no learning curve (hexgym train writes {CURVE_FILE} in its run directory)")
    path = check_input_file(path, "learning curve")
    if path.stat().st_size > MAX_CURVE_BYTES:
        raise ValueError(f"{path}: {path.stat().st_size} bytes is too large for a learning curve")
    try:
        with path.open(newline="", encoding="utf-8") as f:
            rows = list(csv.reader(f))
    except (UnicodeDecodeError, csv.Error) as exc:
        raise ValueError(f"{path}: not a learning curve (not a CSV text file: {exc})") from None
    if not rows or tuple(rows[0]) != CURVE_COLUMNS:
        raise ValueError(f"{path}: not a learning curve (its header must be {','.join(CURVE_COLUMNS)})")
    if len(rows) < 2:
        raise ValueError(f"{path}: no rollout recorded yet")
    values = np.full((len(rows) - 1, len(CURVE_COLUMNS)), math.nan)
    for r, row in enumerate(rows[1:], start=1):
        if len(row) != len(CURVE_COLUMNS):
            raise ValueError(f"{path}: row {r} (line {r + 1}) has {len(row)} fields, not {len(CURVE_COLUMNS)} "
                             "(a truncated or damaged file)")  # fmt: skip
        for c, (name, text) in enumerate(zip(CURVE_COLUMNS, row, strict=True)):
            if text or c == 0:  # empty: nothing ended in that rollout (steps are always written)
                try:
                    values[r - 1, c] = parse_float(text, f"row {r} (line {r + 1}), column {name!r}")
                except ValueError as exc:
                    raise ValueError(f"{path}: a row is not numbers: {exc}") from None
        if r > 1 and not values[r - 1, 0] > values[r - 2, 0]:
            raise ValueError(f"{path}: row {r} (line {r + 1}): steps {values[r - 1, 0]:g} do not increase (rows "
                             "must have increasing steps)")  # fmt: skip
    return {name: values[:, k] for k, name in enumerate(CURVE_COLUMNS)}


def smoothed(values: np.ndarray, window: int = SMOOTHING_ROLLOUTS) -> np.ndarray:
    """The mean of each rollout's value and up to ``window - 1`` before it, ignoring NaNs (NaN if all are)."""
    out = np.full(len(values), math.nan)
    for i in range(len(values)):
        part = values[max(0, i - window + 1) : i + 1]
        if np.isfinite(part).any():
            out[i] = float(np.nanmean(part))
    return out


def on_steps(curve: dict[str, np.ndarray], column: str, steps: np.ndarray) -> np.ndarray:
    """A run's smoothed ``column`` at ``steps``: its last rollout's at or before each (NaN before its first)."""
    index = np.searchsorted(curve["steps"], steps, side="right") - 1
    values = smoothed(curve[column])
    return np.where(index >= 0, values[np.maximum(index, 0)], math.nan)


def summarise(curves: dict[str, dict[str, np.ndarray]], success_level: float = 0.9) -> dict[str, Any]:
    """Per run: its steps, final smoothed success rate and return, and the first step at which its smoothed
    success rate reached ``success_level`` (None if never); and the runs' means."""
    runs = {}
    for name, c in curves.items():
        success = smoothed(c["success_rate"])
        reached = np.flatnonzero(success >= success_level)
        runs[name] = {
            "steps": int(c["steps"][-1]),
            "final_success_rate": _finite(success[-1]),
            "final_mean_return": _finite(smoothed(c["mean_return"])[-1]),
            f"steps_to_success_{success_level:g}": int(c["steps"][reached[0]]) if len(reached) else None,
            "wall_s": _finite(c["wall_s"][-1]),
        }
    finals = [r["final_success_rate"] for r in runs.values() if r["final_success_rate"] is not None]
    return {
        "runs": runs,
        "smoothing_rollouts": SMOOTHING_ROLLOUTS,
        "mean_final_success_rate": float(np.mean(finals)) if finals else None,
        "runs_reaching_success_level": sum(r[f"steps_to_success_{success_level:g}"] is not None for r in runs.values()),
    }


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def _steps_label(steps: float, _position: int) -> str:
    """An axis label for a step count: 250k, 1.5M."""
    return f"{steps / 1e6:g}M" if steps >= 1e6 else f"{steps / 1e3:g}k" if steps else "0"


def plot_curves(curves: dict[str, dict[str, np.ndarray]], out: str | Path, title: str = "") -> Path:
    """The runs' mean and min-max band of each panel that has values (success rate, mean return, tonnes
    delivered per rollout) against steps, saved atomically to ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    from hexgym.files import save_figure

    last = min(int(c["steps"][-1]) for c in curves.values())
    steps = np.linspace(0, last, 200)
    panels = [p for p in FIGURE_PANELS if any(np.isfinite(c[p]).any() for c in curves.values())]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.2), squeeze=False)
    for ax, column in zip(axes[0], panels, strict=True):
        values = np.array([on_steps(c, column, steps) for c in curves.values()])
        seen = np.isfinite(values).any(axis=0)
        ax.fill_between(steps[seen], np.nanmin(values[:, seen], axis=0), np.nanmax(values[:, seen], axis=0),
                        alpha=0.25, label=f"min-max of {len(curves)} run{'s' if len(curves) > 1 else ''}")  # fmt: skip
        ax.plot(steps[seen], np.nanmean(values[:, seen], axis=0), label="mean")
        ax.set_xlabel("environment steps")
        ax.xaxis.set_major_formatter(FuncFormatter(_steps_label))
        ax.set_ylabel(column.replace("_", " "))
        ax.grid(alpha=0.3)
    axes[0][0].legend(loc="lower right", fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return save_figure(fig, out)

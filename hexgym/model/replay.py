"""Replaying a command log on any machine model, sampled at a fixed output interval.

The machine models (:class:`hexgym.hydraulics.reference.ReferenceModel` and the learned model on
either backend) follow :class:`hexgym.model.base.MachineModel`.
"""

from __future__ import annotations

import numpy as np

from hexgym.model.base import MachineModel
from hexgym.model.commandlog import CommandLog


def replay(
    model: MachineModel,
    commands: CommandLog,
    start: str | np.ndarray = "home",
    payload_kg: float = 0.0,
    dt_out: float = 0.05,
    duration: float | None = None,
) -> np.ndarray:
    """Reset ``model`` and replay ``commands``; rows every ``dt_out`` s from 0 to ``duration``.

    ``dt_out`` must be a multiple of the model's step; ``duration`` defaults to the log's last
    time stamp (its last row closes the log).
    """
    dt = model.control_period
    steps_per_row = int(round(dt_out / dt))
    if not np.isfinite(dt_out) or steps_per_row < 1 or abs(steps_per_row * dt - dt_out) > 1e-9:
        raise ValueError(f"dt_out must be a positive multiple of the model's control period {dt} s, got {dt_out}")
    end = float(commands.t[-1]) if duration is None else float(duration)
    if not np.isfinite(end) or end < 0.0:
        raise ValueError(f"duration must be a finite time >= 0 s, got {duration}")
    model.reset(start, payload_kg)
    n_rows = int(np.floor(end / dt_out + 1e-9)) + 1
    model.spools_m = commands.spools_at(0.0) * 1e-3
    first = model.observe()
    rows = np.empty(n_rows, dtype=first.dtype)
    rows[0] = first
    for k in range(1, n_rows):
        for j in range(steps_per_row):
            t = ((k - 1) * steps_per_row + j) * dt
            model.step(commands.spools_at(t + 1e-9 * dt) * 1e-3)
        rows[k] = model.observe()
    return rows

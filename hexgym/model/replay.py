"""Replaying a command log on any machine model, sampled at a fixed output interval.

The machine models (:class:`hexgym.hydraulics.reference.ReferenceModel` and the learned model on
either backend) follow :class:`hexgym.model.base.MachineModel`.
"""

from __future__ import annotations

import mujoco
import numpy as np

from hexgym.model.base import MachineModel
from hexgym.model.commandlog import CommandLog

MAX_OUTPUT_ROWS = 1_000_000  # trajectory rows (~0.3 GB in memory, more as CSV): 14 h at the default 0.05 s


def check_replay_size(duration: float, dt_out: float) -> int:
    """The number of output rows of a replay of ``duration`` s every ``dt_out`` s, or a ValueError
    when they are not finite and positive or would exceed :data:`MAX_OUTPUT_ROWS` (memory)."""
    if not (np.isfinite(dt_out) and dt_out > 0):
        raise ValueError(f"dt_out must be a finite interval > 0 s, got {dt_out}")
    if not (np.isfinite(duration) and duration >= 0):
        raise ValueError(f"duration must be a finite time >= 0 s, got {duration}")
    rows = duration / dt_out + 1
    if rows > MAX_OUTPUT_ROWS:
        raise ValueError(
            f"a replay of {duration:g} s every {dt_out:g} s would make {rows:.3g} trajectory rows; the limit is "
            f"{MAX_OUTPUT_ROWS:.0e} ({MAX_OUTPUT_ROWS * dt_out / 3600:.3g} h at {dt_out:g} s): shorten the log or "
            "raise dt_out"
        )
    return int(np.floor(duration / dt_out + 1e-9)) + 1


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
    end = float(commands.t[-1]) if duration is None else float(duration)
    n_rows = check_replay_size(end, dt_out)
    steps_per_row = int(round(dt_out / dt))
    if steps_per_row < 1 or abs(steps_per_row * dt - dt_out) > 1e-9:
        raise ValueError(f"dt_out must be a positive multiple of the model's control period {dt} s, got {dt_out}")
    model.reset(start, payload_kg)
    warnings = _instability_warnings(model)
    model.spools_m = commands.spools_at(0.0) * 1e-3
    first = model.observe()
    rows = np.empty(n_rows, dtype=first.dtype)
    rows[0] = first
    for k in range(1, n_rows):
        for j in range(steps_per_row):
            t = ((k - 1) * steps_per_row + j) * dt
            model.step(commands.spools_at(t + 1e-9 * dt) * 1e-3)
        rows[k] = model.observe()
        _check_health(model, rows[k], k * dt_out, warnings)
    return rows


def _instability_warnings(model: MachineModel) -> int:
    """MuJoCo's count of bad-acceleration warnings in the model's data (0 for a model without one)."""
    data = getattr(getattr(model, "physics", None), "data", None)
    return 0 if data is None else int(data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number)


def _check_health(model: MachineModel, row: np.ndarray, time: float, warnings: int) -> None:
    """RuntimeError if the simulation went unstable: a non-finite output, or MuJoCo's own instability
    warning (it resets the state and logs to MUJOCO_LOG.TXT only, so it is looked for here)."""
    values = np.array(row.tolist(), dtype=float)
    if not np.all(np.isfinite(values)):
        bad = [n for n, v in zip(row.dtype.names, values, strict=True) if not np.isfinite(v)]
        raise RuntimeError(f"the simulation became unstable at t = {time:g} s ({', '.join(bad[:4])} not finite)")
    if _instability_warnings(model) > warnings:
        raise RuntimeError(f"the simulation became unstable at t = {time:g} s (MuJoCo: bad accelerations)")

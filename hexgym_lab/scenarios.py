"""The validation's command logs: the paper's Tests 1 and 2 (two functions fighting over one pump)
and Test 3 (three loading cycles), each with its start pose.

Used by ``hexgym validate`` (:mod:`hexgym_lab.validate`) and by the benchmarks, which replay
Test 3 (:mod:`hexgym_lab.bench`).
"""

from __future__ import annotations

import numpy as np

from hexgym.machine import parameters as p
from hexgym.model.commandlog import CommandLog

POSE_LOW = np.array([0.0, -0.45, 0.0, -0.9])  # boom low, bucket open
POSE_SWING = np.array([0.0, 0.3, 0.3, 0.5])
POSE_CYCLE = np.array([0.0, 0.2, 0.4, 0.3])


def ramped_log(keys: list[tuple[float, float, float, float, float]], ramp: float = 0.4, dt: float = 0.05) -> CommandLog:
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
    test1 = ramped_log([(0.0, 0, 0, 0, 0), (0.5, 0, full, 0, full), (7.0, 0, 0, 0, 0), (8.0, 0, 0, 0, 0)], ramp=0.2)
    test2 = ramped_log([(0.0, 0, 0, 0, 0), (0.5, full, 0, full, 0), (7.0, 0, 0, 0, 0), (9.0, 0, 0, 0, 0)], ramp=0.2)
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
    return {"test1": (test1, POSE_LOW), "test2": (test2, POSE_SWING), "test3": (ramped_log(keys), POSE_CYCLE)}

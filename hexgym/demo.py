"""The demo: replay a scripted spool sequence and film it (MP4 + PNG snapshot).

Until the learned hydraulic model lands, the demo's valve is the simplest honest one: each
spool meters its cylinder's speed in proportion to its opening, up to one pump's full flow
into the driven chamber (no load, no flow sharing); the servos in the MJCF then track those
rates. Later issues replace this with the learned model driving a loading cycle.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hexgym import parameters as p
from hexgym.commandlog import CommandLog
from hexgym.physics import ExcavatorPhysics

# t (s), swing, boom, stick, bucket spools (mm), each row held until the next (command-log style)
_DEMO_TABLE = np.array(
    [
        [0.0, 0, 0, 0, 0],
        [0.5, 0, 8, -11, -11],  # reach out: boom up, stick out, bucket open
        [3.0, 0, -9, 0, 0],  # lower the bucket to the ground
        [5.0, 0, 0, 11, 8],  # crowd the stick and curl: a dig pass
        [7.5, 11, 11, 0, 6],  # raise and swing left
        [10.5, 0, 0, -6, -11],  # stick out and dump
        [12.0, -11, -6, 0, 8],  # swing back, lower, curl
        [15.0, 0, 0, 0, 0],
    ],
    dtype=float,
)
DEMO_COMMANDS = CommandLog(_DEMO_TABLE[:, 0], _DEMO_TABLE[:, 1:])
DEMO_DURATION = 16.0  # s


def proportional_valve_rates(physics: ExcavatorPhysics, spools_mm: np.ndarray) -> np.ndarray:
    """Joint rates (rad/s) of an unloaded proportional valve with a pump's full flow per function."""
    opening = np.clip(np.asarray(spools_mm, dtype=float) / (p.SPOOL_STROKE * 1e3), -1.0, 1.0)
    areas = [(c.head_area, c.rod_area) for c in p.CYLINDERS.values()]
    speeds = np.array(
        [o * p.PUMP_MAX_FLOW / (a[0] if o > 0 else a[1]) for o, a in zip(opening[1:], areas, strict=True)]
    )
    return np.concatenate([[opening[0] * p.SWING_SPEED], speeds / physics.moment_arms()])


def run_demo(
    out_dir: str | Path, fps: float = 20.0, width: int = 960, height: int = 544, duration: float = DEMO_DURATION
) -> dict[str, Path]:
    """Simulate the scripted sequence, write ``demo.mp4`` and ``demo.png``; return their paths."""
    from hexgym.render import FrameRenderer, write_mp4, write_png

    out_dir = Path(out_dir)
    physics = ExcavatorPhysics(scene=True)
    renderer = FrameRenderer(physics.model, width=width, height=height)
    steps_per_frame = max(1, round(1.0 / (fps * physics.timestep)))
    frames = []
    while physics.time < duration:
        for _ in range(steps_per_frame):
            physics.set_actuator_targets(proportional_valve_rates(physics, DEMO_COMMANDS.spools_at(physics.time)))
            physics.step()
        frames.append(renderer.render(physics.data))
    renderer.close()
    snapshot = frames[int(len(frames) * 0.55)]
    return {
        "video": write_mp4(frames, out_dir / "demo.mp4", fps=fps),
        "snapshot": write_png(snapshot, out_dir / "demo.png"),
    }

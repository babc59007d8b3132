"""The demo: the learned machine model replays a scripted spool sequence, filmed (MP4 + PNG).

The machine is :class:`hexgym.learned.LearnedModel` in the scene (ground, sun, chase camera):
MuJoCo's linkage loads into the MBL tables, so the functions share their pumps' flow as the real
machine does. A later issue makes this a loading-cycle rollout of an agent.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hexgym.commandlog import CommandLog
from hexgym.learned import LearnedModel
from hexgym.resources import load_model

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


def run_demo(
    out_dir: str | Path, fps: float = 20.0, width: int = 960, height: int = 544, duration: float = DEMO_DURATION
) -> dict[str, Path]:
    """Simulate the scripted sequence, write ``demo.mp4`` and ``demo.png``; return their paths."""
    from hexgym.render import FrameRenderer, write_mp4, write_png

    out_dir = Path(out_dir)
    machine = LearnedModel(model=load_model(scene=True))
    machine.reset("home")
    physics = machine.physics
    renderer = FrameRenderer(physics.model, width=width, height=height)
    periods_per_frame = max(1, round(1.0 / (fps * machine.timestep)))
    frames = []
    while physics.time < duration:
        machine.step(DEMO_COMMANDS.spools_at(physics.time) * 1e-3, n=periods_per_frame)
        frames.append(renderer.render(physics.data))
    renderer.close()
    snapshot = frames[int(len(frames) * 0.55)]
    return {
        "video": write_mp4(frames, out_dir / "demo.mp4", fps=fps),
        "snapshot": write_png(snapshot, out_dir / "demo.png"),
    }

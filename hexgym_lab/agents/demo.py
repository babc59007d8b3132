"""The demo: the scripted loader works the HexLoading-v0 site, filmed from the chase camera (MP4 + PNG).

The machine is the learned model (MuJoCo linkage + MBL tables) driven by
:class:`hexgym.agents.scripted.ScriptedLoader`: it digs from the pile, swings, dumps into the truck
and returns. Frames are taken at the environment's 10 Hz control rate, each with the films' caption
(:func:`hexgym_lab.agents.film.film_frame`: time, phase, tonnes in the bucket and delivered, fuel).
"""

from __future__ import annotations

import math
from pathlib import Path

from hexgym.agents.scripted import run_scripted
from hexgym.checks import check_positive, check_seed
from hexgym.envs.loading import STEP_PERIOD, HexLoadingEnv
from hexgym.files import check_output_dir, check_output_file
from hexgym_lab.agents.film import film_frame
from hexgym_lab.progress import CountingList, Progress

DEMO_DURATION = 60.0  # s of simulated time: two loading cycles
DEMO_SEED = 0


def run_demo(
    out_dir: str | Path,
    fps: float | None = None,
    width: int = 960,
    height: int = 544,
    duration: float = DEMO_DURATION,
    seed: int = DEMO_SEED,
) -> dict[str, Path | dict]:
    """Run the scripted loader for ``duration`` s; write ``demo.mp4`` and ``demo.png`` (replaced as a pair, or
    neither: a failed or interrupted run leaves the previous pair).

    ``fps`` is the playback rate (default: the control rate, 10, real time; 20 plays at 2x).
    Returns the two paths and the run's figures (``metrics``, see :func:`run_scripted`).
    """
    from hexgym.machine.render import check_frame_memory, write_mp4

    if check_positive("seconds", duration, "s") < STEP_PERIOD:
        raise ValueError(f"seconds must be at least one control step ({STEP_PERIOD} s), got {duration}")
    check_seed("seed", seed)
    if fps is not None:
        check_positive("fps", fps)
    check_frame_memory(int(duration / STEP_PERIOD) + 2, width, height, "the demo")
    check_output_dir(out_dir, "demo output directory")
    for name in ("demo.mp4", "demo.png"):
        check_output_file(Path(out_dir) / name, "demo output")
    env = HexLoadingEnv(render_mode="rgb_array", width=width, height=height, time_limit=max(duration, 0.1))
    fps = float(fps) if fps is not None else float(env.metadata["render_fps"])
    with Progress(math.ceil(duration / STEP_PERIOD - 1e-9), "demo", "frame") as progress:
        frames = CountingList(progress)
        metrics = run_scripted(env, seed=seed, seconds=duration, frames=frames, film=film_frame)
    env.close()
    snapshot = frames[int(len(frames) * 0.45)]  # mid-cycle: the loaded bucket on its way
    video, picture = Path(out_dir) / "demo.mp4", Path(out_dir) / "demo.png"
    write_mp4(frames, video, fps=fps, snapshot=(snapshot, picture))
    return {"video": video, "snapshot": picture, "metrics": metrics}

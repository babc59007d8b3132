"""``hexgym video``: offscreen rollouts of a policy on HexLoading-v0 as an MP4, with the films' caption.

Frames come from the environment's own ``rgb_array`` rendering (chase or cab camera), one per
10 Hz step; each carries the caption every film of hexgym carries (:func:`hexgym_lab.agents.film.film_frame`:
the episode, time, loading phase, tonnes in the bucket and delivered, fuel).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from hexgym.agents import POLICY_NAMES
from hexgym.agents.policies import Policy, load_policy
from hexgym.checks import check_count, check_positive, check_seed
from hexgym.envs import DIG_ENV_ID, ENV_ID
from hexgym.envs.loading import STEP_PERIOD
from hexgym.files import check_output_file
from hexgym.machine.names import CAMERAS
from hexgym.machine.render import check_frame_memory, write_mp4
from hexgym_lab.agents.evaluate import run_episode, run_success_episode
from hexgym_lab.agents.film import film_frame
from hexgym_lab.progress import CountingList, Progress


def _frame_recorder(frames: list[np.ndarray], episode: int) -> Any:
    """A :func:`run_episode` callback that appends the captioned frame of each step."""

    def on_step(env: Any, info: dict) -> None:
        frames.append(film_frame(env, info, label=f"ep {episode}"))

    return on_step


def _dig_episode(env: gym.Env, policy: Policy, seed: int, frames: list[np.ndarray], episode: int) -> dict[str, Any]:
    """One ``HexDig-v0`` episode, its captioned frames appended: whether and when it succeeded, its return."""

    def on_step(env: Any, info: dict) -> None:
        frames.append(film_frame(env, info, label=f"ep {episode}", note="lifted" if info["is_success"] else ""))

    success, steps, total = run_success_episode(env, policy, seed, on_step)
    return {"seed": seed, "success": success, "time_s": steps * STEP_PERIOD, "return": total}


def record_video(
    policy_spec: str,
    out: str | Path,
    camera: str = "chase",
    episodes: int = 1,
    seed: int = 0,
    seconds: float | None = None,
    width: int = 640,
    height: int = 384,
    snapshot: str | Path | None = None,
    model: str = "learned",
    env_id: str = ENV_ID,
) -> dict[str, Any]:
    """Render ``episodes`` rollouts of a policy (``"scripted"``, ``"shipped"`` or a model path) to ``out``.

    ``seconds`` stops each episode's film early (the episode itself keeps the task's time budget, which the
    observation counts down: a shorter budget would change what a trained policy does); ``snapshot`` also
    writes a PNG of a frame from the middle of the first episode (the video and it are replaced as a pair, or
    neither); ``model``: the machine model, ``"learned"`` or
    ``"reference"`` (the real machine's stand-in); ``env_id``: ``HexLoading-v0`` or ``HexDig-v0`` (a model
    trained on it, or ``"scripted"``). Returns the paths and each episode's figures.
    """
    if env_id not in (ENV_ID, DIG_ENV_ID):
        raise ValueError(f"--env must be {ENV_ID} or {DIG_ENV_ID} (the tasks that render), got {env_id!r}")
    if env_id == DIG_ENV_ID and policy_spec == "shipped":
        raise ValueError(f"the shipped agent loads trucks: film {DIG_ENV_ID} with a model trained on it or 'scripted'")
    if camera not in CAMERAS:
        raise ValueError(f"camera must be one of {CAMERAS}, got {camera!r}")
    check_count("episodes", episodes)
    check_seed("seed", seed)
    check_count("width", width)
    check_count("height", height)
    if seconds is not None:
        check_positive("seconds", seconds, "s")
    if not str(out).endswith(".mp4"):
        raise ValueError(f"the video must be an .mp4 file, got {out}")
    policy_file = None if policy_spec in POLICY_NAMES else policy_spec
    check_output_file(out, "video", inputs=(policy_file,))
    if snapshot is not None:
        check_output_file(snapshot, "snapshot", inputs=(policy_file, out))
    policy = load_policy(policy_spec, env_id, env_kwargs={"model": model})
    kwargs: dict[str, Any] = {"render_mode": "rgb_array", "camera": camera, "width": width, "height": height,
                              "model": model}  # fmt: skip
    if seconds is not None:
        kwargs["max_episode_steps"] = math.ceil(seconds / STEP_PERIOD - 1e-9)  # Gymnasium's TimeLimit truncates
    env = gym.make(env_id, **kwargs)
    limit = env.unwrapped.time_limit if seconds is None else min(seconds, env.unwrapped.time_limit)
    steps = math.ceil(limit / STEP_PERIOD - 1e-9) + 1
    check_frame_memory(int(episodes) * steps, width, height)
    progress = Progress(int(episodes) * steps, "video", "frame")
    frames: list[np.ndarray] = CountingList(progress)
    summaries = []
    still = None  # the snapshot's frame: the middle of the first episode
    try:
        for i in range(int(episodes)):
            if env_id == ENV_ID:
                summaries.append(run_episode(env, policy, seed + i, _frame_recorder(frames, i + 1)).summary())
            else:
                summaries.append(_dig_episode(env, policy, seed + i, frames, i + 1))
            if i == 0:
                still = frames[len(frames) // 2]
    finally:
        progress.close()
        env.close()
    fps = float(env.metadata["render_fps"])
    pair = None if snapshot is None else (still, snapshot)  # the video and its snapshot are replaced together
    result: dict[str, Any] = {"video": write_mp4(frames, out, fps=fps, snapshot=pair), "frames": len(frames),
                              "episodes": summaries}  # fmt: skip
    if snapshot is not None:
        result["snapshot"] = Path(snapshot)
    return result

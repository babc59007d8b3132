"""``hexgym bench``: HexLoading-v0's steps per second against Gymnasium's Hopper-v5, in one process.

Both environments are made with ``gymnasium.make`` (so both carry Gymnasium's default wrappers),
seeded, reset, then stepped with seeded random actions; only ``step`` calls are timed (a reset
after an episode end is not). The ratio is HexLoading-v0's rate over Hopper-v5's.
"""

from __future__ import annotations

import platform
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import hexgym  # noqa: F401 - registers HexLoading-v0
from hexgym.files import write_json
from hexgym.native import native_available, native_benchmark

REFERENCE_ENV = "Hopper-v5"


def steps_per_second(env_id: str, steps: int, seed: int = 0, **kwargs: object) -> float:
    """Random-action ``step`` calls per second of ``env_id`` made with ``kwargs`` (resets excluded from the timing)."""
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    env = gym.make(env_id, **kwargs)
    env.reset(seed=seed)
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(steps)]
    elapsed = 0.0
    for action in actions:
        start = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(action)
        elapsed += time.perf_counter() - start
        if terminated or truncated:
            env.reset()
    env.close()
    return steps / elapsed


def run_bench(steps: int = 2000, seed: int = 0) -> dict:
    """Steps per second of HexLoading-v0 and Hopper-v5 and their ratio (the target is >= 0.5)."""
    loading = steps_per_second("HexLoading-v0", steps, seed)
    hopper = steps_per_second(REFERENCE_ENV, steps, seed)
    native = steps_per_second("HexLoading-v0", steps, seed, backend="native") if native_available() else None
    return {
        "steps": steps,
        "hexloading_steps_per_s": loading,
        "hopper_steps_per_s": hopper,
        "ratio": loading / hopper,
        "hexloading_native_steps_per_s": native,  # backend="native": the machine model in the MuJoCo plugin
        "ratio_native": native / hopper if native else None,
        "hexloading_sim_seconds_per_s": loading * 0.1,  # one step is 0.1 s of simulated time
        **native_benchmark(seconds=2.0),  # learned_realtime_factor_python / _native (one thread)
        "machine": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "numpy": np.__version__,
    }


def print_bench(result: dict, json_path: str | Path | None = None) -> None:
    """Print the figures; with ``json_path`` also write them as JSON (atomically)."""
    print(f"HexLoading-v0: {result['hexloading_steps_per_s']:.0f} steps/s ({result['steps']} random steps)")
    print(f"{REFERENCE_ENV}:     {result['hopper_steps_per_s']:.0f} steps/s")
    print(f"ratio:         {result['ratio']:.3f} (target >= 0.5)")
    if result.get("hexloading_native_steps_per_s"):
        native = result["hexloading_native_steps_per_s"]
        print(f"HexLoading-v0, backend='native': {native:.0f} steps/s, ratio {result['ratio_native']:.3f}")
    for key in ("learned_realtime_factor_python", "learned_realtime_factor_native"):
        print(f"{key}: {result.get(key, float('nan')):.0f}x real time (one thread)")
    if json_path is not None:
        print(f"wrote {write_json(json_path, result)}")

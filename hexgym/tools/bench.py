"""``hexgym bench``: the speed figures of issue 8 in one process.

- ``hexloading_steps_per_s`` / ``hopper_steps_per_s``: HexLoading-v0 (default backend: the native
  plugin when built) against Gymnasium's Hopper-v5, both made with ``gymnasium.make`` (so both carry
  Gymnasium's default wrappers), seeded, reset, then stepped with seeded random actions; only
  ``step`` calls are timed (a reset after an episode end is not). They are stepped in turn, ten
  blocks each, so a slower spell of the machine weighs on both. ``ratio`` is the first over the
  second (target >= 1.0).
- ``vector_steps_per_s``: environment steps (transitions) per second of
  ``gymnasium.make_vec("HexLoading-v0", num_envs=64)`` with random actions: the registered vector
  entry point when there is one, else Gymnasium's ``SyncVectorEnv`` (``vector_env`` names which ran).
- ``learned_realtime_factor_python`` / ``_native`` (one thread) and ``batch_realtime_factor_native``
  (64 rollouts on every core): simulated seconds per wall second of the learned machine model
  alone, from :mod:`hexgym.model.native_backend` (targets: native >= 5,000x, batch >= 10,000x on 2 cores).
"""

from __future__ import annotations

import os
import platform
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import hexgym  # noqa: F401 - registers HexLoading-v0
from hexgym.files import write_json
from hexgym.model.native_backend import batch_benchmark, native_available, native_benchmark

REFERENCE_ENV = "Hopper-v5"
ENV_ID = "HexLoading-v0"
VECTOR_ENVS = 64
BATCH_ROLLOUTS = 64


def steps_per_second(env_id: str, steps: int, seed: int = 0, **kwargs: object) -> float:
    """Random-action ``step`` calls per second of ``env_id`` made with ``kwargs`` (resets excluded from the timing)."""
    return interleaved_steps_per_second({env_id: (env_id, kwargs)}, steps, seed)[env_id]


def interleaved_steps_per_second(
    envs: dict[str, tuple[str, dict]], steps: int, seed: int = 0, rounds: int = 10
) -> dict[str, float]:
    """Random-action ``step`` calls per second of each named ``(env_id, make kwargs)``, stepped in turn in
    ``rounds`` blocks of ``steps / rounds`` steps each, so that a change of the machine's speed during the
    run (other processes, a VM's neighbours) weighs on all of them alike and their ratios stay fair."""
    if steps < 1 or rounds < 1:
        raise ValueError(f"steps and rounds must be >= 1, got {steps} and {rounds}")
    made = {name: gym.make(env_id, **kwargs) for name, (env_id, kwargs) in envs.items()}
    try:
        actions = {}
        for name, env in made.items():
            env.reset(seed=seed)
            env.action_space.seed(seed)
            actions[name] = [env.action_space.sample() for _ in range(steps)]
        elapsed = dict.fromkeys(made, 0.0)
        bounds = np.linspace(0, steps, min(rounds, steps) + 1).astype(int)
        for first, last in zip(bounds[:-1], bounds[1:], strict=True):
            for name, env in made.items():
                elapsed[name] += _timed_steps(env, actions[name][first:last])
        return {name: steps / seconds for name, seconds in elapsed.items()}
    finally:
        for env in made.values():
            env.close()


def _timed_steps(env: gym.Env, actions: list) -> float:
    """Wall seconds in ``env.step`` over ``actions`` (an episode's end resets, untimed)."""
    elapsed = 0.0
    for action in actions:
        start = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(action)
        elapsed += time.perf_counter() - start
        if terminated or truncated:
            env.reset()
    return elapsed


def vector_steps_per_second(
    env_id: str = ENV_ID, num_envs: int = VECTOR_ENVS, vector_steps: int = 32, seed: int = 0
) -> tuple[float, str]:
    """Environment steps per second of ``gymnasium.make_vec(env_id, num_envs)`` under random actions,
    and the vector env's class name (only ``step`` calls are timed; its autoreset is part of them)."""
    if num_envs < 1 or vector_steps < 1:
        raise ValueError(f"num_envs and vector_steps must be >= 1, got {num_envs} and {vector_steps}")
    envs = gym.make_vec(env_id, num_envs=num_envs)
    try:
        envs.reset(seed=seed)
        envs.action_space.seed(seed)
        actions = [envs.action_space.sample() for _ in range(vector_steps)]
        start = time.perf_counter()
        for action in actions:
            envs.step(action)
        elapsed = time.perf_counter() - start
        return num_envs * vector_steps / elapsed, type(envs).__name__
    finally:
        envs.close()


def _physics_bound(vector_steps: int, seed: int) -> float:
    from hexgym.envs.vector import physics_bound_steps_per_second

    return physics_bound_steps_per_second(VECTOR_ENVS, vector_steps, seed)


def run_bench(steps: int = 2000, seed: int = 0, seconds: float = 2.0) -> dict:
    """All figures (see the module docstring); ``steps`` random steps per single environment (and as
    many environment steps of the vector env), ``seconds`` of wall time per real-time factor."""
    if not seconds > 0:
        raise ValueError(f"seconds must be > 0, got {seconds}")
    rates = interleaved_steps_per_second(
        {"loading": (ENV_ID, {}), "hopper": (REFERENCE_ENV, {}), "python": (ENV_ID, {"backend": "python"})},
        steps, seed,
    )  # fmt: skip
    loading, hopper, python = rates["loading"], rates["hopper"], rates["python"]
    vector, vector_env = vector_steps_per_second(vector_steps=max(1, steps // VECTOR_ENVS), seed=seed)
    bound = _physics_bound(max(1, steps // VECTOR_ENVS), seed) if vector_env == "HexLoadingVectorEnv" else None
    result = {
        "steps": steps,
        "hexloading_steps_per_s": loading,
        "hexloading_backend": "native" if native_available() else "python",
        "hopper_steps_per_s": hopper,
        "ratio": loading / hopper,
        "hexloading_python_steps_per_s": python,  # backend="python": the machine model in Python
        "ratio_python": python / hopper,
        "vector_steps_per_s": vector,
        "vector_envs": VECTOR_ENVS,
        "vector_env": vector_env,
        "vector_ratio": vector / hopper,
        # what the batch's physics alone allows the vector env (no task logic): the ceiling of vector_steps_per_s
        "vector_physics_bound_steps_per_s": bound,
        "hexloading_sim_seconds_per_s": loading * 0.1,  # one step is 0.1 s of simulated time
        **native_benchmark(seconds=seconds),  # learned_realtime_factor_python / _native (one thread)
    }
    if native_available():
        result.update(batch_benchmark(BATCH_ROLLOUTS, seconds=seconds), batch_rollouts=BATCH_ROLLOUTS)
        # what the batch made of each core it got: with other processes on the cores it got fewer
        result["batch_realtime_factor_per_core"] = result["batch_realtime_factor_native"] / result["batch_cores_used"]
    result.update(
        machine=platform.processor() or platform.machine(),
        cpus=os.cpu_count(),
        python=platform.python_version(),
        numpy=np.__version__,
    )
    return result


def print_bench(result: dict, json_path: str | Path | None = None) -> None:
    """Print the figures; with ``json_path`` also write them as JSON (atomically)."""
    r = result
    print(f"{ENV_ID}: {r['hexloading_steps_per_s']:.0f} steps/s ({r['steps']} random steps, {r['hexloading_backend']})")
    print(f"{REFERENCE_ENV}:     {r['hopper_steps_per_s']:.0f} steps/s")
    print(f"ratio:         {r['ratio']:.3f} (target >= 1.0)")
    print(
        f"{ENV_ID}, backend='python': {r['hexloading_python_steps_per_s']:.0f} steps/s, ratio {r['ratio_python']:.3f}"
    )
    vector = f"vector ({r['vector_envs']} envs, {r['vector_env']})"
    print(f"{vector}: {r['vector_steps_per_s']:.0f} env steps/s, ratio {r['vector_ratio']:.3f}")
    if r["vector_physics_bound_steps_per_s"] is not None:
        bound = r["vector_physics_bound_steps_per_s"]
        ratio = bound / r["hopper_steps_per_s"]
        print(f"  its physics alone (no task logic): {bound:.0f} env steps/s, ratio {ratio:.3f}")
    for key in ("learned_realtime_factor_python", "learned_realtime_factor_native"):
        print(f"{key}: {result.get(key, float('nan')):.0f}x real time (one thread)")
    if "batch_realtime_factor_native" in result:
        print(
            f"batch_realtime_factor_native: {result['batch_realtime_factor_native']:.0f}x real time"
            f" ({result['batch_rollouts']} rollouts, {result['batch_threads']} threads,"
            f" {result['batch_cores_used']:.2f} cores used: {result['batch_realtime_factor_per_core']:.0f}x per core)"
        )
    if json_path is not None:
        print(f"wrote {write_json(json_path, result)}")

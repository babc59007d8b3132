"""``hexgym evaluate``: run a policy on HexLoading-v0 over seeded episodes and measure its loading figures.

A policy is ``"scripted"`` (:class:`hexgym.agents.scripted.ScriptedLoader`), ``"shipped"`` (the
trained agent packaged in ``hexgym/policies``), the path of a Stable-Baselines3 ``.zip`` saved by
``hexgym train`` (its observation normaliser beside it, ``<stem>_vecnormalize.json``) or an RLlib checkpoint
directory, all loaded by :func:`hexgym.agents.policies.load_policy`. Every figure comes from the environment's
``info`` stream (``truck_kg``, ``spilled_kg``, ``fuel_l``, ``pile_kg``), so all policies are measured the same
way, whatever their internals.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from hexgym.agents.policies import Policy, load_policy
from hexgym.checks import check_count, check_seed
from hexgym.envs import DIG_ENV_ID, ENV_ID  # importing hexgym registers them
from hexgym.files import check_output_file, write_json
from hexgym.machine import parameters as p
from hexgym.mbl.schema import DEFAULT_TABLE_SET
from hexgym.parallel import executor
from hexgym_lab.progress import track

HEAPED_BUCKET_KG = p.BUCKET_HEAPED_CAPACITY * p.MATERIAL_DENSITY
# A dump counts as a full-enough bucket from half a heaped bucket (~1.07 t): the scripted loader's
# dumps carry 1.2-1.6 t; dribbles of a few hundred kg are not a loading cycle.
FULL_ENOUGH_KG = 0.5 * HEAPED_BUCKET_KG
DUMP_MERGE_GAP_S = 2.0  # s: deliveries closer than this are one dump (the flow pauses as the bucket tilts)
METRIC_KEYS = (
    "success_rate", "tonnes_per_hour", "mean_cycle_time_s", "fuel_l_per_tonne",
    "spilled_fraction", "delivered_t_per_episode",
)  # fmt: skip


@dataclass
class Episode:
    """The per-step trace of one episode that the figures are computed from."""

    seed: int
    time_s: list[float] = field(default_factory=list)
    truck_kg: list[float] = field(default_factory=list)
    spilled_kg: float = 0.0
    fuel_l: float = 0.0
    dug_kg: float = 0.0
    total_return: float = 0.0
    terminated: bool = False
    planner: dict[str, Any] | None = None  # a planning policy's figures (PlanningLoader.episode_figures)

    def dumps(self) -> list[tuple[float, float]]:
        """(start time s, delivered kg) of each dump: runs of deliveries with gaps under DUMP_MERGE_GAP_S."""
        t = np.asarray(self.time_s)
        delivered = np.diff(np.asarray([0.0, *self.truck_kg]))
        events: list[list[float]] = []
        for when, kg in zip(t[delivered > 0], delivered[delivered > 0], strict=True):
            if events and when - events[-1][2] < DUMP_MERGE_GAP_S:
                events[-1][1] += kg
                events[-1][2] = when
            else:
                events.append([when, kg, when])
        return [(start, kg) for start, kg, _ in events]

    def summary(self) -> dict[str, Any]:
        """This episode's figures."""
        full = [start for start, kg in self.dumps() if kg >= FULL_ENOUGH_KG]
        delivered = self.truck_kg[-1] if self.truck_kg else 0.0
        return {
            "seed": self.seed,
            "sim_seconds": self.time_s[-1] if self.time_s else 0.0,
            "delivered_t": delivered / 1000.0,
            "spilled_t": self.spilled_kg / 1000.0,
            "fuel_l": self.fuel_l,
            "dumps": len(self.dumps()),
            "full_dumps": len(full),
            "cycle_intervals_s": [float(dt) for dt in np.diff(full)],
            "return": self.total_return,
            "terminated": self.terminated,
        } | ({} if self.planner is None else {"planner": self.planner})


StepCallback = Callable[[Any, dict], None]


def run_episode(env: gym.Env, policy: Policy, seed: int, on_step: StepCallback | None = None) -> Episode:
    """Run one episode from ``env.reset(seed=seed)``; ``on_step(env, info)`` after each step (e.g. a renderer)."""
    obs, info = env.reset(seed=seed)
    policy.reset()
    episode = Episode(seed=seed)
    pile_start = info["pile_kg"]
    if on_step is not None:
        on_step(env, info)
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(policy.act(obs, env.unwrapped))
        episode.time_s.append(info["time_s"])
        episode.truck_kg.append(info["truck_kg"])
        episode.total_return += float(reward)
        done = terminated or truncated
        episode.terminated = bool(terminated)
        if on_step is not None:
            on_step(env, info)
    episode.spilled_kg, episode.fuel_l = info["spilled_kg"], info["fuel_l"]
    episode.dug_kg = pile_start - info["pile_kg"]
    if hasattr(policy, "episode_figures"):
        episode.planner = policy.episode_figures()
    return episode


BOOTSTRAP_RESAMPLES = 10_000  # episode resamples for the t/h interval: its ends move by <= 1.5 t/h between seeds


def tonnes_per_hour_interval(delivered_t: np.ndarray, seconds: np.ndarray) -> list[float] | None:
    """The 95 % bootstrap interval (percentile; episodes resampled) of the pooled t/h; None for one episode.

    Episodes differ a lot (one stall takes an episode to 180 s), so two policies' t/h on 20 episodes can
    differ by this much by chance; compare policies on the same seeds, and on more than one seed set.
    """
    if len(delivered_t) < 2:
        return None
    from scipy.stats import bootstrap

    def pooled(delivered: np.ndarray, time_s: np.ndarray, axis: int = -1) -> np.ndarray:
        return delivered.sum(axis=axis) / time_s.sum(axis=axis) * 3600.0

    result = bootstrap((delivered_t, seconds), pooled, paired=True, vectorized=True, n_resamples=BOOTSTRAP_RESAMPLES,
                       confidence_level=0.95, method="percentile", random_state=0)  # fmt: skip
    return [float(result.confidence_interval.low), float(result.confidence_interval.high)]


# HexLoading-v0's robustness options and their defaults: a result names those given
ROBUSTNESS_DEFAULTS = {"site_ranges": "training", "material_density_scale": 1.0, "engine_power_scale": 1.0}


def aggregate(episodes: list[Episode]) -> dict[str, Any]:
    """The figures over all episodes (totals pooled: t/h is total tonnes over total hours)."""
    summaries = [e.summary() for e in episodes]
    delivered_t = sum(s["delivered_t"] for s in summaries)
    spilled_t = sum(s["spilled_t"] for s in summaries)
    hours = sum(s["sim_seconds"] for s in summaries) / 3600.0
    fuel_l = sum(s["fuel_l"] for s in summaries)
    intervals = [dt for s in summaries for dt in s["cycle_intervals_s"]]
    return {
        "episodes": len(episodes),
        "success_rate": float(np.mean([s["full_dumps"] > 0 for s in summaries])),
        "tonnes_per_hour": delivered_t / hours if hours > 0 else 0.0,
        "tonnes_per_hour_ci95": tonnes_per_hour_interval(
            np.array([s["delivered_t"] for s in summaries]), np.array([s["sim_seconds"] for s in summaries])
        ),
        "mean_cycle_time_s": float(np.mean(intervals)) if intervals else None,
        "fuel_l_per_tonne": fuel_l / delivered_t if delivered_t > 0 else None,
        "spilled_fraction": spilled_t / (spilled_t + delivered_t) if spilled_t + delivered_t > 0 else 0.0,
        "delivered_t_per_episode": delivered_t / len(episodes),
        "mean_return": float(np.mean([s["return"] for s in summaries])),
        "full_enough_kg": FULL_ENOUGH_KG,
        **_planner_figures(summaries),
        "per_episode": summaries,
    }


def _planner_figures(summaries: list[dict[str, Any]]) -> dict[str, Any]:
    """A planning policy's figures over the episodes (none for other policies): plans made, their wall time
    (median, 95th percentile, worst), moves fallen back to the scripted loader's, plans made again."""
    planned = [s["planner"] for s in summaries if "planner" in s]
    if not planned:
        return {}
    walls = np.array([w for e in planned for w in e["plan_walls_s"]])
    return {"planner": {
        "plans": len(walls), "fallbacks": sum(e["fallbacks"] for e in planned),
        "replans": sum(e["replans"] for e in planned),
        "plan_wall_s_median": float(np.median(walls)) if len(walls) else None,
        "plan_wall_s_p95": float(np.quantile(walls, 0.95)) if len(walls) else None,
        "plan_wall_s_max": float(walls.max()) if len(walls) else None,
    }}  # fmt: skip


def evaluate(
    policy_spec: str,
    episodes: int = 20,
    seed: int = 0,
    env_kwargs: dict | None = None,
    json_out: str | None = None,
    workers: int = 1,
    ray: str | None = None,
    loader_settings: str | Path | None = None,
) -> dict[str, Any]:
    """Run ``episodes`` episodes (seeds ``seed``..``seed+episodes-1``) of a policy; the figures of :func:`aggregate`.

    ``success_rate``: share of episodes with at least one dump of FULL_ENOUGH_KG or more into the
    bed; ``mean_cycle_time_s``: mean time between the starts of successive full-enough dumps;
    ``spilled_fraction``: spilled / (spilled + delivered), of the material that left the bucket.
    ``workers`` > 1 processes or ``ray`` ("local" or a cluster's address, :mod:`hexgym.parallel`) run the
    episodes in parallel, each worker with the loaded policy and its own environment: the same figures.
    ``loader_settings``: the scripted loader's settings file (``policy_spec`` ``"scripted"``).
    """
    check_count("episodes", episodes)
    check_seed("seed", seed)
    check_count("workers", workers)
    if json_out:
        check_output_file(json_out, "JSON output", inputs=(policy_spec,))
    policy = load_policy(policy_spec, loader_settings=loader_settings, env_kwargs=env_kwargs)
    seeds = [seed + i for i in range(int(episodes))]
    with executor(min(workers, len(seeds)), ray, initializer=_init_worker, initargs=(policy, env_kwargs)) as pool:
        try:  # as they finish (the progress), then in seed order (the figures)
            done = track(pool.map_unordered(_run_seed, seeds), "evaluate", "episode", total=len(seeds))
            runs = sorted(done, key=lambda episode: episode.seed)
        finally:
            _close_worker()  # the environment of a run in this process
    model = (env_kwargs or {}).get("model", "learned")
    tables = (env_kwargs or {}).get("tables", DEFAULT_TABLE_SET) if model == "learned" else None
    result = {"policy": policy_spec, "env_id": ENV_ID, "model": model, "tables": tables, "seed": seed}
    result |= {name: value for name, value in (env_kwargs or {}).items() if name in ROBUSTNESS_DEFAULTS}
    result |= aggregate(runs)
    if loader_settings is not None:
        result["loader_settings"] = str(loader_settings)
    if json_out:
        write_json(json_out, result)
    return result


def run_success_episode(
    env: gym.Env, policy: Policy, seed: int, on_step: StepCallback | None = None
) -> tuple[bool, int, float]:
    """One episode of a task with a success criterion (``info["is_success"]`` at its end) from
    ``env.reset(seed=seed)``; ``on_step(env, info)`` after each step. Returns whether it succeeded, its steps
    and its return."""
    obs, info = env.reset(seed=seed)
    policy.reset()
    done, total, steps = False, 0.0, 0
    while not done:
        obs, reward, terminated, truncated, info = env.step(policy.act(obs, env.unwrapped))
        total, steps, done = total + float(reward), steps + 1, terminated or truncated
        if on_step is not None:
            on_step(env, info)
    return bool(info.get("is_success", False)), steps, total


def evaluate_success(
    model_path: str | Path, env_id: str, episodes: int = 50, seed: int = 0, env_kwargs: dict | None = None
) -> dict[str, Any]:
    """A trained model on a task with a success criterion (``info["is_success"]`` at the episode's end, e.g.
    ``HexReach-v0``), acting deterministically on seeds ``seed``..``seed+episodes-1``: the share of
    episodes that succeeded, the mean return and the mean episode length (of the successful ones: the
    time to succeed). ``"scripted"``: the scripted loader, on a task with the loading site (``HexDig-v0``)."""
    check_count("episodes", episodes)
    check_seed("seed", seed)
    if model_path == "scripted" and env_id != DIG_ENV_ID:
        raise ValueError(f"the scripted loader acts on the loading site: HexLoading-v0 or {DIG_ENV_ID}, not {env_id}")
    policy = load_policy(model_path, env_id, env_kwargs=env_kwargs)
    env = gym.make(env_id, **(env_kwargs or {}))
    try:
        seeds = range(seed, seed + int(episodes))
        runs = [run_success_episode(env, policy, s) for s in track(seeds, "evaluate", "episode")]
    finally:
        env.close()
    successes, returns = [ok for ok, _, _ in runs], [total for _, _, total in runs]
    won = [steps / env.metadata["render_fps"] for ok, steps, _ in runs if ok]
    return {
        "policy": str(model_path), "env_id": env_id, "seed": seed, "episodes": int(episodes),
        "success_rate": float(np.mean(successes)), "mean_return": float(np.mean(returns)),
        "mean_time_to_success_s": float(np.mean(won)) if won else None,
    }  # fmt: skip


_worker: dict[str, Any] = {}  # per process: the policy and its environment


def _init_worker(policy: Policy, env_kwargs: dict | None) -> None:
    _worker.update(policy=policy, env=gym.make(ENV_ID, **(env_kwargs or {})))


def _run_seed(seed: int) -> Episode:
    return run_episode(_worker["env"], _worker["policy"], seed)


def _close_worker() -> None:
    if "env" in _worker:
        _worker.pop("env").close()
    _worker.clear()

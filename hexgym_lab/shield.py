"""``hexgym shield``: the same seeded episodes of a policy with and without the collision shield.

Figures (pooled over the episodes; an hour is one of simulated time):

- ``contacts_per_hour_without`` / ``_with``: hard contacts (runs of steps whose bucket/stick contact force on
  truck or ground exceeds the environment's 50 kN, ``info["contact_impulse_ns"] > 0``) per hour;
- ``contact_reduction``: 1 - with / without;
- ``interventions_per_hour``: steps at which the shield replaced the action, per hour;
- ``tonnes_per_hour_without`` / ``_with``: delivered tonnes per hour, and their relative change;
- ``shield_ms_per_step``: the shield's own wall time per step (prediction and candidate search);
- ``step_ms_without`` / ``step_ms_with``: the whole step's wall time (policy excluded).

:func:`plot_comparison` draws them per episode.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from hexgym.agents.policies import Policy, load_policy
from hexgym.files import save_figure, write_json
from hexgym.mbl.schema import DEFAULT_TABLE_SET
from hexgym.wrappers import CollisionShield
from hexgym_lab.progress import Progress


class RandomPolicy:
    """Uniform random spools in [-1, 1], seeded per episode (the same actions with and without the shield)."""

    def __init__(self, seed: int = 0) -> None:
        self.seed = seed
        self.rng = np.random.default_rng(seed)

    def reset(self) -> None:
        """Restart the action sequence."""
        self.rng = np.random.default_rng(self.seed)

    def act(self, obs: np.ndarray, env: Any) -> np.ndarray:
        """A random action."""
        return self.rng.uniform(-1.0, 1.0, 4).astype(np.float32)


def _policy(spec: str, seed: int) -> Policy:
    return RandomPolicy(seed) if spec == "random" else load_policy(spec)


def run_episode(env: gym.Env, policy: Policy, seed: int) -> dict[str, float]:
    """One episode from ``env.reset(seed=seed)``: its hard contacts, interventions, tonnes, seconds and timings."""
    obs, info = env.reset(seed=seed)
    policy.reset()
    contacts = interventions = steps = 0
    touching = False
    step_s = shield_ms = 0.0
    done = False
    while not done:
        action = policy.act(obs, env.unwrapped)
        start = time.perf_counter()
        obs, _, terminated, truncated, info = env.step(action)
        step_s += time.perf_counter() - start
        hard = info["contact_impulse_ns"] > 0.0
        contacts += int(hard and not touching)
        touching = hard
        interventions += int(info.get("shield_intervened", False))
        shield_ms += info.get("shield_ms", 0.0)
        steps += 1
        done = terminated or truncated
    return {
        "seed": seed, "contacts": contacts, "interventions": interventions, "delivered_t": info["truck_kg"] / 1000.0,
        "sim_seconds": info["time_s"], "steps": steps, "step_ms": step_s * 1e3 / steps, "shield_ms": shield_ms / steps,
    }  # fmt: skip


def compare(
    policy_spec: str = "random",
    episodes: int = 4,
    seed: int = 0,
    seconds: float | None = None,
    horizon_s: float = 1.5,
    json_out: str | Path | None = None,
) -> dict[str, Any]:
    """Run episodes ``seed..seed+episodes-1`` of a policy without and with :class:`CollisionShield`; the figures."""
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    if not (np.isfinite(horizon_s) and 0 < horizon_s <= 60.0):
        raise ValueError(f"--horizon must be > 0 and at most 60 s, got {horizon_s}")
    kwargs = {} if seconds is None else {"time_limit": seconds}
    runs: dict[str, list[dict[str, float]]] = {"without": [], "with": []}
    with Progress(2 * episodes, "shield", "episode") as progress:
        for label in runs:
            env = gym.make("HexLoading-v0", **kwargs)
            if label == "with":
                env = CollisionShield(env, horizon_s=horizon_s)
            for k in range(episodes):
                runs[label].append(run_episode(env, _policy(policy_spec, seed + k), seed + k))
                progress.update(shield=label)
            env.close()
    out: dict[str, Any] = {"policy": policy_spec, "episodes": episodes, "seed": seed, "horizon_s": horizon_s}
    out["tables"] = DEFAULT_TABLE_SET  # the learned model the episodes and the shield's predictions run
    for label, eps in runs.items():
        hours = sum(e["sim_seconds"] for e in eps) / 3600.0
        steps = sum(e["steps"] for e in eps)
        out[f"contacts_per_hour_{label}"] = sum(e["contacts"] for e in eps) / hours
        out[f"tonnes_per_hour_{label}"] = sum(e["delivered_t"] for e in eps) / hours
        out[f"step_ms_{label}"] = sum(e["step_ms"] * e["steps"] for e in eps) / steps
        if label == "with":
            out["interventions_per_hour"] = sum(e["interventions"] for e in eps) / hours
            out["shield_ms_per_step"] = sum(e["shield_ms"] * e["steps"] for e in eps) / steps
    without, with_ = out["contacts_per_hour_without"], out["contacts_per_hour_with"]
    out["contact_reduction"] = 1.0 - with_ / without if without > 0 else None
    t_without = out["tonnes_per_hour_without"]
    out["tonnes_per_hour_change"] = out["tonnes_per_hour_with"] / t_without - 1.0 if t_without > 0 else None
    out["per_episode"] = runs
    if json_out is not None:
        write_json(json_out, out)
    return out


def reduction_text(result: dict[str, Any]) -> str:
    """The contact reduction as the printout and the plot both say it: two decimals, so that 99.96 % never reads as
    100.0 % (``n/a`` without contacts to reduce)."""
    reduction = result["contact_reduction"]
    return "n/a" if reduction is None else f"{100 * reduction:.2f} %"


def print_comparison(result: dict[str, Any]) -> None:
    """The figures as a few lines."""
    r = result

    def pct(v: float | None) -> str:
        return "n/a" if v is None else f"{100 * v:+.1f} %"

    print(f"policy {r['policy']}, {r['episodes']} episodes from seed {r['seed']}, horizon {r['horizon_s']} s")
    reduction = reduction_text(r)
    print(f"  hard contacts per hour: {r['contacts_per_hour_without']:.1f} without, {r['contacts_per_hour_with']:.1f} "
          f"with the shield (reduction {reduction})")  # fmt: skip
    print(f"  tonnes per hour:        {r['tonnes_per_hour_without']:.1f} without, {r['tonnes_per_hour_with']:.1f} with "
          f"({pct(r['tonnes_per_hour_change'])})")  # fmt: skip
    print(f"  interventions per hour: {r['interventions_per_hour']:.0f}; shield {r['shield_ms_per_step']:.2f} ms/step "
          f"(step {r['step_ms_without']:.2f} ms without, {r['step_ms_with']:.2f} ms with)")  # fmt: skip


def plot_comparison(result: dict[str, Any], out: str | Path) -> Path:
    """The comparison per episode as a PNG: hard contacts per hour without and with the shield (log scale: a random
    policy's fall by orders of magnitude), tonnes per hour without and with, and the shield's interventions per
    hour and its wall time per step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = result["per_episode"]
    seeds = np.array([e["seed"] for e in runs["without"]])
    per_hour = {label: {key: np.array([3600.0 * e[key] / e["sim_seconds"] for e in eps])
                        for key in ("contacts", "delivered_t", "interventions")}
                for label, eps in runs.items()}  # fmt: skip
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    width = 0.4
    for key, ax, title, unit in (("contacts", axes[0], "hard contacts", "per hour (log; 0 marked)"),
                                 ("delivered_t", axes[1], "delivered", "t per hour")):  # fmt: skip
        for shift, label, colour in ((-width / 2, "without", "C3"), (width / 2, "with", "C0")):
            values = per_hour[label][key]
            ax.bar(seeds + shift, values, width, color=colour, label=f"{label} the shield")
            if key == "contacts":  # a log axis has no 0: mark the episodes without a contact
                zero = values == 0
                ax.plot(seeds[zero] + shift, np.ones(zero.sum()), "o", color=colour, markersize=4)
        ax.set(xlabel="episode seed", ylabel=unit, title=title, xticks=seeds)
        if key == "contacts":
            ax.set_yscale("log")
            ax.set_ylim(bottom=0.5)
        elif not any(per_hour[label][key].any() for label in per_hour):
            ax.text(0.5, 0.5, "nothing delivered", transform=ax.transAxes, ha="center")
        ax.legend(fontsize=8)
    axes[2].bar(seeds, per_hour["with"]["interventions"], 0.6, color="C1")
    axes[2].set(xlabel="episode seed", ylabel="interventions per hour", xticks=seeds,
                title=f"interventions (shield {result['shield_ms_per_step']:.2f} ms/step)")  # fmt: skip
    reduction = "" if result["contact_reduction"] is None else f" ({reduction_text(result)} fewer)"
    fig.suptitle(f"collision shield, policy {result['policy']}, horizon {result['horizon_s']} s: hard contacts "
                 f"{result['contacts_per_hour_without']:.1f} -> {result['contacts_per_hour_with']:.1f} per hour"
                 f"{reduction}", fontsize=10)  # fmt: skip
    fig.tight_layout()
    return save_figure(fig, out)

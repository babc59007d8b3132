"""``hexgym train --framework rllib``: RLlib's PPO (new API stack) on HexLoading-v0, env runners across a Ray cluster.

The PPO hyperparameters come from the same rl-zoo3 YAML as the Stable-Baselines3 runs
(``hexgym_lab/hyperparams/ppo.yml``, :func:`hexgym_lab.agents.hyperparams.load_hyperparams`), mapped to
RLlib's names: a training batch of ``n_steps`` x ``n_envs`` steps per iteration, minibatches of
``batch_size``, ``n_epochs`` passes, ``gamma``, ``gae_lambda``, ``learning_rate``, ``clip_range``,
``ent_coef``; the actor's hidden layers from ``policy_kwargs.net_arch.pi`` (the critic has its own
network). Observations go in unnormalised (RLlib's filter state would have to travel with every
policy; the SB3 path's ``VecNormalize`` has no RLlib counterpart in the checkpoint format).

A run lives in ``<log_dir>/rllib_ppo_<env id>/``: ``checkpoint/`` is the newest RLlib checkpoint
(replaced atomically every ``checkpoint_every`` steps and at the end); running the same command
again resumes from it. ``hexgym evaluate --policy <that directory>`` measures its policy
(:func:`hexgym.agents.policies.load_rllib_policy`: the RL module's mean action, deterministic, from its
weights alone: a program runs it without Ray or this module).

Env runners (``num_env_runners``, default: the cluster's cores less one for the learner) are Ray
actors, placed wherever the cluster has cores; the learner runs in the driver. Ray and torch are
imported only when a function here is called: ``import hexgym`` never imports them.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from hexgym.agents.policy_files import RLLIB_CHECKPOINT
from hexgym.checks import check_count, check_seed
from hexgym.envs import ENV_ID
from hexgym.files import check_output_dir, run_lock, staged_dir
from hexgym.parallel import connect, import_ray

RLLIB_ENV = "hexgym-rllib"  # the name the env creator is registered under in Ray's registry


def _make_env(config: dict[str, Any]) -> Any:
    """An env runner's environment (importing hexgym registers it in that process)."""
    import gymnasium as gym

    import hexgym  # noqa: F401

    config = dict(config)
    return gym.make(config.pop("env_id", ENV_ID), **config)


def ppo_config(
    hp: dict[str, Any], env_id: str = ENV_ID, seed: int = 0, num_env_runners: int = 1, env_kwargs: dict | None = None
) -> Any:
    """RLlib's ``PPOConfig`` (new API stack) from rl-zoo3 PPO hyperparameters ``hp`` (see the module docstring)."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig

    n_envs = int(hp.get("n_envs", 1))
    net_arch = hp.get("policy_kwargs", {}).get("net_arch", {})
    hidden = list(net_arch.get("pi", [256, 256])) if isinstance(net_arch, dict) else list(net_arch or [256, 256])
    train_batch = int(hp.get("n_steps", 2048)) * n_envs
    return (
        PPOConfig()
        .api_stack(enable_rl_module_and_learner=True, enable_env_runner_and_connector_v2=True)
        .environment(RLLIB_ENV, env_config={"env_id": env_id, **(env_kwargs or hp.get("env_kwargs") or {})})
        .framework("torch")
        .env_runners(
            num_env_runners=num_env_runners,
            num_envs_per_env_runner=1,
            num_cpus_per_env_runner=1,
            rollout_fragment_length="auto",
        )
        .learners(num_learners=0)
        .training(
            train_batch_size_per_learner=train_batch,
            minibatch_size=min(int(hp.get("batch_size", 64)), train_batch),
            num_epochs=int(hp.get("n_epochs", 10)),
            gamma=float(hp.get("gamma", 0.99)),
            lambda_=float(hp.get("gae_lambda", 0.95)),
            lr=float(hp.get("learning_rate", 3e-4)),
            clip_param=float(hp.get("clip_range", 0.2)),
            entropy_coeff=float(hp.get("ent_coef", 0.0)),
        )
        .rl_module(model_config=DefaultModelConfig(fcnet_hiddens=hidden, vf_share_layers=False))
        .debugging(seed=seed, log_level="ERROR")
    )


def _steps_sampled(result: dict[str, Any]) -> int:
    """Env steps sampled so far (lifetime) in a training result."""
    return int(result.get("env_runners", {}).get("num_env_steps_sampled_lifetime", 0))


def _save(algo: Any, run_dir: Path) -> Path:
    """Replace ``run_dir/checkpoint`` by a new checkpoint of ``algo`` as a whole (written beside it first, then
    swapped in: a failed save, a full disk, leaves the previous checkpoint and no partial folder)."""
    final = run_dir / RLLIB_CHECKPOINT
    with staged_dir(final, keep=False) as tmp:
        algo.save_to_path(str(tmp))
    return final


def train_rllib(
    algo: str = "ppo",
    env_id: str = ENV_ID,
    timesteps: int | None = None,
    seed: int = 0,
    log_dir: str | Path = "logs",
    hyperparams: str | Path | None = None,
    num_env_runners: int | None = None,
    ray: str | None = None,
    checkpoint_every: int = 20_000,
    verbose: bool = True,
) -> Path:
    """Train (or resume) RLlib's PPO on ``env_id`` until ``timesteps`` env steps in all; the checkpoint's path.

    ``ray``: a cluster's address, or None/"local" for a Ray started here (shut down at the end);
    ``num_env_runners``: env runner actors (default: the cluster's cores less one, at least one).
    """
    if algo != "ppo":
        raise ValueError(f"--framework rllib trains ppo only, got --algo {algo}")
    from hexgym_lab.agents.hyperparams import load_hyperparams

    hp = load_hyperparams(algo, env_id, hyperparams)
    if hp.get("env_wrapper"):
        raise ValueError(f"env_wrapper {hp['env_wrapper']!r}: --framework rllib runs the environment unwrapped")
    total = check_count("timesteps", timesteps if timesteps is not None else hp.get("n_timesteps", 100_000))
    check_seed("seed", seed)
    check_count("checkpoint_every", checkpoint_every)
    run_dir = check_output_dir(Path(log_dir) / f"rllib_{algo}_{env_id}", "run directory")
    with run_lock(run_dir):  # a second run into this directory is refused, not interleaved with this one
        return _train_rllib(hp, env_id, total, seed, run_dir, num_env_runners, ray, checkpoint_every, verbose)


def _train_rllib(
    hp: dict[str, Any], env_id: str, total: int, seed: int, run_dir: Path, num_env_runners: int | None,
    ray: str | None, checkpoint_every: int, verbose: bool,
) -> Path:  # fmt: skip
    """:func:`train_rllib` once its arguments are checked and its run directory is locked."""
    ray_module = import_ray()
    started = connect(ray or "local")
    try:
        from ray.tune.registry import register_env

        register_env(RLLIB_ENV, _make_env)
        cpus = int(ray_module.cluster_resources().get("CPU", 1))
        runners = check_count("num_env_runners", num_env_runners if num_env_runners is not None else max(1, cpus - 1))
        if runners > cpus:  # each env runner holds a core: more would wait for cores forever
            raise ValueError(f"--num-env-runners {runners} needs {runners} cores, the Ray cluster has {cpus}")
        algorithm = ppo_config(hp, env_id, seed, runners).build_algo()
        try:
            if (run_dir / RLLIB_CHECKPOINT).exists():
                algorithm.restore_from_path(str((run_dir / RLLIB_CHECKPOINT).resolve()))
            done = int(algorithm.metrics.peek(("env_runners", "num_env_steps_sampled_lifetime"), default=0))
            if verbose and done:
                print(f"resuming from {run_dir / RLLIB_CHECKPOINT} ({done} steps done)")
            saved = done
            while done < total:
                t0 = time.perf_counter()
                result = algorithm.train()
                done = _steps_sampled(result)
                if verbose:
                    ret = result.get("env_runners", {}).get("episode_return_mean", float("nan"))
                    print(f"iteration {result.get('training_iteration')}: {done} steps, "
                          f"mean return {ret:.3g}, {time.perf_counter() - t0:.1f} s")  # fmt: skip
                if done - saved >= checkpoint_every or done >= total:
                    _save(algorithm, run_dir)
                    saved = done
            if not (run_dir / RLLIB_CHECKPOINT).exists():
                _save(algorithm, run_dir)
        finally:
            algorithm.stop()
    finally:
        if started:
            ray_module.shutdown()
    return run_dir / RLLIB_CHECKPOINT

"""``hexgym train --framework rllib``: RLlib's PPO (new API stack) on HexLoading-v0, env runners across a Ray cluster.

The PPO hyperparameters come from the same rl-zoo3 YAML as the Stable-Baselines3 runs
(``training/hyperparams/ppo.yml``, :func:`hexgym.agents.hyperparams.load_hyperparams`), mapped to
RLlib's names: a training batch of ``n_steps`` x ``n_envs`` steps per iteration, minibatches of
``batch_size``, ``n_epochs`` passes, ``gamma``, ``gae_lambda``, ``learning_rate``, ``clip_range``,
``ent_coef``; the actor's hidden layers from ``policy_kwargs.net_arch.pi`` (the critic has its own
network). Observations go in unnormalised (RLlib's filter state would have to travel with every
policy; the SB3 path's ``VecNormalize`` has no RLlib counterpart in the checkpoint format).

A run lives in ``<log_dir>/rllib_ppo_<env id>/``: ``checkpoint/`` is the newest RLlib checkpoint
(replaced atomically every ``checkpoint_every`` steps and at the end); running the same command
again resumes from it. ``hexgym evaluate --policy <that directory>`` measures its policy
(:func:`load_rllib_policy`: the RL module's mean action, deterministic).

Env runners (``num_env_runners``, default: the cluster's cores less one for the learner) are Ray
actors, placed wherever the cluster has cores; the learner runs in the driver. Ray and torch are
imported only when a function here is called: ``import hexgym`` never imports them.
"""

from __future__ import annotations

import os
import pickle
import re
import time
from pathlib import Path
from typing import Any

import numpy as np

from hexgym.agents.policy_files import PolicyFileError
from hexgym.checks import check_count, check_seed
from hexgym.envs import ENV_ID
from hexgym.files import check_input_file, check_output_dir, run_lock, staged_dir
from hexgym.parallel import connect, import_ray

RLLIB_ENV = "hexgym-rllib"  # the name the env creator is registered under in Ray's registry
CHECKPOINT = "checkpoint"
_MODULE_PATH = ("learner_group", "learner", "rl_module", "default_policy")  # RLlib's component names


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
    final = run_dir / CHECKPOINT
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
    from hexgym.agents.hyperparams import load_hyperparams

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
            if (run_dir / CHECKPOINT).exists():
                algorithm.restore_from_path(str((run_dir / CHECKPOINT).resolve()))
            done = int(algorithm.metrics.peek(("env_runners", "num_env_steps_sampled_lifetime"), default=0))
            if verbose and done:
                print(f"resuming from {run_dir / CHECKPOINT} ({done} steps done)")
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
            if not (run_dir / CHECKPOINT).exists():
                _save(algorithm, run_dir)
        finally:
            algorithm.stop()
    finally:
        if started:
            ray_module.shutdown()
    return run_dir / CHECKPOINT


class RLlibPolicy:
    """An RLlib PPO policy from its weights alone: the actor's mean action, clipped to the action space.

    ``layers``: the actor encoder's (weight, bias) pairs, each followed by tanh (RLlib's default
    ``fcnet_activation``, the one ``hexgym train --framework rllib`` uses), then the policy head's pair,
    whose outputs are a diagonal Gaussian's means then log-stds. Plain numpy: nothing of RLlib runs.
    """

    def __init__(self, layers: list[tuple[np.ndarray, np.ndarray]]) -> None:
        self.layers = layers

    def reset(self) -> None:
        """Nothing to forget (the module is feed-forward)."""

    def act(self, obs: np.ndarray, env: Any) -> np.ndarray:
        """The mean action for ``obs``."""
        h = np.asarray(obs, np.float32)
        for weight, bias in self.layers[:-1]:
            h = np.tanh(weight @ h + bias)
        weight, bias = self.layers[-1]
        inputs = weight @ h + bias
        mean = inputs[: len(inputs) // 2]  # a diagonal Gaussian's inputs: means, then log-stds
        return np.clip(mean, -1.0, 1.0).astype(np.float32)


def rllib_module_path(path: str | Path) -> Path:
    """The RL module directory inside an RLlib checkpoint (or a run directory holding ``checkpoint/``)."""
    path = Path(path)
    if (path / CHECKPOINT).is_dir() and not (path / _MODULE_PATH[0]).exists():
        path = path / CHECKPOINT
    module = path.joinpath(*_MODULE_PATH)
    if not module.is_dir():
        raise FileNotFoundError(
            f"{path} is not an RLlib checkpoint of `hexgym train --framework rllib` (no {'/'.join(_MODULE_PATH)})"
        )
    return module


# What an RL module's state pickle (``module_state.pkl``: a dict of numpy arrays) refers to: a dict
# class and numpy's array construction from bytes. Any other reference refuses the file unread.
_WEIGHT_GLOBALS = {
    ("collections", "OrderedDict"),
    ("numpy", "dtype"), ("numpy", "ndarray"),
    ("numpy._core.numeric", "_frombuffer"), ("numpy.core.numeric", "_frombuffer"),
    ("numpy._core.multiarray", "_reconstruct"), ("numpy.core.multiarray", "_reconstruct"),
}  # fmt: skip
MAX_STATE_BYTES = 1 << 30  # an RL module's weights (hexgym's: tens of kB)
_ACTOR = re.compile(r"encoder\.actor_encoder\.net\.mlp\.(\d+)\.(weight|bias)")
_HEAD = re.compile(r"pi\.net\.mlp\.(\d+)\.(weight|bias)")


class _WeightsUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in _WEIGHT_GLOBALS:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"it refers to {module}.{name}; a module's weights are numpy arrays only")

    def persistent_load(self, pid: Any) -> Any:
        raise pickle.UnpicklingError("it refers to an outside object")


def read_module_weights(module_dir: str | Path) -> dict[str, np.ndarray]:
    """The weights of an RL module directory (``module_state.pkl``, or torch's ``module_state.pt``), read
    without running anything from the checkpoint: numpy arrays only (``torch.load(weights_only=True)``)."""
    module_dir = Path(module_dir)
    found = [
        module_dir / name for name in ("module_state.pkl", "module_state.pt") if os.path.lexists(module_dir / name)
    ]
    if not found:
        raise PolicyFileError(f"RLlib checkpoint {module_dir}: no module_state.pkl (the RL module's weights)")
    path = check_input_file(found[0], "RLlib module state")
    if path.stat().st_size > MAX_STATE_BYTES:
        raise PolicyFileError(f"RLlib module state {path}: {path.stat().st_size} bytes, more than {MAX_STATE_BYTES}")
    try:
        if path.suffix == ".pt":
            import torch

            state = torch.load(path, map_location="cpu", weights_only=True)
            state = {k: v.numpy() if hasattr(v, "numpy") else v for k, v in state.items()}
        else:
            with path.open("rb") as f:
                state = _WeightsUnpickler(f).load()
    except Exception as exc:  # noqa: BLE001 - a damaged or crafted file: what it is, in one line
        text = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise PolicyFileError(f"RLlib module state {path} is not an RL module's weights: {text}") from None
    if not isinstance(state, dict) or not all(isinstance(k, str) for k in state):
        raise PolicyFileError(f"RLlib module state {path} is not a mapping of names to arrays")
    for key, value in state.items():
        if not isinstance(value, np.ndarray) or value.dtype.kind != "f" or not np.all(np.isfinite(value)):
            raise PolicyFileError(f"RLlib module state {path}: {key} is not an array of finite numbers")
    return state


def _layers(path: Path, state: dict[str, np.ndarray], pattern: re.Pattern, what: str) -> list[tuple]:
    """The (weight, bias) pairs of the linear layers whose names match ``pattern``, in order."""
    found: dict[int, dict[str, np.ndarray]] = {}
    for key, value in state.items():
        match = pattern.fullmatch(key)
        if match:
            found.setdefault(int(match[1]), {})[match[2]] = value
    layers = []
    for index in sorted(found):
        pair = found[index]
        if (
            set(pair) != {"weight", "bias"}
            or pair["weight"].ndim != 2
            or pair["bias"].shape != pair["weight"][:, 0].shape
        ):
            raise PolicyFileError(
                f"RLlib checkpoint {path}: {what} layer {index} is not a linear layer's weight and bias"
            )
        layers.append((pair["weight"].astype(np.float32), pair["bias"].astype(np.float32)))
    return layers


def load_rllib_policy(path: str | Path) -> RLlibPolicy:
    """The policy of an RLlib checkpoint directory (see :func:`rllib_module_path`), from its weights alone.

    Nothing of the checkpoint is unpickled but numpy arrays (:func:`read_module_weights`); its pickled
    class and constructor arguments are never read, so a crafted checkpoint runs nothing, and Ray is
    not needed. The module must be RLlib PPO's default: an actor MLP with tanh, a linear policy head.
    """
    from hexgym.envs.loading import task_spaces

    module_path = rllib_module_path(path)
    state = read_module_weights(module_path)
    actor = _layers(module_path, state, _ACTOR, "actor encoder")
    head = _layers(module_path, state, _HEAD, "policy head")
    if not actor or len(head) != 1:
        raise PolicyFileError(
            f"RLlib checkpoint {path} is not RLlib PPO's default module (an actor MLP and a linear policy head, "
            "as `hexgym train --framework rllib` writes)"
        )
    layers = actor + head
    observation, action = task_spaces()
    sizes_in = [w.shape[1] for w, _ in layers]
    sizes_out = [w.shape[0] for w, _ in layers]
    if sizes_in[1:] != sizes_out[:-1]:
        raise PolicyFileError(
            f"RLlib checkpoint {path}: its layers' sizes do not chain ({sizes_in} in, {sizes_out} out)"
        )
    if sizes_in[0] != observation.shape[0] or sizes_out[-1] != 2 * action.shape[0]:
        raise PolicyFileError(
            f"RLlib checkpoint {path} is for {sizes_in[0]} observations and {sizes_out[-1] // 2} actions, "
            f"HexLoading-v0 has {observation.shape[0]} and {action.shape[0]}"
        )
    return RLlibPolicy(layers)

"""Policies for HexLoading-v0 (and its siblings): the scripted loader, the shipped agent, a trained model.

A policy is ``"scripted"`` (:class:`hexgym.agents.scripted.ScriptedLoader`), ``"shipped"`` (the trained
agent packaged in ``hexgym/policies``), the path of a Stable-Baselines3 ``.zip`` saved by ``hexgym train``
(its observation normaliser beside it, ``<stem>_vecnormalize.json``) or an RLlib checkpoint directory of
``hexgym train --framework rllib`` (run from its weights alone, :func:`load_rllib_policy`: plain numpy, no Ray
or RLlib). :func:`load_policy` turns any of these into an object with ``reset()`` and ``act(obs, env)``;
policy files are read without unpickling anything (:mod:`hexgym.agents.policy_files`).

A trained model's normaliser file records what it was trained on (:func:`trained_on`); :func:`load_trained`
refuses it on another task, another observation layout or, on the learned model, other tables
(:func:`check_trained_on`). On the reference model (``model="reference"``, the real machine's stand-in) a policy of
any table set is accepted: measuring it there is the point. A file that records nothing is accepted silently.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

from hexgym.agents.policy_files import (
    ObsNormalizer,
    PolicyFileError,
    TrainedOn,
    load_normalizer,
    load_sb3_model,
    normalizer_path,
    read_model_data,
    read_module_weights,
    rllib_module_path,
)
from hexgym.envs import DIG_ENV_ID, ENV_ID  # importing hexgym registers it
from hexgym.mbl.schema import DEFAULT_TABLE_SET
from hexgym.mbl.table import resolve_tables

POLICY_DIR = Path(__file__).resolve().parents[1] / "policies"
SHIPPED_POLICY = POLICY_DIR / "ppo_loading.zip"


class Policy(Protocol):
    """What steps a task (a program's loop, or the lab's evaluation): an action for the observation (and the
    unwrapped env, for scripts)."""

    def reset(self) -> None:
        """Forget the last episode."""

    def act(self, obs: np.ndarray, env: Any) -> np.ndarray:
        """Four spool fractions in [-1, 1]."""


class ScriptedPolicy:
    """The scripted loader (reads the simulation's state, not the observation)."""

    def __init__(self, settings_path: str | Path | None = None) -> None:
        from hexgym.agents.scripted import ScriptedLoader, load_settings

        self.controller = ScriptedLoader(load_settings(settings_path))

    def reset(self) -> None:
        """Start the state machine over."""
        self.controller.reset()

    def act(self, obs: np.ndarray, env: Any) -> np.ndarray:
        """The scripted action for the env's present state."""
        return self.controller.act(env)


class TrainedPolicy:
    """A Stable-Baselines3 model with the observation statistics it was trained with (deterministic actions)."""

    def __init__(self, model: Any, normalizer: ObsNormalizer | None) -> None:
        self.model, self.normalizer = model, normalizer
        self.n_obs = model.observation_space.shape[0]
        self.previous = np.zeros(model.action_space.shape[0], np.float32)

    def reset(self) -> None:
        """Forget the previous action."""
        self.previous[:] = 0.0

    def act(self, obs: np.ndarray, env: Any) -> np.ndarray:
        """The model's mean action on the normalised observation.

        A model trained with ``PreviousActionWrapper`` sees the last action after the observation:
        given the bare environment's observation, the policy appends it itself.
        """
        if len(obs) + len(self.previous) == self.n_obs:
            obs = np.concatenate([obs, self.previous])
        if self.normalizer is not None:
            obs = self.normalizer.normalize_obs(obs)
        action, _ = self.model.predict(obs, deterministic=True)
        self.previous = np.clip(action, -1.0, 1.0).astype(np.float32)
        return self.previous.copy()


def _spaces_for(model_path: Path) -> tuple[Any, Any]:
    """HexLoading-v0's spaces, with the previous action appended when the model was trained so."""
    from hexgym.envs.loading import task_spaces

    observation, action = task_spaces()
    saved = read_model_data(model_path).get("observation_space", {})
    if isinstance(saved, dict) and saved.get("_shape") == [observation.shape[0] + action.shape[0]]:
        low = np.concatenate([observation.low, action.low])  # PreviousActionWrapper's space
        high = np.concatenate([observation.high, action.high])
        observation = gym.spaces.Box(low, high, dtype=np.float32)
    return observation, action


# -- what a policy was trained on --------------------------------------------------------------------
REFERENCE_TABLES = "reference"  # ``TrainedOn.tables`` of a policy trained on the reference model
FITTED_PREFIX = "model:"  # ``TrainedOn.tables`` of a fitted model directory: "model:<its name>"


def tables_label(tables: str | os.PathLike[str] = DEFAULT_TABLE_SET, model: str = "learned") -> str:
    """The machine model an env runs, as :class:`~hexgym.agents.policy_files.TrainedOn` records it: the table set
    (``"circuit"``, ``"paper"``), ``"model:<name>"`` for a fitted model's directory (its name: the path differs
    between machines), ``"reference"`` for the reference model. ValueError for a ``tables`` the envs refuse."""
    if model == "reference":
        return REFERENCE_TABLES
    table_set, directory = resolve_tables(tables)
    return table_set if directory is None else FITTED_PREFIX + directory.resolve().name


def observation_names(env_id: str) -> tuple[str, ...] | None:
    """The observation entries of ``env_id`` by name (the loading site's tasks), or None where they are not named."""
    if env_id in (ENV_ID, DIG_ENV_ID):
        from hexgym.envs.loading import OBSERVATION_NAMES

        return tuple(OBSERVATION_NAMES)
    return None


def trained_on(env_id: str, env_kwargs: Mapping[str, Any] | None = None) -> TrainedOn:
    """What a policy trained on ``gymnasium.make(env_id, **env_kwargs)`` records: the task, the machine model
    (:func:`tables_label`) and the observations' names (:func:`observation_names`)."""
    kwargs = env_kwargs or {}
    if not isinstance(kwargs, Mapping):
        raise ValueError(f"env_kwargs must be a mapping, got {kwargs!r}")
    label = tables_label(kwargs.get("tables", DEFAULT_TABLE_SET), kwargs.get("model", "learned"))
    return TrainedOn(env_id, label, observation_names(env_id))


def _model_words(label: str) -> str:
    if label == REFERENCE_TABLES:
        return "the reference model"
    if label.startswith(FITTED_PREFIX):
        return f"the fitted model {label.removeprefix(FITTED_PREFIX)!r}"
    return f"the {label} tables"


def check_trained_on(
    model_path: str | Path,
    recorded: TrainedOn | None,
    env_id: str = ENV_ID,
    env_kwargs: Mapping[str, Any] | None = None,
) -> None:
    """Refuse a policy used on another task, observation layout or learned model than it was trained on.

    ``recorded``: what its normaliser file says (None: nothing recorded, accepted). ``env_id``/``env_kwargs``: the
    environment it is about to act in. On the reference model any table set is accepted. PolicyFileError in one
    line naming the policy and what differs, e.g. ``p.zip: trained on HexDig-v0, used on HexLoading-v0``.
    """
    if recorded is None:
        return
    used = trained_on(env_id, env_kwargs)
    if recorded.env_id != used.env_id:
        raise PolicyFileError(f"{model_path}: trained on {recorded.env_id}, used on {used.env_id}")
    if recorded.obs_names is not None and used.obs_names is not None and recorded.obs_names != used.obs_names:
        raise PolicyFileError(f"{model_path}: trained on another observation layout than {used.env_id}'s: "
                              f"{_layout_difference(recorded.obs_names, used.obs_names)}")  # fmt: skip
    if recorded.tables is not None and used.tables != REFERENCE_TABLES and recorded.tables != used.tables:
        raise PolicyFileError(f"{model_path}: trained on {_model_words(recorded.tables)}, used on "
                              f"{_model_words(used.tables)}")  # fmt: skip


def _layout_difference(trained: tuple[str, ...], used: tuple[str, ...]) -> str:
    for i, (a, b) in enumerate(zip(trained, used, strict=False)):
        if a != b:
            return f"observation {i} is {a!r} in the policy, {b!r} here"
    return f"the policy's has {len(trained)} entries, the environment's {len(used)}"


def load_trained(
    model_path: str | Path, env_id: str = ENV_ID, env_kwargs: Mapping[str, Any] | None = None
) -> TrainedPolicy:
    """Load a model saved by ``hexgym train`` with its observation normaliser, unpickling nothing, to act in
    ``gymnasium.make(env_id, **env_kwargs)``.

    Refused with :class:`~hexgym.agents.policy_files.PolicyFileError` (a ValueError naming the file):
    a file that is no PPO/SAC model zip, a model for other observations or actions, a missing,
    pickled or malformed normaliser, a normaliser of another size than the observations, a model recorded
    as trained on another task, observation layout or learned model (:func:`check_trained_on`).
    """
    model_path = Path(model_path)
    if not model_path.exists():
        raise FileNotFoundError(f"no policy file {model_path} (give 'shipped', 'scripted' or a model .zip)")
    if env_id == ENV_ID:
        observation_space, action_space = _spaces_for(model_path)  # reads the zip: is it a model at all?
    else:
        env = gym.make(env_id)
        observation_space, action_space = env.observation_space, env.action_space
        env.close()
    normalizer = load_normalizer(model_path)
    check_trained_on(model_path, normalizer.trained_on, env_id, env_kwargs)
    model = load_sb3_model(model_path, observation_space, action_space)
    if normalizer.size is not None and normalizer.size != model.observation_space.shape[0]:
        raise PolicyFileError(
            f"observation normaliser {normalizer_path(model_path)} has {normalizer.size} entries, the policy's "
            f"observations {model.observation_space.shape[0]}"
        )
    return TrainedPolicy(model, normalizer if normalizer.norm_obs else None)


def load_policy(
    spec: str | Path,
    env_id: str = ENV_ID,
    loader_settings: str | Path | None = None,
    env_kwargs: Mapping[str, Any] | None = None,
) -> Policy:
    """``"scripted"``, ``"planner"`` (:class:`~hexgym.agents.planning_loader.PlanningLoader`), ``"shipped"``, a model
    path or an RLlib checkpoint directory -> a policy for ``env_id``
    (another task than HexLoading-v0: ``"scripted"`` or a model trained on it). ``loader_settings``: a JSON
    file of the scripted loader's settings (``"scripted"`` and ``"planner"`` only). ``env_kwargs``: those the
    environment is made
    with (its ``tables`` and ``model``: a trained model is checked against them, :func:`check_trained_on`)."""
    if spec == "scripted":
        return ScriptedPolicy(loader_settings)
    if spec == "planner":
        if env_id != ENV_ID:
            raise ValueError(f"the planning loader loads trucks ({ENV_ID}), not {env_id}")
        from hexgym.agents.planning_loader import PlanningLoader

        return PlanningLoader(settings_path=loader_settings)
    if loader_settings is not None:
        raise ValueError(f"--loader-settings {loader_settings}: only for the scripted policy, not {spec}")
    if env_id != ENV_ID:
        return load_trained(spec, env_id, env_kwargs)
    if spec == "shipped":
        if not SHIPPED_POLICY.is_file():
            raise FileNotFoundError(f"no shipped policy at {SHIPPED_POLICY}: see README, Training agents")
        return load_trained(SHIPPED_POLICY, env_kwargs=env_kwargs)
    if Path(spec).is_dir():  # `hexgym train --framework rllib` checkpoints are directories
        return load_rllib_policy(spec)
    return load_trained(spec, env_kwargs=env_kwargs)


_ACTOR = re.compile(r"encoder\.actor_encoder\.net\.mlp\.(\d+)\.(weight|bias)")
_HEAD = re.compile(r"pi\.net\.mlp\.(\d+)\.(weight|bias)")


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

"""``hexgym train``: Stable-Baselines3 agents for HexLoading-v0, warm-started from the scripted loader.

Hyperparameters are rl-zoo3 YAML keyed by env id (``hexgym_lab/hyperparams/<algo>.yml``). A run lives
in ``<logdir>/<algo>_<env id>/``: ``checkpoints/`` (model + VecNormalize statistics, saved atomically),
``tb/`` (TensorBoard, when installed) and the final ``model.zip`` + ``model_vecnormalize.json`` (the
observation statistics as numbers, :mod:`hexgym.agents.policy_files`: nothing is pickled or unpickled; with what
the model was trained on, the task, the machine model and the observations' names, that loading checks).
Running the same command again resumes from the newest checkpoint.

Reinforcement learning from scratch on a 180 s, 10 Hz loading task is slow on a laptop CPU (the
delivery reward comes ~200 steps after the dig), so :func:`clone_scripted` first fits the PPO actor
to the scripted loader by behaviour cloning with DAgger rounds (the scripted loader, whose action
is a function of the state, labels the states the learner itself visits), and fits the critic to
the demonstrations' discounted returns; ``hexgym train --init-from`` then fine-tunes that model with PPO.
"""

from __future__ import annotations

import contextlib
import importlib.util
import math
import os
import re
import shutil
import signal
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hexgym.agents.policies import check_trained_on, load_trained, trained_on
from hexgym.agents.policy_files import (
    ObsNormalizer,
    PolicyFileError,
    TrainedOn,
    algorithm_of,
    load_normalizer,
    load_sb3_model,
    normalizer_path,
    read_model_data,
    write_normalizer,
)
from hexgym.checks import check_count, check_range, check_seed
from hexgym.envs import ENV_ID
from hexgym.files import atomic_paths, check_input_file, check_output_dir, check_output_file, run_lock
from hexgym.parallel import LocalPool
from hexgym_lab.agents.hyperparams import algo_kwargs, load_hyperparams, wrapper_named
from hexgym_lab.progress import Progress

if TYPE_CHECKING:
    from hexgym.agents.scripted import LoaderSettings

NOISE_HOLD_STEPS = 10  # DART disturbances change once a second: per-step noise would average out in the valves


# -- hyperparameters ------------------------------------------------------------------------------
def check_hyperparams(algo: str, hp: dict[str, Any], env_id: str = ENV_ID) -> None:
    """ValueError naming hyperparameters the algorithm or the environment does not take, before any work."""
    import inspect

    from stable_baselines3 import PPO, SAC

    parameters = inspect.signature({"ppo": PPO, "sac": SAC}[algo]).parameters
    unknown = sorted(set(algo_kwargs(hp)) - set(parameters) | {"policy", "env"} & set(algo_kwargs(hp)))
    if unknown:
        raise ValueError(f"hyperparameter(s) {unknown} are not arguments of {algo.upper()}")
    for key, value in algo_kwargs(hp).items():
        default = parameters[key].default
        if isinstance(default, bool):
            kind_ok = isinstance(value, bool)
        elif isinstance(default, int):
            kind_ok = isinstance(value, int) and not isinstance(value, bool)
        elif isinstance(default, float):
            kind_ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
        else:
            continue
        if not kind_ok:
            what = {bool: "true or false", int: "a whole number", float: "a finite number"}[type(default)]
            raise ValueError(f"hyperparameter {key} must be {what} (default {default!r}), got {value!r}")
    env_kwargs = hp.get("env_kwargs") or {}
    if not isinstance(env_kwargs, dict):
        raise ValueError(f"env_kwargs must be a mapping, got {env_kwargs!r}")
    try:
        make_env(env_id, hp.get("env_wrapper"), **env_kwargs).close()  # the env's own checks, in this process
    except TypeError as exc:  # a keyword the environment does not take
        raise ValueError(f"env_kwargs: {exc}") from None


# -- environments ---------------------------------------------------------------------------------
def make_env(env_id: str = ENV_ID, wrapper: str | None = None, **env_kwargs: Any) -> Any:
    """``gymnasium.make`` after ``import hexgym`` (a subprocess of SubprocVecEnv must register the ids too).

    ``wrapper``: dotted path of a wrapper class applied around the env (rl-zoo3's ``env_wrapper``).
    """
    import gymnasium as gym

    import hexgym  # noqa: F401

    env = gym.make(env_id, **env_kwargs)
    wrapper_class = wrapper_named(wrapper)
    return wrapper_class(env) if wrapper_class is not None else env


VEC_ENVS = ("auto", "batch", "subproc")
"""``train``'s ways of running environments: ``batch`` (the task's batched vector environment, one process, MuJoCo
batch threads: :mod:`hexgym_lab.agents.sb3_vector`), ``subproc`` (one process per environment), ``auto`` (batch where
the task has a batched environment and no wrapper is asked for)."""


def has_batched_env(env_id: str) -> bool:
    """Whether ``env_id`` has a batched vector environment (a ``vector_entry_point``)."""
    import gymnasium as gym

    import hexgym  # noqa: F401

    return gym.spec(env_id).vector_entry_point is not None


def batched(env_id: str, vec_env: str, wrapper: str | None = None) -> bool:
    """Whether ``train`` runs ``env_id`` on its batched vector environment (see :data:`VEC_ENVS`)."""
    if vec_env not in VEC_ENVS:
        raise ValueError(f"vec_env must be one of {VEC_ENVS}, got {vec_env!r}")
    if vec_env == "subproc":
        return False
    available = has_batched_env(env_id) and wrapper is None
    if vec_env == "batch" and not available:
        why = "an env_wrapper is set" if wrapper is not None else f"{env_id} has no batched vector environment"
        raise ValueError(f"--vec-env batch is not possible: {why} (use --vec-env subproc)")
    return available


def make_vec_env(
    env_id: str, n_envs: int, seed: int, env_kwargs: dict | None = None, wrapper: str | None = None,
    batch: bool = False,
) -> Any:  # fmt: skip
    """``n_envs`` environments as an SB3 ``VecEnv`` recording episode returns: with ``batch`` the task's batched
    vector environment (one process); else Monitor-wrapped copies, one process each when more than one."""
    from functools import partial

    from stable_baselines3.common.env_util import make_vec_env as sb3_make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    if batch:
        import gymnasium as gym

        from hexgym_lab.agents.sb3_vector import SB3VectorEnv

        vector = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point", **(env_kwargs or {}))
        venv = VecMonitor(SB3VectorEnv(vector))
        venv.seed(seed)
        return venv
    return sb3_make_vec_env(
        partial(make_env, env_id, wrapper),
        n_envs=n_envs,
        seed=seed,
        env_kwargs=env_kwargs,
        vec_env_cls=SubprocVecEnv if n_envs > 1 else DummyVecEnv,
    )


# -- saving -----------------------------------------------------------------------------------------
def save_model(model: Any, path: str | Path, task: TrainedOn | None = None) -> Path:
    """Save an SB3 model and its observation normaliser (``<stem>_vecnormalize.json``), replaced as a pair.

    The normaliser is always written (an identity for a model trained without one), so a model
    without it is known to be incomplete; it records ``task``, what the model was trained on
    (:func:`hexgym.agents.policies.trained_on`), when given. Both are written to temporary files first: a
    failure leaves the old pair, never a new model beside an old normaliser.
    """
    path = Path(path)
    normalizer = ObsNormalizer.from_vec_normalize(model.get_vec_normalize_env(), task)
    with atomic_paths(path, normalizer_path(path)) as (model_tmp, normalizer_tmp):
        model.save(model_tmp)
        write_normalizer(normalizer, normalizer_tmp)
    return path


def _checkpoint_callback(directory: Path, every: int, task: TrainedOn | None = None) -> Any:
    from stable_baselines3.common.callbacks import BaseCallback

    class AtomicCheckpoint(BaseCallback):
        """Every ``every`` environment steps: ``rl_model_<steps>_steps.zip`` + its VecNormalize statistics."""

        def _on_step(self) -> bool:
            if self.n_calls % max(every // self.training_env.num_envs, 1) == 0:
                save_model(self.model, directory / f"rl_model_{self.num_timesteps}_steps.zip", task)
            return True

    return AtomicCheckpoint()


CURVE_COLUMNS = ("steps", "wall_s", "episodes", "mean_return", "success_rate", "delivered_t")


def _rollout_report_callback(print_line: Callable[[str], None] | None = print, curve: Path | None = None) -> Any:
    from stable_baselines3.common.callbacks import BaseCallback

    class RolloutReport(BaseCallback):
        """One line per rollout: steps so far, tonnes delivered into the trucks during the rollout (tasks
        whose ``info`` has ``truck_kg``), episodes ended, their mean return and (tasks whose ``info`` has
        ``is_success``) their success rate, and the rate; printed (``print_line``) and appended as a row of
        ``CURVE_COLUMNS`` to ``curve`` (a CSV file, the learning curve; empty fields where nothing ended)."""

        def _on_training_start(self) -> None:
            self._truck = np.zeros(self.training_env.num_envs)
            self._clock = time.perf_counter()
            self._start_steps = self.num_timesteps
            self._trucks = False  # whether the task has trucks to deliver to

        def _on_rollout_start(self) -> None:
            self._delivered_kg, self._returns, self._successes = 0.0, [], []

        def _on_step(self) -> bool:
            for i, info in enumerate(self.locals["infos"]):
                self._trucks = self._trucks or "truck_kg" in info
                if "truck_kg" in info:  # a new episode's first info has an empty truck: no delivery
                    self._delivered_kg += max(info["truck_kg"] - self._truck[i], 0.0)
                    self._truck[i] = 0.0 if self.locals["dones"][i] else info["truck_kg"]
                if "episode" in info:
                    self._returns.append(float(info["episode"]["r"]))
                    if "is_success" in info:
                        self._successes.append(bool(info["is_success"]))
            return True

        def _on_rollout_end(self) -> None:
            rate = (self.num_timesteps - self._start_steps) / max(time.perf_counter() - self._clock, 1e-9)
            ended = f"{len(self._returns)} episode{'' if len(self._returns) == 1 else 's'} ended"
            if self._returns:
                ended += f", mean return {np.mean(self._returns):.2f}"
            if self._successes:
                ended += f", success {np.mean(self._successes):.0%}"
            delivered = f"{self._delivered_kg / 1000:6.1f} t delivered, " if self._trucks else ""
            if print_line is not None:
                print_line(f"{self.num_timesteps:>10,} steps | rollout: {delivered}{ended} | {rate:,.0f} steps/s")
            if curve is not None:
                self._append_row(curve)

        def _append_row(self, path: Path) -> None:
            row = (
                self.num_timesteps, f"{time.perf_counter() - self._clock:.1f}", len(self._returns),
                f"{np.mean(self._returns):.4f}" if self._returns else "",
                f"{np.mean(self._successes):.4f}" if self._successes else "",
                f"{self._delivered_kg / 1000:.3f}" if self._trucks else "",
            )  # fmt: skip
            size = path.stat().st_size if path.exists() else 0
            try:
                with path.open("a") as f:  # appended row by row: a resumed run continues its curve
                    if size == 0:
                        f.write(",".join(CURVE_COLUMNS) + "\n")
                    f.write(",".join(str(v) for v in row) + "\n")
            except OSError as exc:  # a full disk: the rows written stay whole, the run stops naming the file
                with contextlib.suppress(OSError):
                    os.truncate(path, size)
                raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None

    return RolloutReport()


def checkpoints(directory: str | Path) -> list[tuple[int, Path]]:
    """The checkpoints (``rl_model_<steps>_steps.zip``) in ``directory`` as (steps, path), fewest steps first."""
    found = []
    for path in Path(directory).glob("rl_model_*_steps.zip"):
        match = re.fullmatch(r"rl_model_(\d+)_steps", path.stem)
        if match:
            found.append((int(match[1]), path))
    return sorted(found)


def latest_checkpoint(run_dir: str | Path) -> Path | None:
    """The checkpoint with the most steps in ``run_dir/checkpoints`` (None when there is none)."""
    found = checkpoints(Path(run_dir) / "checkpoints")
    return found[-1][1] if found else None


def _load_into(path: Path, algo_class: type, venv: Any, update_statistics: bool = True, **kwargs: Any) -> Any:
    """Load a saved model onto ``venv``, wrapped in its saved observation statistics (unpickling nothing), which
    go on updating with ``update_statistics``."""
    if algorithm_of(path) is not algo_class:
        raise PolicyFileError(f"{path} is a {algorithm_of(path).__name__} model, not {algo_class.__name__}")
    venv = load_normalizer(path).vec_normalize(venv, training=update_statistics)
    return load_sb3_model(path, venv.observation_space, venv.action_space, env=venv, **kwargs)


def check_start_model(
    path: str | Path, algo: str = "ppo", env_id: str = ENV_ID, env_kwargs: dict[str, Any] | None = None
) -> Path:
    """``path`` if it is a model ``train`` can start from: a PPO/SAC zip of ``algo`` with its normaliser, not
    recorded as trained on another task or model than ``gymnasium.make(env_id, **env_kwargs)``."""
    from stable_baselines3 import PPO, SAC

    path = check_input_file(path, "model to start from")
    found = algorithm_of(path, read_model_data(path))
    if found is not {"ppo": PPO, "sac": SAC}[algo]:
        raise PolicyFileError(f"{path} is a {found.__name__} model; this run trains {algo.upper()}")
    check_trained_on(path, load_normalizer(path).trained_on, env_id, env_kwargs)
    return path


def rollout_steps(algo: str, hp: dict[str, Any], n_envs: int) -> int:
    """Environment steps of one rollout (PPO: ``n_steps`` per env; SAC: ``train_freq`` per env)."""
    per_env = hp.get("n_steps", 2048) if algo == "ppo" else hp.get("train_freq", 1)
    per_env = per_env[0] if isinstance(per_env, (list, tuple)) else per_env
    return int(per_env) * n_envs


# -- training ---------------------------------------------------------------------------------------
def train(
    algo: str = "ppo",
    env_id: str = ENV_ID,
    timesteps: int | None = None,
    seed: int = 0,
    log_dir: str | Path = "logs",
    hyperparams: str | Path | None = None,
    n_envs: int | None = None,
    init_from: str | Path | None = None,
    checkpoint_every: int = 20_000,
    progress_bar: bool = True,
    report: bool = True,
    vec_env: str = "auto",
) -> Path:
    """Train (or resume) ``algo`` on ``env_id`` to ``timesteps`` steps in all; the final model's path.

    ``progress_bar``: count the steps (:mod:`hexgym_lab.progress`: a bar, or lines, on standard error where it
    shows progress); ``report``: a line per rollout there too (tonnes delivered, episodes ended and their mean
    return, steps per second); every rollout's figures are appended to the run directory's ``curve.csv`` either way.
    Interrupted (Ctrl-C or SIGTERM), the run saves its newest state as ``model.zip`` before stopping.

    Resumes from the newest checkpoint of the run directory when there is one; otherwise starts
    from ``init_from`` (a model saved by :func:`clone_scripted` or an earlier run), or from scratch. With
    ``init_from`` the observation statistics stay those the starting policy was fitted to.

    ``vec_env`` (:data:`VEC_ENVS`): on the task's batched environment ``n_envs`` defaults to the YAML's
    ``n_envs`` (its sites are threads of one process); on subprocesses to one per core.
    """
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.vec_env import VecNormalize

    hp = load_hyperparams(algo, env_id, hyperparams)
    total = check_count("timesteps", timesteps if timesteps is not None else hp.get("n_timesteps", 100_000))
    check_seed("seed", seed)
    batch = batched(env_id, vec_env, hp.get("env_wrapper"))
    default_envs = int(hp.get("n_envs", os.cpu_count() or 1)) if batch else os.cpu_count() or 1
    n_envs = check_count("n_envs", n_envs if n_envs is not None else default_envs)
    rollout = rollout_steps(algo, hp, n_envs)
    if check_count("checkpoint_every", checkpoint_every) < rollout:
        raise ValueError(f"checkpoint_every must be at least one rollout ({rollout} steps: {rollout // n_envs} "
                         f"per environment x {n_envs} environments), got {checkpoint_every}")  # fmt: skip
    algo_class = {"ppo": PPO, "sac": SAC}[algo]
    run_dir = check_output_dir(Path(log_dir) / f"{algo}_{env_id}", "run directory")
    resume = latest_checkpoint(run_dir)
    start = resume or (Path(init_from) if init_from is not None else None)
    if start is not None:
        check_start_model(start, algo, env_id, hp.get("env_kwargs"))
    check_hyperparams(algo, hp, env_id)
    task = trained_on(env_id, hp.get("env_kwargs"))
    with run_lock(run_dir):  # a second run into this directory is refused, not interleaved with this one
        tensorboard = str(run_dir / "tb") if importlib.util.find_spec("tensorboard") else None
        venv = make_vec_env(env_id, n_envs, seed, hp.get("env_kwargs"), hp.get("env_wrapper"), batch=batch)
        if start is not None:
            # a fine-tune keeps the observation statistics its policy was fitted to: updated, they shift every input
            # (a clone fine-tuned with them updating fell from 300 to 202 t/h in 20k steps, held at 296 without)
            # a fine-tune learns with the YAML's settings (the saved model's would apply otherwise) and explores with
            # its log_std_init (a clone's log_std is never fitted); a resumed run goes on as it was saved
            tune = {} if resume else {k: v for k, v in algo_kwargs(hp).items() if k != "policy_kwargs"}
            model = _load_into(start, algo_class, venv, update_statistics=init_from is None,
                               tensorboard_log=tensorboard, seed=seed, **tune)  # fmt: skip
            log_std = (hp.get("policy_kwargs") or {}).get("log_std_init")
            if not resume and log_std is not None and hasattr(model.policy, "log_std"):
                model.policy.log_std.data.fill_(float(log_std))
            print(f"{'resuming' if resume else 'starting'} from {start} ({model.num_timesteps} steps done)")
        else:
            if hp["normalize"]:
                venv = VecNormalize(venv, **hp["normalize"])
            model = _new_model(algo_class, hp, venv, seed=seed, tensorboard_log=tensorboard)
        remaining = total - model.num_timesteps if resume else total
        done = model.num_timesteps if resume else 0
        progress = Progress(done + remaining, "train", "step", initial=done, count=progress_bar)
        callbacks = [
            _checkpoint_callback(run_dir / "checkpoints", checkpoint_every, task),
            _rollout_report_callback(progress.note if report else None, run_dir / "curve.csv"),
            _progress_callback(progress),
        ]
        try:
            if remaining > 0:
                with _terminate_as_interrupt(), progress:
                    model.learn(remaining, callback=callbacks, reset_num_timesteps=resume is None, tb_log_name=algo)
        except KeyboardInterrupt:
            # a stopped run leaves its newest state as a usable model (with its normaliser), then stops
            path = save_model(model, run_dir / "model.zip", task)
            print(stopped_run_message(run_dir, path, model.num_timesteps))
            raise
        finally:
            venv.close()
        return save_model(model, run_dir / "model.zip", task)


def stopped_run_message(run_dir: Path, model_path: Path, steps: int) -> str:
    """What a stopped run kept, where: the model saved at the stop with its normaliser, the last checkpoint (model
    and normaliser, what running the command again resumes from) and the learning curve."""
    kept = [f"the model {model_path} with its normaliser {normalizer_path(model_path)}"]
    last = latest_checkpoint(run_dir)
    if last is not None:
        kept.append(f"the last checkpoint {last} with its normaliser {normalizer_path(last)} (the same command "
                    "resumes from it)")  # fmt: skip
    curve = run_dir / "curve.csv"
    if curve.is_file():
        kept.append(f"the learning curve {curve}")
    return f"stopped at {steps} steps; kept " + "; ".join(kept)


@contextlib.contextmanager
def _terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM (``kill``, a batch scheduler's stop) raises KeyboardInterrupt like Ctrl-C, so a stopped run saves its
    model either way (a background job started from a script ignores SIGINT)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _progress_callback(progress: Progress) -> Any:
    """A callback that counts the run's steps in ``progress`` (a resumed run's from its checkpoint's count)."""
    from stable_baselines3.common.callbacks import BaseCallback

    class StepProgress(BaseCallback):
        def _on_step(self) -> bool:
            progress.set(self.num_timesteps)
            return True

    return StepProgress()


# -- behaviour cloning from the scripted loader ----------------------------------------------------
@dataclass
class Demonstrations:
    """Observations, the scripted loader's actions there, and the discounted returns that followed."""

    obs: np.ndarray
    actions: np.ndarray
    returns: np.ndarray

    @staticmethod
    def concatenate(parts: list[Demonstrations]) -> Demonstrations:
        """All parts in one."""
        return Demonstrations(*(np.concatenate([getattr(d, k) for d in parts]) for k in ("obs", "actions", "returns")))


def record_episode(
    seed: int,
    gamma: float,
    learner_path: str | None = None,
    beta: float = 1.0,
    env_kwargs: dict | None = None,
    wrapper: str | None = None,
    noise: float = 0.0,
    loader_settings: LoaderSettings | None = None,
) -> Demonstrations:
    """One episode labelled by the scripted loader; each step the learner drives with probability ``1 - beta``.

    The labels are :meth:`ScriptedLoader.label`: the loader re-derives its phase from the state
    every step, so a state gets the same label however it was reached, by the loader or by the
    learner (DAgger: the learner's own mistakes lead to the states that teach recovery).
    ``noise`` (DART): the loader's executed action gets Gaussian noise of this standard deviation,
    held for a second at a time, so even the loader's own episodes show recoveries. ``loader_settings``:
    the loader's (default: its hand-set ones).
    """
    import torch

    from hexgym.agents.scripted import DEFAULT_SETTINGS, ScriptedLoader

    torch.set_num_threads(1)
    env = make_env(ENV_ID, wrapper, **(env_kwargs or {}))
    learner = load_trained(learner_path, env_kwargs=env_kwargs) if learner_path else None
    rng = np.random.default_rng(seed + 7919)  # the mixing and noise draws: reproducible per seed
    obs, _ = env.reset(seed=seed)
    if learner is not None:
        learner.reset()
    observations, labels, rewards = [], [], []
    loader, done = ScriptedLoader(loader_settings or DEFAULT_SETTINGS), False
    while not done:
        label = loader.label(env.unwrapped)
        if env.unwrapped.steps % NOISE_HOLD_STEPS == 0:
            disturbance = rng.normal(0.0, noise, label.shape) if noise > 0 else np.zeros_like(label)
        learner_action = learner.act(obs, env.unwrapped) if learner is not None else None  # keeps its state
        action = label + disturbance if learner is None or rng.random() < beta else learner_action
        observations.append(obs)
        labels.append(label)
        obs, reward, terminated, truncated, _ = env.step(action)
        rewards.append(reward)
        done = terminated or truncated
    env.close()
    returns = np.zeros(len(rewards))
    running = 0.0
    for i in range(len(rewards) - 1, -1, -1):
        running = rewards[i] + gamma * running
        returns[i] = running
    return Demonstrations(np.array(observations, np.float32), np.array(labels, np.float32), returns)


def record_demonstrations(
    seeds: list[int],
    gamma: float,
    learner_path: str | None = None,
    beta: float = 1.0,
    env_kwargs: dict | None = None,
    wrapper: str | None = None,
    noise: float = 0.0,
    workers: int | None = None,
    pool: LocalPool | None = None,
    loader_settings: LoaderSettings | None = None,
) -> Demonstrations:
    """:func:`record_episode` for each seed, in parallel worker processes (``pool``, or new ones)."""
    n = len(seeds)
    parts = _in_workers(pool, workers, record_episode, seeds, [gamma] * n, [learner_path] * n, [beta] * n,
                        [env_kwargs] * n, [wrapper] * n, [noise] * n, [loader_settings] * n)  # fmt: skip
    return Demonstrations.concatenate(parts)


def _worker_pool(workers: int | None = None) -> LocalPool:
    """Worker processes, one per core (spawned: torch is not fork-safe; Ctrl-C stops them at once)."""
    return LocalPool(max(1, workers or os.cpu_count() or 1))


def _in_workers(pool: LocalPool | None, workers: int | None, function: Any, *arguments: list) -> list:
    """``function`` over the argument lists in ``pool`` (or in a new pool of at most ``workers``)."""
    jobs = [(function, *job) for job in zip(*arguments, strict=True)]
    if pool is not None:
        return pool.map(_apply, jobs)
    with _worker_pool(min(workers or os.cpu_count() or 1, len(jobs))) as new_pool:
        return new_pool.map(_apply, jobs)


def _apply(job: tuple) -> Any:
    """``function(*arguments)`` of ``job`` = (function, *arguments): a pool's task."""
    function, *arguments = job
    return function(*arguments)


def score_episode(model_path: str, seed: int, env_kwargs: dict | None = None) -> dict[str, float]:
    """One seeded episode of a saved policy: tonnes delivered and full-enough dumps (to pick a clone by)."""
    import gymnasium as gym
    import torch

    from hexgym_lab.agents.evaluate import run_episode

    torch.set_num_threads(1)
    env = gym.make(ENV_ID, **(env_kwargs or {}))
    summary = run_episode(env, load_trained(model_path, env_kwargs=env_kwargs), seed).summary()
    env.close()
    return {"delivered_t": summary["delivered_t"], "full_dumps": summary["full_dumps"]}


CLONE_LOSSES = {"mse": 2, "l1": 1}  # the actor's loss: the power of the action error it averages


def _loss_power(loss: str) -> int:
    """The power of ``loss`` (one of CLONE_LOSSES), or a ValueError naming the choices."""
    if loss not in CLONE_LOSSES:
        raise ValueError(f"loss must be one of {tuple(CLONE_LOSSES)}, got {loss!r}")
    return CLONE_LOSSES[loss]


def fit_to_demonstrations(
    model: Any, demos: Demonstrations, epochs: int, seed: int, batch: int = 512, loss: str = "mse"
) -> dict:
    """Supervised fit of a PPO policy: actor mean to the loader's actions, critic to the returns (MSE).

    ``loss`` of the actor: ``"mse"`` (the mean of the labels a state gets), or ``"l1"`` (their median:
    where nearby states get different labels, as either side of a phase change, the fit takes one side
    instead of their average, which can fall in the valves' dead zone and freeze the machine).
    The observations are normalised with the model's VecNormalize statistics, as PPO will see them.
    Uses its own optimiser, so the model's (saved with it) stays empty and the file small.
    """
    import torch

    power = _loss_power(loss)
    torch.manual_seed(seed)
    policy = model.policy
    obs = torch.as_tensor(model.get_vec_normalize_env().normalize_obs(demos.obs), dtype=torch.float32)
    actions = torch.as_tensor(demos.actions, dtype=torch.float32)
    returns = torch.as_tensor(demos.returns, dtype=torch.float32)
    optimiser = torch.optim.Adam(policy.parameters(), lr=1e-3)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=epochs)
    policy.train()
    for _ in range(epochs):
        order = torch.randperm(len(obs))
        for start in range(0, len(obs), batch):
            idx = order[start : start + batch]
            features = policy.extract_features(obs[idx])
            latent_pi, latent_vf = policy.mlp_extractor(features)
            action_loss = torch.mean(torch.abs(policy.action_net(latent_pi) - actions[idx]) ** power)
            value_loss = torch.mean((policy.value_net(latent_vf).squeeze(-1) - returns[idx]) ** 2)
            optimiser.zero_grad()
            (action_loss + 0.1 * value_loss).backward()
            optimiser.step()
        schedule.step()
    policy.eval()
    return {"action_loss": action_loss.item(), "value_mse": value_loss.item()}


def _new_ppo(hp: dict[str, Any], seed: int) -> Any:
    """A PPO model with ``hp``'s architecture on one in-process environment (VecNormalize, not updating)."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    env_kwargs, wrapper = hp.get("env_kwargs") or {}, hp.get("env_wrapper")
    venv = VecNormalize(
        DummyVecEnv([lambda: make_env(ENV_ID, wrapper, **env_kwargs)]), **(hp["normalize"] or {"norm_obs": True})
    )
    return _new_model(PPO, hp, venv, seed=seed)


def _new_model(algo_class: type, hp: dict[str, Any], venv: Any, **kwargs: Any) -> Any:
    """``algo_class`` built from ``hp`` on ``venv``; a ValueError (and ``venv`` closed) when they do not fit."""
    try:
        return algo_class(hp.get("policy", "MlpPolicy"), venv, device="cpu", **kwargs, **algo_kwargs(hp))
    except (TypeError, ValueError, AssertionError, KeyError) as exc:
        venv.close()
        message = " ".join(str(exc).split()) or type(exc).__name__
        raise ValueError(f"the hyperparameters do not make a {algo_class.__name__} model: {message}") from None


def clone_scripted(
    out: str | Path,
    episodes: int = 16,
    dagger_rounds: int = 2,
    dagger_episodes: int = 8,
    noise: float = 0.0,
    epochs: int = 30,
    seed: int = 1000,
    hyperparams: str | Path | None = None,
    select_episodes: int = 0,
    rounds_dir: str | Path | None = None,
    loss: str = "mse",
    tables: str | None = None,
    loader_settings: str | Path | None = None,
    log: Callable[[str], None] | None = None,
) -> Path:
    """Behaviour-clone the scripted loader into a PPO model saved at ``out`` (+ VecNormalize statistics).

    Seeds start at ``seed`` (default 1000: away from the evaluation seeds 0..N). Round 0 records
    ``episodes`` scripted episodes (with DART ``noise``) and fits; DAgger round k records
    ``dagger_episodes`` more in which the learner of round k-1 drives each step with probability
    1 - 0.5**k, all labelled by the loader, and refits on everything (warm-started). With
    ``select_episodes`` > 0 each round's clone is scored on that many further seeded episodes
    (tonnes delivered) and the best is saved at ``out``; otherwise the last round's. Each round's
    clone is kept in ``rounds_dir`` (``round<k>.zip``) when given. ``loss``: the actor's fit
    (:func:`fit_to_demonstrations`). ``tables``: the learned model the episodes run on (``HexLoading-v0``'s
    ``tables``; default the hyperparameters' ``env_kwargs``, else the environment's default).
    ``loader_settings``: a JSON file of the teaching loader's settings (``hexgym tune-loader``). Progress
    (:mod:`hexgym_lab.progress`): a count of rounds and a line per round (to ``log`` where given).
    """
    _loss_power(loss)  # bad arguments fail here, before minutes of recording
    for name, value, minimum in (("episodes", episodes, 1), ("dagger_rounds", dagger_rounds, 0),
                                 ("dagger_episodes", dagger_episodes, 1), ("epochs", epochs, 1),
                                 ("select_episodes", select_episodes, 0)):  # fmt: skip
        check_count(name, value, minimum)
    check_seed("seed", seed)
    check_range("noise", noise, 0.0, 1.0, "(spool fraction)")
    from hexgym.agents.scripted import load_settings

    teacher = load_settings(loader_settings)
    if not str(out).endswith(".zip"):
        raise ValueError(f"the model must be a .zip file, got {out}")
    check_output_file(out, "model", inputs=(hyperparams,))
    check_output_file(normalizer_path(out), "observation normaliser", inputs=(hyperparams,))
    if rounds_dir is not None:
        check_output_dir(rounds_dir, "rounds directory")
    hp = load_hyperparams("ppo", ENV_ID, hyperparams)
    if tables is not None:
        hp["env_kwargs"] = {**(hp.get("env_kwargs") or {}), "tables": tables}
    check_hyperparams("ppo", hp)
    progress = Progress(dagger_rounds + 1, "clone", "round")
    with _worker_pool() as pool, tempfile.TemporaryDirectory() as tmp, progress:  # workers start once (torch: s)
        rounds = Path(rounds_dir) if rounds_dir is not None else Path(tmp)
        return _clone_rounds(Path(out), rounds, hp, pool, episodes, dagger_rounds, dagger_episodes, noise, epochs,
                             seed, select_episodes, loss, teacher, log or progress.note, progress)  # fmt: skip


def _clone_rounds(
    out: Path, rounds: Path, hp: dict[str, Any], pool: LocalPool, episodes: int, dagger_rounds: int,
    dagger_episodes: int, noise: float, epochs: int, seed: int, select_episodes: int, loss: str,
    teacher: LoaderSettings, log: Callable[[str], None], progress: Progress,
) -> Path:  # fmt: skip
    """:func:`clone_scripted`'s rounds, recording and scoring in ``pool``."""
    gamma = float(hp.get("gamma", 0.99))
    model = _new_ppo(hp, seed)
    env_kwargs, wrapper = hp.get("env_kwargs"), hp.get("env_wrapper")
    task = trained_on(ENV_ID, env_kwargs)
    next_seed = seed + episodes
    demos = record_demonstrations(list(range(seed, next_seed)), gamma, env_kwargs=env_kwargs, wrapper=wrapper,
                                  noise=noise, pool=pool, loader_settings=teacher)  # fmt: skip
    select_seeds = list(range(seed + 100_000, seed + 100_000 + select_episodes))  # never trained on
    best: tuple[float, Path] | None = None
    for round_ in range(dagger_rounds + 1):
        stats = model.get_vec_normalize_env().obs_rms
        stats.mean, stats.var, stats.count = demos.obs.mean(0), demos.obs.var(0) + 1e-8, len(demos.obs)
        losses = fit_to_demonstrations(model, demos, epochs, seed + round_, loss=loss)
        path = save_model(model, rounds / f"round{round_}.zip", task)  # each round's clone, to compare and select
        message = (f"round {round_}: {len(demos.obs)} samples, action {loss} {losses['action_loss']:.4f}, "
                   f"value MSE {losses['value_mse']:.4f}")  # fmt: skip
        if select_seeds:
            n = len(select_seeds)
            scores = _in_workers(pool, None, score_episode, [str(path)] * n, select_seeds, [env_kwargs] * n)
            delivered = float(np.mean([s["delivered_t"] for s in scores]))
            message += f", {delivered:.2f} t delivered per selection episode"
            if best is None or delivered >= best[0]:  # ties: the later round, fitted on more data
                best = (delivered, path)
        log(message)
        progress.update()
        if round_ == dagger_rounds:
            break
        seeds = list(range(next_seed, next_seed + dagger_episodes))
        beta = 0.5 ** (round_ + 1)
        demos = Demonstrations.concatenate(
            [
                demos,
                record_demonstrations(
                    seeds, gamma, str(path), beta, env_kwargs, wrapper, noise, pool=pool, loader_settings=teacher
                ),
            ]
        )
        next_seed += dagger_episodes
    if best is None:
        return save_model(model, out, task)
    log(f"selected {best[1].name} ({best[0]:.2f} t per selection episode)")
    with atomic_paths(out, normalizer_path(out)) as (model_tmp, normalizer_tmp):  # the pair, or neither
        shutil.copyfile(best[1], model_tmp)
        shutil.copyfile(normalizer_path(best[1]), normalizer_tmp)
    return out

"""``HexLoading-v0`` batched: N loading sites stepped together (``gymnasium.make_vec("HexLoading-v0", num_envs=N)``).

:class:`HexLoadingVectorEnv` runs the N machines as one :class:`mujoco.batch.Batch` of the native
plugin's model (a persistent pool of C threads, one ``MjData`` per site, each site's state its
``mjSTATE_INTEGRATION`` row, per-site payload masses; :class:`hexgym.envs.sites.BatchSites`), or on the
Python backend as N learned models (:class:`hexgym.envs.sites.MachineSites`), under the loading task of
N sites (:class:`hexgym.envs.task.LoadingTask`), the one the single environment runs with N = 1, so
that its results equal N :class:`HexLoadingEnv` stepped one by one (``tests/test_vector_env.py``).
Resets (once per episode) draw each site's episode as the single environment's reset does
(:func:`hexgym.envs.loading.draw_loading_start`) and start it through the sites' physics
(:meth:`hexgym.envs.task.SitePhysics.start`); a step's actions become the sites' held spools
(:meth:`hexgym.envs.task.SitePhysics.hold`) in the task's step.
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from hexgym.checks import check_count
from hexgym.envs import ENV_ID
from hexgym.envs.base import check_open, make_config, task_spaces
from hexgym.envs.compiled import jit
from hexgym.envs.loading import LoadingConfig, draw_loading_start
from hexgym.envs.sites import VEL_STAGE, BatchSites, MachineSites, make_machine, native_world_model
from hexgym.envs.task import CONTACT_SLOTS, INFO_KEYS, REWARD_TERMS, STEP_INFO_KEYS, STEP_PERIOD, LoadingTask
from hexgym.envs.world import Layout
from hexgym.machine import parameters as p
from hexgym.model.backend import backend_for
from hexgym.model.plugin import CTRL_PER_SPOOL_M

# the single environment's info keys, each followed by its mask's (SyncVectorEnv's order)
_MASKED_INFO_KEYS, _MASKED_STEP_INFO_KEYS = (
    tuple(name for key in keys for name in (key, f"_{key}")) for keys in (INFO_KEYS, STEP_INFO_KEYS)
)
_ACTION_DTYPES = (np.dtype(np.float32), np.dtype(np.float64))  # (others are converted to float64)
_STROKE = float(p.SPOOL_STROKE)


class HexLoadingVectorEnv(VectorEnv):
    """``num_envs`` independent ``HexLoading-v0`` sites stepped as one batch (see the module docstring).

    Spaces, rewards, observations and ``info`` keys are the single environment's
    (:class:`hexgym.envs.loading.HexLoadingEnv`), batched: actions ``(num_envs, 4)``, observations
    ``(num_envs, 23)``, rewards, terminations and truncations ``(num_envs,)``, ``info`` a dict of
    arrays with a ``_key`` mask each (Gymnasium's vector convention). Episodes reset automatically
    on the step after they end (``AutoresetMode.NEXT_STEP``, as ``SyncVectorEnv``): that step
    returns the new episode's first observation with reward 0. ``reset(seed=s)`` seeds site ``i``
    with ``s + i``, so site ``i`` follows ``HexLoadingEnv`` reset with that seed.

    On the native plugin the sites are one MuJoCo batch stepped in C threads (:class:`BatchSites`); on
    the Python backend (``backend="python"``, or ``"auto"`` without the plugin or with
    ``HEXGYM_BACKEND=python``) N learned models in turn (:class:`MachineSites`: slow, but the same
    task and results as N single environments). No rendering: render a single environment.

    Args:
        num_envs: number of sites.
        nthread: the batch's threads (default: the CPUs this process may use, at most ``num_envs``).
        scene_path: as ``HexLoadingEnv``'s (the batch's model is built on it too).
        backend: ``"native"`` (needs the plugin), ``"python"`` or ``"auto"``
            (:func:`hexgym.model.backend.resolve_backend`).
        render_mode: only None.
        env_kwargs: the other fields of :class:`hexgym.envs.loading.LoadingConfig` (time limit, truck capacity,
            reward weights, earthwork periods, start shares), checked as the single environment checks them.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": [], "render_fps": round(1 / STEP_PERIOD)}

    def __init__(
        self,
        num_envs: int,
        nthread: int | None = None,
        scene_path: str | Path | None = None,
        backend: str = "auto",
        render_mode: str | None = None,
        **env_kwargs: Any,
    ) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if nthread is not None:
            check_count("nthread", nthread)
        if render_mode is not None:
            raise ValueError(
                f"the batched HexLoading-v0 does not render (render_mode {render_mode!r}): render a "
                "single environment, or use gymnasium.make_vec(..., vectorization_mode='sync')"
            )
        if env_kwargs.get("model", "learned") != "learned":
            raise ValueError(
                f"the batched HexLoading-v0 runs the learned model only (model={env_kwargs['model']!r}): use "
                "gymnasium.make_vec(..., vectorization_mode='sync') or single environments"
            )
        # the single environment's config: its checks, its defaults
        overrides = {"scene_path": scene_path, "backend": backend, **env_kwargs}
        self.config = config = make_config(LoadingConfig, ENV_ID, None, overrides)
        backend = backend_for(config.table_set, backend)
        if backend == "native":
            from hexgym.model.plugin import NativePluginError, load_plugin

            reason = load_plugin()
            if reason:
                raise NativePluginError(
                    f"the batched HexLoading-v0 on the native backend needs the native plugin: {reason}; use "
                    "backend='python' or gymnasium.make_vec('HexLoading-v0', num_envs, vectorization_mode='sync')"
                )
        self.backend = backend
        self.num_envs = int(num_envs)
        self.render_mode = None
        self.single_observation_space, self.single_action_space = task_spaces()
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        if backend == "native":
            model = native_world_model(
                scene_path, config.table_set, tool_contact_slots=CONTACT_SLOTS, tables_dir=config.tables_dir,
                hydraulics=config.hydraulics(),
            )  # fmt: skip
            if nthread is None:
                nthread = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
            self.nthread = max(1, min(int(nthread), self.num_envs))
            self.sites: BatchSites | MachineSites = BatchSites(model, self.num_envs, self.nthread)
        else:
            self.nthread = 1
            machines = [
                make_machine("python", scene_path, config.table_set, CONTACT_SLOTS, config.tables_dir,
                             config.hydraulics())
                for _ in range(self.num_envs)
            ]  # fmt: skip
            self.sites = MachineSites(machines)
        self.task = LoadingTask(
            self.num_envs, self.sites, *config.site_rules(), config.earthwork_periods, config.material_density,
            config.engine_power_w,
        )  # fmt: skip
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._autoreset = np.zeros(self.num_envs, bool)
        self._obs = np.zeros((self.num_envs, *self.single_observation_space.shape), np.float32)
        self._every = np.arange(self.num_envs)
        self._spools_m = np.zeros((self.num_envs, 4))  # a step's actions as spools, m
        self._started = False

    @property
    def time_limit(self) -> float:
        """Episode length, s."""
        return self.config.time_limit

    @property
    def layouts(self) -> list[Layout | None]:
        """Each site's pile and truck placement."""
        return self.task.layouts

    @property
    def physics_seconds(self) -> float:
        """Wall seconds spent in the batch's physics steps (the rest of a step is the task logic; native only)."""
        return getattr(self.sites, "seconds", math.nan)

    # -- Gymnasium API -------------------------------------------------------------------------
    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every site (``seed``: an int gives site ``i`` the seed ``seed + i``; a list one each).

        ``options={"reset_mask": m}`` (a bool array, one per site) resets only the sites where ``m`` is True,
        as ``SyncVectorEnv`` does; the others keep their episode (and their last observation). Other options
        are ignored, as ``HexLoadingEnv.reset`` ignores them.
        """
        self._check_open()
        mask = np.ones(self.num_envs, bool)
        if options is not None and "reset_mask" in options:
            mask = options["reset_mask"]
            if not isinstance(mask, np.ndarray) or mask.shape != (self.num_envs,) or mask.dtype != np.bool_:
                raise ValueError(
                    f"options['reset_mask'] must be a bool array of shape ({self.num_envs},), got {mask!r}"
                )
            if not mask.any():
                raise ValueError("options['reset_mask'] resets no environment")
        if seed is None:
            seeds: list[int | None] = [None] * self.num_envs
        elif isinstance(seed, int | np.integer) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed must be an int or a list of {self.num_envs} seeds, got {len(seeds)}")
        if not self._started and not mask.all():
            raise RuntimeError("the first reset() must reset every environment (no reset_mask)")
        sites = np.flatnonzero(mask)
        self._start_sites(sites, [seeds[i] for i in sites])
        self._started = True
        self._obs[sites] = self.task.observe(sites)
        reported = None if mask.all() else mask
        no_step = np.zeros(self.num_envs, bool)
        return self._obs.copy(), self._infos(np.zeros((self.num_envs, len(REWARD_TERMS))), reported, no_step)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every site by 0.1 s; sites whose episode ended on the last step start a new one instead."""
        self._check_open()
        if not self._started:
            raise RuntimeError("call reset() before step()")
        if self._autoreset.any():
            return self._step_restarting(actions)
        spools = self._spools_from(actions)
        terms, rewards, ended = self.task.step(self._every, spools)  # every site steps: the results are the task's
        return self._results(terms, rewards, ended, None)

    def _check_open(self) -> None:
        check_open("the batched HexLoading-v0", self.closed)

    def _step_restarting(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """:meth:`step` where some sites start a new episode instead (reward 0, not ended)."""
        n = self.num_envs
        stepped = ~self._autoreset
        stepping, restarting = np.flatnonzero(stepped), np.flatnonzero(self._autoreset)
        spools = self._spools_from(actions)  # (checks every row before a site restarts)
        self._start_sites(restarting, [None] * len(restarting))
        terms, rewards, ended = np.zeros((n, len(REWARD_TERMS))), np.zeros(n), np.zeros((n, 2), bool)
        if len(stepping):
            terms[stepping], rewards[stepping], ended[stepping] = self.task.step(stepping, spools[stepping])
        return self._results(terms, rewards, ended, stepped)

    def _results(
        self, terms: np.ndarray, rewards: np.ndarray, ended: np.ndarray, stepped: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """A step's returns from every site's reward terms, rewards and ends (terminated, truncated) and the mask of
        the sites that stepped (None: every site); the observations and ``info`` are read from the task."""
        self.task.observe(self._every, out=self._obs)
        infos = self._infos(terms, None, stepped)
        terminated, truncated = ended.T.copy()
        self._autoreset = terminated | truncated
        return self._obs.copy(), rewards, terminated, truncated, infos

    def _spools_from(self, actions: np.ndarray) -> np.ndarray:
        """The spools (num_envs, 4), m, of ``actions`` ((num_envs, 4), finite): clipped to [-1, 1] and scaled as
        the single environment's (the array is reused by the next step)."""
        try:
            a = np.asarray(actions)
        except ValueError as exc:  # nested sequences of different lengths
            raise ValueError(f"actions must be an array of shape ({self.num_envs}, 4): {exc}") from None
        if a.dtype.kind not in "biuf":  # numpy makes an object or text array of a dict, text or None
            raise TypeError(
                f"actions must be an array of shape ({self.num_envs}, 4) of numbers, got {type(actions).__name__} "
                f"{actions!r:.60}"
            )
        if a.shape != (self.num_envs, 4):
            raise ValueError(
                f"actions must have shape ({self.num_envs}, 4) (one row of swing, boom, stick, bucket "
                f"spools per environment), got shape {a.shape}"
            )
        if a.dtype not in _ACTION_DTYPES or not a.flags.c_contiguous:
            a = np.ascontiguousarray(a, dtype=np.float64)
        bad = _spools_of(a, self._spools_m)
        if bad >= 0:
            not_finite = ~np.isfinite(a)
            rows = np.flatnonzero(not_finite.any(axis=1))
            raise ValueError(
                f"actions must be finite: environment {bad} got {a[bad]} (NaN or inf in entries "
                f"{np.flatnonzero(not_finite[bad]).tolist()}; environments {rows.tolist()} have one)"
            )
        return self._spools_m

    def step_physics_only(self, spools_mm: np.ndarray) -> float:
        """Step every site's physics one environment step with ``spools_mm`` ((num_envs, 4), the plugin's ctrl)
        and no task logic; returns the wall seconds of the batch's step. The physics' share of a step: what
        benchmarks compare the full step with (the site states are left inconsistent with the task: reset after).
        Native backend only."""
        self._check_open()
        if not isinstance(self.sites, BatchSites):
            raise NotImplementedError("step_physics_only times the native batch; this environment runs in Python")
        self.sites.hold(self._every, np.asarray(spools_mm, dtype=float) / CTRL_PER_SPOOL_M)
        start = time.perf_counter()
        self.sites.batch.step(None, nstep=self.task.periods, stage=VEL_STAGE)  # as BatchSites.step every site
        return time.perf_counter() - start

    def close_extras(self, **kwargs: Any) -> None:
        """Stop the batch's threads."""
        if isinstance(getattr(self, "sites", None), BatchSites):  # (a failed construction closes too)
            self.sites.batch = None

    # -- resets ---------------------------------------------------------------------------------
    def _start_sites(self, ids: np.ndarray, seeds: list[int | None]) -> None:
        """Draw the episodes of sites ``ids`` as HexLoadingEnv.reset does (site ``i`` from its own generator,
        seeded anew where a seed is given) and start them."""
        starts = []
        for i, seed in zip(ids.tolist(), seeds, strict=True):
            if seed is not None or self._rngs[i] is None:
                self._rngs[i], _ = gym.utils.seeding.np_random(seed)
            starts.append(draw_loading_start(self._rngs[i], self.config))
        self.task.start(ids, starts)
        self._autoreset[ids] = False

    # -- info ---------------------------------------------------------------------------------------
    def _infos(self, terms: np.ndarray, reported: np.ndarray | None, stepped: np.ndarray | None) -> dict[str, Any]:
        """The info dicts of the sites as SyncVectorEnv gathers them: per key an array and a ``_key`` mask. The reward
        ``terms`` (num_envs, 10) and the stores of the ``reported`` sites (a mask; None: every site; 0 elsewhere), and
        the step's fuel and impulse of the sites that ``stepped`` (a mask, none after a reset; None: every site). The
        values are the rows of one array, the masks of another."""
        n, k = self.num_envs, len(INFO_KEYS)
        extras = stepped is None or stepped.any()
        keys = _MASKED_STEP_INFO_KEYS if extras else _MASKED_INFO_KEYS
        values = np.empty((len(keys) // 2, n))
        values[: len(REWARD_TERMS)] = terms.T
        values[len(REWARD_TERMS) : k] = self.task.stores_of(self._every).T
        if extras:
            values[k], values[k + 1] = self.task.step_fuel_l, self.task.step_impulse
        masks = np.ones(values.shape, bool)
        if reported is not None:  # (a reset of some sites)
            masks[:k] = reported
            values[:k, ~reported] = 0.0
        if extras and stepped is not None:  # (a step where some sites restart)
            masks[k:] = stepped
            values[k:, ~stepped] = 0.0
        entries = [None] * len(keys)
        entries[0::2], entries[1::2] = values, masks
        return dict(zip(keys, entries, strict=True))


@jit
def _spools_of(actions: np.ndarray, out: np.ndarray) -> int:
    """Each site's ``actions`` row clipped to [-1, 1] times the stroke (m; the single environment's arithmetic)
    into ``out``. Returns the first site whose row is not finite (nothing set then), else -1."""
    for i in range(actions.shape[0]):
        for j in range(4):
            if not math.isfinite(actions[i, j]):
                return i
    for i in range(actions.shape[0]):
        for j in range(4):
            out[i, j] = min(max(float(actions[i, j]), -1.0), 1.0) * _STROKE
    return -1


def make_vector_env(num_envs: int, **kwargs: Any) -> HexLoadingVectorEnv:
    """``HexLoading-v0``'s ``vector_entry_point`` (``gymnasium.make_vec`` passes ``num_envs`` and the env kwargs)."""
    kwargs.pop("max_episode_steps", None)  # the environment truncates itself (time_limit)
    return HexLoadingVectorEnv(num_envs, **kwargs)

"""``HexLoading-v0`` batched: N loading sites stepped together (``gymnasium.make_vec("HexLoading-v0", num_envs=N)``).

:class:`HexLoadingVectorEnv` runs the N machines as one :class:`mujoco.batch.Batch` of the native
plugin's model (a persistent pool of C threads, one ``MjData`` per site, each site's state its
``mjSTATE_INTEGRATION`` row, per-site payload masses; :class:`hexgym.envs.sites.BatchSites`), or on the
Python backend as N learned models (:class:`hexgym.envs.sites.MachineSites`), under the loading task of
N sites (:class:`hexgym.envs.task.LoadingTask`), the one the single environment runs with N = 1, so
that its results equal N :class:`HexLoadingEnv` stepped one by one (``tests/test_vector_env.py``).
Resets (once per episode) draw each site's episode as the single environment's reset does; on the
batch, its machine starts on a scratch :class:`HexLoadingEnv` whose state is copied into the site's row.
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from hexgym.envs.loading import HexLoadingEnv, heap_for, make_machine, native_world_model, start_machine
from hexgym.envs.sites import BatchSites, MachineSites
from hexgym.envs.task import CONTACT_SLOTS, INFO_STORES, REWARD_TERMS, STEP_PERIOD, LoadingTask
from hexgym.envs.world import Layout, World
from hexgym.machine import parameters as p
from hexgym.mbl.schema import DEFAULT_TABLE_SET
from hexgym.model.backend import backend_for
from hexgym.model.plugin import CTRL_PER_SPOOL_M

_VEL = int(mujoco.mjtStage.mjSTAGE_VEL)  # after a step: positions and velocities current, as mj_step1 leaves them
_ACC = int(mujoco.mjtStage.mjSTAGE_ACC)
_STATE = mujoco.mjtState.mjSTATE_INTEGRATION
_INFO_KEYS = (*(f"reward_{term}" for term in REWARD_TERMS), *INFO_STORES)


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
        env_kwargs: the other keyword arguments of ``HexLoadingEnv`` (time limit, truck capacity, reward
            weights, earthwork periods), with its defaults: the single environment takes and checks them.
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
        backend = backend_for(env_kwargs.get("tables", DEFAULT_TABLE_SET), backend)
        if backend == "native":
            from hexgym.model.plugin import NativePluginError, load_plugin

            reason = load_plugin()
            if reason:
                raise NativePluginError(
                    f"the batched HexLoading-v0 on the native backend needs the native plugin: {reason}; use "
                    "backend='python' or gymnasium.make_vec('HexLoading-v0', num_envs, vectorization_mode='sync')"
                )
        self.backend = backend
        # the single environment checks the arguments, resets the sites and holds the spaces
        self._scratch = HexLoadingEnv(scene_path=scene_path, backend=backend, **env_kwargs)
        scratch = self._scratch
        self.num_envs = int(num_envs)
        self.render_mode = None
        self.time_limit, self.truck_capacity_kg = scratch.time_limit, scratch.truck_capacity_kg
        self.weights, self.earthwork_periods = scratch.weights, scratch.earthwork_periods
        self.single_action_space, self.single_observation_space = scratch.action_space, scratch.observation_space
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        if backend == "native":
            model = native_world_model(scene_path, scratch.tables, tool_contact_slots=CONTACT_SLOTS)
            if mujoco.mj_stateSize(model, _STATE) != mujoco.mj_stateSize(scratch.physics.model, _STATE):
                raise RuntimeError("the batch's model and the single environment's differ in their state")
            if nthread is None:
                nthread = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
            self.nthread = max(1, min(int(nthread), self.num_envs))
            self.sites: BatchSites | MachineSites = BatchSites(model, self.num_envs, self.nthread)
            self._worlds: list[World] = []
        else:
            self.nthread = 1
            machines = [
                make_machine("python", scene_path, scratch.tables, tool_contact_slots=CONTACT_SLOTS)
                for _ in range(self.num_envs)
            ]  # fmt: skip
            self._worlds = [World(machine.physics.model) for machine in machines]
            self.sites = MachineSites(machines)
        self.task = LoadingTask(
            self.num_envs, self.sites, scratch.task.period, self.time_limit, self.truck_capacity_kg, self.weights,
            self.earthwork_periods,
        )  # fmt: skip
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._autoreset = np.zeros(self.num_envs, bool)
        self._obs = np.zeros((self.num_envs, *self.single_observation_space.shape), np.float32)
        self._every = np.arange(self.num_envs)
        self._started = False

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
        for i in sites:
            self._start_site(int(i), seeds[i])
        self._finish_starts(sites)
        self._autoreset[sites] = False
        self._started = True
        self._obs[sites] = self.task.observe(sites)
        return self._obs.copy(), self._infos(mask, np.zeros((self.num_envs, len(REWARD_TERMS))), None)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every site by 0.1 s; sites whose episode ended on the last step start a new one instead."""
        if not self._started:
            raise RuntimeError("call reset() before step()")
        a = self._check_actions(actions)
        n = self.num_envs
        stepping = self._every
        if self._autoreset.any():
            stepping, restarting = np.flatnonzero(~self._autoreset), np.flatnonzero(self._autoreset)
            for i in restarting:
                self._start_site(int(i), None)
            self._finish_starts(restarting)
        stepped = np.zeros(n, bool)
        stepped[stepping] = True
        if len(stepping) == n:  # the usual step: every site steps, its results are the task's arrays
            self._hold_spools(stepping, a)
            terms, rewards, ended = self.task.step(stepping)
        else:  # some sites restart instead: reward 0, not ended
            terms, rewards, ended = np.zeros((n, len(REWARD_TERMS))), np.zeros(n), np.zeros((n, 2), bool)
            if len(stepping):
                self._hold_spools(stepping, a[stepping])
                terms[stepping], rewards[stepping], ended[stepping] = self.task.step(stepping)
        self._obs = self.task.observe(self._every)
        infos = self._infos(np.ones(n, bool), terms, (stepped, self.task.step_fuel_l, self.task.step_impulse))
        terminated, truncated = ended[:, 0].copy(), ended[:, 1].copy()
        self._autoreset = terminated | truncated
        return self._obs.copy(), rewards, terminated, truncated, infos

    def _hold_spools(self, ids: np.ndarray, actions: np.ndarray) -> None:
        """Set the spools of sites ``ids`` from their ``actions`` (k, 4; clipped to [-1, 1], scaled to the stroke)."""
        spools = np.minimum(np.maximum(actions, -1.0), 1.0) * p.SPOOL_STROKE
        if isinstance(self.sites, BatchSites):
            self.sites.ctrl[ids[:, None], self.sites.ctrl_ids] = spools * CTRL_PER_SPOOL_M
        else:
            self.sites.spools_m[ids] = spools

    def step_physics_only(self, spools_mm: np.ndarray) -> float:
        """Step every site's physics one environment step with ``spools_mm`` ((num_envs, 4), the plugin's ctrl)
        and no task logic; returns the wall seconds of the batch's step. The physics' share of a step: what
        benchmarks compare the full step with (the site states are left inconsistent with the task: reset after).
        Native backend only."""
        if not isinstance(self.sites, BatchSites):
            raise NotImplementedError("step_physics_only times the native batch; this environment runs in Python")
        self.sites.ctrl[:, self.sites.ctrl_ids] = spools_mm
        start = time.perf_counter()
        self.sites.batch.step(np.arange(self.num_envs), nstep=self.task.periods, stage=_VEL)
        return time.perf_counter() - start

    def close_extras(self, **kwargs: Any) -> None:
        """Stop the batch's threads."""
        if isinstance(getattr(self, "sites", None), BatchSites):  # (a failed construction closes too)
            self.sites.batch = None
        if hasattr(self, "_scratch"):
            self._scratch.close()

    def _check_actions(self, actions: np.ndarray) -> np.ndarray:
        a = np.asarray(actions, dtype=np.float64)
        if a.shape != (self.num_envs, 4):
            raise ValueError(
                f"actions must have shape ({self.num_envs}, 4) (one row of swing, boom, stick, bucket "
                f"spools per environment), got shape {a.shape}"
            )
        if not np.isfinite(a).all():
            bad = ~np.isfinite(a)
            rows = np.flatnonzero(bad.any(axis=1))
            i = int(rows[0])
            raise ValueError(
                f"actions must be finite: environment {i} got {a[i]} (NaN or inf in entries "
                f"{np.flatnonzero(bad[i]).tolist()}; environments {rows.tolist()} have one)"
            )
        return a

    # -- resets ---------------------------------------------------------------------------------
    def _start_site(self, i: int, seed: int | None) -> None:
        """Draw site ``i``'s episode as HexLoadingEnv.reset does (on the scratch environment) and load it."""
        if seed is not None or self._rngs[i] is None:
            self._rngs[i], _ = gym.utils.seeding.np_random(seed)
        layout, q = self._scratch._draw_start(self._rngs[i])  # the single environment's start, dig starts too
        scratch, sites = self._scratch, self.sites
        if isinstance(sites, BatchSites):
            scratch.start_machine(q, layout)
            mujoco.mj_getState(scratch.physics.model, scratch.physics.data, sites.state[i], _STATE)
            sites.body_mass[i, sites.payload_body] = scratch.physics.model.body_mass[sites.payload_body]
            sites.body_inertia[i, sites.payload_body] = scratch.physics.model.body_inertia[sites.payload_body]
            payload_kg = scratch.physics.payload_kg
        else:
            start_machine(sites.machines[i], self._worlds[i], q, layout)
            payload_kg = sites.machines[i].physics.payload_kg
        self.task.start(i, layout, heap_for(layout), payload_kg)
        self._autoreset[i] = False

    def _finish_starts(self, ids: np.ndarray) -> None:
        """Derived quantities of freshly loaded sites (the start's masses, ``mj_forward``) and their teeth."""
        if isinstance(self.sites, BatchSites):
            self.sites.batch.set_const(ids)
            self.sites.batch.forward(ids, stage=_ACC)
        self.sites.refresh(ids)
        self.task.finish_starts(ids)

    # -- info ---------------------------------------------------------------------------------------
    def _infos(
        self, reported: np.ndarray, terms: np.ndarray, step_extras: tuple[np.ndarray, ...] | None
    ) -> dict[str, Any]:
        """The info dicts of the sites where ``reported`` as SyncVectorEnv gathers them: an array (0 elsewhere) and
        a ``_key`` mask per key; ``terms`` (num_envs, 6); ``step_extras``: (mask of the sites that stepped, their
        fuel, their impulse)."""
        info = _columns(_INFO_KEYS, np.concatenate([terms, self.task.stores_of(self._every)], axis=1), reported)
        if step_extras is not None and step_extras[0].any():
            stepped, fuel_l, impulse = step_extras
            info |= _columns(("fuel_l_step", "contact_impulse_ns"), np.stack([fuel_l, impulse], axis=1), stepped)
        return info


def _columns(keys: tuple[str, ...], columns: np.ndarray, reported: np.ndarray) -> dict[str, np.ndarray]:
    """``{key: its column of columns where reported, else 0; _key: reported}``, one array each (each a row of one
    transposed copy: contiguous, and one copy for all keys instead of one per key)."""
    if not reported.all():
        columns = np.where(reported[:, None], columns, 0.0)
    values = np.ascontiguousarray(columns.T)
    masks = np.repeat(reported[None], len(keys), axis=0)
    info = {}
    for k, key in enumerate(keys):
        info[key], info[f"_{key}"] = values[k], masks[k]
    return info


def make_vector_env(num_envs: int, **kwargs: Any) -> HexLoadingVectorEnv:
    """``HexLoading-v0``'s ``vector_entry_point`` (``gymnasium.make_vec`` passes ``num_envs`` and the env kwargs)."""
    kwargs.pop("max_episode_steps", None)  # the environment truncates itself (time_limit)
    return HexLoadingVectorEnv(num_envs, **kwargs)

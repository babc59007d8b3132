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

from hexgym.checks import check_choice, check_count
from hexgym.envs.earthwork import jit
from hexgym.envs.loading import HexLoadingEnv, check_open, heap_for, make_machine, native_world_model, start_machine
from hexgym.envs.sites import ACC_STAGE, VEL_STAGE, BatchSites, MachineSites
from hexgym.envs.task import CONTACT_SLOTS, INFO_KEYS, REWARD_TERMS, STEP_INFO_KEYS, STEP_PERIOD, LoadingTask
from hexgym.envs.world import Layout, World
from hexgym.machine import parameters as p
from hexgym.mbl.schema import DEFAULT_TABLE_SET, TABLE_SETS
from hexgym.model.backend import backend_for
from hexgym.model.plugin import CTRL_PER_SPOOL_M

_STATE = mujoco.mjtState.mjSTATE_INTEGRATION
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
        backend = backend_for(check_choice("tables", env_kwargs.get("tables", DEFAULT_TABLE_SET), TABLE_SETS), backend)
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
        # where the spools go: the batch's ctrl columns in the plugin's units, or the machines' spools in m
        if isinstance(self.sites, BatchSites):
            self._spools = self.sites.ctrl, self.sites.ctrl_ids, CTRL_PER_SPOOL_M
        else:
            self._spools = self.sites.spools_m, np.arange(4), 1.0
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
        for i in sites:
            self._start_site(int(i), seeds[i])
        self._finish_starts(sites)
        self._autoreset[sites] = False
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
        self._hold_spools(self._every, actions)
        terms, rewards, ended = self.task.step(self._every)  # every site steps: the task's arrays are the results
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
        self._hold_spools(stepping, actions)  # (checks every row before a site restarts)
        for i in restarting:
            self._start_site(int(i), None)
        self._finish_starts(restarting)
        terms, rewards, ended = np.zeros((n, len(REWARD_TERMS))), np.zeros(n), np.zeros((n, 2), bool)
        if len(stepping):
            terms[stepping], rewards[stepping], ended[stepping] = self.task.step(stepping)
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

    def _hold_spools(self, ids: np.ndarray, actions: np.ndarray) -> None:
        """Check ``actions`` ((num_envs, 4), finite) and hold the spools of sites ``ids`` from their rows."""
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
        target, columns, scale = self._spools
        bad = _set_spools(a, ids, target, columns, scale)
        if bad >= 0:
            not_finite = ~np.isfinite(a)
            rows = np.flatnonzero(not_finite.any(axis=1))
            raise ValueError(
                f"actions must be finite: environment {bad} got {a[bad]} (NaN or inf in entries "
                f"{np.flatnonzero(not_finite[bad]).tolist()}; environments {rows.tolist()} have one)"
            )

    def step_physics_only(self, spools_mm: np.ndarray) -> float:
        """Step every site's physics one environment step with ``spools_mm`` ((num_envs, 4), the plugin's ctrl)
        and no task logic; returns the wall seconds of the batch's step. The physics' share of a step: what
        benchmarks compare the full step with (the site states are left inconsistent with the task: reset after).
        Native backend only."""
        self._check_open()
        if not isinstance(self.sites, BatchSites):
            raise NotImplementedError("step_physics_only times the native batch; this environment runs in Python")
        self.sites.ctrl[:, self.sites.ctrl_ids] = spools_mm
        start = time.perf_counter()
        self.sites.batch.step(None, nstep=self.task.periods, stage=VEL_STAGE)  # as BatchSites.step every site
        return time.perf_counter() - start

    def close_extras(self, **kwargs: Any) -> None:
        """Stop the batch's threads."""
        if isinstance(getattr(self, "sites", None), BatchSites):  # (a failed construction closes too)
            self.sites.batch = None
        if hasattr(self, "_scratch"):
            self._scratch.close()

    # -- resets ---------------------------------------------------------------------------------
    def _start_site(self, i: int, seed: int | None) -> None:
        """Draw site ``i``'s episode as HexLoadingEnv.reset does (on the scratch environment) and load it."""
        if seed is not None or self._rngs[i] is None:
            self._rngs[i], _ = gym.utils.seeding.np_random(seed)
        layout, q, payload_kg = self._scratch._draw_start(self._rngs[i])  # the single environment's start
        scratch, sites = self._scratch, self.sites
        if isinstance(sites, BatchSites):
            scratch.start_machine(q, layout, payload_kg)
            mujoco.mj_getState(scratch.physics.model, scratch.physics.data, sites.state[i], _STATE)
            sites.body_mass[i, sites.payload_body] = scratch.physics.model.body_mass[sites.payload_body]
            sites.body_inertia[i, sites.payload_body] = scratch.physics.model.body_inertia[sites.payload_body]
            payload_kg = scratch.physics.payload_kg
        else:
            start_machine(sites.machines[i], self._worlds[i], q, layout, payload_kg)
            payload_kg = sites.machines[i].physics.payload_kg
        self.task.start(i, layout, heap_for(layout), payload_kg)
        self._autoreset[i] = False

    def _finish_starts(self, ids: np.ndarray) -> None:
        """Derived quantities of freshly loaded sites (the start's masses, ``mj_forward``) and their teeth."""
        if isinstance(self.sites, BatchSites):
            self.sites.batch.set_const(ids)
            self.sites.batch.forward(ids, stage=ACC_STAGE)
        self.sites.refresh(ids)
        self.task.finish_starts(ids)

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
def _set_spools(actions: np.ndarray, ids: np.ndarray, target: np.ndarray, columns: np.ndarray, scale: float) -> int:
    """Set the spools of sites ``ids``: their ``actions`` rows clipped to [-1, 1], times the stroke (m), times
    ``scale`` (the plugin's ctrl per m, or 1), into ``target``'s ``columns`` (the single environment's arithmetic).
    Returns the first site whose row is not finite (nothing set then), else -1."""
    for i in range(actions.shape[0]):
        for j in range(4):
            if not math.isfinite(actions[i, j]):
                return i
    for k in range(len(ids)):
        i = ids[k]
        for j in range(4):
            target[i, columns[j]] = min(max(float(actions[i, j]), -1.0), 1.0) * _STROKE * scale
    return -1


def make_vector_env(num_envs: int, **kwargs: Any) -> HexLoadingVectorEnv:
    """``HexLoading-v0``'s ``vector_entry_point`` (``gymnasium.make_vec`` passes ``num_envs`` and the env kwargs)."""
    kwargs.pop("max_episode_steps", None)  # the environment truncates itself (time_limit)
    return HexLoadingVectorEnv(num_envs, **kwargs)

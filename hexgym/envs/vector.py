"""``HexLoading-v0`` batched: N loading sites stepped together (``gymnasium.make_vec("HexLoading-v0", num_envs=N)``).

:class:`HexLoadingVectorEnv` runs the N machines as one :class:`mujoco.batch.Batch` of the native
plugin's model (a persistent pool of C threads, one ``MjData`` per site, each site's state its
``mjSTATE_INTEGRATION`` row, per-site payload masses) under the loading task of N sites
(:class:`hexgym.envs.task.LoadingTask`), the one the single environment runs with N = 1, so that
its results equal N :class:`HexLoadingEnv` stepped one by one (``tests/test_vector_env.py``).

:class:`BatchSites` is the batch as the task's :class:`hexgym.envs.task.SitePhysics`: what the task
reads comes from the batch without a Python loop over sites (bound state and outputs: joints, teeth
site, bucket frame, contact sensor; the plugin state's last constraint load and swing acceleration),
the digging force's joint forces from ``Batch.jac``. Resets (once per episode) run the single
environment's own reset on a scratch :class:`HexLoadingEnv` and copy its state into the site's row.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from mujoco import batch as mjbatch

from hexgym.envs.loading import HexLoadingEnv, heap_for, native_world_model, sample_start
from hexgym.envs.task import CONTACT_SLOTS, INFO_STORES, REWARD_TERMS, STEP_PERIOD, LoadingTask
from hexgym.envs.world import TOOL_CONTACT_SENSOR, Layout
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.physics import payload_inertia
from hexgym.model.plugin import CTRL_PER_SPOOL_M
from hexgym.model.plugin import STATE as PLUGIN_STATE

_VEL = int(mujoco.mjtStage.mjSTAGE_VEL)  # after a step: positions and velocities current, as mj_step1 leaves them
_ACC = int(mujoco.mjtStage.mjSTAGE_ACC)
_STATE = mujoco.mjtState.mjSTATE_INTEGRATION
THREADED_SITE_STEPS = 32  # site steps in one call from which the batch's thread pool is worth waking


class BatchSites:
    """A :class:`mujoco.batch.Batch` of the plugin's model as the loading task's
    :class:`hexgym.envs.task.SitePhysics` (the spools are the batch's ``ctrl``).

    Each call does for its sites what the single environment's machine does to its ``MjData``, to the
    last bit: a batch site steps as ``mj_step``, the joint loads are ``NativeLearnedModel.joint_loads``,
    the digging force ``mj_applyFT``'s sum, the payload ``ExcavatorPhysics.set_payload``'s masses.
    """

    def __init__(self, model: mujoco.MjModel, count: int, nthread: int) -> None:
        self.model = model
        self.batch = b = mjbatch.Batch(model, count, nthread=nthread, persistent=True)
        self.state = b.state
        self.qpos, self.qvel = b.bind("qpos"), b.bind("qvel")
        self.ctrl, self._qfrc_applied = b.bind("ctrl"), b.bind("qfrc_applied")
        self._plugin_state = b.bind("plugin_state")
        self.site_xpos, self.xpos, self.xmat = b.bind("site_xpos"), b.bind("xpos"), b.bind("xmat")
        self._qfrc_bias, self._qfrc_passive = b.bind("qfrc_bias"), b.bind("qfrc_passive")
        self._mass_matrix = b.bind("M")
        self.sensordata = b.bind("sensordata")
        self.body_mass, self.body_inertia = b.expand("body_mass"), b.expand("body_inertia")
        m = model
        self.qadr = np.array([m.jnt_qposadr[m.joint(n).id] for n in kinematics.JOINTS])
        self.dadr = np.array([m.jnt_dofadr[m.joint(n).id] for n in kinematics.JOINTS])
        self.ctrl_ids = np.array([m.actuator(n).id for n in kinematics.JOINTS])
        self.tip_site, self.bucket_body, self.payload_body = m.site("tip").id, m.body("bucket").id, m.body("payload").id
        swing = self.dadr[0]
        self._swing_diag = m.M_rowadr[swing] + m.M_rownnz[swing] - 1
        state = int(m.plugin_stateadr[0])
        self._load_slots = state + PLUGIN_STATE["load"] + np.arange(4)  # the plugin's last constraint load
        self._acceleration_slot = state + PLUGIN_STATE["acceleration"]  # its last swing acceleration
        self.contact_adr = int(m.sensor(TOOL_CONTACT_SENSOR).adr[0])
        self.seconds = 0.0  # wall time spent in the batch's steps (the rest is the task logic)
        self.steps = 0  # MuJoCo steps (of one site) they made

    def step(self, ids: np.ndarray, periods: int) -> None:
        """Advance the sites ``ids`` by ``periods`` control periods (the model's steps); positions and velocities
        then belong to the new state, as after ``mj_step1`` (timed: :attr:`seconds`).

        In the batch's threads when there is enough work to share (``THREADED_SITE_STEPS``), else site by site
        in this thread: handing a few steps to the pool costs more than they do (~0.1 ms against ~7 us a step).
        """
        start = time.perf_counter()
        if len(ids) * periods >= THREADED_SITE_STEPS:
            self.batch.step(ids, nstep=periods, stage=_VEL)
        else:
            for k in range(len(ids)):
                self.batch.step(ids[k : k + 1], nstep=periods, stage=_VEL)
        self.seconds += time.perf_counter() - start
        self.steps += len(ids) * periods

    def apply_tip_force(self, ids: np.ndarray, force: np.ndarray) -> None:
        """ExcavatorPhysics.apply_tip_force of the sites ``ids``: ``qfrc_applied = J^T force`` at the teeth.

        The sum is mj_applyFT's (``mju_mulMatTVec``: rows with a zero force skipped, added in order into
        zeros), so the joint forces are the same floats.
        """
        if not np.isfinite(force).all():
            raise ValueError(f"tip force must be finite, got {force[~np.isfinite(force).all(axis=1)]}")
        if not force.any():
            self._qfrc_applied[ids] = 0.0
            return
        tip = self.site_xpos[ids, self.tip_site]
        jacp, _ = self.batch.jac(self.bucket_body, tip, ids)
        qforce = np.zeros((len(ids), self.model.nv))
        for r in range(3):
            component = force[:, r : r + 1]
            qforce = np.where(component != 0.0, qforce + jacp[:, r, :] * component, qforce)
        self._qfrc_applied[ids] = 0.0 + qforce

    def set_payload(self, ids: np.ndarray, mass_kg: np.ndarray) -> None:
        """ExcavatorPhysics.set_payload of the sites ``ids``: mass and inertia, ``mj_setConst``, ``mj_forward``."""
        self.body_mass[ids, self.payload_body] = mass_kg
        self.body_inertia[ids, self.payload_body] = payload_inertia(mass_kg)
        self.batch.set_const(ids)
        self.batch.forward(ids, stage=_ACC)

    def joint_loads(self, ids: np.ndarray) -> np.ndarray:
        """NativeLearnedModel.joint_loads of the sites ``ids`` (N m), (k, 4)."""
        tau = self._qfrc_bias[ids] - self._qfrc_passive[ids] - self._qfrc_applied[ids]
        return tau[:, self.dadr] - self._plugin_state[ids][:, self._load_slots]

    def swing_torques(self, ids: np.ndarray) -> np.ndarray:
        """The swing's inertia times the plugin's last swing acceleration of the sites ``ids``, N m."""
        return self._mass_matrix[ids, self._swing_diag] * self._plugin_state[ids, self._acceleration_slot]


class HexLoadingVectorEnv(VectorEnv):
    """``num_envs`` independent ``HexLoading-v0`` sites stepped as one batch (see the module docstring).

    Spaces, rewards, observations and ``info`` keys are the single environment's
    (:class:`hexgym.envs.loading.HexLoadingEnv`), batched: actions ``(num_envs, 4)``, observations
    ``(num_envs, 23)``, rewards, terminations and truncations ``(num_envs,)``, ``info`` a dict of
    arrays with a ``_key`` mask each (Gymnasium's vector convention). Episodes reset automatically
    on the step after they end (``AutoresetMode.NEXT_STEP``, as ``SyncVectorEnv``): that step
    returns the new episode's first observation with reward 0. ``reset(seed=s)`` seeds site ``i``
    with ``s + i``, so site ``i`` follows ``HexLoadingEnv`` reset with that seed.

    Needs the native plugin (the batch steps its model in C threads); without it use
    ``gymnasium.make_vec(..., vectorization_mode="sync")``. No rendering: render a single
    environment.

    Args:
        num_envs: number of sites.
        nthread: the batch's threads (default: the CPUs this process may use, at most ``num_envs``).
        scene_path: as ``HexLoadingEnv``'s (the batch's model is built on it too).
        backend: ``"native"`` or ``"auto"`` (the same here); ``"python"`` raises.
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
        backend: str = "native",
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
        if backend not in ("auto", "native"):
            raise ValueError(
                f"the batched HexLoading-v0 runs the native plugin only, got backend={backend!r}; use "
                "gymnasium.make_vec('HexLoading-v0', ..., vectorization_mode='sync') for the Python one"
            )
        from hexgym.model.plugin import NativePluginError, load_plugin

        reason = load_plugin()
        if reason:
            raise NativePluginError(
                f"the batched HexLoading-v0 needs the native plugin: {reason}; use "
                "gymnasium.make_vec('HexLoading-v0', num_envs, vectorization_mode='sync')"
            )
        # the single environment checks the arguments, resets the sites and holds the spaces
        self._scratch = HexLoadingEnv(scene_path=scene_path, backend="native", **env_kwargs)
        scratch = self._scratch
        self.num_envs = int(num_envs)
        self.render_mode = None
        self.time_limit, self.truck_capacity_kg = scratch.time_limit, scratch.truck_capacity_kg
        self.weights, self.earthwork_periods = scratch.weights, scratch.earthwork_periods
        self.single_action_space, self.single_observation_space = scratch.action_space, scratch.observation_space
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        model = native_world_model(scene_path, scratch.tables, tool_contact_slots=CONTACT_SLOTS)
        if mujoco.mj_stateSize(model, _STATE) != mujoco.mj_stateSize(scratch.physics.model, _STATE):
            raise RuntimeError("the batch's model and the single environment's differ in their state")
        if nthread is None:
            nthread = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        self.nthread = max(1, min(int(nthread), self.num_envs))
        self.model = model
        self.sites = BatchSites(model, self.num_envs, self.nthread)
        self.task = LoadingTask(
            self.num_envs, self.sites, scratch.task.period, self.time_limit, self.truck_capacity_kg, self.weights,
            self.earthwork_periods,
        )  # fmt: skip
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._autoreset = np.zeros(self.num_envs, bool)
        self._obs = np.zeros((self.num_envs, *self.single_observation_space.shape), np.float32)
        self._started = False

    @property
    def layouts(self) -> list[Layout | None]:
        """Each site's pile and truck placement."""
        return self.task.layouts

    @property
    def physics_seconds(self) -> float:
        """Wall seconds spent in the batch's physics steps (the rest of a step is the task logic)."""
        return self.sites.seconds

    @property
    def physics_steps(self) -> int:
        """MuJoCo steps (of one site) the batch made."""
        return self.sites.steps

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
        restarting = np.flatnonzero(self._autoreset)
        stepping = np.flatnonzero(~self._autoreset)
        for i in restarting:
            self._start_site(int(i), None)
        if len(restarting):
            self._finish_starts(restarting)
        rewards = np.zeros(n)
        terminated, truncated = np.zeros(n, bool), np.zeros(n, bool)
        terms = np.zeros((n, len(REWARD_TERMS)))
        stepped = np.zeros(n, bool)
        if len(stepping):
            spools = np.minimum(np.maximum(a[stepping], -1.0), 1.0) * p.SPOOL_STROKE
            self.sites.ctrl[stepping[:, None], self.sites.ctrl_ids] = spools * CTRL_PER_SPOOL_M
            terms[stepping], rewards[stepping], ended = self.task.step(stepping)
            terminated[stepping], truncated[stepping] = ended[:, 0], ended[:, 1]
            stepped[stepping] = True
        self._obs[:] = self.task.observe(np.arange(n))
        infos = self._infos(np.ones(n, bool), terms, (stepped, self.task.step_fuel_l, self.task.step_impulse))
        self._autoreset = terminated | truncated
        return self._obs.copy(), rewards, terminated, truncated, infos

    def step_physics_only(self, spools_mm: np.ndarray) -> float:
        """Step every site's physics one environment step with ``spools_mm`` ((num_envs, 4), the plugin's ctrl)
        and no task logic; returns the wall seconds of the batch's step. The physics' share of a step: what
        benchmarks compare the full step with (the site states are left inconsistent with the task: reset after)."""
        self.sites.ctrl[:, self.sites.ctrl_ids] = spools_mm
        start = time.perf_counter()
        self.sites.batch.step(np.arange(self.num_envs), nstep=self.task.periods, stage=_VEL)
        return time.perf_counter() - start

    def close_extras(self, **kwargs: Any) -> None:
        """Stop the batch's threads."""
        if hasattr(self, "sites"):  # (a failed construction closes too)
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
        bad = ~np.isfinite(a)
        if bad.any():
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
        layout, q = sample_start(self._rngs[i])
        scratch, sites = self._scratch, self.sites
        scratch.start_machine(q, layout)
        mujoco.mj_getState(scratch.physics.model, scratch.physics.data, sites.state[i], _STATE)
        sites.body_mass[i, sites.payload_body] = scratch.physics.model.body_mass[sites.payload_body]
        sites.body_inertia[i, sites.payload_body] = scratch.physics.model.body_inertia[sites.payload_body]
        self.task.start(i, layout, heap_for(layout), scratch.physics.payload_kg)
        self._autoreset[i] = False

    def _finish_starts(self, ids: np.ndarray) -> None:
        """Derived quantities of freshly loaded sites (the start's masses, ``mj_forward``) and their teeth."""
        self.sites.batch.set_const(ids)
        self.sites.batch.forward(ids, stage=_ACC)
        self.task.finish_starts(ids)

    # -- info ---------------------------------------------------------------------------------------
    def _infos(
        self, reported: np.ndarray, terms: np.ndarray, step_extras: tuple[np.ndarray, ...] | None
    ) -> dict[str, Any]:
        """The info dicts of the sites where ``reported`` as SyncVectorEnv gathers them: an array (0 elsewhere) and
        a ``_key`` mask per key; ``terms`` (num_envs, 6); ``step_extras``: (mask of the sites that stepped, their
        fuel, their impulse)."""
        info: dict[str, Any] = {}
        stores = self.task.stores_of(np.arange(self.num_envs))
        columns = {f"reward_{term}": terms[:, k] for k, term in enumerate(REWARD_TERMS)}
        columns |= {key: stores[:, k] for k, key in enumerate(INFO_STORES)}
        for key, values in columns.items():
            info[key], info[f"_{key}"] = np.where(reported, values, 0.0), reported.copy()
        if step_extras is not None and step_extras[0].any():
            stepped = step_extras[0]
            for key, values in zip(("fuel_l_step", "contact_impulse_ns"), step_extras[1:], strict=True):
                info[key], info[f"_{key}"] = np.where(stepped, values, 0.0), stepped.copy()
        return info


def make_vector_env(num_envs: int, **kwargs: Any) -> HexLoadingVectorEnv:
    """``HexLoading-v0``'s ``vector_entry_point`` (``gymnasium.make_vec`` passes ``num_envs`` and the env kwargs)."""
    kwargs.pop("max_episode_steps", None)  # the environment truncates itself (time_limit)
    return HexLoadingVectorEnv(num_envs, **kwargs)

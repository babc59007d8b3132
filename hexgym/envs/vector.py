"""``HexLoading-v0`` batched: N loading sites stepped together (``gymnasium.make_vec("HexLoading-v0", num_envs=N)``).

:class:`HexLoadingVectorEnv` runs the N machines as one :class:`mujoco.batch.Batch` of the native
plugin's model (a persistent pool of C threads, one ``MjData`` per site, each site's state its
``mjSTATE_INTEGRATION`` row, per-site payload masses) and the task logic (pile, digging, spill,
payload, fuel, contacts, rewards, observations) as numpy over the sites, with the single
environment's arithmetic element for element, so that its results equal N :class:`HexLoadingEnv`
stepped one by one (``tests/test_vector_env.py``). Each site keeps the single environment's adaptive
schedule: a step's 25 ms control periods are advanced in rounds; in each, the sites whose teeth
surely stay clear of the pile advance all the periods they can in one batch call (grouped by how
many), the others dig once and advance ``earthwork_periods`` periods, period by period while their
edge cuts (the digging force is re-aimed each period).

What needs the ``MjData`` of a site comes from the batch without a Python loop over sites: the
state rows (joints, plugin state with the last constraint load and swing acceleration), bound
outputs (teeth site, bucket frame, bias and passive forces, mass matrix), ``Batch.jac`` for the
digging force's joint forces and a contact sensor (``build_world_model(tool_contact_slots=...)``) for
the bucket's and stick's contacts. Resets (once per episode) run the single environment's own reset
on a scratch :class:`HexLoadingEnv` and copy its state into the site's row.
"""

from __future__ import annotations

import functools
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
from mujoco import batch as mjbatch

from hexgym.envs.earthwork import (
    EDGE_OFFSETS,
    EDGE_SAMPLES,
    BatchedPiles,
    earthmoving_force,
    n_gamma_at,
    retained_volumes,
    spilled_fraction,
    surcharge_pressure,
)
from hexgym.envs.loading import (
    _CLIP_HIGH,
    _CLIP_LOW,
    _MOUTH_CENTRE,
    _MOUTH_NORMAL_X,
    _MOUTH_NORMAL_Z,
    _PILE_MARGIN,
    _TEETH_X,
    _TEETH_Z,
    FORCE_PERIODS,
    PAYLOAD_UPDATE_KG,
    REWARD_TERMS,
    STEP_PERIOD,
    HexLoadingEnv,
    heap_for,
    native_world_model,
    sample_start,
    wrap_angle,
)
from hexgym.envs.world import (
    BED_RIM_HEIGHT,
    PILE_GRID_POINTS,
    PILE_GRID_SPACING,
    TOOL_CONTACT_SENSOR,
    Layout,
    bed_frame,
    fullest_cut_direction,
    over_bed,
)
from hexgym.hydraulics import fuel
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.physics import payload_inertia
from hexgym.model.plugin import CTRL_PER_SPOOL_M
from hexgym.model.plugin import STATE as PLUGIN_STATE

CONTACT_SLOTS = 16  # contacts of the bucket and stick the sensor reports (random actions reach 7 of all kinds)
_VEL = int(mujoco.mjtStage.mjSTAGE_VEL)  # after a step: positions and velocities current, as mj_step1 leaves them
_ACC = int(mujoco.mjtStage.mjSTAGE_ACC)
_STATE = mujoco.mjtState.mjSTATE_INTEGRATION


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
        if FORCE_PERIODS != 1:
            raise NotImplementedError("the batched environment re-aims the digging force every period (FORCE_PERIODS)")
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
        self._period, self._periods = scratch._period, scratch._periods
        self._velocity_blend = scratch._velocity_blend
        self._build_batch(scene_path, nthread)
        self._build_site_state()

    # -- construction -------------------------------------------------------------------------
    def _build_batch(self, scene_path: str | Path | None, nthread: int | None) -> None:
        model = native_world_model(scene_path, self._scratch.tables, tool_contact_slots=CONTACT_SLOTS)
        scratch_model = self._scratch.physics.model
        if mujoco.mj_stateSize(model, _STATE) != mujoco.mj_stateSize(scratch_model, _STATE):
            raise RuntimeError("the batch's model and the single environment's differ in their state")
        if nthread is None:
            nthread = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        self.nthread = max(1, min(int(nthread), self.num_envs))
        self.model = model
        self._batch = mjbatch.Batch(model, self.num_envs, nthread=self.nthread, persistent=True)
        b = self._batch
        self._state = b.state
        self._qpos, self._qvel = b.bind("qpos"), b.bind("qvel")
        self._ctrl, self._qfrc_applied = b.bind("ctrl"), b.bind("qfrc_applied")
        self._plugin_state = b.bind("plugin_state")
        self._site_xpos, self._xpos, self._xmat = b.bind("site_xpos"), b.bind("xpos"), b.bind("xmat")
        self._qfrc_bias, self._qfrc_passive = b.bind("qfrc_bias"), b.bind("qfrc_passive")
        self._mass_matrix = b.bind("M")
        self._sensordata = b.bind("sensordata")
        self._body_mass, self._body_inertia = b.expand("body_mass"), b.expand("body_inertia")
        m = model
        self._qadr = np.array([m.jnt_qposadr[m.joint(n).id] for n in kinematics.JOINTS])
        self._dadr = np.array([m.jnt_dofadr[m.joint(n).id] for n in kinematics.JOINTS])
        self._ctrl_ids = np.array([m.actuator(n).id for n in kinematics.JOINTS])
        self._tip_site, self._bucket, self._payload = m.site("tip").id, m.body("bucket").id, m.body("payload").id
        swing = self._dadr[0]
        self._swing_diag = m.M_rowadr[swing] + m.M_rownnz[swing] - 1
        state = int(m.plugin_stateadr[0])
        self._load_slots = state + PLUGIN_STATE["load"] + np.arange(4)  # the plugin's last constraint load
        self._acceleration_slot = state + PLUGIN_STATE["acceleration"]  # its last swing acceleration
        sensor = m.sensor(TOOL_CONTACT_SENSOR)
        self._contact_slots = slice(int(sensor.adr[0]), int(sensor.adr[0]) + 2 * CONTACT_SLOTS)

    def _build_site_state(self) -> None:
        n = self.num_envs
        self._piles = BatchedPiles(n, PILE_GRID_POINTS, PILE_GRID_SPACING)
        self._rngs: list[np.random.Generator | None] = [None] * n
        self.layouts: list[Layout | None] = [None] * n  # each site's pile and truck placement
        self._pile_centre, self._truck_centre = np.zeros((n, 2)), np.zeros((n, 2))
        self._pile_dir, self._truck_dir = np.zeros(n), np.zeros(n)
        self._pile_cos, self._pile_sin = np.zeros(n), np.zeros(n)
        self._cut_dir = np.zeros(n)  # each pile's fullest cut line's direction (rad), kept while the pile stands
        self._truck_cos, self._truck_sin = np.zeros(n), np.zeros(n)
        self.bucket_kg, self.truck_kg, self.spilled_kg = np.zeros(n), np.zeros(n), np.zeros(n)
        self._payload_kg = np.zeros(n)
        self._tip_before, self._tip_velocity = np.zeros((n, 3)), np.zeros((n, 3))
        self._tip_interval = np.full(n, math.inf)
        self._tip_force_on = np.zeros(n, bool)
        self._dig_depth = np.zeros(n)
        self._joint_loads = np.zeros((n, 4))
        self.fuel_l, self.elapsed = np.zeros(n), np.zeros(n)
        self.steps = np.zeros(n, np.int64)
        self._autoreset = np.zeros(n, bool)
        self.physics_seconds = 0.0  # wall time spent in the batch's steps (the rest is the task logic in numpy)
        self.physics_steps = 0  # MuJoCo steps (of one site) they made
        self._obs = np.zeros((n, *self.single_observation_space.shape), np.float32)
        self._started = False
        # the low-pass blend of the teeth's velocity for a sample interval of k periods, k = 0..periods (0: none yet)
        intervals = np.arange(self._periods + 1) * self._period
        blends = [1.0] + [1.0 - math.exp(-t / p.DIG_VELOCITY_FILTER) for t in intervals[1:]]
        blends[1] = self._velocity_blend  # HexLoadingEnv._sample_tip's one-period constant
        self._blends = np.array(blends)

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
        self._obs[sites] = self._observations(sites)
        return self._obs.copy(), self._infos(mask, np.zeros((6, self.num_envs)), None)

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
        terms = np.zeros((6, n))
        fuel_step, contact_step = np.zeros(n), np.zeros(n)
        if len(stepping):
            spools = np.minimum(np.maximum(a[stepping], -1.0), 1.0) * p.SPOOL_STROKE
            self._ctrl[stepping[:, None], self._ctrl_ids] = spools * CTRL_PER_SPOOL_M
            flows = np.zeros((3, n))  # dug, delivered, spilled (kg)
            self._advance(stepping, flows, fuel_step, contact_step)
            self.fuel_l[stepping] += fuel_step[stepping]
            self.steps[stepping] += 1
            self.elapsed[stepping] = self.steps[stepping] * STEP_PERIOD
            w = self.weights
            terms[:, stepping] = [
                w["delivery"] * flows[1, stepping] / 1000.0,
                w["fill"] * flows[0, stepping] / 1000.0,
                np.full(len(stepping), -w["time"] * STEP_PERIOD),
                -w["fuel"] * fuel_step[stepping],
                -w["spill"] * flows[2, stepping] / 1000.0,
                -w["contact"] * contact_step[stepping] / 1000.0,
            ]
            total = terms[0, stepping]
            for k in range(1, len(REWARD_TERMS)):  # in HexLoadingEnv.step's order: the same float sum
                total = total + terms[k, stepping]
            rewards[stepping] = total
            terminated[stepping] = self.truck_kg[stepping] >= self.truck_capacity_kg
            truncated[stepping] = self.elapsed[stepping] >= self.time_limit - 1e-9
        self._obs[:] = self._observations(np.arange(n))
        stepped = np.zeros(n, bool)
        stepped[stepping] = True
        infos = self._infos(np.ones(n, bool), terms, (stepped, fuel_step, contact_step))
        self._autoreset = terminated | truncated
        return self._obs.copy(), rewards, terminated, truncated, infos

    def step_physics_only(self, spools_mm: np.ndarray) -> float:
        """Step every site's physics one environment step with ``spools_mm`` ((num_envs, 4), the plugin's ctrl)
        and no task logic; returns the wall seconds of the batch's step. The physics' share of a step: what
        benchmarks compare the full step with (the site states are left inconsistent with the task: reset after)."""
        self._ctrl[:, self._ctrl_ids] = spools_mm
        start = time.perf_counter()
        self._batch.step(np.arange(self.num_envs), nstep=self._periods, stage=_VEL)
        return time.perf_counter() - start

    def close_extras(self, **kwargs: Any) -> None:
        """Stop the batch's threads."""
        self._batch = None
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
            i = int(np.flatnonzero(bad.any(axis=1))[0])
            raise ValueError(
                f"actions must be finite: environment {i} got {a[i]} (NaN or inf; "
                f"environments {np.flatnonzero(bad.any(axis=1)).tolist()} have one)"
            )
        return a

    # -- resets ---------------------------------------------------------------------------------
    def _start_site(self, i: int, seed: int | None) -> None:
        """Draw site ``i``'s episode as HexLoadingEnv.reset does (on the scratch environment) and load it."""
        if seed is not None or self._rngs[i] is None:
            self._rngs[i], _ = gym.utils.seeding.np_random(seed)
        layout, q = sample_start(self._rngs[i])
        pile = heap_for(layout)
        scratch = self._scratch
        scratch.start_machine(q, layout)
        mujoco.mj_getState(scratch.physics.model, scratch.physics.data, self._state[i], _STATE)
        self.layouts[i] = layout
        self._piles.load(i, pile)
        self._pile_centre[i], self._truck_centre[i] = layout.pile_centre, layout.truck_centre
        self._pile_dir[i], self._truck_dir[i] = layout.pile_direction, layout.truck_direction
        self._pile_cos[i], self._pile_sin[i] = math.cos(layout.pile_direction), math.sin(layout.pile_direction)
        self._truck_cos[i], self._truck_sin[i] = math.cos(layout.truck_yaw), math.sin(layout.truck_yaw)
        self.bucket_kg[i] = self.truck_kg[i] = self.spilled_kg[i] = 0.0
        self._body_mass[i, self._payload] = scratch.physics.model.body_mass[self._payload]
        self._body_inertia[i, self._payload] = scratch.physics.model.body_inertia[self._payload]
        self._payload_kg[i] = scratch.physics.payload_kg
        self._tip_interval[i] = math.inf
        self._tip_velocity[i] = 0.0
        self._tip_force_on[i] = False
        self._dig_depth[i] = 0.0
        self.fuel_l[i] = self.elapsed[i] = 0.0
        self.steps[i] = 0
        self._autoreset[i] = False

    def _finish_starts(self, ids: np.ndarray) -> None:
        """Derived quantities of freshly loaded sites (the start's masses, ``mj_forward``) and their teeth."""
        self._batch.set_const(ids)
        self._batch.forward(ids, stage=_ACC)
        self._tip_before[ids] = self._site_xpos[ids, self._tip_site]
        self._joint_loads[ids] = self._current_joint_loads(ids)

    # -- one step: the schedule -----------------------------------------------------------------
    def _advance(self, ids: np.ndarray, flows: np.ndarray, fuel_l: np.ndarray, impulse: np.ndarray) -> None:
        """HexLoadingEnv._advance for the sites ``ids``: rounds of clear or digging intervals until each site
        has advanced its step's periods (fuel, contact impulse and flows accumulate per site)."""
        left = np.zeros(self.num_envs, np.int64)
        left[ids] = self._periods
        while True:
            active = np.flatnonzero(left)
            if not len(active):
                return
            clear = np.zeros(len(active), np.int64)
            free = ~self._tip_force_on[active]  # force on: in the pile
            if free.any():
                clear[free] = np.minimum(self._clear_periods(active[free]), left[active[free]])
            in_clear = clear > 0
            clear_ids, clear_periods = active[in_clear], clear[in_clear]
            pile_ids = active[~in_clear]
            pile_periods = np.minimum(self.earthwork_periods, left[pile_ids])
            if len(clear_ids):
                self._advance_clear(clear_ids, clear_periods, flows, fuel_l, impulse)
            if len(pile_ids):
                self._advance_in_pile(pile_ids, pile_periods, flows, fuel_l, impulse)
            left[clear_ids] -= clear_periods
            left[pile_ids] -= pile_periods

    def _clear_periods(self, ids: np.ndarray) -> np.ndarray:
        """HexLoadingEnv._clear_periods of the sites ``ids``: periods (up to a step's) surely clear of the pile."""
        per_period = _PILE_MARGIN / self._periods
        travels = [(m + 1) * per_period for m in range(self._periods)]
        clear = np.full(len(ids), self._periods, np.int64)
        tip = self._site_xpos[ids, self._tip_site]
        # Pile.clearance's cheap bound first: teeth above the whole pile by the longest travel are clear
        near = np.flatnonzero(tip[:, 2] - self._piles.top[ids] < travels[-1])
        if not len(near):
            return clear
        ids, x, y, z = ids[near], tip[near, 0], tip[near, 1], tip[near, 2]
        radii = p.BUCKET_WIDTH / 2.0 + np.array(travels)
        r0, r1, c0, c1 = self._piles.windows(ids[:, None], x[:, None], y[:, None], radii)  # (k, periods) each
        blocked = self._piles.first_blocked_window(ids, z, (r0, r1, c0, c1), np.array(travels))
        above_top = z - self._piles.top[ids]
        count = np.zeros(len(ids), np.int64)
        going = np.ones(len(ids), bool)
        for m, travel in enumerate(travels):
            # Pile.clearance: above the whole pile by `travel`, no grid point near, or above the nearby ones by it
            empty = (r1[:, m] <= r0[:, m]) | (c1[:, m] <= c0[:, m])
            going &= (above_top >= travel) | empty | (m < blocked)
            count += going
        clear[near] = count
        return clear

    def _advance_clear(
        self, ids: np.ndarray, periods: np.ndarray, flows: np.ndarray, fuel_l: np.ndarray, impulse: np.ndarray
    ) -> None:
        """HexLoadingEnv._advance_clear: each site's ``periods`` in one batch call (grouped by count)."""
        on = ids[self._tip_force_on[ids]]
        if len(on):
            self._qfrc_applied[on] = 0.0  # apply_tip_force(0): the joint forces of no force
            self._tip_force_on[on] = False
        seconds = periods * self._period
        tip_start = self._site_xpos[ids, self._tip_site].copy()
        self._step_grouped(ids, periods)
        tip, _, _, tilt = self._bucket_pose(ids)
        self._tip_velocity[ids] = (tip - tip_start) / seconds[:, None]
        self._tip_before[ids], self._tip_interval[ids] = tip_start, seconds
        self._spill(ids, tilt, seconds, flows)
        self._update_payload(ids)
        self._account(ids, seconds, fuel_l, impulse)

    def _advance_in_pile(
        self, ids: np.ndarray, periods: np.ndarray, flows: np.ndarray, fuel_l: np.ndarray, impulse: np.ndarray
    ) -> None:
        """HexLoadingEnv._advance_in_pile: one dig, then the periods; cutting sites period by period, re-aiming
        their digging force between periods (FORCE_PERIODS = 1)."""
        seconds = periods * self._period
        self._earthwork(ids, seconds, flows)
        cutting = self._tip_force_on[ids]
        still = ~cutting
        if still.any():
            self._step_grouped(ids[still], periods[still])
            self._tip_interval[ids[still]] = seconds[still]
        cut_ids, cut_periods = ids[cutting], periods[cutting]
        for start in range(int(cut_periods.max(initial=0))):
            now = cut_ids[cut_periods > start]
            if start:
                self._follow_resistance(now)
            self._physics_step(now, 1)
            self._tip_interval[now] = self._period  # 1 * period, as the single environment's `done * period`
        self._account(ids, seconds, fuel_l, impulse)

    def _step_grouped(self, ids: np.ndarray, periods: np.ndarray) -> None:
        """Advance each site ``ids[k]`` by ``periods[k]`` control periods: one batch call per distinct count."""
        for count in np.unique(periods):
            self._physics_step(ids[periods == count], int(count))

    def _physics_step(self, ids: np.ndarray, periods: int) -> None:
        """Advance the sites ``ids`` by ``periods`` control periods (the model's steps) in the batch's threads;
        positions and velocities then belong to the new state, as after ``mj_step1`` (timed: ``physics_seconds``)."""
        start = time.perf_counter()
        self._batch.step(ids, nstep=periods, stage=_VEL)
        self.physics_seconds += time.perf_counter() - start
        self.physics_steps += len(ids) * periods

    def _account(self, ids: np.ndarray, seconds: np.ndarray, fuel_l: np.ndarray, impulse: np.ndarray) -> None:
        """Fuel and hard-contact impulse of an interval of ``seconds`` ending now; keep the joint loads."""
        loads = self._current_joint_loads(ids)
        self._joint_loads[ids] = loads
        rates = self._qvel[ids][:, self._dadr]
        swing_torque = self._mass_matrix[ids, self._swing_diag] * self._plugin_state[ids, self._acceleration_slot]
        power = fuel.actuator_powers(loads[:, 1:], rates[:, 1:], swing_torque, rates[:, 0])
        fuel_l[ids] += fuel.fuel_litres_many(power, seconds)
        impulse[ids] += self._hard_contact_force(ids) * seconds

    def _current_joint_loads(self, ids: np.ndarray) -> np.ndarray:
        """NativeLearnedModel.joint_loads of the sites ``ids`` (N m), (k, 4)."""
        tau = self._qfrc_bias[ids] - self._qfrc_passive[ids] - self._qfrc_applied[ids]
        return tau[:, self._dadr] - self._plugin_state[ids][:, self._load_slots]

    def _hard_contact_force(self, ids: np.ndarray) -> np.ndarray:
        """HexLoadingEnv._hard_contact_force of the sites ``ids`` from the contact sensor, N."""
        slots = self._sensordata[ids, self._contact_slots].reshape(len(ids), CONTACT_SLOTS, 2)
        found, dist = slots[:, 0, 0].astype(np.int64), slots[:, :, 1]
        if (found > CONTACT_SLOTS).any():
            raise RuntimeError(f"more than {CONTACT_SLOTS} bucket/stick contacts at sites {ids[found > CONTACT_SLOTS]}")
        shallow = np.minimum(dist, 0.0)
        total = np.full(len(ids), -0.0)  # numpy's sum of fewer than 8 values: in order from -0.0
        for k in range(min(int(found.max(initial=0)), CONTACT_SLOTS)):
            total = np.where(k < found, total + shallow[:, k], total)
        for row in np.flatnonzero(found >= 8):  # numpy sums 8 or more pairwise: sum those as it does
            total[row] = shallow[row, : found[row]].sum()
        depth = -total
        force = p.CONTACT_STIFFNESS * depth
        cap = p.HARD_CONTACT_FORCE_CAP - p.HARD_CONTACT_FORCE
        excess = np.minimum(np.maximum(force - p.HARD_CONTACT_FORCE, 0.0), cap)
        return np.where(found > 0, excess, 0.0)

    # -- the bucket, the earthwork and the payload -----------------------------------------------
    def _bucket_pose(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """HexLoadingEnv._bucket_pose of the sites ``ids``: teeth (k, 3), lateral (k, 3), teeth direction (k, 3),
        mouth tilt (k,)."""
        r = self._xmat[ids, self._bucket]  # (k, 9) row-major, bucket frame -> world
        tilt = np.arccos(np.minimum(np.maximum(r[:, 6] * _MOUTH_NORMAL_X + r[:, 8] * _MOUTH_NORMAL_Z, -1.0), 1.0))
        teeth = np.stack(
            [r[:, 0] * _TEETH_X + r[:, 2] * _TEETH_Z, r[:, 3] * _TEETH_X + r[:, 5] * _TEETH_Z,
             r[:, 6] * _TEETH_X + r[:, 8] * _TEETH_Z], axis=1,
        )  # fmt: skip
        lateral = r[:, [1, 4, 7]]
        return self._site_xpos[ids, self._tip_site].copy(), lateral, teeth, tilt

    def _sample_tip(self, ids: np.ndarray, tip: np.ndarray) -> np.ndarray:
        """HexLoadingEnv._sample_tip: the teeth's mean velocity since the last sample; fold it into the low-pass."""
        interval = self._tip_interval[ids]
        velocity = (tip - self._tip_before[ids]) / interval[:, None]
        periods = np.where(np.isinf(interval), 0, np.rint(interval / self._period)).astype(np.intp)
        blend = self._blends[np.minimum(periods, len(self._blends) - 1)]
        filtered = self._tip_velocity[ids]
        self._tip_velocity[ids] = filtered + (velocity - filtered) * blend[:, None]
        self._tip_before[ids] = tip
        return velocity

    def _earthwork(self, ids: np.ndarray, seconds: np.ndarray, flows: np.ndarray) -> None:
        """HexLoadingEnv._earthwork: dig (or spill), apply the digging force, re-mass the bucket."""
        tip, lateral, teeth, tilt = self._bucket_pose(ids)
        velocity = self._sample_tip(ids, tip)
        force, taken_kg, depth = self._dig(ids, tip, lateral, teeth, velocity, seconds, self._tip_velocity[ids])
        self._dig_depth[ids] = depth
        out = depth <= 0.0
        if out.any():
            self._spill(ids[out], tilt[out], seconds[out], flows)
        push = (depth > 0.0) | self._tip_force_on[ids]
        if push.any():
            self._apply_tip_force(ids[push], force[push], tip[push])
            self._tip_force_on[ids[push]] = depth[push] > 0.0
        flows[0, ids] += taken_kg
        self._update_payload(ids)

    def _dig(
        self, ids: np.ndarray, edge: np.ndarray, lateral: np.ndarray, teeth: np.ndarray, velocity: np.ndarray,
        dt: np.ndarray, force_velocity: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
        """Earthwork.dig of the sites ``ids``: resistance (k, 3), kg taken, cutting depth."""
        k = len(ids)
        force, taken_kg, depth = np.zeros((k, 3)), np.zeros(k), np.zeros(k)
        x, y, z = edge[:, 0], edge[:, 1], edge[:, 2]
        below_top = np.flatnonzero(z < self._piles.top[ids])  # above the whole pile: nothing to do
        if not len(below_top):
            return force, taken_kg, depth
        s = below_top
        floor = np.maximum(z[s], 0.0)
        lx, ly = lateral[s, 0], lateral[s, 1]
        total = 0
        for offset in EDGE_OFFSETS:  # Earthwork.dig's sum: in order, from 0
            surface = self._piles.height_at(ids[s], x[s] + offset * lx, y[s] + offset * ly)
            total = total + np.maximum(surface - floor, 0.0)
        d = total / EDGE_SAMPLES
        cutting = d > 0.0
        s, floor, d = s[cutting], floor[cutting], d[cutting]
        if not len(s):
            return force, taken_kg, depth
        t, v = teeth[s], velocity[s]
        cut_speed = np.maximum(v[:, 0] * t[:, 0] + v[:, 1] * t[:, 1] + v[:, 2] * t[:, 2], 0.0)
        room = np.maximum(p.BUCKET_HEAPED_CAPACITY - self.bucket_kg[ids[s]] / p.MATERIAL_DENSITY, 0.0)
        wanted = np.minimum(p.BUCKET_WIDTH * d * cut_speed * dt[s], room)
        got = self._piles.take(ids[s], x[s], y[s], lateral[s, 0], lateral[s, 1], p.BUCKET_WIDTH, floor, wanted)
        taken_kg[s] = got * p.MATERIAL_DENSITY
        self.bucket_kg[ids[s]] += taken_kg[s]
        depth[s] = d
        force[s] = self._resistance(ids[s], d, lateral[s], teeth[s], force_velocity[s])
        return force, taken_kg, depth

    def _resistance(
        self, ids: np.ndarray, depth: np.ndarray, lateral: np.ndarray, teeth: np.ndarray, velocity: np.ndarray
    ) -> np.ndarray:
        """Earthwork.resistance of the sites ``ids`` (N, world), (k, 3)."""
        vx, vy, vz = velocity[:, 0], velocity[:, 1], velocity[:, 2]
        tx, ty, tz = teeth[:, 0], teeth[:, 1], teeth[:, 2]
        speed = np.sqrt(vx * vx + vy * vy + vz * vz)
        moving = speed > 1e-9
        with np.errstate(divide="ignore", invalid="ignore"):
            ux, uy = np.where(moving, vx / speed, tx), np.where(moving, vy / speed, ty)
            # math.hypot, not np.hypot: the two differ in the last bit
            horizontal = np.fromiter(map(math.hypot, ux.tolist(), uy.tolist()), float, len(ux))
            forward = np.where(horizontal > 1e-9, (tx * ux + ty * uy) / horizontal, 0.0)
        rake = np.arctan2(-tz, forward)
        surcharge = surcharge_pressure(self.bucket_kg[ids] / p.MATERIAL_DENSITY)
        magnitude = np.where(depth > 0.0, earthmoving_force(depth, n_gamma_at(rake), surcharge, p.BUCKET_WIDTH), 0.0)
        scale = -magnitude / np.maximum(speed, p.DIG_REFERENCE_SPEED)
        f = scale[:, None] * velocity
        sideways = f[:, 0] * lateral[:, 0] + f[:, 1] * lateral[:, 1] + f[:, 2] * lateral[:, 2]
        return f - sideways[:, None] * lateral

    def _follow_resistance(self, ids: np.ndarray) -> None:
        """HexLoadingEnv._follow_resistance of cutting sites ``ids``: re-aim the force with the teeth's motion."""
        tip, lateral, teeth, _ = self._bucket_pose(ids)
        self._sample_tip(ids, tip)
        on = self._tip_force_on[ids]
        if on.any():
            s = ids[on]
            force = self._resistance(s, self._dig_depth[s], lateral[on], teeth[on], self._tip_velocity[s])
            self._apply_tip_force(s, force, tip[on])

    def _apply_tip_force(self, ids: np.ndarray, force: np.ndarray, tip: np.ndarray) -> None:
        """ExcavatorPhysics.apply_tip_force of the sites ``ids``: ``qfrc_applied = J^T force`` at the teeth.

        The sum is mj_applyFT's (``mju_mulMatTVec``: rows with a zero force skipped, added in order into
        zeros), so the joint forces are the same floats.
        """
        if not np.isfinite(force).all():
            raise ValueError(f"tip force must be finite, got {force[~np.isfinite(force).all(axis=1)]}")
        jacp, _ = self._batch.jac(self._bucket, tip, ids)
        qforce = np.zeros((len(ids), self.model.nv))
        for r in range(3):
            component = force[:, r : r + 1]
            qforce = np.where(component != 0.0, qforce + jacp[:, r, :] * component, qforce)
        self._qfrc_applied[ids] = 0.0 + qforce

    def _spill(self, ids: np.ndarray, tilt: np.ndarray, seconds: np.ndarray, flows: np.ndarray) -> None:
        """HexLoadingEnv._spill + Earthwork.spill of the sites ``ids`` (into the bed if the mouth is over it)."""
        holding = self.bucket_kg[ids] > 0.0
        if not holding.any():
            return
        ids, tilt, seconds = ids[holding], tilt[holding], seconds[holding]
        excess = self.bucket_kg[ids] - retained_volumes(tilt) * p.MATERIAL_DENSITY
        spilling = excess > 0.0
        if not spilling.any():
            return
        ids, excess, seconds = ids[spilling], excess[spilling], seconds[spilling]
        frames = self._xmat[ids, self._bucket].reshape(-1, 3, 3)
        mouth = self._xpos[ids, self._bucket] + np.matmul(frames, _MOUTH_CENTRE)  # HexLoadingEnv.mouth_position
        along, across = bed_frame(mouth[:, 0], mouth[:, 1], self._truck_centre[ids, 0], self._truck_centre[ids, 1],
                                  self._truck_cos[ids], self._truck_sin[ids])  # fmt: skip
        into_truck = over_bed(along, across)
        bucket = self.bucket_kg[ids]
        out = excess * spilled_fraction(seconds)
        out = np.where(bucket - out < 1.0, bucket, out)  # the last kilogram goes too
        out = np.minimum(out, bucket)
        self.bucket_kg[ids] = bucket - out
        truck, ground = ids[into_truck], ids[~into_truck]
        self.truck_kg[truck] += out[into_truck]
        self.spilled_kg[ground] += out[~into_truck]
        flows[1, truck] += out[into_truck]
        flows[2, ground] += out[~into_truck]

    def _update_payload(self, ids: np.ndarray) -> None:
        """HexLoadingEnv._update_payload: re-mass the bucket where its contents changed enough (ExcavatorPhysics.
        set_payload's mass and inertia, ``mj_setConst``, ``mj_forward``)."""
        bucket, payload = self.bucket_kg[ids], self._payload_kg[ids]
        change = (np.abs(bucket - payload) > PAYLOAD_UPDATE_KG) | ((bucket < 1.0) & (1.0 < payload))
        if not change.any():
            return
        ids, mass = ids[change], bucket[change]
        self._payload_kg[ids] = mass
        self._body_mass[ids, self._payload] = mass
        self._body_inertia[ids, self._payload] = payload_inertia(mass)
        self._batch.set_const(ids)
        self._batch.forward(ids, stage=_ACC)

    # -- observation and info ------------------------------------------------------------------
    def _observations(self, ids: np.ndarray) -> np.ndarray:
        """HexLoadingEnv._observation of the sites ``ids`` (float32, clipped), (k, 23)."""
        q, qd = self._qpos[ids][:, self._qadr], self._qvel[ids][:, self._dadr]
        arms = np.stack([table.at(q[:, i + 1]) for i, table in enumerate(kinematics.moment_arm_tables())], axis=1)
        loads = self._joint_loads[ids][:, 1:] / arms / 1e6
        tip, _, _, tilt = self._bucket_pose(ids)
        rel_x, rel_y = tip[:, 0] - self._pile_centre[ids, 0], tip[:, 1] - self._pile_centre[ids, 1]
        c, s = self._pile_cos[ids], self._pile_sin[ids]
        above_pile = tip[:, 2] - self._piles.height_at(ids, tip[:, 0], tip[:, 1])
        along, across = bed_frame(tip[:, 0], tip[:, 1], self._truck_centre[ids, 0], self._truck_centre[ids, 1],
                                  self._truck_cos[ids], self._truck_sin[ids])  # fmt: skip
        columns = [
            q[:, 1], q[:, 2], q[:, 3], wrap_angle(q[:, 0] - self._pile_dir[ids]),
            wrap_angle(q[:, 0] - self._truck_dir[ids]), qd[:, 0], qd[:, 1], qd[:, 2], qd[:, 3],
            loads[:, 0], loads[:, 1], loads[:, 2], self.bucket_kg[ids] / 1000.0, c * rel_x + s * rel_y,
            -s * rel_x + c * rel_y, above_pile, along, across, tip[:, 2] - BED_RIM_HEIGHT, tilt,
            self.truck_kg[ids] / self.truck_capacity_kg, np.maximum(1.0 - self.elapsed[ids] / self.time_limit, 0.0),
            wrap_angle(q[:, 0] - self._fullest_cut_directions(ids)),
        ]  # fmt: skip
        obs = np.stack(columns, axis=1)
        finite = np.isfinite(obs).all(axis=1)
        if not finite.all():
            bad = ids[~finite]
            raise RuntimeError(
                f"the simulation diverged (non-finite observation) at environments {bad.tolist()}, "
                f"t = {self.elapsed[bad].tolist()} s"
            )
        np.minimum(np.maximum(obs, _CLIP_LOW, out=obs), _CLIP_HIGH, out=obs)
        return obs.astype(np.float32)

    def _fullest_cut_directions(self, ids: np.ndarray) -> np.ndarray:
        """HexLoadingEnv.fullest_cut_direction of the sites ``ids``: recomputed, site by site, for the piles that
        changed (few in a step: those being dug)."""
        changed = ids[self._piles.changed[ids]]
        for i in changed.tolist():
            heights = functools.partial(self._heights_at, i)
            self._cut_dir[i] = fullest_cut_direction(heights, self.layouts[i])
        self._piles.changed[changed] = False
        return self._cut_dir[ids]

    def _heights_at(self, site: int, xy: np.ndarray) -> np.ndarray:
        """Pile.height_at of site ``site``'s pile at world points ``xy`` (..., 2)."""
        return self._piles.height_at(site, xy[..., 0], xy[..., 1])

    def _infos(
        self, reported: np.ndarray, terms: np.ndarray, step_extras: tuple[np.ndarray, ...] | None
    ) -> dict[str, Any]:
        """The info dicts of the sites where ``reported`` as SyncVectorEnv gathers them: an array (0 elsewhere) and
        a ``_key`` mask per key; ``step_extras``: (mask of the sites that stepped, their fuel, their impulse)."""
        info: dict[str, Any] = {}
        pile_kg = self._piles.volumes() * p.MATERIAL_DENSITY
        stores = {"pile_kg": pile_kg, "bucket_kg": self.bucket_kg, "truck_kg": self.truck_kg,
                  "spilled_kg": self.spilled_kg, "fuel_l": self.fuel_l, "time_s": self.elapsed}  # fmt: skip
        columns = {f"reward_{term}": terms[k] for k, term in enumerate(REWARD_TERMS)} | stores
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

"""The machines of the loading task's sites (:class:`hexgym.envs.task.SitePhysics`): learned machine models or a
MuJoCo batch, and the machine models a site is built with (:func:`make_machine`).

- :class:`MachineSites`: N learned machine models of any backend (the single environment's one, or the
  Python backend's N for the batched environment without the native plugin): each stepped by its
  model's ``step``; the task's arrays are views of the one ``MjData`` (N = 1) or copies gathered
  after each change.
- :class:`BatchSites`: a :class:`mujoco.batch.Batch` of the native plugin's model: the sites step in
  the batch's C threads, the arrays are the batch's bound state and outputs; a site starts on a machine
  model of its own model (:func:`start_machine`), whose state is loaded into the site's row.

Both do to each site what the machine model does to its ``MjData``, to the last bit, so that the task
gives the same floats on either (``tests/test_vector_env.py``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from copy import copy as copied
from pathlib import Path
from typing import TYPE_CHECKING

import mujoco
import numpy as np
from mujoco import batch as mjbatch

from hexgym.envs.compiled import jit
from hexgym.envs.task import SiteStart
from hexgym.envs.world import TOOL_CONTACT_SENSOR, World, build_world_model
from hexgym.machine import kinematics
from hexgym.machine.assets import asset_path
from hexgym.machine.names import BUCKET_BODY, PAYLOAD_BODY, TIP_SITE
from hexgym.machine.physics import payload_inertia
from hexgym.mbl.schema import DEFAULT_TABLE_SET
from hexgym.model.backend import backend_for, python_learned_model
from hexgym.model.base import LearnedModelBase
from hexgym.model.plugin import CTRL_PER_SPOOL_M
from hexgym.model.plugin import STATE as PLUGIN_STATE

if TYPE_CHECKING:
    from hexgym.hydraulics.overrides import HydraulicsOverrides

VEL_STAGE = int(mujoco.mjtStage.mjSTAGE_VEL)  # after a step: positions and velocities current, as mj_step1 leaves them
ACC_STAGE = int(mujoco.mjtStage.mjSTAGE_ACC)
_ARRAYS = ("site_xpos", "xpos", "xmat", "qpos", "qvel", "sensordata")  # what the task reads
_STATE = mujoco.mjtState.mjSTATE_INTEGRATION  # a batch site's state row
# s: the Python backend's table period on a scene whose step is finer than the lean machine's 25 ms (e.g. the
# full scene.xml at 2 ms); on the lean machine the tables are asked every step
PYTHON_CONTROL_PERIOD = 0.01
PYTHON_SCENE = "scene_lean.xml"  # the learned model's default machine (hexgym.model.python_backend)


def make_machine(
    backend: str = "auto",
    scene_path: str | Path | None = None,
    table_set: str = DEFAULT_TABLE_SET,
    tool_contact_slots: int = 0,
    tables_dir: str | Path | None = None,
    hydraulics: HydraulicsOverrides | None = None,
) -> LearnedModelBase:
    """The machine model that drives the environment, on the loading site.

    ``"python"``: :func:`hexgym.model.backend.python_learned_model` on the lean machine (``scene_lean.xml``:
    no cylinder bodies, 25 ms step); ``"native"``: the ``hexgym.mbl`` MuJoCo plugin on
    ``cat325_mbl.xml`` (:mod:`hexgym.model.native_backend`, needs the built plugin). ``scene_path`` overrides
    the scene (e.g. the full ``scene.xml``). ``"auto"``: :func:`hexgym.model.backend.backend_for`.
    ``table_set``: the learned model's tables, "circuit" or "paper" (:mod:`hexgym.mbl.schema`).
    ``tool_contact_slots``: see :func:`hexgym.envs.world.build_world_model`. ``tables_dir``: other tables of that
    set than the packaged ones (a fitted model's directory). ``hydraulics``: the circuit model's pumps (default: the
    fitted model's or the data sheet's; see :func:`hexgym.model.plugin_mjcf.circuit_config`).
    """
    if backend_for(table_set, backend) == "native":
        from hexgym.model.native_backend import NativeLearnedModel

        world = native_world_model(scene_path, table_set, tool_contact_slots, tables_dir=tables_dir,
                                   hydraulics=hydraulics)  # fmt: skip
        return NativeLearnedModel(model=world)
    model = build_world_model(
        scene_path if scene_path is not None else asset_path(PYTHON_SCENE), tool_contact_slots=tool_contact_slots
    )
    step = model.opt.timestep  # on a finer model than the lean machine's, the tables are asked every 10 ms
    period = step * max(1, round(PYTHON_CONTROL_PERIOD / step))
    return python_learned_model(table_set, tables_dir, model=model, control_period=period, hydraulics=hydraulics)


def native_world_model(
    scene_path: str | Path | None = None,
    table_set: str = DEFAULT_TABLE_SET,
    tool_contact_slots: int = 0,
    customise: Callable[[mujoco.MjSpec], None] | None = None,
    tables_dir: str | Path | None = None,
    hydraulics: HydraulicsOverrides | None = None,
) -> mujoco.MjModel:
    """The loading site around the lean machine driven by the native plugin with ``table_set``'s tables (from
    ``tables_dir``, default the packaged ones; ``customise``: see :func:`hexgym.envs.world.build_world_model`;
    ``hydraulics``: the circuit model's pumps, see :func:`make_machine`)."""
    from hexgym.model.plugin import require_plugin
    from hexgym.model.plugin_mjcf import MBL_MODEL_FILE, mbl_model_xml

    require_plugin()
    if table_set == DEFAULT_TABLE_SET and tables_dir is None and hydraulics is None:  # the packaged machine file
        return build_world_model(
            scene_path, machine_file=MBL_MODEL_FILE, tool_contact_slots=tool_contact_slots, customise=customise
        )
    if tables_dir is not None:
        from hexgym.mbl.table import check_model_table_set

        check_model_table_set(tables_dir, table_set)
    xml = mbl_model_xml(tables_dir, table_set=table_set, hydraulics=hydraulics)
    return build_world_model(scene_path, machine_xml=xml, tool_contact_slots=tool_contact_slots, customise=customise)


def start_machine(machine: LearnedModelBase, world: World, start: SiteStart) -> None:
    """Put ``machine`` at rest at ``start`` (its joint angles and payload) on its site ``world``, laid out as the
    start says, with no force at the teeth."""
    model, data = machine.physics.model, machine.physics.data
    mujoco.mj_resetData(model, data)  # warm starts too: same seed, same episode
    machine.reset(start.q, payload_kg=start.payload_kg)
    world.place(data, start.layout)
    data.qfrc_applied[:] = 0.0
    mujoco.mj_forward(model, data)


def _servo_bands(model: mujoco.MjModel) -> tuple[np.ndarray, ...]:
    """Per integrated-velocity servo: act, qpos and dof addresses, kv/kp, and forcerange/kp.

    Its force ``kp (act - q) - kv qd`` is within ``forcerange`` while ``act`` is within
    ``q + kv/kp qd +- forcerange/kp``.
    """
    servos = [
        i
        for i in range(model.nu)
        if model.actuator_plugin[i] < 0
        and model.actuator_dyntype[i] == mujoco.mjtDyn.mjDYN_INTEGRATOR
        and model.actuator_biastype[i] == mujoco.mjtBias.mjBIAS_AFFINE
    ]  # integrated-velocity servos (a plugin actuator keeps its own state)
    joints = model.actuator_trnid[servos, 0]
    kp = model.actuator_gainprm[servos, 0]
    kv = -model.actuator_biasprm[servos, 2]
    return (
        model.actuator_actadr[servos],
        model.jnt_qposadr[joints],
        model.jnt_dofadr[joints],
        kv / kp,
        model.actuator_forcerange[servos, 1] / kp,
    )


def _read_only(array: np.ndarray) -> np.ndarray:
    """``array`` marked read-only (the task only reads the sites' arrays: one compiled version for both kinds)."""
    array.flags.writeable = False
    return array


class MachineSites:
    """N learned machine models (any backend, the same site model) as the task's sites.

    Each machine holds its spools (:meth:`hold`) through its model's ``step``. A machine with
    integrated-velocity servos (the Python backend) has their targets limited after each step
    (:meth:`limit_servo_windup`). The task's arrays are views of the machine's ``MjData`` for one
    machine, else copies refreshed after each step, re-massing and start.
    """

    def __init__(self, machines: list[LearnedModelBase]) -> None:
        self.machines = list(machines)
        self.worlds = [World(machine.physics.model) for machine in self.machines]  # each machine's site
        self.control_period = self.machines[0].control_period
        model = self.machines[0].physics.model
        self.tip_site, self.bucket_body = model.site(TIP_SITE).id, model.body(BUCKET_BODY).id
        self.qadr = np.array([model.jnt_qposadr[model.joint(n).id] for n in kinematics.JOINTS])
        self.dadr = np.array([model.jnt_dofadr[model.joint(n).id] for n in kinematics.JOINTS])
        self.contact_adr = int(model.sensor(TOOL_CONTACT_SENSOR).adr[0])
        self._servo_bands = _servo_bands(model)
        self._spools_m = np.zeros((len(self.machines), 4))  # what each machine holds, m
        self._bind()

    def _bind(self) -> None:
        datas = [m.physics.data for m in self.machines]
        self._copies = {}
        for name in _ARRAYS:
            if len(datas) == 1:
                array = getattr(datas[0], name)[None]  # a view: always current
            else:
                self._copies[name] = np.stack([getattr(d, name) for d in datas])
                array = self._copies[name].view()
            setattr(self, name, _read_only(array))

    def _refresh(self, ids: np.ndarray) -> None:
        """Gather the sites' arrays after their machines changed."""
        if not self._copies:
            return
        for i in ids.tolist():
            d = self.machines[i].physics.data
            for name, copy in self._copies.items():
                copy[i] = getattr(d, name)

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        for name in (*_ARRAYS, "_copies"):
            del state[name]  # views or copies: rebound to the unpickled MjData
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._bind()

    def start(self, ids: np.ndarray, starts: Sequence[SiteStart]) -> None:
        """Start each site's machine at rest at its start (:func:`start_machine`), spools neutral."""
        for i, start in zip(ids.tolist(), starts, strict=True):
            start_machine(self.machines[i], self.worlds[i], start)
            self._spools_m[i] = 0.0
        self._refresh(ids)

    def hold(self, ids: np.ndarray, spools_m: np.ndarray) -> None:
        """Hold the spools (k, 4), m, at sites ``ids`` from the next :meth:`step` on."""
        self._spools_m[ids] = spools_m

    def step(self, ids: np.ndarray, periods: int) -> None:
        """Advance each site's machine ``periods`` control periods with its spools held."""
        for i in ids.tolist():
            self.machines[i].step(self._spools_m[i], n=periods)
            self.limit_servo_windup(i)
        self._refresh(ids)

    def apply_tip_force(self, ids: np.ndarray, force: np.ndarray) -> None:
        """Push each site's teeth with its ``force`` row (N, world) from now on."""
        for k, i in enumerate(ids.tolist()):
            self.machines[i].physics.apply_tip_force(force[k])

    def set_payload(self, ids: np.ndarray, mass_kg: np.ndarray) -> None:
        """Re-mass each site's bucket payload."""
        for k, i in enumerate(ids.tolist()):
            self.machines[i].physics.set_payload(float(mass_kg[k]))
        self._refresh(ids)

    def loads(self, ids: np.ndarray, joint_loads: np.ndarray, swing_torques: np.ndarray) -> None:
        """The machine models' joint loads into ``joint_loads`` (k, 4), N m, and each swing's inertia times its last
        table acceleration into ``swing_torques`` (k,), N m."""
        for k, i in enumerate(ids.tolist()):
            machine = self.machines[i]
            joint_loads[k] = machine.joint_loads()
            swing_torques[k] = machine.physics.swing_inertia() * machine.swing_acceleration

    def measured_fuel(self, ids: np.ndarray, out: np.ndarray) -> None:
        """Each machine's own fuel measure since it was last asked into ``out`` (k,), L: NaN for a learned model."""
        for k, i in enumerate(ids.tolist()):
            out[k] = self.machines[i].take_fuel_l()

    def limit_servo_windup(self, i: int = 0) -> None:
        """Keep each servo's integrated target where the servo is at most saturated (anti-windup).

        The machine's integrated-velocity servos integrate the tables' rate targets even while a
        joint is stalled (bucket against the truck, dig force above the swing's torque); released,
        the servo would then drive the joint to the stale target whatever the spools say. A stalled
        hydraulic actuator stores no such displacement (its reliefs open), so the target is held
        within the band where the servo force is at its limit.
        """
        act_adr, qpos_adr, dof_adr, ratio, slack = self._servo_bands
        if not len(act_adr):
            return  # a plugin backend: no integrated servo targets
        d = self.machines[i].physics.data
        centre = d.qpos[qpos_adr] + ratio * d.qvel[dof_adr]
        d.act[act_adr] = np.clip(d.act[act_adr], centre - slack, centre + slack)


class BatchSites:
    """A :class:`mujoco.batch.Batch` of the plugin's model as the loading task's
    :class:`hexgym.envs.task.SitePhysics` (the spools are the batch's ``ctrl``).

    Each call does for its sites what the single environment's machine does to its ``MjData``, to the
    last bit: a site starts as :func:`start_machine` starts a machine (on :attr:`starter`, a machine model of
    its own copy of the model, whose state and payload masses it then takes), steps as ``mj_step``, the joint
    loads are ``NativeLearnedModel.joint_loads``, the digging force ``mj_applyFT``'s sum, the payload
    ``ExcavatorPhysics.set_payload``'s masses.

    Args:
        model: the site's model with the native plugin (:func:`native_world_model`).
        count: number of sites.
        nthread: the batch's threads.
    """

    def __init__(self, model: mujoco.MjModel, count: int, nthread: int) -> None:
        from hexgym.model.native_backend import NativeLearnedModel

        self.model = model
        self.count = count
        # starts are made on a copy: starting re-masses its payload and recomputes its constants
        self.starter = NativeLearnedModel(model=copied(model))
        self._starter_world = World(self.starter.physics.model)
        self.control_period = self.starter.control_period
        self.batch = b = mjbatch.Batch(model, count, nthread=nthread, persistent=True)
        self.state = b.state
        # joints: contiguous read-only copies of the state rows' (as the single environment's arrays are typed)
        self._qpos, self._qvel = b.bind("qpos"), b.bind("qvel")
        self._joints = np.zeros(self._qpos.shape), np.zeros(self._qvel.shape)
        self.qpos, self.qvel = (_read_only(copy.view()) for copy in self._joints)
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
        self.tip_site, self.bucket_body, self.payload_body = (
            m.site(TIP_SITE).id,
            m.body(BUCKET_BODY).id,
            m.body(PAYLOAD_BODY).id,
        )
        swing = self.dadr[0]
        self._swing_diag = int(m.M_rowadr[swing] + m.M_rownnz[swing] - 1)
        state = int(m.plugin_stateadr[m.actuator_plugin[self.ctrl_ids[0]]])  # the hexgym.mbl instance's
        self._load_slots = state + PLUGIN_STATE["load"] + np.arange(4)  # the plugin's last constraint load
        self._acceleration_slot = int(state + PLUGIN_STATE["acceleration"])  # its last swing acceleration
        self.contact_adr = int(m.sensor(TOOL_CONTACT_SENSOR).adr[0])
        self._refresh(np.arange(count))
        self.seconds = 0.0  # wall time spent in the batch's steps (the rest is the task logic)
        self.steps = 0  # MuJoCo steps (of one site) they made

    def start(self, ids: np.ndarray, starts: Sequence[SiteStart]) -> None:
        """Start each site as :func:`start_machine` starts a machine: on :attr:`starter`, whose state (spools
        neutral, no applied force) and payload masses the site's row takes; then its constants and derived
        quantities (``mj_setConst``, ``mj_forward``)."""
        physics = self.starter.physics
        payload = self.payload_body
        for i, start in zip(ids.tolist(), starts, strict=True):
            start_machine(self.starter, self._starter_world, start)
            mujoco.mj_getState(physics.model, physics.data, self.state[i], _STATE)
            self.body_mass[i, payload] = physics.model.body_mass[payload]
            self.body_inertia[i, payload] = physics.model.body_inertia[payload]
        self.batch.set_const(ids)
        self.batch.forward(ids, stage=ACC_STAGE)
        self._refresh(ids)

    def hold(self, ids: np.ndarray, spools_m: np.ndarray) -> None:
        """Hold the spools (k, 4), m, at sites ``ids``: the plugin's ctrl columns, in its units."""
        _hold(ids, spools_m, self.ctrl, self.ctrl_ids, CTRL_PER_SPOOL_M)

    def step(self, ids: np.ndarray, periods: int) -> None:
        """Advance the sites ``ids`` by ``periods`` control periods (the model's steps) in the batch's threads;
        positions and velocities then belong to the new state, as after ``mj_step1`` (timed: :attr:`seconds`).

        Even a call of two sites goes to the pool: on free cores waking it costs a few microseconds (measured:
        2 sites one step 8 us against 11-14 us in turn, 8 sites 22-25 against 43 us).
        """
        start = time.perf_counter()
        every = len(ids) == self.count  # None for every site: no ids for the batch to check
        self.batch.step(None if every else ids, nstep=periods, stage=VEL_STAGE)
        self.seconds += time.perf_counter() - start
        self.steps += len(ids) * periods
        self._refresh(ids)

    def _refresh(self, ids: np.ndarray) -> None:
        """Copy the joint positions and velocities of the sites ``ids`` from their state rows (after a step or a
        start)."""
        _copy_rows(ids, self._qpos, self._qvel, *self._joints)

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
        self.batch.forward(ids, stage=ACC_STAGE)

    def loads(self, ids: np.ndarray, joint_loads: np.ndarray, swing_torques: np.ndarray) -> None:
        """NativeLearnedModel.joint_loads of the sites ``ids`` into ``joint_loads`` (k, 4), N m, and the swing's
        inertia times the plugin's last swing acceleration into ``swing_torques`` (k,), N m."""
        _loads(ids, self._qfrc_bias, self._qfrc_passive, self._qfrc_applied, self._plugin_state, self.dadr,
               self._load_slots, self._mass_matrix, self._swing_diag, self._acceleration_slot, joint_loads,
               swing_torques)  # fmt: skip

    def measured_fuel(self, ids: np.ndarray, out: np.ndarray) -> None:
        """No fuel measure of their own (NaN into ``out``): the task estimates the learned machines' fuel."""
        out[: len(ids)] = np.nan


# compiled: gathering a few numbers per site with numpy's fancy indexing costs more than the numbers
@jit
def _loads(
    ids: np.ndarray, bias: np.ndarray, passive: np.ndarray, applied: np.ndarray, plugin_state: np.ndarray,
    dadr: np.ndarray, load_slots: np.ndarray, mass_matrix: np.ndarray, swing_diag: int, acceleration_slot: int,
    joint_loads: np.ndarray, swing_torques: np.ndarray,
) -> None:  # fmt: skip
    """NativeLearnedModel.joint_loads per site: ``qfrc_bias - qfrc_passive - qfrc_applied`` at the main joints less
    the plugin's constraint loads (the same operations in the same order: the same floats); and the swing's inertia
    (its diagonal entry of the sparse mass matrix) times its last table acceleration."""
    for k in range(len(ids)):
        i = ids[k]
        for j in range(4):
            d = dadr[j]
            joint_loads[k, j] = (bias[i, d] - passive[i, d] - applied[i, d]) - plugin_state[i, load_slots[j]]
        swing_torques[k] = mass_matrix[i, swing_diag] * plugin_state[i, acceleration_slot]


@jit
def _hold(ids: np.ndarray, spools_m: np.ndarray, ctrl: np.ndarray, columns: np.ndarray, scale: float) -> None:
    """Row ``k`` of ``spools_m`` times ``scale`` into columns ``columns`` of ``ctrl``'s row ``ids[k]``."""
    for k in range(len(ids)):
        i = ids[k]
        for j in range(4):
            ctrl[i, columns[j]] = spools_m[k, j] * scale


@jit
def _copy_rows(ids: np.ndarray, qpos: np.ndarray, qvel: np.ndarray, qpos_out: np.ndarray, qvel_out: np.ndarray) -> None:
    """Rows ``ids`` of ``qpos`` and ``qvel`` into their copies."""
    for k in range(len(ids)):
        i = ids[k]
        for j in range(qpos.shape[1]):
            qpos_out[i, j] = qpos[i, j]
        for j in range(qvel.shape[1]):
            qvel_out[i, j] = qvel[i, j]

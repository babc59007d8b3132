"""Batched rollouts of the native learned model on the loading site, with the tool's clearance to truck and ground.

:class:`RolloutModel` compiles the site of ``HexLoading-v0`` (pile, truck) around the lean machine driven
by the ``hexgym.mbl`` plugin (:func:`hexgym.envs.sites.native_world_model`) with, added for prediction:

- ``framepos`` sensors of the teeth (site ``tip``) and of the mouth's centre (a site added to the bucket);
  the bucket's x and z axes, the joints' rates and the actuators' forces (the mouth's tilt and the power);
- a clearance sensor (the ``hexgym.clearance`` plugin, cutoff ``detection_m``) per pair of a tool collision
  geom (the bucket's, the stick's) and an obstacle (the ground; the truck: each of its solid geoms): the
  least signed distance between them (negative = penetration), as MuJoCo's ``geomdist`` sensors of the
  geom pairs would read it, but measuring only the pairs whose bounding volumes are within the cutoff.
  Sensors only: the contacts and the motion are the environment's. The bucket's distances are measured
  to its collision mesh's convex hull given as its own mesh (no contacts): the same distances (MuJoCo
  collides a mesh's hull), found faster (its 104 corners instead of the 704 vertices).

``contacts=False`` leaves MuJoCo's collision pass out of the rollouts: the motion is the environment's until
bucket or stick touch something, after which they pass through it, deeper (clearances more negative) than
where the contact would have stopped them; for a planner that rejects every contact.

:meth:`RolloutModel.rollout` runs a batch of spool sequences from one :class:`MachineState` with
``mujoco.rollout`` (``nthread`` threads, a persistent pool) and returns a :class:`RolloutBatch`: per
rollout and control period, the joint angles, the teeth's position, the four pairs' clearances and the
physics states (:meth:`RolloutModel.closest_point` finds a pair's closest point at one). The state is the
machine's full physics state when taken from a native environment (:meth:`MachineState.from_env`), else
built at the given joint angles and rates.

What the prediction leaves out: the digging force (the pile is no collision geom; a bucket in the pile is
predicted as if in air) and changes of the payload during the horizon.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import mujoco
import numpy as np

from hexgym.envs.earthwork import mouth_normal
from hexgym.envs.sites import native_world_model
from hexgym.envs.world import Layout, World
from hexgym.hydraulics import fuel
from hexgym.hydraulics.circuit import engine_fuel_rates
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.assets import asset_path
from hexgym.machine.bucket import BUCKET
from hexgym.machine.names import BUCKET_BODY, GROUND_GEOM, PLANNING_MOUTH_SITE, STICK_BODY, TIP_SITE, TRUCK_BODY
from hexgym.mbl.schema import DEFAULT_TABLE_SET
from hexgym.mbl.table import resolve_tables
from hexgym.model.native_backend import NativeLearnedModel
from hexgym.model.plugin import CLEARANCE_PLUGIN_NAME, CTRL_PER_SPOOL_M

_MOUTH_NORMAL = mouth_normal()  # bucket frame (x, z)
PAIRS = ((BUCKET_BODY, TRUCK_BODY), (BUCKET_BODY, GROUND_GEOM), (STICK_BODY, TRUCK_BODY), (STICK_BODY, GROUND_GEOM))
"""The (tool, obstacle) pairs whose clearance is predicted, in the order of :attr:`RolloutBatch.clearance_m`."""
DETECTION_M = 1.0  # m: contacts are reported this far apart; clearances beyond read as this
HARD_CONTACT_DEPTH_M = p.HARD_CONTACT_FORCE / p.CONTACT_STIFFNESS  # m: the env counts hard contact beyond this depth
MAX_ROLLOUT_BYTES = 2 * 2**30  # the states a batch holds at once, at most (a longer horizon is a mistake)
TOE_MARGIN_M = 0.3e-3  # m past the valves' dead band a plan's spool opens at least (or it is closed): off_the_toe
JOINT_TOLERANCE = 0.05  # rad: a state this far past a stop still counts as inside (MuJoCo's limits are soft)
_TOOL_GEOMS = {"bucket": "planning_bucket_hull", "stick": "planning_stick_collision"}  # both made here
_TRUCK_GEOMS = (
    "truck_floor", "truck_headboard", "truck_tailgate", "truck_left_wall", "truck_right_wall", "truck_chassis",
    "truck_cab",
)  # fmt: skip
_OBSTACLE_GEOMS = {TRUCK_BODY: _TRUCK_GEOMS, GROUND_GEOM: (GROUND_GEOM,)}


@dataclasses.dataclass(frozen=True)
class MachineState:
    """The machine on its site: joint angles (rad) and rates (rad/s) in the order swing, boom, stick,
    bucket; the payload (kg); the site's layout; optionally the full physics state of a native
    environment's model (``mjSTATE_FULLPHYSICS``), which then stands for the rest, or the circuit's state of a
    reference environment (its pressures and pump displacements), which a circuit model's rollouts start from."""

    q: np.ndarray
    qd: np.ndarray
    payload_kg: float
    layout: Layout
    physics_state: np.ndarray | None = None
    hydraulic_state: np.ndarray | None = None

    def __post_init__(self) -> None:
        q, qd = np.asarray(self.q, float), np.asarray(self.qd, float)
        if q.shape != (4,) or qd.shape != (4,):
            raise ValueError(f"state q and qd must have shape (4,), got {q.shape} and {qd.shape}")
        if not (np.isfinite(q).all() and np.isfinite(qd).all()):
            raise ValueError(f"state q and qd must be finite, got q={q}, qd={qd}")
        for name, angle in zip(kinematics.JOINTS, q, strict=True):
            low, high = kinematics.joint_range(name)
            if not low - JOINT_TOLERANCE <= angle <= high + JOINT_TOLERANCE:
                raise ValueError(
                    f"state outside the joint ranges: {name} angle {angle:.4f} rad is outside [{low:.4f}, {high:.4f}]"
                )
        if not (math.isfinite(self.payload_kg) and self.payload_kg >= 0.0):
            raise ValueError(f"payload_kg must be finite and >= 0, got {self.payload_kg}")
        object.__setattr__(self, "q", q)
        object.__setattr__(self, "qd", qd)

    @classmethod
    def from_env(cls, env: Any) -> MachineState:
        """The present state of a ``HexLoading-v0`` environment (wrapped or not; after ``reset``)."""
        env = getattr(env, "unwrapped", env)
        if getattr(env, "layout", None) is None:
            raise RuntimeError("the environment has no state yet: call reset() first")
        ph = env.physics
        physics_state = None
        if isinstance(env.machine, NativeLearnedModel):
            kind = mujoco.mjtState.mjSTATE_FULLPHYSICS
            physics_state = np.empty(mujoco.mj_stateSize(ph.model, kind))
            mujoco.mj_getState(ph.model, ph.data, physics_state, kind)
        reference = getattr(env.machine, "reference", None)  # the reference environment's machine: its circuit
        hydraulic = None if reference is None else np.array(reference.state, float)
        return cls(ph.joint_positions().copy(), ph.joint_velocities().copy(), ph.payload_kg, env.layout, physics_state,
                   hydraulic)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class RolloutBatch:
    """Predicted motions: B rollouts of T control periods (the state at the end of each period).

    ``times_s`` (T,); ``q`` (B, T, 4) rad; ``tip`` (B, T, 3) world m; ``clearance_m`` (B, T, 4): per
    pair of :data:`PAIRS`, the closest distance (m; negative: penetration; ``detection_m`` when farther);
    ``states`` (B, T, nstate): the physics states (``mjSTATE_FULLPHYSICS``); ``qd`` (B, T, 4) rad/s;
    ``mouth`` (B, T, 3): the mouth's centre, world m; ``tilt`` (B, T): the mouth's normal from straight up,
    rad; ``power_w`` (B, T): the servos' |force x rate| summed (W: the lean machine's stiff servos' figure,
    no fuel measure: :meth:`RolloutModel.actuator_power` gives the environment's); ``fuel_l_per_h`` (B, T): the
    engine's fuel rate where the model reports it (the circuit model's pumps), else None (the planner accounts the
    fuel from the motion).
    """

    times_s: np.ndarray
    q: np.ndarray
    tip: np.ndarray
    clearance_m: np.ndarray
    states: np.ndarray
    detection_m: float
    qd: np.ndarray
    mouth: np.ndarray
    tilt: np.ndarray
    power_w: np.ndarray
    fuel_l_per_h: np.ndarray | None = None

    @property
    def min_clearance_m(self) -> np.ndarray:
        """(B,): each rollout's least clearance of bucket and stick to truck and ground (negative = contact)."""
        return self.clearance_m.min(axis=(1, 2))

    @property
    def bucket_clearance_m(self) -> np.ndarray:
        """(B,): each rollout's least clearance of the bucket to truck and ground."""
        return self.clearance_m[:, :, :2].min(axis=(1, 2))

    @property
    def stick_clearance_m(self) -> np.ndarray:
        """(B,): each rollout's least clearance of the stick to truck and ground."""
        return self.clearance_m[:, :, 2:].min(axis=(1, 2))


def _periods(horizon_s: float, period: float) -> int:
    if not (isinstance(horizon_s, int | float) and math.isfinite(horizon_s) and horizon_s > 0):
        raise ValueError(f"horizon_s must be finite and > 0, got {horizon_s!r}")
    return max(1, math.ceil(horizon_s / period - 1e-9))


_BYTES_PER_PERIOD = 256  # a rollout period's figures (angles, rates, teeth, mouth, clearances, tilt, fuel), with room


def spool_batch(
    spools_m: np.ndarray, horizon_s: float, period: float, bytes_per_period: int = _BYTES_PER_PERIOD
) -> np.ndarray:
    """(B, T, 4) spools (m) per control period over ``horizon_s`` from (4,) held, (T', 4) per control period or
    (B, T', 4); a sequence shorter than the horizon holds its last row. Refuses other shapes, non-finite spools,
    spools beyond the stroke and a batch whose rollouts would hold more than ``MAX_ROLLOUT_BYTES`` at
    ``bytes_per_period`` each."""
    spools = np.asarray(spools_m, float)
    if spools.ndim == 1:
        spools = spools[None, None]
    elif spools.ndim == 2:
        spools = spools[None]
    if spools.ndim != 3 or spools.shape[-1] != 4 or spools.shape[1] == 0 or spools.shape[0] == 0:
        raise ValueError(f"spools must have shape (4,), (T, 4) or (B, T, 4) with T, B >= 1, got {spools.shape}")
    if not np.isfinite(spools).all():
        raise ValueError("spools must be finite")
    if np.abs(spools).max() > p.SPOOL_STROKE + 1e-12:
        raise ValueError(f"spools must be within +-{p.SPOOL_STROKE} m, got up to {np.abs(spools).max():.4g} m")
    periods = _periods(horizon_s, period)
    if spools.shape[0] * periods * bytes_per_period > MAX_ROLLOUT_BYTES:
        raise ValueError(
            f"horizon_s {horizon_s} s with {spools.shape[0]} rollouts is too long for memory "
            f"(at most {MAX_ROLLOUT_BYTES // 2**30} GiB of states and sensors at once)"
        )
    if spools.shape[1] < periods:
        spools = np.concatenate([spools, np.repeat(spools[:, -1:], periods - spools.shape[1], axis=1)], axis=1)
    return spools[:, :periods]


def off_the_toe(spools_m: np.ndarray) -> np.ndarray:
    """Spools (m) with every one that opens less than ``TOE_MARGIN_M`` past the valves' dead band closed: there a
    passage barely opens while the open centre's bypass starts to close, and the circuit's response to a micrometre
    is chaotic (a return trimmed to 1.523 mm ended 0.1-0.3 m apart under 1 um of noise). A plan keeps off it."""
    spools = np.array(spools_m, float)
    spools[np.abs(spools) < p.SPOOL_DEAD_BAND + TOE_MARGIN_M] = 0.0
    return spools


class SitePoses(NamedTuple):
    """Where the tool is at joint angles (N rows) on a site: the teeth and the mouth's centre (N, 3, world m), the
    pairs' clearances (N, 4, m, as :attr:`RolloutBatch.clearance_m`) and the mouth's tilt (N, rad, as
    :attr:`RolloutBatch.tilt`)."""

    tip: np.ndarray
    mouth: np.ndarray
    clearance: np.ndarray
    tilt: np.ndarray


class RolloutModel:
    """The native learned model on the loading site, for batched predictions (see the module docstring).

    Args:
        table_set: the learned model's tables (as ``HexLoading-v0``'s ``tables``: a set, or a fitted model's
            directory).
        nthread: threads of ``mujoco.rollout`` (1: in this thread).
        detection_m: how far apart contacts are reported (m, > 0).
        contacts: simulate contacts (False: tool and obstacles pass through each other, see the module docstring).
    """

    def __init__(
        self, table_set: str = DEFAULT_TABLE_SET, nthread: int = 1, detection_m: float = DETECTION_M,
        contacts: bool = True,
    ) -> None:  # fmt: skip
        if isinstance(nthread, bool) or not isinstance(nthread, int) or nthread < 1:
            raise ValueError(f"nthread must be an integer >= 1, got {nthread!r}")
        if not (math.isfinite(detection_m) and detection_m > 0):
            raise ValueError(f"detection_m must be finite and > 0, got {detection_m!r}")
        self.table_set, self.nthread, self.detection_m = table_set, nthread, float(detection_m)
        name, tables_dir = resolve_tables(table_set, "table_set")
        world = native_world_model(table_set=name, customise=self._customise, tables_dir=tables_dir)
        self.machine = NativeLearnedModel(model=world)
        self.physics = self.machine.physics
        m = self.model = self.physics.model
        if not contacts:
            m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        self.world = World(m)
        self.control_period = self.machine.control_period
        self._steps_per_period = round(self.control_period / m.opt.timestep)
        if abs(self._steps_per_period * m.opt.timestep - self.control_period) > 1e-9:
            raise ValueError("the rollout model's control period must be a whole number of steps")
        self._ctrl = np.array([m.actuator(n).id for n in kinematics.JOINTS])
        self._qadr = np.array([m.jnt_qposadr[m.joint(n).id] for n in kinematics.JOINTS])
        self._swing_act = int(m.actuator_actadr[self._ctrl[0]])
        self._kind = mujoco.mjtState.mjSTATE_FULLPHYSICS
        self.state_size = mujoco.mj_stateSize(m, self._kind)
        adr = {m.sensor(i).name: int(m.sensor_adr[i]) for i in range(m.nsensor)}
        self._tip = slice(adr["planning_tip"], adr["planning_tip"] + 3)
        self._mouth = slice(adr["planning_mouth"], adr["planning_mouth"] + 3)
        self._bucket_x, self._bucket_z = adr["planning_bucket_x"], adr["planning_bucket_z"]
        self._qd = np.array([adr[f"planning_qd_{j}"] for j in kinematics.JOINTS])
        self._force = np.array([adr[f"planning_force_{j}"] for j in kinematics.JOINTS])
        self._pair_adr = np.array([m.sensor(f"planning_{a}_{b}").adr[0] for a, b in PAIRS])
        self._pair_geoms = [(m.geom(_TOOL_GEOMS[a]).id, [m.geom(g).id for g in _OBSTACLE_GEOMS[b]]) for a, b in PAIRS]
        self._hydraulics = _plugin_offset(m, self._kind) + self.machine.hydraulic_slots if (
            self.machine.hydraulic_slots is not None) else None  # fmt: skip
        self._datas = [mujoco.MjData(m) for _ in range(nthread)]
        self._pool: Any = None

    def _customise(self, spec: mujoco.MjSpec) -> None:
        """The teeth's position sensor and the clearance sensors (see the module docstring)."""
        stick = [g for g in spec.body("stick").geoms if g.contype or g.conaffinity]
        if len(stick) != 1:
            raise ValueError(f"the machine's stick must have one collision geom, found {len(stick)}")
        stick[0].name = _TOOL_GEOMS["stick"]
        spec.add_mesh(name=_TOOL_GEOMS["bucket"], uservert=_bucket_hull().ravel().tolist())
        spec.body(BUCKET_BODY).add_geom(name=_TOOL_GEOMS["bucket"], type=mujoco.mjtGeom.mjGEOM_MESH,
                                     meshname=_TOOL_GEOMS["bucket"], contype=0, conaffinity=0, group=5)  # fmt: skip
        site, sensor = mujoco.mjtObj.mjOBJ_SITE, mujoco.mjtSensor
        spec.body(BUCKET_BODY).add_site(name=PLANNING_MOUTH_SITE, pos=list(BUCKET.mouth_centre), group=5)
        spec.add_sensor(name="planning_tip", type=sensor.mjSENS_FRAMEPOS, objtype=site, objname=TIP_SITE)
        spec.add_sensor(name="planning_mouth", type=sensor.mjSENS_FRAMEPOS, objtype=site, objname=PLANNING_MOUTH_SITE)
        for axis, kind in (("x", sensor.mjSENS_FRAMEXAXIS), ("z", sensor.mjSENS_FRAMEZAXIS)):
            spec.add_sensor(
                name=f"planning_bucket_{axis}", type=kind, objtype=mujoco.mjtObj.mjOBJ_XBODY, objname="bucket"
            )
        for joint in kinematics.JOINTS:
            spec.add_sensor(name=f"planning_qd_{joint}", type=sensor.mjSENS_JOINTVEL, objtype=mujoco.mjtObj.mjOBJ_JOINT,
                            objname=joint)  # fmt: skip
            spec.add_sensor(name=f"planning_force_{joint}", type=sensor.mjSENS_ACTUATORFRC,
                            objtype=mujoco.mjtObj.mjOBJ_ACTUATOR, objname=joint)  # fmt: skip
        spec.activate_plugin(CLEARANCE_PLUGIN_NAME)
        for tool, obstacle in PAIRS:
            name = f"planning_{tool}_{obstacle}"
            instance = spec.add_plugin(name=name, plugin_name=CLEARANCE_PLUGIN_NAME, active=True)
            obstacles = " ".join(_OBSTACLE_GEOMS[obstacle])
            instance.config = {"tool": _TOOL_GEOMS[tool], "obstacles": obstacles, "cutoff": repr(self.detection_m)}
            clearance = spec.add_sensor(name=name, type=mujoco.mjtSensor.mjSENS_PLUGIN)
            clearance.plugin.plugin_name, clearance.plugin.name = CLEARANCE_PLUGIN_NAME, name

    def initial_state(self, state: MachineState) -> np.ndarray:
        """The physics state (``mjSTATE_FULLPHYSICS``) this model starts a rollout from; sets the payload."""
        ph, m, d = self.physics, self.model, self.physics.data
        if abs(ph.payload_kg - state.payload_kg) > 1e-6:
            ph.set_payload(state.payload_kg)
        self._place_truck(state.layout)
        x0 = np.empty(self.state_size)
        if state.physics_state is not None and state.physics_state.shape == (self.state_size,):
            x0[:] = state.physics_state
            return x0
        mujoco.mj_resetData(m, d)
        self.machine.reset(state.q, payload_kg=state.payload_kg)
        ph.set_joint_state(state.q, state.qd)
        d.act[self._swing_act] = state.qd[0]  # the lean swing servo's rate target
        if state.hydraulic_state is not None and self.machine.hydraulic_slots is not None:
            self.machine.set_hydraulic_state(state.hydraulic_state, state.qd)
        self.world.place(d, state.layout)
        mujoco.mj_forward(m, d)
        mujoco.mj_getState(m, d, x0, self._kind)
        return x0

    def _place_truck(self, layout: Layout) -> None:
        """Put the truck where ``layout`` says in the model (``body_pos``, which ``mj_resetData`` copies to the mocap)
        and in every thread's data: the mocap pose is no part of the ``mjSTATE_FULLPHYSICS`` state a rollout sets."""
        m, body = self.model, self.model.body(TRUCK_BODY).id
        for d in (self.physics.data, *self._datas):
            self.world.place(d, layout)
        m.body_pos[body] = self.physics.data.mocap_pos[self.world.truck_mocap]
        m.body_quat[body] = self.physics.data.mocap_quat[self.world.truck_mocap]

    def spool_controls(self, spools_m: np.ndarray, horizon_s: float) -> np.ndarray:
        """(B, S + 1, nu) plugin controls (mm) for the S physics steps of the horizon and one more, from spools (m):
        (4,) held, (T', 4) per control period or (B, T', 4); a sequence shorter than the horizon holds its last row,
        and so does the step after the horizon (mj_step computes the sensors before it integrates, so a step's state
        is read from the next step's sensors: the horizon's last step's too)."""
        per_step = self.state_size + self.model.nsensordata + self.model.nu  # values held per rollout step
        spools = spool_batch(spools_m, horizon_s, self.control_period, self._steps_per_period * per_step * 8)
        steps = spools.shape[1] * self._steps_per_period
        controls = np.zeros((spools.shape[0], steps + 1, self.model.nu))
        controls[:, :steps, self._ctrl] = np.repeat(spools, self._steps_per_period, axis=1) * CTRL_PER_SPOOL_M
        controls[:, steps] = controls[:, steps - 1]
        return controls

    def rollout(self, state: MachineState, spools_m: np.ndarray, horizon_s: float) -> RolloutBatch:
        """Roll out spool sequences (see :meth:`spool_controls`) from ``state`` for ``horizon_s`` seconds."""
        controls = self.spool_controls(spools_m, horizon_s)
        nbatch, nstep = controls.shape[:2]
        x0 = self.initial_state(state)
        from mujoco import rollout

        states = np.empty((nbatch, nstep, self.state_size))
        sensors = np.empty((nbatch, nstep, self.model.nsensordata))
        if self.nthread == 1:
            rollout.rollout(self.model, self._datas[0], x0[None], controls, state=states, sensordata=sensors)
        else:
            if self._pool is None:
                self._pool = rollout.Rollout(nthread=self.nthread)
            self._pool.rollout(self.model, self._datas, x0[None], controls, state=states, sensordata=sensors)
        return self._batch(states, sensors)

    def _batch(self, states: np.ndarray, sensors: np.ndarray) -> RolloutBatch:
        """Sample the end of each control period from a rollout one step longer than its periods. Sensors lag the
        state by one step (mj_step computes them before integrating), so a period's end is read from the next
        step's sensors."""
        k = self._steps_per_period
        ends = np.arange(k - 1, states.shape[1] - 1, k)
        q = states[:, ends][:, :, self._qadr + 1]  # state[0] is the time
        s = sensors[:, ends + 1]
        tip = s[:, :, self._tip]
        clearance = s[:, :, self._pair_adr]
        times = (np.arange(len(ends)) + 1) * self.control_period
        qd = s[:, :, self._qd]
        power = np.abs(s[:, :, self._force] * qd).sum(axis=2)
        fuel = None if self._hydraulics is None else engine_fuel_rates(states[:, ends][:, :, self._hydraulics])
        return RolloutBatch(
            times, q, tip, clearance, states[:, ends], self.detection_m, qd, s[:, :, self._mouth],
            _tilt(s[:, :, self._bucket_x + 2], s[:, :, self._bucket_z + 2]), power, fuel,
        )  # fmt: skip

    def closest_point(self, physics_state: np.ndarray, pair: int) -> tuple[np.ndarray, float]:
        """The middle of the closest points of pair ``pair`` of :data:`PAIRS` at a physics state, and their distance."""
        m, d = self.model, self.physics.data
        mujoco.mj_setState(m, d, physics_state, self._kind)
        mujoco.mj_kinematics(m, d)
        tool, obstacles = self._pair_geoms[pair]
        best, point = math.inf, np.full(3, np.nan)
        fromto = np.empty(6)
        for other in obstacles:
            dist = mujoco.mj_geomDistance(m, d, tool, other, self.detection_m, fromto)
            if dist < best:
                best, point = dist, (fromto[:3] + fromto[3:]) / 2.0
        return point, float(min(best, self.detection_m))

    def at_angles(self, q: np.ndarray, layout: Layout) -> SitePoses:
        """The tool's poses at joint angles ``q`` (N, 4) on a site laid out as ``layout`` (kinematics only: e.g.
        another model's trajectory)."""
        m, d = self.model, self.physics.data
        q = np.atleast_2d(np.asarray(q, float))
        mujoco.mj_resetData(m, d)
        self.world.place(d, layout)
        tips, mouths, clearance = np.empty((len(q), 3)), np.empty((len(q), 3)), np.empty((len(q), len(PAIRS)))
        up = np.empty((len(q), 2))  # the bucket's x and z axes' world z components
        tip_site, mouth_site, bucket = m.site(TIP_SITE).id, m.site(PLANNING_MOUTH_SITE).id, m.body(BUCKET_BODY).id
        fromto = np.empty(6)
        for k, angles in enumerate(q):
            d.qpos[self._qadr] = angles
            mujoco.mj_kinematics(m, d)
            tips[k], mouths[k] = d.site_xpos[tip_site], d.site_xpos[mouth_site]
            up[k] = d.xmat[bucket][[6, 8]]  # row-major: column 0 is the x axis, column 2 the z axis
            for j, (tool, obstacles) in enumerate(self._pair_geoms):
                clearance[k, j] = min(
                    min(mujoco.mj_geomDistance(m, d, tool, o, self.detection_m, fromto) for o in obstacles),
                    self.detection_m,
                )
        return SitePoses(tips, mouths, clearance, _tilt(up[:, 0], up[:, 1]))

    def actuator_power(self, physics_states: np.ndarray) -> np.ndarray:
        """The actuators' mechanical power (W) at physics states (N, nstate), as the environment accounts it for fuel
        (:func:`hexgym.hydraulics.fuel.actuator_power` of the machine's joint loads and rates)."""
        m, d = self.model, self.physics.data
        out = np.empty(len(physics_states))
        for k, x in enumerate(physics_states):
            mujoco.mj_setState(m, d, x, self._kind)
            mujoco.mj_forward(m, d)
            loads, rates = self.machine.joint_loads(), self.physics.joint_velocities()
            swing_torque = self.physics.swing_inertia() * self.machine.swing_acceleration
            out[k] = fuel.actuator_power(loads[1:], rates[1:], swing_torque, rates[0])
        return out

    def clearance_at(self, physics_state: np.ndarray) -> np.ndarray:
        """(4,) the clearance (m) of each pair of :data:`PAIRS` at a physics state (``detection_m`` when farther)."""
        return np.array([self.closest_point(physics_state, pair)[1] for pair in range(len(PAIRS))])

    def close(self) -> None:
        """Shut the rollout threads down."""
        if self._pool is not None:
            self._pool.close()
            self._pool = None


def _plugin_offset(m: mujoco.MjModel, kind: int) -> int:
    """Where the plugin state begins in a state vector of ``kind`` (the parts are in the order of their bits)."""
    plugin = int(mujoco.mjtState.mjSTATE_PLUGIN)
    return sum(mujoco.mj_stateSize(m, bit) for bit in (1 << k for k in range(plugin.bit_length() - 1))
               if kind & bit)  # fmt: skip


def _tilt(x_up: np.ndarray, z_up: np.ndarray) -> np.ndarray:
    """The mouth's normal from straight up (rad), from the world z components of the bucket's x and z axes."""
    return np.arccos(np.clip(x_up * _MOUTH_NORMAL[0] + z_up * _MOUTH_NORMAL[1], -1.0, 1.0))


def bang_bang(sign: float, switch: int, stop: int, periods: int) -> np.ndarray:
    """Swing spools (m) per control period: full towards ``sign`` to ``switch``, full against it to ``stop``, closed."""
    swing = np.zeros(periods)
    swing[:switch] = sign * p.SPOOL_STROKE
    swing[switch:stop] = -sign * p.SPOOL_STROKE
    return swing


def _bucket_hull() -> np.ndarray:
    """The corners (N, 3) of the bucket collision mesh's convex hull, in the bucket's frame (the mesh's own)."""
    import trimesh

    return np.asarray(trimesh.load_mesh(asset_path("meshes/bucket.stl")).convex_hull.vertices)


def pair_names(index: int | Sequence[int]) -> tuple[str, str] | list[tuple[str, str]]:
    """The (tool, obstacle) names of a pair index (or indices) of :data:`PAIRS`."""
    if isinstance(index, int | np.integer):
        return PAIRS[int(index)]
    return [PAIRS[int(i)] for i in index]

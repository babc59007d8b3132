"""The excavator's MuJoCo simulation: state in machine terms, payload, tip forces.

:class:`ExcavatorPhysics` owns an ``MjModel``/``MjData`` pair of ``assets/cat325.xml`` (or the
scene that includes it) and exposes the physical quantities the hydraulic models and the
environment need as methods, dm_control-style. The actuators act on the four main joints:
by default integrated-velocity servos (ctrl: joint rate, rad/s; zero holds the pose), or, in
the model from :func:`force_actuated_model`, plain torques (ctrl: N m). The closed kinematic chains (cylinders, bucket
four-bar) are assembled from :mod:`hexgym.machine.kinematics` whenever the joint state is set, so resets
are exact.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.assets import MODEL_FILE, SCENE_FILE, AssetError, asset_path, load_model
from hexgym.machine.names import BUCKET_BODY, PAYLOAD_BODY, TIP_SITE

_FD_STEP = 1e-6  # rad, central differences for the passive joints' velocities
MAX_PAYLOAD_KG = p.BUCKET_HEAPED_CAPACITY * p.MATERIAL_DENSITY  # kg: a heaped bucket (2145 kg)
HEAVIEST_PAYLOAD_KG = MAX_PAYLOAD_KG * p.MATERIAL_DENSITY_SCALE_RANGE[1]  # kg: of the heaviest material (3218 kg)
_RETRACTED = np.array([p.CYLINDERS[n].retracted_length for n in kinematics.FRONT_CYLINDERS])


def _joint_values(q: np.ndarray) -> dict[str, float]:
    """Every joint's value (main and passive) for main joint angles ``q``, as MuJoCo measures it."""
    passive, passive0 = kinematics.passive_joints(q), kinematics.passive_joints(np.zeros(4))
    values = dict(zip(kinematics.JOINTS, (float(v) for v in q), strict=True))
    for name in kinematics.FRONT_CYLINDERS:
        values[f"{name}_cylinder_pivot"] = passive[f"{name}_barrel"] - passive0[f"{name}_barrel"]
        values[f"{name}_cylinder"] = passive[f"{name}_extension"]
    for name in ("guide_link", "power_link"):
        values[name] = passive[name] - passive0[name]
    return values


def assembled_state(
    model: mujoco.MjModel, q: np.ndarray, qd: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray] | tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(qpos, act) of the assembled closed chain at main joints ``q``; with ``qd`` also qvel.

    ``act`` holds the actuators' position targets (swing angle, cylinder extensions), so the
    integrated-velocity servos hold the pose they start in.
    """
    q = np.asarray(q, dtype=float)
    present = {model.joint(i).name for i in range(model.njnt)}  # the lean model has no passive joints
    values = {name: v for name, v in _joint_values(q).items() if name in present}
    qpos = np.array(model.qpos0, dtype=float)
    for name, value in values.items():
        qpos[model.jnt_qposadr[model.joint(name).id]] = value
    act = np.array([values[_actuated_joint(model, i)] for i in range(model.nu) if model.actuator_actadr[i] >= 0])
    if qd is None:
        return qpos, act
    qd = np.asarray(qd, dtype=float)
    plus, minus = _joint_values(q + _FD_STEP * qd), _joint_values(q - _FD_STEP * qd)
    qvel = np.zeros(model.nv)
    for name in values:
        qvel[model.jnt_dofadr[model.joint(name).id]] = (plus[name] - minus[name]) / (2 * _FD_STEP)
    return qpos, act, qvel


def contiguous_index(ids: np.ndarray) -> slice | np.ndarray:
    """``ids`` as a slice where they are consecutive and ascending (the usual layout of the four main
    joints): indexing with a slice is a view, several times cheaper than numpy's fancy indexing."""
    ids = np.asarray(ids, dtype=int)
    if len(ids) and np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids))):
        return slice(int(ids[0]), int(ids[0]) + len(ids))
    return ids


def _actuated_joint(model: mujoco.MjModel, actuator: int) -> str:
    return model.joint(model.actuator_trnid[actuator, 0]).name


def force_actuated_model(path: str | Path | None = None, scene: bool = False) -> mujoco.MjModel:
    """The machine with its four servos replaced by plain force inputs (ctrl in N or N m).

    The reference hydraulic model computes cylinder forces and the swing torque itself and uses
    this model; ctrl is then the joint torque (see :meth:`ExcavatorPhysics.set_actuator_forces`).
    Force limits are lifted too: the circuit's reliefs bound the pressures.
    """
    path = Path(path) if path is not None else asset_path(SCENE_FILE if scene else MODEL_FILE)
    try:
        spec = mujoco.MjSpec.from_file(str(path))
        to_force_inputs(spec)
        return spec.compile()
    except ValueError as exc:
        raise AssetError(f"cannot load model {path}: {exc}") from exc


def to_force_inputs(spec: mujoco.MjSpec) -> None:
    """Turn every actuator of ``spec`` into an unlimited force input (see :func:`force_actuated_model`)."""
    for actuator in spec.actuators:
        actuator.set_to_motor()
        actuator.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        actuator.forcelimited = mujoco.mjtLimited.mjLIMITED_FALSE
        actuator.actlimited = mujoco.mjtLimited.mjLIMITED_FALSE
    # keyframes carry one activation per servo; motors have none
    for key in spec.keys:
        key.act = []


class ExcavatorPhysics:
    """A MuJoCo simulation of the machine with accessors in machine terms.

    Args:
        model: a compiled model of ``cat325.xml`` or a scene including it; default the
            packaged machine (``scene=True``: the packaged scene).
        scene: load the packaged ``scene.xml`` when ``model`` is not given.
    """

    def __init__(self, model: mujoco.MjModel | None = None, scene: bool = False) -> None:
        self.model = model if model is not None else load_model(scene=scene)
        skip_collisions_if_none_possible(self.model)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._qadr = np.array([m.jnt_qposadr[m.joint(n).id] for n in kinematics.JOINTS])
        self._dadr = np.array([m.jnt_dofadr[m.joint(n).id] for n in kinematics.JOINTS])
        self._qpos_index, self._dof_index = contiguous_index(self._qadr), contiguous_index(self._dadr)
        self._tip = m.site(TIP_SITE).id
        self._bucket = m.body(BUCKET_BODY).id
        self._payload = m.body(PAYLOAD_BODY).id
        # data.M is the lower triangle of the mass matrix in CSR form; a row's diagonal is its last entry
        swing_dof = self._dadr[0]
        self._swing_diag = m.M_rowadr[swing_dof] + m.M_rownnz[swing_dof] - 1
        self.payload_kg = 0.0
        # the constraint forces less the joint limits' share, from the last step's solve (see holding_loads);
        # kept only when a model reads holding_loads: it costs ~10 us a step
        self.tracks_constraint_load = False
        self.constraint_load = np.zeros(m.nv)
        self.reset()

    # -- pickling ------------------------------------------------------------------------
    def __getstate__(self) -> dict:
        """Pickle the model and the simulation state (``mjSTATE_INTEGRATION``), not the ``MjData``.

        Unpickling an ``MjData`` copies its plugin instances' pointers, so two datas would share
        (and both free) the native plugin's instance; a fresh ``MjData`` set to the state has its own.
        """
        state = self.__dict__.copy()
        kind = mujoco.mjtState.mjSTATE_INTEGRATION
        sim_state = np.empty(mujoco.mj_stateSize(self.model, kind))
        mujoco.mj_getState(self.model, self.data, sim_state, kind)
        state["data"] = sim_state
        return state

    def __setstate__(self, state: dict) -> None:
        sim_state = state.pop("data")
        self.__dict__.update(state)
        self.data = mujoco.MjData(self.model)
        mujoco.mj_setState(self.model, self.data, sim_state, mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_step1(self.model, self.data)  # positions and velocities derived, as after step()

    # -- state ---------------------------------------------------------------------------
    def reset(self, keyframe: str = "home") -> None:
        """Reset to a keyframe of the model (time 0, payload kept); ValueError naming the model's keyframes."""
        names = [self.model.key(i).name for i in range(self.model.nkey)]
        if keyframe not in names:
            raise ValueError(f"no keyframe {keyframe!r} in the model; it has {', '.join(names) or 'none'}")
        mujoco.mj_resetDataKeyframe(self.model, self.data, self.model.key(keyframe).id)
        mujoco.mj_forward(self.model, self.data)

    def start_at(self, start: str | np.ndarray = "home", payload_kg: float = 0.0) -> None:
        """Start at rest at a keyframe name or main joint angles (rad), with a payload, at time 0."""
        self.set_payload(payload_kg)
        if isinstance(start, str):
            self.reset(start)
        else:
            self.set_joint_state(np.asarray(start, dtype=float))
        self.data.time = 0.0
        if self.tracks_constraint_load:
            self.record_constraint_load()

    def set_joint_state(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """Place the machine at main joint angles ``q`` (rad) and velocities ``qd`` (rad/s)."""
        q = np.asarray(q, dtype=float)
        if q.shape != (4,) or not np.all(np.isfinite(q)):
            raise ValueError(f"joint positions must be 4 finite numbers, got {q!r}")
        qd = np.zeros(4) if qd is None else np.asarray(qd, dtype=float)
        qpos, act, qvel = assembled_state(self.model, q, qd)
        self.data.qpos[:], self.data.act[:], self.data.qvel[:] = qpos, act, qvel
        mujoco.mj_forward(self.model, self.data)

    def step(self, n: int = 1) -> None:
        """Advance the simulation ``n`` MuJoCo steps.

        Each step is ``mj_step2`` then ``mj_step1`` (as dm_control does): the same trajectory as
        ``mj_step``, but positions, sites and the mass matrix afterwards belong to the new state.
        """
        m, d = self.model, self.data
        for _ in range(n):
            mujoco.mj_step2(m, d)
            if self.tracks_constraint_load:
                self.record_constraint_load()
            mujoco.mj_step1(m, d)

    def holding_loads(self) -> np.ndarray:
        """Torque each main joint's actuator must supply to hold the present motion (N m): gravity, the
        velocity terms, joint damping, the tip force and the linkage's constraint forces, as the machine's
        dynamic model computes the actuators' loads from its state (the paper's Step 1; the tables' load
        inputs). ``tracks_constraint_load`` must be set before stepping.

        Joint-limit forces are not part of it: at a stroke end the cylinder's stop carries the load, not
        its oil. The constraint share is the last step's solve, taken between ``mj_step2`` and ``mj_step1``:
        after ``mj_step1`` the constraint rows already belong to the next state while ``efc_force`` and
        ``qfrc_constraint`` are the last solve's, so the share cannot be taken then (a limit row that
        vanished would leave its force, ~1e10 N m against the stiff servos, in the load).
        """
        d = self.data
        tau = d.qfrc_bias - d.qfrc_passive - d.qfrc_applied - self.constraint_load
        return tau[self._dof_index]

    def record_constraint_load(self) -> None:
        """Keep the present solve's constraint forces less the joint limits' share for :meth:`holding_loads`
        (after ``mj_forward`` or ``mj_step2``; :meth:`step` does it when ``tracks_constraint_load`` is set)."""
        self.constraint_load = self.data.qfrc_constraint - self._limit_forces()

    def _limit_forces(self) -> np.ndarray:
        """The joint limits' share of ``qfrc_constraint`` (J^T f over the limit rows)."""
        m, d = self.model, self.data
        out = np.zeros(m.nv)
        limit_rows = d.efc_type == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT
        if limit_rows.any():
            mujoco.mj_mulJacTVec(m, d, out, np.where(limit_rows, d.efc_force, 0.0))
        return out

    @property
    def time(self) -> float:
        """Simulated time, s."""
        return float(self.data.time)

    @property
    def timestep(self) -> float:
        """MuJoCo step, s."""
        return float(self.model.opt.timestep)

    # -- quantities ----------------------------------------------------------------------
    def joint_positions(self) -> np.ndarray:
        """[swing, boom, stick, bucket], rad (a copy)."""
        return self.data.qpos[self._qpos_index].copy()

    def joint_velocities(self) -> np.ndarray:
        """[swing, boom, stick, bucket], rad/s (a copy)."""
        return self.data.qvel[self._dof_index].copy()

    def cylinder_lengths(self) -> np.ndarray:
        """[boom, stick, bucket] pin-to-pin lengths, m, from the joint angles (hexgym.machine.kinematics)."""
        q = self.data.qpos[self._qadr]
        return np.array([kinematics.cylinder_length(n, q[i + 1]) for i, n in enumerate(kinematics.FRONT_CYLINDERS)])

    def cylinder_extensions(self) -> np.ndarray:
        """[boom, stick, bucket] extension from fully retracted, m."""
        return self.cylinder_lengths() - _RETRACTED

    def moment_arms(self) -> np.ndarray:
        """[boom, stick, bucket] dC/dq, m/rad: joint torque = cylinder force x arm (Eqn 5)."""
        q = self.data.qpos[self._qadr]
        return np.array([kinematics.moment_arm(n, q[i + 1]) for i, n in enumerate(kinematics.FRONT_CYLINDERS)])

    def cylinder_velocities(self) -> np.ndarray:
        """[boom, stick, bucket] extension speed, m/s (moment arm x joint rate)."""
        return self.moment_arms() * self.data.qvel[self._dadr[1:]]

    def set_actuator_targets(self, joint_rates: np.ndarray) -> None:
        """Command the four joint-rate servos, rad/s (clipped to their ranges)."""
        rates = np.asarray(joint_rates, dtype=float)
        rng = self.model.actuator_ctrlrange
        self.data.ctrl[:] = np.clip(rates, rng[:, 0], rng[:, 1])

    def set_actuator_forces(self, cylinder_forces: np.ndarray, swing_torque: float) -> None:
        """Force-actuated models only: cylinder forces (N, + extends) and swing torque (N m)."""
        self.data.ctrl[0] = swing_torque
        self.data.ctrl[1:] = np.asarray(cylinder_forces, dtype=float) * self.moment_arms()

    def tip_position(self) -> np.ndarray:
        """Bucket teeth position in the world frame, m."""
        return self.data.site_xpos[self._tip].copy()

    def swing_inertia(self) -> float:
        """Inertia about the swing axis of everything above the swing bearing, kg m^2."""
        return float(self.data.M[self._swing_diag])

    # -- loads -----------------------------------------------------------------------------
    def set_payload(self, mass_kg: float) -> None:
        """Put ``mass_kg`` of material in the bucket (a box of loose material at its centroid).

        At most :data:`HEAVIEST_PAYLOAD_KG`, a heaped bucket of the heaviest material a site task takes
        (``MATERIAL_DENSITY_SCALE_RANGE``): the machine was built and its tables fitted for a heaped bucket of the
        nominal material (their data hold 0 to 2 t), and far more makes the simulation unstable.
        """
        if not np.isfinite(mass_kg) or not 0 <= mass_kg <= HEAVIEST_PAYLOAD_KG * (1 + 1e-9):
            raise ValueError(
                f"payload must be a finite mass from 0 to {HEAVIEST_PAYLOAD_KG:.0f} kg (a heaped bucket of "
                f"{p.BUCKET_HEAPED_CAPACITY} m^3 at {p.MATERIAL_DENSITY_SCALE_RANGE[1] * p.MATERIAL_DENSITY:.0f} "
                f"kg/m^3), got {mass_kg} kg"
            )
        self.payload_kg = float(mass_kg)
        self.model.body_mass[self._payload] = mass_kg
        self.model.body_inertia[self._payload] = payload_inertia(np.array([mass_kg]))[0]
        # mj_setConst recomputes the model's constants at qpos0 in this MjData: keep the state
        kind = mujoco.mjtState.mjSTATE_INTEGRATION
        state = np.empty(mujoco.mj_stateSize(self.model, kind))
        mujoco.mj_getState(self.model, self.data, state, kind)
        mujoco.mj_setConst(self.model, self.data)
        mujoco.mj_setState(self.model, self.data, state, kind)
        mujoco.mj_forward(self.model, self.data)

    def apply_tip_force(self, force: np.ndarray) -> None:
        """Apply ``force`` (N, world frame) at the teeth's current position; call every step it acts.

        It is written as the equivalent joint forces into ``data.qfrc_applied`` (which it owns),
        so the linkage loads see it as ``qfrc_applied``.
        """
        force = np.asarray(force, dtype=float)
        if force.shape != (3,) or not np.all(np.isfinite(force)):
            raise ValueError(f"tip force must be 3 finite numbers, got {force!r}")
        self.data.qfrc_applied[:] = 0.0
        tip = self.data.site_xpos[self._tip]
        mujoco.mj_applyFT(self.model, self.data, force, np.zeros(3), tip, self._bucket, self.data.qfrc_applied)


def skip_collisions_if_none_possible(model: mujoco.MjModel) -> bool:
    """Turn off MuJoCo's collision pass (``mjDSBL_CONTACT``) when no two geoms of ``model`` can ever touch.

    The machine alone is such a model: its geoms collide only with world geoms (contype 2 /
    conaffinity 1), so the pass finds nothing, yet its broad phase costs ~15 % of a step. Exact:
    nothing it could find is lost. A scene with ground or truck keeps the pass. True when turned off.
    The flag is set on ``model`` itself: a caller that later makes geoms collidable (``geom_contype``
    is writable) must clear it.
    """
    types, affinities, bodies = model.geom_contype, model.geom_conaffinity, model.geom_bodyid
    candidates = np.flatnonzero((types != 0) | (affinities != 0))
    for k, i in enumerate(candidates):
        others = candidates[k + 1 :]
        others = others[bodies[others] != bodies[i]]  # MuJoCo never collides two geoms of one body
        if np.any((types[i] & affinities[others]) | (types[others] & affinities[i])):
            return False
    if model.npair:  # explicit <pair>s collide whatever their geoms' types say
        return False
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    return True


def payload_inertia(mass_kg: np.ndarray) -> np.ndarray:
    """Principal inertias (k, 3), kg m^2, of ``mass_kg`` (k,) of material in the bucket: a box of loose
    material, its depth from the volume over the bucket's width (one formula for one and many envs)."""
    mass = np.asarray(mass_kg, dtype=float)
    volume = mass / p.MATERIAL_DENSITY
    depth = np.sqrt(np.maximum(volume, 0.0) / p.BUCKET_WIDTH)
    width = p.BUCKET_WIDTH
    return np.stack(
        [mass * (width**2 + depth**2) / 12, mass * (depth**2 + depth**2) / 12, mass * (depth**2 + width**2) / 12],
        axis=1,
    )

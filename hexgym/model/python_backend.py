"""The learned machine model: MuJoCo's linkage dynamics + the MBL tables (paper Sec III), in Python.

Every control period (default: one 25 ms step of the lean machine), the paper's three steps:

1. **Loads.** The cylinder force loads of the present state from the linkage model: the joint
   torque that holds the links against gravity, velocity terms, the cylinders' and links' own
   loads (the full model's closed chains' constraint forces) and any tip force,
   ``tau = qfrc_bias - qfrc_passive - qfrc_applied - qfrc_constraint`` at the main joints (less the
   joint limits' share), mapped to cylinder forces by the moment arms (Eqn 5:
   ``f = tau / (dC/dq)``). The tables are steady-state models, so the links' own acceleration is
   not part of the load.
2. **Tables.** Boom, bucket and stick tables turn spools + loads into cylinder velocities; the
   swing table gives the swing acceleration from the spools, the stick load, the swing inertia
   (MuJoCo's mass matrix) and the swing rate.
3. **Integration.** The cylinder velocities become joint-rate targets through the moment arms;
   the swing's target rate is integrated from the acceleration. The MJCF's stiff velocity servos
   reach the targets within the step (a zero target holds the joint: no sag) and MuJoCo integrates.

All Python happens in this step loop, not in ``mujoco.set_mjcb_control`` (one global hook per process,
holding the GIL, which makes ``mujoco.rollout`` serialise).
"""

from __future__ import annotations

import mujoco
import numpy as np

from hexgym.hydraulics.circuit import validate_spools
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.assets import load_model
from hexgym.machine.names import UPPER_BODY
from hexgym.machine.physics import ExcavatorPhysics
from hexgym.mbl.schema import TABLE_SETS, table_set_of
from hexgym.mbl.table import MBLTable, load_tables
from hexgym.model.base import END_MARGIN, PULL_LIMIT, PUSH_LIMIT, STROKES, LearnedModelBase, next_swing_rate


class LearnedModel(LearnedModelBase):
    """MuJoCo linkage driven by the MBL tables, in Python.

    Args:
        tables: the tables of one table set (default: the packaged ones of ``table_set``,
            :func:`hexgym.mbl.table.load_tables`; the circuit model's are
            :class:`hexgym.model.circuit_model.CircuitModel`'s).
        model: a compiled machine or scene model with joint-rate servo actuators (default: the lean
            machine, ``assets/cat325_lean.xml``, whose step is the control period).
        control_period: seconds between table queries; a multiple of the MuJoCo step (default:
            one step).
        table_set: ``"paper"`` (the paper's four tables, :mod:`hexgym.mbl.schema`; the default); with
            ``tables``, the set they form.
    """

    def __init__(
        self,
        tables: dict[str, MBLTable] | None = None,
        model: mujoco.MjModel | None = None,
        control_period: float | None = None,
        table_set: str | None = None,
    ) -> None:
        self._init_machine(model, control_period)
        if tables is None:
            tables = load_tables(table_set=table_set or "paper")
        self.table_set = table_set_of(tables)
        self.tables = tables
        self._schema = TABLE_SETS[self.table_set]
        self._swing_acceleration = 0.0
        self._swing_rate_target = 0.0
        rate_axis = tables["swing"].axes[tables["swing"].inputs.index("swing_rate_radps")]
        self._slowest_swing, self._fastest_swing = rate_axis[0], rate_axis[-1]

    def _init_machine(self, model: mujoco.MjModel | None, control_period: float | None) -> None:
        """The lean machine (or ``model``), the control period's MuJoCo steps and the contact stall's data."""
        self.physics = ExcavatorPhysics(model if model is not None else load_model(lean=True))
        if control_period is None:
            control_period = self.physics.timestep
        self._substeps = int(round(control_period / self.physics.timestep))
        if self._substeps < 1 or abs(self._substeps * self.physics.timestep - control_period) > 1e-9:
            raise ValueError(f"control_period must be a multiple of the model step, got {control_period}")
        self._dofs = np.array([self.physics.model.joint(n).dofadr[0] for n in kinematics.JOINTS])
        self.spools_m = np.zeros(4)
        self.physics.tracks_constraint_load = True  # the loads (step 1) read it
        m = self.physics.model
        upper = m.body(UPPER_BODY).id  # the swinging structure and all it carries
        self._machine_body = np.array([upper in _ancestors(m, b) for b in range(m.nbody)])
        self._jacp = np.zeros((3, m.nv))

    @property
    def control_period(self) -> float:
        """Seconds between table queries (one :meth:`step`)."""
        return self._substeps * self.physics.timestep

    @property
    def swing_acceleration(self) -> float:
        """The swing table's last acceleration, rad/s^2."""
        return self._swing_acceleration

    def reset(self, start: str | np.ndarray = "home", payload_kg: float = 0.0) -> None:
        """Start at a keyframe name or joint angles (rad), at rest, spools neutral."""
        self.physics.start_at(start, payload_kg)
        self.spools_m = np.zeros(4)
        self._swing_acceleration = 0.0
        self._swing_rate_target = 0.0
        self.physics.set_actuator_targets(np.zeros(4))
        self.physics.step(1)  # one step so the constraint forces (part of the loads) exist
        self.physics.data.time = 0.0

    def joint_loads(self) -> np.ndarray:
        """Torque each main joint's actuator must supply to hold the present motion (N m):
        :meth:`ExcavatorPhysics.holding_loads`."""
        return self.physics.holding_loads()

    def step(self, spools_m: np.ndarray, n: int = 1) -> None:
        """Advance ``n`` control periods with the spools (m; swing, boom, stick, bucket) held."""
        self.spools_m = validate_spools(spools_m).copy()
        for _ in range(n):
            self._control_period()

    def effective_spools(self, loads: np.ndarray | None = None) -> np.ndarray:
        """The spools as the tables should see them: a stalled function passes no flow.

        A function stalls when a cylinder is driven into its stroke end, or when its load exceeds
        what its line relief lets it push or pull (a cylinder or the swing against the ground,
        the truck or a digging force it cannot overcome). The tables were learned away from both
        (there the stop or the relief, not the valve, sets the speed), so they cannot know it:
        closing that spool for the lookup says so, and its partner on the same pump then gets the
        flow (the boom rises once the bucket is fully curled). What it leaves out is the stalled
        spool's closed centre bypass, which in the circuit sends a little more flow to the partner.

        ``loads``: [swing torque, N m, and boom, stick, bucket cylinder forces, N]; default: the
        present ones.
        """
        if loads is None:
            loads = np.concatenate([self.joint_loads()[:1], self.cylinder_loads()])
        spools = self.spools_m.copy()
        ext = self.physics.cylinder_extensions()
        extending, retracting = spools[1:] > 0, spools[1:] < 0
        at_start, at_end = ext <= END_MARGIN, ext >= STROKES - END_MARGIN
        stalled = (at_start & retracting) | (at_end & extending)
        stalled |= (extending & (loads[1:] > PUSH_LIMIT)) | (retracting & (loads[1:] < -PULL_LIMIT))
        spools[1:][stalled] = 0.0
        if abs(loads[0]) > p.SWING_TORQUE_AT_RELIEF and loads[0] * spools[0] > 0:
            spools[0] = 0.0
        return spools

    def _control_period(self) -> None:
        ph = self.physics
        arms = ph.moment_arms()  # once per period: the loads and the rate targets both need them
        tau = self.joint_loads()
        f_boom, f_stick, f_bucket = tau[1:] / arms
        u_swing, u_boom, u_stick, u_bucket = self.effective_spools(np.array([tau[0], f_boom, f_stick, f_bucket]))
        inertia = ph.swing_inertia()
        closed = np.abs([u_swing, u_boom, u_stick, u_bucket]) < p.SPOOL_DEAD_BAND
        # Step 3 for the swing: the model integrates its own rate from the table's acceleration
        # (the table sees that rate); the servo makes the upper structure follow it
        rate = self._swing_rate_target
        q = {
            "swing_spool_m": u_swing, "boom_spool_m": u_boom, "stick_spool_m": u_stick, "bucket_spool_m": u_bucket,
            "boom_force_n": f_boom, "stick_force_n": f_stick, "bucket_force_n": f_bucket,
            "swing_inertia_kgm2": inertia, "swing_rate_radps": rate,
        }  # fmt: skip

        def table(name: str) -> float:  # the table at its schema inputs
            return self.tables[name](tuple(q[i] for i in self._schema[name].inputs))

        # a spool in its dead band blocks its cylinder's ports: the cylinder holds (no table noise)
        v_boom = 0.0 if closed[1] else table("boom")
        v_bucket = 0.0 if closed[3] else table("bucket")
        v_stick = 0.0 if closed[2] else table("stick")
        self._swing_acceleration = table("swing")
        new_rate, self._swing_acceleration = next_swing_rate(
            rate, self._swing_acceleration, self.control_period, closed[0], self._slowest_swing, self._fastest_swing
        )
        targets = np.array([new_rate, v_boom / arms[0], v_stick / arms[1], v_bucket / arms[2]])
        targets[self.blocked_by_contact(targets)] = 0.0
        self._swing_rate_target = targets[0]
        ph.set_actuator_targets(targets)
        self.physics.step(self._substeps)

    def blocked_by_contact(self, rates: np.ndarray) -> np.ndarray:
        """Which joints' ``rates`` would drive the machine further into a contact (ground, truck).

        Hydraulics cannot push through the ground or a truck (the reaction exceeds any relief), so
        a joint whose rate would move a contact point of the machine along the contact normal into
        the other body stalls. The lean machine's contacts are detected but inactive (hexgym/machine/mjcf.py:
        solved against its stiff velocity servos they would kick the links), so this stall is what
        keeps the machine out of the ground and the truck: it stops within one step of touching.
        """
        m, d = self.physics.model, self.physics.data
        blocked = np.zeros(4, dtype=bool)
        for i in range(d.ncon):
            c = d.contact[i]
            if c.dist >= 0.0:
                continue  # not touching
            b1, b2 = m.geom_bodyid[c.geom1], m.geom_bodyid[c.geom2]
            mine1, mine2 = self._machine_body[b1], self._machine_body[b2]
            if mine1 == mine2:
                continue
            body, sign = (b1, 1.0) if mine1 else (b2, -1.0)  # the normal points from geom1 to geom2
            mujoco.mj_jac(m, d, self._jacp, None, c.pos, body)
            approach = sign * (c.frame[:3] @ self._jacp[:, self._dofs])  # normal speed per unit joint rate
            blocked |= approach * rates > 0.0
        return blocked


def _ancestors(model: mujoco.MjModel, body: int) -> set[int]:
    """``body`` and the bodies it hangs from, up to the world."""
    out = {body}
    while body:
        body = int(model.body_parentid[body])
        out.add(body)
    return out

"""The reference model: the analytical hydraulic circuit driving the MuJoCo linkage.

This is the paper's "slow but complete analytical machine model" (Sec II), the stand-in for the
real machine and the source of the learned tables' training data. Every MuJoCo step:

1. the circuit advances over the step at the present cylinder extensions and velocities and
   swing rate (linearly implicit Euler, see :mod:`hexgym.hydraulics.circuit`), and reports how its end
   pressures move with those velocities;
2. the end pressures give the cylinder forces and the swing motor torque, which become joint
   torques through the moment arms (the paper's Eqn 5) in a force-actuated copy of the model,
   handed to MuJoCo as ``ctrl + bias * qd`` (affine actuators) so that its ``implicitfast``
   integrator treats the hydraulic stiffness and damping implicitly; MuJoCo advances the
   linkage (gravity, payload, tip forces, joint limits);
3. the circuit's end state is corrected with the velocities MuJoCo reached.

The hydraulic spring-mass modes of the linkage and the orifice damping are stiff; the linearly
implicit coupling is a margin for them: on the replay below an explicit coupling (forces from
the pressures at the start of the step) measured the same at 2 ms and was still stable at 8 ms,
where the implicit one has a quarter less tip error.

``DEFAULT_TIMESTEP`` (2 ms, the model's step) was chosen by measurement on a 9 s replay that
moves every function, stalls the boom, stick and bucket at their ends and dumps the bucket
against 0.125 ms steps: tip error max 2.4 cm, mean 5 mm, pump pressure mean error 0.15 MPa,
at about 0.4 s of computing per simulated second (1 ms: 1.9 cm / 3 mm at 0.7 s/s; 4 ms:
9 cm / 3 cm at 0.17 s/s).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from hexgym.hydraulics.circuit import DEFAULT_VALVE, NODES, HydraulicCircuit, fuel_rate, validate_spools, valve_layout
from hexgym.hydraulics.overrides import HydraulicsOverrides, overridden_circuit
from hexgym.machine import kinematics, trajectory
from hexgym.machine import parameters as p
from hexgym.machine.physics import ExcavatorPhysics, force_actuated_model

DEFAULT_TIMESTEP = 0.002  # s, MuJoCo and hydraulics alike (see the module docstring)
_CHAMBERS = NODES[4:]  # boom_head ... swing_b
# the common columns, then the circuit's pumps, power and fuel, chamber pressures, swing torque and brake power
TRAJECTORY_COLUMNS = (
    trajectory.COMMON_COLUMNS
    + trajectory.PUMP_COLUMNS
    + trajectory.POWER_COLUMNS
    + tuple(f"{n}_pressure_pa" for n in _CHAMBERS)
    + ("swing_torque_nm", "brake_power_w")
)
TRAJECTORY_DTYPE = trajectory.row_dtype(TRAJECTORY_COLUMNS)


@dataclass
class _Mechanics:
    ext: np.ndarray  # cylinder extensions, m
    vel: np.ndarray  # cylinder velocities, m/s
    swing_rate: float  # rad/s
    arms: np.ndarray  # moment arms dC/dq, m/rad


class ReferenceModel:
    """MuJoCo linkage + analytical open-centre circuit, stepped together at a fixed step.

    Args:
        model: a compiled force-actuated model (:func:`hexgym.machine.physics.force_actuated_model`);
            default the packaged machine converted to force inputs.
        timestep: the common step (s); sets the model copy's ``opt.timestep``.
        valve: the main valve's layout (:data:`hexgym.hydraulics.circuit.VALVE_LAYOUTS`): ``"cat"`` (default), a
            Cat two-pump valve (flow combining, swing and boom priority, stick and boom regeneration), or
            ``"paper"``, the paper's simplified schematic (pump 1 boom and bucket, pump 2 swing and stick).
        hydraulics: a unit that is not the packaged one (:mod:`hexgym.hydraulics.overrides`: its overrides, a
            hydraulics file's path or content); default the packaged circuit.
    """

    def __init__(
        self,
        model: mujoco.MjModel | None = None,
        timestep: float = DEFAULT_TIMESTEP,
        valve: str = DEFAULT_VALVE,
        hydraulics: HydraulicsOverrides | Mapping | str | Path | None = None,
    ) -> None:
        if not (np.isfinite(timestep) and 0.0 < timestep <= 0.005):
            raise ValueError(f"timestep must be in (0, 5 ms], got {timestep} s")
        layout = valve_layout(valve)
        model = force_actuated_model() if model is None else model
        model.opt.timestep = timestep
        model.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST  # uses d(tau)/d(qd) below
        model.actuator_biastype[:] = mujoco.mjtBias.mjBIAS_AFFINE  # tau = ctrl + biasprm[2] qd
        model.actuator_biasprm[:] = 0.0
        self.physics = ExcavatorPhysics(model)
        self._ctrl, self._bias = self.physics.data.ctrl, model.actuator_biasprm[:, 2]
        self.circuit = HydraulicCircuit(layout=layout) if hydraulics is None else overridden_circuit(hydraulics, layout)
        self.spools_m = np.zeros(len(kinematics.JOINTS))
        self.state = self.circuit.initial_state()
        self.reset()

    @property
    def timestep(self) -> float:
        """The common MuJoCo / hydraulics step, s."""
        return self.physics.timestep

    @property
    def control_period(self) -> float:
        """Seconds one :meth:`step` advances: one MuJoCo / hydraulics step."""
        return self.physics.timestep

    def reset(self, start: str | np.ndarray = "home", payload_kg: float = 0.0) -> None:
        """Start at a keyframe name or joint angles (rad), at rest, loads held, spools neutral."""
        self.physics.start_at(start, payload_kg)
        self.physics.set_joint_state(self.physics.joint_positions(), np.zeros(4))
        self.spools_m = np.zeros(len(kinematics.JOINTS))
        self.state = self.circuit.initial_state(self.holding_forces())
        self._mech = self._mechanics()

    def holding_forces(self) -> np.ndarray:
        """Cylinder forces (N) that hold the present pose against gravity: dU/dq / (dC/dq)."""
        q0 = self.physics.joint_positions()
        arms = self.physics.moment_arms()
        forces = np.zeros(3)
        eps = 1e-5
        for i in range(3):
            dq = np.zeros(4)
            dq[i + 1] = eps
            forces[i] = (self._potential(q0 + dq) - self._potential(q0 - dq)) / (2 * eps) / arms[i]
        self.physics.set_joint_state(q0)
        return forces

    def _potential(self, q: np.ndarray) -> float:
        self.physics.set_joint_state(q)
        m, d = self.physics.model, self.physics.data
        return float(p.GRAVITY * m.body_mass @ d.xipos[:, 2])

    def _mechanics(self) -> _Mechanics:
        ph = self.physics
        arms, rates = ph.moment_arms(), ph.joint_velocities()  # the arms once: they cost most here
        return _Mechanics(ph.cylinder_extensions(), arms * rates[1:], float(rates[0]), arms)

    def step(self, spools_m: np.ndarray, n: int = 1) -> None:
        """Advance ``n`` steps with the spools (m, order swing, boom, stick, bucket) held."""
        self.spools_m = validate_spools(spools_m).copy()
        for _ in range(n):
            self._step_once()

    def _step_once(self) -> None:
        # 1. the circuit over the step at the present velocities, and its sensitivity to them
        mech, dt = self._mech, self.timestep
        predicted, sens = self.circuit.step_with_sensitivity(
            self.state, dt, self.spools_m, mech.ext, mech.vel, mech.swing_rate
        )
        # 2. joint torques affine in the joint rates: tau = ctrl + bias * qd, which MuJoCo's
        #    implicit integrator treats implicitly (the hydraulic spring and damping are stiff)
        forces, torque = self.circuit.actuator_forces(
            predicted, mech.ext, mech.vel, mech.swing_rate, end_stops=False
        )  # MuJoCo's joint and slide limits are the end stops; the circuit adds the cushions
        dforce, dtorque = self.circuit.coupling_derivatives(sens, mech.vel, mech.swing_rate)
        arms = mech.arms
        self._bias[0], self._bias[1:] = dtorque, dforce * arms**2
        self._ctrl[0] = torque - dtorque * mech.swing_rate
        self._ctrl[1:] = arms * (forces - dforce * mech.vel)
        self.physics.step()
        # 3. the circuit's end state follows the velocities the linkage reached
        new = self._mechanics()
        dv = np.append(new.vel - mech.vel, new.swing_rate - mech.swing_rate)
        self.state = predicted + sens @ dv
        self._mech = new

    def fuel_rate_l_per_h(self) -> float:
        """The engine's fuel rate (L/h) now: its brake power for the pumps' pressures times flows (and the
        accessories) through the BSFC map, as :meth:`observe` reports it."""
        return fuel_rate(self.circuit.pump_power(self.state)[2])

    def joint_torques(self) -> np.ndarray:
        """The torques (N m) the circuit's present pressures put on the main joints [swing, boom, stick,
        bucket]: the swing motor's, and each cylinder's force times its moment arm."""
        mech = self._mech
        forces, torque = self.circuit.actuator_forces(self.state, mech.ext, mech.vel, mech.swing_rate, end_stops=False)
        return np.concatenate(([torque], mech.arms * forces))

    def observe(self) -> np.ndarray:
        """One trajectory row (a record of ``TRAJECTORY_DTYPE``) of the present state."""
        ph, mech = self.physics, self._mech
        out = self.circuit.outputs(self.state, self.spools_m, mech.ext, mech.vel, mech.swing_rate)
        forces, torque = self.circuit.actuator_forces(self.state, mech.ext, mech.vel, mech.swing_rate, end_stops=False)
        values = (
            [ph.time, *ph.joint_positions(), *ph.joint_velocities(), *ph.tip_position()]
            + [*(self.spools_m * 1e3), *mech.ext, *mech.vel, *forces, ph.swing_inertia()]
            + [out[k] for k in trajectory.PUMP_COLUMNS + trajectory.POWER_COLUMNS]
            + [out[f"{n}_pressure_pa"] for n in _CHAMBERS]
            + [torque, out["brake_power_w"]]
        )
        return np.array(tuple(values), dtype=TRAJECTORY_DTYPE)

"""The circuit model: the open-centre circuit's structure with a learned valve, on the lean machine.

The table models (:mod:`hexgym.model.python_backend`) map spools and loads to velocities with no
circuit state, so they cannot see how the functions share the pumps' flow and power over time: the
swing line's pressure, the pump lines' oil, a cavitated chamber refilling. This model keeps that state
and learns only what a real machine's data sheet does not give, the control valve's passage areas
(:mod:`hexgym.mbl.valve`, the ``circuit`` tables). Everything else is the machine's data
(:mod:`hexgym.machine.parameters`): the pumps' regulator law, reliefs, cylinder and motor sizes, line
volumes, the oil's bulk modulus.

Every control period (one 25 ms step of the lean machine), ``SUBSTEPS`` times:

1. the circuit (:class:`hexgym.hydraulics.circuit.HydraulicCircuit` with the learned valve) advances
   its 14 states (12 pressures, 2 pump displacements) at the present joint rates, and gives the
   pressures' sensitivity to those rates;
2. the main joints' rates follow ``M dw/dt = tau_oil(w) - tau_load``: ``M`` the lean machine's mass
   matrix of the four main joints and ``tau_load`` the torque that holds the present motion (gravity,
   velocity terms, joint damping, any tip force; :meth:`LearnedModel.joint_loads`), both from the
   period's start; the oil's torques are linearised in the rates (the circuit's sensitivity) and the
   step is implicit in them, so the stiff oil springs stay stable at this step;
3. a cylinder reaching a stroke end meets its stop's spring-damper, implicit in the rates like the oil, and its
   impulse reaches the other joints through ``M`` over the stop's time; a step in which a cylinder runs into its
   stop is split (the kick's chambers near vacuum need the finer steps).

The lean machine's stiff rate servos then move the joints by the period's mean rates (so MuJoCo's
positions follow the circuit's); the rates at the period's end stay the model's state.

The period's circuit steps run natively (:class:`hexgym.model.circuit_kernel.NativeCircuit`: the C++ kernel the
``hexgym.mbl`` plugin runs, called through ``ctypes``); ``_control_period_numpy`` runs the same steps through
:class:`HydraulicCircuit`'s numpy methods, the definition the kernel is tested against, and the fallback (several
times slower, said once per process) where the plugin library was not built. The native plugin runs this whole
period inside ``mj_step`` (:class:`hexgym.model.native_backend.NativeLearnedModel` with a circuit table set's
tables); either runs any valve layout (:data:`hexgym.hydraulics.circuit.VALVE_LAYOUTS`), taken as data.
"""

from __future__ import annotations

import warnings

import mujoco
import numpy as np

from hexgym.hydraulics.circuit import STATE_NAMES, STATE_SIZE, HydraulicCircuit, fuel_rate, valve_layout
from hexgym.hydraulics.overrides import HydraulicsOverrides, OverriddenCircuit
from hexgym.machine import parameters as p
from hexgym.machine import trajectory
from hexgym.mbl.schema import CIRCUIT_TABLE_SETS, VALVE_OF_TABLE_SET
from hexgym.mbl.table import MBLTable
from hexgym.mbl.valve import LearnedValve
from hexgym.model import circuit_kernel
from hexgym.model.base import LEARNED_DTYPE
from hexgym.model.circuit_kernel import STOP_SPLIT, STOP_SPLIT_SPEED
from hexgym.model.python_backend import LearnedModel

STOP_CLEARANCE = 1e-3  # m: the circuit's stroke ends, inside MuJoCo's joint limits (which would kick the servos)
MAX_RATE = 10.0  # rad/s: the servos' range here, far beyond any joint's
SUBSTEPS = 5  # circuit steps per 25 ms period (5 ms): 3.1 ms steps moved the selection logs by < 0.02 m
# a period whose end is no state of the machine (a pressure beyond ten reliefs, or not finite) is run again from its
# start in steps REFINE times shorter, up to MAX_REFINE (kRefine, kMaxRefine in native/circuit.h): the scripted loader
# with searched settings diverged at 9.9 s on seed 100 in 5 ms steps, not in 0.6 ms ones
REFINE, MAX_REFINE = 8, 64

# a row: the learned models' columns, and the pumps' power and the fuel rate as the reference reports them
CIRCUIT_DTYPE = trajectory.row_dtype(LEARNED_DTYPE.names + trajectory.PUMP_COLUMNS + trajectory.POWER_COLUMNS)


class CircuitModel(LearnedModel):
    """The lean MuJoCo machine driven by the open-centre circuit with the learned valve (its steps compiled).

    Args:
        tables: the valve's tables (default: the packaged ``circuit`` ones).
        model, control_period: as :class:`~hexgym.model.python_backend.LearnedModel`.
        substeps: circuit steps per control period.
        table_set: which valve the tables are of (:data:`hexgym.mbl.schema.CIRCUIT_TABLE_SETS`): ``circuit``, the
            reference machine's Cat two-pump valve.
        hydraulics: a unit's pumps (:func:`hexgym.mbl.table.model_hydraulics`, a model fitted to its logs); default
            the data sheet's.
    """

    def __init__(
        self,
        tables: dict[str, MBLTable] | None = None,
        model: mujoco.MjModel | None = None,
        control_period: float | None = None,
        substeps: int = SUBSTEPS,
        table_set: str = "circuit",
        hydraulics: HydraulicsOverrides | None = None,
    ) -> None:
        if table_set not in CIRCUIT_TABLE_SETS:
            raise ValueError(f"the circuit model runs the table sets {CIRCUIT_TABLE_SETS}, not {table_set!r}")
        if tables is None:
            from hexgym.mbl.table import load_tables

            tables = load_tables(table_set=table_set)
        if not isinstance(substeps, int) or substeps < 1:
            raise ValueError(f"substeps must be a whole number >= 1, got {substeps!r}")
        self._init_machine(model, control_period)
        # the servos follow the circuit's rates; their ranges (the table models' limits) would clip a
        # swing that the pump drives faster with the front pulled in
        self.physics.model.actuator_ctrlrange[:] = (-MAX_RATE, MAX_RATE)
        self.tables, self.table_set = tables, table_set
        layout = valve_layout(VALVE_OF_TABLE_SET[table_set])
        valve = LearnedValve(tables, layout)
        self.circuit = (
            HydraulicCircuit(valve=valve, layout=layout)
            if hydraulics is None
            else OverriddenCircuit(hydraulics, layout, valve=valve)
        )
        self._kernel = _native_kernel(self.circuit, tables)
        self._fault_pressure = circuit_kernel.fault_pressure(self.circuit)
        if self._kernel is None:
            self._control_period = self._control_period_numpy
        nv = self.physics.model.nv
        self._mass_index = self._dofs[:, None] * nv + self._dofs[None, :]  # the main joints' block of M, flat
        self.substeps = substeps
        self.state = self.circuit.initial_state()
        self.rates = np.zeros(4)  # the main joints' rates, rad/s: the model's mechanical state

    def reset(self, start: str | np.ndarray = "home", payload_kg: float = 0.0) -> None:
        """Start at a keyframe name or joint angles (rad), at rest, loads held, spools neutral."""
        super().reset(start, payload_kg)
        holding = self.joint_loads()[1:] / self.physics.moment_arms()
        self.state = self.circuit.initial_state(holding)
        self.rates = np.zeros(4)

    def observe(self) -> np.ndarray:
        """One trajectory row (``CIRCUIT_DTYPE``): the learned models' columns, then the pumps' pressures and flows,
        their power and the fuel rate (L/h), as :class:`~hexgym.hydraulics.reference.ReferenceModel` reports them."""
        return circuit_row(super().observe(), self.circuit, self.state)

    def _control_period(self) -> None:
        arms, mass, load = self._period_start()
        h = self.control_period / self.substeps
        ext = self.physics.cylinder_extensions()
        state, rates, _, travel, splits = self._kernel.control_period(
            self.spools_m, self.state, self.rates, ext, arms, mass, load, h, self.substeps
        )
        check_state(state, self._fault_pressure)
        self.state = state
        self.circuit.split_count += splits
        self._end_period(travel, rates)

    def _control_period_numpy(self) -> None:
        """:meth:`_control_period` through :class:`HydraulicCircuit`'s numpy methods, one :meth:`_substep` at a time
        (the definition the native kernel is tested against, and its fallback)."""
        arms, mass, load = self._period_start()
        start = self.state.copy()
        refine = 1
        while True:  # a diverged period again from its start in shorter steps, as the kernel does (REFINE)
            rates, ext = self.rates, self.physics.cylinder_extensions().copy()
            h = self.control_period / (self.substeps * refine)
            travel = np.zeros(4)
            for _ in range(self.substeps * refine):
                rates, ext = self._substep(h, rates, ext, arms, mass, load)
                travel += rates * h
            if refine >= MAX_REFINE or not _diverged(self.state, rates, travel, self._fault_pressure):
                break
            self.state, refine = start.copy(), refine * REFINE
        self._end_period(travel, rates)

    def _period_start(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The cylinders' moment arms, the main joints' mass matrix (4, 4) and their loads at the period's start."""
        ph = self.physics
        m, d = ph.model, ph.data
        arms = ph.moment_arms()
        load = self.joint_loads()
        full = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, full)
        return arms, full.take(self._mass_index), load

    def _end_period(self, travel: np.ndarray, rates: np.ndarray) -> None:
        """Move MuJoCo's machine as far as the circuit's joints went (their mean rate over the period) and keep
        the rates at its end as the model's state; a joint blocked by a contact stops."""
        targets = travel / self.control_period
        blocked = self.blocked_by_contact(targets)
        targets[blocked], rates[blocked] = 0.0, 0.0
        self.rates = rates
        self.physics.set_actuator_targets(targets)
        self.physics.step(self._substeps)

    def _substep(
        self, h: float, rates: np.ndarray, ext: np.ndarray, arms: np.ndarray, mass: np.ndarray, load: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """One circuit step of ``h`` s with the joints' rates implicit in the oil's torques: the new
        joint rates (swing, boom, stick, bucket) and cylinder extensions; the circuit state advances.

        A cylinder that runs into its stop within the step faster than ``STOP_SPLIT_SPEED`` splits it into
        ``STOP_SPLIT`` steps: the stop's kick drives the other cylinders' chambers towards vacuum and their make-up
        valves open, which a 5 ms linearised step does not follow (see :meth:`_joint_step`)."""
        vel = arms * rates[1:]
        reach = ext + vel * h
        lo, hi = STOP_CLEARANCE, self.circuit.stroke - STOP_CLEARANCE
        if (((reach > hi) & (vel > STOP_SPLIT_SPEED)) | ((reach < lo) & (vel < -STOP_SPLIT_SPEED))).any():
            for _ in range(STOP_SPLIT):
                rates, ext = self._joint_step(h / STOP_SPLIT, rates, ext, arms, mass, load)
            return rates, ext
        return self._joint_step(h, rates, ext, arms, mass, load)

    def _joint_step(
        self, h: float, rates: np.ndarray, ext: np.ndarray, arms: np.ndarray, mass: np.ndarray, load: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_substep`'s one circuit step. A cylinder that would pass its stop (``STOP_CLEARANCE`` inside its
        stroke) meets the stop's spring-damper (``CYLINDER_STOP_STIFFNESS``, ``CYLINDER_STOP_DAMPING`` per cylinder),
        implicit in the joint rates like the oil, so its impulse reaches the other joints through ``M`` over the
        stop's time, as the reference's joint limit hands it over, not within one step."""
        vel = arms * rates[1:]
        predicted, sens = self.circuit.step_with_sensitivity(self.state, h, self.spools_m, ext, vel, rates[0])
        forces, torque = self.circuit.actuator_forces(predicted, ext, vel, rates[0], end_stops=False)
        dforce, dtorque = self.circuit.coupling_derivatives(sens, vel, rates[0])
        oil = np.concatenate(([torque], forces * arms))
        lhs = mass - h * np.diag(np.concatenate(([dtorque], dforce * arms**2)))
        rhs = h * (oil - load)
        new = rates + np.linalg.solve(lhs, rhs)
        lo, hi = STOP_CLEARANCE, self.circuit.stroke - STOP_CLEARANCE
        reach = ext + arms * new[1:] * h
        up, down = reach > hi, reach < lo
        if (up | down).any():  # the stops' springs, implicit: force -K (ext + h v - end) - D v at the step's end
            count = self.circuit.cylinder_count * (up | down)
            stiff, damp = count * p.CYLINDER_STOP_STIFFNESS, count * p.CYLINDER_STOP_DAMPING
            gain = (h * stiff + damp) * arms**2
            lhs = lhs + h * np.diag(np.concatenate(([0.0], gain)))
            push = stiff * arms * (ext - np.where(up, hi, lo)) + gain * rates[1:]
            new = rates + np.linalg.solve(lhs, rhs - h * np.concatenate(([0.0], push)))
        new_ext = ext + arms * new[1:] * h
        dv = np.append(arms * (new[1:] - rates[1:]), new[0] - rates[0])
        self.state = predicted + sens @ dv  # the pressures follow the rates the step reached
        return new, new_ext


_fallback_said = False


def circuit_row(row: np.ndarray, circuit: HydraulicCircuit, state: np.ndarray) -> np.ndarray:
    """A learned model's trajectory ``row`` with what the circuit ``state`` adds (``CIRCUIT_DTYPE``)."""
    flows, hydraulic, brake = circuit.pump_power(state)
    pumps = (state[0], state[1], flows[0], flows[1])
    return np.array((*row.tolist(), *pumps, hydraulic, fuel_rate(brake)), dtype=CIRCUIT_DTYPE)


def _diverged(state: np.ndarray, rates: np.ndarray, travel: np.ndarray, fault_pressure: float) -> bool:
    """Whether a period's end is no state of the machine (``Diverged`` in native/circuit.cc)."""
    finite = np.isfinite(state).all() and np.isfinite(rates).all() and np.isfinite(travel).all()
    return not finite or float(np.abs(state[: STATE_SIZE - 2]).max()) > fault_pressure


def check_state(state: np.ndarray, fault_pressure: float) -> None:
    """Raise ValueError unless ``state`` is finite with every pressure within ``fault_pressure`` (Pa)."""
    if not np.isfinite(state.sum()):
        raise ValueError(f"hydraulic state must be {STATE_SIZE} finite numbers ({STATE_NAMES})")
    worst = float(np.abs(state[: STATE_SIZE - 2]).max())
    if worst > fault_pressure:
        raise ValueError(
            f"hydraulic state diverged: a pressure of {worst / 1e6:.0f} MPa, beyond {fault_pressure / 1e6:.0f} MPa"
            " (ten times the highest relief)"
        )


def _native_kernel(circuit: HydraulicCircuit, tables: dict[str, MBLTable]) -> circuit_kernel.NativeCircuit | None:
    """The native kernel for this circuit and valve, or None where the library cannot be used (said once per
    process: the model then runs the definition's numpy steps, several times slower)."""
    global _fallback_said
    reason = circuit_kernel.native_reason()
    if not reason:
        return circuit_kernel.NativeCircuit(circuit, tables, STOP_CLEARANCE)
    if not _fallback_said:
        _fallback_said = True
        warnings.warn(f"hexgym: {reason}; the circuit model runs its numpy definition", RuntimeWarning, stacklevel=3)
    return None

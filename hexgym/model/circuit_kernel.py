"""The circuit model's control period, native: the C++ kernel the ``hexgym.mbl`` plugin runs, called from Python.

``native/circuit.cc`` runs what :class:`hexgym.model.circuit_model.CircuitModel` does in one control period: the
valve's passage areas from a circuit table set's tables (:class:`hexgym.mbl.valve.LearnedValve`'s rules), then
``substeps`` steps of the circuit (:class:`hexgym.hydraulics.circuit.HydraulicCircuit`: branch flows and
conductances, pumps, compliance, the linearly implicit Euler step with its splitting and velocity sensitivity)
coupled implicitly to the joints' ``M dw/dt = tau_oil - tau_load``, with the stroke ends holding their joints.
:mod:`hexgym.hydraulics.circuit` stays the definition (it makes the training data); the tests hold the two to
rounding (the law's derivatives to 1e-9 relative, tip paths within 1 mm).

The circuit is data to the kernel: :func:`circuit_numbers` packs the circuit's nodes, branches (a valve opened by
another node's pressure among them), its valve layout (any :class:`~hexgym.hydraulics.circuit.ValveLayout`: the
sections with their functions, pumps, tables and branches, each pump's bypass series, priority valves and
regeneration passages), pumps, cylinders, swing motor and scalar laws in the layout :mod:`hexgym.model.plugin`
defines (``CIRCUIT_COUNTS``, ``CIRCUIT_FIELDS``, ``CIRCUIT_LAWS``), the numbers the plugin reads from its
``circuit`` config key and :class:`NativeCircuit` hands the library through ``ctypes``. A change of the circuit's
structure is a change of :class:`HydraulicCircuit` only.
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np

from hexgym.hydraulics.circuit import (
    _SQRT_2_RHO,
    _VACUUM,
    CYLINDER_NAMES,
    DEFAULT_LAYOUT,
    FUNCTIONS,
    N_NODES,
    NODES,
    PASSAGES,
    REGENERATION,
    REST_PRESSURE,
    STATE_SIZE,
    SWING_DISPLACEMENT_RAD,
    TRUST_FLOOR_PA,
    TRUST_JUMP_PA,
    HydraulicCircuit,
    ValveLayout,
    priority_shares,
)
from hexgym.machine import parameters as p
from hexgym.mbl.schema import VALVE_PASSAGES, valve_tables
from hexgym.mbl.table import MBLTable
from hexgym.mbl.valve import CLOSED_AREA
from hexgym.model.plugin import (
    CIRCUIT_COUNTS,
    CIRCUIT_FIELDS,
    CIRCUIT_LAWS,
    NUM_CYLINDERS,
    NUM_PUMPS,
    PERIOD,
    PERIOD_SIZE,
    load_plugin,
    plugin_library,
)

# A circuit step in which a cylinder runs into its stop faster than STOP_SPLIT_SPEED (m/s) is split into STOP_SPLIT
# steps (hexgym.model.circuit_model.CircuitModel._substep): at 5 ms steps the stop's kick on the stick left the
# bucket's cylinder 14-41 mm from the reference's (its chambers near vacuum, their make-up valves), split into
# 1 ms steps within 2.5 mm; holding a cylinder at its stop (slower) does not split
STOP_SPLIT = 5
_STICK = FUNCTIONS.index("stick")
STOP_SPLIT_SPEED = 0.02


def pump_max_flow(circuit: HydraulicCircuit) -> float:
    """Each pump's maximum flow (m^3/s) in ``circuit``: a unit's (its overrides') or the data sheet's."""
    overrides = getattr(circuit, "overrides", None)
    flow = getattr(overrides, "max_flow_m3s", None)
    return p.PUMP_MAX_FLOW if flow is None else float(flow)


def pump_power_limit(circuit: HydraulicCircuit) -> float:
    """The pumps' power limit (W, p1 Q1 + p2 Q2) in ``circuit``: a unit's (its overrides') or the data sheet's."""
    overrides = getattr(circuit, "overrides", None)
    limit = getattr(overrides, "power_limit_w", None)
    return p.PUMP_POWER_LIMIT if limit is None else float(limit)


def circuit_laws(circuit: HydraulicCircuit, stop_clearance: float) -> dict[str, float]:
    """The circuit's scalar laws by :data:`~hexgym.model.plugin.CIRCUIT_LAWS` name (machine parameters and what
    :mod:`hexgym.hydraulics.circuit` derives from them)."""
    return {
        "discharge": p.DISCHARGE_COEFFICIENT,
        "sqrt_2_rho": _SQRT_2_RHO,
        "laminar_sq": p.ORIFICE_LAMINAR_PRESSURE**2,
        "atmosphere": p.ATMOSPHERIC_PRESSURE,
        "vacuum": _VACUUM,
        "polytropic": p.AIR_POLYTROPIC_EXPONENT,
        "air_fraction": p.OIL_AIR_FRACTION,
        "bulk_modulus": p.OIL_BULK_MODULUS,
        "cushion_length": p.CUSHION_LENGTH,
        "cushion_area": p.CUSHION_AREA,
        "cushion_port_area": p.CUSHION_PORT_AREA,
        "nfc_full_flow": p.NFC_PRESSURE_FULL_FLOW,
        "nfc_min_flow": p.NFC_PRESSURE_MIN_FLOW,
        "idle_fraction": p.PUMP_IDLE_FLOW_FRACTION,
        "power_limit": pump_power_limit(circuit),
        "max_flow": pump_max_flow(circuit),
        "regulator_time": p.PUMP_REGULATOR_TIME_CONSTANT,
        "max_splits": circuit.MAX_SPLITS,
        "trust_floor": TRUST_FLOOR_PA,
        "trust_jump": TRUST_JUMP_PA,
        "coulomb": p.CYLINDER_COULOMB_FRICTION,
        "friction_velocity": p.CYLINDER_FRICTION_VELOCITY,
        "viscous": p.CYLINDER_VISCOUS_FRICTION,
        "swing_reduction": p.SWING_REDUCTION,
        "swing_displacement": SWING_DISPLACEMENT_RAD,
        "swing_viscous": p.SWING_MOTOR_VISCOUS_FRICTION,
        "swing_efficiency": p.SWING_MECHANICAL_EFFICIENCY,
        "swing_friction_speed": p.SWING_FRICTION_SPEED,
        "swing_a": NODES.index("swing_a"),
        "swing_b": NODES.index("swing_b"),
        "stop_clearance": stop_clearance,
        "stop_stiffness": p.CYLINDER_STOP_STIFFNESS,
        "stop_damping": p.CYLINDER_STOP_DAMPING,
        "stop_split": STOP_SPLIT,
        "stop_split_speed": STOP_SPLIT_SPEED,
        "dead_band": p.SPOOL_DEAD_BAND,
        "spool_stroke": p.SPOOL_STROKE,
        "metering_exponent": p.METERING_EXPONENT,
        "closed_area": CLOSED_AREA,
        "idle_pressure": p.NFC_PRESSURE_IDLE,
        "rest_pressure": REST_PRESSURE,
        "fault_pressure": fault_pressure(circuit),
    }


FAULT_FACTOR = 10.0  # a pressure this many times the highest relief's setting is no state of the machine


def fault_pressure(circuit: HydraulicCircuit) -> float:
    """Pa beyond which a node's pressure means the circuit's state diverged: :data:`FAULT_FACTOR` times the highest
    cracking pressure of its pressure-operated valves (the reliefs)."""
    return FAULT_FACTOR * float(np.max(circuit.branches.crack))


def circuit_fields(circuit: HydraulicCircuit, stop_clearance: float) -> dict[str, np.ndarray]:
    """Every field of :data:`~hexgym.model.plugin.CIRCUIT_FIELDS` of ``circuit``, as an array of its shape.

    The valve is its layout's sections (function, pump, the tables and branches of the passages it has, a priority
    valve on its meter-in: :func:`hexgym.hydraulics.circuit.priority_shares`'s, the data sheet's), each pump's bypass
    the series of its sections' in layout order, and its regeneration passages (a table's, or the stick unloading
    valve's data-sheet area metered by the spool; that valve's opening piloted by the stick head's pressure,
    ``branch_pilot``), each through its cylinder end's cushion. Table indices are into :func:`valve_table_names` of
    the layout; a section moves only to the sides it has passages on
    (:func:`hexgym.hydraulics.circuit.section_spools`), which the kernel reads from its tables."""
    layout = circuit.layout
    br, groups = circuit.branches, circuit.branch_groups
    crack, inv_span = np.zeros(len(br.names)), np.zeros(len(br.names))
    pilot = np.full(len(br.names), -1)
    crack[br.valve], inv_span[br.valve], pilot[br.valve] = br.crack, br.inv_span, br.pilot
    node_volume = circuit.volumes(np.zeros(NUM_CYLINDERS))
    node_volume[circuit.head_nodes] = node_volume[circuit.rod_nodes] = 0.0  # the chambers' follow the pistons
    laws = circuit_laws(circuit, stop_clearance)
    table = {name: i for i, name in enumerate(valve_table_names(layout))}
    n = len(layout.sections)
    section_table, section_branch = np.full((n, len(VALVE_PASSAGES)), -1), np.full((n, len(PASSAGES)), -1)
    for i, section in enumerate(layout.sections):
        for j, key in enumerate(VALVE_PASSAGES):
            section_table[i, j] = table.get(f"{section.name}_{key}", -1)
    for j, key in enumerate(PASSAGES):
        section_branch[groups[f"{key}_section"], j] = groups[key]
    return {
        "laws": np.array([laws[name] for name in CIRCUIT_LAWS], dtype=float),
        "branch_from": br.frm,
        "branch_to": br.to,
        "branch_area": br.area,
        "branch_crack": crack,
        "branch_inv_span": inv_span,
        "branch_laminar": br.laminar,
        "branch_pilot": pilot,
        "section_function": np.array([FUNCTIONS.index(s.function) for s in layout.sections]),
        "section_pump": np.array([s.pump for s in layout.sections]),
        "section_table": section_table,
        "section_branch": section_branch,
        "section_priority": _priorities(layout),
        "regeneration": _regenerations(layout, groups, table),
        "bypass_branch": groups["bypass"],
        "pump_node": np.array([NODES.index("pump1"), NODES.index("pump2")]),
        "signal_node": np.array([NODES.index("bypass1"), NODES.index("bypass2")]),
        "head_area": circuit.head_area,
        "rod_area": circuit.rod_area,
        "stroke": circuit.stroke,
        "cylinder_count": circuit.cylinder_count,
        "port_volume": circuit.port_volumes,
        "head_node": circuit.head_nodes,
        "rod_node": circuit.rod_nodes,
        "function": np.array([FUNCTIONS.index(n) for n in CYLINDER_NAMES]),  # the first sections: one per function
        "node_volume": node_volume,
        "displacement": circuit.displacement,
    }


def _priorities(layout: ValveLayout) -> np.ndarray:
    """Each section's priority valve (piloting function or -1, its spool's side, the share left at full spool), as
    :func:`hexgym.hydraulics.circuit.priority_shares` applies them: the swing's (either way) on stick 1's meter-in,
    the boom raise's on each stick 2 section's."""
    rows = np.array([[-1.0, 0.0, 1.0]] * len(layout.sections))
    if layout.swing_priority:
        rows[_STICK] = (FUNCTIONS.index("swing"), 0, p.SWING_PRIORITY_STICK_SHARE)
    stick2, _, _ = priority_shares(layout, np.zeros(len(FUNCTIONS)))
    if layout.boom_priority:
        rows[stick2] = (FUNCTIONS.index("boom"), 1, p.BOOM_PRIORITY_STICK_SHARE)
    return rows


def _regenerations(layout: ValveLayout, groups: dict[str, np.ndarray], table: dict[str, int]) -> np.ndarray:
    """Each regeneration passage of the layout (:class:`hexgym.mbl.valve.LearnedValve`'s): its branch, the function
    whose spool opens it and on which side, its table (-1 for the stick unloading valve, the data sheet's area), and
    the cylinder end whose cushion its oil leaves through (:meth:`HydraulicCircuit.branch_areas`: stick in, the
    rod's; boom lower, the head's)."""
    rows = []
    for passage in layout.regeneration_passages:
        r = REGENERATION[passage]
        area = 0.0 if r.learned else p.STICK_UNLOADING_AREA  # the one not learned: the stick's unloading valve
        function, cylinder, end = (
            FUNCTIONS.index(r.cylinder),
            CYLINDER_NAMES.index(r.cylinder),
            1 if r.leaves_rod else -1,
        )
        rows.append((groups[passage][0], function, r.side, table.get(passage, -1), area, cylinder, end))
    return np.array(rows, dtype=float).reshape(-1, 7)


def valve_table_names(layout: ValveLayout) -> tuple[str, ...]:
    """The valve's tables in the order the kernel takes them: :func:`hexgym.mbl.schema.valve_tables`' (the plugin's
    table set's order)."""
    return tuple(valve_tables(layout))


def circuit_counts(circuit: HydraulicCircuit) -> dict[str, int]:
    """The counts (:data:`~hexgym.model.plugin.CIRCUIT_COUNTS`) the circuit's numbers start with."""
    layout = circuit.layout
    return {
        "nodes": N_NODES,
        "branches": len(circuit.branches.names),
        "sections": len(layout.sections),
        "regenerations": len(layout.regeneration_passages),
    }


def circuit_numbers(circuit: HydraulicCircuit, stop_clearance: float) -> np.ndarray:
    """The circuit as the kernel reads it: its counts (:data:`~hexgym.model.plugin.CIRCUIT_COUNTS`), then each field
    of :data:`~hexgym.model.plugin.CIRCUIT_FIELDS` in order (C order), as one float64 array."""
    return pack_fields(circuit_fields(circuit, stop_clearance), circuit_counts(circuit))


def pack_fields(fields: dict[str, np.ndarray], counts: dict[str, int]) -> np.ndarray:
    """``fields`` (:func:`circuit_fields`) of a circuit of these ``counts`` (:func:`circuit_counts`), packed."""
    extents = {"one": 1, "pumps": NUM_PUMPS, "functions": len(FUNCTIONS), "cylinders": NUM_CYLINDERS}
    extents |= {name: counts[name] for name in CIRCUIT_COUNTS}
    parts = [np.array([counts[name] for name in CIRCUIT_COUNTS], dtype=float)]
    for name, (rows, per) in CIRCUIT_FIELDS.items():
        value = np.asarray(fields[name], dtype=float)
        if value.size != rows * extents[per]:
            raise ValueError(f"circuit field {name!r} has {value.size} numbers, the layout {rows} x {per}")
        parts.append(value.ravel())
    return np.concatenate(parts)


def valve_arrays(
    tables: dict[str, MBLTable], layout: ValveLayout = DEFAULT_LAYOUT
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The valve's tables (:func:`valve_table_names` order) as the kernel takes them: nodes per table (int32), and
    all tables' nodes and values, concatenated."""
    names = valve_table_names(layout)
    for name in names:
        if name not in tables:
            raise ValueError(f"the circuit model needs the valve table {name!r}")
        if tables[name].values.ndim != 1:
            raise ValueError(f"valve table {name!r} must have one input, got shape {tables[name].values.shape}")
    sizes = np.array([len(tables[n].axes[0]) for n in names], dtype=np.int32)
    nodes = np.concatenate([np.asarray(tables[n].axes[0], dtype=float) for n in names])
    values = np.concatenate([np.asarray(tables[n].values, dtype=float) for n in names])
    return sizes, nodes, values


_DOUBLES = ctypes.POINTER(ctypes.c_double)


@functools.cache
def _library() -> ctypes.CDLL | None:
    """The plugin library with the kernel's functions typed, or None where it cannot be used (see
    :func:`hexgym.model.plugin.load_plugin`)."""
    if load_plugin():
        return None
    lib = ctypes.CDLL(str(plugin_library()))
    lib.hexgym_circuit_new.restype = ctypes.c_void_p
    lib.hexgym_circuit_new.argtypes = [
        _DOUBLES, ctypes.c_int, ctypes.POINTER(ctypes.c_int32), ctypes.c_int, _DOUBLES, _DOUBLES, ctypes.c_char_p,
        ctypes.c_int,
    ]  # fmt: skip
    lib.hexgym_circuit_free.argtypes = [ctypes.c_void_p]
    lib.hexgym_circuit_period.restype = ctypes.c_int
    lib.hexgym_circuit_period.argtypes = [ctypes.c_void_p, _DOUBLES, ctypes.c_double, ctypes.c_int]
    # the period's pieces, for the tests
    lib.hexgym_circuit_areas.argtypes = [ctypes.c_void_p, _DOUBLES, _DOUBLES, _DOUBLES]
    lib.hexgym_circuit_derivatives.argtypes = [ctypes.c_void_p, *[_DOUBLES] * 4, ctypes.c_double, _DOUBLES, _DOUBLES]
    lib.hexgym_circuit_step.restype = ctypes.c_int
    lib.hexgym_circuit_step.argtypes = [ctypes.c_void_p, *[_DOUBLES] * 4, ctypes.c_double, ctypes.c_double, _DOUBLES]
    lib.hexgym_circuit_forces.restype = ctypes.c_double
    lib.hexgym_circuit_forces.argtypes = [ctypes.c_void_p, _DOUBLES, _DOUBLES, ctypes.c_double, _DOUBLES]
    lib.hexgym_circuit_coupling.restype = ctypes.c_double
    lib.hexgym_circuit_coupling.argtypes = [ctypes.c_void_p, _DOUBLES, _DOUBLES, _DOUBLES]
    lib.hexgym_circuit_time.restype = ctypes.c_double
    lib.hexgym_circuit_time.argtypes = [ctypes.c_void_p, _DOUBLES, ctypes.c_double, *[ctypes.c_int] * 3]
    return lib


def _in(values: np.ndarray) -> ctypes._Pointer:
    """A pointer to a float64 copy of ``values`` (kept alive by the pointer's ``_keep``)."""
    array = np.ascontiguousarray(values, dtype=float)
    pointer = array.ctypes.data_as(_DOUBLES)
    pointer._keep = array
    return pointer


def native_reason() -> str:
    """Why the native kernel cannot run in this process ("" when it can)."""
    return load_plugin()


class NativeCircuit:
    """The native kernel for one circuit and valve: :meth:`control_period` as the plugin runs it.

    Raises RuntimeError where the library cannot be used (:func:`native_reason`), ValueError when the library
    refuses the circuit's numbers or the valve's tables (naming what is wrong).
    """

    def __init__(self, circuit: HydraulicCircuit, tables: dict[str, MBLTable], stop_clearance: float) -> None:
        numbers = circuit_numbers(circuit, stop_clearance)
        self._init(numbers, tables, len(circuit.branches.names), circuit.layout)

    def _init(
        self, numbers: np.ndarray, tables: dict[str, MBLTable], branches: int, layout: ValveLayout = DEFAULT_LAYOUT
    ) -> None:
        """A kernel of packed circuit ``numbers`` (:func:`circuit_numbers`) and the valve's tables of ``layout``."""
        lib = _library()
        if lib is None:
            raise RuntimeError(native_reason())
        self._lib, self._recipe = lib, (numbers, tables, branches, layout)
        sizes, nodes, values = valve_arrays(tables, layout)
        error = ctypes.create_string_buffer(512)
        handle = lib.hexgym_circuit_new(
            _in(numbers), numbers.size, sizes.ctypes.data_as(ctypes.POINTER(ctypes.c_int32)), len(sizes),
            _in(nodes), _in(values), error, len(error),
        )  # fmt: skip
        if not handle:
            raise ValueError(f"the native circuit kernel refuses the circuit model: {error.value.decode()}")
        self._handle, self._branches = handle, branches
        self._buffer = np.zeros(PERIOD_SIZE)
        self._pointer = self._buffer.ctypes.data_as(_DOUBLES)

    def __reduce__(self) -> tuple:
        """Pickled as its recipe (the library's handle is per process): a copy builds its own kernel."""
        return (_rebuilt, self._recipe)

    def __del__(self) -> None:
        handle, self._handle = getattr(self, "_handle", None), None
        if handle:
            self._lib.hexgym_circuit_free(handle)

    def control_period(
        self,
        spools: np.ndarray,
        state: np.ndarray,
        rates: np.ndarray,
        ext: np.ndarray,
        arms: np.ndarray,
        mass: np.ndarray,
        load: np.ndarray,
        h: float,
        substeps: int,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
        """``substeps`` circuit steps of ``h`` s at the spools (m), from the circuit ``state``, the joints' ``rates``
        and cylinder extensions ``ext``, with the period's moment arms, the joints' mass matrix (4, 4) and loads:
        the new circuit state, joint rates, cylinder extensions, each joint's travel (rad) and the steps split."""
        b, s = self._buffer, PERIOD
        b[s["spools"]], b[s["state"]], b[s["rates"]], b[s["ext"]] = spools, state, rates, ext
        b[s["arms"]], b[s["mass"]], b[s["load"]] = arms, mass.ravel(), load
        splits = self._lib.hexgym_circuit_period(self._handle, self._pointer, h, substeps)
        return b[s["state"]].copy(), b[s["rates"]].copy(), b[s["ext"]].copy(), b[s["travel"]].copy(), splits

    # ---- the period's pieces, for the tests that hold the kernel to the definition ----
    def branch_areas(self, spools: np.ndarray, ext: np.ndarray) -> np.ndarray:
        """Every branch's area (m^2) at the spools (m) and cylinder extensions (m)."""
        out = np.zeros(self._branches)
        self._lib.hexgym_circuit_areas(self._handle, _in(spools), _in(ext), out.ctypes.data_as(_DOUBLES))
        return out

    def derivatives(
        self, state: np.ndarray, spools: np.ndarray, ext: np.ndarray, vel: np.ndarray, swing_rate: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """d(state)/dt and its Jacobian (HydraulicCircuit.jacobian)."""
        f, jac = np.zeros(STATE_SIZE), np.zeros((STATE_SIZE, STATE_SIZE))
        self._lib.hexgym_circuit_derivatives(
            self._handle, _in(state), _in(spools), _in(ext), _in(vel), swing_rate,
            f.ctypes.data_as(_DOUBLES), jac.ctypes.data_as(_DOUBLES),
        )  # fmt: skip
        return f, jac

    def step(
        self, state: np.ndarray, spools: np.ndarray, ext: np.ndarray, vel: np.ndarray, swing_rate: float, dt: float
    ) -> tuple[np.ndarray, np.ndarray, int]:
        """One circuit step of ``dt``: the new state, d(state)/d(velocities) and the splits taken
        (HydraulicCircuit.step_with_sensitivity)."""
        y, sens = np.array(state, dtype=float), np.zeros((STATE_SIZE, 4))
        splits = self._lib.hexgym_circuit_step(
            self._handle, y.ctypes.data_as(_DOUBLES), _in(spools), _in(ext), _in(vel), swing_rate, dt,
            sens.ctypes.data_as(_DOUBLES),
        )  # fmt: skip
        return y, sens, splits

    def forces(self, state: np.ndarray, vel: np.ndarray, swing_rate: float) -> tuple[np.ndarray, float]:
        """The oil's cylinder forces (N) and swing torque (N m), no end stops (HydraulicCircuit.actuator_forces)."""
        force = np.zeros(NUM_CYLINDERS)
        torque = self._lib.hexgym_circuit_forces(
            self._handle, _in(state), _in(vel), swing_rate, force.ctypes.data_as(_DOUBLES)
        )
        return force, torque

    def coupling(self, sens: np.ndarray, vel: np.ndarray) -> tuple[np.ndarray, float]:
        """d(force)/d(velocity) and d(swing torque)/d(swing rate) (HydraulicCircuit.coupling_derivatives)."""
        dforce = np.zeros(NUM_CYLINDERS)
        dtorque = self._lib.hexgym_circuit_coupling(self._handle, _in(sens), _in(vel), dforce.ctypes.data_as(_DOUBLES))
        return dforce, dtorque

    def period_ns(self, h: float, substeps: int, repeat: int, steps_only: bool = False) -> float:
        """Nanoseconds per control period on the inputs of the last :meth:`control_period`, timed in the library
        (``steps_only``: its circuit steps alone, without the joints' coupling)."""
        return self._lib.hexgym_circuit_time(self._handle, self._pointer, h, substeps, repeat, int(steps_only))


def _rebuilt(numbers: np.ndarray, tables: dict[str, MBLTable], branches: int, layout: ValveLayout) -> NativeCircuit:
    """A :class:`NativeCircuit` of packed circuit numbers and valve tables (unpickling)."""
    kernel = NativeCircuit.__new__(NativeCircuit)
    kernel._init(numbers, tables, branches, layout)
    return kernel

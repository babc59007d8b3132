"""The circuit model's control period, compiled: the open-centre circuit with the learned valve on the main joints.

:func:`control_period` runs what :class:`hexgym.model.circuit_model.CircuitModel` does in one control period, on
plain float arrays: the valve's passage areas from the ``circuit`` tables (the lookup, dead band and sign rules of
:class:`hexgym.mbl.valve.LearnedValve` and the pumps' bypass law of :func:`hexgym.mbl.valve.pump_bypass_area`), then
``substeps`` times one step of the circuit (:class:`hexgym.hydraulics.circuit.HydraulicCircuit`: branch flows and
conductances, pumps, compliance, the linearly implicit Euler step with its splitting and velocity sensitivity)
coupled implicitly to the joints' ``M dw/dt = tau_oil - tau_load``, with the stroke ends holding their joints.

It mirrors the circuit's law and the model's coupling term by term; :mod:`hexgym.hydraulics.circuit` stays the
definition (it makes the training data), and the tests hold the two to 1e-10 and the model's tip paths to 1e-6 m.
Sums run in another order than numpy's and two powers are products and square roots, so the results agree to
rounding, not bit for bit.

Every number comes in through :func:`pack`, once per model, from the circuit object and the tables: the compiled
functions freeze no other module's constants, so numba's own check of this file (``cache=True``) keeps their cache
current. The constants are a few arrays with named rows and a few numbers, the values of :class:`Circuit`,
:class:`Valve` and :class:`Laws` passed as plain tuples; each function names them again on entry
(``k = Circuit(*circuit)``, free once compiled). Plain tuples because numba's cache index records the argument types
of every compiled signature and cannot be read at all once a class named there is renamed (numba #6018), and
because numba types a plain tuple at each call in a fraction of the time a named one takes. Array expressions and
slice assignments are written as loops: they compile several times slower. The 14-state's and the joints' linear
systems are solved by Gaussian elimination with partial pivoting (:func:`solve`), as LAPACK's LU does, without
numpy's per-call overhead on such small matrices.
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from hexgym.hydraulics.circuit import (
    _SQRT_2_RHO,
    _VACUUM,
    CYLINDER_NAMES,
    FUNCTIONS,
    NODES,
    SWING_DISPLACEMENT_RAD,
    HydraulicCircuit,
)
from hexgym.machine import parameters as p
from hexgym.mbl.table import MBLTable
from hexgym.mbl.valve import CLOSED_AREA, LearnedValve

# cached on disk; no fastmath (numpy's arithmetic); numpy's error model (x / 0 is inf, as in the numpy circuit)
jit = numba.njit(cache=True, nogil=True, error_model="numpy")
_UNIFORM_RTOL = 1e-9  # an axis whose steps agree to this is looked up by its step, as MBLTable does
PASSAGES = ("bypass", "pa", "pb", "at", "bt")  # the valve tables' rows, by the names' passage part
BYPASS, PA, PB, AT, BT = range(len(PASSAGES))
FROM, TO = range(2)  # rows of Circuit.branch_nodes
AREA, CRACK, INV_SPAN, LAMINAR = range(4)  # rows of Circuit.branch
HEAD_AREA, ROD_AREA, STROKE, COUNT, PORT_VOLUME = range(5)  # rows of Circuit.cylinder
HEAD, ROD, FUNCTION = range(3)  # rows of Circuit.cylinder_index


class Laws(NamedTuple):
    """The circuit's scalar parameters: plain numbers, passed by value to the compiled functions."""

    discharge: float
    sqrt_2_rho: float
    laminar_sq: float  # the orifice law's laminar pressure, squared
    atmosphere: float
    vacuum: float
    polytropic: float
    air_fraction: float
    bulk_modulus: float
    cushion_length: float
    cushion_area: float
    cushion_port_area: float
    nfc_full_flow: float
    nfc_min_flow: float
    idle_fraction: float
    power_limit: float
    max_flow: float
    regulator_time: float
    max_splits: int
    coulomb: float
    friction_velocity: float
    viscous: float
    swing_reduction: float
    swing_displacement: float
    swing_viscous: float
    swing_efficiency: float
    swing_friction_speed: float
    swing_a: int  # the swing motor's port nodes
    swing_b: int
    stop_clearance: float  # m inside each stroke end, where the joints are held


class Circuit(NamedTuple):
    """The circuit's layout: branches, valve passages, cylinders and nodes."""

    branch_nodes: np.ndarray  # (2, branches) int: FROM, TO node (the tank is node N_NODES)
    branch: np.ndarray  # (4, branches): AREA (fixed), CRACK, INV_SPAN (> 0: a pressure-operated valve), LAMINAR
    passage_branch: np.ndarray  # (5, 4) int: the branch of each passage (PASSAGES) and function; BYPASS row unused
    bypass_branch: np.ndarray  # (2,) int: each pump's bypass
    cylinder: np.ndarray  # (5, 3): HEAD_AREA, ROD_AREA, STROKE, COUNT, PORT_VOLUME of boom, stick, bucket
    cylinder_index: np.ndarray  # (3, 3) int: HEAD and ROD node, FUNCTION index
    node_volume: np.ndarray  # (N_NODES,) the volumes of the nodes that are no cylinder chamber (0 for those)
    displacement: np.ndarray  # (N_NODES, 4) d(volume rate)/d(boom, stick, bucket velocity, swing rate)
    laws: tuple  # the values of Laws


class Valve(NamedTuple):
    """The learned valve: one 1-D table per passage and function (row ``PASSAGES index * 4 + function``)."""

    nodes: np.ndarray  # (20, longest axis), padded
    values: np.ndarray
    size: np.ndarray  # int: nodes per table
    inv_step: np.ndarray  # 1 / node spacing; 0 for an uneven axis (searched)
    sections: np.ndarray  # (2, 2) int: each pump's two functions
    inv_neutral_sq: np.ndarray  # (2,) 1 / (each pump's bypass area at neutral)^2
    dead_band: float
    closed_area: float


def pack(circuit: HydraulicCircuit, valve: LearnedValve, stop_clearance: float) -> tuple[tuple, tuple]:
    """The constants of ``circuit`` with the learned ``valve`` (its tables), joints held ``stop_clearance`` (m) inside
    their stroke ends: the values of a :class:`Circuit` and of a :class:`Valve`, as the plain tuples the compiled
    functions take."""
    return tuple(_pack_circuit(circuit, stop_clearance)), tuple(_pack_valve(valve))


def _pack_circuit(circuit: HydraulicCircuit, stop_clearance: float) -> Circuit:
    br, groups = circuit.branches, circuit.branch_groups
    branch = np.zeros((4, len(br.names)))
    branch[AREA], branch[LAMINAR] = br.area, br.laminar
    branch[CRACK, br.valve], branch[INV_SPAN, br.valve] = br.crack, br.inv_span
    passage_branch = np.zeros((len(PASSAGES), len(FUNCTIONS)), dtype=np.int64)
    for k in (PA, PB, AT, BT):
        passage_branch[k] = groups[PASSAGES[k]]
    cylinder = np.zeros((5, len(CYLINDER_NAMES)))
    cylinder[HEAD_AREA], cylinder[ROD_AREA], cylinder[STROKE] = circuit.head_area, circuit.rod_area, circuit.stroke
    cylinder[COUNT], cylinder[PORT_VOLUME] = circuit.cylinder_count, circuit.port_volumes
    functions = [FUNCTIONS.index(n) for n in CYLINDER_NAMES]
    node_volume = circuit.volumes(np.zeros(len(CYLINDER_NAMES)))
    node_volume[circuit.head_nodes] = node_volume[circuit.rod_nodes] = 0.0  # the chambers' follow the pistons
    return Circuit(
        branch_nodes=np.array([br.frm, br.to], dtype=np.int64),
        branch=branch,
        passage_branch=passage_branch,
        bypass_branch=groups["bypass"].astype(np.int64),
        cylinder=cylinder,
        cylinder_index=np.array([circuit.head_nodes, circuit.rod_nodes, functions], dtype=np.int64),
        node_volume=node_volume,
        displacement=circuit.displacement,
        laws=tuple(_laws(circuit, stop_clearance)),
    )


def _laws(circuit: HydraulicCircuit, stop_clearance: float) -> Laws:
    """The scalar parameters (:mod:`hexgym.machine.parameters`, and what the circuit's module derives from them)."""
    return Laws(
        discharge=float(p.DISCHARGE_COEFFICIENT),
        sqrt_2_rho=float(_SQRT_2_RHO),
        laminar_sq=float(p.ORIFICE_LAMINAR_PRESSURE**2),
        atmosphere=float(p.ATMOSPHERIC_PRESSURE),
        vacuum=float(_VACUUM),
        polytropic=float(p.AIR_POLYTROPIC_EXPONENT),
        air_fraction=float(p.OIL_AIR_FRACTION),
        bulk_modulus=float(p.OIL_BULK_MODULUS),
        cushion_length=float(p.CUSHION_LENGTH),
        cushion_area=float(p.CUSHION_AREA),
        cushion_port_area=float(p.CUSHION_PORT_AREA),
        nfc_full_flow=float(p.NFC_PRESSURE_FULL_FLOW),
        nfc_min_flow=float(p.NFC_PRESSURE_MIN_FLOW),
        idle_fraction=float(p.PUMP_IDLE_FLOW_FRACTION),
        power_limit=float(p.PUMP_POWER_LIMIT),
        max_flow=float(p.PUMP_MAX_FLOW),
        regulator_time=float(p.PUMP_REGULATOR_TIME_CONSTANT),
        max_splits=int(circuit.MAX_SPLITS),
        coulomb=float(p.CYLINDER_COULOMB_FRICTION),
        friction_velocity=float(p.CYLINDER_FRICTION_VELOCITY),
        viscous=float(p.CYLINDER_VISCOUS_FRICTION),
        swing_reduction=float(p.SWING_REDUCTION),
        swing_displacement=float(SWING_DISPLACEMENT_RAD),
        swing_viscous=float(p.SWING_MOTOR_VISCOUS_FRICTION),
        swing_efficiency=float(p.SWING_MECHANICAL_EFFICIENCY),
        swing_friction_speed=float(p.SWING_FRICTION_SPEED),
        swing_a=NODES.index("swing_a"),
        swing_b=NODES.index("swing_b"),
        stop_clearance=float(stop_clearance),
    )


def _pack_valve(valve: LearnedValve) -> Valve:
    tables: dict[str, MBLTable] = valve.tables
    names = [f"{f}_{k}" for k in PASSAGES for f in FUNCTIONS]
    for name in names:
        if tables[name].values.ndim != 1:
            raise ValueError(f"valve table {name!r} must have one input, got shape {tables[name].values.shape}")
    axes = [tables[n].axes[0] for n in names]
    longest = max(len(a) for a in axes)
    nodes, values = np.zeros((len(names), longest)), np.zeros((len(names), longest))
    for row, (name, axis) in enumerate(zip(names, axes, strict=True)):
        nodes[row, : len(axis)], values[row, : len(axis)] = axis, tables[name].values
    even = [bool(np.allclose(np.diff(a), a[1] - a[0], rtol=_UNIFORM_RTOL, atol=0.0)) for a in axes]
    neutral = [float(a) for a in valve._neutral]  # the valve's own figures, as it combines its sections
    return Valve(
        nodes=nodes,
        values=values,
        size=np.array([len(a) for a in axes], dtype=np.int64),
        inv_step=np.array([(len(a) - 1) / float(a[-1] - a[0]) if e else 0.0 for a, e in zip(axes, even, strict=True)]),
        sections=np.array(valve._sections, dtype=np.int64),
        inv_neutral_sq=np.array([1.0 / a**2 for a in neutral]),
        dead_band=float(p.SPOOL_DEAD_BAND),
        closed_area=float(CLOSED_AREA),
    )


# --------------------------------------------------------------------------------------------
# Element laws (one value each; HydraulicCircuit's vectorised laws).
@jit
def smoothstep(z: float) -> tuple[float, float]:
    """C1 ramp 0 -> 1 on z in [0, 1] and its derivative."""
    z = min(max(z, 0.0), 1.0)
    return z * z * (3.0 - 2.0 * z), 6.0 * z * (1.0 - z)


@jit
def orifice_law(dp: float, laminar_sq: float, sqrt_2_rho: float) -> tuple[float, float]:
    """sqrt(2|dp|/rho) sign(dp), regularised to laminar near 0, and its derivative.

    ``s^-1/4`` as ``1/sqrt(sqrt(s))`` and ``w^5`` as products: within an ulp of numpy's powers, five times faster.
    """
    w = 1.0 / np.sqrt(np.sqrt(dp * dp + laminar_sq))
    w2 = w * w
    return sqrt_2_rho * dp * w, sqrt_2_rho * (w2 * w2 * w) * (0.5 * dp * dp + laminar_sq)


@jit
def series_area(a1: float, a2: float) -> float:
    """Equivalent area of two turbulent orifices in series."""
    return a1 * a2 / np.sqrt(a1 * a1 + a2 * a2 + 1e-30)


@jit
def compliance(laws: tuple, pressure: float) -> tuple[float, float]:
    """1/beta(p) of oil with entrained air, and d(1/beta)/dp (0 on the vacuum floor)."""
    law = Laws(*laws)
    n, pa = law.polytropic, law.atmosphere
    p_abs = pressure + pa
    floor = p_abs < law.vacuum + pa
    if floor:
        p_abs = law.vacuum + pa
    x = law.air_fraction * (pa / p_abs) ** (1.0 / n)
    dx = -x / (n * p_abs)
    num = 1.0 / law.bulk_modulus + x / (n * p_abs)
    dnum = -x * (1.0 + 1.0 / n) / (n * p_abs * p_abs)
    c = num / (1.0 + x)
    dc = (dnum * (1.0 + x) - num * dx) / (1.0 + x) ** 2
    return c, 0.0 if floor else dc


@jit
def cushion(laws: tuple, count: float, distance: float) -> float:
    """Outlet area left by the cushion spear ``distance`` (m) before the end of stroke (``count`` cylinders)."""
    law = Laws(*laws)
    s = smoothstep(distance / law.cushion_length)[0]
    return count * (law.cushion_area + (law.cushion_port_area - law.cushion_area) * s)


# --------------------------------------------------------------------------------------------
# The valve and the branches.
@jit
def table_value(nodes: np.ndarray, values: np.ndarray, n: int, inv_step: float, x: float) -> float:
    """A table of ``n`` nodes at spool ``x`` (m): linear between its nodes, clamped to its ends (MBLTable's lookup)."""
    lo, hi = nodes[0], nodes[n - 1]
    v = lo if x < lo else hi if x > hi else x
    if inv_step > 0.0:  # an even axis: the cell from the spacing
        pos = (v - lo) * inv_step
        i = min(int(pos), n - 2)
        t = pos - i
    else:  # the last node at or below v, as bisect_right
        i, top = 0, n - 1
        while top - i > 1:
            mid = (i + top) // 2
            if nodes[mid] <= v:
                i = mid
            else:
                top = mid
        t = (v - nodes[i]) / (nodes[i + 1] - nodes[i])
    return values[i] + t * (values[i + 1] - values[i])


@jit
def valve_areas(valve_values: tuple, spools: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Passage areas (m^2; rows ``PASSAGES``, columns ``FUNCTIONS``) and each pump's bypass area.

    A passage is closed in the dead band and on the other side of neutral, elsewhere its table's area (>= 0);
    the pump's bypass combines its two sections' tables in series (:func:`hexgym.mbl.valve.pump_bypass_area`).
    """
    valve = Valve(*valve_values)
    nf = spools.shape[0]
    area = np.zeros((len(PASSAGES), nf))
    for i in range(nf):
        u = spools[i]
        for key in (BYPASS, PA, BT) if u > 0 else (BYPASS, PB, AT):
            if key == BYPASS or abs(u) >= valve.dead_band:
                row = key * nf + i
                value = table_value(valve.nodes[row], valve.values[row], valve.size[row], valve.inv_step[row], u)
                area[key, i] = max(value, 0.0)
    pump = np.empty(2)
    for j in range(2):
        first = max(area[BYPASS, valve.sections[j, 0]], valve.closed_area)
        second = max(area[BYPASS, valve.sections[j, 1]], valve.closed_area)
        resistance = 1.0 / (first * first) + 1.0 / (second * second) - valve.inv_neutral_sq[j]
        smaller = min(first, second)
        pump[j] = 1.0 / np.sqrt(max(resistance, 1.0 / (smaller * smaller)))
    return area, pump


@jit
def branch_areas(circuit: tuple, passages: np.ndarray, pump_bypass: np.ndarray, ext: np.ndarray) -> np.ndarray:
    """Geometric area (m^2) of every branch for these valve areas and cylinder extensions."""
    k = Circuit(*circuit)
    area = k.branch[AREA].copy()
    for key in (PA, PB, AT, BT):
        for i in range(passages.shape[1]):
            area[k.passage_branch[key, i]] = passages[key, i]
    for c in range(ext.shape[0]):  # a->T leaves the head end (retracting), b->T the rod end (extending)
        f, count, stroke = k.cylinder_index[FUNCTION, c], k.cylinder[COUNT, c], k.cylinder[STROKE, c]
        area[k.passage_branch[AT, f]] = series_area(passages[AT, f], cushion(k.laws, count, ext[c]))
        area[k.passage_branch[BT, f]] = series_area(passages[BT, f], cushion(k.laws, count, stroke - ext[c]))
    for j in range(2):
        area[k.bypass_branch[j]] = pump_bypass[j]
    return area


@jit
def branch_flows(
    laws: tuple, nodes: np.ndarray, branch: np.ndarray, pressures: np.ndarray, area: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Flow (m^3/s, from -> to) of every branch and its conductance dq/d(dp); the tank stays at 0 Pa."""
    law = Laws(*laws)
    pe = np.zeros(pressures.shape[0] + 1)  # the tank, last
    for i in range(pressures.shape[0]):
        pe[i] = pressures[i]
    q, g = np.empty(area.shape[0]), np.empty(area.shape[0])
    for b in range(area.shape[0]):
        dp = pe[nodes[FROM, b]] - pe[nodes[TO, b]]
        r, dr = orifice_law(dp, law.laminar_sq, law.sqrt_2_rho)
        opening, dopening, inv_span = 1.0, 0.0, branch[INV_SPAN, b]
        if inv_span > 0.0:  # a pressure-operated valve
            opening, ds = smoothstep((dp - branch[CRACK, b]) * inv_span)
            dopening = ds * inv_span
        cda = law.discharge * area[b]
        q[b] = cda * opening * r + branch[LAMINAR, b] * dp
        g[b] = cda * (dopening * r + opening * dr) + branch[LAMINAR, b]
    return q, g


@jit
def pump_flows(
    laws: tuple, p1: float, p2: float, displacement: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pump flows (m^3/s), dQ/d(displacement) and dQ_i/d(p1) (= dQ_i/d(p2)): NFC under the horsepower limit."""
    law = Laws(*laws)
    total = p1 + p2
    q_hp = law.power_limit / total if total > 0.0 else np.inf
    q, dq_dd, dq_dp = np.empty(2), np.empty(2), np.zeros(2)
    for i in range(2):
        nfc = law.max_flow * min(max(displacement[i], 0.0), 1.0)
        limited = nfc > q_hp
        q[i] = q_hp if limited else nfc
        dq_dd[i] = 0.0 if limited else law.max_flow
        if limited and total > 0.0:
            dq_dp[i] = -law.power_limit / total**2
    return q, dq_dd, dq_dp


# --------------------------------------------------------------------------------------------
# The ODE and its step.
@jit
def evaluate(
    circuit: tuple, y: np.ndarray, area: np.ndarray, ext: np.ndarray, vel: np.ndarray, swing_rate: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """d(state)/dt, its Jacobian and the nodes' capacities V/beta (HydraulicCircuit._evaluate)."""
    k = Circuit(*circuit)
    nn, nodes = k.node_volume.shape[0], k.branch_nodes
    pr = y[:nn]
    q, g = branch_flows(k.laws, nodes, k.branch, pr, area)
    net, jac = np.zeros(nn), np.zeros((y.shape[0], y.shape[0]))
    for b in range(q.shape[0]):  # the incidence of each branch; the tank has no row
        a, c = nodes[FROM, b], nodes[TO, b]
        if a < nn:
            net[a] -= q[b]
            jac[a, a] -= g[b]
        if c < nn:
            net[c] += q[b]
            jac[c, c] -= g[b]
        if a < nn and c < nn:
            jac[a, c] += g[b]
            jac[c, a] += g[b]
    q_pump, dq_dd, dq_dp = pump_flows(k.laws, pr[0], pr[1], y[nn:])
    f, cap, disp = np.empty(y.shape[0]), volumes(k.cylinder, k.cylinder_index, k.node_volume, ext), k.displacement
    for i in range(nn):
        c, dc = compliance(k.laws, pr[i])
        cap[i] *= c
        if i < 2:
            net[i] += q_pump[i]
            jac[i, 0] += dq_dp[i]
            jac[i, 1] += dq_dp[i]
        rate = disp[i, 0] * vel[0] + disp[i, 1] * vel[1] + disp[i, 2] * vel[2]
        f[i] = (net[i] - (rate + disp[i, 3] * swing_rate)) / cap[i]
        for j in range(nn):
            if jac[i, j] != 0.0:  # a row has a few branches
                jac[i, j] /= cap[i]
        jac[i, i] -= f[i] * dc / c
    regulator(k.laws, y, f, jac, dq_dd, cap)
    return f, jac, cap


@jit
def regulator(laws: tuple, y: np.ndarray, f: np.ndarray, jac: np.ndarray, dq_dd: np.ndarray, cap: np.ndarray) -> None:
    """The pumps' displacement rows of ``f`` and ``jac`` (NFC through its lag) and d(pump pdot)/d(displacement)."""
    law = Laws(*laws)
    nn, tau = cap.shape[0], law.regulator_time
    width = law.nfc_min_flow - law.nfc_full_flow
    drop = 1.0 - law.idle_fraction
    for i in range(2):
        s, ds = smoothstep((y[2 + i] - law.nfc_full_flow) / width)
        f[nn + i] = (1.0 - drop * s - y[nn + i]) / tau
        jac[nn + i, 2 + i] = -drop * ds / width / tau
        jac[nn + i, nn + i] = -1.0 / tau
        jac[i, nn + i] = dq_dd[i] / cap[i]


@jit
def volumes(cylinder: np.ndarray, index: np.ndarray, node_volume: np.ndarray, ext: np.ndarray) -> np.ndarray:
    """Oil volume (m^3) of every node at cylinder extensions ``ext``."""
    vol = node_volume.copy()
    for c in range(ext.shape[0]):
        stroke = cylinder[STROKE, c]
        x = min(max(ext[c], 0.0), stroke)
        vol[index[HEAD, c]] = cylinder[PORT_VOLUME, c] + cylinder[HEAD_AREA, c] * x
        vol[index[ROD, c]] = cylinder[PORT_VOLUME, c] + cylinder[ROD_AREA, c] * (stroke - x)
    return vol


@jit
def solve(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x of ``a x = b`` (b: (n, m)) by Gaussian elimination with partial pivoting; ``a`` and ``b`` are overwritten."""
    n = a.shape[0]
    for col in range(n):
        pivot = col
        for r in range(col + 1, n):
            if abs(a[r, col]) > abs(a[pivot, col]):
                pivot = r
        if pivot != col:
            for j in range(n):
                a[col, j], a[pivot, j] = a[pivot, j], a[col, j]
            for j in range(b.shape[1]):
                b[col, j], b[pivot, j] = b[pivot, j], b[col, j]
        for r in range(col + 1, n):
            if a[r, col] != 0.0:  # the circuit's matrix is sparse
                factor = a[r, col] / a[col, col]
                for j in range(col + 1, n):
                    a[r, j] -= factor * a[col, j]
                for j in range(b.shape[1]):
                    b[r, j] -= factor * b[col, j]
    for col in range(n - 1, -1, -1):
        for j in range(b.shape[1]):
            s = b[col, j]
            for c in range(col + 1, n):
                s -= a[col, c] * b[c, j]
            b[col, j] = s / a[col, col]
    return b


@jit
def trusted(p0: np.ndarray, p1: np.ndarray, vacuum: float) -> bool:
    """Whether a step's pressure change is small enough for its linearisation (HydraulicCircuit._trusted)."""
    for i in range(p0.shape[0]):
        if (p1[i] < 0.5 * p0[i] and p0[i] > 0.3e6) or p1[i] < vacuum or abs(p1[i] - p0[i]) > 5e6:
            return False
    return True


@jit
def implicit_euler(
    y: np.ndarray,
    sens: np.ndarray,
    dt: float,
    f: np.ndarray,
    jac: np.ndarray,
    cap: np.ndarray,
    displacement: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One linearly implicit Euler step of ``dt`` from ``y`` (where the ODE gives ``f``, ``jac`` and ``cap``): the new
    state and sensitivity, ``(y, 0) + L^-1 (dt f, S - dt dV/dv / cap)`` with ``L = I - dt J``."""
    n, nn = y.shape[0], cap.shape[0]
    lhs, rhs = np.empty((n, n)), np.empty((n, 5))
    for i in range(n):
        for j in range(n):
            lhs[i, j] = (1.0 if i == j else 0.0) - dt * jac[i, j]
        rhs[i, 0] = dt * f[i]
        for j in range(4):
            rhs[i, 1 + j] = sens[i, j] - (dt * displacement[i, j] / cap[i] if i < nn else 0.0)
    sol = solve(lhs, rhs)
    y1, sens1 = np.empty(n), np.empty((n, 4))
    for i in range(n):
        y1[i] = y[i] + sol[i, 0]
        for j in range(4):
            sens1[i, j] = sol[i, 1 + j]
    return y1, sens1


@jit
def advance(
    circuit: tuple, y: np.ndarray, dt: float, area: np.ndarray, ext: np.ndarray, vel: np.ndarray, swing_rate: float
) -> tuple[np.ndarray, np.ndarray, int]:
    """HydraulicCircuit.step_with_sensitivity: the state after ``dt``, d(state)/d(velocities), and the splits taken.

    A step the linearisation cannot be trusted with is split in halves, up to ``max_splits`` deep; the halves run
    depth first, as the circuit's recursion does. The first half starts where the step did, so it reuses that
    point's derivative and Jacobian.
    """
    k = Circuit(*circuit)
    law = Laws(*k.laws)
    nn, vacuum = k.node_volume.shape[0], law.vacuum
    sens = np.zeros((y.shape[0], 4))
    pending = np.empty(law.max_splits + 1, dtype=np.int64)  # depths of the intervals still to go, last is next
    pending[0], top, splits = 0, 1, 0
    f, jac, cap = evaluate(circuit, y, area, ext, vel, swing_rate)
    while top > 0:
        top -= 1
        depth = pending[top]
        y1, sens1 = implicit_euler(y, sens, dt * 0.5**depth, f, jac, cap, k.displacement)
        if depth < law.max_splits and not trusted(y[:nn], y1[:nn], vacuum):
            splits += 1
            pending[top], pending[top + 1] = depth + 1, depth + 1
            top += 2
            continue
        for i in range(nn):  # a last guard: oil cannot pull a vacuum
            if y1[i] < vacuum:
                y1[i] = vacuum
                for j in range(4):
                    sens1[i, j] = 0.0
        y, sens = y1, sens1
        if top > 0:  # the second half of a split step: from the first's end
            f, jac, cap = evaluate(circuit, y, area, ext, vel, swing_rate)
    return y, sens, splits


# --------------------------------------------------------------------------------------------
# The joints.
@jit
def oil_loads(
    laws: tuple, cylinder: np.ndarray, index: np.ndarray, y: np.ndarray, vel: np.ndarray, swing_rate: float
) -> tuple[np.ndarray, float]:
    """Cylinder forces (N) and swing torque (N m) of state ``y``, no end stops (HydraulicCircuit.actuator_forces)."""
    law = Laws(*laws)
    force = np.empty(3)
    for c in range(3):
        friction = law.coulomb * np.tanh(vel[c] / law.friction_velocity)
        force[c] = y[index[HEAD, c]] * cylinder[HEAD_AREA, c] - y[index[ROD, c]] * cylinder[ROD_AREA, c]
        force[c] -= cylinder[COUNT, c] * (friction + law.viscous * vel[c])
    omega = law.swing_reduction * swing_rate
    ideal = law.swing_displacement * (y[law.swing_a] - y[law.swing_b])
    loss = (1.0 - law.swing_efficiency) * abs(ideal) * np.tanh(omega / law.swing_friction_speed)
    return force, law.swing_reduction * (ideal - loss - law.swing_viscous * omega)


@jit
def coupling(
    laws: tuple, cylinder: np.ndarray, index: np.ndarray, sens: np.ndarray, vel: np.ndarray
) -> tuple[np.ndarray, float]:
    """d(force_i)/d(v_i) (N s/m) and d(swing torque)/d(swing rate) (N m s/rad) along a step of sensitivity
    ``sens`` (HydraulicCircuit.coupling_derivatives)."""
    law = Laws(*laws)
    dforce = np.empty(3)
    for c in range(3):
        dpressure = cylinder[HEAD_AREA, c] * sens[index[HEAD, c], c] - cylinder[ROD_AREA, c] * sens[index[ROD, c], c]
        sech2 = 1.0 - np.tanh(vel[c] / law.friction_velocity) ** 2
        friction = law.coulomb / law.friction_velocity * sech2 + law.viscous
        dforce[c] = dpressure - cylinder[COUNT, c] * friction
    ratio = law.swing_reduction
    dtorque = ratio * law.swing_displacement * (sens[law.swing_a, 3] - sens[law.swing_b, 3])
    return dforce, dtorque - ratio * ratio * law.swing_viscous


@jit
def held_solve(lhs: np.ndarray, rhs: np.ndarray, rates: np.ndarray, held: np.ndarray) -> np.ndarray:
    """The implicit step ``lhs (new - rates) = rhs`` (rhs: (n, 1)) with the ``held`` joints' new rates zero: the free
    joints' rows, with the held joints' change (to rest) on the right-hand side."""
    free = np.empty(rates.shape[0], dtype=np.int64)
    nf = 0
    for j in range(rates.shape[0]):
        if not held[j]:
            free[nf] = j
            nf += 1
    a, b = np.empty((nf, nf)), np.empty((nf, 1))
    for r in range(nf):
        s = 0.0
        for j in range(rates.shape[0]):
            if held[j]:
                s += lhs[free[r], j] * -rates[j]
        b[r, 0] = rhs[free[r], 0] - s
        for c in range(nf):
            a[r, c] = lhs[free[r], free[c]]
    change = solve(a, b)
    new = np.zeros(rates.shape[0])
    for r in range(nf):
        new[free[r]] = rates[free[r]] + change[r, 0]
    return new


@jit
def substep(
    circuit: tuple,
    h: float,
    area: np.ndarray,
    state: np.ndarray,
    rates: np.ndarray,
    ext: np.ndarray,
    arms: np.ndarray,
    mass: np.ndarray,
    load: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """One circuit step of ``h`` s with the joints' rates implicit in the oil's torques: the new state, joint rates
    (swing, boom, stick, bucket), cylinder extensions and the splits taken (CircuitModel's step)."""
    k = Circuit(*circuit)
    cyl, index = k.cylinder, k.cylinder_index
    vel = np.empty(3)
    for c in range(3):
        vel[c] = arms[c] * rates[c + 1]
    predicted, sens, splits = advance(circuit, state, h, area, ext, vel, rates[0])
    forces, torque = oil_loads(k.laws, cyl, index, predicted, vel, rates[0])
    dforce, dtorque = coupling(k.laws, cyl, index, sens, vel)
    lhs, rhs = mass.copy(), np.empty((4, 1))
    lhs[0, 0] -= h * dtorque
    rhs[0, 0] = h * (torque - load[0])
    for c in range(3):
        lhs[c + 1, c + 1] -= h * (dforce[c] * (arms[c] * arms[c]))
        rhs[c + 1, 0] = h * (forces[c] * arms[c] - load[c + 1])
    change = solve(lhs.copy(), rhs.copy())
    new = np.empty(4)
    for j in range(4):
        new[j] = rates[j] + change[j, 0]
    new_ext, held, stopped = np.empty(3), np.zeros(4, dtype=np.bool_), False
    lo = Laws(*k.laws).stop_clearance
    for c in range(3):
        new_ext[c] = ext[c] + arms[c] * new[c + 1] * h
        v = arms[c] * new[c + 1]
        held[c + 1] = (new_ext[c] > cyl[STROKE, c] - lo and v > 0.0) or (new_ext[c] < lo and v < 0.0)
        stopped |= held[c + 1]
    if stopped:  # the stops hold those joints; their impulse reaches the others through M
        new = held_solve(lhs, rhs, rates, held)
        for c in range(3):
            new_ext[c] = ext[c] if held[c + 1] else ext[c] + arms[c] * new[c + 1] * h
    dv = np.empty(4)
    for c in range(3):
        dv[c] = arms[c] * (new[c + 1] - rates[c + 1])
    dv[3] = new[0] - rates[0]
    for i in range(predicted.shape[0]):  # the pressures follow the rates the step reached
        predicted[i] += sens[i, 0] * dv[0] + sens[i, 1] * dv[1] + sens[i, 2] * dv[2] + sens[i, 3] * dv[3]
    return predicted, new, new_ext, splits


@jit
def control_period(
    circuit: tuple,
    valve: tuple,
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
    """``substeps`` circuit steps of ``h`` s at the spools (m), from the circuit ``state``, the joints' ``rates`` and
    cylinder extensions ``ext``, with the period's moment arms, the joints' mass matrix ``mass`` (4, 4) and their
    loads ``load``: the new circuit state, joint rates, cylinder extensions, each joint's travel over the period
    (rad) and the steps split. ``circuit``, ``valve``: :func:`pack`. The inputs are not changed."""
    passages, pump_bypass = valve_areas(valve, spools)
    travel, splits = np.zeros(4), 0
    for _ in range(substeps):
        area = branch_areas(circuit, passages, pump_bypass, ext)
        state, rates, ext, n = substep(circuit, h, area, state, rates, ext, arms, mass, load)
        for j in range(4):
            travel[j] += rates[j] * h
        splits += n
    return state, rates, ext, travel, splits

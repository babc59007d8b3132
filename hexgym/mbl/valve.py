"""The control valve, learned: each passage's orifice area against its spool, from measured motion.

What a real machine's logs give is enough to see the valve: the pump and port pressures, the pumps'
flows, the NFC signal (bypass) pressure, the cylinders' velocities and the swing's rate. Along an
operator-like log, each row where a passage is clearly metering gives one sample of its area,
``A = q / (Cd sqrt(2 dp / rho))`` with the passage's flow ``q`` and pressure drop ``dp``:

- pump -> port (``pa``, ``pb``): the port's displacement flow (piston area x velocity, the swing
  motor's swept volume x rate plus its leaks and its oil's compression) over pump minus port
  pressure, while the load check is fully open and the port is not cavitating;
- port -> tank (``at``, ``bt``): the outgoing displacement flow over the port's pressure, away from
  the end cushions (which the circuit model adds in series);
- centre bypass: the pump's flow less the sections' meter-in flows, over pump minus NFC signal
  pressure, while the section's partner on the same pump is at neutral. The table holds the pump's
  bypass area with the partner at neutral; :func:`pump_bypass_area` combines two sections, exactly
  for any split of the neutral resistance between them.

Rows near a relief's setting, with small flows or pressure drops, or with the spool in its dead band
give no sample of that passage (NaN). The tables are the ``circuit`` set of :mod:`hexgym.mbl.schema`,
fitted like the others (LWR, leave-one-out); :class:`LearnedValve` turns them into the areas the
circuit model (:mod:`hexgym.model.circuit_model`) reads.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from hexgym.hydraulics.circuit import (
    DEFAULT_LAYOUT,
    FUNCTIONS,
    REGENERATION,
    SWING_DISPLACEMENT_RAD,
    SpoolAreas,
    ValveLayout,
    compliance,
    metering_fraction,
    orifice_law,
    priority_shares,
    section_spools,
    smoothstep,
)
from hexgym.machine import parameters as p
from hexgym.mbl.schema import REGENERATION_SPOOLS, VALVE_PASSAGES, valve_tables
from hexgym.mbl.table import MBLTable

MIN_DROP_PA = 0.5e6  # metering passages: a smaller drop says little about the area (flows near zero)
MIN_BYPASS_DROP_PA = 2e3  # the open centre at neutral drops only kPa, and it is that area the NFC sees
MIN_PORT_PA = 0.3e6  # an inlet below this may be fed by its make-up check too: no sample
MIN_SPEED_MPS = 0.005  # cylinder speeds below this carry mostly leakage and compression flows
MIN_SWING_RATE = 0.02  # rad/s, the same for the swing
CLOSED_AREA = 1e-12  # m^2: a closed bypass section, in the series law (no division by zero)
RELIEF_MARGIN_PA = 2.0e6  # a pressure this close to its relief's setting may be relieving
_CUSHION_CLEAR = p.CUSHION_LENGTH + 0.01  # m from a stroke end: the cushion is out of the outlet's way
_CHECK_OPEN = p.LOAD_CHECK_CRACKING + p.LOAD_CHECK_SPAN
SWING_SWEPT = SWING_DISPLACEMENT_RAD * p.SWING_REDUCTION  # m^3 per radian of the upper structure
_SHARE = p.SWING_MOTOR_EXTERNAL_LEAK_SHARE
_STICK = FUNCTIONS.index("stick")


def compression_flows(volumes: np.ndarray, pressures: np.ndarray, pressure_rates: np.ndarray) -> np.ndarray:
    """The oil (m^3/s) each node's compression takes, ``V / beta(p) dp/dt`` (any leading shape)."""
    return volumes * compliance(pressures)[0] * pressure_rates


def nfc_orifice_flow(signal_pa: np.ndarray | float) -> np.ndarray:
    """The flow (m^3/s) through a pump's NFC orifice at its signal pressure: the end of its centre bypass."""
    return p.DISCHARGE_COEFFICIENT * p.NFC_ORIFICE_AREA * orifice_law(np.asarray(signal_pa, dtype=float))[0]


def swing_port_leak(p_port: np.ndarray | float, p_other: np.ndarray | float) -> np.ndarray | float:
    """The oil (m^3/s) leaving a swing motor port through the motor's leaks: to the other port and to the case
    drain (the circuit's ``swing_internal_leak`` and ``swing_drain_*`` branches)."""
    return (1.0 - _SHARE) * p.SWING_MOTOR_LEAKAGE * (p_port - p_other) + 0.5 * _SHARE * p.SWING_MOTOR_LEAKAGE * p_port


def _area(q: float, dp: float, min_drop: float = MIN_DROP_PA) -> float:
    """Orifice area passing ``q`` at ``dp`` (the circuit's orifice law), or NaN if the sample is not clear."""
    if q <= 0.0 or dp < min_drop:
        return math.nan
    return q / (p.DISCHARGE_COEFFICIENT * float(orifice_law(np.array(dp))[0]))


@dataclass(frozen=True)
class ReliefSettings:
    """The relief settings (Pa) the identification keeps its samples clear of: a unit's (identified from its
    logs, :mod:`hexgym_lab.machine_logs.reliefs`) or the data sheet's."""

    main: float = p.MAIN_RELIEF
    swing: float = p.SWING_RELIEF
    line: dict[str, float] = field(default_factory=lambda: dict(p.LINE_RELIEF))


PACKAGED_RELIEFS = ReliefSettings()


@dataclass
class _Function:
    """What one function's continuity gives at an instant: which way its spool meters, the oil that must enter its
    inlet port and leave its outlet port (m^3/s; ``q_in`` NaN where make-up oil or a relief may take part), the
    ports' pressures, and whether its motion and outlet make clear samples."""

    name: str
    spool: float
    positive: bool
    q_in: float
    q_out: float
    p_in: float
    p_out: float
    moving: bool
    outlet_clear: bool
    outlet_port_area: float  # the cushion's open port in series with the outlet (inf: none)

    @property
    def inlet(self) -> str:
        return "pa" if self.positive else "pb"

    @property
    def outlet(self) -> str:
        return "bt" if self.positive else "at"


def _cylinder(f: str, u: float, v: float, ext: float, pressures: tuple, compression: tuple, line_relief: float):
    """The :class:`_Function` of a cylinder (``pressures``, ``compression``: its head's and rod's pressures and
    compression flows; ``line_relief``: its port reliefs' setting)."""
    p_head, p_rod = pressures
    c_head, c_rod = compression
    cyl = p.CYLINDERS[f]
    extending = u > 0.0
    speed = v if extending else -v
    a_in, a_out = (cyl.head_area, cyl.rod_area) if extending else (cyl.rod_area, cyl.head_area)
    p_in, p_out = (p_head, p_rod) if extending else (p_rod, p_head)
    c_in, c_out = (c_head, c_rod) if extending else (c_rod, c_head)
    # The inlet's continuity gives the meter-in flow at any speed (a held cylinder's closed load check
    # passes none) unless make-up oil from tank or the port relief takes part.
    fed = MIN_PORT_PA < p_in < line_relief - RELIEF_MARGIN_PA
    to_end = cyl.stroke - ext if extending else ext
    clear = to_end > _CUSHION_CLEAR and p_out < line_relief - RELIEF_MARGIN_PA
    q_in = a_in * speed + c_in if fed else math.nan
    moving = speed >= MIN_SPEED_MPS  # below: stalled, held or overrun backwards: no clear metering
    port = cyl.count * p.CUSHION_PORT_AREA
    return _Function(f, u, extending, q_in, a_out * speed - c_out, p_in, p_out, moving, clear, port)


def _swing(u: float, rate: float, pa: float, pb: float, compression: np.ndarray, relief: float) -> _Function | None:
    """The :class:`_Function` of the swing motor (``compression``: its ports'), or None while its crossover reliefs
    (set at ``relief``) may pass oil."""
    if abs(pa - pb) > relief - RELIEF_MARGIN_PA:
        return None
    positive = u > 0.0
    into_a = SWING_SWEPT * rate + swing_port_leak(pa, pb) + compression[0]  # what must enter port a
    into_b = -SWING_SWEPT * rate + swing_port_leak(pb, pa) + compression[1]
    q_in, q_out = (into_a, -into_b) if positive else (into_b, -into_a)
    p_in, p_out = (pa, pb) if positive else (pb, pa)
    q_in = q_in if p_in > MIN_PORT_PA else math.nan  # the inlet's continuity, unless make-up oil enters
    moving = (rate if positive else -rate) >= MIN_SWING_RATE  # starting, braking or reversing: the ports' oil rules
    return _Function("swing", u, positive, q_in, q_out, p_in, p_out, moving, True, math.inf)


def _functions(pressures, compression, spools_m, ext_m, vel_mps, swing_rate, reliefs) -> dict[str, _Function | None]:
    """Each function whose spool meters (outside its dead band): its continuity, or None where it gives none."""
    out: dict[str, _Function | None] = {}
    for j, f in enumerate(("boom", "stick", "bucket")):
        u = spools_m[j + 1]
        if abs(u) >= p.SPOOL_DEAD_BAND:
            head, rod = 4 + 2 * j, 5 + 2 * j
            out[f] = _cylinder(f, u, vel_mps[j], ext_m[j], (pressures[head], pressures[rod]),
                               (compression[head], compression[rod]), reliefs.line[f])  # fmt: skip
    if abs(spools_m[0]) >= p.SPOOL_DEAD_BAND:
        out["swing"] = _swing(spools_m[0], swing_rate, pressures[10], pressures[11], compression[10:12], reliefs.swing)
    return out


def identify_areas(
    pressures: np.ndarray,
    pressure_rates: np.ndarray,
    volumes: np.ndarray,
    pump_flows: np.ndarray,
    spools_m: np.ndarray,
    ext_m: np.ndarray,
    vel_mps: np.ndarray,
    swing_rate: float,
    layout: ValveLayout = DEFAULT_LAYOUT,
    reliefs: ReliefSettings = PACKAGED_RELIEFS,
) -> dict[str, float]:
    """One sample (m^2, or NaN) of every table of ``layout``'s valve (:func:`~hexgym.mbl.schema.valve_tables`) from one
    instant's measurements.

    ``pressures``, ``pressure_rates`` (Pa, Pa/s) and oil ``volumes`` (m^3) of the circuit's nodes
    (:data:`hexgym.hydraulics.circuit.NODES`: pumps, NFC signals, boom/stick/bucket head and rod,
    swing ports a and b): the oil a node's compression takes, ``V / beta dp/dt``, is part of the
    flows; ``pump_flows`` m^3/s; ``spools_m`` (swing, boom, stick, bucket); cylinder extensions and
    velocities (boom, stick, bucket); ``swing_rate`` rad/s; ``reliefs``: the settings near which a pressure may be
    a relief's (no sample there).

    Where two sections on different pumps feed one function (a two-pump valve's boom raise, stick), each pump's
    balance splits the function's flow: what the pump delivers less its centre bypass's flow (the NFC orifice's at
    the signal pressure, the machine's data) is its one open section's. A regeneration passage's flow is what the
    inlet takes beyond the sections'.
    """
    compression = compression_flows(volumes, pressures, pressure_rates)
    out = {spec.output: math.nan for spec in valve_tables(layout).values()}
    functions = _functions(pressures, compression, spools_m, ext_m, vel_mps, swing_rate, reliefs)
    near_main = pressures[:2] > reliefs.main - RELIEF_MARGIN_PA
    flows, regen = _section_flows(layout, functions, pressures, compression, pump_flows, near_main)
    stick2, swing_share, boom_share = priority_shares(layout, spools_m)
    shares = {_STICK: swing_share} | dict.fromkeys(stick2, boom_share)
    for i, section in enumerate(layout.sections):
        fn = functions.get(section.function)
        if fn is None or not fn.moving or fn.inlet not in section.areas:
            continue
        pump, share = pressures[section.pump], shares.get(i, 1.0)
        if fn.p_in > MIN_PORT_PA and pump - fn.p_in > _CHECK_OPEN and not near_main[section.pump]:
            if share >= MIN_PRIORITY_SHARE:
                out[f"{section.name}_{fn.inlet}_area_m2"] = _area(flows.get(i, math.nan), pump - fn.p_in) / share
    for f, fn in functions.items():
        if fn is not None and fn.moving:
            out |= _outlet_and_regeneration(layout, fn, regen.get(f), pressures)
    out |= _bypass_samples(layout, functions, flows, spools_m, pressures, compression, pump_flows, near_main)
    return out


MIN_PRIORITY_SHARE = 0.5  # a meter-in passage throttled below this share by a priority valve gives no sample


def _section_flows(layout: ValveLayout, functions: dict, pressures, compression, pump_flows, near_main) -> tuple:
    """({section index: meter-in flow}, {function: regeneration flow into its inlet}) as far as the functions'
    continuity and the pumps' balances give them (NaN or absent where not)."""
    feeders = {f: [i for i, s in enumerate(layout.sections) if s.function == f and fn and fn.inlet in s.areas]
               for f, fn in functions.items()}  # fmt: skip
    regenerating = {f: _regeneration_passage(layout, fn) for f, fn in functions.items() if fn is not None}
    flows: dict[int, float] = {}
    for f, fn in functions.items():
        if fn is not None and len(feeders[f]) == 1 and not regenerating[f]:
            flows[feeders[f][0]] = fn.q_in
        elif fn is None:
            flows |= dict.fromkeys(feeders[f], math.nan)
    for k in (0, 1):  # a pump with one section of unknown flow: the pump's balance gives it
        active = [i for f in functions for i in feeders[f] if layout.sections[i].pump == k]
        unknown = [i for i in active if i not in flows]
        if len(unknown) == 1:
            known = sum(flows[i] for i in active if i in flows)
            flows[unknown[0]] = _pump_meter_in(k, pressures, compression, pump_flows, near_main[k]) - known
    regen = {}
    for f, fn in functions.items():
        if fn is None or not feeders[f]:
            continue
        missing = [i for i in feeders[f] if i not in flows]
        remainder = fn.q_in - sum(flows[i] for i in feeders[f] if i in flows)
        if regenerating[f] and not missing:
            regen[f] = remainder
        elif len(missing) == 1 and not regenerating[f]:
            flows[missing[0]] = remainder
    return flows, regen


def _regeneration_passage(layout: ValveLayout, fn: _Function) -> str | None:
    """The learned regeneration passage that feeds ``fn``'s inlet as its spool is now, if the layout has one."""
    for passage, cylinder in REGENERATION_SPOOLS.items():
        opens = REGENERATION[passage].side > 0
        if cylinder == fn.name and opens == fn.positive and passage in layout.regeneration_passages:
            return passage
    return None


def _pump_meter_in(k: int, pressures: np.ndarray, compression: np.ndarray, pump_flows: np.ndarray, near_main: bool):
    """Pump ``k``'s flow into its sections: its delivery less its line's compression and its centre bypass's flow,
    the NFC orifice's at the signal pressure (NaN near the main relief or with the NFC relief open)."""
    signal = pressures[2 + k]
    if near_main or signal > p.NFC_RELIEF:
        return math.nan
    return pump_flows[k] - compression[k] - float(nfc_orifice_flow(signal)) - compression[2 + k]


def _outlet_and_regeneration(layout: ValveLayout, fn: _Function, regen: float | None, pressures) -> dict[str, float]:
    """Samples of ``fn``'s outlet passage (its first section's) and of the regeneration passage feeding its inlet."""
    out: dict[str, float] = {}
    passage = _regeneration_passage(layout, fn)
    q_out = fn.q_out
    if passage is not None:
        if regen is None or math.isnan(regen):
            return out
        if fn.p_out - fn.p_in > _CHECK_OPEN and fn.outlet_clear:  # away from the port's cushion
            out[f"{passage}_area_m2"] = _area(regen, fn.p_out - fn.p_in)
        q_out -= regen
    if passage == "stick_regeneration":  # the unloading valve (the machine's data) returns rod oil to tank too
        q_out -= _unloading_flow(fn.spool, fn.p_in, fn.p_out)
    if fn.outlet_clear:
        seen = _area(q_out, fn.p_out)  # the valve's passage in series with the cushion's open port
        port = fn.outlet_port_area
        if math.isinf(port):
            out[f"{fn.name}_{fn.outlet}_area_m2"] = seen
        else:
            out[f"{fn.name}_{fn.outlet}_area_m2"] = 1.0 / math.sqrt(max(1.0 / seen**2 - 1.0 / port**2, 1.0 / port**2))
    return out


def _unloading_flow(spool: float, p_head: float, p_rod: float) -> float:
    """The stick's rod oil through its unloading valve (m^3/s): its data-sheet area, opened by the head pressure."""
    opening, _ = smoothstep(np.array((p_head - p.STICK_UNLOADING_PRESSURE) / p.STICK_UNLOADING_SPAN))
    area = p.STICK_UNLOADING_AREA * float(metering_fraction(np.array(spool))[0]) * float(opening)
    return p.DISCHARGE_COEFFICIENT * area * float(orifice_law(np.array(p_rod))[0])


def _section_meter_in(i: int, section, functions: dict, flows: dict) -> float:
    """Section ``i``'s meter-in flow: 0 at neutral or on the side it has no passage, NaN where unknown."""
    if section.function not in functions:
        return 0.0
    fn = functions[section.function]
    if fn is None:
        return math.nan
    return flows.get(i, math.nan) if fn.inlet in section.areas else 0.0


def _bypass_samples(layout, functions, flows, spools_m, pressures, compression, pump_flows, near_main) -> dict:
    """Each section's bypass table: its pump's bypass area while the pump's other sections are at neutral."""
    out: dict[str, float] = {}
    moved = section_spools(layout, spools_m)
    for i, section in enumerate(layout.sections):
        k = section.pump
        others = [j for j, s in enumerate(layout.sections) if s.pump == k and j != i]
        if np.any(np.abs(moved[others]) >= p.SPOOL_DEAD_BAND):
            continue
        if near_main[k]:
            continue
        q = pump_flows[k] - _section_meter_in(i, section, functions, flows) - compression[k]
        out[f"{section.name}_bypass_area_m2"] = _area(q, pressures[k] - pressures[2 + k], MIN_BYPASS_DROP_PA)
    return out


def pump_bypass_area(first: np.ndarray, second: np.ndarray, neutral: float, *more: np.ndarray) -> np.ndarray:
    """A pump's bypass area with its sections anywhere, from each section's table (the pump's bypass area with that
    section at ``u`` and the others at neutral) and the area with all at neutral: the resistances ``1/A^2`` of
    sections in series add, so ``1/A^2 = sum 1/A_i^2 - (n - 1)/A0^2``."""
    areas = [np.maximum(a, CLOSED_AREA) for a in (first, second, *more)]
    resistance = sum(1.0 / np.square(a) for a in areas) - (len(areas) - 1) / neutral**2
    return 1.0 / np.sqrt(np.maximum(resistance, 1.0 / np.square(functools.reduce(np.minimum, areas))))


class LearnedValve:
    """The valve's passage areas from its tables (:func:`hexgym.mbl.schema.valve_tables` of ``layout``):
    ``valve(spools_m) -> SpoolAreas``.

    A passage is closed in the spool's dead band and on the other side of neutral (pump -> a and b -> tank open
    only with a positive spool); elsewhere the table's area, at least zero. The layout's priority valves are its
    structure (:func:`hexgym.hydraulics.circuit.priority_shares`, the data sheet's), applied to the learned areas.
    """

    def __init__(self, tables: dict[str, MBLTable], layout: ValveLayout = DEFAULT_LAYOUT) -> None:
        missing = sorted(set(valve_tables(layout)) - set(tables))
        if missing:
            raise ValueError(f"the circuit model needs the valve tables {missing}")
        self.tables, self.layout = tables, layout
        # each pump's sections (indices in the layout) and its bypass area with all at neutral
        self._sections = [[i for i, s in enumerate(layout.sections) if s.pump == k] for k in (0, 1)]
        self._neutral = [
            float(np.mean([tables[f"{layout.sections[i].name}_bypass"]((0.0,)) for i in sections]))
            for sections in self._sections
        ]
        if min(self._neutral) <= 0.0:
            raise ValueError(f"the bypass tables give a closed centre at neutral ({self._neutral} m^2)")

    def __call__(self, spools_m: np.ndarray) -> SpoolAreas:
        """The passage areas (m^2, the layout's section order) at these spools (m)."""
        u = np.asarray(spools_m, dtype=float)
        n = len(self.layout.sections)
        area = {k: np.zeros(n) for k in VALVE_PASSAGES}
        moved = section_spools(self.layout, u)
        for i, section in enumerate(self.layout.sections):
            x = moved[i]
            area["bypass"][i] = self._area(section.name, "bypass", x)
            if abs(x) >= p.SPOOL_DEAD_BAND:
                for key in ("pa", "bt") if x > 0 else ("pb", "at"):
                    if key in section.areas:
                        area[key][i] = self._area(section.name, key, x)
        stick2, swing_share, boom_share = priority_shares(self.layout, u)
        area["pa"][_STICK] *= swing_share
        area["pb"][_STICK] *= swing_share
        area["pa"][stick2] *= boom_share
        area["pb"][stick2] *= boom_share
        pump_bypass = np.array(
            [
                pump_bypass_area(*area["bypass"][sections[:2]], neutral, *area["bypass"][sections[2:]])
                for sections, neutral in zip(self._sections, self._neutral, strict=True)
            ]
        )
        extra = {}
        for passage, function in REGENERATION_SPOOLS.items():
            if passage in self.layout.regeneration_passages:
                x = u[FUNCTIONS.index(function)]
                opens = REGENERATION[passage].side * x >= p.SPOOL_DEAD_BAND
                extra[passage] = self._area(passage, None, x) if opens else 0.0
        if "stick_unloading" in self.layout.regeneration_passages:
            extra["stick_unloading"] = p.STICK_UNLOADING_AREA * float(metering_fraction(u[_STICK])[0])
        return SpoolAreas(**area, pump_bypass=pump_bypass, **extra)

    def _area(self, section: str, passage: str | None, u: float) -> float:
        name = section if passage is None else f"{section}_{passage}"
        return max(float(self.tables[name]((u,))), 0.0)

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

import math

import numpy as np

from hexgym.hydraulics.circuit import FUNCTIONS, PUMP_OF, SWING_DISPLACEMENT_RAD, SpoolAreas, compliance, orifice_law
from hexgym.machine import parameters as p
from hexgym.mbl.schema import TABLE_SETS, VALVE_PASSAGES
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
_SWEPT = SWING_DISPLACEMENT_RAD * p.SWING_REDUCTION  # m^3 per radian of the upper structure
_SHARE = p.SWING_MOTOR_EXTERNAL_LEAK_SHARE


def _area(q: float, dp: float, min_drop: float = MIN_DROP_PA) -> float:
    """Orifice area passing ``q`` at ``dp`` (the circuit's orifice law), or NaN if the sample is not clear."""
    if q <= 0.0 or dp < min_drop:
        return math.nan
    return q / (p.DISCHARGE_COEFFICIENT * float(orifice_law(np.array(dp))[0]))


def identify_areas(
    pressures: np.ndarray,
    pressure_rates: np.ndarray,
    volumes: np.ndarray,
    pump_flows: np.ndarray,
    spools_m: np.ndarray,
    ext_m: np.ndarray,
    vel_mps: np.ndarray,
    swing_rate: float,
) -> dict[str, float]:
    """One sample (m^2, or NaN) of every ``circuit`` table's output from one instant's measurements.

    ``pressures``, ``pressure_rates`` (Pa, Pa/s) and oil ``volumes`` (m^3) of the circuit's nodes
    (:data:`hexgym.hydraulics.circuit.NODES`: pumps, NFC signals, boom/stick/bucket head and rod,
    swing ports a and b): the oil a node's compression takes, ``V / beta dp/dt``, is part of the
    flows; ``pump_flows`` m^3/s; ``spools_m`` (swing, boom, stick, bucket); cylinder extensions and
    velocities (boom, stick, bucket); ``swing_rate`` rad/s.
    """
    compression = volumes * compliance(pressures)[0] * pressure_rates  # m^3/s into each node's oil
    out = {spec.output: math.nan for spec in TABLE_SETS["circuit"].values()}
    meter_in = [0.0, 0.0]  # per pump, known only where every open section's flow is
    known = [True, True]
    for j, f in enumerate(("boom", "stick", "bucket")):
        u, v, pump = spools_m[j + 1], vel_mps[j], PUMP_OF[f]
        head, rod = 4 + 2 * j, 5 + 2 * j
        flow, areas = _cylinder(
            f, u, v, ext_m[j], pressures[pump], pressures[head], pressures[rod], compression[head], compression[rod]
        )
        out.update(areas)
        meter_in[pump] += flow
        known[pump] &= not math.isnan(flow)
    flow, areas = _swing(spools_m[0], swing_rate, pressures[1], pressures[10], pressures[11], compression[10:12])
    out.update(areas)
    meter_in[1] += flow
    known[1] &= not math.isnan(flow)
    for f in FUNCTIONS:
        pump = PUMP_OF[f]
        partner = next(g for g in FUNCTIONS if g != f and PUMP_OF[g] == pump)
        if abs(spools_m[FUNCTIONS.index(partner)]) >= p.SPOOL_DEAD_BAND or not known[pump]:
            continue
        if pressures[pump] > p.MAIN_RELIEF - RELIEF_MARGIN_PA:
            continue
        q = pump_flows[pump] - meter_in[pump] - compression[pump]
        out[f"{f}_bypass_area_m2"] = _area(q, pressures[pump] - pressures[2 + pump], MIN_BYPASS_DROP_PA)
    return out


def _cylinder(
    f: str, u: float, v: float, ext: float, p_pump: float, p_head: float, p_rod: float, c_head: float, c_rod: float
) -> tuple[float, dict[str, float]]:
    """(meter-in flow from the pump or NaN if unknown, {output: area sample}) of one cylinder; ``c_*``:
    the chambers' compression flows."""
    cyl = p.CYLINDERS[f]
    if abs(u) < p.SPOOL_DEAD_BAND:
        return 0.0, {}  # the section passes nothing to the cylinder
    extending = u > 0.0
    speed = v if extending else -v
    a_in, a_out = (cyl.head_area, cyl.rod_area) if extending else (cyl.rod_area, cyl.head_area)
    p_in, p_out = (p_head, p_rod) if extending else (p_rod, p_head)
    c_in, c_out = (c_head, c_rod) if extending else (c_rod, c_head)
    q_in, q_out = a_in * speed + c_in, a_out * speed - c_out
    # The inlet's continuity gives the meter-in flow at any speed (a held cylinder's closed load check
    # passes none) unless make-up oil from tank or the port relief takes part.
    fed = MIN_PORT_PA < p_in < p.LINE_RELIEF[f] - RELIEF_MARGIN_PA
    flow = q_in if fed else math.nan
    if speed < MIN_SPEED_MPS:
        return flow, {}  # stalled, held or overrun backwards: no clear metering
    inlet, outlet = ("pa", "bt") if extending else ("pb", "at")
    out = {}
    if p_in > MIN_PORT_PA and p_pump - p_in > _CHECK_OPEN and p_pump < p.MAIN_RELIEF - RELIEF_MARGIN_PA:
        out[f"{f}_{inlet}_area_m2"] = _area(q_in, p_pump - p_in)
    to_end = cyl.stroke - ext if extending else ext
    if to_end > _CUSHION_CLEAR and p_out < p.LINE_RELIEF[f] - RELIEF_MARGIN_PA:
        seen = _area(q_out, p_out)  # the valve's passage in series with the cushion's open port
        port = cyl.count * p.CUSHION_PORT_AREA
        out[f"{f}_{outlet}_area_m2"] = 1.0 / math.sqrt(max(1.0 / seen**2 - 1.0 / port**2, 1.0 / port**2))
    return flow, out


def _swing(
    u: float, rate: float, p_pump: float, pa: float, pb: float, compression: np.ndarray
) -> tuple[float, dict[str, float]]:
    """(meter-in flow from pump 2 or NaN if unknown, {output: area sample}) of the swing motor;
    ``compression``: the ports' compression flows."""
    if abs(u) < p.SPOOL_DEAD_BAND:
        return 0.0, {}
    positive = u > 0.0
    cross = (1.0 - _SHARE) * p.SWING_MOTOR_LEAKAGE * (pa - pb)
    drain = 0.5 * _SHARE * p.SWING_MOTOR_LEAKAGE
    into_a = _SWEPT * rate + cross + drain * pa + compression[0]  # what must enter port a
    into_b = -_SWEPT * rate - cross + drain * pb + compression[1]
    q_in, q_out = (into_a, -into_b) if positive else (into_b, -into_a)
    p_in, p_out = (pa, pb) if positive else (pb, pa)
    if abs(pa - pb) > p.SWING_RELIEF - RELIEF_MARGIN_PA:
        return math.nan, {}  # the crossover reliefs may pass oil
    flow = q_in if p_in > MIN_PORT_PA else math.nan  # the inlet's continuity, unless make-up oil enters
    if (rate if positive else -rate) < MIN_SWING_RATE:
        return flow, {}  # starting, braking or reversing: the ports' oil, not the valve, rules
    inlet, outlet = ("pa", "bt") if positive else ("pb", "at")
    out = {}
    if p_in > MIN_PORT_PA and p_pump - p_in > _CHECK_OPEN:
        out[f"swing_{inlet}_area_m2"] = _area(q_in, p_pump - p_in)
    out[f"swing_{outlet}_area_m2"] = _area(q_out, p_out)
    return flow, out


def pump_bypass_area(first: np.ndarray, second: np.ndarray, neutral: float) -> np.ndarray:
    """A pump's bypass area with both sections anywhere, from each section's table (the pump's bypass
    area with that section at ``u`` and its partner at neutral) and the area with both at neutral:
    the resistances ``1/A^2`` of sections in series add, so ``1/A^2 = 1/A1^2 + 1/A2^2 - 1/A0^2``."""
    first, second = np.maximum(first, CLOSED_AREA), np.maximum(second, CLOSED_AREA)
    resistance = 1.0 / np.square(first) + 1.0 / np.square(second) - 1.0 / neutral**2
    return 1.0 / np.sqrt(np.maximum(resistance, 1.0 / np.square(np.minimum(first, second))))


class LearnedValve:
    """The valve's passage areas from the ``circuit`` tables: ``valve(spools_m) -> SpoolAreas``.

    A passage is closed in the spool's dead band and on the other side of neutral (pump -> a and
    b -> tank open only with a positive spool); elsewhere the table's area, at least zero.
    """

    def __init__(self, tables: dict[str, MBLTable]) -> None:
        missing = sorted(set(TABLE_SETS["circuit"]) - set(tables))
        if missing:
            raise ValueError(f"the circuit model needs the valve tables {missing}")
        self.tables = tables
        # each pump's two sections (indices in FUNCTIONS) and its bypass area with both at neutral
        self._sections = [[i for i, f in enumerate(FUNCTIONS) if PUMP_OF[f] == k] for k in (0, 1)]
        self._neutral = [
            float(np.mean([tables[f"{FUNCTIONS[i]}_bypass"]((0.0,)) for i in sections])) for sections in self._sections
        ]
        if min(self._neutral) <= 0.0:
            raise ValueError(f"the bypass tables give a closed centre at neutral ({self._neutral} m^2)")

    def __call__(self, spools_m: np.ndarray) -> SpoolAreas:
        """The passage areas (m^2, ``FUNCTIONS`` order) at these spools (m)."""
        u = np.asarray(spools_m, dtype=float)
        area = {k: np.zeros(len(FUNCTIONS)) for k in VALVE_PASSAGES}
        for i, f in enumerate(FUNCTIONS):
            area["bypass"][i] = self._area(f, "bypass", u[i])
            if abs(u[i]) >= p.SPOOL_DEAD_BAND:
                for key in ("pa", "bt") if u[i] > 0 else ("pb", "at"):
                    area[key][i] = self._area(f, key, u[i])
        pump_bypass = np.array(
            [
                pump_bypass_area(area["bypass"][a], area["bypass"][b], neutral)
                for (a, b), neutral in zip(self._sections, self._neutral, strict=True)
            ]
        )
        return SpoolAreas(**area, pump_bypass=pump_bypass)

    def _area(self, f: str, passage: str, u: float) -> float:
        return max(float(self.tables[f"{f}_{passage}"]((u,))), 0.0)

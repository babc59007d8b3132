"""Relief settings from a machine's logs: the pressure at which each relief passes the oil the log says it passes.

A relief (:func:`hexgym.hydraulics.circuit.relief_area`) starts to open at its setting and is fully open
:data:`~hexgym.machine.parameters.RELIEF_OVERRIDE` above it, where it passes its rated flow. Where a log shows a
relief passing a flow ``q`` that continuity gives at a pressure drop ``dp``, the setting is the one at which the
circuit's relief law passes ``q`` at ``dp`` (:func:`setting_from_flow`). Each relief is seen where nothing else can
take the oil:

- the **swing crossover reliefs** while the upper structure brakes with its spool at neutral: the motor pumps
  ``swept x rate`` (less its leaks and the outlet's compression) from the outlet port over the relief to the inlet;
- a cylinder's **port reliefs** while the cylinder moves with its spool at neutral and the chamber it compresses is
  near the setting (a boom stopped on its way down, a load pushing the stick): that chamber's displacement flow
  less its compression and the piston's leak;
- the **main relief** while a pump's pressure is near the setting and steady with every function that pump
  feeds stalled: the pump's delivery (the regulator's law, :func:`.derive.estimated_pump_flows`) less its line's
  compression and the bypass's flow.

A setting is the median over those rows, with a standard error over the logs (rows of one log are correlated); one
seen in fewer than :data:`MIN_ROWS` rows or :data:`MIN_LOGS` logs, with a standard error above
:data:`MAX_STANDARD_ERROR` or more than :data:`PLAUSIBLE` from the data sheet's, is not identified (the packaged
setting stands, and the report says why).
"""

from __future__ import annotations

import math

import numpy as np

from hexgym.hydraulics.circuit import (
    DEFAULT_LAYOUT,
    NODES,
    orifice_law,
    relief_area,
    smoothstep,
)
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.mbl.valve import SWING_SWEPT, nfc_orifice_flow, swing_port_leak
from hexgym_lab.machine_logs import derive

NEAR_SETTING = 0.8  # a pressure above this share of the data sheet's setting may be the relief's
MIN_MOTION = 0.005  # m/s of a cylinder (rad/s of the swing: MIN_SWING_RATE) below which it counts as still
MIN_SWING_RATE = 0.05  # rad/s: a slower braking swing passes too little oil to tell the setting
MIN_RELIEF_FLOW = 0.2  # share of the rated flow: less says little about the setting (a held load creeps)
STEADY_PA_S = 5e6  # Pa/s: a pump's pressure changing faster is not on its relief's plateau
MIN_ROWS = 20  # fewer rows: not identified
MIN_LOGS = 2  # ... or from fewer logs
PLAUSIBLE = 0.25  # an estimate further than this share from the data sheet's setting is not trusted
MAX_STANDARD_ERROR = 0.5e6  # Pa: logs that disagree more than this (seen only in transients) are not trusted
_CLEAR = p.CUSHION_LENGTH + 0.02  # m from a stroke end: the stops' and cushions' spikes are not the relief's


def setting_from_flow(dp: np.ndarray, q: np.ndarray, rated_flow: float) -> np.ndarray:
    """The settings (Pa) at which a relief rated ``rated_flow`` passes ``q`` (m^3/s) at ``dp`` (Pa): the circuit's
    relief law (smoothstep opening over the override, full area by :func:`relief_area`, the orifice law) solved by
    bisection; a flow the relief cannot pass at ``dp`` gives ``dp - override`` (fully open)."""
    dp, q = np.asarray(dp, float), np.asarray(q, float)
    lo, hi = dp - p.RELIEF_OVERRIDE, dp.copy()  # fully open .. closed
    law = p.DISCHARGE_COEFFICIENT * orifice_law(dp)[0]
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        passes = relief_area(mid, rated_flow) * law * smoothstep((dp - mid) / p.RELIEF_OVERRIDE)[0]
        more = passes > q  # opens too far at this setting: the setting is higher
        lo, hi = np.where(more, mid, lo), np.where(more, hi, mid)
    return 0.5 * (lo + hi)


def _closed(rows: derive.LogRows, function: str) -> np.ndarray:
    return np.abs(rows.spools_m[:, kinematics.JOINTS.index(function)]) < p.SPOOL_DEAD_BAND


def swing_rows(rows: derive.LogRows, compression: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(dp, q) of the swing crossover relief while the swing brakes with its spool at neutral."""
    a, b = NODES.index("swing_a"), NODES.index("swing_b")
    rate = rows.swing_rate
    forward = rate > 0  # the motor takes oil in at port a and pushes it out at b
    p_out = np.where(forward, rows.pressures[:, b], rows.pressures[:, a])
    p_in = np.where(forward, rows.pressures[:, a], rows.pressures[:, b])
    c_out = np.where(forward, compression[:, b], compression[:, a])
    dp = p_out - p_in
    q = SWING_SWEPT * np.abs(rate) - swing_port_leak(p_out, p_in) - c_out
    pick = rows.usable & _closed(rows, "swing") & (np.abs(rate) >= MIN_SWING_RATE)
    pick &= (dp > NEAR_SETTING * p.SWING_RELIEF) & (q > MIN_RELIEF_FLOW * p.LINE_RELIEF_RATED_FLOW)
    return dp[pick], q[pick]


def line_rows(rows: derive.LogRows, compression: np.ndarray, cylinder: str) -> tuple[np.ndarray, np.ndarray]:
    """(dp, q) of ``cylinder``'s port reliefs while it moves with its spool at neutral, compressing a chamber near
    the setting (the head while it retracts, the rod while it extends)."""
    j = kinematics.FRONT_CYLINDERS.index(cylinder)
    cyl = p.CYLINDERS[cylinder]
    head, rod = NODES.index(f"{cylinder}_head"), NODES.index(f"{cylinder}_rod")
    v, ext = rows.vel[:, j], rows.ext[:, j]
    leak = cyl.count * p.CYLINDER_LEAKAGE * (rows.pressures[:, head] - rows.pressures[:, rod])  # head -> rod
    q_head = cyl.count * cyl.head_area * -v - compression[:, head] - leak
    q_rod = cyl.count * cyl.rod_area * v - compression[:, rod] + leak
    retracting = v < 0
    dp = np.where(retracting, rows.pressures[:, head], rows.pressures[:, rod])
    q = np.where(retracting, q_head, q_rod)
    steady = np.abs(np.where(retracting, rows.rates[:, head], rows.rates[:, rod])) < STEADY_PA_S
    pick = rows.usable & _closed(rows, cylinder) & (np.abs(v) >= MIN_MOTION) & steady
    pick &= (ext > _CLEAR) & (ext < cyl.stroke - _CLEAR)
    pick &= (dp > NEAR_SETTING * p.LINE_RELIEF[cylinder]) & (q > MIN_RELIEF_FLOW * p.LINE_RELIEF_RATED_FLOW)
    return dp[pick], q[pick]


def main_rows(rows: derive.LogRows, compression: np.ndarray, max_flow: float) -> tuple[np.ndarray, np.ndarray]:
    """(dp, q) of the main reliefs while a pump's pressure is near the setting and steady, every function it feeds
    with its spool open stalled (the swing's open spool excluded: its crossover relief sits below the main)."""
    flows = rows.pump_flows(max_flow)
    dps, qs = [], []
    for k in (0, 1):
        pick = rows.usable & (rows.pressures[:, k] > NEAR_SETTING * p.MAIN_RELIEF)
        pick &= np.abs(rows.rates[:, k]) < STEADY_PA_S
        fed = {s.function for s in DEFAULT_LAYOUT.sections if s.pump == k}
        for f in fed:
            open_ = ~_closed(rows, f)
            if f == "swing":
                pick &= ~open_
            else:
                moving = np.abs(rows.vel[:, kinematics.FRONT_CYLINDERS.index(f)]) >= MIN_MOTION
                pick &= ~(open_ & moving)
        pick &= np.any([~_closed(rows, f) for f in fed if f != "swing"], axis=0)  # something pushes on the pump
        q = flows[:, k] - compression[:, k] - compression[:, 2 + k] - nfc_orifice_flow(rows.pressures[:, 2 + k])
        pick &= q > MIN_RELIEF_FLOW * p.MAIN_RELIEF_RATED_FLOW
        dps.append(rows.pressures[pick, k])
        qs.append(q[pick])
    return np.concatenate(dps), np.concatenate(qs)


def _summary(per_log: list[np.ndarray], packaged: float) -> dict[str, object]:
    """The setting over all logs' estimates: median, standard error by log, rows and logs; or why not."""
    logs = [e for e in per_log if len(e)]
    values = np.concatenate(logs) if logs else np.zeros(0)
    base = {"rows": int(len(values)), "logs": len(logs), "packaged_pa": packaged}
    if len(values) < MIN_ROWS or len(logs) < MIN_LOGS:
        return base | {"identified": False, "why": f"seen in {len(values)} rows of {len(logs)} logs; {MIN_ROWS} rows "
                                                   f"from {MIN_LOGS} logs needed"}  # fmt: skip
    value = float(np.median(values))
    medians = np.array([np.median(e) for e in logs])
    error = float(np.std(medians, ddof=1) / math.sqrt(len(medians)))
    base |= {"value_pa": value, "standard_error_pa": error, "relative_to_packaged": value / packaged}
    if error > MAX_STANDARD_ERROR:
        why = f"the logs disagree (standard error {error / 1e6:.2f} MPa > {MAX_STANDARD_ERROR / 1e6:g}): transients?"
        return base | {"identified": False, "why": why}
    if abs(value / packaged - 1.0) > PLAUSIBLE:
        return base | {"identified": False, "why": f"{value / 1e6:.1f} MPa is more than {PLAUSIBLE:.0%} from the data "
                                                   "sheet's setting: not trusted"}  # fmt: skip
    return base | {"identified": True}


def identify_reliefs(all_rows: list[derive.LogRows], max_flow: float) -> dict[str, dict]:
    """Each relief's setting over the logs (see the module): ``main``, ``swing`` and ``line_<cylinder>``, each a
    summary with ``identified`` and, where it is, ``value_pa`` and ``standard_error_pa``."""
    found: dict[str, list[np.ndarray]] = {"main": [], "swing": []} | {f"line_{c}": [] for c in p.LINE_RELIEF}
    for rows in all_rows:
        compression = derive.node_compression(rows)
        dp, q = main_rows(rows, compression, max_flow)
        found["main"].append(setting_from_flow(dp, q, p.MAIN_RELIEF_RATED_FLOW))
        dp, q = swing_rows(rows, compression)
        found["swing"].append(setting_from_flow(dp, q, p.LINE_RELIEF_RATED_FLOW))
        for c in p.LINE_RELIEF:
            dp, q = line_rows(rows, compression, c)
            found[f"line_{c}"].append(setting_from_flow(dp, q, p.LINE_RELIEF_RATED_FLOW))
    packaged = {"main": p.MAIN_RELIEF, "swing": p.SWING_RELIEF} | {f"line_{c}": v for c, v in p.LINE_RELIEF.items()}
    return {name: _summary(per_log, packaged[name]) for name, per_log in found.items()}


def relief_hydraulics(reliefs: dict[str, dict]) -> dict[str, object]:
    """The identified settings as a hydraulics file's ``relief`` section (empty where none is identified)."""
    out: dict[str, object] = {}
    if reliefs["main"]["identified"]:
        out["main_pa"] = reliefs["main"]["value_pa"]
    if reliefs["swing"]["identified"]:
        out["swing_pa"] = reliefs["swing"]["value_pa"]
    lines = {c: reliefs[f"line_{c}"]["value_pa"] for c in p.LINE_RELIEF if reliefs[f"line_{c}"]["identified"]}
    return out | ({"line_pa": lines} if lines else {})

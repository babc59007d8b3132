"""From what a machine measures to what the valve's identification needs, row by row.

:func:`hexgym.mbl.valve.identify_areas` takes the circuit's node pressures and their rates, the nodes' oil volumes,
the pumps' flows, the spools, the cylinders' extensions and velocities and the swing rate. A machine log
(:mod:`.signals`) has the spools, the pump and chamber pressures and the joint angles, noisy (pressures σ 0.2 MPa,
angles σ 0.1°) and sampled 50-200 Hz, not necessarily evenly. Here each log is

- put on an even time base at its median period (linear interpolation; a logger's jitter is a fraction of it);
- smoothed and differentiated by Savitzky-Golay filters (:data:`SMOOTH_S` wide, quadratic): the pressures and their
  rates; the cylinder extensions (from the angles through the kinematics' cylinder lengths) and their velocities;
  the swing angle and its rate;
- given the two signals a machine does not measure. The **NFC signal pressures** (the centre bypass's end, which the
  pumps' negative flow control reads) follow from the pump pressures and the *packaged* bypass tables: in steady
  flow the bypass passage and the NFC orifice (the data sheet's) pass the same oil, so
  ``p_sig = p_pump A_b^2 / (A_b^2 + A_nfc^2)``, capped by the NFC relief. The **pump flows** follow from the
  regulator's law (:meth:`hexgym.hydraulics.circuit.HydraulicCircuit.pump_flows`): the NFC displacement
  (:meth:`~hexgym.hydraulics.circuit.HydraulicCircuit.nfc_target` through the servo's first-order lag) under the
  horsepower limit, with the pump's maximum flow the data sheet's or the one the logs give
  (:func:`identify_pump_max_flow`).

The bypass tables themselves cannot be learned without the NFC signal pressure (it is what would measure their
flow); the fit keeps the packaged ones and says so.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter

from hexgym.hydraulics.circuit import DEFAULT_LAYOUT, NODES, HydraulicCircuit
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.mbl.table import load_tables
from hexgym.mbl.valve import (
    PACKAGED_RELIEFS,
    LearnedValve,
    ReliefSettings,
    compression_flows,
    identify_areas,
    nfc_orifice_flow,
)
from hexgym_lab.machine_logs import signals as s

SMOOTH_S = 0.15  # s: the Savitzky-Golay window (quadratic); wider rounds off the ~2 Hz modes (tests)
SAMPLE_EVERY_S = 0.05  # s between the rows a log gives (rows closer than this are near copies)
# Pump max flow from the bucket alone at full spool (one pump, below its power limit, the bypass closed)
FULL_SPOOL_MM = 10.5
HELD_S = 0.5  # the spool held this long before a row counts (the valve's and the regulator's transients are over)
MIN_PUMP_ROWS = 20  # fewer such rows: the logs do not determine the pump's maximum flow
SIGNALS_USED = (*s.SPOOLS, *s.PUMP_PRESSURES, *s.CHAMBER_PRESSURES, *s.JOINT_ANGLES)
_HEAD = [NODES.index(f"{c}_head") for c in kinematics.FRONT_CYLINDERS]


@dataclass
class LogRows:
    """One log's rows for the identification, on its even time base (``n`` rows): spools (m), the circuit's node
    pressures and rates (Pa, Pa/s, :data:`~hexgym.hydraulics.circuit.NODES`; the NFC signals estimated), cylinder
    extensions and velocities (m, m/s), swing rate (rad/s), and ``usable`` (False near the ends, where the
    filters have no data on one side, and where a signal is missing)."""

    name: str
    sha256: str
    t: np.ndarray
    spools_m: np.ndarray
    pressures: np.ndarray
    rates: np.ndarray
    ext: np.ndarray
    vel: np.ndarray
    swing_rate: np.ndarray
    usable: np.ndarray
    warnings: tuple[str, ...] = ()  # check-log's warnings on the log

    def pump_flows(self, max_flow: float) -> np.ndarray:
        """(n, 2) pump flows (m^3/s) by the regulator's law at this maximum flow (see the module)."""
        return estimated_pump_flows(self.t, self.pressures, max_flow)


def file_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _even(t: np.ndarray, values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Columns of ``values`` interpolated onto ``grid`` (NaN samples skipped; NaN where a column has none)."""
    out = np.full((len(grid), values.shape[1]), np.nan)
    for j in range(values.shape[1]):
        good = np.isfinite(values[:, j])
        if good.sum() >= 2:
            out[:, j] = np.interp(grid, t[good], values[good, j])
    return out


def _window(period: float) -> int:
    """An odd Savitzky-Golay window of :data:`SMOOTH_S`, at least 5 samples."""
    n = max(5, int(round(SMOOTH_S / period)))
    return n if n % 2 else n + 1


def extensions_of(angles: np.ndarray) -> np.ndarray:
    """(n, 3) cylinder extensions (m from fully retracted) of (n, 4) joint angles, through the kinematics'
    cylinder lengths (tabulated, :func:`hexgym_lab.machine_logs.signals.angles_from_extensions`' inverse)."""
    out = np.empty((len(angles), 3))
    for i, name in enumerate(kinematics.FRONT_CYLINDERS):
        lengths, table_angles = s._length_table(name)
        out[:, i] = np.interp(angles[:, i + 1], table_angles, lengths) - p.CYLINDERS[name].retracted_length
    return out


def log_rows(log: s.MachineLog, sha256: str = "") -> LogRows:
    """The rows of ``log`` (see the module); ValueError naming the log where it lacks spools or angles."""
    u, q = log.spools_mm(), log.angles()
    if u is None or q is None:
        raise ValueError(f"{log.name}: no spools (or pilots) or no joint angles (or strokes): nothing to fit")
    order = np.argsort(log.t, kind="stable")
    t = log.t[order]
    period = float(np.median(np.diff(t)))
    grid = t[0] + period * np.arange(int(np.floor((t[-1] - t[0]) / period)) + 1)
    n, w = len(grid), _window(period)
    if n < 2 * w:
        raise ValueError(f"{log.name}: {t[-1] - t[0]:.2f} s long; a log to fit needs {2 * w * period:.1f} s at least")
    pressure_names = (*s.PUMP_PRESSURES, *s.CHAMBER_PRESSURES)
    measured = np.column_stack([log.signals.get(k, np.full(len(t), np.nan))[order] for k in pressure_names])
    qa = q[order].copy()
    qa[:, 0] = np.unwrap(qa[:, 0]) if np.all(np.isfinite(qa[:, 0])) else qa[:, 0]
    spools = _even(t, u[order], grid) * 1e-3
    angles = _even(t, qa, grid)
    chambers = _even(t, measured, grid)
    smooth = np.where(np.isfinite(chambers), 0.0, np.nan)  # NaN stays where a signal is missing
    ext_raw = extensions_of(np.nan_to_num(angles))
    ext = savgol_filter(ext_raw, w, 2, axis=0)
    vel = savgol_filter(ext_raw, w, 2, deriv=1, delta=period, axis=0)
    swing_rate = savgol_filter(np.nan_to_num(angles[:, 0]), w, 2, deriv=1, delta=period)
    press = savgol_filter(np.nan_to_num(chambers), w, 2, axis=0) + smooth
    press_rate = savgol_filter(np.nan_to_num(chambers), w, 2, deriv=1, delta=period, axis=0) + smooth
    pressures, rates = np.zeros((n, len(NODES))), np.zeros((n, len(NODES)))
    keep = [0, 1] + list(range(4, len(NODES)))  # the logged nodes: pumps and chambers (not the NFC signals)
    pressures[:, keep], rates[:, keep] = press, press_rate
    pressures[:, 2:4] = nfc_signal_pressures(pressures[:, 0:2], np.nan_to_num(spools))
    rates[:, 2:4] = np.gradient(pressures[:, 2:4], period, axis=0)
    usable = np.all(np.isfinite(spools), axis=1) & np.all(np.isfinite(angles), axis=1)
    usable[: w // 2 + 1] = usable[-(w // 2 + 1) :] = False
    return LogRows(log.name, sha256, grid, np.nan_to_num(spools), pressures, rates, ext, vel, swing_rate, usable)


def _packaged_valve() -> LearnedValve:
    return LearnedValve(load_tables(None, "circuit"), DEFAULT_LAYOUT)


def nfc_signal_pressures(pump_pa: np.ndarray, spools_m: np.ndarray) -> np.ndarray:
    """(n, 2) NFC signal pressures (Pa) estimated from the pump pressures and the packaged bypass tables: the bypass
    passage and the NFC orifice in series pass the same oil (capped at the NFC relief's setting)."""
    valve = _packaged_valve()
    distinct, index = np.unique(spools_m, axis=0, return_inverse=True)  # spools are held: far fewer distinct rows
    bypass = np.array([valve(u).pump_bypass for u in distinct])[index.ravel()]  # (n, 2) m^2
    share = bypass**2 / (bypass**2 + p.NFC_ORIFICE_AREA**2)
    return np.minimum(np.maximum(pump_pa, 0.0) * share, p.NFC_RELIEF)


def estimated_pump_flows(t: np.ndarray, pressures: np.ndarray, max_flow: float) -> np.ndarray:
    """(n, 2) pump flows (m^3/s): the NFC displacement of the signal pressures through the regulator's lag, under
    the horsepower limit (:meth:`~hexgym.hydraulics.circuit.HydraulicCircuit.pump_flows`)."""
    target, _ = HydraulicCircuit.nfc_target(pressures[:, 2:4])
    d = np.empty_like(target)
    d[0] = target[0]
    for k in range(1, len(t)):
        a = 1.0 - math.exp(-(t[k] - t[k - 1]) / p.PUMP_REGULATOR_TIME_CONSTANT)
        d[k] = d[k - 1] + a * (target[k] - d[k - 1])
    pumps = pressures[:, 0:2]
    return np.array([HydraulicCircuit.pump_flows(pr, dk, max_flow)[0] for pr, dk in zip(pumps, d, strict=True)])


def area_samples(rows: LogRows, max_flow: float, reliefs: ReliefSettings = PACKAGED_RELIEFS) -> list[dict[str, float]]:
    """Every :data:`SAMPLE_EVERY_S` of ``rows``' usable rows: the spools (``<joint>_spool_m``) and each passage's
    area sample (:func:`hexgym.mbl.valve.identify_areas`; NaN where the passage does not meter clearly). Rows with
    the stick driven into its stroke end give none (its relief, not the valve, sets the pressure); ``reliefs``: the
    unit's settings (no samples near them)."""
    period = float(np.median(np.diff(rows.t)))
    every = max(1, int(round(SAMPLE_EVERY_S / period)))
    flows = rows.pump_flows(max_flow)
    circuit = HydraulicCircuit(layout=DEFAULT_LAYOUT)
    stick, stroke = 1, p.CYLINDERS["stick"].stroke
    out = []
    for k in np.flatnonzero(rows.usable)[::every]:
        u, ext = rows.spools_m[k], rows.ext[k]
        margin = p.STROKE_END_MARGIN
        if (ext[stick] <= margin and u[2] < 0) or (ext[stick] >= stroke - margin and u[2] > 0):
            continue
        volumes = circuit.volumes(ext)
        sample = identify_areas(rows.pressures[k], rows.rates[k], volumes, flows[k], u, ext, rows.vel[k],
                                float(rows.swing_rate[k]), DEFAULT_LAYOUT, reliefs)  # fmt: skip
        out.append({f"{j}_spool_m": float(u[i]) for i, j in enumerate(kinematics.JOINTS)} | sample)
    return out


def pump_flow_rows(rows: LogRows) -> np.ndarray:
    """Pump 1's delivered flow (m^3/s) at each row where the bucket alone is at full spool, held for
    :data:`HELD_S`, and pump 1 is below its power limit: the bucket cylinder's displacement flow (head area x
    speed out, rod area x speed in), the oil its inlet chamber's and pump 1's line's pressure changes take
    (``V / beta dp/dt``), and the centre bypass's (nearly closed at full spool: the NFC orifice's at the estimated
    signal pressure)."""
    u = rows.spools_m * 1e3
    period = float(np.median(np.diff(rows.t)))
    held = max(1, int(round(HELD_S / period)))
    bucket = np.abs(u[:, 3]) >= FULL_SPOOL_MM
    alone = np.all(np.abs(u[:, :3]) < p.SPOOL_DEAD_BAND * 1e3, axis=1)
    ok = bucket & alone & rows.usable
    run = np.convolve(ok.astype(float), np.ones(held), mode="full")[: len(ok)] >= held  # ok for the last held rows
    below = rows.pressures[:, 0] * p.PUMP_MAX_FLOW * 1.2 + rows.pressures[:, 1] * p.PUMP_MAX_FLOW < p.PUMP_POWER_LIMIT
    ext, stroke = rows.ext[:, 2], p.CYLINDERS["bucket"].stroke
    clear = (ext > p.CUSHION_LENGTH + 0.02) & (ext < stroke - p.CUSHION_LENGTH - 0.02)
    pick = np.flatnonzero(run & below & clear)
    cyl = p.CYLINDERS["bucket"]
    extending = u[pick, 3] > 0
    area = np.where(extending, cyl.head_area, cyl.rod_area) * cyl.count
    inlet = np.where(extending, NODES.index("bucket_head"), NODES.index("bucket_rod"))
    compression = node_compression(rows, pick)
    chamber = compression[np.arange(len(pick)), inlet]
    nfc = nfc_orifice_flow(rows.pressures[pick, 2])
    return area * np.abs(rows.vel[pick, 2]) + chamber + compression[:, 0] + compression[:, 2] + nfc


def node_compression(rows: LogRows, pick: np.ndarray | None = None) -> np.ndarray:
    """(rows, nodes) m^3/s each node's compression takes at ``rows``' rows ``pick`` (default: all): the oil volumes
    at the cylinders' extensions (:meth:`~hexgym.hydraulics.circuit.HydraulicCircuit.volumes`) through
    :func:`hexgym.mbl.valve.compression_flows`."""
    pick = np.arange(len(rows.t)) if pick is None else pick
    circuit = HydraulicCircuit(layout=DEFAULT_LAYOUT)
    volumes = np.array([circuit.volumes(rows.ext[k]) for k in pick]).reshape(-1, len(NODES))
    return compression_flows(volumes, rows.pressures[pick], rows.rates[pick])


def identify_pump_max_flow(all_rows: list[LogRows]) -> dict[str, object]:
    """The pumps' maximum flow from the bucket's full-spool moves (:func:`pump_flow_rows`) over all logs: the
    median, its standard error (by log: rows of one log are correlated) and the rows and logs it rests on; or
    ``identified: False`` and why."""
    per_log = [pump_flow_rows(r) for r in all_rows]
    flows = np.concatenate(per_log) if per_log else np.zeros(0)
    logs = [f for f in per_log if len(f)]
    if len(flows) < MIN_PUMP_ROWS:
        return {"identified": False, "rows": int(len(flows)), "packaged_m3s": p.PUMP_MAX_FLOW,
                "why": f"{len(flows)} rows of the bucket alone at full spool held {HELD_S:g} s below the power limit; "
                       f"{MIN_PUMP_ROWS} needed (the excitation log has them)"}  # fmt: skip
    medians = np.array([np.median(f) for f in logs])
    error = float(np.std(medians, ddof=1) / math.sqrt(len(medians))) if len(medians) > 1 else float("nan")
    value = float(np.median(flows))
    return {"identified": True, "value_m3s": value, "value_l_min": value * 60000.0, "standard_error_m3s": error,
            "relative_to_packaged": value / p.PUMP_MAX_FLOW, "rows": int(len(flows)), "logs": len(logs),
            "packaged_m3s": p.PUMP_MAX_FLOW}  # fmt: skip

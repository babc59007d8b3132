"""``hexgym excitation``: a command log whose run fills a valve fit's gaps.

Slow spool sweeps, one function at a time, both directions: the spool steps through levels from just past the dead
band to full stroke (:data:`LEVELS_MM`), each level ramped in over :data:`RAMP_S` and held, the opposite direction
right after at the same level so the cylinder returns (its hold scaled by the nominal speeds of
:data:`hexgym_lab.mbl.operator_logs.NOMINAL_SPEED_MPS`, so each pair moves it out and back about equally): from
mid-stroke (:data:`START_FRACTIONS`) every cylinder stays within its working envelope. The bucket ends with
full-spool moves alone held :data:`PUMP_HOLD_S`, which give the pumps' maximum flow
(:func:`hexgym_lab.machine_logs.derive.identify_pump_max_flow`). Rows every 0.05 s (the operator logs' grid).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.model.commandlog import CommandLog, write_command_log
from hexgym_lab.mbl.operator_logs import DT, NOMINAL_SPEED_MPS, SPOOL_LIMIT_MM, pose_from_fractions

LEVELS_MM = (2.5, 3.5, 4.5, 5.5, 7.0, 8.5, 11.0)  # past the 1.5 mm dead band to full stroke
RAMP_S = 0.6  # a slow ramp in and out: the ramps sample every level between too
HOLD_S = 1.2  # at each level, the faster direction (the other is held longer to come back as far)
SWING_HOLD_S = 2.5  # the swing has no stroke: longer holds reach its steady speed
PUMP_HOLD_S = 1.2  # the bucket alone at full spool: after ~0.5 s of transient, steady flow for the pump's estimate
GAP_S = 0.8  # neutral between moves
START_FRACTIONS = (0.5, 0.5, 0.5)  # boom, stick, bucket cylinders out, at the start
ORDER = ("boom", "stick", "bucket", "swing")


def _move(level_mm: float, hold_s: float) -> np.ndarray:
    """One move's spool (mm) every DT: ramp in, hold, ramp out, then neutral for GAP_S."""
    ramp = np.arange(1, int(round(RAMP_S / DT)) + 1) / round(RAMP_S / DT)
    hold = np.ones(int(round(hold_s / DT)))
    return level_mm * np.concatenate([ramp, hold, ramp[::-1], np.zeros(int(round(GAP_S / DT)))])


def _sweep(function: str) -> np.ndarray:
    """The function's levels in both directions; the slower direction held longer to come back as far."""
    if function == "swing":
        return np.concatenate([_move(s * lv, SWING_HOLD_S) for lv in LEVELS_MM for s in (1.0, -1.0)])
    hold_out, hold_in = _holds(function, HOLD_S)
    return np.concatenate([np.concatenate([_move(lv, hold_out), _move(-lv, hold_in)]) for lv in LEVELS_MM])


def _holds(function: str, hold_s: float) -> tuple[float, float]:
    """Holds out and in (s): the slower direction ``hold_s``, the faster as long as moves it as far (ramps
    included) at the nominal speeds."""
    out_mps, in_mps = NOMINAL_SPEED_MPS[function]
    fast = max(0.0, min(out_mps, in_mps) * (hold_s + RAMP_S) / max(out_mps, in_mps) - RAMP_S)
    return (hold_s, fast) if out_mps < in_mps else (fast, hold_s)


def excitation_log(functions: tuple[str, ...] = ORDER) -> CommandLog:
    """The sweeps of ``functions`` in turn (see the module; none: only the next), then the bucket's full-spool
    pump-flow moves."""
    parts = [np.zeros((int(round(1.0 / DT)), 4))]
    for f in functions:
        column = np.zeros((len(sweep := _sweep(f)), 4))
        column[:, kinematics.JOINTS.index(f)] = sweep
        parts.append(column)
    hold_out, hold_in = _holds("bucket", PUMP_HOLD_S)
    pump = np.concatenate([_move(SPOOL_LIMIT_MM, hold_out), _move(-SPOOL_LIMIT_MM, hold_in)] * 2)
    column = np.zeros((len(pump), 4))
    column[:, kinematics.JOINTS.index("bucket")] = pump
    parts.append(column)
    spools = np.round(np.vstack(parts), 3)
    return CommandLog(np.round(DT * np.arange(len(spools)), 10), spools)


def functions_with_gaps(model_dir: str | Path) -> tuple[str, ...]:
    """The functions (in :data:`ORDER`) whose passages a fitted model's logs left gaps in or too few samples of
    (its ``provenance.json``'s coverage; the bypass tables, never fitted, aside)."""
    from hexgym.mbl.schema import TABLE_SETS

    path = Path(model_dir) / "provenance.json"
    if not path.is_file():
        raise ValueError(f"--model {model_dir}: no provenance.json (a model written by `hexgym fit --logs`)")
    tables = json.loads(path.read_text(encoding="utf-8")).get("tables", {})
    short = set()
    for name, report in tables.items():
        if name.endswith("_bypass") or name not in TABLE_SETS["circuit"]:
            continue
        if report.get("gaps_mm") or "kept" in report:
            short.add(TABLE_SETS["circuit"][name].inputs[0].removesuffix("_spool_m"))
    return tuple(f for f in ORDER if f in short)


def start_pose() -> np.ndarray:
    """The pose the excitation log starts from (rad): the swing at 0, the cylinders at :data:`START_FRACTIONS`."""
    return pose_from_fractions(0.0, np.array(START_FRACTIONS))


def write_excitation(path: str | Path, functions: tuple[str, ...] = ORDER) -> CommandLog:
    """Write the excitation command log (the simulate command-log format), atomically."""
    unknown = [f for f in functions if f not in kinematics.JOINTS]
    if unknown:
        raise ValueError(f"--functions: unknown {unknown}; the functions are {list(kinematics.JOINTS)}")
    log = excitation_log(functions)
    write_command_log(path, log)
    return log


def max_travel_m(log: CommandLog) -> dict[str, float]:
    """Each cylinder's largest excursion (m) from its start along the log at the nominal speeds (a check that the
    sweeps stay within the stroke)."""
    out = {}
    for j, f in enumerate(kinematics.FRONT_CYLINDERS):
        u = log.spools_mm[:, j + 1] / SPOOL_LIMIT_MM
        v = np.where(u > 0, NOMINAL_SPEED_MPS[f][0] * u, NOMINAL_SPEED_MPS[f][1] * u)
        x = np.cumsum(v) * DT
        out[f] = float(np.max(np.abs(x)))
    return out | {"strokes": {f: p.CYLINDERS[f].stroke for f in kinematics.FRONT_CYLINDERS}}

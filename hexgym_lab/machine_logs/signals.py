"""The machine-log format: the signals a retrofitted excavator records, their names, units and signs.

One vocabulary: where the trajectory format (:mod:`hexgym.machine.trajectory`) or the reference model's rows
(:data:`hexgym.hydraulics.reference.TRAJECTORY_COLUMNS`) already name a quantity, a log names it the same, in the
same unit; the names below are imported from there, not retyped. ``docs/machine-logs.md`` is the format's page.

A log holds time (``t``, s, ascending, 50-200 Hz, not necessarily uniform) and, per sample, some of:

- the spools (``<joint>_spool_mm``, mm, + extends the cylinder / swings counter-clockwise) **or** the pilot
  pressures that move them (``<joint>_pilot_extend_pa``, ``<joint>_pilot_retract_pa``, Pa), mapped to spool
  positions by :func:`spools_from_pilots`;
- the two pump delivery pressures (``pump1_pressure_pa``, ``pump2_pressure_pa``);
- each cylinder's head and rod pressures and the swing motor's port pressures (``boom_head_pressure_pa`` ...
  ``swing_a_pressure_pa``, ``swing_b_pressure_pa``; port a drives the swing counter-clockwise);
- the joint angles (``q_<joint>_rad``, rad, hexgym's conventions) **or** the cylinder extensions
  (``<cylinder>_extension_m``, m from fully retracted; the swing angle is still needed), mapped to angles through
  :mod:`hexgym.machine.kinematics` by :func:`angles_from_extensions`;
- the engine speed (``engine_speed_rpm``) and, optionally, the payload (``payload_kg``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from hexgym.hydraulics.reference import TRAJECTORY_COLUMNS
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine import trajectory as tr

TIME = tr.TIME
SPOOLS = tr.SPOOLS  # mm
JOINT_ANGLES = tr.JOINT_ANGLES  # rad
EXTENSIONS = tr.CYLINDER_EXTENSIONS  # m, boom, stick, bucket
PUMP_PRESSURES = tr.PUMP_COLUMNS[:2]  # Pa
# the chambers' pressures as the reference names them: boom head, boom rod, ..., swing a, swing b
CHAMBER_PRESSURES = tuple(c for c in TRAJECTORY_COLUMNS if c.endswith("_pressure_pa") and c not in tr.PUMP_COLUMNS)
HEAD_PRESSURES = tuple(c for c in CHAMBER_PRESSURES if "_head_" in c)
ROD_PRESSURES = tuple(c for c in CHAMBER_PRESSURES if "_rod_" in c)
SWING_PRESSURES = tuple(c for c in CHAMBER_PRESSURES if c.startswith("swing_"))
PILOT_PRESSURES = tuple(f"{j}_pilot_{side}_pa" for j in kinematics.JOINTS for side in ("extend", "retract"))
ENGINE_SPEED = "engine_speed_rpm"
PAYLOAD = "payload_kg"
PRESSURES = PUMP_PRESSURES + CHAMBER_PRESSURES + PILOT_PRESSURES
SIGNALS = (TIME, *SPOOLS, *PILOT_PRESSURES, *PUMP_PRESSURES, *CHAMBER_PRESSURES, *JOINT_ANGLES, *EXTENSIONS,
           ENGINE_SPEED, PAYLOAD)  # fmt: skip
UNITS = {TIME: "s", ENGINE_SPEED: "rpm", PAYLOAD: "kg"} | {s: "mm" for s in SPOOLS} | {s: "Pa" for s in PRESSURES}
UNITS |= {s: "rad" for s in JOINT_ANGLES} | {s: "m" for s in EXTENSIONS}
RATE_RANGE_HZ = (50.0, 200.0)  # what a retrofit's logger records; outside it a log is flagged, not refused

# Pilot pressure -> spool: linear from PILOT_START_PA (the spool's centring spring preload: it starts to move) to
# PILOT_FULL_PA (full stroke), the net of the extend and retract pilots; per machine, the YAML mapping may set both.
# [est: pilot-operated open-centre valves of the class begin to stroke near 0.5 MPa and reach full stroke near
# 3 MPa of a ~4 MPa pilot supply; a unit's figures come from its valve's service data]
STROKE_TOLERANCE_M = 2e-3  # a stroke sensor's reading this far beyond an end of the stroke is the end (its noise)
PILOT_START_PA = 0.5e6
PILOT_FULL_PA = 3.0e6


@dataclass
class MachineLog:
    """A machine log read into arrays: ``t`` (n,) s and each signal it has, (n,) in the format's unit (NaN where a
    sample is missing). ``name`` names the log in every finding; ``clocks``: each source's own time stamps (a bag's
    topics), which the time checks read too; ``ignored``: the source's columns the format does not name."""

    name: str
    t: np.ndarray
    signals: dict[str, np.ndarray]
    clocks: dict[str, np.ndarray] = field(default_factory=dict)
    ignored: tuple[str, ...] = ()
    pilot_pa: tuple[float, float] = (PILOT_START_PA, PILOT_FULL_PA)  # the pilot -> spool map's start and full

    def has(self, *names: str) -> bool:
        """Whether the log has all of these signals."""
        return all(n in self.signals for n in names)

    def angles(self) -> np.ndarray | None:
        """(n, 4) joint angles (rad): measured, or from the cylinder extensions and the swing angle; None without."""
        if self.has(*JOINT_ANGLES):
            return np.column_stack([self.signals[n] for n in JOINT_ANGLES])
        if self.has(JOINT_ANGLES[0], *EXTENSIONS):
            front = angles_from_extensions(np.column_stack([self.signals[n] for n in EXTENSIONS]))
            return np.column_stack([self.signals[JOINT_ANGLES[0]], front])
        return None

    def spools_mm(self) -> np.ndarray | None:
        """(n, 4) spool positions (mm): measured, or from the pilot pressures; None without either."""
        if self.has(*SPOOLS):
            return np.column_stack([self.signals[n] for n in SPOOLS])
        if self.has(*PILOT_PRESSURES):
            pilots = np.column_stack([self.signals[n] for n in PILOT_PRESSURES])
            return spools_from_pilots(pilots[:, 0::2], pilots[:, 1::2], *self.pilot_pa)
        return None


def spools_from_pilots(
    extend_pa: np.ndarray, retract_pa: np.ndarray, start_pa: float = PILOT_START_PA, full_pa: float = PILOT_FULL_PA
) -> np.ndarray:
    """Spool positions (mm) from the extend and retract pilot pressures (Pa, same shapes): the net pilot pressure
    beyond ``start_pa`` moves the spool linearly, to the full stroke at ``full_pa``."""
    net = np.asarray(extend_pa, dtype=float) - np.asarray(retract_pa, dtype=float)
    travel = np.clip((np.abs(net) - start_pa) / (full_pa - start_pa), 0.0, 1.0)
    return np.sign(net) * travel * p.SPOOL_STROKE * 1e3


@functools.cache
def _length_table(name: str, samples: int = 20001) -> tuple[np.ndarray, np.ndarray]:
    """Cylinder length (m) against joint angle (rad) over the joint's range: rising, so it inverts by np.interp."""
    lo, hi = kinematics.joint_range(name)
    angles = np.linspace(lo, hi, samples)
    return np.array([kinematics.cylinder_length(name, a) for a in angles]), angles


def angles_from_extensions(extensions_m: np.ndarray) -> np.ndarray:
    """(n, 3) boom, stick, bucket angles (rad) from the cylinders' extensions (m from fully retracted), through
    :func:`hexgym.machine.kinematics.cylinder_length` tabulated over each joint's range (within 1e-6 rad); an
    extension up to :data:`STROKE_TOLERANCE_M` beyond an end is that end (a sensor's noise), further is NaN."""
    x = np.atleast_2d(np.asarray(extensions_m, dtype=float))
    out = np.empty_like(x)
    for i, name in enumerate(kinematics.FRONT_CYLINDERS):
        lengths, angles = _length_table(name)
        length = x[:, i] + p.CYLINDERS[name].retracted_length
        inside = (length >= lengths[0] - STROKE_TOLERANCE_M) & (length <= lengths[-1] + STROKE_TOLERANCE_M)
        out[:, i] = np.where(inside, np.interp(length, lengths, angles), np.nan)
    return out


def joint_rates(t: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(n, 4) joint rates (rad/s) by central differences on the log's own (possibly uneven) time stamps."""
    if len(t) < 2:
        return np.zeros_like(angles)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.gradient(angles, t, axis=0)

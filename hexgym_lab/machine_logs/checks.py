"""What a machine log can be trusted with: structured findings, each naming the log, the signal and the time range.

:func:`check_log` runs every check and returns :class:`Finding` s; a caller prints them (:meth:`Finding.line`) or
refuses a log with an ``error`` among them (:func:`trusted`). The thresholds are module constants, each with its
reason; ``docs/machine-logs.md`` ("Checks") lists them. All checks are vectorised over the samples.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hexgym.hydraulics.circuit import DEFAULT_LAYOUT, FUNCTIONS
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.physics import MAX_PAYLOAD_KG
from hexgym_lab.machine_logs import signals as s

ERROR, WARNING, NOTE = "error", "warning", "note"
GAP_PERIODS = 5.0  # a time step longer than this many median periods is a gap (a dropped sample or two is not)
NAN_RUN_S = 0.1  # a NaN run at least this long is an error (a sensor or its bus out); shorter ones a warning
STUCK_S = 2.0  # a sensor exactly constant this long while the machine moves is stuck or saturated
MOVING_RADPS = 0.05  # a joint faster than this moves (above the rate noise of 0.1 deg angles over RATE_WINDOW_S)
RATE_WINDOW_S = 0.2  # joint rates are differences over this window (noise of 0.1 deg at 200 Hz: ~0.01 rad/s)
MOVING_SHARE = 0.5  # "while the machine moves": on at least this share of the stretch
OPEN_SPOOL_MM = p.SPOOL_DEAD_BAND * 1e3 + 1.0  # a spool this far from neutral meters (1 mm past the dead band)
# A joint moving against its open spool on more than this share of the samples where both are clear of zero is
# flipped: a machine moves with its spool but for brief overruns and the swing's counter-spool braking (on six of
# the reference's operator-like logs, suite seed 3, logged at 50 and 200 Hz with default noise: at most 4 %).
SIGN_FLIP_SHARE = 0.5
SIGN_MIN_S = 1.0  # ... over at least this much of such samples (less says nothing)
MIN_MOTION_S = 3.0  # seconds of a passage metering with its joint moving that an LWR fit of its area needs
PA_PLAUSIBLE = (1e5, 1e8)  # Pa: a working log's largest pressure lies within (standby ~3 MPa, reliefs ~35 MPa)
MAX_JOINT_RADPS = 3.0  # no joint of the class turns this fast (swing ~1.2 rad/s): faster is degrees read as rad
RATE_TOLERANCE = 0.05  # a logger's median rate may stray this share outside RATE_RANGE_HZ (jitter, clock drift)
RPM_PLAUSIBLE = (500.0, 3000.0)  # engine speed, rpm: idle to high idle of the class's engines


@dataclass(frozen=True)
class Finding:
    """One thing a check found: in ``log``, ``signal`` (or ``clock <topic>``, ``log``), over ``t0``-``t1`` s of
    the log's time, ``what``; ``severity``: error (the log cannot be trusted), warning or note."""

    log: str
    signal: str
    t0: float
    t1: float
    what: str
    severity: str = ERROR

    def as_dict(self) -> dict:
        """JSON-ready (a time that is not a number: None)."""
        times = {k: (v if np.isfinite(v) else None) for k, v in (("t0", self.t0), ("t1", self.t1))}
        return {"log": self.log, "signal": self.signal, **times, "what": self.what, "severity": self.severity}

    def line(self) -> str:
        """The finding as one line: ``log: severity: signal, t0-t1 s: what``."""
        return f"{self.log}: {self.severity}: {self.signal}, t {self.t0:.2f}-{self.t1:.2f} s: {self.what}"


def trusted(findings: list[Finding]) -> bool:
    """Whether no finding is an error."""
    return not any(f.severity == ERROR for f in findings)


def check_log(log: s.MachineLog) -> list[Finding]:
    """Every check on ``log``: time, missing signals, NaN runs, units, stuck sensors, signs, motion."""
    found: list[Finding] = []
    for check in CHECKS:
        found += check(log)
    return found


def _span(log: s.MachineLog) -> tuple[float, float]:
    t = log.t[np.isfinite(log.t)]
    return (float(t.min()), float(t.max())) if len(t) else (np.nan, np.nan)


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (exclusive) indices of each run of True in ``mask``."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


# -- time ----------------------------------------------------------------------------------------------------
def check_time(log: s.MachineLog) -> list[Finding]:
    """Time that is not finite, goes backwards or repeats, has gaps, or runs outside the loggers' rates."""
    found = []
    for name, t in {s.TIME: log.t, **log.clocks}.items():
        found += _clock_findings(log.name, name, np.asarray(t, dtype=float))
    return found


def _clock_findings(log: str, name: str, t: np.ndarray) -> list[Finding]:
    bad = ~np.isfinite(t)
    found = [Finding(log, name, *_around(t, i), "time stamp is not a number") for i in np.flatnonzero(bad)[:3]]
    t = t[~bad]
    if len(t) < 2:
        return found + [Finding(log, name, *(t.tolist() * 2 or [np.nan] * 2), "fewer than 2 samples")]
    dt = np.diff(t)
    period = float(np.median(dt[dt > 0])) if np.any(dt > 0) else np.nan
    for i in np.flatnonzero(dt <= 0)[:5]:
        what = "clock jumps backwards" if dt[i] < 0 else "time stamp repeats"
        found.append(Finding(log, name, float(t[i]), float(t[i + 1]), f"{what} by {-dt[i]:.3g} s (non-monotonic time)"))
    for i in np.flatnonzero(dt > GAP_PERIODS * period)[:5]:
        found.append(Finding(log, name, float(t[i]), float(t[i + 1]), f"gap of {dt[i]:.3g} s in time "
                             f"({dt[i] / period:.0f} sample periods of {period * 1e3:.3g} ms)"))  # fmt: skip
    rate = 1.0 / period
    lo, hi = s.RATE_RANGE_HZ
    if not lo * (1 - RATE_TOLERANCE) <= rate <= hi * (1 + RATE_TOLERANCE):
        found.append(Finding(log, name, float(t[0]), float(t[-1]), f"sampled at {rate:.3g} Hz, outside the "
                             f"{lo:g}-{hi:g} Hz a logger records (time in ms or µs, not s?)", WARNING))  # fmt: skip
    return found


def _around(t: np.ndarray, i: int) -> tuple[float, float]:
    """The finite time stamps either side of index ``i`` (for a sample whose own is not)."""
    before = t[:i][np.isfinite(t[:i])]
    after = t[i + 1 :][np.isfinite(t[i + 1 :])]
    return float(before[-1]) if len(before) else np.nan, float(after[0]) if len(after) else np.nan


# -- what is there ---------------------------------------------------------------------------------------------
_PASSAGE_SIDE = {"pa": "P->a", "pb": "P->b", "at": "a->T", "bt": "b->T"}  # a: a cylinder's head, b: its rod
# (signals, what cannot be learned without them, severity), a group's signals all needed
_NEEDED: tuple[tuple[tuple[str, ...], str, str], ...] = (
    (s.PUMP_PRESSURES, "the pumps' pressure-flow regulator (NFC curve, power limit) and the meter-in passages "
     "(P->a, P->b) cannot be identified", WARNING),
    (s.HEAD_PRESSURES, "the head-side passages (P->a meter-in, a->T meter-out) cannot be identified", WARNING),
    (s.ROD_PRESSURES, "the rod-side passages (P->b, and b->T: the return side while extending) cannot be "
     "identified", WARNING),
    (s.SWING_PRESSURES, "the swing motor's passages and its crossover reliefs cannot be identified", WARNING),
    ((s.ENGINE_SPEED,), "the pump flows assume the rated engine speed (2000 rpm)", NOTE),
    ((s.PAYLOAD,), "the loads assume an empty bucket", NOTE),
)  # fmt: skip


def check_signals(log: s.MachineLog) -> list[Finding]:
    """What is missing and what cannot be learned without it; nothing without motion or without the spools."""
    t0, t1 = _span(log)
    found = []
    if log.angles() is None:
        found.append(Finding(log.name, "joint angles", t0, t1, "no joint angles and no swing angle with cylinder "
                             "strokes: nothing can be learned (no motion to fit)"))  # fmt: skip
    if log.spools_mm() is None:
        found.append(Finding(log.name, "spools", t0, t1, "no spool positions and no pilot pressures: nothing can be "
                             "learned (the valve's openings are unknown)"))  # fmt: skip
    for names, what, severity in _NEEDED:
        missing = [n for n in names if n not in log.signals]
        if missing:
            found.append(Finding(log.name, ", ".join(missing), t0, t1, f"missing: {what}", severity))
    if log.ignored:
        found.append(Finding(log.name, "log", t0, t1, f"columns not in the format, ignored: {', '.join(log.ignored)}",
                             NOTE))  # fmt: skip
    return found


# -- NaN runs ---------------------------------------------------------------------------------------------------
def check_nan_runs(log: s.MachineLog) -> list[Finding]:
    """Runs of missing samples: an error from :data:`NAN_RUN_S` on, shorter ones one warning per signal."""
    found = []
    t = log.t
    for name, values in log.signals.items():
        starts, ends = _runs(~np.isfinite(values))
        if not len(starts):
            continue
        t0, t1 = t[starts], t[np.minimum(ends, len(t) - 1)]
        long = (t1 - t0) >= NAN_RUN_S
        for a, b in zip(t0[long][:5], t1[long][:5], strict=True):
            found.append(Finding(log.name, name, float(a), float(b), f"no values (NaN) for {b - a:.3g} s"))
        if np.any(~long):
            count = int(np.sum(ends[~long] - starts[~long]))
            found.append(Finding(log.name, name, float(t0[~long][0]), float(t1[~long][-1]), f"{count} missing "
                                 f"samples (NaN) in {int(np.sum(~long))} short runs", WARNING))  # fmt: skip
    return found


# -- units ------------------------------------------------------------------------------------------------------
def check_units(log: s.MachineLog) -> list[Finding]:
    """Values whose magnitude or range says they are in another unit: pressures in bar, angles in degrees..."""
    found = []
    t0, t1 = _span(log)
    for name, values in log.signals.items():
        finite = values[np.isfinite(values)]
        if len(finite):
            what = _unit_problem(name, finite)
            if what:
                found.append(Finding(log.name, name, t0, t1, what))
    return found + _angle_rates(log)


def _unit_problem(name: str, v: np.ndarray) -> str:
    """What is wrong with the unit of a signal's finite values, or ''."""
    top = float(np.max(np.abs(v)))
    if name in s.PRESSURES:
        lo, hi = PA_PLAUSIBLE
        if 0 < top < lo:  # (a pilot never moved reads 0 in any unit)
            return f"largest value {top:.4g}: pressures are in Pa; this looks like bar, MPa or psi"
        if top > hi:
            return f"largest value {top:.4g} Pa exceeds {hi:.0e} Pa: a different unit?"
    elif name in s.SPOOLS:
        if top > p.SPOOL_STROKE * 1e3 * 1.05:
            return f"largest value {top:.4g} mm is beyond the ±{p.SPOOL_STROKE * 1e3:g} mm stroke (µm or 1/100 mm?)"
        if 0 < top < 0.05:
            return f"largest value {top:.4g}: spools are in mm; this looks like metres"
    elif name in s.JOINT_ANGLES[1:]:
        return _angle_problem(name, v)
    elif name in s.EXTENSIONS:
        stroke = p.CYLINDERS[kinematics.FRONT_CYLINDERS[s.EXTENSIONS.index(name)]].stroke
        if v.min() < -0.02 or v.max() > stroke + 0.02:
            return f"values {v.min():.4g} to {v.max():.4g} m leave the 0-{stroke:.3g} m stroke (mm? or length, not " \
                   "extension?)"  # fmt: skip
    elif name == s.ENGINE_SPEED and not RPM_PLAUSIBLE[0] <= float(np.median(v)) <= RPM_PLAUSIBLE[1]:
        return f"median {float(np.median(v)):.4g}: engine speed is in rpm ({RPM_PLAUSIBLE[0]:g}-{RPM_PLAUSIBLE[1]:g})"
    elif name == s.PAYLOAD and (v.min() < -50.0 or v.max() > 2 * MAX_PAYLOAD_KG):
        return f"values {v.min():.4g} to {v.max():.4g} kg: not a bucket's payload (tonnes, or lb?)"
    return ""


def _angle_problem(name: str, v: np.ndarray) -> str:
    joint = name.removeprefix("q_").removesuffix("_rad")
    lo, hi = kinematics.joint_range(joint)
    margin = 0.1
    if v.min() >= lo - margin and v.max() <= hi + margin:
        return ""
    hint = " (degrees?)" if np.max(np.abs(v)) > np.pi else ""
    return f"values {v.min():.4g} to {v.max():.4g} rad leave the joint's range {lo:.3f} to {hi:.3f} rad{hint}"


def _angle_rates(log: s.MachineLog) -> list[Finding]:
    """A joint turning faster than any of the class does: its angle is in degrees (the swing included)."""
    q = log.angles()
    if q is None:
        return []
    rates = smoothed_rates(log.t, q)
    found = []
    for j, name in enumerate(s.JOINT_ANGLES):
        r = np.abs(rates[:, j])
        r = r[np.isfinite(r)]
        if len(r) and np.percentile(r, 99) > MAX_JOINT_RADPS:
            top = float(np.percentile(r, 99))
            found.append(Finding(log.name, name, *_span(log), f"turns at {top:.3g} rad/s (99th percentile), faster "
                                 f"than {MAX_JOINT_RADPS:g} rad/s: degrees, not radians?"))  # fmt: skip
    return found


def smoothed_rates(t: np.ndarray, q: np.ndarray, window_s: float = RATE_WINDOW_S) -> np.ndarray:
    """(n, k) rates of ``q`` (n, k): the difference over ``window_s`` centred on each sample (one-sided at the
    ends), which keeps sensor noise out of the sign and motion checks."""
    order = np.maximum.accumulate(np.where(np.isfinite(t), t, -np.inf))
    lo = np.searchsorted(order, order - window_s / 2, side="left")
    hi = np.minimum(np.searchsorted(order, order + window_s / 2, side="right") - 1, len(t) - 1)
    span = order[hi] - order[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        rates = (q[hi] - q[lo]) / span[:, None]
    rates[span <= 0] = np.nan
    return rates


# -- stuck sensors ----------------------------------------------------------------------------------------------
def check_stuck(log: s.MachineLog) -> list[Finding]:
    """A pressure exactly constant for :data:`STUCK_S` while the machine moves, and a joint angle constant while its
    own spool is open: a stuck or saturated sensor (commands, engine speed and payload may be held)."""
    q = log.angles()
    if q is None:
        return []
    rates = np.abs(smoothed_rates(log.t, q))
    moving = np.any(rates > MOVING_RADPS, axis=1)
    spools = log.spools_mm()
    found = []
    for name, values in log.signals.items():
        if name in s.PRESSURES and name not in s.PILOT_PRESSURES:
            found += _constant_runs(log, name, values, moving, "while the machine moves")
        elif name in s.JOINT_ANGLES and spools is not None:
            j = s.JOINT_ANGLES.index(name)
            found += _constant_runs(log, name, values, np.abs(spools[:, j]) > OPEN_SPOOL_MM, "while its spool is open")
    return found


def _constant_runs(log: s.MachineLog, name: str, v: np.ndarray, active: np.ndarray, why: str) -> list[Finding]:
    same = np.concatenate(([False], v[1:] == v[:-1]))  # NaN != NaN: a NaN run is not a constant one
    starts, ends = _runs(same)
    starts = np.maximum(starts - 1, 0)  # the run's first sample is the one before its first repeat
    found = []
    for a, b in zip(starts, ends - 1, strict=True):
        duration = log.t[b] - log.t[a]
        if duration >= STUCK_S and np.mean(active[a : b + 1]) >= MOVING_SHARE:
            finite = v[np.isfinite(v)]
            edge = " (the log's extreme: saturated?)" if v[a] in (finite.min(), finite.max()) else ""
            found.append(Finding(log.name, name, float(log.t[a]), float(log.t[b]), f"constant at {v[a]:.6g} for "
                                 f"{duration:.3g} s {why}: a stuck sensor{edge}"))  # fmt: skip
    return found


# -- signs and motion -------------------------------------------------------------------------------------------
def check_signs(log: s.MachineLog) -> list[Finding]:
    """A joint that moves against its open spool on more than :data:`SIGN_FLIP_SHARE` of the samples where both
    are clear of zero: the angle's (or the spool's) sign convention is flipped."""
    moving = _spools_and_rates(log)
    if moving is None:
        return []
    u, rates, period = moving
    found = []
    for j, name in enumerate(s.JOINT_ANGLES):
        both = (np.abs(u[:, j]) > OPEN_SPOOL_MM) & (np.abs(rates[:, j]) > MOVING_RADPS)
        if np.sum(both) * period < SIGN_MIN_S:
            continue
        against = float(np.mean(np.sign(u[both, j]) != np.sign(rates[both, j])))
        if against > SIGN_FLIP_SHARE:
            idx = np.flatnonzero(both)
            found.append(Finding(log.name, f"{name} vs {s.SPOOLS[j]}", float(log.t[idx[0]]), float(log.t[idx[-1]]),
                                 f"the joint moves against its spool on {against:.0%} of the samples where both are "
                                 f"clear of zero (over {SIGN_FLIP_SHARE:.0%}): a sign convention flipped"))  # fmt: skip
    return found


def _spools_and_rates(log: s.MachineLog) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(spools in mm, the joints' smoothed rates, the median sample period) of a log, or None without spools or
    angles."""
    q, u = log.angles(), log.spools_mm()
    if q is None or u is None:
        return None
    return u, smoothed_rates(log.t, q), _period(log)


def _period(log: s.MachineLog) -> float:
    dt = np.diff(log.t)
    dt = dt[np.isfinite(dt) & (dt > 0)]
    return float(np.median(dt)) if len(dt) else 0.0


def check_motion(log: s.MachineLog) -> list[Finding]:
    """Each spool side's passages need :data:`MIN_MOTION_S` of metering with the joint moving its way."""
    moving = _spools_and_rates(log)
    if moving is None:
        return []
    u, rates, period = moving
    found = []
    for j in range(len(FUNCTIONS)):
        section = DEFAULT_LAYOUT.sections[j].name  # the function's own section
        for side, passages in ((1.0, ("pa", "bt")), (-1.0, ("pb", "at"))):
            seconds = period * np.sum((side * u[:, j] > OPEN_SPOOL_MM) & (side * rates[:, j] > MOVING_RADPS))
            if seconds < MIN_MOTION_S:
                names = ", ".join(f"{section}_{k} ({_PASSAGE_SIDE[k]})" for k in passages)
                way = "extending" if side > 0 else "retracting"
                found.append(
                    Finding(
                        log.name,
                        f"{s.SPOOLS[j]}",
                        *_span(log),
                        f"too little motion to learn {names}: "
                        f"{seconds:.3g} s {way} with the spool open, {MIN_MOTION_S:g} s needed",
                        WARNING,
                    )
                )
    return found


CHECKS: tuple[Callable[[s.MachineLog], list[Finding]], ...] = (
    check_time, check_signals, check_nan_runs, check_units, check_stuck, check_signs, check_motion,
)  # fmt: skip

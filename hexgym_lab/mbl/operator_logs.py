"""Seeded random operator-like command logs: the generalisation suite of ``hexgym validate --suite``
and the collection program of the tables that learn from operator-like motion (:mod:`hexgym_lab.mbl.collect`).

The paper's Tests 1-3 are three fixed logs; the learned model was tuned while looking at them.
These logs are drawn afresh from a seed, as an operator would move the joysticks:

- **Phases** of one to three functions at once, separated by short pauses (0-1.5 s). Each
  joystick in a phase is ramped (0.2-0.6 s) to a level, often full (±11 mm), else partial
  (3-11 mm), held 1-6 s and ramped back; a second or third joystick joins within a second.
- **Long swings** (held 3-8 s) in about a third of the phases, half of them alone, half with
  the stick moving in or out during the swing (a loading cycle's swing to the truck).
- **Both directions** of every function. A cylinder's direction is drawn towards the middle
  of its stroke (the further it is from one end, the likelier it moves that way), and most
  holds are cut short where the cylinder would reach its end, as estimated from its nominal
  full-spool speed (``NOMINAL_SPEED_MPS``); an end is still reached now and then, as operators do.
- **Bucket at full spool with the stick moving** in about one phase in ten (``Style.p_bucket_stick``: 15 %
  of the phases that are not long swings):
  the bucket curls or dumps with its joystick at the stop (±11 mm) while the stick moves in or
  out (joining within 0.5 s), as in digging and in the curl that closes a pass; the boom joins in
  a third of them. Here the stick and the bucket run on to their stroke ends half of the time
  (``P_RUN_TO_END``): an operator crowds the stick and curls the bucket to their stops. This is
  where a learned model's bucket, near its curled end (where the linkage turns a few millimetres
  of cylinder into a tenth of a radian), is most sensitive to what reaches it from the stick.
- **Start poses** with each cylinder 15-85 % out (inside the joint ranges,
  :func:`hexgym.machine.kinematics.joint_range`), any swing angle; **payload** 0, 1 or 2 t.

Rows are every 0.05 s, 30-60 s long; all times lie on that grid. Each log is reproducible on
its own: :func:`suite_log` seeds it from ``np.random.SeedSequence([suite_seed, index])``.

The ``sweep`` style (:data:`STYLES`) moves the joysticks as someone learning the valve would: partial
levels anywhere from the dead band up and slow ramps, so that every spool position is passed and
held, where an operator mostly pushes the stick to its stop; it has no bucket-with-stick phases. The
``bucket_stick`` style draws only those phases: the dedicated suite of that motion
(``hexgym validate --suite-style bucket_stick``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hexgym.machine import kinematics
from hexgym.machine import parameters as p

SPOOL_LIMIT_MM = p.SPOOL_STROKE * 1e3
DT = 0.05  # s between rows
DURATION_S = (30.0, 60.0)
RAMP_S = (0.2, 0.6)
HOLD_S = (1.0, 6.0)
SWING_HOLD_S = (3.0, 8.0)
PARTIAL_MM = (3.0, SPOOL_LIMIT_MM)
PAYLOADS_KG = (0.0, 1000.0, 2000.0)
START_FRACTION = (0.15, 0.85)  # of each cylinder's stroke
# Full-spool cylinder speeds (extend, retract), m/s: the reference model alone, empty bucket
# (``hexgym reference-report``); only to estimate where a cylinder is in its stroke.
NOMINAL_SPEED_MPS = {"boom": (0.14, 0.45), "stick": (0.35, 0.42), "bucket": (0.29, 0.43)}
P_FULL = 0.6  # a joystick pushed to its stop


@dataclass(frozen=True)
class Style:
    """How the joysticks move: the chance of a full stroke, partial levels (mm), ramp times (s) and the
    chance that a phase is the bucket at full spool with the stick moving."""

    p_full: float
    partial_mm: tuple[float, float]
    ramp_s: tuple[float, float]
    p_bucket_stick: float = 0.0


P_SWING_PHASE = 0.35
P_BUCKET_STICK_PHASE = 0.15  # of an operator's phases (drawn from those that are not a long swing)
STYLES = {
    "operator": Style(P_FULL, PARTIAL_MM, RAMP_S, P_BUCKET_STICK_PHASE),
    "sweep": Style(0.2, (p.SPOOL_DEAD_BAND * 1e3, SPOOL_LIMIT_MM), (0.5, 3.0)),
    "bucket_stick": Style(P_FULL, PARTIAL_MM, RAMP_S, 1.0),
}
P_STOP_AT_END = 0.85  # a hold that would run the cylinder into its end is cut short
P_RUN_TO_END = 0.5  # in a bucket-with-stick phase: the stick and the bucket are run on to their stops
P_BOOM_JOINS = 1.0 / 3.0  # in a bucket-with-stick phase: the boom moves too


@dataclass(frozen=True)
class Stroke:
    """One joystick movement: ramp from neutral to ``level_mm``, hold, ramp back (times in s)."""

    function: str
    level_mm: float
    start_s: float
    ramp_up_s: float
    hold_s: float
    ramp_down_s: float

    @property
    def end_s(self) -> float:
        """When the spool is back at neutral."""
        return self.start_s + self.ramp_up_s + self.hold_s + self.ramp_down_s

    def spool_mm(self, t: np.ndarray) -> np.ndarray:
        """The spool position (mm) at times ``t``: a trapezoid."""
        up = (t - self.start_s) / self.ramp_up_s
        down = (self.end_s - t) / self.ramp_down_s
        return self.level_mm * np.clip(np.minimum(up, down), 0.0, 1.0)


@dataclass(frozen=True)
class OperatorLog:
    """A drawn log with the start and load it is replayed from."""

    t: np.ndarray  # s, every DT from 0
    spools_mm: np.ndarray  # (rows, 4): swing, boom, stick, bucket
    start_pose: np.ndarray  # rad: swing, boom, stick, bucket
    payload_kg: float
    strokes: tuple[Stroke, ...]

    @property
    def duration(self) -> float:
        """Seconds from the first row to the last."""
        return float(self.t[-1] - self.t[0])

    def describe(self) -> dict[str, object]:
        """JSON-ready: duration, payload, start pose, the functions used and their moves by direction."""
        moves: dict[str, int] = {}
        for s in self.strokes:
            key = f"{s.function}{'+' if s.level_mm > 0 else '-'}"
            moves[key] = moves.get(key, 0) + 1
        return {
            "duration_s": self.duration,
            "payload_kg": self.payload_kg,
            "start_pose_rad": [round(float(q), 4) for q in self.start_pose],
            "functions": [f for f in kinematics.JOINTS if any(s.function == f for s in self.strokes)],
            "moves": dict(sorted(moves.items())),
        }


def _grid(t: float) -> float:
    """``t`` on the row grid."""
    return round(round(t / DT) * DT, 10)


def pose_from_fractions(swing: float, fractions: np.ndarray) -> np.ndarray:
    """Joint angles (rad) with the boom, stick and bucket cylinders ``fractions`` (0-1) out."""
    q = [swing]
    for name, f in zip(kinematics.FRONT_CYLINDERS, fractions, strict=True):
        cyl = p.CYLINDERS[name]
        q.append(kinematics.joint_angle(name, cyl.retracted_length + f * cyl.stroke))
    return np.array(q)


def _stroke(
    rng: np.random.Generator,
    function: str,
    start: float,
    fractions: dict[str, float],
    style: Style,
    full: bool = False,
    p_stop_at_end: float = P_STOP_AT_END,
) -> Stroke:
    """One joystick movement of ``function`` (``full``: at the stop); moves the estimated stroke fraction in
    ``fractions``; a hold that would reach the stroke's end is cut short with probability ``p_stop_at_end``."""
    drawn_full = rng.random() < style.p_full
    level = SPOOL_LIMIT_MM if full or drawn_full else float(rng.uniform(*style.partial_mm))
    ramp_up, ramp_down = (_grid(rng.uniform(*style.ramp_s)) for _ in range(2))
    if function == "swing":
        level *= float(rng.choice([-1.0, 1.0]))
        return Stroke(function, level, start, ramp_up, _grid(rng.uniform(*SWING_HOLD_S)), ramp_down)
    f = fractions[function]
    extend = rng.random() < np.clip(1.0 - f, 0.1, 0.9)
    speed = NOMINAL_SPEED_MPS[function][0 if extend else 1] * level / SPOOL_LIMIT_MM / p.CYLINDERS[function].stroke
    room_s = (1.0 - f if extend else f) / speed - (ramp_up + ramp_down) / 2
    hold = rng.uniform(*HOLD_S)
    if hold > room_s and rng.random() < p_stop_at_end:
        hold = max(HOLD_S[0], room_s)
    hold = _grid(hold)
    travel = speed * (hold + (ramp_up + ramp_down) / 2)
    fractions[function] = float(np.clip(f + (travel if extend else -travel), 0.0, 1.0))
    return Stroke(function, level if extend else -level, start, ramp_up, hold, ramp_down)


def _bucket_stick_phase(
    rng: np.random.Generator, start: float, fractions: dict[str, float], style: Style
) -> list[Stroke]:
    """The bucket curling or dumping at full spool while the stick moves (and, a third of the time, the boom);
    the stick and the bucket run on to their stops half of the time."""
    p_stop = 0.0 if rng.random() < P_RUN_TO_END else P_STOP_AT_END
    first, second = ("bucket", "stick") if rng.random() < 0.5 else ("stick", "bucket")
    strokes = [
        _stroke(rng, first, start, fractions, style, full=first == "bucket", p_stop_at_end=p_stop),
        _stroke(rng, second, _grid(start + rng.uniform(0.0, 0.5)), fractions, style, second == "bucket", p_stop),
    ]
    if rng.random() < P_BOOM_JOINS:
        strokes.append(_stroke(rng, "boom", _grid(start + rng.uniform(0.0, 1.0)), fractions, style))
    return strokes


def _phase(rng: np.random.Generator, start: float, fractions: dict[str, float], style: Style) -> list[Stroke]:
    """The strokes of one phase: a long swing (alone or with the stick), the bucket at full spool with the
    stick moving (:func:`_bucket_stick_phase`), or 1-3 functions."""
    kind = rng.random()
    if style.p_bucket_stick >= 1.0:
        return _bucket_stick_phase(rng, start, fractions, style)
    if kind < P_SWING_PHASE:
        swing = _stroke(rng, "swing", start, fractions, style)
        if rng.random() < 0.5:
            return [swing]
        return [swing, _stroke(rng, "stick", _grid(start + rng.uniform(0.0, 2.0)), fractions, style)]
    if kind < P_SWING_PHASE + (1.0 - P_SWING_PHASE) * style.p_bucket_stick:
        return _bucket_stick_phase(rng, start, fractions, style)
    k = rng.choice([1, 2, 3], p=[0.35, 0.4, 0.25])
    functions = rng.choice(kinematics.JOINTS, size=k, replace=False)
    return [
        _stroke(rng, str(fn), start if i == 0 else _grid(start + rng.uniform(0.0, 1.0)), fractions, style)
        for i, fn in enumerate(functions)
    ]


def operator_log(rng: np.random.Generator, duration_s: float | None = None, style: str = "operator") -> OperatorLog:
    """Draw one operator-like log (30-60 s unless ``duration_s``), its start pose and payload; ``style``:
    a key of :data:`STYLES`."""
    if style not in STYLES:
        raise ValueError(f"style must be one of {tuple(STYLES)}, got {style!r}")
    duration = _grid(rng.uniform(*DURATION_S) if duration_s is None else duration_s)
    payload = float(rng.choice(PAYLOADS_KG))
    start_fractions = rng.uniform(*START_FRACTION, size=3)
    pose = pose_from_fractions(rng.uniform(-np.pi, np.pi), start_fractions)
    fractions = dict(zip(kinematics.FRONT_CYLINDERS, start_fractions.tolist(), strict=True))
    strokes: list[Stroke] = []
    t, misses = _grid(rng.uniform(0.3, 1.0)), 0
    while duration - t > 3.0 and misses < 20:  # phases until the last few seconds; it ends in neutral
        trial = dict(fractions)
        phase = _phase(rng, t, trial, STYLES[style])
        end = max(s.end_s for s in phase)
        if end > duration - 0.5:
            misses += 1  # too long for what is left: draw another
            continue
        strokes += phase
        fractions = trial
        t = _grid(end + rng.uniform(0.0, 1.5))
    times = np.round(np.arange(0.0, duration + DT / 2, DT), 10)
    spools = np.zeros((len(times), 4))
    for s in strokes:
        spools[:, kinematics.JOINTS.index(s.function)] += s.spool_mm(times)
    return OperatorLog(times, np.round(spools, 2), pose, payload, tuple(strokes))


def suite_log(suite_seed: int, index: int, duration_s: float | None = None, style: str = "operator") -> OperatorLog:
    """Log ``index`` of suite ``suite_seed`` in ``style`` (a key of :data:`STYLES`): reproducible on its own."""
    return operator_log(np.random.default_rng(np.random.SeedSequence([suite_seed, index])), duration_s, style)

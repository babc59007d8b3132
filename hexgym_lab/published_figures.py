"""The reference model beside a real machine's published figures: cylinder times, swing, relief settings.

What a service manual's acceptance tests measure on a new machine (:mod:`hexgym.machine.parameters`,
``PUBLISHED_*``), measured the same way on the reference model: each cylinder run from one end of its stroke to
the other at full spool, empty bucket, engine at full speed, timed from the command until the cylinder is within
``STROKE_END_MARGIN`` of its far end (the end cushion included, as a stopwatch on a machine includes it); the swing
from rest through 180 degrees, and its top speed.
"""

from __future__ import annotations

import numpy as np

from hexgym.hydraulics.reference import ReferenceModel
from hexgym.machine import kinematics
from hexgym.machine import parameters as p

TIME_LIMIT_S = 15.0  # a cylinder not at its end by then is reported as not reaching it (NaN)
# Where the other joints stand while a cylinder is timed (fraction of each joint's range, boom/stick/bucket):
# the stick near vertical and the bucket half curled for the boom, the boom half up for the stick and bucket.
_POSE_FRACTIONS = {"boom": (None, 0.5, 0.5), "stick": (0.6, None, 0.5), "bucket": (0.6, 0.5, None)}
_SPOOL = p.SPOOL_STROKE


def _pose(cylinder: str, extend: bool) -> np.ndarray:
    """Joint angles (swing, boom, stick, bucket) with ``cylinder`` at the end it starts from."""
    q = np.zeros(4)
    for i, (name, fraction) in enumerate(zip(kinematics.FRONT_CYLINDERS, _POSE_FRACTIONS[cylinder], strict=True)):
        lower, upper = kinematics.joint_range(name)
        share = (0.0 if extend else 1.0) if fraction is None else fraction
        q[i + 1] = lower + share * (upper - lower)
    return q


def cylinder_time(sim: ReferenceModel, cylinder: str, extend: bool) -> float:
    """Seconds from full spool until ``cylinder`` is within ``STROKE_END_MARGIN`` of its far end (NaN: not by
    :data:`TIME_LIMIT_S`), from rest at the other end."""
    j = kinematics.FRONT_CYLINDERS.index(cylinder)
    sim.reset(_pose(cylinder, extend))
    spools = np.zeros(4)
    spools[j + 1] = _SPOOL if extend else -_SPOOL
    goal = p.CYLINDERS[cylinder].stroke - p.STROKE_END_MARGIN if extend else p.STROKE_END_MARGIN
    for step in range(1, int(TIME_LIMIT_S / sim.timestep) + 1):
        sim.step(spools)
        ext = sim.physics.cylinder_extensions()[j]
        if (ext >= goal) if extend else (ext <= goal):
            return step * sim.timestep
    return float("nan")


def swing_figures(sim: ReferenceModel) -> tuple[float, float]:
    """(seconds from rest through 180 degrees at full spool, top speed in rpm over the following seconds)."""
    sim.reset(np.array([0.0, *(_pose("bucket", True)[1:3]), 0.5]))
    spools = np.array([_SPOOL, 0.0, 0.0, 0.0])
    half_turn, top = float("nan"), 0.0
    for step in range(1, int(TIME_LIMIT_S / sim.timestep) + 1):
        sim.step(spools)
        q, qd = sim.physics.joint_positions()[0], sim.physics.joint_velocities()[0]
        if np.isnan(half_turn) and q >= np.pi:
            half_turn = step * sim.timestep
        top = max(top, qd)
        if q >= 3.0 * np.pi:
            break
    return half_turn, top * 60.0 / (2.0 * np.pi)


def relief_settings(sim: ReferenceModel) -> dict[str, float]:
    """The reliefs' cracking pressures (Pa) the model's circuit is built with."""
    br = sim.circuit.branches
    crack = dict(zip([br.names[i] for i in br.valve], br.crack, strict=True))
    out = {"main": crack["main_relief1"], "swing": crack["swing_crossover_ab"]}
    return out | {c: crack[f"{c}_line_relief_a"] for c in kinematics.FRONT_CYLINDERS}


def _row(model: float, published: float, at_most: bool = False) -> dict[str, float | bool]:
    ratio = float(model) / published
    low = 0.0 if at_most else 1.0 - p.PUBLISHED_FIGURE_TOLERANCE
    ok = bool(np.isfinite(ratio) and low <= ratio <= 1.0 + p.PUBLISHED_FIGURE_TOLERANCE)
    return {"model": round(float(model), 2), "published": published, "ratio": round(ratio, 3), "within": ok}


def published_figures(valve: str = "paper") -> dict[str, dict]:
    """Every published figure beside the reference model's (with valve layout ``valve``): ``cylinder_times_s``
    (model, published, ratio, within +-20 %, the service limit), ``swing`` and ``relief_settings_mpa``."""
    sim = ReferenceModel(valve=valve)
    times = {}
    for name, published in p.PUBLISHED_CYLINDER_TIMES_S.items():
        cylinder, move = name.split("_")
        extend = move in ("raise", "extend")
        row = _row(cylinder_time(sim, cylinder, extend), published)
        times[name] = row | {"service_limit": p.PUBLISHED_SERVICE_LIMITS_S[name]}
    half_turn, rpm = swing_figures(sim)
    swing = {
        "half_turn_s": _row(half_turn, p.PUBLISHED_SWING_180_S, at_most=True),
        "top_speed_rpm": _row(rpm, p.PUBLISHED_SWING_RPM),
    }
    reliefs = {}
    for name, setting in relief_settings(sim).items():
        low, high = p.PUBLISHED_RELIEF_RANGES_PA[name]
        within = bool(low <= setting <= high)
        reliefs[name] = {"model": float(setting) / 1e6, "published": [low / 1e6, high / 1e6], "within": within}
    return {"valve": valve, "cylinder_times_s": times, "swing": swing, "relief_settings_mpa": reliefs}

"""The reference model beside a real machine's published figures: cylinder times, swing, relief settings.

What a service manual's acceptance tests measure on a new machine (:mod:`hexgym.machine.parameters`,
``PUBLISHED_*``), measured the same way on the reference model: empty bucket, engine at full speed, full spool,
in the poses of Cat's "Cylinder Speed - Check" procedure [pub: Cat 323F, 325D/329D and 330D-340D testing and
adjusting, one procedure]:

- boom: stick and bucket cylinders fully retracted; raise timed from the bucket resting on level ground to the boom
  cylinders' full extension, lower timed from full extension until the bucket touches the ground;
- stick: the boom's upper surface parallel to the ground (its pin-to-pin line level, our reading), the bucket
  cylinder fully extended; each way over the stick cylinder's full stroke;
- bucket: the boom level, the stick perpendicular to the ground; each way over the bucket cylinder's full stroke.

A cylinder's end counts as reached within ``STROKE_END_MARGIN`` (the end cushion included, as a stopwatch on a
machine includes it); the ground is the tracks' plane, z = 0. The swing is timed from rest through 180 degrees, and
its top speed taken after.
"""

from __future__ import annotations

import mujoco
import numpy as np
from scipy.optimize import brentq

from hexgym.hydraulics.circuit import DEFAULT_VALVE
from hexgym.hydraulics.reference import ReferenceModel
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.names import BUCKET_BODY

TIME_LIMIT_S = 15.0  # a cylinder not at its end by then is reported as not reaching it (NaN)
_SPOOL = p.SPOOL_STROKE
_RETRACTED, _EXTENDED = 0, 1  # ends of kinematics.joint_range


def _end(name: str, end: int) -> float:
    """The joint angle (rad) with ``name``'s cylinder at one end of its stroke."""
    return kinematics.joint_range(name)[end]


def _within(name: str, share: float) -> float:
    """The joint angle (rad) with ``name``'s cylinder ``share`` of the way from retracted to extended."""
    retracted, extended = kinematics.joint_range(name)
    return retracted + share * (extended - retracted)


# the swing test's pose: the boom 0.6 of its range up, the stick half way, the bucket 0.5 rad [est]
_SWING_POSE = np.array([0.0, _within("boom", 0.6), _within("stick", 0.5), 0.5])


def bucket_lowest_z(sim: ReferenceModel, q: np.ndarray) -> float:
    """The bucket's lowest point (m above the tracks' plane) with the joints at ``q``: its collision mesh's vertices."""
    sim.reset(q)
    m, d = sim.physics.model, sim.physics.data
    lowest = np.inf
    for g in np.flatnonzero(m.geom_bodyid == m.body(BUCKET_BODY).id):
        mesh = m.geom_dataid[g]
        if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH or mesh < 0:
            continue
        start, count = m.mesh_vertadr[mesh], m.mesh_vertnum[mesh]
        vertices = m.mesh_vert[start : start + count] @ d.geom_xmat[g].reshape(3, 3).T + d.geom_xpos[g]
        lowest = min(lowest, float(vertices[:, 2].min()))
    return lowest


def boom_on_ground(sim: ReferenceModel) -> float:
    """The boom's angle (rad) in its test pose, stick and bucket cylinders retracted, with the bucket resting on the
    ground; the boom's lowest angle if the bucket cannot reach the ground."""
    stick, bucket = _end("stick", _RETRACTED), _end("bucket", _RETRACTED)
    low, high = sorted(kinematics.joint_range("boom"))
    height = lambda boom: bucket_lowest_z(sim, np.array([0.0, boom, stick, bucket]))  # noqa: E731
    return low if height(low) >= 0.0 else brentq(height, low, high, xtol=1e-6)


def _start_pose(cylinder: str, extend: bool, boom_ground: float | None) -> np.ndarray:
    """Joint angles (swing, boom, stick, bucket) where ``cylinder``'s test starts (``boom_ground``: the boom test's
    :func:`boom_on_ground`)."""
    if cylinder == "boom":
        boom = boom_ground if extend else _end("boom", _EXTENDED)
        return np.array([0.0, boom, _end("stick", _RETRACTED), _end("bucket", _RETRACTED)])
    start = _RETRACTED if extend else _EXTENDED
    if cylinder == "stick":
        return np.array([0.0, 0.0, _end("stick", start), _end("bucket", _EXTENDED)])
    return np.array([0.0, 0.0, 0.0, _end("bucket", start)])  # boom level, stick vertical (kinematics' frames)


def cylinder_time(sim: ReferenceModel, cylinder: str, extend: bool) -> float:
    """Seconds from full spool until ``cylinder``'s test ends (NaN: not by :data:`TIME_LIMIT_S`): its far end
    within ``STROKE_END_MARGIN``, or, lowering the boom, the bucket on the ground."""
    j = kinematics.FRONT_CYLINDERS.index(cylinder)
    boom_ground = boom_on_ground(sim) if cylinder == "boom" else None  # only the boom's test has the ground in it
    q0 = _start_pose(cylinder, extend, boom_ground)
    spools = np.zeros(4)
    spools[j + 1] = _SPOOL if extend else -_SPOOL
    goal = p.CYLINDERS[cylinder].stroke - p.STROKE_END_MARGIN if extend else p.STROKE_END_MARGIN
    to_ground = cylinder == "boom" and not extend and boom_ground != min(kinematics.joint_range("boom"))
    sim.reset(q0)
    for step in range(1, int(TIME_LIMIT_S / sim.timestep) + 1):
        sim.step(spools)
        if to_ground:
            done = sim.physics.joint_positions()[1] <= boom_ground
        else:
            ext = sim.physics.cylinder_extensions()[j]
            done = (ext >= goal) if extend else (ext <= goal)
        if done:
            return step * sim.timestep
    return float("nan")


def swing_figures(sim: ReferenceModel) -> tuple[float, float]:
    """(seconds from rest through 180 degrees at full spool, top speed in rpm over the following seconds)."""
    sim.reset(_SWING_POSE)
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


def published_figures(valve: str = DEFAULT_VALVE) -> dict[str, dict]:
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

"""The loading task over N sites, written once: the single environment is N = 1, the batched one N sites.

:class:`LoadingTask` holds what the task knows of each site beyond the machine (its pile, the
material in the bucket, truck and on the ground, the teeth's sampled motion, fuel and time) as
arrays over the sites, and advances a step of any subset of them. The machines are behind a
:class:`SitePhysics`: one learned machine model (:mod:`hexgym.envs.loading`) or a MuJoCo batch
(:mod:`hexgym.envs.sites`); it exposes the simulation's arrays with a leading site axis and
steps, pushes and re-masses sites. The arithmetic of each stage is one numba-compiled function
over the sites (``cache=True``: compiled on the first call of a fresh install, then loaded from
``__pycache__``), so N single environments and one batch of N give the same floats.

A step advances four 25 ms control periods per site on the single environment's schedule:

1. :func:`plan`: each site's next interval. Where the teeth surely stay clear of the pile
   (:func:`clear_count`: their height above the highest pile point near them against 0.15 m of
   travel per period), its periods go in one call of the physics, closed by :func:`end_clear`
   (teeth velocity, spill, payload).
2. Otherwise :func:`begin_dig` digs once for ``earthwork_periods`` periods (fill, cut and relax the
   pile, the digging force; spill when not cutting); while the edge cuts, :func:`follow_resistance`
   re-aims the force every period (it is proportional to the speed below 5 cm/s: held over a
   whole step it would lag the motion).
3. After each interval, :func:`account`: fuel (the machine's own measure where it has one, the
   reference's pumps; else the actuators' power through the engine's BSFC,
   :mod:`hexgym.hydraulics.fuel`'s own functions), hard contacts (:func:`hard_contact_force`) and
   the joint loads; the bucket is re-massed on changes over 20 kg (:func:`payload_change`).
4. :func:`finish`: reward terms (the shaping terms from :func:`potentials`, computed only when one is
   weighted) and the episode's end; :func:`observe`: the observation;
   :func:`info_stores`: the material stores for ``info``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

import numpy as np

from hexgym.envs import earthwork as ew
from hexgym.envs import world
from hexgym.envs.earthwork import jit
from hexgym.envs.world import (
    BED_RIM_HEIGHT,
    PILE_GRID_POINTS,
    PILE_GRID_SPACING,
    Layout,
    fullest_cut_direction,
)
from hexgym.hydraulics import fuel
from hexgym.machine import kinematics
from hexgym.machine import parameters as p

STEP_PERIOD = 0.1  # s: one environment step, 10 Hz, an operator's reaction time scale
# Control periods per dig (fill, pile cut and relaxation, spill) while the teeth may be in the pile: 4 = once
# per 0.1 s step (fast; the digging force still follows the motion every period; `hexgym scripted` results
# stay within 1 % of digging every period), 1 = every 25 ms period.
EARTHWORK_PERIODS = 4
PAYLOAD_UPDATE_KG = 20.0  # re-mass the bucket only on changes this large (1 % of a heaped bucket): mj_setConst is slow
PILE_MARGIN = 0.6  # m: the teeth travel at most this far in one step (6 m/s), so cannot reach a pile lower by more
CONTACT_SLOTS = 16  # bucket/stick contacts the contact sensor reports (random actions reach 7 of all kinds)
REWARD_TERMS = ("delivery", "fill", "time", "fuel", "spill", "contact", "reach", "load", "lift", "carry")
SHAPING_TERMS = REWARD_TERMS[6:]  # potential-based, 0 by default: each the change of a potential (see potentials)
SHAPING_EMPTY_KG = 100.0  # kg: a bucket with less counts as empty (it reaches for the pile)
SHAPING_PILE_REACHED_M = 1.0  # m from the pile's centre: reached (within its flat top, 1.0-1.4 m)
SHAPING_LIFT_M = 1.0  # m above the pile's surface: lifted clear
INFO_STORES = ("pile_kg", "bucket_kg", "truck_kg", "spilled_kg", "fuel_l", "time_s")
INFO_KEYS = (*(f"reward_{term}" for term in REWARD_TERMS), *INFO_STORES)  # every info, reset's included
STEP_INFO_KEYS = (*INFO_KEYS, "fuel_l_step", "contact_impulse_ns")  # a step's info
OBSERVATION_SIZE = 23
# bucket-frame (x, z) of the teeth's direction and the mouth's normal (both have y = 0), and the mouth's centre
_TEETH_X, _TEETH_Z = (float(v) for v in p.BUCKET_TEETH_DIRECTION)
_MOUTH_NORMAL_X, _MOUTH_NORMAL_Z = (float(v) for v in ew.mouth_normal())
MOUTH_CENTRE = ((p.BUCKET_LIP[0] + p.BUCKET_EDGE[0]) / 2, 0.0, (p.BUCKET_LIP[1] + p.BUCKET_EDGE[1]) / 2)  # bucket frame
_MOUTH_X, _MOUTH_Z = MOUTH_CENTRE[0], MOUTH_CENTRE[2]
# the site's own functions, compiled for floats: the bed's frame, whether a point is over the bed
_bed_frame, _over_bed = jit(world.bed_frame), jit(world.over_bed)
_DENSITY = float(p.MATERIAL_DENSITY)
_HALF_WIDTH = p.BUCKET_WIDTH / 2.0
_FILTER = float(p.DIG_VELOCITY_FILTER)
_RIM = float(BED_RIM_HEIGHT)
_ENGINE_POWER = float(p.ENGINE_POWER)
_brake_power = jit(fuel._uncapped_brake_power)  # the engine's brake power for an actuator power, compiled
_HARD, _CAP, _STIFFNESS = float(p.HARD_CONTACT_FORCE), float(p.HARD_CONTACT_FORCE_CAP), float(p.CONTACT_STIFFNESS)
# Bounds (observations are clipped to them): angles, rates (rad/s) well beyond the servos' ranges,
# loads (MN) beyond the reliefs' forces, a bucket's load (t), the site's extent (m)
OBS_HIGH = np.array([np.pi] * 5 + [10.0] * 4 + [10.0] * 3 + [5.0] + [30.0] * 6 + [np.pi, 2.0, 1.0, np.pi], np.float32)
OBS_LOW = np.array([-np.pi] * 5 + [-10.0] * 4 + [-10.0] * 3 + [0.0] + [-30.0] * 6 + [0.0, 0.0, 0.0, -np.pi], np.float32)
_CLIP_LOW, _CLIP_HIGH = OBS_LOW.astype(float), OBS_HIGH.astype(float)  # as float64: clip before casting


class SitePhysics(Protocol):
    """The machines of N sites as the task sees them.

    Read-only arrays with a leading site axis, current after each of the calls below (views of the
    simulation or copies refreshed by them; C-contiguous, so that one compiled version of each stage
    serves every kind of site): ``site_xpos`` (N, nsite, 3), ``xpos`` (N, nbody, 3), ``xmat`` (N, nbody, 9),
    ``qpos`` (N, nq), ``qvel`` (N, nv), ``sensordata`` (N, nsensor); ``tip_site``, ``bucket_body`` ids;
    ``qadr``, ``dadr`` (4,) the main joints' addresses; ``contact_adr`` the tool-contact sensor's first slot.
    """

    site_xpos: np.ndarray
    xpos: np.ndarray
    xmat: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    sensordata: np.ndarray
    tip_site: int
    bucket_body: int
    qadr: np.ndarray
    dadr: np.ndarray
    contact_adr: int

    def step(self, ids: np.ndarray, periods: int) -> None:
        """Advance the sites ``ids`` by ``periods`` control periods with their spools (positions and velocities
        then current)."""

    def apply_tip_force(self, ids: np.ndarray, force: np.ndarray) -> None:
        """Apply ``force`` (k, 3; N, world) at the teeth of sites ``ids`` from now on (zero: none)."""

    def set_payload(self, ids: np.ndarray, mass_kg: np.ndarray) -> None:
        """Re-mass the payload of sites ``ids``, keeping their state."""

    def loads(self, ids: np.ndarray, joint_loads: np.ndarray, swing_torques: np.ndarray) -> None:
        """Write the main joints' loads into ``joint_loads`` (k, 4), N m (the machine model's ``joint_loads``), and
        the swing's inertia times its last table acceleration into ``swing_torques`` (k,), N m."""

    def measured_fuel(self, ids: np.ndarray, out: np.ndarray) -> None:
        """Write into ``out`` (k,) the diesel (L) each machine burnt since last asked, where the machine model
        measures it (the reference: its pumps), else NaN (the task's account estimates it)."""


# -- the compiled stages ----------------------------------------------------------------------------
@jit
def wrap(angle: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@jit
def _bucket_pose(site_xpos: np.ndarray, xmat: np.ndarray, i: int, tip_site: int, bucket: int) -> tuple:
    """Teeth (x, y, z), the edge's lateral unit vector, the teeth's direction and the mouth's tilt from up."""
    r = xmat[i, bucket]  # row-major, bucket frame -> world
    tilt = math.acos(min(max(r[6] * _MOUTH_NORMAL_X + r[8] * _MOUTH_NORMAL_Z, -1.0), 1.0))
    tip = site_xpos[i, tip_site]
    teeth = (r[0] * _TEETH_X + r[2] * _TEETH_Z, r[3] * _TEETH_X + r[5] * _TEETH_Z, r[6] * _TEETH_X + r[8] * _TEETH_Z)
    return (tip[0], tip[1], tip[2]), (r[1], r[4], r[7]), teeth, tilt


@jit
def _sample_tip(
    i: int, tip: tuple, tip_before: np.ndarray, tip_velocity: np.ndarray, tip_interval: np.ndarray, period: float,
    blend_one: float,
) -> tuple[float, float, float]:  # fmt: skip
    """The teeth's mean velocity since the last sample (m/s), also folded into the low-passed one."""
    interval = tip_interval[i]
    vx = (tip[0] - tip_before[i, 0]) / interval
    vy = (tip[1] - tip_before[i, 1]) / interval
    vz = (tip[2] - tip_before[i, 2]) / interval
    blend = blend_one if interval == period else 1.0 - math.exp(-interval / _FILTER)
    tip_velocity[i, 0] += (vx - tip_velocity[i, 0]) * blend
    tip_velocity[i, 1] += (vy - tip_velocity[i, 1]) * blend
    tip_velocity[i, 2] += (vz - tip_velocity[i, 2]) * blend
    tip_before[i, 0] = tip[0]
    tip_before[i, 1] = tip[1]
    tip_before[i, 2] = tip[2]
    return vx, vy, vz


@jit
def _spill(
    i: int, tilt: float, dt: float, xpos: np.ndarray, xmat: np.ndarray, bucket: int, truck: np.ndarray,
    stores: np.ndarray, flows: np.ndarray,
) -> None:  # fmt: skip
    """Let what the bucket cannot hold at ``tilt`` run out over ``dt`` s, into the bed if its mouth is over it."""
    out = ew.spill_out(stores[i, 0], tilt, dt)
    if out <= 0.0:
        return
    r = xmat[i, bucket]
    mx = xpos[i, bucket, 0] + r[0] * _MOUTH_X + r[2] * _MOUTH_Z
    my = xpos[i, bucket, 1] + r[3] * _MOUTH_X + r[5] * _MOUTH_Z
    along, across = _bed_frame(mx, my, truck[i, 0], truck[i, 1], truck[i, 2], truck[i, 3])  # centre, cos, sin yaw
    stores[i, 0] -= out
    if _over_bed(along, across):
        stores[i, 1] += out
        flows[i, 1] += out
    else:
        stores[i, 2] += out
        flows[i, 2] += out


@jit
def begin_step(
    ids: np.ndarray, periods: int, left: np.ndarray, flows: np.ndarray, fuel_l: np.ndarray, impulse: np.ndarray
) -> None:
    """Start a step of each site: all its ``periods`` left, no flows, fuel or impulse yet."""
    for k in range(len(ids)):
        i = ids[k]
        left[i] = periods
        flows[i, 0] = flows[i, 1] = flows[i, 2] = 0.0
        fuel_l[i] = impulse[i] = 0.0


@jit
def clear_count(
    i: int, periods: int, site_xpos: np.ndarray, tip_site: int, heights: np.ndarray, origin: np.ndarray,
    spacing: float, top: np.ndarray,
) -> int:  # fmt: skip
    """Control periods (up to a step's ``periods``) within which site ``i``'s teeth surely stay out of the pile.

    The teeth travel at most ``PILE_MARGIN`` per step, ``m`` periods at most ``m / periods`` of it; the dig
    samples lie within half a bucket width of them. ``m`` periods are clear when no pile point within half a
    width plus that travel stands higher than the teeth less that travel.
    """
    per_period = PILE_MARGIN / periods
    x, y, z = site_xpos[i, tip_site, 0], site_xpos[i, tip_site, 1], site_xpos[i, tip_site, 2]
    whole = periods * per_period
    # the usual case first: clear over the whole step is clear over each part (less travel, a smaller window)
    if ew.clearance(heights, origin, spacing, top[i], i, x, y, z, _HALF_WIDTH + whole, whole) >= whole:
        return periods
    clear = 0
    while clear < periods:
        travel = (clear + 1) * per_period
        if ew.clearance(heights, origin, spacing, top[i], i, x, y, z, _HALF_WIDTH + travel, travel) < travel:
            break
        clear += 1
    return clear


@jit
def plan(
    ids: np.ndarray, left: np.ndarray, periods: int, earthwork_periods: int, period: float, site_xpos: np.ndarray,
    tip_site: int, heights: np.ndarray, origin: np.ndarray, spacing: float, top: np.ndarray, force_on: np.ndarray,
    interval: np.ndarray, seconds: np.ndarray, tip_start: np.ndarray, clear: np.ndarray,
) -> int:  # fmt: skip
    """Each site's next interval: the periods it stays clear of the pile (:func:`clear_count`, none while its
    edge cuts), else ``earthwork_periods`` with a dig; at most the ``left`` of its step.

    Writes ``interval`` (periods), ``seconds``, ``clear`` (per k) and, for clear sites, the teeth's start.
    Returns 0 when all go clear for the same periods, 1 when all go clear, 2 when some dig.
    """
    code, first = 0, -1
    for k in range(len(ids)):
        i = ids[k]
        n = 0 if force_on[i] else min(clear_count(i, periods, site_xpos, tip_site, heights, origin, spacing, top),
                                      left[i])  # fmt: skip
        clear[k] = n > 0
        if n > 0:
            for a in range(3):
                tip_start[i, a] = site_xpos[i, tip_site, a]
            if first < 0:
                first = n
            elif n != first and code == 0:
                code = 1
        else:
            n = min(earthwork_periods, left[i])
            code = 2
        interval[i] = n
        seconds[i] = n * period
    return code


@jit
def end_clear(
    ids: np.ndarray, seconds: np.ndarray, tip_start: np.ndarray, site_xpos: np.ndarray, xpos: np.ndarray,
    xmat: np.ndarray, tip_site: int, bucket: int, tip_before: np.ndarray, tip_velocity: np.ndarray,
    tip_interval: np.ndarray, truck: np.ndarray, stores: np.ndarray, flows: np.ndarray, payload_kg: np.ndarray,
    change: np.ndarray,
) -> bool:  # fmt: skip
    """Close an interval clear of the pile: the teeth's mean velocity over it, the spill at its end tilt (its
    exact exponential over the interval), the payload (:func:`payload_change`). Returns whether any changed."""
    any_change = False
    for k in range(len(ids)):
        i = ids[k]
        tip, _, _, tilt = _bucket_pose(site_xpos, xmat, i, tip_site, bucket)
        for a in range(3):
            tip_velocity[i, a] = (tip[a] - tip_start[i, a]) / seconds[i]
            tip_before[i, a] = tip_start[i, a]
        tip_interval[i] = seconds[i]
        _spill(i, tilt, seconds[i], xpos, xmat, bucket, truck, stores, flows)
        change[k] = payload_change(i, stores, payload_kg)
        any_change |= change[k]
    return any_change


@jit
def begin_dig(
    ids: np.ndarray, seconds: np.ndarray, site_xpos: np.ndarray, xpos: np.ndarray, xmat: np.ndarray, tip_site: int,
    bucket: int, heights: np.ndarray, origin: np.ndarray, spacing: float, top: np.ndarray, tip_before: np.ndarray,
    tip_velocity: np.ndarray, tip_interval: np.ndarray, period: float, blend_one: float, dig_depth: np.ndarray,
    force_on: np.ndarray, truck: np.ndarray, stores: np.ndarray, flows: np.ndarray, payload_kg: np.ndarray,
    pile_flags: np.ndarray, force: np.ndarray, push: np.ndarray, change: np.ndarray,
) -> tuple[bool, bool, bool]:  # fmt: skip
    """Dig once for the next ``seconds`` per site: sample the teeth's motion (a backward difference since the last
    sample), fill and cut the pile (:func:`hexgym.envs.earthwork.dig`), or spill where the edge does not cut.

    Writes the digging force (k, 3) and whether to push it (``push``: cutting now or before; a zero force
    clears the last); a site cuts from now on where its depth is positive (``force_on``; its pile is
    flagged changed: ``pile_flags`` columns changed, volume stale, revision). Returns whether any site pushes,
    any payload changed (``change``) and any site cuts.
    """
    any_push, any_change, any_cut = False, False, False
    for k in range(len(ids)):
        i = ids[k]
        tip, lateral, teeth, tilt = _bucket_pose(site_xpos, xmat, i, tip_site, bucket)
        vx, vy, vz = _sample_tip(i, tip, tip_before, tip_velocity, tip_interval, period, blend_one)
        fx, fy, fz, taken_kg, depth = ew.dig(
            heights, origin, spacing, top[i], i, stores[i, 0], tip[0], tip[1], tip[2], lateral[0], lateral[1],
            lateral[2], teeth[0], teeth[1], teeth[2], vx, vy, vz, seconds[i], tip_velocity[i, 0],
            tip_velocity[i, 1], tip_velocity[i, 2],
        )  # fmt: skip
        dig_depth[i] = depth
        stores[i, 0] += taken_kg
        flows[i, 0] += taken_kg
        if depth <= 0.0:
            _spill(i, tilt, seconds[i], xpos, xmat, bucket, truck, stores, flows)
        else:
            pile_flags[i, 0] = pile_flags[i, 1] = 1
            pile_flags[i, 2] += 1
            any_cut = True
        push[k] = depth > 0.0 or force_on[i]
        any_push |= push[k]
        force_on[i] = depth > 0.0
        force[k, 0], force[k, 1], force[k, 2] = fx, fy, fz
        change[k] = payload_change(i, stores, payload_kg)
        any_change |= change[k]
    return any_push, any_change, any_cut


@jit
def follow_resistance(
    ids: np.ndarray, site_xpos: np.ndarray, xmat: np.ndarray, tip_site: int, bucket: int, tip_before: np.ndarray,
    tip_velocity: np.ndarray, tip_interval: np.ndarray, period: float, blend_one: float, dig_depth: np.ndarray,
    stores: np.ndarray, force: np.ndarray,
) -> None:  # fmt: skip
    """Re-aim the digging force of cutting sites with the teeth's motion (sampled now) at their last dig's depth."""
    for k in range(len(ids)):
        i = ids[k]
        tip, lateral, teeth, _ = _bucket_pose(site_xpos, xmat, i, tip_site, bucket)
        _sample_tip(i, tip, tip_before, tip_velocity, tip_interval, period, blend_one)
        fx, fy, fz = ew.resistance(
            dig_depth[i], stores[i, 0], lateral[0], lateral[1], lateral[2], teeth[0], teeth[1], teeth[2],
            tip_velocity[i, 0], tip_velocity[i, 1], tip_velocity[i, 2],
        )  # fmt: skip
        force[k, 0], force[k, 1], force[k, 2] = fx, fy, fz


@jit
def payload_change(i: int, stores: np.ndarray, payload_kg: np.ndarray) -> bool:
    """Whether site ``i``'s bucket contents moved more than ``PAYLOAD_UPDATE_KG`` from its machine's payload, or
    emptied; if so the payload becomes them (and the caller re-masses the machine: ``mj_setConst`` is slow)."""
    bucket, payload = stores[i, 0], payload_kg[i]
    if abs(bucket - payload) > PAYLOAD_UPDATE_KG or (bucket < 1.0 and 1.0 < payload):
        payload_kg[i] = bucket
        return True
    return False


@jit
def hard_contact_force(i: int, sensordata: np.ndarray, adr: int, slots: int) -> float:
    """Site ``i``'s bucket and stick contact force on the ground and the truck beyond ``HARD_CONTACT_FORCE``
    (capped at the machine's weight), N; -1 when it has more contacts than the sensor's ``slots``.

    From the contact sensor's depths (``CONTACT_STIFFNESS``): the machine's contacts are detected but
    inactive, the learned model stalls a joint that drives into one.
    """
    found = int(sensordata[i, adr])
    if found > slots:
        return -1.0
    if found == 0:
        return 0.0
    depth = 0.0
    for s in range(found):
        depth -= min(sensordata[i, adr + 2 * s + 1], 0.0)
    return min(max(_STIFFNESS * depth - _HARD, 0.0), _CAP - _HARD)


@jit
def account(
    ids: np.ndarray, seconds: np.ndarray, loads: np.ndarray, swing_torques: np.ndarray, qvel: np.ndarray,
    dadr: np.ndarray, fuel_rates: np.ndarray, fuel_start: float, fuel_step: float, measured: np.ndarray,
    sensordata: np.ndarray, contact_adr: int, slots: int, joint_loads: np.ndarray, fuel_l: np.ndarray,
    impulse: np.ndarray, left: np.ndarray, interval: np.ndarray, going: np.ndarray,
) -> int:  # fmt: skip
    """Close each site's interval of ``seconds``: fuel (the machine's own measure, ``measured`` (k,) L, where it
    has one; else the actuators' power at the interval's end through the engine's BSFC,
    :mod:`hexgym.hydraulics.fuel`), hard-contact impulse, the joint loads (k, 4) kept for the
    observation, and the periods ``left`` of the step. Returns how many sites have periods left (their ids first
    in ``going``, which may be ``ids`` itself), or -1 - i for a site i with too many contacts."""
    count = 0
    for k in range(len(ids)):
        i = ids[k]
        power = 0.0
        for j in range(1, 4):  # the front's joints, in order, then the swing
            power += abs(loads[k, j] * qvel[i, dadr[j]])
            joint_loads[i, j] = loads[k, j]
        joint_loads[i, 0] = loads[k, 0]
        power += abs(swing_torques[k] * qvel[i, dadr[0]])
        if measured[k] == measured[k]:  # not NaN: the machine's own
            fuel_l[i] += measured[k]
        else:
            brake = min(_brake_power(power), _ENGINE_POWER)
            fuel_l[i] += ew.table_at(fuel_rates, fuel_start, fuel_step, brake) * seconds[i] / 3600.0
        force = hard_contact_force(i, sensordata, contact_adr, slots)
        if force < 0.0:
            return -1 - i
        impulse[i] += force * seconds[i]
        left[i] -= interval[i]
        if left[i] > 0:
            going[count] = i
            count += 1
    return count


@jit
def potentials(
    ids: np.ndarray, site_xpos: np.ndarray, tip_site: int, heights: np.ndarray, origin: np.ndarray, spacing: float,
    layout: np.ndarray, stores: np.ndarray, out: np.ndarray,
) -> None:  # fmt: skip
    """The shaping potentials of each site into ``out[i]`` (n, 4), in ``SHAPING_TERMS`` order, from where its
    teeth are and what its bucket holds (t):

    - reach: an empty bucket's teeth, minus their horizontal distance (m) beyond ``SHAPING_PILE_REACHED_M``
      from the pile's centre and minus their height above the pile's surface (0 while loaded): down onto it;
    - load: the tonnes in the bucket;
    - lift: the tonnes times the teeth's height above the pile's surface, up to ``SHAPING_LIFT_M``, over it;
    - carry: the tonnes times how much of the way from the pile's centre to the bed's the teeth have come
      horizontally (1 over the bed's centre, 0 at the pile's distance from it or farther).
    """
    for k in range(len(ids)):
        i = ids[k]
        x, y, z = site_xpos[i, tip_site, 0], site_xpos[i, tip_site, 1], site_xpos[i, tip_site, 2]
        tonnes = stores[i, 0] / 1000.0
        to_pile = math.hypot(x - layout[i, 0], y - layout[i, 1])
        above = z - ew.height_at(heights, origin, spacing, i, x, y)
        empty = stores[i, 0] < SHAPING_EMPTY_KG
        out[i, 0] = -max(to_pile - SHAPING_PILE_REACHED_M, 0.0) - max(above, 0.0) if empty else 0.0
        out[i, 1] = tonnes
        out[i, 2] = tonnes * min(max(above, 0.0), SHAPING_LIFT_M) / SHAPING_LIFT_M
        span = math.hypot(layout[i, 5] - layout[i, 0], layout[i, 6] - layout[i, 1])
        out[i, 3] = tonnes * (1.0 - min(math.hypot(x - layout[i, 5], y - layout[i, 6]) / span, 1.0))


@jit
def finish(
    ids: np.ndarray, weights: np.ndarray, flows: np.ndarray, fuel_step: np.ndarray, impulse: np.ndarray,
    fuel_l: np.ndarray, steps: np.ndarray, elapsed: np.ndarray, stores: np.ndarray, capacity: float,
    time_limit: float, before: np.ndarray, after: np.ndarray, terms: np.ndarray, rewards: np.ndarray,
    ended: np.ndarray,
) -> None:  # fmt: skip
    """End the step of each site: fuel and time, the reward terms (k, 10: ``REWARD_TERMS``, weighted; their sum
    in order is the reward; the shaping terms the change of :func:`potentials` from ``before`` to ``after``,
    which then becomes ``before``) and whether it terminated (the truck holds its capacity) or truncated (time)."""
    for k in range(len(ids)):
        i = ids[k]
        fuel_l[i] += fuel_step[i]
        steps[i] += 1
        elapsed[i] = steps[i] * STEP_PERIOD
        terms[k, 0] = weights[0] * flows[i, 1] / 1000.0
        terms[k, 1] = weights[1] * flows[i, 0] / 1000.0
        terms[k, 2] = -weights[2] * STEP_PERIOD
        terms[k, 3] = -weights[3] * fuel_step[i]
        terms[k, 4] = -weights[4] * flows[i, 2] / 1000.0
        terms[k, 5] = -weights[5] * impulse[i] / 1000.0
        for j in range(4):
            terms[k, 6 + j] = weights[6 + j] * (after[i, j] - before[i, j])
            before[i, j] = after[i, j]
        total = terms[k, 0]
        for j in range(1, 10):
            total += terms[k, j]
        rewards[k] = total
        ended[k, 0] = stores[i, 1] >= capacity
        ended[k, 1] = elapsed[i] >= time_limit - 1e-9


@jit
def observe(
    ids: np.ndarray, qpos: np.ndarray, qvel: np.ndarray, qadr: np.ndarray, dadr: np.ndarray, site_xpos: np.ndarray,
    xmat: np.ndarray, tip_site: int, bucket: int, joint_loads: np.ndarray, arms: np.ndarray, arm_start: np.ndarray,
    arm_step: np.ndarray, heights: np.ndarray, origin: np.ndarray, spacing: float, layout: np.ndarray,
    stores: np.ndarray, truck_capacity: float, elapsed: np.ndarray, time_limit: float, cut_dir: np.ndarray,
    out: np.ndarray,
) -> int:  # fmt: skip
    """Write the observation of each site (see :class:`hexgym.envs.loading.HexLoadingEnv`) into ``out`` (k, 23,
    float32), clipped to its bounds (as float64, then rounded); returns the first site whose observation is not
    finite (-1: none)."""
    values = np.empty(OBSERVATION_SIZE)
    for k in range(len(ids)):
        i = ids[k]
        tip, _, _, tilt = _bucket_pose(site_xpos, xmat, i, tip_site, bucket)
        swing = qpos[i, qadr[0]]
        for j in range(3):
            values[j] = qpos[i, qadr[j + 1]]
            arm = ew.table_at(arms[j], arm_start[j], arm_step[j], values[j])
            values[9 + j] = joint_loads[i, j + 1] / arm / 1e6  # MN
        for j in range(4):
            values[5 + j] = qvel[i, dadr[j]]
        # layout: pile centre x, y, direction, cos, sin; truck centre x, y, direction, cos yaw, sin yaw
        values[3] = wrap(swing - layout[i, 2])
        values[4] = wrap(swing - layout[i, 7])
        values[12] = stores[i, 0] / 1000.0
        rel_x, rel_y = tip[0] - layout[i, 0], tip[1] - layout[i, 1]
        c, s = layout[i, 3], layout[i, 4]
        values[13] = c * rel_x + s * rel_y
        values[14] = -s * rel_x + c * rel_y
        values[15] = tip[2] - ew.height_at(heights, origin, spacing, i, tip[0], tip[1])
        values[16], values[17] = _bed_frame(tip[0], tip[1], layout[i, 5], layout[i, 6], layout[i, 8], layout[i, 9])
        values[18] = tip[2] - _RIM
        values[19] = tilt
        values[20] = stores[i, 1] / truck_capacity
        values[21] = max(1.0 - elapsed[i] / time_limit, 0.0)
        values[22] = wrap(swing - cut_dir[i])
        for j in range(OBSERVATION_SIZE):
            if not math.isfinite(values[j]):
                return i
            out[k, j] = min(max(values[j], _CLIP_LOW[j]), _CLIP_HIGH[j])
    return -1


@jit
def any_flagged(ids: np.ndarray, flags: np.ndarray, column: int) -> bool:
    """Whether any site's ``flags[i, column]`` is set."""
    for k in range(len(ids)):
        if flags[ids[k], column]:
            return True
    return False


@jit
def info_stores(
    ids: np.ndarray, heights: np.ndarray, pile_flags: np.ndarray, volume: np.ndarray, cell_area: float,
    stores: np.ndarray, fuel_l: np.ndarray, elapsed: np.ndarray, out: np.ndarray,
) -> None:  # fmt: skip
    """``INFO_STORES`` of each site into ``out`` (k, 6): pile, bucket, truck, spilled (kg), fuel (L), time (s); a
    pile's volume is summed again only when flagged stale (``pile_flags[:, 1]``)."""
    for k in range(len(ids)):
        i = ids[k]
        if pile_flags[i, 1]:
            volume[i] = heights[i].sum() * cell_area
            pile_flags[i, 1] = 0
        out[k, 0] = volume[i] * _DENSITY
        out[k, 1], out[k, 2], out[k, 3] = stores[i, 0], stores[i, 1], stores[i, 2]
        out[k, 4], out[k, 5] = fuel_l[i], elapsed[i]


# -- the task ---------------------------------------------------------------------------------------
class LoadingTask:
    """The loading task's state for ``count`` sites and its step (see the module docstring).

    Args:
        count: number of sites.
        physics: the sites' machines (:class:`SitePhysics`).
        period: the machine model's control period, s (a whole number of them make a step).
        time_limit, truck_capacity_kg, weights, earthwork_periods: as ``HexLoadingEnv``'s arguments.
    """

    def __init__(
        self,
        count: int,
        physics: SitePhysics,
        period: float,
        time_limit: float,
        truck_capacity_kg: float,
        weights: dict[str, float],
        earthwork_periods: int = EARTHWORK_PERIODS,
    ) -> None:
        self.count, self.physics, self.period = int(count), physics, float(period)
        self.periods = int(round(STEP_PERIOD / period))
        if abs(self.periods * period - STEP_PERIOD) > 1e-9:
            raise ValueError(f"the machine's control period {period} s does not divide the step {STEP_PERIOD} s")
        self.time_limit, self.truck_capacity_kg = float(time_limit), float(truck_capacity_kg)
        self.weights, self.earthwork_periods = weights, int(earthwork_periods)
        self._weights = np.array([float(weights[term]) for term in REWARD_TERMS])
        self._blend_one = 1.0 - math.exp(-self.period / p.DIG_VELOCITY_FILTER)
        n = self.count
        self.heights = np.zeros((n, PILE_GRID_POINTS, PILE_GRID_POINTS))
        self.origin = np.zeros((n, 2))  # world (x, y) of each pile's grid point [0, 0]
        self.top = np.zeros(n)  # upper bound of each pile's surface (digging only lowers it)
        self.spacing = PILE_GRID_SPACING
        self._volume = np.zeros(n)
        # per pile: changed since its fullest cut line was found, volume stale, revision (counts the cuts)
        self.pile_flags = np.zeros((n, 3), np.int64)
        self.layouts: list[Layout | None] = [None] * n
        # pile centre x, y, direction, cos, sin; truck centre x, y, direction, cos yaw, sin yaw
        self.layout = np.zeros((n, 10))
        self.truck = np.zeros((n, 4))  # the bed's frame: centre x, y, cos yaw, sin yaw
        self.cut_dir = np.zeros(n)  # each pile's fullest cut line (rad), kept while the pile stands
        self.stores = np.zeros((n, 3))  # bucket, truck, spilled, kg
        self.payload_kg = np.zeros(n)  # the payload each machine is massed with
        self.tip_before, self.tip_velocity = np.zeros((n, 3)), np.zeros((n, 3))
        self.tip_interval = np.full(n, math.inf)  # s since tip_before was taken (inf: none yet, velocity 0)
        self.force_on = np.zeros(n, np.bool_)
        self.dig_depth = np.zeros(n)
        self.joint_loads = np.zeros((n, 4))
        self.fuel_l, self.elapsed, self.steps = np.zeros(n), np.zeros(n), np.zeros(n, np.int64)
        # a step's scratch, per site: periods left, this interval's periods and seconds, teeth at its start,
        # the step's flows (dug, delivered, spilled, kg), fuel (L) and contact impulse (N s)
        self._left, self._interval = np.zeros(n, np.int64), np.zeros(n, np.int64)
        self._seconds, self._tip_start = np.zeros(n), np.zeros((n, 3))
        self._flows, self._fuel, self._impulse = np.zeros((n, 3)), np.zeros(n), np.zeros(n)
        # and per k of a call's sites (written before read): clear of the pile, payload changed, the machines' loads;
        # the sites with periods left after an interval
        self._clear, self._change = np.zeros(n, np.bool_), np.zeros(n, np.bool_)
        self._loads, self._swing_torques, self._measured_fuel = np.zeros((n, 4)), np.zeros(n), np.zeros(n)
        self._going = np.zeros(n, np.int64)
        # shaping potentials after the last step and now (zeros, never computed, while every shaping weight is 0)
        self._shaping = any(float(weights[term]) != 0.0 for term in SHAPING_TERMS)
        self._potential, self._potential_now = np.zeros((n, 4)), np.zeros((n, 4))
        tables = kinematics.moment_arm_tables()
        self._arms = np.array([t.values for t in tables])
        self._arm_start = np.array([t.start for t in tables])
        self._arm_step = np.array([t.step for t in tables])
        rates = fuel._fuel_rate_table()
        self._fuel_rates, self._fuel_start, self._fuel_step = np.array(rates.values), rates.start, rates.step
        self.contact_slots = CONTACT_SLOTS

    # -- episodes ---------------------------------------------------------------------------------
    def start(self, i: int, layout: Layout, pile: ew.Pile, payload_kg: float = 0.0) -> None:
        """Begin an episode at site ``i`` on ``layout`` with ``pile`` (copied), the machine already placed and
        massed with ``payload_kg``, which its bucket holds; call :meth:`finish_starts` once the machines' derived
        quantities are current."""
        self.layouts[i] = layout
        self.heights[i] = pile.heights
        self.origin[i] = pile.origin
        self.top[i] = pile.top
        self.pile_flags[i, :2] = 1
        c, s = math.cos(layout.pile_direction), math.sin(layout.pile_direction)
        ct, st = math.cos(layout.truck_yaw), math.sin(layout.truck_yaw)
        (px, py), (tx, ty) = layout.pile_centre, layout.truck_centre
        self.layout[i] = (px, py, layout.pile_direction, c, s, tx, ty, layout.truck_direction, ct, st)
        self.truck[i] = (tx, ty, ct, st)
        self.stores[i] = 0.0
        self.stores[i, 0] = self.payload_kg[i] = payload_kg
        self.tip_interval[i] = math.inf
        self.tip_velocity[i] = 0.0
        self.force_on[i] = False
        self.dig_depth[i] = 0.0
        self.fuel_l[i] = self.elapsed[i] = 0.0
        self.steps[i] = 0

    def finish_starts(self, ids: np.ndarray) -> None:
        """The teeth and joint loads of freshly started sites (their machines' derived quantities current)."""
        ph = self.physics
        self.tip_before[ids] = ph.site_xpos[ids, ph.tip_site]
        ph.loads(ids, self._loads, self._swing_torques)
        ph.measured_fuel(ids, self._measured_fuel)  # what a start burnt is no part of the episode
        self.joint_loads[ids] = self._loads[: len(ids)]
        if self._shaping:
            self._potentials(ids, self._potential)

    def _potentials(self, ids: np.ndarray, out: np.ndarray) -> None:
        ph = self.physics
        potentials(ids, ph.site_xpos, ph.tip_site, self.heights, self.origin, self.spacing, self.layout, self.stores,
                   out)  # fmt: skip

    def pile(self, i: int) -> ew.Pile:
        """A handle on site ``i``'s pile (its heights are the task's; a cut through it flags the pile changed)."""
        flags = tuple(self.pile_flags.T)
        pile = ew.Pile(None, None, self.spacing, self.heights, self.origin, i, flags)
        pile.top = float(self.top[i])
        return pile

    # -- a step -----------------------------------------------------------------------------------
    def step(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Advance sites ``ids`` (their spools set) by a step.

        Returns their reward terms (k, 10), rewards (k,) and terminated, truncated (k, 2); the step's fuel
        (L) and hard-contact impulse (N s) stay in ``step_fuel_l`` and ``step_impulse``.
        """
        k = len(ids)
        begin_step(ids, self.periods, self._left, self._flows, self._fuel, self._impulse)
        self._advance(ids)
        if self._shaping:
            self._potentials(ids, self._potential_now)
        terms, rewards, ended = np.empty((k, len(REWARD_TERMS))), np.empty(k), np.empty((k, 2), np.bool_)
        finish(ids, self._weights, self._flows, self._fuel, self._impulse, self.fuel_l, self.steps, self.elapsed,
               self.stores, self.truck_capacity_kg, self.time_limit, self._potential, self._potential_now, terms,
               rewards, ended)  # fmt: skip
        return terms, rewards, ended

    @property
    def step_fuel_l(self) -> np.ndarray:
        """Each site's fuel in its last step, L."""
        return self._fuel

    @property
    def step_impulse(self) -> np.ndarray:
        """Each site's hard-contact impulse in its last step, N s."""
        return self._impulse

    def _advance(self, ids: np.ndarray) -> None:
        """Rounds of clear or digging intervals until each site has advanced its step's periods."""
        ph = self.physics
        while True:
            code = plan(ids, self._left, self.periods, self.earthwork_periods, self.period, ph.site_xpos, ph.tip_site,
                        self.heights, self.origin, self.spacing, self.top, self.force_on, self._interval,
                        self._seconds, self._tip_start, self._clear)  # fmt: skip
            if code == 0:  # the usual case: all clear of the pile, for the same periods
                ph.step(ids, int(self._interval[ids[0]]))
                self._end_clear(ids)
            elif code == 1:
                self._step_grouped(ids)
                self._end_clear(ids)
            else:
                clear = self._clear[: len(ids)]
                self._dig(ids[~clear])
                if clear.any():
                    self._step_grouped(ids[clear])
                    self._end_clear(ids[clear])
            ids = self._account(ids)
            if not len(ids):
                return

    def _step_grouped(self, ids: np.ndarray) -> None:
        """Advance each site by its interval's periods: one physics call per distinct count."""
        periods = self._interval[ids]
        for count in sorted(set(periods.tolist())):
            self.physics.step(ids[periods == count], count)

    def _end_clear(self, ids: np.ndarray) -> None:
        """After an interval clear of the pile (:func:`end_clear`): no digging force acted; re-mass the bucket."""
        ph = self.physics
        change = self._change
        if end_clear(ids, self._seconds, self._tip_start, ph.site_xpos, ph.xpos, ph.xmat, ph.tip_site,
                     ph.bucket_body, self.tip_before, self.tip_velocity, self.tip_interval, self.truck, self.stores,
                     self._flows, self.payload_kg, change):  # fmt: skip
            changed = ids[change[: len(ids)]]
            ph.set_payload(changed, self.payload_kg[changed])

    def _dig(self, ids: np.ndarray) -> None:
        """One dig (:func:`begin_dig`), then the interval's periods: cutting sites period by period, re-aiming their
        digging force between them (:func:`follow_resistance`)."""
        ph = self.physics
        k = len(ids)
        force, push, change = np.empty((k, 3)), np.empty(k, np.bool_), np.empty(k, np.bool_)
        any_push, any_change, any_cut = begin_dig(
            ids, self._seconds, ph.site_xpos, ph.xpos, ph.xmat, ph.tip_site, ph.bucket_body, self.heights,
            self.origin, self.spacing, self.top, self.tip_before, self.tip_velocity, self.tip_interval, self.period,
            self._blend_one, self.dig_depth, self.force_on, self.truck, self.stores, self._flows, self.payload_kg,
            self.pile_flags, force, push, change,
        )  # fmt: skip
        if any_push:
            ph.apply_tip_force(ids[push], force[push])
        if any_change:
            ph.set_payload(ids[change], self.payload_kg[ids[change]])
        cutting = self.force_on[ids] if any_cut else np.zeros(k, np.bool_)
        if not any_cut or not cutting.all():
            still = ids[~cutting]
            self._step_grouped(still)
            self.tip_interval[still] = self._seconds[still]
        if any_cut:
            cut_ids = ids[cutting]
            cut_periods = self._interval[cut_ids]
            for start in range(int(cut_periods.max())):
                now = cut_ids[cut_periods > start] if start else cut_ids
                if start:
                    force = np.empty((len(now), 3))
                    follow_resistance(now, ph.site_xpos, ph.xmat, ph.tip_site, ph.bucket_body, self.tip_before,
                                      self.tip_velocity, self.tip_interval, self.period, self._blend_one,
                                      self.dig_depth, self.stores, force)  # fmt: skip
                    ph.apply_tip_force(now, force)
                ph.step(now, 1)
                self.tip_interval[now] = self.period

    def _account(self, ids: np.ndarray) -> np.ndarray:
        """Fuel, hard-contact impulse and joint loads at the end of the sites' intervals (:func:`account`); returns
        the sites with periods left."""
        ph = self.physics
        ph.loads(ids, self._loads, self._swing_torques)
        ph.measured_fuel(ids, self._measured_fuel)
        going = account(ids, self._seconds, self._loads, self._swing_torques, ph.qvel, ph.dadr, self._fuel_rates,
                        self._fuel_start, self._fuel_step, self._measured_fuel, ph.sensordata, ph.contact_adr,
                        self.contact_slots, self.joint_loads, self._fuel, self._impulse, self._left, self._interval,
                        self._going)  # fmt: skip
        if going < 0:
            raise RuntimeError(f"more than {self.contact_slots} bucket/stick contacts at environment {-1 - going}")
        return self._going[:going]

    # -- observation and info ---------------------------------------------------------------------
    def observe(self, ids: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The observations of sites ``ids`` (k, 23), float32 (written into ``out`` when given)."""
        self.update_cut_directions(ids)
        ph = self.physics
        if out is None:
            out = np.empty((len(ids), OBSERVATION_SIZE), np.float32)
        bad = observe(ids, ph.qpos, ph.qvel, ph.qadr, ph.dadr, ph.site_xpos, ph.xmat, ph.tip_site, ph.bucket_body,
                      self.joint_loads, self._arms, self._arm_start, self._arm_step, self.heights, self.origin,
                      self.spacing, self.layout, self.stores, self.truck_capacity_kg, self.elapsed, self.time_limit,
                      self.cut_dir, out)  # fmt: skip
        if bad >= 0:
            raise RuntimeError(
                f"the simulation diverged (non-finite observation) at environment {bad}, t = {self.elapsed[bad]:.1f} s"
            )
        return out

    def update_cut_directions(self, ids: np.ndarray) -> None:
        """Find the fullest cut line (:func:`hexgym.envs.world.fullest_cut_direction`) of the piles ``ids`` that
        changed since it was last found."""
        if not any_flagged(ids, self.pile_flags, 0):
            return
        for i in ids[self.pile_flags[ids, 0] > 0].tolist():
            self.cut_dir[i] = fullest_cut_direction(self._height_function(i), self.layouts[i])
            self.pile_flags[i, 0] = 0

    def _height_function(self, i: int) -> Callable[[np.ndarray], np.ndarray]:
        heights, origin, spacing = self.heights, self.origin, self.spacing

        def height(xy: np.ndarray) -> np.ndarray:
            flat = np.ascontiguousarray(xy.reshape(-1, 2), dtype=float)
            return ew.heights_at(heights, origin, spacing, i, flat).reshape(xy.shape[:-1])

        return height

    def stores_of(self, ids: np.ndarray) -> np.ndarray:
        """``INFO_STORES`` of sites ``ids`` (k, 6): pile, bucket, truck, spilled (kg), fuel (L), time (s)."""
        out = np.empty((len(ids), len(INFO_STORES)))
        info_stores(ids, self.heights, self.pile_flags, self._volume, self.spacing**2, self.stores, self.fuel_l,
                    self.elapsed, out)  # fmt: skip
        return out

    @property
    def revision(self) -> np.ndarray:
        """Counts each pile's changes (for a renderer's copy of it)."""
        return self.pile_flags[:, 2]

    def pile_kg(self) -> np.ndarray:
        """Material in each pile, kg."""
        return self.stores_of(np.arange(self.count))[:, 0]

    def clear_periods_of(self, ids: np.ndarray) -> np.ndarray:
        """:func:`clear_count` of sites ``ids`` (0 where the edge cuts)."""
        ph = self.physics
        return np.array([0 if self.force_on[i] else clear_count(i, self.periods, ph.site_xpos, ph.tip_site,
                         self.heights, self.origin, self.spacing, self.top) for i in ids.tolist()])  # fmt: skip

    def hard_contact_forces(self, ids: np.ndarray) -> np.ndarray:
        """:func:`hard_contact_force` of sites ``ids``, N."""
        ph = self.physics
        force = np.array([hard_contact_force(i, ph.sensordata, ph.contact_adr, self.contact_slots)
                          for i in ids.tolist()])  # fmt: skip
        if (force < 0).any():
            raise RuntimeError(f"more than {self.contact_slots} bucket/stick contacts at environment {ids[force < 0]}")
        return force

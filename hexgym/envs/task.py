"""The loading task over N sites, written once: the single environment is N = 1, the batched one N sites.

:class:`LoadingTask` holds what the task knows of each site beyond the machine (its pile, the
material in the bucket, truck and on the ground, the teeth's sampled motion, fuel and time) as
one record per site (:data:`SITE`: fields by name), and advances a step of any subset of them. The machines are behind a
:class:`SitePhysics` (learned machine models or a MuJoCo batch, :mod:`hexgym.envs.sites`): the task starts sites
through it (:meth:`LoadingTask.start`: a :class:`SiteStart` each), hands it each step's spools
(:meth:`LoadingTask.step`), and has it step, push and re-mass sites; it exposes the simulation's arrays with a
leading site axis. The arithmetic of each stage is one numba-compiled function
over the sites (:data:`hexgym.envs.compiled.jit`: compiled on the first call of a fresh install, then loaded
from ``__pycache__``), so N single environments and one batch of N give the same floats.

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
from collections.abc import Callable, Sequence
from typing import NamedTuple, Protocol

import numpy as np

from hexgym.envs import earthwork as ew
from hexgym.envs import world
from hexgym.envs.compiled import jit
from hexgym.envs.world import (
    BED_RIM_HEIGHT,
    PILE_GRID_POINTS,
    PILE_GRID_SPACING,
    Layout,
    fullest_cut_direction,
    heap_for,
)
from hexgym.hydraulics import fuel
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.bucket import BUCKET

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
_DELIVERY, _FILL, _TIME, _FUEL, _SPILL, _CONTACT = (
    REWARD_TERMS.index(term) for term in ("delivery", "fill", "time", "fuel", "spill", "contact")
)  # their columns
SHAPING_EMPTY_KG = 100.0  # kg: a bucket with less counts as empty (it reaches for the pile)
SHAPING_PILE_REACHED_M = 1.0  # m from the pile's centre: reached (within its flat top, 1.0-1.4 m)
SHAPING_LIFT_M = 1.0  # m above the pile's surface: lifted clear
INFO_STORES = ("pile_kg", "bucket_kg", "truck_kg", "spilled_kg", "fuel_l", "time_s")
INFO_KEYS = (*(f"reward_{term}" for term in REWARD_TERMS), *INFO_STORES)  # every info, reset's included
STEP_INFO_KEYS = (*INFO_KEYS, "fuel_l_step", "contact_impulse_ns")  # a step's info
OBSERVATION_SIZE = 23
# bucket-frame (x, z) of the teeth's direction and the mouth's normal (both have y = 0), and the mouth's centre
_TEETH_X, _TEETH_Z = BUCKET.teeth_direction
_MOUTH_NORMAL_X, _MOUTH_NORMAL_Z = (float(v) for v in ew.mouth_normal())
_MOUTH_X, _MOUTH_Z = BUCKET.mouth_centre[0], BUCKET.mouth_centre[2]  # bucket frame
# the site's own functions, compiled for floats: the bed's frame, whether a point is over the bed
_bed_frame, _over_bed = jit(world.bed_frame), jit(world.over_bed)
_HALF_WIDTH = p.BUCKET_WIDTH / 2.0
_FILTER = float(p.DIG_VELOCITY_FILTER)
_RIM = float(BED_RIM_HEIGHT)
_brake_power = jit(fuel._uncapped_brake_power)  # the engine's brake power for an actuator power, compiled
_HARD, _CAP, _STIFFNESS = float(p.HARD_CONTACT_FORCE), float(p.HARD_CONTACT_FORCE_CAP), float(p.CONTACT_STIFFNESS)
# Bounds (observations are clipped to them): angles, rates (rad/s) well beyond the servos' ranges,
# loads (MN) beyond the reliefs' forces, a bucket's load (t), the site's extent (m)
OBS_HIGH = np.array([np.pi] * 5 + [10.0] * 4 + [10.0] * 3 + [5.0] + [30.0] * 6 + [np.pi, 2.0, 1.0, np.pi], np.float32)
OBS_LOW = np.array([-np.pi] * 5 + [-10.0] * 4 + [-10.0] * 3 + [0.0] + [-30.0] * 6 + [0.0, 0.0, 0.0, -np.pi], np.float32)
_CLIP_LOW, _CLIP_HIGH = OBS_LOW.astype(float), OBS_HIGH.astype(float)  # as float64: clip before casting


class SiteStart(NamedTuple):
    """How a site's episode starts: where its pile and truck stand, the machine's joint angles (rad; swing, boom,
    stick, bucket) at rest, and the material in its bucket (kg)."""

    layout: Layout
    q: np.ndarray
    payload_kg: float = 0.0


class SitePhysics(Protocol):
    """The machines of N sites as the task sees them: the loading task's physics (as dm_control's ``Physics`` is a
    task's), single or batched.

    A task starts sites (:meth:`start`), holds each site's spools (:meth:`hold`, the action) and advances them
    (:meth:`step`), and between steps pushes the teeth, re-masses the bucket and reads loads and fuel.
    Read-only arrays with a leading site axis, current after each of these calls (views of the simulation or
    copies refreshed by them; C-contiguous, so that one compiled version of each stage serves every kind of
    site): ``site_xpos`` (N, nsite, 3), ``xpos`` (N, nbody, 3), ``xmat`` (N, nbody, 9), ``qpos`` (N, nq),
    ``qvel`` (N, nv), ``sensordata`` (N, nsensor); ``tip_site``, ``bucket_body`` ids; ``qadr``, ``dadr`` (4,)
    the main joints' addresses; ``contact_adr`` the tool-contact sensor's first slot; ``control_period`` the
    machines' control period (s).
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
    control_period: float

    def start(self, ids: np.ndarray, starts: Sequence[SiteStart]) -> None:
        """Put the machine of each site ``ids[k]`` at rest at ``starts[k]`` (its site laid out, its bucket massed,
        spools neutral, no digging force), its derived quantities current."""

    def hold(self, ids: np.ndarray, spools_m: np.ndarray) -> None:
        """Hold the spools (k, 4), m (swing, boom, stick, bucket; within the stroke) of sites ``ids`` from the next
        :meth:`step` on."""

    def step(self, ids: np.ndarray, periods: int) -> None:
        """Advance the sites ``ids`` by ``periods`` control periods with their spools held (positions and velocities
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


# -- the task's state, named --------------------------------------------------------------------------
# Each site's state is a record of SITE (a structured array over the sites) and a step's scratch one of SCRATCH:
# the compiled stages read and write them by field. What MuJoCo and the earthwork own stays in plain arrays,
# grouped in the named tuples below; the stages take those as plain tuples and name them again on entry
# (``t = Tool(*tool)``, free once compiled): numba types a plain tuple at each call in a fraction of the
# time a named one takes, and its cache index, which records the argument types by the class's name, could not be
# read at all once a class named there is renamed. A record array is one argument however many fields it has.
# columns of a site's stores (kg held; the earthwork's) and a step's flows (kg moved into them)
BUCKET, TRUCK, SPILLED = ew.BUCKET_STORE, ew.TRUCK_STORE, ew.SPILLED_STORE
BEFORE, NOW = range(2)  # rows of the shaping potentials: after the last step, after this one
_SHAPING = REWARD_TERMS.index(SHAPING_TERMS[0])  # the first shaping term's column
REACH, LOAD, LIFT, CARRY = range(len(SHAPING_TERMS))  # columns of the potentials
SITE = np.dtype([
    # the layout: the pile's centre (world m), direction (rad) and its cos, sin; the truck's centre, direction and
    # the cos, sin of its yaw (the bed's frame)
    ("pile_x", float), ("pile_y", float), ("pile_direction", float), ("pile_cos", float), ("pile_sin", float),
    ("truck_x", float), ("truck_y", float), ("truck_direction", float), ("truck_cos", float), ("truck_sin", float),
    # the pile: an upper bound of its surface (digging only lowers it), its fullest cut line (rad, kept while the
    # pile stands), its volume (m^3, summed again when stale); counted up by a change: cut line stale, volume
    # stale, revision (for a renderer's copy)
    ("pile_top", float), ("cut_direction", float), ("pile_volume", float),
    ("cut_line_stale", np.int64), ("volume_stale", np.int64), ("revision", np.int64),
    # the material: its density (kg/m^3); kg held in BUCKET, TRUCK, SPILLED; the payload the machine is massed with
    ("density", float), ("stores", float, 3), ("payload_kg", float),
    # the teeth: where last sampled (world m), their low-passed velocity (m/s), s since the sample (inf: none yet,
    # velocity 0); whether the edge cuts (the digging force on) and the last dig's depth (m)
    ("tip_before", float, 3), ("tip_velocity", float, 3), ("tip_interval", float), ("cutting", np.bool_),
    ("dig_depth", float),
    # the episode: the main joints' loads for the observation (N m), fuel (L), time (s), steps
    ("joint_loads", float, 4), ("fuel_l", float), ("elapsed", float), ("steps", np.int64),
])  # fmt: skip
SCRATCH = np.dtype([
    # the step's periods left; this interval's periods and seconds, whether clear of the pile, the teeth at its start
    ("left", np.int64), ("interval", np.int64), ("seconds", float), ("clear", np.bool_), ("tip_start", float, 3),
    # the step's flows (kg dug into the BUCKET, delivered to the TRUCK, SPILLED), fuel (L), contact impulse (N s)
    ("flows", float, 3), ("fuel_l", float), ("impulse", float),
    # the interval's digging force (N, world), whether to push it, whether the payload changed
    ("force", float, 3), ("push", np.bool_), ("change", np.bool_),
])  # fmt: skip


class Schedule(NamedTuple):
    """A step's control periods, the periods of a dig, the control period (s) and the teeth's velocity filter's
    blend over one period."""

    periods: int
    earthwork_periods: int
    period: float
    blend_one: float


class Rules(NamedTuple):
    """The reward terms' weights (``REWARD_TERMS`` order), the truck's capacity (kg) and the time limit (s)."""

    weights: np.ndarray
    truck_capacity_kg: float
    time_limit: float


class Curves(NamedTuple):
    """The machine's curves the task looks up: the boom, stick and bucket cylinders' moment arms (rows, over their
    joint angles from ``arm_start`` by ``arm_step``), the engine's fuel rate over its brake power and its power (W,
    the most brake power it gives)."""

    arms: np.ndarray
    arm_start: np.ndarray
    arm_step: np.ndarray
    fuel_rates: np.ndarray
    fuel_start: float
    fuel_step: float
    engine_power_w: float


class Piles(NamedTuple):
    """The sites' piles as the earthwork's functions take them: heights (N, n, n), m, the world (x, y) of each
    grid point [0, 0] (N, 2), the grid's spacing (m) and the area each point stands for (m^2)."""

    heights: np.ndarray
    origin: np.ndarray
    spacing: float
    cell_area: float


class Tool(NamedTuple):
    """Where the sites' buckets are (:class:`SitePhysics`' arrays): sites, bodies' positions and orientations,
    the teeth's site and the bucket's body."""

    site_xpos: np.ndarray
    xpos: np.ndarray
    xmat: np.ndarray
    tip_site: int
    bucket: int


class Joints(NamedTuple):
    """The sites' joints (:class:`SitePhysics`' arrays): positions, velocities and the main joints' addresses."""

    qpos: np.ndarray
    qvel: np.ndarray
    qadr: np.ndarray
    dadr: np.ndarray


class Contacts(NamedTuple):
    """The sites' tool-contact sensor: the sensor data, the sensor's first slot and how many contacts it reports."""

    sensordata: np.ndarray
    adr: int
    slots: int


class Readings(NamedTuple):
    """What the machines report at the end of an interval, per k of a call's sites: the main joints' loads
    (k, 4), N m, the swing's inertia times its last table acceleration (k,), N m, and the fuel they measured (k,),
    L (NaN: none)."""

    loads: np.ndarray
    swing_torques: np.ndarray
    measured_fuel: np.ndarray


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
def _sample_tip(site: np.void, tip: tuple, period: float, blend_one: float) -> tuple[float, float, float]:
    """The teeth's mean velocity since the ``site``'s last sample (m/s), also folded into the low-passed one."""
    interval = site.tip_interval
    before, velocity = site.tip_before, site.tip_velocity
    vx = (tip[0] - before[0]) / interval
    vy = (tip[1] - before[1]) / interval
    vz = (tip[2] - before[2]) / interval
    blend = blend_one if interval == period else 1.0 - math.exp(-interval / _FILTER)
    velocity[0] += (vx - velocity[0]) * blend
    velocity[1] += (vy - velocity[1]) * blend
    velocity[2] += (vz - velocity[2]) * blend
    before[0] = tip[0]
    before[1] = tip[1]
    before[2] = tip[2]
    return vx, vy, vz


@jit
def _spill(site: np.void, flows: np.ndarray, tilt: float, dt: float, tool: tuple, i: int) -> None:
    """Let what the bucket of ``site`` (site ``i`` of ``tool``) cannot hold at ``tilt`` run out over ``dt`` s,
    into the bed if its mouth is over it; the step's ``flows`` count it."""
    out = ew.spill_out(site.stores[BUCKET], tilt, dt, site.density)
    if out <= 0.0:
        return
    t = Tool(*tool)
    r = t.xmat[i, t.bucket]
    mx = t.xpos[i, t.bucket, 0] + r[0] * _MOUTH_X + r[2] * _MOUTH_Z
    my = t.xpos[i, t.bucket, 1] + r[3] * _MOUTH_X + r[5] * _MOUTH_Z
    along, across = _bed_frame(mx, my, site.truck_x, site.truck_y, site.truck_cos, site.truck_sin)
    site.stores[BUCKET] -= out
    if _over_bed(along, across):
        site.stores[TRUCK] += out
        flows[TRUCK] += out
    else:
        site.stores[SPILLED] += out
        flows[SPILLED] += out


@jit
def begin_step(ids: np.ndarray, schedule: tuple, scratch: np.ndarray) -> None:
    """Start a step of each site: all its :class:`Schedule` ``periods`` left, no flows, fuel or impulse yet."""
    s = Schedule(*schedule)
    for k in range(len(ids)):
        step = scratch[ids[k]]
        step.left = s.periods
        step.flows[BUCKET] = step.flows[TRUCK] = step.flows[SPILLED] = 0.0
        step.fuel_l = 0.0
        step.impulse = 0.0


@jit
def clear_count(i: int, periods: int, tool: tuple, piles: tuple, top: float) -> int:
    """Control periods (up to a step's ``periods``) within which site ``i``'s teeth surely stay out of its pile
    (``top``: an upper bound of its surface).

    The teeth travel at most ``PILE_MARGIN`` per step, ``m`` periods at most ``m / periods`` of it; the dig
    samples lie within half a bucket width of them. ``m`` periods are clear when no pile point within half a
    width plus that travel stands higher than the teeth less that travel.
    """
    t, pl = Tool(*tool), Piles(*piles)
    per_period = PILE_MARGIN / periods
    x, y, z = t.site_xpos[i, t.tip_site, 0], t.site_xpos[i, t.tip_site, 1], t.site_xpos[i, t.tip_site, 2]
    whole = periods * per_period
    # the usual case first: clear over the whole step is clear over each part (less travel, a smaller window)
    if ew.clearance(pl.heights, pl.origin, pl.spacing, top, i, x, y, z, _HALF_WIDTH + whole, whole) >= whole:
        return periods
    clear = 0
    while clear < periods:
        travel = (clear + 1) * per_period
        if ew.clearance(pl.heights, pl.origin, pl.spacing, top, i, x, y, z, _HALF_WIDTH + travel, travel) < travel:
            break
        clear += 1
    return clear


@jit
def plan(ids: np.ndarray, schedule: tuple, tool: tuple, piles: tuple, sites: np.ndarray, scratch: np.ndarray) -> int:
    """Each site's next interval: the periods it stays clear of the pile (:func:`clear_count`, none while its
    edge cuts), else ``earthwork_periods`` with a dig; at most the ``left`` of its step.

    Writes the sites' ``interval`` (periods), ``seconds``, ``clear`` and, for clear sites, the teeth's start.
    Returns 0 when all go clear for the same periods, 1 when all go clear, 2 when some dig.
    """
    s, t = Schedule(*schedule), Tool(*tool)
    code, first = 0, -1
    for k in range(len(ids)):
        i = ids[k]
        site, step = sites[i], scratch[i]
        n = 0 if site.cutting else min(clear_count(i, s.periods, tool, piles, site.pile_top), step.left)
        step.clear = n > 0
        if n > 0:
            for a in range(3):
                step.tip_start[a] = t.site_xpos[i, t.tip_site, a]
            if first < 0:
                first = n
            elif n != first and code == 0:
                code = 1
        else:
            n = min(s.earthwork_periods, step.left)
            code = 2
        step.interval = n
        step.seconds = n * s.period
    return code


@jit
def end_clear(ids: np.ndarray, tool: tuple, sites: np.ndarray, scratch: np.ndarray) -> bool:
    """Close an interval clear of the pile: the teeth's mean velocity over it, the spill at its end tilt (its
    exact exponential over the interval), the payload (:func:`payload_change`, into ``change``). Returns whether
    any changed."""
    t = Tool(*tool)
    any_change = False
    for k in range(len(ids)):
        i = ids[k]
        site, step = sites[i], scratch[i]
        tip, _, _, tilt = _bucket_pose(t.site_xpos, t.xmat, i, t.tip_site, t.bucket)
        for a in range(3):
            site.tip_velocity[a] = (tip[a] - step.tip_start[a]) / step.seconds
            site.tip_before[a] = step.tip_start[a]
        site.tip_interval = step.seconds
        _spill(site, step.flows, tilt, step.seconds, tool, i)
        step.change = payload_change(site)
        any_change |= step.change
    return any_change


@jit
def begin_dig(
    ids: np.ndarray, schedule: tuple, tool: tuple, piles: tuple, sites: np.ndarray, scratch: np.ndarray
) -> tuple[bool, bool, bool]:
    """Dig once for the next ``seconds`` per site: sample the teeth's motion (a backward difference since the last
    sample), fill and cut the pile (:func:`hexgym.envs.earthwork.dig`), or spill where the edge does not cut.

    Writes the digging ``force`` (N, world) and whether to ``push`` it (cutting now or before; a zero force
    clears the last); a site is ``cutting`` from now on where its depth is positive (its pile's cut line and
    volume then stale, its revision counted up). Returns whether any site pushes, any payload changed
    (``change``) and any site cuts.
    """
    s, t, pl = Schedule(*schedule), Tool(*tool), Piles(*piles)
    any_push, any_change, any_cut = False, False, False
    for k in range(len(ids)):
        i = ids[k]
        site, step = sites[i], scratch[i]
        tip, lateral, teeth, tilt = _bucket_pose(t.site_xpos, t.xmat, i, t.tip_site, t.bucket)
        vx, vy, vz = _sample_tip(site, tip, s.period, s.blend_one)
        velocity = site.tip_velocity
        fx, fy, fz, taken_kg, depth = ew.dig(
            pl.heights,
            pl.origin,
            pl.spacing,
            site.pile_top,
            i,
            site.stores[BUCKET],
            tip[0],
            tip[1],
            tip[2],
            lateral[0],
            lateral[1],
            lateral[2],
            teeth[0],
            teeth[1],
            teeth[2],
            vx,
            vy,
            vz,
            step.seconds,
            velocity[0],
            velocity[1],
            velocity[2],
            site.density,
        )
        site.dig_depth = depth
        site.stores[BUCKET] += taken_kg
        step.flows[BUCKET] += taken_kg
        if depth <= 0.0:
            _spill(site, step.flows, tilt, step.seconds, tool, i)
        else:
            site.cut_line_stale = 1
            site.volume_stale = 1
            site.revision += 1
            any_cut = True
        step.push = depth > 0.0 or site.cutting
        any_push |= step.push
        site.cutting = depth > 0.0
        step.force[0], step.force[1], step.force[2] = fx, fy, fz
        step.change = payload_change(site)
        any_change |= step.change
    return any_push, any_change, any_cut


@jit
def follow_resistance(ids: np.ndarray, schedule: tuple, tool: tuple, sites: np.ndarray, force: np.ndarray) -> None:
    """Re-aim the digging force (k, 3) of cutting sites with the teeth's motion (sampled now) at their last dig's
    depth."""
    s, t = Schedule(*schedule), Tool(*tool)
    for k in range(len(ids)):
        i = ids[k]
        site = sites[i]
        tip, lateral, teeth, _ = _bucket_pose(t.site_xpos, t.xmat, i, t.tip_site, t.bucket)
        _sample_tip(site, tip, s.period, s.blend_one)
        velocity = site.tip_velocity
        fx, fy, fz = ew.resistance(
            site.dig_depth,
            site.stores[BUCKET],
            lateral[0],
            lateral[1],
            lateral[2],
            teeth[0],
            teeth[1],
            teeth[2],
            velocity[0],
            velocity[1],
            velocity[2],
            site.density,
        )
        force[k, 0], force[k, 1], force[k, 2] = fx, fy, fz


@jit
def payload_change(site: np.void) -> bool:
    """Whether the ``site``'s bucket contents moved more than ``PAYLOAD_UPDATE_KG`` from its machine's payload, or
    emptied; if so the payload becomes them (and the caller re-masses the machine: ``mj_setConst`` is slow)."""
    bucket, payload = site.stores[BUCKET], site.payload_kg
    if abs(bucket - payload) > PAYLOAD_UPDATE_KG or (bucket < 1.0 and 1.0 < payload):
        site.payload_kg = bucket
        return True
    return False


@jit
def hard_contact_force(i: int, contacts: tuple) -> float:
    """Site ``i``'s bucket and stick contact force on the ground and the truck beyond ``HARD_CONTACT_FORCE``
    (capped at the machine's weight), N; -1 when it has more contacts than the sensor's (:class:`Contacts`) slots.

    From the contact sensor's depths (``CONTACT_STIFFNESS``): the machine's contacts are detected but
    inactive, the learned model stalls a joint that drives into one.
    """
    sensordata, adr, slots = Contacts(*contacts)
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
    ids: np.ndarray,
    curves: tuple,
    joints: tuple,
    contacts: tuple,
    readings: tuple,
    sites: np.ndarray,
    scratch: np.ndarray,
    going: np.ndarray,
) -> int:
    """Close each site's interval of ``seconds``: fuel (the machine's own measure, :class:`Readings`'
    ``measured_fuel``, where it has one; else the actuators' power at the interval's end through the engine's
    BSFC, :mod:`hexgym.hydraulics.fuel`), hard-contact impulse, the joint loads kept for the observation, and the
    periods ``left`` of the step. Returns how many sites have periods left (their ids first in ``going``, which
    may be ``ids`` itself), or -1 - i for a site i with too many contacts."""
    c, jt, r = Curves(*curves), Joints(*joints), Readings(*readings)
    count = 0
    for k in range(len(ids)):
        i = ids[k]
        site, step = sites[i], scratch[i]
        power = 0.0
        for j in range(1, 4):  # the front's joints, in order, then the swing
            power += abs(r.loads[k, j] * jt.qvel[i, jt.dadr[j]])
            site.joint_loads[j] = r.loads[k, j]
        site.joint_loads[0] = r.loads[k, 0]
        power += abs(r.swing_torques[k] * jt.qvel[i, jt.dadr[0]])
        measured = r.measured_fuel[k]
        if measured == measured:  # not NaN: the machine's own
            step.fuel_l += measured
        else:
            brake = min(_brake_power(power), c.engine_power_w)
            step.fuel_l += ew.table_at(c.fuel_rates, c.fuel_start, c.fuel_step, brake) * step.seconds / 3600.0
        force = hard_contact_force(i, contacts)
        if force < 0.0:
            return -1 - i
        step.impulse += force * step.seconds
        step.left -= step.interval
        if step.left > 0:
            going[count] = i
            count += 1
    return count


@jit
def potentials(ids: np.ndarray, tool: tuple, piles: tuple, sites: np.ndarray, out: np.ndarray) -> None:
    """The shaping potentials of each site into ``out[i]`` (n, 4), in ``SHAPING_TERMS`` order, from where its
    teeth are and what its bucket holds (t):

    - reach: an empty bucket's teeth, minus their horizontal distance (m) beyond ``SHAPING_PILE_REACHED_M``
      from the pile's centre and minus their height above the pile's surface (0 while loaded): down onto it;
    - load: the tonnes in the bucket;
    - lift: the tonnes times the teeth's height above the pile's surface, up to ``SHAPING_LIFT_M``, over it;
    - carry: the tonnes times how much of the way from the pile's centre to the bed's the teeth have come
      horizontally (1 over the bed's centre, 0 at the pile's distance from it or farther).
    """
    t, pl = Tool(*tool), Piles(*piles)
    for k in range(len(ids)):
        i = ids[k]
        site = sites[i]
        x, y, z = t.site_xpos[i, t.tip_site, 0], t.site_xpos[i, t.tip_site, 1], t.site_xpos[i, t.tip_site, 2]
        tonnes = site.stores[BUCKET] / 1000.0
        to_pile = math.hypot(x - site.pile_x, y - site.pile_y)
        above = z - ew.height_at(pl.heights, pl.origin, pl.spacing, i, x, y)
        empty = site.stores[BUCKET] < SHAPING_EMPTY_KG
        out[i, REACH] = -max(to_pile - SHAPING_PILE_REACHED_M, 0.0) - max(above, 0.0) if empty else 0.0
        out[i, LOAD] = tonnes
        out[i, LIFT] = tonnes * min(max(above, 0.0), SHAPING_LIFT_M) / SHAPING_LIFT_M
        span = math.hypot(site.truck_x - site.pile_x, site.truck_y - site.pile_y)
        out[i, CARRY] = tonnes * (1.0 - min(math.hypot(x - site.truck_x, y - site.truck_y) / span, 1.0))


@jit
def finish(
    ids: np.ndarray,
    rules: tuple,
    sites: np.ndarray,
    scratch: np.ndarray,
    potential: np.ndarray,
    terms: np.ndarray,
    rewards: np.ndarray,
    ended: np.ndarray,
) -> None:
    """End the step of each site: fuel and time, the reward terms (k, 10: ``REWARD_TERMS``, weighted; their sum
    in order is the reward; the shaping terms the change of the :func:`potentials` (2, n, 4) from ``BEFORE`` to
    ``NOW``, which then becomes ``BEFORE``) and whether it terminated (the truck holds its capacity) or truncated
    (time), (k, 2)."""
    rule = Rules(*rules)
    weights = rule.weights
    for k in range(len(ids)):
        i = ids[k]
        site, step = sites[i], scratch[i]
        site.fuel_l += step.fuel_l
        site.steps += 1
        site.elapsed = site.steps * STEP_PERIOD
        terms[k, _DELIVERY] = weights[_DELIVERY] * step.flows[TRUCK] / 1000.0
        terms[k, _FILL] = weights[_FILL] * step.flows[BUCKET] / 1000.0
        terms[k, _TIME] = -weights[_TIME] * STEP_PERIOD
        terms[k, _FUEL] = -weights[_FUEL] * step.fuel_l
        terms[k, _SPILL] = -weights[_SPILL] * step.flows[SPILLED] / 1000.0
        terms[k, _CONTACT] = -weights[_CONTACT] * step.impulse / 1000.0
        for j in range(len(SHAPING_TERMS)):
            terms[k, _SHAPING + j] = weights[_SHAPING + j] * (potential[NOW, i, j] - potential[BEFORE, i, j])
            potential[BEFORE, i, j] = potential[NOW, i, j]
        total = terms[k, 0]
        for j in range(1, len(REWARD_TERMS)):
            total += terms[k, j]
        rewards[k] = total
        ended[k, 0] = site.stores[TRUCK] >= rule.truck_capacity_kg
        ended[k, 1] = site.elapsed >= rule.time_limit - 1e-9


@jit
def observe(
    ids: np.ndarray,
    rules: tuple,
    curves: tuple,
    tool: tuple,
    joints: tuple,
    piles: tuple,
    sites: np.ndarray,
    out: np.ndarray,
) -> int:
    """Write the observation of each site (see :class:`hexgym.envs.loading.HexLoadingEnv`) into ``out`` (k, 23,
    float32), clipped to its bounds (as float64, then rounded); returns the first site whose observation is not
    finite (-1: none)."""
    rule, c, t, jt, pl = Rules(*rules), Curves(*curves), Tool(*tool), Joints(*joints), Piles(*piles)
    values = np.empty(OBSERVATION_SIZE)
    for k in range(len(ids)):
        i = ids[k]
        site = sites[i]
        tip, _, _, tilt = _bucket_pose(t.site_xpos, t.xmat, i, t.tip_site, t.bucket)
        swing = jt.qpos[i, jt.qadr[0]]
        for j in range(3):
            values[j] = jt.qpos[i, jt.qadr[j + 1]]
            arm = ew.table_at(c.arms[j], c.arm_start[j], c.arm_step[j], values[j])
            values[9 + j] = site.joint_loads[j + 1] / arm / 1e6  # MN
        for j in range(4):
            values[5 + j] = jt.qvel[i, jt.dadr[j]]
        values[3] = wrap(swing - site.pile_direction)
        values[4] = wrap(swing - site.truck_direction)
        values[12] = site.stores[BUCKET] / 1000.0
        rel_x, rel_y = tip[0] - site.pile_x, tip[1] - site.pile_y
        cos, sin = site.pile_cos, site.pile_sin
        values[13] = cos * rel_x + sin * rel_y
        values[14] = -sin * rel_x + cos * rel_y
        values[15] = tip[2] - ew.height_at(pl.heights, pl.origin, pl.spacing, i, tip[0], tip[1])
        values[16], values[17] = _bed_frame(tip[0], tip[1], site.truck_x, site.truck_y, site.truck_cos, site.truck_sin)
        values[18] = tip[2] - _RIM
        values[19] = tilt
        values[20] = site.stores[TRUCK] / rule.truck_capacity_kg
        values[21] = max(1.0 - site.elapsed / rule.time_limit, 0.0)
        values[22] = wrap(swing - site.cut_direction)
        for j in range(OBSERVATION_SIZE):
            if not math.isfinite(values[j]):
                return i
            out[k, j] = min(max(values[j], _CLIP_LOW[j]), _CLIP_HIGH[j])
    return -1


@jit
def any_cut_line_stale(ids: np.ndarray, sites: np.ndarray) -> bool:
    """Whether any site's pile changed since its fullest cut line was found."""
    for k in range(len(ids)):
        if sites[ids[k]].cut_line_stale:
            return True
    return False


@jit
def info_stores(ids: np.ndarray, piles: tuple, sites: np.ndarray, out: np.ndarray) -> None:
    """``INFO_STORES`` of each site into ``out`` (k, 6): pile, bucket, truck, spilled (kg), fuel (L), time (s); a
    pile's volume is summed again only when stale."""
    pl = Piles(*piles)
    for k in range(len(ids)):
        i = ids[k]
        site = sites[i]
        if site.volume_stale:
            site.pile_volume = pl.heights[i].sum() * pl.cell_area
            site.volume_stale = 0
        out[k, 0] = site.pile_volume * site.density
        out[k, 1], out[k, 2], out[k, 3] = site.stores[BUCKET], site.stores[TRUCK], site.stores[SPILLED]
        out[k, 4], out[k, 5] = site.fuel_l, site.elapsed


def _site_field(name: str, doc: str) -> property:
    """A read-only attribute: the view of field ``name`` of every site's record (``LoadingTask.sites``)."""
    return property(lambda self: self.sites[name], doc=doc)


# -- the task ---------------------------------------------------------------------------------------
class LoadingTask:
    """The loading task's state for ``count`` sites and its step (see the module docstring).

    Args:
        count: number of sites.
        physics: the sites' machines (:class:`SitePhysics`; a whole number of their control periods make a step).
        time_limit, truck_capacity_kg, weights, earthwork_periods: as :class:`hexgym.envs.loading.LoadingConfig`'s.
        material_density: the pile's material, kg/m^3 (a heavier material: the same bucket holds more kilograms and
            digs harder).
        engine_power_w: the engine's power, W: the most brake power the fuel estimate counts.
    """

    def __init__(
        self,
        count: int,
        physics: SitePhysics,
        time_limit: float,
        truck_capacity_kg: float,
        weights: dict[str, float],
        earthwork_periods: int = EARTHWORK_PERIODS,
        material_density: float = p.MATERIAL_DENSITY,
        engine_power_w: float = p.ENGINE_POWER,
    ) -> None:
        period = float(physics.control_period)
        self.material_density = float(material_density)
        self.count, self.physics, self.period = int(count), physics, period
        self.periods = int(round(STEP_PERIOD / period))
        if abs(self.periods * period - STEP_PERIOD) > 1e-9:
            raise ValueError(f"the machine's control period {period} s does not divide the step {STEP_PERIOD} s")
        self.time_limit, self.truck_capacity_kg = float(time_limit), float(truck_capacity_kg)
        self.weights, self.earthwork_periods = weights, int(earthwork_periods)
        n = self.count
        self.heights = np.zeros((n, PILE_GRID_POINTS, PILE_GRID_POINTS))
        self.origin = np.zeros((n, 2))  # world (x, y) of each pile's grid point [0, 0]
        self.spacing = PILE_GRID_SPACING
        self.layouts: list[Layout | None] = [None] * n
        self.sites = np.zeros(n, SITE)  # each site's state (see SITE)
        self.sites["tip_interval"] = math.inf
        self._scratch = np.zeros(n, SCRATCH)  # a step's, per site (see SCRATCH)
        # per k of a call's sites (written before read): the machines' readings; the sites with periods left after
        # an interval
        self._readings = tuple(Readings(loads=np.zeros((n, 4)), swing_torques=np.zeros(n), measured_fuel=np.zeros(n)))
        self._going = np.zeros(n, np.int64)
        # shaping potentials after the last step and now (zeros, never computed, while every shaping weight is 0)
        self._shaping = any(float(weights[term]) != 0.0 for term in SHAPING_TERMS)
        self._potential = np.zeros((2, n, len(SHAPING_TERMS)))
        tables, rates = kinematics.moment_arm_tables(), fuel._fuel_rate_table()
        # what the compiled stages take (see Schedule, Rules, Curves, Piles)
        self._schedule = tuple(
            Schedule(
                periods=self.periods,
                earthwork_periods=self.earthwork_periods,
                period=self.period,
                blend_one=1.0 - math.exp(-self.period / p.DIG_VELOCITY_FILTER),
            )
        )
        self._rules = tuple(
            Rules(
                weights=np.array([float(weights[term]) for term in REWARD_TERMS]),
                truck_capacity_kg=self.truck_capacity_kg,
                time_limit=self.time_limit,
            )
        )
        self._curves = tuple(
            Curves(
                arms=np.array([t.values for t in tables]),
                arm_start=np.array([t.start for t in tables]),
                arm_step=np.array([t.step for t in tables]),
                fuel_rates=np.array(rates.values),
                fuel_start=rates.start,
                fuel_step=rates.step,
                engine_power_w=float(engine_power_w),
            )
        )
        self._piles = tuple(Piles(self.heights, self.origin, self.spacing, self.spacing**2))
        self.contact_slots = CONTACT_SLOTS
        self._machines_read: tuple[tuple, tuple, tuple] | None = None

    def _machines(self) -> tuple[tuple, tuple, tuple]:
        """The sites' machines as the compiled stages take them: a :class:`Tool`, :class:`Joints` and
        :class:`Contacts`, made again only when the physics rebinds its arrays (an unpickled
        :class:`hexgym.envs.sites.MachineSites`); it refreshes them in place."""
        ph = self.physics
        if self._machines_read is None or self._machines_read[0][0] is not ph.site_xpos:
            tool = Tool(site_xpos=ph.site_xpos, xpos=ph.xpos, xmat=ph.xmat, tip_site=ph.tip_site, bucket=ph.bucket_body)
            joints = Joints(qpos=ph.qpos, qvel=ph.qvel, qadr=ph.qadr, dadr=ph.dadr)
            contacts = Contacts(sensordata=ph.sensordata, adr=ph.contact_adr, slots=self.contact_slots)
            self._machines_read = tuple(tool), tuple(joints), tuple(contacts)
        return self._machines_read

    # -- the state by name: views of a field of every site's record ----------------------------------
    stores = _site_field("stores", "The material each site holds (N, 3), kg: ``BUCKET``, ``TRUCK``, ``SPILLED``.")
    fuel_l = _site_field("fuel_l", "Diesel each site burnt this episode, L.")
    elapsed = _site_field("elapsed", "Simulated seconds of each site's episode.")
    steps = _site_field("steps", "Steps of each site's episode.")
    cut_dir = _site_field("cut_direction", "Each pile's fullest cut line (rad), as last found (update_cut_directions).")
    revision = _site_field("revision", "Counts each pile's changes (for a renderer's copy of it).")

    # -- episodes ---------------------------------------------------------------------------------
    def start(self, ids: np.ndarray, starts: Sequence[SiteStart]) -> None:
        """Begin an episode at each site ``ids[k]`` from ``starts[k]``: its machine started by the physics, its pile
        heaped on the layout (:func:`hexgym.envs.world.heap_for`), its bucket holding the start's payload."""
        self.physics.start(ids, starts)
        for i, start in zip(ids.tolist(), starts, strict=True):
            self._begin(i, start.layout, heap_for(start.layout), float(start.payload_kg))
        ph = self.physics
        loads, swing_torques, measured_fuel = self._readings
        self.sites["tip_before"][ids] = ph.site_xpos[ids, ph.tip_site]
        ph.loads(ids, loads, swing_torques)
        ph.measured_fuel(ids, measured_fuel)  # what a start burnt is no part of the episode
        self.sites["joint_loads"][ids] = loads[: len(ids)]
        if self._shaping:
            potentials(ids, self._machines()[0], self._piles, self.sites, self._potential[BEFORE])

    def _begin(self, i: int, layout: Layout, pile: ew.Pile, payload_kg: float) -> None:
        """Site ``i``'s record at the start of an episode on ``layout`` with ``pile`` (copied), its bucket holding
        ``payload_kg``."""
        self.layouts[i] = layout
        self.heights[i] = pile.heights
        self.origin[i] = pile.origin
        site = self.sites[i : i + 1]  # a view of the record
        site["pile_top"] = pile.top
        site["cut_line_stale"] = site["volume_stale"] = 1
        (site["pile_x"], site["pile_y"]), (site["truck_x"], site["truck_y"]) = layout.pile_centre, layout.truck_centre
        site["pile_direction"], site["truck_direction"] = layout.pile_direction, layout.truck_direction
        site["pile_cos"], site["pile_sin"] = math.cos(layout.pile_direction), math.sin(layout.pile_direction)
        site["truck_cos"], site["truck_sin"] = math.cos(layout.truck_yaw), math.sin(layout.truck_yaw)
        site["density"] = self.material_density
        site["stores"] = 0.0
        site["stores"][:, BUCKET] = site["payload_kg"] = payload_kg
        site["tip_interval"] = math.inf
        site["tip_velocity"] = 0.0
        site["cutting"] = False
        site["dig_depth"] = site["fuel_l"] = site["elapsed"] = 0.0
        site["steps"] = 0

    def potentials_of(self, ids: np.ndarray) -> np.ndarray:
        """:func:`potentials` of sites ``ids`` now (k, 4), in ``SHAPING_TERMS`` order."""
        out = np.zeros((self.count, len(SHAPING_TERMS)))
        potentials(ids, self._machines()[0], self._piles, self.sites, out)
        return out[ids]

    def pile(self, i: int) -> ew.Pile:
        """A handle on site ``i``'s pile (its heights are the task's; a cut through it flags the pile changed)."""
        flags = (self.sites["cut_line_stale"], self.sites["volume_stale"], self.sites["revision"])
        pile = ew.Pile(None, None, self.spacing, self.heights, self.origin, i, flags)
        pile.top = float(self.sites["pile_top"][i])
        return pile

    def earthwork(self, i: int) -> ew.Earthwork:
        """Site ``i``'s material stores: its :meth:`pile` and a view of its bucket, truck and spilled kilograms
        (setting them sets the task's)."""
        return ew.Earthwork(self.pile(i), self.stores[i], self.material_density)

    # -- a step -----------------------------------------------------------------------------------
    def step(self, ids: np.ndarray, spools_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Hold the spools ``spools_m`` (k, 4), m, at sites ``ids`` for a step (the action, through the physics'
        :meth:`SitePhysics.hold`) and advance them.

        Returns their reward terms (k, 10), rewards (k,) and terminated, truncated (k, 2); the step's fuel
        (L) and hard-contact impulse (N s) stay in ``step_fuel_l`` and ``step_impulse``.
        """
        k = len(ids)
        self.physics.hold(ids, spools_m)
        machines = self._machines()
        begin_step(ids, self._schedule, self._scratch)
        self._advance(ids, machines)
        if self._shaping:
            potentials(ids, machines[0], self._piles, self.sites, self._potential[NOW])
        terms, rewards, ended = np.empty((k, len(REWARD_TERMS))), np.empty(k), np.empty((k, 2), np.bool_)
        finish(ids, self._rules, self.sites, self._scratch, self._potential, terms, rewards, ended)
        return terms, rewards, ended

    @property
    def step_fuel_l(self) -> np.ndarray:
        """Each site's fuel in its last step, L."""
        return self._scratch["fuel_l"]

    @property
    def step_impulse(self) -> np.ndarray:
        """Each site's hard-contact impulse in its last step, N s."""
        return self._scratch["impulse"]

    def _advance(self, ids: np.ndarray, machines: tuple) -> None:
        """Rounds of clear or digging intervals until each site has advanced its step's periods."""
        ph, scratch = self.physics, self._scratch
        while True:
            code = plan(ids, self._schedule, machines[0], self._piles, self.sites, scratch)
            if code == 0:  # the usual case: all clear of the pile, for the same periods
                ph.step(ids, int(scratch["interval"][ids[0]]))
                self._end_clear(ids, machines)
            elif code == 1:
                self._step_grouped(ids)
                self._end_clear(ids, machines)
            else:
                clear = scratch["clear"][ids]
                self._dig(ids[~clear], machines)
                if clear.any():
                    self._step_grouped(ids[clear])
                    self._end_clear(ids[clear], machines)
            ids = self._account(ids, machines)
            if not len(ids):
                return

    def _step_grouped(self, ids: np.ndarray) -> None:
        """Advance each site by its interval's periods: one physics call per distinct count."""
        periods = self._scratch["interval"][ids]
        for count in sorted(set(periods.tolist())):
            self.physics.step(ids[periods == count], count)

    def _end_clear(self, ids: np.ndarray, machines: tuple) -> None:
        """After an interval clear of the pile (:func:`end_clear`): no digging force acted; re-mass the bucket."""
        if end_clear(ids, machines[0], self.sites, self._scratch):
            changed = ids[self._scratch["change"][ids]]
            self.physics.set_payload(changed, self.sites["payload_kg"][changed])

    def _dig(self, ids: np.ndarray, machines: tuple) -> None:
        """One dig (:func:`begin_dig`), then the interval's periods: cutting sites period by period, re-aiming their
        digging force between them (:func:`follow_resistance`)."""
        ph, sites, scratch = self.physics, self.sites, self._scratch
        any_push, any_change, any_cut = begin_dig(ids, self._schedule, machines[0], self._piles, sites, scratch)
        if any_push:
            pushed = ids[scratch["push"][ids]]
            ph.apply_tip_force(pushed, scratch["force"][pushed])
        if any_change:
            changed = ids[scratch["change"][ids]]
            ph.set_payload(changed, sites["payload_kg"][changed])
        cutting = sites["cutting"][ids] if any_cut else np.zeros(len(ids), np.bool_)
        tip_interval = sites["tip_interval"]
        if not any_cut or not cutting.all():
            still = ids[~cutting]
            self._step_grouped(still)
            tip_interval[still] = scratch["seconds"][still]
        if any_cut:
            cut_ids = ids[cutting]
            cut_periods = scratch["interval"][cut_ids]
            for start in range(int(cut_periods.max())):
                now = cut_ids[cut_periods > start] if start else cut_ids
                if start:
                    force = np.empty((len(now), 3))
                    follow_resistance(now, self._schedule, machines[0], sites, force)
                    ph.apply_tip_force(now, force)
                ph.step(now, 1)
                tip_interval[now] = self.period

    def _account(self, ids: np.ndarray, machines: tuple) -> np.ndarray:
        """Fuel, hard-contact impulse and joint loads at the end of the sites' intervals (:func:`account`); returns
        the sites with periods left."""
        ph = self.physics
        loads, swing_torques, measured_fuel = self._readings
        ph.loads(ids, loads, swing_torques)
        ph.measured_fuel(ids, measured_fuel)
        _, joints, contacts = machines
        going = account(ids, self._curves, joints, contacts, self._readings, self.sites, self._scratch, self._going)
        if going < 0:
            raise RuntimeError(f"more than {self.contact_slots} bucket/stick contacts at environment {-1 - going}")
        return self._going[:going]

    # -- observation and info ---------------------------------------------------------------------
    def observe(self, ids: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """The observations of sites ``ids`` (k, 23), float32 (written into ``out`` when given)."""
        self.update_cut_directions(ids)
        if out is None:
            out = np.empty((len(ids), OBSERVATION_SIZE), np.float32)
        tool, joints, _ = self._machines()
        bad = observe(ids, self._rules, self._curves, tool, joints, self._piles, self.sites, out)
        if bad >= 0:
            raise RuntimeError(
                f"the simulation diverged (non-finite observation) at environment {bad}, t = {self.elapsed[bad]:.1f} s"
            )
        return out

    def update_cut_directions(self, ids: np.ndarray) -> None:
        """Find the fullest cut line (:func:`hexgym.envs.world.fullest_cut_direction`) of the piles ``ids`` that
        changed since it was last found."""
        if not any_cut_line_stale(ids, self.sites):
            return
        stale = self.sites["cut_line_stale"]
        for i in ids[stale[ids] > 0].tolist():
            self.sites["cut_direction"][i] = fullest_cut_direction(self._height_function(i), self.layouts[i])
            stale[i] = 0

    def _height_function(self, i: int) -> Callable[[np.ndarray], np.ndarray]:
        heights, origin, spacing = self.heights, self.origin, self.spacing

        def height(xy: np.ndarray) -> np.ndarray:
            flat = np.ascontiguousarray(xy.reshape(-1, 2), dtype=float)
            return ew.heights_at(heights, origin, spacing, i, flat).reshape(xy.shape[:-1])

        return height

    def stores_of(self, ids: np.ndarray) -> np.ndarray:
        """``INFO_STORES`` of sites ``ids`` (k, 6): pile, bucket, truck, spilled (kg), fuel (L), time (s)."""
        out = np.empty((len(ids), len(INFO_STORES)))
        info_stores(ids, self._piles, self.sites, out)
        return out

    def pile_kg(self) -> np.ndarray:
        """Material in each pile, kg."""
        return self.stores_of(np.arange(self.count))[:, 0]

    def clear_periods_of(self, ids: np.ndarray) -> np.ndarray:
        """:func:`clear_count` of sites ``ids`` (0 where the edge cuts)."""
        tool, sites = self._machines()[0], self.sites
        return np.array(
            [
                0 if sites["cutting"][i] else clear_count(i, self.periods, tool, self._piles, sites["pile_top"][i])
                for i in ids.tolist()
            ]
        )

    def hard_contact_forces(self, ids: np.ndarray) -> np.ndarray:
        """:func:`hard_contact_force` of sites ``ids``, N."""
        contacts = self._machines()[2]
        force = np.array([hard_contact_force(i, contacts) for i in ids.tolist()])
        if (force < 0).any():
            raise RuntimeError(f"more than {self.contact_slots} bucket/stick contacts at environment {ids[force < 0]}")
        return force

"""Training data for the MBL tables: the reference model driven through motion sequences.

The paper (Sec III, "Data Collection") drove its slow analytical model through motion sequences
that cover each table's input space: the spools over ±11 mm at 1 mm resolution in combinations
(boom with bucket, swing with stick), slowly, with an empty, half-full and full bucket, the
cylinder forces following from the machine's configuration. This module does the same on
:class:`hexgym.hydraulics.reference.ReferenceModel`, and also applies digging-like tip forces so that the
learned model does not extrapolate when the environment digs.

The paper's tables (inputs -> output, SI units; spools in m, + extends / turns counter-clockwise;
every set's in :mod:`hexgym.mbl.schema`):

======  =====================================================================  ===========================
table   inputs                                                                 output
======  =====================================================================  ===========================
boom    boom spool, bucket spool, boom force, bucket force                     boom cylinder velocity m/s
bucket  boom spool, bucket spool, boom force, bucket force                     bucket cylinder velocity m/s
stick   swing spool, stick spool, swing inertia, stick force                   stick cylinder velocity m/s
swing   swing spool, stick spool, stick force, swing inertia, swing rate       swing acceleration rad/s^2
======  =====================================================================  ===========================

Forces are the circuit's (``P_head A_head - P_rod A_rod - friction``, + pushes the cylinder out).

Episodes. Two groups of episodes: ``boom_bucket`` moves the boom and bucket spools (stick and
swing at 0), ``stick_swing`` the swing and stick spools (boom and bucket at 0). An episode starts
at rest at a random pose (swing anywhere; each cylinder uniform over its stroke, ``start_margin_m``
away from the ends), with a payload of 0, 1000 or 2000 kg (in turn) and a constant tip force in
the arm plane (none in a third of the episodes; otherwise up to 80 kN, its direction mostly in
the upper half-plane: resistance to a bucket moving down into material, towards or away from the
machine; the start pressures hold it). It then runs ``segments_per_episode`` segments: spools
drawn on the 1 mm grid and held for 1.4-1.7 s. A spool that would run its cylinder into a
stroke end within the segment (at a generous nominal speed) is reversed. A segment that does run
a cylinder within ``margin_m`` of a stroke end (the cushions act over the last 40 mm, and then
the stop, not the valve, sets the speed) is cut short, and the episode ends: the next starts at
a fresh pose.

Samples. Each segment ends in two back-to-back 0.5 s windows; each gives one sample for the
segment tables (boom, bucket, stick): the inputs and the velocity averaged over the window
(velocity = change of extension / time). The windows are 0.5 s, not shorter, because the boom,
stick and bucket ride on the oil's compliance as lightly damped ~2 Hz spring-mass modes (period
0.45-0.6 s, with spool steps and ramps alike, unchanged at 0.5 ms steps): a 0.5 s mean cancels
most of the swing of the velocity, a 0.2 s one does not (measured: rms change between successive
windows 0.003-0.008 m/s with 0.5 s, 0.02-0.04 m/s with 0.2 s). The valve transient itself is
over within ~0.4 s, so a window from 0.4-0.7 s after the spool step is as good as a later one,
and two windows per segment halve the cost of the transients.
The swing table is dynamic (its output is the acceleration), so it is sampled along the
trajectory: every ``swing_interval_s`` from ``swing_settle_s`` after each spool change, the
acceleration a central difference of the swing rate over ~0.05 s, the inputs at that instant.
Its spool is kept over several segments with probability ``swing_persistence``, so the swing
reaches full speed (about 3 s at full spool) and brakes (spool reversed or zero while turning:
the crossover reliefs brake it).

Operator-like logs (group ``operator``: the ``circuit`` set's valve passages). The valve's areas are
identified from the pressures, pump flows and velocities along the motion, so every spool position
must be passed, ramps included. These episodes replay one seeded sweep log each
(:mod:`hexgym_lab.mbl.operator_logs`: partial levels from the dead band up, slow ramps, one to three
functions, payloads 0-2 t) and take a row every ``operator_interval_s`` along the motion; the group
collects ``operator_sample_factor`` times the samples of the others (rows of one log are correlated).

Reproducibility and resumption. Each episode has its own random generator, seeded by
``SeedSequence(seed, spawn_key=(group, episode))``; episodes are computed in chunks of
``episodes_per_chunk``, each written atomically to ``<out>/chunks/<group>_<index>.npz``. A
restart skips finished chunks, and the data set is the first episodes (in index order) that
reach ``samples_per_group`` segment samples, so it does not depend on the number of workers or
on interruptions. Workers are ``multiprocessing`` processes (spawn context: MuJoCo and OpenGL do
not like a fork after they initialise).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hexgym.files import atomic_path, check_output_dir, staged_dir
from hexgym.hydraulics.circuit import DEFAULT_VALVE, HydraulicCircuit
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.mbl.schema import DEFAULT_TABLE_SET, TABLE_SETS, VALVE_OF_TABLE_SET
from hexgym.mbl.valve import identify_areas
from hexgym.parallel import Executor, executor
from hexgym_lab.mbl.datafile import refuse_other_npz
from hexgym_lab.mbl.operator_logs import DT as OPERATOR_DT
from hexgym_lab.mbl.operator_logs import DURATION_S as OPERATOR_DURATION_S
from hexgym_lab.mbl.operator_logs import operator_log
from hexgym_lab.progress import Progress

GENERATOR_VERSION = 2  # 2: the operator group's rows run to the end of each log
DEFAULT_SAMPLES = 6400  # per group: the paper had 5500 (boom/bucket) and 6400 (stick/swing) points

_SPOOL = {name: i for i, name in enumerate(kinematics.JOINTS)}  # spool vector order
_CYL = {name: i for i, name in enumerate(kinematics.FRONT_CYLINDERS)}
_STROKE = np.array([p.CYLINDERS[n].stroke for n in kinematics.FRONT_CYLINDERS])
# Nominal full-spool cylinder speeds with generous factors (a lowered load runs faster than the
# pump's flow over the rod area), only to reverse spools that would run into a stroke end.
_SPEED_OUT = np.array([2.0 * p.PUMP_MAX_FLOW / p.CYLINDERS[n].head_area for n in kinematics.FRONT_CYLINDERS])
_SPEED_IN = np.array([1.6 * p.PUMP_MAX_FLOW / p.CYLINDERS[n].rod_area for n in kinematics.FRONT_CYLINDERS])


# group -> the functions whose spools its episodes move (its tables: CollectConfig.tables)
GROUPS: dict[str, tuple[str, ...]] = {
    "boom_bucket": ("boom", "bucket"),
    "stick_swing": ("swing", "stick"),
    "operator": kinematics.JOINTS,  # operator-like logs: any function, ramps, long swings
}
_GROUP_ID = {"boom_bucket": 0, "stick_swing": 1, "operator": 2}


@dataclass(frozen=True)
class CollectConfig:
    """How episodes are built and sampled (defaults: the production data set; see the module docs)."""

    segments_per_episode: int = 12
    episodes_per_chunk: int = 4
    hold_s: tuple[float, float] = (1.4, 1.7)  # spool hold per segment, uniform
    window_s: float = 0.5  # averaging window (about one period of the boom's oil-spring mode)
    windows_per_segment: int = 2  # back-to-back windows ending the segment, one sample each
    margin_m: float = 0.05  # reject within this of a stroke end (cushions: last 40 mm)
    start_margin_m: float = 0.15  # start poses this far from the stroke ends
    payloads_kg: tuple[float, ...] = p.PAYLOAD_EMPTY_HALF_FULL
    tip_force_max_n: float = 80e3
    tip_force_zero_fraction: float = 1.0 / 3.0
    tip_force_upward_fraction: float = 0.8  # directions in the upper half-plane; the rest anywhere
    zero_spool_probability: float = 0.15  # a spool exactly at neutral (single-function motions)
    swing_persistence: float = 0.65  # probability the swing spool is kept into the next segment
    swing_interval_s: float = 0.1
    swing_settle_s: float = 0.1  # no swing samples this soon after a spool change
    swing_half_width_s: float = 0.024  # central difference over twice this
    record_every: int = 10  # steps between force records in the window and limit checks
    table_set: str = DEFAULT_TABLE_SET  # which tables' data sets to write (hexgym.mbl.schema.TABLE_SETS)
    operator_interval_s: float = 0.2  # operator group: one row this often along each log
    operator_duration_s: float | None = None  # operator group: each log this long (None: 30-60 s)
    operator_sample_factor: int = 2  # operator group: this many times the samples per group

    def groups(self) -> tuple[str, ...]:
        """The collection groups the table set's tables learn from, in ``GROUPS`` order."""
        used = {spec.group for spec in TABLE_SETS[self.table_set].values()}
        return tuple(g for g in GROUPS if g in used)

    def target(self, group: str, samples_per_group: int) -> int:
        """Samples ``group``'s first table needs: operator rows are many per episode but correlated."""
        return samples_per_group * (self.operator_sample_factor if group == "operator" else 1)

    def tables(self, group: str) -> tuple[str, ...]:
        """The tables whose samples ``group``'s episodes give, the first the one counted."""
        return tuple(name for name, spec in TABLE_SETS[self.table_set].items() if spec.group == group)

    def window_s_steps(self, dt: float) -> int:
        """The averaging window in model steps of ``dt``."""
        return max(1, round(self.window_s / dt))

    def to_json(self) -> str:
        """The configuration as canonical JSON (stored with chunks and data sets)."""
        return json.dumps(asdict(self), sort_keys=True)


# --------------------------------------------------------------------------------------------
# One segment on the reference model.
@dataclass
class WindowMean:
    """Means over one averaging window of a segment."""

    velocity: np.ndarray  # (3,) cylinder velocities (change of extension / time), m/s
    force: np.ndarray  # (3,) cylinder forces, N
    inertia: float  # swing inertia, kg m^2


@dataclass
class SegmentResult:
    """What one held-spool segment produced."""

    spools: np.ndarray  # m, order swing, boom, stick, bucket
    limited: bool = False  # ran within the margin of a stroke end (cut short there)
    windows: list[WindowMean] = field(default_factory=list)  # the windows completed before that
    swing_rows: list[tuple[float, ...]] = field(default_factory=list)  # F_stick, I, w, dw/dt
    swing_rejected: int = 0
    windows_rejected: int = 0
    steps: int = 0


def _forces(sim: Any) -> np.ndarray:
    """The circuit's cylinder forces at the present state (as ``observe`` reports them), N."""
    ph = sim.physics
    rate = ph.joint_velocities()[0]
    forces, _ = sim.circuit.actuator_forces(
        sim.state, ph.cylinder_extensions(), ph.cylinder_velocities(), rate, end_stops=False
    )
    return forces


def _inside(ext: np.ndarray, margin: float) -> bool:
    return bool(np.all(ext > margin) and np.all(ext < _STROKE - margin))


def tip_force_world(force_arm: np.ndarray, swing: float) -> np.ndarray:
    """A tip force given in the arm plane (radial out, up; N) in the world frame at swing angle ``swing``."""
    c, s = math.cos(swing), math.sin(swing)
    return np.array([force_arm[0] * c, force_arm[0] * s, force_arm[1]])


_CHECK, _RECORD, _CENTRE, _EDGE = 1, 2, 4, 8


def run_segment(
    sim: Any,
    spools_m: np.ndarray,
    steps: int,
    config: CollectConfig,
    tip_force_arm: np.ndarray | None = None,
    swing_samples: bool = False,
) -> SegmentResult:
    """Hold ``spools_m`` for ``steps`` model steps on ``sim`` (a ReferenceModel) and sample it.

    The segment ends in ``windows_per_segment`` back-to-back windows of ``window_s``; each
    gives the means of the cylinder velocities, forces and swing inertia. ``tip_force_arm``
    (radial, vertical; N) is re-applied at the teeth before every step (MuJoCo keeps
    ``qfrc_applied``, but the lever follows the bucket and the arm plane the swing). With
    ``swing_samples`` the swing table's rows are taken along the way. A segment that runs a
    cylinder within ``margin_m`` of a stroke end stops there, keeping what was complete.
    """
    ph, dt = sim.physics, sim.timestep
    spools = np.asarray(spools_m, dtype=float)
    half = max(1, round(config.swing_half_width_s / dt))
    plan, edges = _segment_plan(steps, config, half, dt, swing_samples)
    rates = np.empty(steps + 1)
    rates[0] = ph.joint_velocities()[0]
    pending: dict[int, tuple[float, ...]] = {}  # centre step -> (F_stick, I, w)
    result = SegmentResult(spools=spools.copy())
    ext_edge = ph.cylinder_extensions() if edges[0] == 0 else None
    records: list[tuple[np.ndarray, float]] = []
    for k in range(1, steps + 1):
        if tip_force_arm is not None:
            ph.apply_tip_force(tip_force_world(tip_force_arm, float(ph.joint_positions()[0])))
        sim.step(spools)
        rates[k] = ph.joint_velocities()[0]
        if pending:
            result.swing_rows.extend(_finish_swing(pending, rates, k, half, dt))
        action = plan[k]
        if not action:
            continue
        ext = ph.cylinder_extensions()
        if not _inside(ext, config.margin_m):
            result.limited, result.steps = True, k
            result.swing_rejected = len(pending) + int(np.count_nonzero(plan[k:] & _CENTRE))
            result.windows_rejected = len(edges) - 1 - len(result.windows)
            return result
        if action & _RECORD:
            records.append((_forces(sim), ph.swing_inertia()))
        if action & _CENTRE:
            pending[k] = (float(_forces(sim)[_CYL["stick"]]), ph.swing_inertia(), float(rates[k]))
        if action & _EDGE:
            if ext_edge is not None and records:
                velocity = (ext - ext_edge) / (config.window_s_steps(dt) * dt)
                force = np.mean([f for f, _ in records], axis=0)
                inertia = float(np.mean([i for _, i in records]))
                result.windows.append(WindowMean(velocity, force, inertia))
            ext_edge, records = ext, []
    result.steps = steps
    return result


def _segment_plan(steps: int, config: CollectConfig, half: int, dt: float, swing: bool) -> tuple[np.ndarray, list[int]]:
    """Per step (1..steps) what to do after it, and the window edges (steps, ascending).

    Flags: limit check (every ``record_every`` steps), force record (mid-way in each record
    slot of a window), swing-sample centre, window edge.
    """
    every, window = config.record_every, config.window_s_steps(dt)
    first_edge = max(0, steps - config.windows_per_segment * window)
    edges = list(range(first_edge + (steps - first_edge) % window, steps + 1, window))
    plan = np.zeros(steps + 1, dtype=np.int8)
    plan[every::every] |= _CHECK
    plan[edges] |= _EDGE | _CHECK
    for start in edges[:-1]:
        plan[start + max(1, every // 2) : start + window + 1 : every] |= _RECORD | _CHECK
    if swing:
        first, interval = round(config.swing_settle_s / dt), max(1, round(config.swing_interval_s / dt))
        plan[max(first, half) : steps - half + 1 : interval] |= _CENTRE | _CHECK
    plan[0] = 0
    return plan, edges


def _finish_swing(
    pending: dict[int, tuple[float, ...]], rates: np.ndarray, k: int, half: int, dt: float
) -> list[tuple[float, ...]]:
    """Swing rows whose central difference completes at step ``k`` (removed from ``pending``)."""
    rows = []
    for c in [c for c in pending if c + half <= k]:
        rows.append((*pending.pop(c), float((rates[c + half] - rates[c - half]) / (2 * half * dt))))
    return rows


# --------------------------------------------------------------------------------------------
# Episodes.
@dataclass(frozen=True)
class EpisodeSetup:
    """The random start of an episode."""

    q: np.ndarray  # joint angles, rad
    payload_kg: float
    tip_force_arm: np.ndarray | None  # (radial out, up), N; None: no tip force


def episode_rng(seed: int, group: str, episode: int) -> np.random.Generator:
    """The episode's own generator: independent of workers, chunks and the other episodes."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(_GROUP_ID[group], episode)))


def episode_setup(rng: np.random.Generator, episode: int, config: CollectConfig) -> EpisodeSetup:
    """A random pose (cylinders uniform over their strokes), payload in turn, tip force."""
    q = np.zeros(4)
    q[0] = rng.uniform(-np.pi, np.pi)
    for i, name in enumerate(kinematics.FRONT_CYLINDERS):
        cyl = p.CYLINDERS[name]
        ext = rng.uniform(config.start_margin_m, cyl.stroke - config.start_margin_m)
        q[i + 1] = kinematics.joint_angle(name, cyl.retracted_length + ext)
    payload = float(config.payloads_kg[episode % len(config.payloads_kg)])
    u_zero, u_mag, u_up, u_dir = rng.uniform(size=4)
    tip = None
    if u_zero >= config.tip_force_zero_fraction:
        # angle from the outward radial towards up: mostly resisting a bucket moving down into
        # material (dragged in or pushed out), sometimes any direction (pulled out of the ground)
        angle = np.pi * u_dir if u_up < config.tip_force_upward_fraction else 2.0 * np.pi * u_dir
        magnitude = config.tip_force_max_n * u_mag
        tip = magnitude * np.array([np.cos(angle), np.sin(angle)])
    return EpisodeSetup(q, payload, tip)


def _draw_spool(rng: np.random.Generator, config: CollectConfig) -> float:
    """A spool on the 1 mm grid over ±11 mm (exactly neutral with ``zero_spool_probability``), m."""
    u, level = rng.uniform(), int(rng.integers(-11, 12))
    return 0.0 if u < config.zero_spool_probability else level * 1e-3


def _keep_in_stroke(spool: float, cylinder: str, ext: np.ndarray, hold_s: float, config: CollectConfig) -> float:
    """Reverse a spool that would run its cylinder into the margin of a stroke end this segment."""
    i = _CYL[cylinder]
    opening = min(max((abs(spool) - p.SPOOL_DEAD_BAND) / (p.SPOOL_STROKE - p.SPOOL_DEAD_BAND), 0.0), 1.0)
    room_out = _STROKE[i] - config.margin_m - ext[i] - _SPEED_OUT[i] * opening * hold_s
    room_in = ext[i] - config.margin_m - _SPEED_IN[i] * opening * hold_s
    if (spool > 0 and room_out < 0 and room_in > room_out) or (spool < 0 and room_in < 0 and room_out > room_in):
        return -spool
    return spool


def hold_tip_force(sim: Any, force_world: np.ndarray) -> None:
    """Apply a tip force to a model at rest and start its circuit holding it as well as gravity.

    ``ReferenceModel.reset`` sets chamber pressures that hold gravity only; against a tip force
    as well, the cylinders would first be yanked (and the chambers that lose pressure cavitate,
    which the circuit integrates in many small steps). Cylinder i must add ``-F . dtip/dq_i /
    arm_i`` (virtual work) to the gravity holding force.
    """
    ph = sim.physics
    q = ph.joint_positions()
    ph.apply_tip_force(force_world)
    extra = -(np.asarray(force_world) @ kinematics.tip_jacobian(q)[:, 1:]) / ph.moment_arms()
    sim.state = sim.circuit.initial_state(sim.holding_forces() + extra)


def plan_segment(
    rng: np.random.Generator, group: str, previous: np.ndarray, ext: np.ndarray, dt: float, config: CollectConfig
) -> tuple[np.ndarray, int]:
    """The next segment's spools (m) and length (steps); every call draws the same numbers."""
    hold = rng.uniform(*config.hold_s)
    draws = [_draw_spool(rng, config) for _ in range(2)]
    keep_swing = rng.uniform() < config.swing_persistence
    spools = np.zeros(4)
    _set_spools(spools, GROUPS[group], draws, keep_swing, previous, ext, hold, config)
    return spools, max(1, round(hold / dt))


def _set_spools(
    spools: np.ndarray,
    functions: tuple[str, ...],
    draws: list[float],
    keep_swing: bool,
    previous: np.ndarray,
    ext: np.ndarray,
    hold: float,
    config: CollectConfig,
) -> None:
    for name, value in zip(functions, draws, strict=True):
        if name == "swing":  # unlimited: no stroke ends, but persistence to reach full speed
            spools[_SPOOL[name]] = previous[_SPOOL[name]] if keep_swing else value
        else:
            spools[_SPOOL[name]] = _keep_in_stroke(value, name, ext, hold, config)


@dataclass
class EpisodeResult:
    """Rows per table (inputs, output, segment index) and counters of one episode."""

    rows: dict[str, list[tuple[np.ndarray, float, int]]]
    segments: int = 0
    rejected_segments: int = 0  # cut short at a stroke end
    rejected_windows: int = 0  # segment samples lost with them
    swing_rejected: int = 0
    ended_at_limit: bool = False
    error: str = ""
    sim_seconds: float = 0.0


def collect_episode(sim: Any, group: str, episode: int, seed: int, config: CollectConfig) -> EpisodeResult:
    """One episode of ``group`` on ``sim`` (a ReferenceModel): reset at a random start, run segments."""
    rng = episode_rng(seed, group, episode)
    setup = episode_setup(rng, episode, config)
    # a keyframe reset first clears what a reset to joint angles keeps (the previous episode's
    # tip force, the solver's warm start), so an episode does not depend on the one before it
    sim.reset("home", setup.payload_kg)
    sim.reset(setup.q, setup.payload_kg)
    if setup.tip_force_arm is not None:
        hold_tip_force(sim, tip_force_world(setup.tip_force_arm, setup.q[0]))
    result = EpisodeResult(rows={t: [] for t in config.tables(group)})
    spools = np.zeros(4)
    for seg in range(config.segments_per_episode):
        spools, steps = plan_segment(rng, group, spools, sim.physics.cylinder_extensions(), sim.timestep, config)
        try:
            seg_result = run_segment(sim, spools, steps, config, setup.tip_force_arm, group == "stick_swing")
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:  # a diverged model: end it here
            result.error = f"segment {seg}: {exc}"
            break
        result.segments += 1
        result.sim_seconds += seg_result.steps * sim.timestep
        _add_rows(result, group, seg, seg_result, config)
        if seg_result.limited:
            result.rejected_segments += 1
            result.ended_at_limit = True
            break
    return result


def collect_operator_episode(sim: Any, episode: int, seed: int, config: CollectConfig) -> EpisodeResult:
    """One sweep log (:func:`hexgym_lab.mbl.operator_logs.operator_log`, style ``sweep``) replayed on ``sim``.

    A row every ``operator_interval_s`` along the motion: the valve's passage areas identifiable at that
    instant (:func:`hexgym.mbl.valve.identify_areas`), each against the spools that acted on the step just
    taken (its flows and pressure rates; the log's rows change the spools every 0.05 s). Rows where a
    cylinder on pump 2 (the stick) is driven into its stroke end are left out: there its relief, not the
    valve, sets the pressure.
    """
    drawn = operator_log(episode_rng(seed, "operator", episode), config.operator_duration_s, "sweep")
    sim.reset("home", drawn.payload_kg)  # clears what a reset to joint angles keeps (see collect_episode)
    sim.reset(drawn.start_pose, drawn.payload_kg)
    ph, dt = sim.physics, sim.timestep
    every = max(1, round(config.operator_interval_s / dt))
    steps = int(round(drawn.duration / dt))
    row_of_step = np.minimum(((np.arange(steps + 1) * dt) / OPERATOR_DT + 1e-6).astype(int), len(drawn.t) - 1)
    spools_m = drawn.spools_mm[row_of_step] * 1e-3  # the spools acting from each step on
    result = EpisodeResult(rows={t: [] for t in config.tables("operator")})
    stick, stroke = _CYL["stick"], _STROKE[_CYL["stick"]]
    for k in range(1, steps + 1):
        before = sim.state[:12].copy()
        u = spools_m[k - 1]
        try:
            sim.step(u)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:  # a diverged model: end it here
            result.error = f"step {k}: {exc}"
            break
        result.sim_seconds += dt
        if k % every:
            continue
        ext = ph.cylinder_extensions()[stick]
        if (ext <= p.STROKE_END_MARGIN and u[2] < 0) or (ext >= stroke - p.STROKE_END_MARGIN and u[2] > 0):
            result.rejected_windows += 1
            continue
        q = {f"{name}_spool_m": float(u[i]) for name, i in _SPOOL.items()}
        q |= _valve_samples(sim, u, (sim.state[:12] - before) / dt)
        for table in config.tables("operator"):
            spec = TABLE_SETS[config.table_set][table]
            if not math.isnan(q[spec.output]):  # a passage not metering clearly gives none
                result.rows[table].append((np.array([q[name] for name in spec.inputs]), q[spec.output], k))
    result.segments = 1
    return result


def _valve_samples(sim: Any, spools_m: np.ndarray, pressure_rates: np.ndarray) -> dict[str, float]:
    """The valve's passage areas identifiable at this instant of ``sim`` (:func:`identify_areas`)."""
    state, ph = sim.state, sim.physics
    flows, _, _ = HydraulicCircuit.pump_flows(state[0:2], state[12:14])
    ext, vel = ph.cylinder_extensions(), ph.cylinder_velocities()
    volumes = sim.circuit.volumes(ext)
    rate = float(ph.joint_velocities()[0])
    return identify_areas(state[:12], pressure_rates, volumes, flows, spools_m, ext, vel, rate, sim.circuit.layout)


def _episode(sim: Any, group: str, episode: int, seed: int, config: CollectConfig) -> EpisodeResult:
    """One episode of ``group``: held-spool segments, or an operator-like log."""
    if group == "operator":
        return collect_operator_episode(sim, episode, seed, config)
    return collect_episode(sim, group, episode, seed, config)


def _add_rows(result: EpisodeResult, group: str, seg: int, r: SegmentResult, config: CollectConfig) -> None:
    """The segment's samples as rows of each of the group's tables, its inputs picked by name."""
    result.swing_rejected += r.swing_rejected
    result.rejected_windows += r.windows_rejected
    spools = {f"{name}_spool_m": float(r.spools[i]) for name, i in _SPOOL.items()}
    samples: dict[str, list[dict[str, float]]] = {"window": [], "trajectory": []}
    for w in r.windows:
        forces = {f"{c}_force_n": float(w.force[i]) for c, i in _CYL.items()}
        velocities = {f"{c}_velocity_mps": float(w.velocity[i]) for c, i in _CYL.items()}
        samples["window"].append(spools | forces | velocities | {"swing_inertia_kgm2": w.inertia})
    if group == "stick_swing":
        for force, inertia, rate, accel in r.swing_rows:
            samples["trajectory"].append(
                spools
                | {"stick_force_n": force, "swing_inertia_kgm2": inertia, "swing_rate_radps": rate}
                | {"swing_acceleration_radps2": accel}
            )
    for table in config.tables(group):
        spec = TABLE_SETS[config.table_set][table]
        for q in samples[spec.sampling]:
            result.rows[table].append((np.array([q[name] for name in spec.inputs]), q[spec.output], seg))


# --------------------------------------------------------------------------------------------
# Chunks of episodes: computed by workers, stored atomically, merged in index order.
_EPISODE_COUNTERS = (
    "segments",
    "rejected_segments",
    "rejected_windows",
    "swing_rejected",
    "ended_at_limit",
    "sim_seconds",
)
_SIMS: dict[str, Any] = {}  # one reference model per valve layout and process, made on first use
# Samples per episode as a fraction of segments x windows, measured on the default data set
# (episodes end at a stroke end; the bucket's runs there most often), a little low so the first
# round of chunks rather overshoots than needs a second one.
_YIELD = {"boom_bucket": 0.57, "stick_swing": 0.83}
_OPERATOR_YIELD = 0.9  # of a log's rows (0.98 measured: rows with the stick at its stop are dropped), low too


def _expected_samples_per_episode(group: str, config: CollectConfig) -> float:
    """A first estimate of the samples one episode of ``group`` gives (then the measured rate is used)."""
    if group == "operator":
        duration = config.operator_duration_s or float(np.mean(OPERATOR_DURATION_S))
        return _OPERATOR_YIELD * duration / config.operator_interval_s
    return config.segments_per_episode * config.windows_per_segment * _YIELD[group]


def _simulator(valve: str = DEFAULT_VALVE) -> Any:
    """This process's reference model with valve layout ``valve`` (one each, made on first use)."""
    if valve not in _SIMS:
        from hexgym.hydraulics.reference import ReferenceModel  # here: the CLI parser must not load MuJoCo

        _SIMS[valve] = ReferenceModel(valve=valve)
    return _SIMS[valve]


def model_fingerprint(valve: str = DEFAULT_VALVE) -> str:
    """A digest of a short fixed run of this process's reference model (16 hex digits).

    Stored with every chunk and data set: chunks from another reference model (any change to
    the circuit, the linkage, the parameters or the step, down to round-off) are never mixed
    in when a collection resumes, and a data set names the model it came from.
    """
    if valve not in _FINGERPRINTS:
        sim = _simulator(valve)
        sim.reset("home", 1000.0)
        sim.reset(np.array([0.3, 0.2, 0.4, 0.5]), 1000.0)
        force = np.array([-20e3, 0.0, 30e3])
        hold_tip_force(sim, force)
        for _ in range(25):
            sim.physics.apply_tip_force(force)
            sim.step(np.array([5.0, 9.0, -7.0, 11.0]) * 1e-3)
        digest = hashlib.sha256(np.float64(sim.timestep).tobytes())
        for array in (sim.physics.data.qpos, sim.physics.data.qvel, sim.state):
            digest.update(np.ascontiguousarray(array, dtype=np.float64).tobytes())
        _FINGERPRINTS[valve] = digest.hexdigest()[:16]
    return _FINGERPRINTS[valve]


_FINGERPRINTS: dict[str, str] = {}


def chunk_path(out_dir: str | os.PathLike[str], group: str, index: int) -> Path:
    """Where chunk ``index`` of ``group`` is stored."""
    return Path(out_dir) / "chunks" / f"{group}_{index:05d}.npz"


def _chunk_meta(group: str, index: int, seed: int, config: CollectConfig, fingerprint: str) -> dict[str, Any]:
    """What a chunk must have been made with to be reused."""
    return {
        "generator_version": GENERATOR_VERSION,
        "group": group,
        "chunk": index,
        "seed": seed,
        "config": json.loads(config.to_json()),
        "model_fingerprint": fingerprint,
    }


def _config_from_json(text: str) -> CollectConfig:
    return CollectConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in json.loads(text).items()})


def _chunk_task(task: tuple[str, str, int, int, str, str]) -> tuple[str, int, int, float]:
    """Compute and store one chunk; returns (group, index, counted samples, wall seconds)."""
    return _store_chunk(task[0], _compute_chunk(task))


def _compute_chunk(task: tuple[str, str, int, int, str, str]) -> tuple[str, int, int, float, dict[str, np.ndarray]]:
    """Compute one chunk: (group, index, counted samples, wall seconds, its arrays). The driver stores
    it (:func:`_store_chunk`), so workers on other machines need no shared file system."""
    out_dir, group, index, seed, config_json, fingerprint = task
    config = _config_from_json(config_json)
    valve = VALVE_OF_TABLE_SET[config.table_set]
    if model_fingerprint(valve) != fingerprint:  # e.g. a source file edited while a collection runs
        raise RuntimeError(
            f"the reference model in this worker ({model_fingerprint(valve)}) is not the one the "
            f"collection started with ({fingerprint}); restart the collection"
        )
    sim = _simulator(valve)
    t0 = time.perf_counter()
    first = index * config.episodes_per_chunk
    episodes = [(e, _episode(sim, group, e, seed, config)) for e in range(first, first + config.episodes_per_chunk)]
    wall = time.perf_counter() - t0
    arrays = _chunk_arrays(group, episodes, config)
    meta = _chunk_meta(group, index, seed, config, fingerprint) | {
        "wall_seconds": wall,
        "errors": [f"episode {e}: {r.error}" for e, r in episodes if r.error],
    }
    arrays["meta"] = np.array(json.dumps(meta, sort_keys=True))
    return group, index, len(arrays[f"{config.tables(group)[0]}_y"]), wall, arrays


def _store_chunk(
    out_dir: str, result: tuple[str, int, int, float, dict[str, np.ndarray]]
) -> tuple[str, int, int, float]:
    """Write a computed chunk; returns (group, index, counted samples, wall seconds)."""
    group, index, samples, wall, arrays = result
    _save_npz(chunk_path(out_dir, group, index), arrays)
    return group, index, samples, wall


def _chunk_arrays(
    group: str, episodes: list[tuple[int, EpisodeResult]], config: CollectConfig
) -> dict[str, np.ndarray]:
    arrays: dict[str, np.ndarray] = {}
    for table in config.tables(group):
        rows = [(e, *row) for e, r in episodes for row in r.rows[table]]
        d = len(TABLE_SETS[config.table_set][table].inputs)
        arrays[f"{table}_X"] = np.array([x for _, x, _, _ in rows], dtype=np.float64).reshape(-1, d)
        arrays[f"{table}_y"] = np.array([y for _, _, y, _ in rows], dtype=np.float64)
        arrays[f"{table}_episode"] = np.array([e for e, _, _, _ in rows], dtype=np.int64)
        arrays[f"{table}_segment"] = np.array([s for _, _, _, s in rows], dtype=np.int64)
    arrays["episode_index"] = np.array([e for e, _ in episodes], dtype=np.int64)
    for name in _EPISODE_COUNTERS:
        arrays[f"episode_{name}"] = np.array([getattr(r, name) for _, r in episodes], dtype=np.float64)
    return arrays


def _save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` to ``path`` atomically (temporary file in the same folder, then rename)."""
    with atomic_path(path) as tmp, tmp.open("wb") as fh:  # a file object: numpy appends no ".npz"
        np.savez(fh, **arrays)


def _load_chunk(path: Path, expected: dict[str, Any]) -> dict[str, np.ndarray]:
    """A stored chunk, checked to come from the same generator, seed and configuration."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        meta = json.loads(str(arrays["meta"]))
        if not isinstance(meta, dict):
            raise ValueError("its metadata is not a JSON object")
    except Exception as exc:  # a truncated or damaged file: zip, zlib, npy and JSON errors alike
        raise ValueError(
            f"chunk {path} is unreadable ({type(exc).__name__}: {exc}); delete it to recompute it"
        ) from None
    for key, value in expected.items():
        if meta.get(key) != value:
            raise ValueError(
                f"chunk {path} was made with {key}={meta.get(key)!r}, this run has {value!r}: "
                "use another output folder or delete its chunks/ folder"
            )
    tables = _config_from_json(json.dumps(expected["config"])).tables(expected["group"])
    problem = _chunk_problem(arrays, tables)
    if problem:
        raise ValueError(f"chunk {path} {problem}; delete it to recompute it")
    return arrays


def _chunk_problem(arrays: dict[str, np.ndarray], tables: tuple[str, ...]) -> str:
    """What is wrong with a chunk's arrays for ``tables`` ('' when nothing)."""
    for t in tables:
        for key, kind, ndim in (("X", "f", 2), ("y", "f", 1), ("episode", "iu", 1), ("segment", "iu", 1)):
            name = f"{t}_{key}"
            if name not in arrays:
                return f"lacks {name!r}"
            a = arrays[name]
            if a.dtype.kind not in kind or a.ndim != ndim or len(a) != len(arrays.get(f"{t}_X", a)):
                return f"has {name!r} of the wrong type or length ({a.dtype}, {a.shape})"
            if kind == "f" and not np.all(np.isfinite(a)):
                return f"holds non-finite numbers in {name!r}"
    index = arrays.get("episode_index")
    if index is None or index.dtype.kind not in "iu" or index.ndim != 1:
        return "lacks a whole-number 'episode_index'"
    return ""


@dataclass
class _GroupState:
    counted: int  # samples of the group's first table in the contiguous finished chunks 0 .. prefix-1
    prefix: int
    episodes_needed: int | None  # the first episodes that reach the target, once known


def _group_state(
    out_dir: Path, group: str, seed: int, config: CollectConfig, target: int, fingerprint: str
) -> _GroupState:
    counted, index, per = 0, 0, config.episodes_per_chunk
    count_table = config.tables(group)[0]
    while (path := chunk_path(out_dir, group, index)).exists():
        arrays = _load_chunk(path, _chunk_meta(group, index, seed, config, fingerprint))
        per_episode = np.bincount(arrays[f"{count_table}_episode"] - index * per, minlength=per)
        for j, n in enumerate(per_episode):
            counted += int(n)
            if counted >= target:
                return _GroupState(counted, index + 1, index * per + j + 1)
        index += 1
    return _GroupState(counted, index, None)


def _missing_chunks(out_dir: Path, group: str, state: _GroupState, target: int, config: CollectConfig) -> list[int]:
    """Chunk indices to compute next: as many as the samples still missing need at the rate so far."""
    per_chunk = config.episodes_per_chunk * _expected_samples_per_episode(group, config)
    if state.prefix > 0 and state.counted > 0:
        per_chunk = state.counted / state.prefix
    need = max(1, math.ceil((target - state.counted) / per_chunk))
    return [i for i in range(state.prefix, state.prefix + need) if not chunk_path(out_dir, group, i).exists()]


def _run_tasks(
    pool: Executor, tasks: list[tuple[str, str, int, int, str, str]]
) -> Iterator[tuple[str, int, int, float]]:
    """Run chunk tasks on ``pool`` (this process, a process pool or Ray); each is stored as it finishes."""
    for result in pool.map_unordered(_compute_chunk, tasks):
        yield _store_chunk(tasks[0][0], result)


# --------------------------------------------------------------------------------------------
# The data sets.
def collect(
    out_dir: str | os.PathLike[str],
    *,
    samples_per_group: int,
    seed: int,
    workers: int = 2,
    progress: bool = True,
    config: CollectConfig | None = None,
    max_chunks: int | None = None,
    ray: str | None = None,
) -> dict[str, Path]:
    """Collect the four tables' data sets into ``<out_dir>/<table>.npz``; returns the paths by table.

    Each group (boom_bucket: boom and bucket tables; stick_swing: stick and swing) runs episodes
    until its first table has ``samples_per_group`` samples; the data set holds every sample of
    the first episodes (in index order) that reach that count, so a few more. Finished chunks
    in ``<out_dir>/chunks`` are reused, so an interrupted run resumes where it stopped.
    ``max_chunks`` computes at most that many new chunks and returns ``{}`` if the data sets are
    not complete by then (a time-boxed run; the next call goes on). ``ray``: run the chunks as Ray
    tasks (:mod:`hexgym.parallel`: "local" or a cluster's address) instead of ``workers`` processes.

    Each ``.npz`` holds ``X`` (n, d) float64, ``y`` (n,), ``inputs`` (d,) and ``output`` (0-d)
    names, ``episode`` and ``segment`` (n,) indices (samples of one segment or episode are
    correlated: group them in cross-validation), ``seed``, ``generator_version`` and ``meta``
    (JSON: table, group, configuration, counters).
    """
    if samples_per_group < 1:
        raise ValueError(f"samples_per_group must be >= 1, got {samples_per_group}")
    if seed < 0 or workers < 1:
        raise ValueError(f"seed must be >= 0 and workers >= 1, got seed={seed}, workers={workers}")
    config = config or CollectConfig()
    out = check_output_dir(out_dir, "collection output directory")
    refuse_other_npz(out, [t for g in config.groups() for t in config.tables(g)], "data set")
    check_output_dir(out / "chunks", "chunk directory")
    (out / "chunks").mkdir(parents=True, exist_ok=True)
    with executor(workers, ray=ray) as pool:  # first: a cluster that cannot run the chunks is refused at once
        fingerprint = model_fingerprint(VALVE_OF_TABLE_SET[config.table_set])
        bar = _ProgressBar({g: config.target(g, samples_per_group) for g in config.groups()}, enabled=progress)
        new_chunks = 0
        try:
            while True:
                states = {
                    g: _group_state(out, g, seed, config, config.target(g, samples_per_group), fingerprint)
                    for g in config.groups()
                }
                bar.set({g: s.counted for g, s in states.items()})
                todo = sorted(  # by index: the groups advance together
                    (i, g)
                    for g, s in states.items()
                    if s.episodes_needed is None
                    for i in _missing_chunks(out, g, s, config.target(g, samples_per_group), config)
                )
                if not todo:
                    break
                if max_chunks is not None:
                    todo = todo[: max(0, max_chunks - new_chunks)]
                    if not todo:
                        return {}
                tasks = [(str(out), g, i, seed, config.to_json(), fingerprint) for i, g in todo]
                for group, _index, samples, _wall in _run_tasks(pool, tasks):
                    new_chunks += 1
                    bar.add(group, samples)
        finally:
            bar.close()
    return _write_datasets(out, states, seed, config, fingerprint)


class _ProgressBar:
    """Progress over samples (per group, capped at the target): :mod:`hexgym_lab.progress`."""

    def __init__(self, targets: dict[str, int], enabled: bool) -> None:
        self._caps = targets
        self._counts: dict[str, int] = {}
        self._bar = Progress(sum(targets.values()), "collect", "sample") if enabled else None

    def set(self, counts: dict[str, int]) -> None:
        self._counts = {g: min(self._caps[g], n) for g, n in counts.items()}
        self._refresh()

    def add(self, group: str, samples: int) -> None:
        self._counts[group] = min(self._caps[group], self._counts.get(group, 0) + samples)
        self._refresh()

    def _refresh(self) -> None:
        if self._bar is not None:
            self._bar.set(sum(self._counts.values()), **self._counts)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


def _write_datasets(
    out: Path, states: dict[str, _GroupState], seed: int, config: CollectConfig, fingerprint: str
) -> dict[str, Path]:
    paths, sets = {}, {}
    for group, state in states.items():
        n_episodes = int(state.episodes_needed)
        chunks = [
            _load_chunk(chunk_path(out, group, i), _chunk_meta(group, i, seed, config, fingerprint))
            for i in range(math.ceil(n_episodes / config.episodes_per_chunk))
        ]
        stats = _group_stats(chunks, n_episodes)
        for table in config.tables(group):
            spec = TABLE_SETS[config.table_set][table]
            kept = {
                key: np.concatenate([c[f"{table}_{key}"][c[f"{table}_episode"] < n_episodes] for c in chunks])
                for key in ("X", "y", "episode", "segment")
            }
            meta = {
                "table": table,
                "group": group,
                "config": json.loads(config.to_json()),
                "model_fingerprint": fingerprint,
                "timestep": _simulator(VALVE_OF_TABLE_SET[config.table_set]).timestep,
                "valve": VALVE_OF_TABLE_SET[config.table_set],
                "stats": stats,
            }
            arrays = {
                **kept,
                "inputs": np.array(spec.inputs),
                "output": np.array(spec.output),
                "seed": np.array(seed, dtype=np.int64),
                "generator_version": np.array(GENERATOR_VERSION, dtype=np.int64),
                "meta": np.array(json.dumps(meta, sort_keys=True)),
            }
            paths[table] = out / f"{table}.npz"
            sets[table] = arrays
    with staged_dir(out) as staging:  # the data sets are replaced together or not at all
        for table, arrays in sets.items():
            _save_npz(staging / f"{table}.npz", arrays)
    return paths


def _group_stats(chunks: list[dict[str, np.ndarray]], n_episodes: int) -> dict[str, float]:
    """Counters over the episodes kept: segments, rejections, simulated and computing time."""
    keep = np.concatenate([c["episode_index"] for c in chunks]) < n_episodes
    total = {
        name: float(np.concatenate([c[f"episode_{name}"] for c in chunks])[keep].sum()) for name in _EPISODE_COUNTERS
    }
    metas = [json.loads(str(c["meta"])) for c in chunks]
    return total | {
        "episodes": n_episodes,
        "rejected_fraction": total["rejected_segments"] / max(total["segments"], 1.0),
        "chunk_wall_seconds": float(sum(m["wall_seconds"] for m in metas)),
        "errors": sum(len(m["errors"]) for m in metas),
    }


def load_dataset(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A table's data set: X, y, inputs (tuple), output (str), episode, segment, seed, meta (dict)."""
    with np.load(path, allow_pickle=False) as data:
        return {
            "X": data["X"],
            "y": data["y"],
            "inputs": tuple(str(s) for s in data["inputs"]),
            "output": str(data["output"]),
            "episode": data["episode"],
            "segment": data["segment"],
            "seed": int(data["seed"]),
            "generator_version": int(data["generator_version"]),
            "meta": json.loads(str(data["meta"])),
        }


def samples_digest(paths: dict[str, Path]) -> str:
    """SHA-256 (hex) of the data sets' samples: X, y, episode, segment of each table in name order. Equal
    collections give equal digests; the files themselves differ in wall times and zip timestamps."""
    digest = hashlib.sha256()
    for table in sorted(paths):
        data = load_dataset(paths[table])
        for key in ("X", "y", "episode", "segment"):
            digest.update(np.ascontiguousarray(data[key]).tobytes())
    return digest.hexdigest()


def coverage_report(paths: dict[str, Path]) -> str:
    """Per table: sample count, rejection counters and min / percentiles / max of every column."""
    header = " " * 28 + " ".join(f"{h:>10s}" for h in ("min", "p5", "p25", "p50", "p75", "p95", "max"))
    lines = [header]
    for table, path in paths.items():
        ds = load_dataset(path)
        st = ds["meta"]["stats"]
        lines.append(
            f"{table}: {len(ds['y'])} samples, {st['episodes']} episodes, {st['segments']:.0f} segments "
            f"({st['rejected_fraction']:.1%} cut at a stroke end, {st['rejected_windows']:.0f} samples lost), "
            f"{st['sim_seconds']:.0f} s simulated"
            + (f", {st['swing_rejected']:.0f} swing samples rejected" if table == "swing" else "")
        )
        if len(ds["y"]) == 0:  # a short collection leaves some of a set's tables without samples (yet)
            lines.append("  no samples: collect more (a larger --samples) before fitting")
            continue
        for name, col in zip((*ds["inputs"], ds["output"]), np.column_stack([ds["X"], ds["y"]]).T, strict=True):
            q = np.percentile(col, [0, 5, 25, 50, 75, 95, 100])
            lines.append(f"  {name:26s}" + " ".join(f"{v:10.4g}" for v in q))
    return "\n".join(lines)

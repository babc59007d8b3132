"""A scripted loading controller: loading phases read off the state, tracked by resolved-rate control.

Phases: ``to_pile`` (swing to the cut where the pile stands highest, bucket open above its far
side), ``penetrate`` (teeth into the pile), ``drag`` (pull the edge towards the machine at a
constant depth below the surface, turning the teeth along the motion), ``curl`` (close the bucket,
mouth up), ``to_truck`` (lift and swing, the swing held short of the truck until the teeth clear
its rim), ``dump`` (reach out and open the bucket over the bed), then ``to_pile`` again. The phase
is not remembered: :func:`infer_phase` derives it every step from the state (payload, teeth
relative to pile and truck, mouth tilt, swing angles), so the loader's action is a function of
the state and it can label any state a learner reaches (DAgger, :mod:`hexgym_lab.agents.training`). It
proves the task can be done and drives the demo; :func:`run_scripted` measures cycle time,
tonnes per hour and fuel. Its targets and thresholds are :class:`LoaderSettings` (hand-set defaults;
:mod:`hexgym_lab.agents.loader_search` searches them).

Control: the front linkage is planar, so a target is the teeth's radius and height and the
bucket's absolute angle. Boom and stick steer the bucket pin (its error gives a saturated
velocity, the linkage Jacobian the two joint rates), the bucket joint turns the bucket to its
angle; the joint rates give cylinder speeds and the machine's own MBL tables, inverted at the
present loads, the spool for each speed (the open-centre valves' dead zone is large). The swing
follows the stopping curve of the deceleration its crossover reliefs give at the present
inertia. Functions sharing a pump slow each other (boom + bucket, swing + stick), so the loader
overlaps only what the pumps allow: boom raise with swing, stick reach-out after the swing.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

from hexgym.envs.earthwork import mouth_normal
from hexgym.envs.loading import REWARD_TERMS, HexLoadingEnv, bucket_angle_for
from hexgym.envs.world import TRUCK_CAB_LENGTH, Layout, World, entry_radius, inner_radius
from hexgym.files import write_json
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.names import BUCKET_BODY
from hexgym.mbl.table import MBLTable

_MOUTH_NORMAL_3D = np.array([mouth_normal()[0], 0.0, mouth_normal()[1]])  # bucket frame
FULL_SPOOL_CYLINDER_SPEED = np.array([0.28, 0.48, 0.29])  # m/s boom up, stick in, bucket curl [hexgym reference-report]
SWING_BRAKE = 0.35  # rad/s^2: default planned deceleration of swing_spool (the loader plans with swing_brake)
SWING_GAIN = 4.0  # spool per rad/s of swing-rate error (the valve's dead zone swallows small spools)
POSITION_GAIN = 1.5  # 1/s: planar velocity per metre (or rad) of error
MAX_TIP_SPEED = 2.0  # m/s planned (beyond the boom's full-spool speed: it sets the pace)
DRAG_FLOOR = 0.3  # m: lowest teeth height in the drag (teeth along it: the bucket's body rides above them)
GROUND_CLEARANCE = 0.5  # m: lowest teeth height while digging (the bucket's heel hangs below the teeth)
DRAG_LEAD = 0.3  # m: the drag's radius target runs this far ahead of the teeth
PILE_CLEARANCE = 0.5  # m: teeth above the pile's surface before the loaded swing starts
REACH_PER_METRE = 2.0  # m: the empty bucket reaches out over the pile this far per metre above its top
ENTRY_TOLERANCE = 0.4  # m: radius error within which the teeth are at the entry point
IN_PILE = 0.05  # m: teeth lower than this above the surface are in the pile...
MATERIAL_DEPTH = 0.1  # m: ...where it is at least this high (elsewhere the teeth are at the ground)
EMPTY_KG = 100.0  # kg: less left in the bucket counts as empty (the open bucket drops the rest on its way)
WORTH_CARRYING_KG = 500.0  # kg: out of the pile with this much, curl and carry it; with less, dig on
CARRIED_TILT = 0.6  # rad: the mouth this close to facing up holds its load (repose 0.59): carry it
CARRY_MARGIN = 0.2  # rad inside CARRIED_TILT by which the carried bucket's pull-in takes its full target
DUMP_PIN_BEYOND = 0.0  # m: bucket pin radius beyond the bed's centre line


@dataclass(frozen=True)
class LoaderSettings:
    """The loader's tunable targets and thresholds; the defaults are hand-set (``hexgym tune-loader`` searches them).

    Files: JSON of the fields to change (:meth:`load`); the rest keep their defaults.
    """

    full_fraction: float = 0.85  # of the heaped capacity: stop dragging (a fuller bucket spills on the way)
    dig_depth: float = 0.45  # m below the surface during the drag
    drag_speed: float = 0.6  # m/s towards the machine
    approach_height: float = 0.6  # m above the pile's top: where the empty bucket arrives before it goes in
    open_within: float = 2.0  # m: the empty bucket opens for the dig over this distance to the entry radius
    clearance: float = 1.5  # m: teeth above the rim when swinging over it (the curled bucket hangs below them)
    arrive_height: float = 1.2  # m: teeth above the rim before the loaded bucket swings over the truck
    truck_approach: float = 0.8  # rad: the loaded swing waits at most this far short of the truck until...
    hold_back_per_metre: float = 1.0  # rad: ...the teeth clear its rim: this far per metre they still have to rise
    dump_window: float = 0.25  # rad: the swing this close to the truck's direction: reach out and dump
    dump_pin_height: float = 1.5  # m: bucket pin above the rim to dump from (the opened teeth swing down, out)
    leave_height: float = 0.5  # m: teeth (the open bucket's lowest point) above the rim before it swings away
    brake_margin: float = 1.0  # of the crossover reliefs' deceleration, planned for the swing's stop
    # for teaching (0: the hand-set loader's step changes): labels that agree either side of a phase change
    carry_blend: float = 0.0  # rad of tilt before the carried tilt over which the curl moves on to the carry's targets
    return_blend: float = 0.0  # kg above empty over which the dump's spools move on to the return's
    penetrate_aim: float = 0.0  # 1: the entering bucket lines up with the cut until it is in the pile (0: holds)

    def __post_init__(self) -> None:
        for f in fields(self):  # bool is an int: refused too
            low, high = SETTING_RANGES[f.name]
            value = getattr(self, f.name)
            if isinstance(value, bool) or not (
                isinstance(value, (int, float)) and math.isfinite(value) and low <= value <= high
            ):
                raise ValueError(f"loader setting {f.name}={value!r} must be a number in [{low}, {high}]")

    @classmethod
    def load(cls, path: str | Path) -> LoaderSettings:
        """Settings from a JSON file of field values; unknown fields and out-of-range values are refused."""
        from hexgym.files import check_input_file

        path = check_input_file(path, "loader settings")  # a regular file: a pipe or a device would be read forever
        if path.stat().st_size > 1 << 20:
            raise ValueError(f"{path}: {path.stat().st_size} bytes is too large for loader settings")

        def finite_only(name: str) -> float:
            raise ValueError(f"{name} is not a finite number")

        try:
            values = json.loads(path.read_bytes().decode("utf-8"), parse_constant=finite_only)
        except (OSError, UnicodeDecodeError, ValueError, RecursionError) as error:
            raise ValueError(f"{path}: not a readable JSON file of loader settings ({error})") from None
        if not isinstance(values, dict):
            raise ValueError(f"{path}: expected a JSON object of loader settings, got {type(values).__name__}")
        unknown = sorted(set(values) - {f.name for f in fields(cls)})
        if unknown:
            raise ValueError(f"{path}: unknown loader settings {unknown} (known: {sorted(SETTING_RANGES)})")
        try:
            return cls(**values)
        except ValueError as error:
            raise ValueError(f"{path}: {error}") from None

    def save(self, path: str | Path) -> None:
        """Write the settings as JSON (atomically)."""
        write_json(path, asdict(self))


SETTING_RANGES = {  # the values a setting may take (the search's bounds; the defaults inside)
    "full_fraction": (0.5, 0.95), "dig_depth": (0.2, 0.8), "drag_speed": (0.3, 1.5), "approach_height": (0.2, 1.2),
    "open_within": (0.5, 3.5), "clearance": (0.8, 2.5), "arrive_height": (0.4, 2.0), "truck_approach": (0.3, 1.5),
    "hold_back_per_metre": (0.3, 2.5), "dump_window": (0.1, 0.6), "dump_pin_height": (0.8, 2.5),
    "leave_height": (0.1, 1.2), "brake_margin": (0.7, 1.6), "carry_blend": (0.0, 1.0),
    "return_blend": (0.0, 500.0), "penetrate_aim": (0.0, 1.0),
}  # fmt: skip
# shape the labels a clone learns from, not what the loader delivers: hexgym tune-loader leaves them alone
TEACHING_SETTINGS = ("carry_blend", "return_blend", "penetrate_aim")
DEFAULT_SETTINGS = LoaderSettings()


def load_settings(path: str | Path | None) -> LoaderSettings:
    """The settings in the JSON file ``path`` (:meth:`LoaderSettings.load`), or the hand-set ones for None."""
    return DEFAULT_SETTINGS if path is None else LoaderSettings.load(path)


PENETRATE_ANGLE = bucket_angle_for(teeth_world_angle=np.radians(-115.0))  # teeth down, towards the machine
DRAG_ANGLE = bucket_angle_for(teeth_world_angle=np.radians(-165.0))  # teeth along the drag
CARRY_ANGLE = bucket_angle_for(mouth_world_angle=np.radians(100.0))  # mouth up, a little towards the cab
DUMP_ANGLE = bucket_angle_for(mouth_world_angle=np.radians(-130.0))  # mouth 140 deg from up: all runs out
CARRY_RADIUS = 5.0  # m: close in, where the fully curled bucket can be level (it cannot at full reach)


def _planar_state(q: np.ndarray) -> np.ndarray:
    """(radius, height above ground, absolute bucket angle) of the teeth at joint angles ``q``."""
    q0 = np.array([0.0, *q[1:]])
    tip = kinematics.tip_position(q0)
    return np.array([tip[0], tip[2], kinematics.link_angles(q0)[2]])


_STOP_MARGIN = 0.02  # rad from a joint's stop: treat it as there
_LOWER = np.array([kinematics.joint_range(n)[0] for n in kinematics.FRONT_CYLINDERS]) + _STOP_MARGIN
_UPPER = np.array([kinematics.joint_range(n)[1] for n in kinematics.FRONT_CYLINDERS]) - _STOP_MARGIN
_SPOOL_GRID = np.linspace(0.0, 1.0, 23)  # spool fractions searched (0.5 mm steps)


def _spool_for(table: MBLTable, column: int, base: np.ndarray, wanted: float) -> float:
    """Spool fraction whose steady cylinder speed (the table's, at the present loads) is ``wanted`` m/s.

    The open-centre valve passes no flow until the pump pressure beats the load (for the boom
    lifting 300 kN, ~7 mm of 11): inverting the table's curve removes that dead zone.
    """
    if abs(wanted) < 1e-3:
        return 0.0
    side = np.sign(wanted)
    queries = np.tile(base, (len(_SPOOL_GRID), 1))
    queries[:, column] = side * _SPOOL_GRID * p.SPOOL_STROKE
    speeds = np.maximum.accumulate(side * table.lookup(queries))  # monotone for the inverse
    if abs(wanted) >= speeds[-1]:
        return float(side)
    return float(side * np.interp(abs(wanted), speeds, _SPOOL_GRID))


def _joint_rates(q: np.ndarray, target: np.ndarray, feed: np.ndarray | None) -> np.ndarray:
    """Boom, stick, bucket rates (rad/s) towards a teeth target (radius, height, bucket angle).

    Boom and stick steer the bucket pin to where the teeth target puts it at the target angle;
    the bucket joint then turns the bucket to its angle. A joint at its stop is left out.
    """
    q0 = np.array([0.0, *q[1:]])
    pins = kinematics.planar_pins(q0)
    pin, foot, stick_pin = pins["bucket_pin"], pins["boom_foot"], pins["stick_pin"]
    teeth = kinematics.rotation(target[2]) @ np.array(p.BUCKET_TIP)
    pin_target = np.array([target[0], target[1] - p.SWING_BEARING_HEIGHT]) - teeth
    velocity = POSITION_GAIN * (pin_target - pin) + (feed[:2] if feed is not None else 0.0)
    speed = np.hypot(*velocity)
    if speed > MAX_TIP_SPEED:
        velocity *= MAX_TIP_SPEED / speed
    jac = np.column_stack([[-(pin - foot)[1], (pin - foot)[0]], [(pin - stick_pin)[1], -(pin - stick_pin)[0]]])
    free = np.ones(2, bool)
    arm = np.zeros(2)
    for _ in range(2):
        arm[:] = 0.0
        arm[free] = np.linalg.lstsq(jac[:, free], velocity, rcond=None)[0]
        blocked = free & (((q[1:3] >= _UPPER[:2]) & (arm > 0)) | ((q[1:3] <= _LOWER[:2]) & (arm < 0)))
        if not blocked.any():
            break
        free &= ~blocked
    angle_error = target[2] - kinematics.link_angles(q0)[2]  # no wrapping: the bucket cannot turn round
    angle_rate = POSITION_GAIN * angle_error + (feed[2] if feed is not None else 0.0)
    return np.array([arm[0], arm[1], arm[0] - arm[1] - angle_rate])  # bucket angle = boom - pi/2 - stick - bucket


@functools.cache
def _packaged_tables() -> dict[str, MBLTable]:
    from hexgym.mbl.table import load_tables

    return load_tables(table_set="paper")  # the steady velocity tables, whatever model drives the machine


def _tables(env: HexLoadingEnv) -> dict[str, MBLTable]:
    """The machine's velocity tables; the packaged ones where it has none here (the native backend keeps its
    copy in C++, the circuit model learns the valve instead): the loader's model of the machine, not the machine."""
    tables = getattr(env.machine, "tables", None)
    return tables if tables is not None and "boom" in tables else _packaged_tables()


def front_spools(env: HexLoadingEnv, target: np.ndarray, feed: np.ndarray | None = None) -> np.ndarray:
    """Boom, stick, bucket spools (fractions) that move the teeth towards ``target`` (radius, height, angle)."""
    q = env.physics.joint_positions()
    rates = _joint_rates(q, target, feed)
    arms = env.physics.moment_arms()
    cylinder_speeds = rates * arms
    # the slowest function sets the pace: scale all so none is asked beyond its full-spool speed
    cylinder_speeds /= max(1.0, float(np.max(np.abs(cylinder_speeds) / FULL_SPOOL_CYLINDER_SPEED)))
    f_boom, f_stick, f_bucket = env.machine.cylinder_loads(arms)
    tables = _tables(env)
    pump1 = np.array([0.0, 0.0, f_boom, f_bucket])  # boom, bucket spools; boom, bucket forces
    stick = np.array([0.0, 0.0, env.physics.swing_inertia(), f_stick])
    return np.array(
        [
            _spool_for(tables["boom"], 0, pump1, cylinder_speeds[0]),
            _spool_for(tables["stick"], 1, stick, cylinder_speeds[1]),
            _spool_for(tables["bucket"], 1, pump1, cylinder_speeds[2]),
        ]
    )


def swing_brake(inertia_kgm2: float, settings: LoaderSettings = DEFAULT_SETTINGS) -> float:
    """Planned swing deceleration (rad/s^2) at a swing inertia: the crossover reliefs' torque, with a margin."""
    return settings.brake_margin * p.SWING_TORQUE_AT_RELIEF / inertia_kgm2


def swing_spool(error: float, rate: float, brake: float = SWING_BRAKE) -> float:
    """Swing spool (fraction) following the braking curve (``brake`` rad/s^2) to a swing error (rad) from a rate."""
    wanted = np.sign(error) * min(np.sqrt(2.0 * brake * abs(error)), p.SWING_SPEED)
    u = SWING_GAIN * (wanted - rate)
    return float(np.clip(u, -1.0, 1.0)) if abs(error) > 0.01 or abs(rate) > 0.02 else 0.0


def _over_truck(tip: np.ndarray, layout: Layout) -> bool:
    """Whether the teeth are above the truck's footprint (bed and cab) or within a metre of it."""
    along, across, _ = World.truck_frame(tip, layout)
    front = p.TRUCK_BED_LENGTH / 2 + TRUCK_CAB_LENGTH
    return bool(-p.TRUCK_BED_LENGTH / 2 - 1.0 < along < front + 1.0 and abs(across) < p.TRUCK_BED_WIDTH / 2 + 1.0)


def _wrap(a: float) -> float:
    return float((a + np.pi) % (2 * np.pi) - np.pi)


RIM = p.TRUCK_BED_FLOOR_HEIGHT + p.TRUCK_BED_WALL_HEIGHT  # m: the bed's rim above the ground


@dataclass(frozen=True)
class LoaderState:
    """What the loader decides from: the machine and site now (the observation's quantities, and the pile)."""

    q: np.ndarray  # joint angles, rad
    qd: np.ndarray  # joint rates, rad/s
    tip: np.ndarray  # teeth, world m
    radius: float  # teeth from the swing axis, m
    surface: float  # height of the pile's surface below the teeth, m (0 off the pile)
    above_pile: float  # teeth above the pile's surface below them, m (negative: in the pile)
    tilt: float  # mouth from facing up, rad
    payload_kg: float
    swing_to_pile: float  # swing minus the pile's direction, rad
    swing_to_truck: float  # swing minus the truck's direction, rad
    dig_direction: float  # swing angle of the next cut (where the pile stands highest), rad
    swing_to_dig: float  # swing minus dig_direction, rad

    @staticmethod
    def of(env: HexLoadingEnv) -> LoaderState:
        """The state of ``env`` (unwrapped) now."""
        ph, lay = env.physics, env.layout
        q, tip = ph.joint_positions(), ph.tip_position()
        rotation = ph.data.xmat[ph.model.body(BUCKET_BODY).id].reshape(3, 3)
        surface = env.earth.pile.height_at_point(float(tip[0]), float(tip[1]))
        dig = env.fullest_cut_direction()
        return LoaderState(
            q=q, qd=ph.joint_velocities(), tip=tip, radius=float(np.hypot(*tip[:2])),
            surface=surface, above_pile=float(tip[2] - surface),
            tilt=float(np.arccos(np.clip(rotation[2] @ _MOUTH_NORMAL_3D, -1.0, 1.0))),
            payload_kg=float(env.earth.bucket_kg),
            swing_to_pile=_wrap(q[0] - lay.pile_direction), swing_to_truck=_wrap(q[0] - lay.truck_direction),
            dig_direction=dig, swing_to_dig=_wrap(q[0] - dig),
        )  # fmt: skip


def infer_phase(s: LoaderState, layout: Layout, settings: LoaderSettings = DEFAULT_SETTINGS) -> str:
    """The loading phase the state calls for: a function of the state alone (no timers, no memory).

    The same state always gets the same phase, so the loader can label any state a learner
    reaches (DAgger) consistently. Hysteresis comes from the state itself: a dump runs while
    material is left, a curl until the mouth faces up, a drag until the bucket is full.
    """
    loaded = s.payload_kg > EMPTY_KG
    if loaded and abs(s.swing_to_truck) < settings.dump_window:
        return "dump"
    if loaded and s.tilt < CARRIED_TILT:
        return "to_truck"
    full = s.payload_kg >= settings.full_fraction * p.BUCKET_HEAPED_CAPACITY * p.MATERIAL_DENSITY
    if s.above_pile < IN_PILE and s.surface > MATERIAL_DEPTH:
        if full:
            return "curl"
        if s.radius < inner_radius(layout):  # at the near edge: carry what is there, or go round again
            return "curl" if s.payload_kg >= WORTH_CARRYING_KG else "to_pile"
        depth = -s.above_pile
        at_entry = s.radius > entry_radius(layout) - ENTRY_TOLERANCE
        if at_entry and depth < settings.dig_depth - 0.15 and s.tip[2] > GROUND_CLEARANCE + 0.15:
            return "penetrate"
        return "drag"
    if s.payload_kg >= WORTH_CARRYING_KG:
        return "curl"  # out of the pile with a load and the bucket open: close it
    aligned = abs(s.swing_to_dig) < 0.08 and abs(s.qd[0]) < 0.2
    low = s.tip[2] < layout.pile_height + settings.approach_height + 0.3
    if aligned and abs(s.radius - entry_radius(layout)) < ENTRY_TOLERANCE and low:
        return "penetrate"
    return "to_pile"


@dataclass
class ScriptedLoader:
    """The loader; call :meth:`act` with the (unwrapped) environment every step.

    Its phase is re-derived from the state every step (:func:`infer_phase`), so :meth:`act` is a
    function of the state: :meth:`label` gives the same action for any state, however it was reached.
    """

    settings: LoaderSettings = DEFAULT_SETTINGS
    phase: str = "to_pile"
    log: list[tuple[float, str]] = field(default_factory=list)

    def reset(self) -> None:
        """Forget the phase log."""
        self.phase, self.log = "to_pile", []

    def act(self, env: HexLoadingEnv) -> np.ndarray:
        """The action (4 spool fractions) for the environment's present state; logs phase changes."""
        state = LoaderState.of(env)
        phase = infer_phase(state, env.layout, self.settings)
        if phase != self.phase:
            self.phase = phase
            self.log.append((env.elapsed, phase))
        return action_for(env, state, phase, self.settings)

    def label(self, env: HexLoadingEnv) -> np.ndarray:
        """The action for the present state, without touching the phase log (the DAgger expert's label)."""
        state = LoaderState.of(env)
        return action_for(env, state, infer_phase(state, env.layout, self.settings), self.settings)


Targets = tuple[np.ndarray, float, np.ndarray | None]  # teeth (radius, height, angle), swing angle, planar feed


def _to_pile(env: HexLoadingEnv, s: LoaderState, settings: LoaderSettings) -> Targets:
    lay = env.layout
    entry = entry_radius(lay)
    if _over_truck(s.tip, lay):  # above the truck: up to the carry height, swing once above the rim
        swing = s.dig_direction if s.tip[2] > RIM + settings.leave_height else s.q[0]
        return np.array([s.radius, RIM + settings.clearance, _planar_state(s.q)[2]]), swing, None
    # reach out only as far as the height over the pile's top allows (reaching out sags the teeth)
    reach = REACH_PER_METRE * max(s.tip[2] - lay.pile_height - 0.1, 0.0)
    radius = entry if s.radius > entry - ENTRY_TOLERANCE else min(entry, s.radius + reach)
    # open the bucket (teeth down) near the entry; until then carry it mouth up, clear of its stops
    within = settings.open_within
    opened = float(np.clip((s.radius - entry + within) / within, 0.0, 1.0))  # smoothly: no chatter
    angle = CARRY_ANGLE + opened * (PENETRATE_ANGLE - CARRY_ANGLE)
    return np.array([radius, lay.pile_height + settings.approach_height, angle]), s.dig_direction, None


def _penetrate(env: HexLoadingEnv, s: LoaderState, settings: LoaderSettings) -> Targets:
    surface = float(env.earth.pile.height_at(s.tip[:2]))
    target = [entry_radius(env.layout), max(surface - settings.dig_depth - 0.2, GROUND_CLEARANCE), PENETRATE_ANGLE]
    # in the pile the swing holds (the cut's direction moves as it digs)
    swing = s.q[0] + settings.penetrate_aim * _wrap(s.dig_direction - s.q[0]) if s.above_pile > 0.0 else s.q[0]
    return np.array(target), swing, None


def _drag(env: HexLoadingEnv, s: LoaderState, settings: LoaderSettings) -> Targets:
    ahead_radius = max(s.radius - DRAG_LEAD, 1.0)
    surface = float(env.earth.pile.height_at(s.tip[:2] * ahead_radius / max(s.radius, 1e-6)))
    target = [ahead_radius, max(surface - settings.dig_depth, DRAG_FLOOR), DRAG_ANGLE]
    return np.array(target), s.q[0], np.array([-settings.drag_speed, 0.0, 0.0])


def _curl(env: HexLoadingEnv, s: LoaderState, settings: LoaderSettings) -> Targets:
    """Close the bucket while the pile still holds the contents.

    Over the last ``carry_blend`` rad of tilt the teeth's target moves on to the carry's (``to_truck``'s),
    so that at the carried tilt both phases ask for the same motion: a clone averaging the labels either
    side of that boundary would otherwise ask for neither, and the loaded bucket would stall in the pile.
    """
    surface = float(env.earth.pile.height_at(s.tip[:2]))
    radius = s.radius if s.above_pile < IN_PILE else min(s.radius, CARRY_RADIUS)  # out: level it close in
    hold = np.array([radius, max(surface - 0.1, s.tip[2], 2 * GROUND_CLEARANCE), CARRY_ANGLE])
    if settings.carry_blend <= 0.0:
        return hold, s.q[0], None
    carry = _to_truck(env, s, settings)[0]
    weight = float(np.clip((CARRIED_TILT + settings.carry_blend - s.tilt) / settings.carry_blend, 0.0, 1.0))
    return hold + weight * (carry - hold), s.q[0], None


def _to_truck(env: HexLoadingEnv, s: LoaderState, settings: LoaderSettings) -> Targets:
    target = np.array([CARRY_RADIUS, RIM + settings.clearance, CARRY_ANGLE])
    if s.radius > CARRY_RADIUS + 0.5:  # pull in low first: only close in can the curled bucket be level
        target[1] = min(target[1], s.tip[2] + 0.3)
    # the teeth pull in only as the mouth curls inside the carried tilt: the stick pulling in at once would take
    # the flow the bucket needs (stick 2 shares its pump) and tip the mouth back past that tilt
    target[0] = s.radius + float(np.clip((CARRIED_TILT - s.tilt) / CARRY_MARGIN, 0.0, 1.0)) * (target[0] - s.radius)
    # the boom keeps rising while it swings: clear of the pile, swing to short of the truck until above its rim
    swing = s.q[0]
    if s.above_pile > PILE_CLEARANCE:  # the curled bucket hangs ~1 m below the teeth: clear the cab and rim
        deficit = max(RIM + settings.arrive_height - s.tip[2], 0.0)
        swing = env.layout.truck_direction + min(
            settings.truck_approach, settings.hold_back_per_metre * deficit
        ) * np.sign(s.swing_to_truck)
    return target, swing, None


def _dump(env: HexLoadingEnv, s: LoaderState, settings: LoaderSettings) -> Targets:
    lay = env.layout
    mouth = env.mouth_position()
    # open with the mouth over the bed: the pin is over the bed's centre line, so the teeth swing out over it
    over_bed = env.world.in_bed(mouth[:2], lay) and mouth[2] > RIM + 0.3
    # the bucket pin goes to one place over the bed whatever the bucket does; the bucket opens once over the
    # bed and until then holds (never curls back): the labels either side of the bed's edge then agree on
    # boom and stick, and a clone averaging them does not stall there
    angle = DUMP_ANGLE if over_bed else _planar_state(s.q)[2]
    return (
        _teeth_for_pin(lay.truck_distance + DUMP_PIN_BEYOND, RIM + settings.dump_pin_height, angle),
        lay.truck_direction,
        None,
    )


_PHASES = {
    "to_pile": _to_pile, "penetrate": _penetrate, "drag": _drag, "curl": _curl, "to_truck": _to_truck, "dump": _dump,
}  # fmt: skip


def _phase_targets(env: HexLoadingEnv, s: LoaderState, phase: str, settings: LoaderSettings) -> Targets:
    """(teeth target: radius, height, bucket angle; swing target, rad; planar feed velocity or None) of a phase."""
    if phase not in _PHASES:
        raise ValueError(f"unknown phase {phase!r} (one of {sorted(_PHASES)})")
    return _PHASES[phase](env, s, settings)


def _teeth_for_pin(radius: float, height: float, angle: float) -> np.ndarray:
    """The teeth target (radius, height, angle) that puts the bucket pin at ``radius``, ``height`` (m)."""
    teeth = kinematics.rotation(angle) @ np.array(p.BUCKET_TIP)
    return np.array([radius + teeth[0], height + teeth[1], angle])


def action_for(
    env: HexLoadingEnv, s: LoaderState, phase: str, settings: LoaderSettings = DEFAULT_SETTINGS
) -> np.ndarray:
    """The four spool fractions that carry out ``phase`` from state ``s``."""
    left = s.payload_kg - EMPTY_KG  # a nearly empty dump moves on to the return over return_blend kg
    if phase == "dump" and left < settings.return_blend:
        weight = 1.0 - left / settings.return_blend
        dump, back = (_phase_action(env, s, name, settings) for name in ("dump", "to_pile"))
        return (dump + weight * (back - dump)).astype(np.float32)
    return _phase_action(env, s, phase, settings)


def _phase_action(env: HexLoadingEnv, s: LoaderState, phase: str, settings: LoaderSettings) -> np.ndarray:
    """The spools of one phase's targets."""
    target, swing_target, feed = _phase_targets(env, s, phase, settings)
    action = np.zeros(4)
    brake = swing_brake(env.physics.swing_inertia(), settings)
    action[0] = swing_spool(_wrap(swing_target - s.q[0]), s.qd[0], brake)
    action[1:] = front_spools(env, target, feed)
    if phase == "to_truck" and s.above_pile < PILE_CLEARANCE:  # a loaded bucket is never pushed down into the pile
        action[1] = max(action[1], 0.0)
    return action.astype(np.float32)


def run_scripted(
    env: HexLoadingEnv,
    seed: int = 0,
    seconds: float | None = None,
    frames: list | None = None,
    settings: LoaderSettings = DEFAULT_SETTINGS,
    film: Callable[[HexLoadingEnv, dict], np.ndarray] | None = None,
) -> dict:
    """Run the scripted loader for an episode (or ``seconds``); return its measured figures.

    ``frames``: if given, a rendered frame is appended every step (the env needs a render_mode): ``film(env,
    info)``'s (e.g. a captioned frame) or, without ``film``, ``env.render()``.
    A cycle is counted at each start of a dump; the cycle time is the mean time between them.
    """
    controller = ScriptedLoader(settings)
    env.reset(seed=seed)
    controller.reset()
    terms = dict.fromkeys(REWARD_TERMS, 0.0)
    terminated = truncated = False
    while not (terminated or truncated) and (seconds is None or env.elapsed < seconds - 1e-9):
        _, _, terminated, truncated, info = env.step(controller.act(env))
        for k in terms:
            terms[k] += info[f"reward_{k}"]
        if frames is not None:
            frames.append(env.render() if film is None else film(env, info))
    dumps = [t for t, phase in controller.log if phase == "dump"]
    delivered_t = info["truck_kg"] / 1000.0
    hours = env.elapsed / 3600.0
    return {
        "seed": seed,
        "sim_seconds": round(env.elapsed, 3),
        "dumps": len(dumps),
        "first_dump_s": dumps[0] if dumps else None,
        "cycle_time_s": float(np.mean(np.diff(dumps))) if len(dumps) > 1 else None,
        "delivered_t": delivered_t,
        "tonnes_per_hour": delivered_t / hours if hours > 0 else 0.0,
        "spilled_t": info["spilled_kg"] / 1000.0,
        "fuel_l": info["fuel_l"],
        "fuel_l_per_t": info["fuel_l"] / delivered_t if delivered_t > 0 else None,
        "return": float(sum(terms.values())),
        "return_terms": terms,
        "terminated": bool(terminated),
    }

"""A scripted loading controller: a state machine of tip targets, tracked by resolved-rate control.

Phases: ``to_pile`` (swing to the pile, bucket open above its far side), ``penetrate`` (teeth into
the pile), ``drag`` (pull the edge towards the machine at a constant depth below the surface,
turning the teeth along the motion), ``curl`` (close the bucket, mouth up, and lift out),
``to_truck`` (lift above the bed's rim and swing), ``dump`` (open the bucket over the bed), then
``to_pile`` again. It proves the task can be done and drives the demo; :func:`run_scripted` measures
cycle time, tonnes per hour and fuel.

Control: the front linkage is planar, so a target is the teeth's radius and height and the
bucket's absolute angle. Boom and stick steer the bucket pin (its error gives a saturated
velocity, the linkage Jacobian the two joint rates), the bucket joint turns the bucket to its
angle; the joint rates give cylinder speeds and the machine's own MBL tables, inverted at the
present loads, the spool for each speed (the open-centre valves' dead zone is large). The swing
follows the stopping curve of its brake-limited deceleration.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from hexgym import machine
from hexgym import parameters as p
from hexgym.envs.earthwork import mouth_normal
from hexgym.envs.loading import REWARD_TERMS, STEP_PERIOD, HexLoadingEnv
from hexgym.envs.world import TRUCK_CAB_LENGTH, Layout, World
from hexgym.tables import MBLTable

# bucket frame directions (angle from the bucket frame's x axis towards z) of the teeth and mouth
_TEETH_ANGLE = float(np.arctan2(p.BUCKET_TEETH_DIRECTION[1], p.BUCKET_TEETH_DIRECTION[0]))
_MOUTH_ANGLE = float(np.arctan2(mouth_normal()[1], mouth_normal()[0]))
FULL_SPOOL_CYLINDER_SPEED = np.array([0.14, 0.35, 0.29])  # m/s boom, stick, bucket [README: reference model]
SWING_BRAKE = 0.35  # rad/s^2 planned deceleration (the crossover reliefs give ~0.5 with a loaded bucket)
SWING_GAIN = 2.0  # spool per rad/s of swing-rate error
POSITION_GAIN = 1.5  # 1/s: planar velocity per metre (or rad) of error
MAX_TIP_SPEED = 1.2  # m/s planned
DIG_DEPTH = 0.45  # m below the surface during the drag
DRAG_SPEED = 0.6  # m/s towards the machine
GROUND_CLEARANCE = 0.5  # m: lowest teeth height while digging (the bucket's heel hangs below the teeth)
FULL_FRACTION = 0.95  # of the heaped capacity: stop dragging
CLEARANCE = 1.5  # m: teeth above the bed's rim when swinging over it (the curled bucket hangs below them)


def bucket_angle_for(teeth_world_angle: float | None = None, mouth_world_angle: float | None = None) -> float:
    """Absolute bucket-frame angle (the branch :func:`hexgym.machine.link_angles` uses, about -4 to 0.5 rad)
    that points the teeth (or the mouth) along a planar world angle."""
    if teeth_world_angle is not None:
        angle = teeth_world_angle - _TEETH_ANGLE
    else:
        angle = float(mouth_world_angle) - _MOUTH_ANGLE
    return float((angle + 3.5) % (2 * np.pi) - 3.5)


PENETRATE_ANGLE = bucket_angle_for(teeth_world_angle=np.radians(-115.0))  # teeth down, towards the machine
DRAG_ANGLE = bucket_angle_for(teeth_world_angle=np.radians(-165.0))  # teeth along the drag
CARRY_ANGLE = bucket_angle_for(mouth_world_angle=np.radians(100.0))  # mouth up, a little towards the cab
DUMP_ANGLE = bucket_angle_for(mouth_world_angle=np.radians(-130.0))  # mouth 140 deg from up: all runs out
CARRY_RADIUS = 5.0  # m: close in, where the fully curled bucket can be level (it cannot at full reach)


def _planar_state(q: np.ndarray) -> np.ndarray:
    """(radius, height above ground, absolute bucket angle) of the teeth at joint angles ``q``."""
    q0 = np.array([0.0, *q[1:]])
    tip = machine.tip_position(q0)
    return np.array([tip[0], tip[2], machine.link_angles(q0)[2]])


_STOP_MARGIN = 0.02  # rad from a joint's stop: treat it as there
_LOWER = np.array([machine.joint_range(n)[0] for n in machine.FRONT_CYLINDERS]) + _STOP_MARGIN
_UPPER = np.array([machine.joint_range(n)[1] for n in machine.FRONT_CYLINDERS]) - _STOP_MARGIN
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
    pins = machine.planar_pins(q0)
    pin, foot, stick_pin = pins["bucket_pin"], pins["boom_foot"], pins["stick_pin"]
    teeth = machine.rotation(target[2]) @ np.array(p.BUCKET_TIP)
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
    angle_error = target[2] - machine.link_angles(q0)[2]  # no wrapping: the bucket cannot turn round
    angle_rate = POSITION_GAIN * angle_error + (feed[2] if feed is not None else 0.0)
    return np.array([arm[0], arm[1], arm[0] - arm[1] - angle_rate])  # bucket angle = boom - pi/2 - stick - bucket


@functools.cache
def _packaged_tables() -> dict[str, MBLTable]:
    from hexgym.fit import load_tables

    return load_tables()


def _tables(env: HexLoadingEnv) -> dict[str, MBLTable]:
    """The machine's MBL tables (the native backend keeps its own copy in C++: use the packaged files)."""
    tables = getattr(env.machine, "tables", None)
    return tables if tables is not None else _packaged_tables()


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


def swing_spool(error: float, rate: float) -> float:
    """Swing spool (fraction) following the braking curve to a swing error (rad) from a rate (rad/s)."""
    wanted = np.sign(error) * min(np.sqrt(2.0 * SWING_BRAKE * abs(error)), p.SWING_SPEED)
    u = SWING_GAIN * (wanted - rate)
    return float(np.clip(u, -1.0, 1.0)) if abs(error) > 0.01 or abs(rate) > 0.02 else 0.0


def _over_truck(tip: np.ndarray, layout: Layout) -> bool:
    """Whether the teeth are above the truck's footprint (bed and cab) or within a metre of it."""
    along, across, _ = World.truck_frame(tip, layout)
    front = p.TRUCK_BED_LENGTH / 2 + TRUCK_CAB_LENGTH
    return bool(-p.TRUCK_BED_LENGTH / 2 - 1.0 < along < front + 1.0 and abs(across) < p.TRUCK_BED_WIDTH / 2 + 1.0)


def _wrap(a: float) -> float:
    return float((a + np.pi) % (2 * np.pi) - np.pi)


@dataclass
class ScriptedLoader:
    """The state machine; call :meth:`act` with the (unwrapped) environment every step."""

    phase: str = "to_pile"
    phase_time: float = 0.0
    drag_radius: float = 0.0
    log: list[tuple[float, str]] = field(default_factory=list)

    def reset(self) -> None:
        """Start over at ``to_pile``."""
        self.phase, self.phase_time, self.log = "to_pile", 0.0, []

    def _go(self, phase: str, env: HexLoadingEnv) -> None:
        self.phase, self.phase_time = phase, 0.0
        self.log.append((env.elapsed, phase))

    def act(self, env: HexLoadingEnv) -> np.ndarray:
        """The action (4 spool fractions) for the environment's present state."""
        lay, earth, ph = env.layout, env.earth, env.physics
        q, qd = ph.joint_positions(), ph.joint_velocities()
        tip = ph.tip_position()
        radius = float(np.hypot(*tip[:2]))
        pile_r = float(np.hypot(*lay.pile_centre))
        far = pile_r + 0.8
        self.phase_time += STEP_PERIOD
        swing_target = lay.pile_direction
        feed = None
        if self.phase == "to_pile":
            target = np.array([far, lay.pile_height + 0.6, PENETRATE_ANGLE])
            rim = p.TRUCK_BED_FLOOR_HEIGHT + p.TRUCK_BED_WALL_HEIGHT
            if _over_truck(tip, lay):  # above the truck: up to the carry height, swing once above the rim
                target = np.array([radius, rim + CLEARANCE, _planar_state(q)[2]])
                swing_target = lay.pile_direction if tip[2] > rim + 0.5 else q[0]
            state = _planar_state(q)
            if abs(_wrap(lay.pile_direction - q[0])) < 0.04 and np.hypot(*(target - state)[:2]) < 0.35:
                self._go("penetrate", env)
        if self.phase == "penetrate":
            surface = float(earth.pile.height_at(tip[:2]))
            target = np.array([far, max(surface - DIG_DEPTH - 0.2, GROUND_CLEARANCE), PENETRATE_ANGLE])
            if surface - tip[2] > DIG_DEPTH or tip[2] < target[1] + 0.1 or self.phase_time > 4.0:
                self.drag_radius = radius
                self._go("drag", env)
        if self.phase == "drag":
            self.drag_radius = max(self.drag_radius - DRAG_SPEED * STEP_PERIOD, 0.0)
            ahead = tip[:2] * max(self.drag_radius, 1.0) / max(radius, 1e-6)
            surface = float(earth.pile.height_at(ahead))
            target = np.array([self.drag_radius, max(surface - DIG_DEPTH, GROUND_CLEARANCE), DRAG_ANGLE])
            feed = np.array([-DRAG_SPEED, 0.0, 0.0])
            near_edge = radius < pile_r - lay.pile_top_radius - 1.0
            if earth.bucket_volume >= FULL_FRACTION * p.BUCKET_HEAPED_CAPACITY or near_edge or self.phase_time > 8.0:
                self._go("curl", env)
        if self.phase == "curl":  # close the bucket while the pile still holds the contents
            surface = float(earth.pile.height_at(tip[:2]))
            target = np.array([radius, max(surface - 0.1, tip[2], 2 * GROUND_CLEARANCE), CARRY_ANGLE])
            state = _planar_state(q)
            if abs(CARRY_ANGLE - state[2]) < 0.15 or self.phase_time > 4.0:
                self._go("to_truck", env)
        if self.phase == "to_truck":
            rim = p.TRUCK_BED_FLOOR_HEIGHT + p.TRUCK_BED_WALL_HEIGHT
            target = np.array([CARRY_RADIUS, rim + CLEARANCE, CARRY_ANGLE])
            if radius > CARRY_RADIUS + 0.5:  # pull in low first: only close in can the curled bucket be level
                target[1] = min(target[1], tip[2] + 0.3)
            clear = tip[2] > max(lay.pile_height + 0.5, rim - 0.5)  # the boom keeps rising while it swings
            swing_target = lay.truck_direction if clear else q[0]
            if abs(_wrap(lay.truck_direction - q[0])) < 0.05 and abs(qd[0]) < 0.1:
                self._go("dump", env)
        if self.phase == "dump":
            swing_target = lay.truck_direction
            rim = p.TRUCK_BED_FLOOR_HEIGHT + p.TRUCK_BED_WALL_HEIGHT
            over_bed = env.world.in_bed(env.mouth_position()[:2], lay)
            target = np.array([lay.truck_distance + 0.3, rim + CLEARANCE, DUMP_ANGLE if over_bed else CARRY_ANGLE])
            if earth.bucket_kg < 5.0 or self.phase_time > 5.0:
                self._go("to_pile", env)
                target = np.array([far, lay.pile_height + 0.6, PENETRATE_ANGLE])
        action = np.zeros(4)
        action[0] = swing_spool(_wrap(swing_target - q[0]), qd[0])
        action[1:] = front_spools(env, target, feed)
        return action.astype(np.float32)


def run_scripted(env: HexLoadingEnv, seed: int = 0, seconds: float | None = None, frames: list | None = None) -> dict:
    """Run the scripted loader for an episode (or ``seconds``); return its measured figures.

    ``frames``: if given, a rendered frame is appended every step (the env needs a render_mode).
    A cycle is counted at each start of a dump; the cycle time is the mean time between them.
    """
    controller = ScriptedLoader()
    env.reset(seed=seed)
    controller.reset()
    terms = dict.fromkeys(REWARD_TERMS, 0.0)
    terminated = truncated = False
    while not (terminated or truncated) and (seconds is None or env.elapsed < seconds - 1e-9):
        _, _, terminated, truncated, info = env.step(controller.act(env))
        for k in terms:
            terms[k] += info[f"reward_{k}"]
        if frames is not None:
            frames.append(env.render())
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

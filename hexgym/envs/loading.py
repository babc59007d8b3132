"""``HexLoading-v0``: load a dump truck from a pile with the Cat 325-class excavator."""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from hexgym.checks import check_choice, check_path_type, check_positive
from hexgym.envs import ENV_ID
from hexgym.envs.earthwork import Pile, mouth_normal, retained_volume
from hexgym.envs.sites import MachineSites
from hexgym.envs.task import (
    CONTACT_SLOTS,
    EARTHWORK_PERIODS,
    INFO_KEYS,
    OBS_HIGH,
    OBS_LOW,
    REWARD_TERMS,
    STEP_INFO_KEYS,
    STEP_PERIOD,
    LoadingTask,
    wrap,
)
from hexgym.envs.world import (
    BED_RIM_HEIGHT,
    PILE_GRID_POINTS,
    PILE_GRID_SPACING,
    Layout,
    World,
    build_world_model,
    entry_radius,
    sample_layout,
)
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.assets import SCENE_FILE, asset_path
from hexgym.machine.bucket import BUCKET
from hexgym.machine.render import ModelMirror
from hexgym.mbl.schema import DEFAULT_TABLE_SET, TABLE_SETS
from hexgym.model.backend import backend_for, python_learned_model
from hexgym.model.base import LearnedModelBase

# s: the Python backend's table period on a scene whose step is finer than the lean machine's 25 ms (e.g. the
# full scene.xml at 2 ms); on the lean machine the tables are asked every step
PYTHON_CONTROL_PERIOD = 0.01
MAX_TIME_LIMIT = 86_400.0  # s: an episode of at most a day (a longer one is a mistake that fills memory)
START_NOISE = 0.1  # rad, uniform noise on the start pose's boom, stick and bucket angles
_HOME = np.array([0.0, 0.35, 0.85, 0.75])  # the machine's keyframe `home`: bucket curled near the ground
_MOUTH_CENTRE = np.array(BUCKET.mouth_centre)  # bucket frame, m
_SITE = np.zeros(1, np.intp)  # the single environment is site 0 of a task of one
OBSERVATION_NAMES = (
    "boom_angle", "stick_angle", "bucket_angle", "swing_to_pile", "swing_to_truck",
    "swing_rate", "boom_rate", "stick_rate", "bucket_rate",
    "boom_load", "stick_load", "bucket_load", "payload",
    "tip_pile_radial", "tip_pile_lateral", "tip_above_pile",
    "tip_truck_along", "tip_truck_across", "tip_above_rim",
    "bucket_tilt", "truck_fill", "time_left", "swing_to_cut",
)  # fmt: skip


PYTHON_SCENE = "scene_lean.xml"  # the learned model's default machine (hexgym.model.python_backend)


def make_machine(
    backend: str = "auto",
    scene_path: str | Path | None = None,
    table_set: str = DEFAULT_TABLE_SET,
    tool_contact_slots: int = 0,
) -> LearnedModelBase:
    """The machine model that drives the environment, on the loading site.

    ``"python"``: :func:`hexgym.model.backend.python_learned_model` on the lean machine (``scene_lean.xml``:
    no cylinder bodies, 25 ms step); ``"native"``: the ``hexgym.mbl`` MuJoCo plugin on
    ``cat325_mbl.xml`` (:mod:`hexgym.model.native_backend`, needs the built plugin). ``scene_path`` overrides
    the scene (e.g. the full ``scene.xml``). ``"auto"``: :func:`hexgym.model.backend.backend_for`.
    ``table_set``: the learned model's tables, "paper" or "circuit" (:mod:`hexgym.mbl.schema`).
    ``tool_contact_slots``: see :func:`hexgym.envs.world.build_world_model`.
    """
    if backend_for(table_set, backend) == "native":
        from hexgym.model.native_backend import NativeLearnedModel

        return NativeLearnedModel(model=native_world_model(scene_path, table_set, tool_contact_slots))
    model = build_world_model(
        scene_path if scene_path is not None else asset_path(PYTHON_SCENE), tool_contact_slots=tool_contact_slots
    )
    step = model.opt.timestep  # on a finer model than the lean machine's, the tables are asked every 10 ms
    period = step * max(1, round(PYTHON_CONTROL_PERIOD / step))
    return python_learned_model(table_set, model=model, control_period=period)


def native_world_model(
    scene_path: str | Path | None = None,
    table_set: str = DEFAULT_TABLE_SET,
    tool_contact_slots: int = 0,
    customise: Callable[[mujoco.MjSpec], None] | None = None,
) -> mujoco.MjModel:
    """The loading site around the lean machine driven by the native plugin with ``table_set``'s tables
    (``customise``: see :func:`hexgym.envs.world.build_world_model`)."""
    from hexgym.model.plugin import require_plugin
    from hexgym.model.plugin_mjcf import MBL_MODEL_FILE, mbl_model_xml

    require_plugin()
    if table_set == DEFAULT_TABLE_SET:  # the packaged machine file
        return build_world_model(
            scene_path, machine_file=MBL_MODEL_FILE, tool_contact_slots=tool_contact_slots, customise=customise
        )
    xml = mbl_model_xml(table_set=table_set)
    return build_world_model(scene_path, machine_xml=xml, tool_contact_slots=tool_contact_slots, customise=customise)


def _display_available() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def sample_start(rng: np.random.Generator) -> tuple[Layout, np.ndarray]:
    """An episode's random site and the machine's start angles (rad), drawn from ``rng`` in a fixed order."""
    layout = sample_layout(rng)
    between = wrap(float(layout.truck_direction - layout.pile_direction))
    q = _HOME.copy()
    q[0] = layout.pile_direction + rng.uniform(0.0, 1.0) * between
    q[1:] += rng.uniform(-START_NOISE, START_NOISE, 3)
    for i, name in enumerate(kinematics.JOINTS[1:], start=1):
        q[i] = np.clip(q[i], *kinematics.joint_range(name))
    return layout, q


DIG_START_SWING_NOISE = 0.05  # rad about the pile's direction
DIG_START_RADIUS_NOISE = 0.5  # m about the cut's entry radius
DIG_START_HEIGHT = (0.3, 1.0)  # m of the teeth above the pile's top
DIG_START_TEETH_ANGLE = (-130.0, -100.0)  # deg: the teeth's planar world direction (-90: straight down)
_TEETH_ANGLE = math.atan2(BUCKET.teeth_direction[1], BUCKET.teeth_direction[0])  # in the bucket frame
_FRONT_GUESS = np.array([0.65, -0.3, 0.0])  # boom, stick, bucket near an entry pose (the search's start)


def dig_start_pose(rng: np.random.Generator, layout: Layout) -> np.ndarray:
    """Joint angles with the empty bucket open over ``layout``'s cut entry, above the pile's top, teeth down
    (``HexDig-v0``'s start; ``HexLoading-v0``'s with ``dig_start_share``)."""
    while True:
        radius = entry_radius(layout) + rng.uniform(-DIG_START_RADIUS_NOISE, DIG_START_RADIUS_NOISE)
        height = layout.pile_height + rng.uniform(*DIG_START_HEIGHT)
        bucket = math.radians(rng.uniform(*DIG_START_TEETH_ANGLE)) - _TEETH_ANGLE
        front, miss = kinematics.front_angles_for(radius, height, bucket, _FRONT_GUESS)
        if miss < 0.05:  # within reach (always, for the layouts drawn; a miss draws again)
            swing = layout.pile_direction + rng.uniform(-DIG_START_SWING_NOISE, DIG_START_SWING_NOISE)
            return np.array([swing, *front])


LOADED_START_PAYLOAD_KG = (1000.0, 1600.0)  # within what the curled bucket holds at the start's tilt (no spill)
LOADED_START_RADIUS = (4.0, 5.5)  # m: the teeth from the swing axis (close in, where the curled bucket is level)
LOADED_START_HEIGHT = (1.4, 2.0)  # m of the teeth above the bed's rim (the curled bucket hangs below them)
LOADED_START_TILT = (-0.1, 0.3)  # rad: the mouth's normal from straight up (positive: towards the cab)
AT_TRUCK_RADIUS = (5.8, 6.6)  # m: the teeth at the bed's near wall (the opening bucket pours over it)
AT_TRUCK_HEIGHT = (1.2, 1.8)  # m above the rim
AT_TRUCK_TILT = (0.4, 0.7)  # rad: reached out, the bucket cannot be level; it holds less
AT_TRUCK_SWING = 0.1  # rad about the truck's direction
AT_TRUCK_FILL = (0.6, 0.9)  # of what the bucket holds at its tilt
LOADED_START_TRIES = 1000  # draws of a reachable pose (about one in two is)
_MOUTH_ANGLE = math.atan2(mouth_normal()[1], mouth_normal()[0])  # the mouth's normal in the bucket frame


def bucket_angle_for(teeth_world_angle: float | None = None, mouth_world_angle: float | None = None) -> float:
    """Absolute bucket-frame angle (the branch :func:`hexgym.machine.kinematics.link_angles` uses, about -4 to 0.5 rad)
    that points the teeth (or the mouth) along a planar world angle."""
    if teeth_world_angle is not None:
        angle = teeth_world_angle - _TEETH_ANGLE
    else:
        angle = float(mouth_world_angle) - _MOUTH_ANGLE
    return float((angle + 3.5) % (2 * math.pi) - 3.5)


def loaded_start_pose(rng: np.random.Generator, layout: Layout) -> tuple[np.ndarray, float]:
    """Joint angles and payload (kg) with a loaded bucket lifted clear (``HexLoading-v0``'s start with
    ``loaded_start_share``): half the starts curled mouth up, close in, anywhere on the swing from ``layout``'s
    pile to its truck (the carry to learn); half reached out to the bed's near wall, tilted, about to pour
    (the dump to learn: where opening the bucket pays at once)."""
    at_truck = rng.uniform() < 0.5
    radii, heights, tilts = (AT_TRUCK_RADIUS, AT_TRUCK_HEIGHT, AT_TRUCK_TILT) if at_truck else (
        LOADED_START_RADIUS, LOADED_START_HEIGHT, LOADED_START_TILT)  # fmt: skip
    for _ in range(LOADED_START_TRIES):
        radius, height, tilt = rng.uniform(*radii), BED_RIM_HEIGHT + rng.uniform(*heights), rng.uniform(*tilts)
        bucket = bucket_angle_for(mouth_world_angle=math.pi / 2.0 + tilt)
        front, miss = kinematics.front_angles_for(radius, height, bucket, _FRONT_GUESS)
        if miss < 0.05:  # within reach
            break
    else:
        raise RuntimeError(f"no reachable loaded start pose in {LOADED_START_TRIES} draws")
    if at_truck:
        swing = layout.truck_direction + rng.uniform(-AT_TRUCK_SWING, AT_TRUCK_SWING)
        payload = rng.uniform(*AT_TRUCK_FILL) * retained_volume(tilt) * p.MATERIAL_DENSITY
    else:
        swing = layout.pile_direction + rng.uniform(0.0, 1.0) * wrap(
            float(layout.truck_direction - layout.pile_direction)
        )
        payload = rng.uniform(*LOADED_START_PAYLOAD_KG)
    return np.array([swing, *front]), float(payload)


def heap_for(layout: Layout) -> Pile:
    """The pile an episode on ``layout`` starts with."""
    return Pile.heap(
        layout.pile_centre, layout.pile_height, layout.pile_top_radius, PILE_GRID_POINTS, PILE_GRID_SPACING
    )


def task_spaces() -> tuple[spaces.Box, spaces.Box]:
    """HexLoading-v0's observation and action spaces, without building an environment."""
    return spaces.Box(OBS_LOW, OBS_HIGH, dtype=np.float32), spaces.Box(-1.0, 1.0, (4,), np.float32)


def _is_number(value: Any) -> bool:
    """A real number (Python or NumPy), not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def check_open(env_name: str, closed: bool) -> None:
    """Refuse to use a closed environment: RuntimeError naming it (every environment's ``step`` and ``reset``)."""
    if closed:
        raise RuntimeError(f"{env_name} is closed: make a new one to go on")


def spools_from_action(action: np.ndarray) -> np.ndarray:
    """A single environment's action (swing, boom, stick, bucket spools as fractions of the stroke) as spool
    positions, m: clipped to [-1, 1] and scaled; ValueError naming the shape or the non-finite entries, TypeError
    for what is not numbers (a dict, text, None)."""
    try:
        a = np.asarray(action)
    except ValueError as exc:  # nested sequences of different lengths
        raise ValueError(f"action must be an array of 4 numbers (swing, boom, stick, bucket spools): {exc}") from None
    if a.dtype.kind not in "biuf":  # numpy makes an object or text array of a dict, text or None
        raise TypeError(
            "action must be an array of 4 numbers (swing, boom, stick, bucket spools), "
            f"got {type(action).__name__} {action!r:.60}"
        )
    a = a.astype(np.float64, copy=False)
    if a.shape != (4,):
        raise ValueError(f"action must have shape (4,) (swing, boom, stick, bucket spools), got shape {a.shape}")
    if not math.isfinite(sum(a.tolist())) and not np.isfinite(a).all():  # a NaN or inf makes the sum one
        raise ValueError(
            f"action must be finite, got {a} (a NaN or inf in entries {np.flatnonzero(~np.isfinite(a)).tolist()})"
        )
    return np.minimum(np.maximum(a, -1.0), 1.0) * p.SPOOL_STROKE  # (np.clip: slower)


MODELS = ("learned", "reference")


def _check_model(model: str, backend: str, tables: str) -> None:
    """Refuse an unknown ``model``, and learned-model options given with ``model="reference"``."""
    check_choice("model", model, MODELS)
    if model == "reference" and backend != "auto":
        raise ValueError(f"backend={backend!r} does not apply to model='reference' (it runs no learned model)")
    if model == "reference" and tables != DEFAULT_TABLE_SET:
        raise ValueError(f"tables={tables!r} does not apply to model='reference' (it runs no learned model)")


def start_machine(
    machine: LearnedModelBase, world: World, q: np.ndarray, layout: Layout, payload_kg: float = 0.0
) -> None:
    """Put ``machine`` at rest at angles ``q`` with ``payload_kg`` in its bucket on its site ``world`` laid out as
    ``layout``."""
    model, data = machine.physics.model, machine.physics.data
    mujoco.mj_resetData(model, data)  # warm starts too: same seed, same episode
    machine.reset(q, payload_kg=payload_kg)
    world.place(data, layout)
    data.qfrc_applied[:] = 0.0
    mujoco.mj_forward(model, data)


class SiteEarth:
    """The material stores of site ``i`` of a :class:`hexgym.envs.task.LoadingTask` (the single environment's
    ``earth``): its pile (a :class:`hexgym.envs.earthwork.Pile` on the task's heights) and the bucket, truck
    and spilled kilograms (settable)."""

    def __init__(self, task: LoadingTask, i: int = 0) -> None:
        self._task, self._i = task, i
        self.pile = task.pile(i)

    @property
    def bucket_kg(self) -> float:
        """Material in the bucket, kg."""
        return float(self._task.stores[self._i, 0])

    @bucket_kg.setter
    def bucket_kg(self, value: float) -> None:
        self._task.stores[self._i, 0] = value

    @property
    def truck_kg(self) -> float:
        """Material in the truck, kg."""
        return float(self._task.stores[self._i, 1])

    @property
    def spilled_kg(self) -> float:
        """Material spilled on the ground, kg."""
        return float(self._task.stores[self._i, 2])

    @property
    def pile_kg(self) -> float:
        """Material in the pile, kg."""
        return float(self._task.pile_kg()[self._i])

    def total_kg(self) -> float:
        """Pile + bucket + truck + spilled, kg: constant."""
        return self.pile_kg + self.bucket_kg + self.truck_kg + self.spilled_kg


class HexLoadingEnv(gym.Env):
    r"""Load a dump truck from a pile of sand and gravel with a 25 t hydraulic excavator.

    ## Description
    The paper's motivating task: fill the bucket from a pile, lift and swing to a truck, dump,
    return, quickly and with little fuel. The machine is the learned model of
    :mod:`hexgym.model.python_backend` (MuJoCo linkage + MBL tables of the open-centre hydraulics), so the
    functions on one pump share its flow and the engine's power limit shows. The pile is a
    heightmap: the bucket's edge cuts into it, fills at a rate set by depth and attack angle, and
    feels the fundamental earthmoving equation's resistance, which loads the cylinders
    (:mod:`hexgym.envs.earthwork`). The bucket's contents load the linkage and the swing;
    tilting past the angle of repose spills them. The truck's bed and the ground are solid.

    ## Action Space
    ``Box(-1, 1, (4,), float32)``: the four spools as fractions of their ±11 mm stroke; values
    outside [-1, 1] are clipped. A positive spool extends the cylinder.

    | Num | Action | Min | Max | Unit |
    |-----|--------|-----|-----|------|
    | 0 | swing spool (+ turns counter-clockwise seen from above) | -1 | 1 | × 11 mm |
    | 1 | boom spool (+ raises the boom) | -1 | 1 | × 11 mm |
    | 2 | stick spool (+ crowds the stick in) | -1 | 1 | × 11 mm |
    | 3 | bucket spool (+ curls the bucket closed) | -1 | 1 | × 11 mm |

    ## Observation Space
    ``Box(low, high, (23,), float32)``, clipped to generous bounds (±pi rad, ±10 rad/s, ±10 MN,
    0-5 t, ±30 m):

    | Num | Observation | Unit |
    |-----|-------------|------|
    | 0-2 | boom, stick, bucket joint angles | rad |
    | 3 | swing angle minus the pile's direction, wrapped to [-pi, pi] | rad |
    | 4 | swing angle minus the truck's direction, wrapped | rad |
    | 5-8 | swing, boom, stick, bucket joint rates | rad/s |
    | 9-11 | boom, stick, bucket cylinder force loads from the state (+ = the cylinder pushes; any model) | MN |
    | 12 | material in the bucket | t |
    | 13-14 | bucket teeth relative to the pile's centre: radial (away from the machine), lateral | m |
    | 15 | teeth height above the pile's surface below them (negative: in the pile) | m |
    | 16-17 | teeth relative to the bed's centre: along the truck, across it | m |
    | 18 | teeth height above the bed's rim | m |
    | 19 | bucket mouth's tilt from facing up (> repose angle 0.59 rad: it spills) | rad |
    | 20 | truck fill: delivered / truck capacity | 1 |
    | 21 | time left: fraction of the time budget | 1 |
    | 22 | swing angle minus the direction of the pile's fullest cut line, wrapped (see below) | rad |

    Entry 22 tells where the material still stands: of nine radial cut lines within ±0.3 rad of the
    pile's direction, across its flat top (:func:`hexgym.envs.world.fullest_cut_direction`), the one
    holding the most (ties go to the centre line). It moves as the pile is dug away; the scripted
    loader cuts along it, and a policy that did not see it could not tell which way to swing.

    ## Rewards
    Per step, the sum of the terms below, each in ``info`` as ``reward_<term>``:

    | term | value |
    |------|-------|
    | delivery | ``delivery_weight`` × tonnes that landed in the truck's bed |
    | fill | ``fill_weight`` × tonnes dug into the bucket (shaping; 0 by default) |
    | time | −``time_weight`` × 0.1 s |
    | fuel | −``fuel_weight`` × litres of diesel (actuator power → valves → pumps → engine BSFC) |
    | spill | −``spill_weight`` × tonnes spilled outside the bed |
    | contact | −``contact_weight`` × kN·s of bucket/stick contact force on ground or truck above 50 kN (to 265 kN) |
    | reach | ``reach_weight`` × the change of −(an empty bucket's teeth beyond 1 m from the pile, plus above it), m |
    | load | ``load_weight`` × the change of the tonnes in the bucket |
    | lift | ``lift_weight`` × the change of tonnes × the teeth's height above the pile (up to 1 m) |
    | carry | ``carry_weight`` × the change of tonnes × the share of the way from the pile to the bed |

    The default weights make delivered tonnes the point: a full truck (13 t) is worth +13, an episode's
    time −3.6, its fuel about −0.4. The four shaping terms (0 by default) are potential-based (Ng et al.
    1999): each is the change of a function of the state (:func:`hexgym.envs.task.potentials`), so over an
    episode it sums to that function's end value less its start value and cannot be farmed by going back
    and forth; they lead an exploring policy from the pile to a loaded lift and on to the truck long before
    its first delivery pays. Keep ``load_weight + lift_weight + carry_weight`` below ``delivery_weight``:
    emptying the bucket over the bed drops those potentials, and the delivery must pay more than they lose.

    ## Starting State
    A random site (seeded ``np_random``): the pile 7.0-7.8 m ahead within ±10°, 1.3-1.6 m high;
    the truck 6.6-7.4 m away at 70-110° to either side, parked broadside. The machine starts at
    rest with an empty bucket near the `home` pose (boom, stick, bucket ±0.1 rad) with its swing
    anywhere between the pile and the truck.

    ## Episode End
    Terminates when the truck holds ``truck_capacity_kg``; truncates after ``time_limit`` s
    (the environment truncates itself; ``gymnasium.make`` adds no TimeLimit).

    ## Arguments
    | argument | default | meaning |
    |----------|---------|---------|
    | render_mode | None | ``"rgb_array"``, ``"depth_array"`` (metric depth, m) or ``"human"`` (needs a display) |
    | camera | ``"chase"`` | ``"chase"`` (the scene's) or ``"cab"`` (operator's view) |
    | width, height | 640, 384 | frame size in pixels |
    | time_limit | 180.0 | episode length, s |
    | truck_capacity_kg | 13000.0 | payload that ends the episode |
    | delivery_weight | 1.0 | per tonne delivered |
    | fill_weight | 0.0 | per tonne dug |
    | time_weight | 0.02 | per second |
    | fuel_weight | 0.5 | per litre |
    | spill_weight | 2.0 | per tonne spilled |
    | contact_weight | 0.01 | per kN·s of hard contact |
    | reach_weight, load_weight, lift_weight, carry_weight | 0.0 | the shaping terms (e.g. 0.05, 0.3, 0.2, 0.3) |
    | scene_path | None | MJCF scene to build the site on (default ``scene_lean.xml``; reference: ``scene.xml``) |
    | backend | ``"auto"`` | ``"native"`` (MuJoCo plugin), ``"python"`` (LearnedModel), ``"auto"`` (native if built) |
    | earthwork_periods | 4 | control periods (25 ms) per dig (fill, pile cut, spill) near the pile; 1: every period |
    | tables | ``"circuit"`` | the learned model: ``"circuit"`` (the circuit model) or ``"paper"`` (the paper's model) |
    | model | ``"learned"`` | ``"reference"``: the same task on the analytical circuit (the real machine's stand-in) |
    | dig_start_share | 0.0 | share of episodes starting with the open bucket over the pile (a curriculum) |
    | loaded_start_share | 0.0 | share starting loaded: curled between pile and truck, or reached out to the truck |

    ``model="reference"`` runs the whole task on the reference model (:mod:`hexgym.envs.reference_machine`):
    a few times real time, for checking what was learned on the fast model, not for training.

    Metadata: ``render_fps`` = 10, the control rate.
    """

    metadata = {
        # "human" (a window) only where a display exists; offscreen modes everywhere (MUJOCO_GL=egl)
        "render_modes": ["rgb_array", "depth_array"] + (["human"] if _display_available() else []),
        "render_fps": round(1.0 / STEP_PERIOD),
    }
    env_id = ENV_ID  # what errors call it
    closed = False  # set by close()

    def __init__(
        self,
        render_mode: str | None = None,
        camera: str = "chase",
        width: int = 640,
        height: int = 384,
        time_limit: float = 180.0,
        truck_capacity_kg: float = p.TRUCK_CAPACITY,
        delivery_weight: float = 1.0,
        fill_weight: float = 0.0,
        time_weight: float = 0.02,
        fuel_weight: float = 0.5,
        spill_weight: float = 2.0,
        contact_weight: float = 0.01,
        reach_weight: float = 0.0,
        load_weight: float = 0.0,
        lift_weight: float = 0.0,
        carry_weight: float = 0.0,
        scene_path: str | Path | None = None,
        backend: str = "auto",
        earthwork_periods: int = EARTHWORK_PERIODS,
        tables: str = DEFAULT_TABLE_SET,
        model: str = "learned",
        dig_start_share: float = 0.0,
        loaded_start_share: float = 0.0,
    ) -> None:
        _check_model(model, backend, tables)
        for name, share in (("dig_start_share", dig_start_share), ("loaded_start_share", loaded_start_share)):
            if not _is_number(share) or not 0.0 <= share <= 1.0:
                raise ValueError(f"{name} must be a number from 0 to 1, got {share!r}")
        if dig_start_share + loaded_start_share > 1.0:
            raise ValueError(
                f"dig_start_share + loaded_start_share must be at most 1, got {dig_start_share} + {loaded_start_share}"
            )
        self.dig_start_share, self.loaded_start_share = float(dig_start_share), float(loaded_start_share)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            why = " ('human' needs a display: DISPLAY is unset)" if render_mode == "human" else ""
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}{why}"
            )
        if camera not in ("chase", "cab"):
            raise ValueError(f"camera must be 'chase' or 'cab', got {camera!r}")
        if isinstance(earthwork_periods, bool) or not isinstance(earthwork_periods, int) or earthwork_periods < 1:
            raise ValueError(f"earthwork_periods must be an integer >= 1, got {earthwork_periods!r}")
        self.earthwork_periods = earthwork_periods
        time_limit = check_positive("time_limit", time_limit, "s")
        truck_capacity_kg = check_positive("truck_capacity_kg", truck_capacity_kg, "kg")
        if time_limit > MAX_TIME_LIMIT:
            raise ValueError(f"time_limit must be at most {MAX_TIME_LIMIT:.0f} s (a day), got {time_limit}")
        for name, size in (("width", width), ("height", height)):
            if not _is_number(size) or int(size) != size or size < 1:
                raise ValueError(f"{name} must be a whole number of pixels >= 1, got {size!r}")
        self.render_mode, self.camera, self.width, self.height = render_mode, camera, int(width), int(height)
        self.time_limit, self.truck_capacity_kg = float(time_limit), float(truck_capacity_kg)
        self.weights = {
            "delivery": delivery_weight, "fill": fill_weight, "time": time_weight,
            "fuel": fuel_weight, "spill": spill_weight, "contact": contact_weight, "reach": reach_weight,
            "load": load_weight, "lift": lift_weight, "carry": carry_weight,
        }  # fmt: skip
        for name, weight in self.weights.items():
            if not _is_number(weight) or not math.isfinite(weight):
                raise ValueError(f"{name}_weight must be a finite number, got {weight!r}")
        check_choice("tables", tables, TABLE_SETS)
        if scene_path is not None:
            check_path_type("scene_path", scene_path)
        if model == "learned":
            backend_for(tables, backend)  # a set the plugin does not run, with backend "native": refused here
        self._scene_path, self._backend, self.tables = scene_path, backend, tables
        self.machine_model = model  # "learned" or "reference" (``model`` is MuJoCo's in Gymnasium's envs)
        self.observation_space, self.action_space = task_spaces()
        self._build()
        frame = self.physics.model.vis.global_
        offscreen = render_mode in ("rgb_array", "depth_array")
        if offscreen and (self.width > frame.offwidth or self.height > frame.offheight):
            raise ValueError(
                f"frames of {self.width} x {self.height} pixels exceed the scene's offscreen buffer "
                f"({frame.offwidth} x {frame.offheight})"
            )
        self.layout: Layout | None = None
        self.earth: SiteEarth | None = None

    # -- simulation ----------------------------------------------------------------------------
    def _build(self) -> None:
        if self.machine_model == "reference":
            from hexgym.envs.reference_machine import ReferenceMachine, reference_world_model

            self.machine = ReferenceMachine(reference_world_model(self._scene_path, tool_contact_slots=CONTACT_SLOTS))
        else:
            self.machine = make_machine(self._backend, self._scene_path, self.tables, tool_contact_slots=CONTACT_SLOTS)
        self.physics = self.machine.physics
        model = self.physics.model
        self.world = World(model)
        self._site = MachineSites([self.machine])
        self.task = LoadingTask(
            1, self._site, self.machine.control_period, self.time_limit, self.truck_capacity_kg, self.weights,
            self.earthwork_periods,
        )  # fmt: skip
        self._period, self._periods = self.task.period, self.task.periods
        self._bucket_body, self._tip_site = self._site.bucket_body, self._site.tip_site
        self._renderer: Any = None
        self._view: tuple[mujoco.MjModel, mujoco.MjData, ModelMirror] | None = None  # see _render_view
        self._pile_shown = -1  # the pile revision the renderer's copy of the hfield shows

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Start an episode on a new random site (see the class docstring)."""
        check_open(self.env_id, self.closed)
        super().reset(seed=seed)
        self.layout, q, payload_kg = self._draw_start(self.np_random)
        pile = heap_for(self.layout)
        self.start_machine(q, self.layout, payload_kg)
        self.task.start(0, self.layout, pile, self.physics.payload_kg)
        self.task.finish_starts(_SITE)
        self.earth = SiteEarth(self.task)
        self.world.show_pile(pile.heights)
        self._pile_shown = -1
        return self.task.observe(_SITE)[0], self._info(None, 0.0, 0.0)

    def _draw_start(self, rng: np.random.Generator) -> tuple[Layout, np.ndarray, float]:
        """An episode's site, the machine's start angles and payload (kg): :func:`sample_start` with an empty
        bucket, or with probability ``dig_start_share`` :func:`dig_start_pose`, with ``loaded_start_share``
        :func:`loaded_start_pose` on its site (a task with another start overrides this)."""
        layout, q = sample_start(rng)
        if self.dig_start_share + self.loaded_start_share > 0.0:  # no draw at the defaults
            draw = rng.uniform()
            if draw < self.dig_start_share:
                return layout, dig_start_pose(rng, layout), 0.0
            if draw < self.dig_start_share + self.loaded_start_share:
                return layout, *loaded_start_pose(rng, layout)
        return layout, q, 0.0

    def start_machine(self, q: np.ndarray, layout: Layout, payload_kg: float = 0.0) -> None:
        """Put the machine at rest at angles ``q`` with ``payload_kg`` in the bucket on a site laid out as
        ``layout`` (the simulation part of :meth:`reset`; the batched environment starts its machines through it)."""
        start_machine(self.machine, self.world, q, layout, payload_kg)

    @property
    def fuel_l(self) -> float:
        """Diesel burnt this episode, L."""
        return float(self.task.fuel_l[0])

    @property
    def steps(self) -> int:
        """Steps taken this episode."""
        return int(self.task.steps[0])

    @property
    def elapsed(self) -> float:
        """Simulated seconds this episode."""
        return float(self.task.elapsed[0])

    def mouth_position(self) -> np.ndarray:
        """Centre of the bucket's mouth (where its contents pour from), world m."""
        d = self.physics.data
        return d.xpos[self._bucket_body] + d.xmat[self._bucket_body].reshape(3, 3) @ _MOUTH_CENTRE

    def fullest_cut_direction(self) -> float:
        """Swing angle (rad) of the pile's cut line with the most material (:func:`world.fullest_cut_direction`),
        recomputed only when the pile has changed."""
        self.task.update_cut_directions(_SITE)
        return float(self.task.cut_dir[0])

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Hold the spools for 0.1 s (several control periods of the machine model)."""
        check_open(self.env_id, self.closed)
        if self.earth is None:
            raise RuntimeError("call reset() before step()")
        self._site.spools_m[0] = spools_from_action(action)
        task = self.task
        terms, rewards, ended = task.step(_SITE)
        obs = task.observe(_SITE)[0]
        info = self._info(terms[0].tolist(), float(task.step_fuel_l[0]), float(task.step_impulse[0]))
        if self.render_mode == "human":
            self.render()
        return obs, float(rewards[0]), bool(ended[0, 0]), bool(ended[0, 1]), info

    def _clear_periods(self) -> int:
        """Control periods (up to a step's) within which the teeth surely stay out of the pile
        (:func:`hexgym.envs.task.clear_count`)."""
        return int(self.task.clear_periods_of(_SITE)[0])

    def _hard_contact_force(self) -> float:
        """Bucket and stick contact force on the ground and the truck beyond HARD_CONTACT_FORCE (capped), N
        (:func:`hexgym.envs.task.hard_contact_force`)."""
        return float(self.task.hard_contact_forces(_SITE)[0])

    def _info(self, terms: list[float] | None, fuel_step: float, impulse: float) -> dict[str, Any]:
        """The step's ``info``: the reward terms (0 after a reset), the stores, and the step's fuel and impulse."""
        stores = self.task.stores_of(_SITE)[0].tolist()
        if terms is None:
            return dict(zip(INFO_KEYS, [0.0] * len(REWARD_TERMS) + stores, strict=True))
        return dict(zip(STEP_INFO_KEYS, [*terms, *stores, fuel_step, impulse], strict=True))

    # -- rendering ----------------------------------------------------------------------------
    def render(self) -> np.ndarray | None:
        """A frame from ``camera`` (rgb_array: uint8 H x W x 3; depth_array: float32 H x W, m) or a window."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode to gymnasium.make")
            return None
        if self.earth is None:
            raise RuntimeError("call reset() before render()")
        self.world.show_loads(self.earth.truck_kg, self.earth.bucket_kg)
        self.world.aim_camera(self.layout, self.width / self.height)
        if self._pile_shown != self.task.revision[0]:
            self.world.show_pile(self.earth.pile.heights)
            self._pile_shown = int(self.task.revision[0])
        model, data, mirror = self._render_view()
        changed = mirror.sync(self.physics.data, data)
        if self.render_mode == "human":
            return self._render_window(model, data, changed)
        if self._renderer is None:  # a new context uploads the present heightfield itself
            self._renderer = mujoco.Renderer(model, height=self.height, width=self.width)
            if self.render_mode == "depth_array":
                self._renderer.enable_depth_rendering()
        else:  # the renderer keeps its own copy of the hfield on the GPU side (private context attribute)
            for hfield in changed:
                mujoco.mjr_uploadHField(model, self._renderer._mjr_context, hfield)
        self._renderer.update_scene(data, camera=self.camera)
        return self._renderer.render().copy()

    def _render_view(self) -> tuple[mujoco.MjModel, mujoco.MjData, ModelMirror]:
        """The site around the full machine, posed like the simulation: pictures show cylinders and links.

        The simulation runs on the lean machine (no cylinder or four-bar bodies); frames are drawn
        from the full one (``scene.xml``) mirrored to it (:class:`hexgym.machine.render.ModelMirror`).
        """
        if self._view is None:
            model = build_world_model(asset_path(SCENE_FILE))
            self._view = (model, mujoco.MjData(model), ModelMirror(self.physics.model, model))
        return self._view

    def _render_window(self, model: mujoco.MjModel, data: mujoco.MjData, changed: list[int]) -> None:
        if self._renderer is None:
            from gymnasium.envs.mujoco.mujoco_rendering import MujocoRenderer

            self._renderer = MujocoRenderer(model, data, width=self.width, height=self.height, camera_name=self.camera)
        viewer = self._renderer._get_viewer("human")
        for hfield in changed:
            mujoco.mjr_uploadHField(model, viewer.con, hfield)
        self._renderer.render("human")
        return None

    def close(self) -> None:
        """Release the renderer's OpenGL context; ``step`` and ``reset`` are refused after it (closing again is
        harmless)."""
        self.closed = True
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # -- pickling: everything but the renderer ----------------------------------------------
    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_renderer"] = None
        state["_view"] = None
        state["_pile_shown"] = -1
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)

"""``HexLoading-v0``: load a dump truck from a pile with the Cat 325-class excavator.

:class:`HexLoadingEnv` is a task over the site base (:class:`hexgym.envs.base.SiteEnv`) with its frozen
:class:`LoadingConfig`; its starts (:func:`draw_loading_start`: the plain start, and the dig and loaded starts of
the curriculum) are drawn by the batched environment too (:mod:`hexgym.envs.vector`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from hexgym.checks import check_choice, check_positive, check_range
from hexgym.envs import ENV_ID
from hexgym.envs.base import SiteConfig, SiteEnv, SiteRules, is_number, task_spaces
from hexgym.envs.earthwork import mouth_normal, retained_volume
from hexgym.envs.sites import make_machine, native_world_model
from hexgym.envs.task import REWARD_TERMS, STEP_PERIOD, SiteStart, wrap
from hexgym.envs.world import BED_RIM_HEIGHT, SITE_RANGES, Layout, entry_radius, heap_for, sample_layout
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.bucket import BUCKET
from hexgym.mbl.schema import CIRCUIT_TABLE_SETS
from hexgym.mbl.table import model_hydraulics

if TYPE_CHECKING:
    from hexgym.hydraulics.overrides import HydraulicsOverrides

# what other modules take from here, defined in the modules the environment is built of
__all__ = [
    "OBSERVATION_NAMES", "REWARD_TERMS", "STEP_PERIOD", "HexLoadingEnv", "LoadingConfig", "bucket_angle_for",
    "dig_start_pose", "draw_loading_start", "heap_for", "loaded_start_pose", "make_machine", "native_world_model",
    "sample_start", "task_spaces",
]  # fmt: skip

ENGINE_POWER_SCALE_RANGE = (0.5, 1.0)  # engine_power_scale: from half the rated power to all of it
START_NOISE = 0.1  # rad, uniform noise on the start pose's boom, stick and bucket angles
_HOME = np.array([0.0, 0.35, 0.85, 0.75])  # the machine's keyframe `home`: bucket curled near the ground
OBSERVATION_NAMES = (
    "boom_angle", "stick_angle", "bucket_angle", "swing_to_pile", "swing_to_truck",
    "swing_rate", "boom_rate", "stick_rate", "bucket_rate",
    "boom_load", "stick_load", "bucket_load", "payload",
    "tip_pile_radial", "tip_pile_lateral", "tip_above_pile",
    "tip_truck_along", "tip_truck_across", "tip_above_rim",
    "bucket_tilt", "truck_fill", "time_left", "swing_to_cut",
)  # fmt: skip


def sample_start(rng: np.random.Generator, site_ranges: str = "training") -> tuple[Layout, np.ndarray]:
    """An episode's random site (:func:`hexgym.envs.world.sample_layout` from ``site_ranges``) and the machine's
    start angles (rad), drawn from ``rng`` in a fixed order."""
    layout = sample_layout(rng, site_ranges)
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


def loaded_start_pose(
    rng: np.random.Generator, layout: Layout, density: float = p.MATERIAL_DENSITY
) -> tuple[np.ndarray, float]:
    """Joint angles and payload (kg) with a loaded bucket lifted clear (``HexLoading-v0``'s start with
    ``loaded_start_share``): half the starts curled mouth up, close in, anywhere on the swing from ``layout``'s
    pile to its truck (the carry to learn); half reached out to the bed's near wall, tilted, about to pour
    (the dump to learn: where opening the bucket pays at once). ``density``: the material's, kg/m^3."""
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
        payload = rng.uniform(*AT_TRUCK_FILL) * retained_volume(tilt) * density
    else:
        swing = layout.pile_direction + rng.uniform(0.0, 1.0) * wrap(
            float(layout.truck_direction - layout.pile_direction)
        )
        payload = rng.uniform(*LOADED_START_PAYLOAD_KG)
    return np.array([swing, *front]), float(payload)


@dataclass(frozen=True)
class LoadingConfig(SiteConfig):
    """``HexLoading-v0``'s configuration: the site's (:class:`hexgym.envs.base.SiteConfig`), the truck, the
    reward terms' weights and the start curriculum (see :class:`HexLoadingEnv`'s Arguments). Frozen; checked once
    when made."""

    truck_capacity_kg: float = p.TRUCK_CAPACITY
    delivery_weight: float = 1.0
    fill_weight: float = 0.0
    time_weight: float = 0.02
    fuel_weight: float = 0.5
    spill_weight: float = 2.0
    contact_weight: float = 0.01
    reach_weight: float = 0.0
    load_weight: float = 0.0
    lift_weight: float = 0.0
    carry_weight: float = 0.0
    dig_start_share: float = 0.0
    loaded_start_share: float = 0.0
    site_ranges: str = "training"
    material_density_scale: float = 1.0
    engine_power_scale: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        check_choice("site_ranges", self.site_ranges, SITE_RANGES)
        lo, hi = p.MATERIAL_DENSITY_SCALE_RANGE
        self._set("material_density_scale", check_range("material_density_scale", self.material_density_scale, lo, hi))
        lo, hi = ENGINE_POWER_SCALE_RANGE
        self._set("engine_power_scale", check_range("engine_power_scale", self.engine_power_scale, lo, hi))
        if self.engine_power_scale != 1.0 and self.model == "learned" and self.table_set not in CIRCUIT_TABLE_SETS:
            raise ValueError(
                f"engine_power_scale={self.engine_power_scale!r} does not apply to tables={self.tables!r}: the "
                "paper's tables hold the pumps' power limit in their data (use the circuit model)"
            )
        for name in ("dig_start_share", "loaded_start_share"):
            share = getattr(self, name)
            if not is_number(share) or not 0.0 <= share <= 1.0:
                raise ValueError(f"{name} must be a number from 0 to 1, got {share!r}")
            self._set(name, float(share))
        if self.dig_start_share + self.loaded_start_share > 1.0:
            raise ValueError(
                f"dig_start_share + loaded_start_share must be at most 1, got {self.dig_start_share} + "
                f"{self.loaded_start_share}"
            )
        self._set("truck_capacity_kg", check_positive("truck_capacity_kg", self.truck_capacity_kg, "kg"))
        for term in REWARD_TERMS:
            weight = getattr(self, f"{term}_weight")
            if not is_number(weight) or not math.isfinite(weight):
                raise ValueError(f"{term}_weight must be a finite number, got {weight!r}")

    @property
    def material_density(self) -> float:
        """The pile's material, kg/m^3: ``MATERIAL_DENSITY`` times ``material_density_scale``."""
        return float(p.MATERIAL_DENSITY) * self.material_density_scale

    @property
    def engine_power_w(self) -> float:
        """The engine's power, W: ``ENGINE_POWER`` times ``engine_power_scale``."""
        return float(p.ENGINE_POWER) * self.engine_power_scale

    def hydraulics(self) -> HydraulicsOverrides | None:
        """With ``engine_power_scale`` below 1, the circuit with the weaker engine's pump power limit
        (:func:`hexgym.hydraulics.overrides.with_engine_power`, over a fitted model's own pumps); else None."""
        if self.engine_power_scale == 1.0:
            return None
        from hexgym.hydraulics.overrides import with_engine_power

        own = model_hydraulics(self.tables_dir) if self.model == "learned" else None
        return with_engine_power(own, self.engine_power_scale)

    @property
    def weights(self) -> dict[str, float]:
        """The reward terms' weights by term (``REWARD_TERMS``)."""
        return {term: getattr(self, f"{term}_weight") for term in REWARD_TERMS}

    def site_rules(self) -> SiteRules:
        """The loading task counts this task's reward: its terms weighted as configured."""
        return SiteRules(self.time_limit, self.truck_capacity_kg, self.weights)


def draw_loading_start(rng: np.random.Generator, config: LoadingConfig) -> SiteStart:
    """A ``HexLoading-v0`` episode's start: :func:`sample_start` with an empty bucket, or with probability
    ``dig_start_share`` :func:`dig_start_pose`, with ``loaded_start_share`` :func:`loaded_start_pose` on its site;
    drawn from ``rng`` in a fixed order."""
    layout, q = sample_start(rng, config.site_ranges)
    dig, loaded = config.dig_start_share, config.loaded_start_share
    if dig + loaded > 0.0:  # no draw at the defaults
        draw = rng.uniform()
        if draw < dig:
            return SiteStart(layout, dig_start_pose(rng, layout), 0.0)
        if draw < dig + loaded:
            return SiteStart(layout, *loaded_start_pose(rng, layout, config.material_density))
    return SiteStart(layout, q, 0.0)


class HexLoadingEnv(SiteEnv):
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
    Keyword arguments (``gymnasium.make("HexLoading-v0", **kwargs)``) or a :class:`LoadingConfig` with overrides:

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
    | site_ranges | ``"training"`` | ``"shifted"``: the pile and truck just outside those ranges (``sample_layout``) |
    | material_density_scale | 1.0 | the material's density times this (0.5-1.5): heavier loads, harder digging |
    | engine_power_scale | 1.0 | the engine's power times this (0.5-1): the pumps' power limit follows |

    ``model="reference"`` runs the whole task on the reference model (:mod:`hexgym.envs.reference_machine`):
    a few times real time, for checking what was learned on the fast model, not for training.

    Metadata: ``render_fps`` = 10, the control rate.

    ## Version History
    * v0: the loading task, its shaping terms and start curriculum (``dig_start_share``, ``loaded_start_share``), and
      its off-nominal conditions (``site_ranges``, ``material_density_scale``, ``engine_power_scale``).
    """

    env_id = ENV_ID
    config_type = LoadingConfig
    config: LoadingConfig

    def draw_start(self, rng: np.random.Generator) -> SiteStart:
        """An episode's start (:func:`draw_loading_start`)."""
        return draw_loading_start(rng, self.config)

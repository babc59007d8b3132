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

from hexgym.envs.earthwork import Earthwork, Pile, mouth_normal
from hexgym.envs.world import (
    BED_RIM_HEIGHT,
    PILE_GRID_POINTS,
    PILE_GRID_SPACING,
    Layout,
    World,
    bed_coordinates,
    build_world_model,
    fullest_cut_direction,
    sample_layout,
)
from hexgym.hydraulics import fuel
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.assets import SCENE_FILE, asset_path
from hexgym.machine.render import ModelMirror
from hexgym.mbl.schema import DEFAULT_TABLE_SET, TABLE_SETS
from hexgym.mbl.table import load_tables
from hexgym.model.backend import resolve_backend
from hexgym.model.base import LearnedModelBase
from hexgym.model.python_backend import LearnedModel

# s: the Python backend's table period on a scene whose step is finer than the lean machine's 25 ms (e.g. the
# full scene.xml at 2 ms); on the lean machine the tables are asked every step
PYTHON_CONTROL_PERIOD = 0.01
STEP_PERIOD = 0.1  # s: one environment step, 10 Hz, an operator's reaction time scale
MAX_TIME_LIMIT = 86_400.0  # s: an episode of at most a day (a longer one is a mistake that fills memory)
# Control periods per dig (fill, pile cut and relaxation, spill) while the teeth may be in the pile: 4 = once
# per 0.1 s step (fast; the digging force still follows the motion every period; `hexgym scripted` results
# stay within 1 % of digging every period, see README), 1 = every 25 ms period.
EARTHWORK_PERIODS = 4
# Control periods between re-aims of the digging force while the edge cuts: 2 is ~15 % faster on random actions
# but the scripted loader's first curl stalls 2.9 s instead of 4.0 s and it delivers up to 2.3 % less (README)
FORCE_PERIODS = 1
PAYLOAD_UPDATE_KG = 20.0  # re-mass the bucket only on changes this large (1 % of a heaped bucket): mj_setConst is slow
_PILE_MARGIN = 0.6  # m: the teeth travel at most this far in one step (6 m/s), so cannot reach a pile lower by more
START_NOISE = 0.1  # rad, uniform noise on the start pose's boom, stick and bucket angles
_HOME = np.array([0.0, 0.35, 0.85, 0.75])  # the machine's keyframe `home`: bucket curled near the ground
# bucket-frame (x, z) of the teeth's direction and the mouth's normal (both have y = 0), as floats
_TEETH_X, _TEETH_Z = (float(v) for v in p.BUCKET_TEETH_DIRECTION)
_MOUTH_NORMAL_X, _MOUTH_NORMAL_Z = mouth_normal().tolist()
_MOUTH_CENTRE = np.array([(p.BUCKET_LIP[0] + p.BUCKET_EDGE[0]) / 2, 0.0, (p.BUCKET_LIP[1] + p.BUCKET_EDGE[1]) / 2])
REWARD_TERMS = ("delivery", "fill", "time", "fuel", "spill", "contact")
OBSERVATION_NAMES = (
    "boom_angle", "stick_angle", "bucket_angle", "swing_to_pile", "swing_to_truck",
    "swing_rate", "boom_rate", "stick_rate", "bucket_rate",
    "boom_load", "stick_load", "bucket_load", "payload",
    "tip_pile_radial", "tip_pile_lateral", "tip_above_pile",
    "tip_truck_along", "tip_truck_across", "tip_above_rim",
    "bucket_tilt", "truck_fill", "time_left", "swing_to_cut",
)  # fmt: skip
# Bounds (observations are clipped to them): angles, rates (rad/s) well beyond the servos' ranges,
# loads (MN) beyond the reliefs' forces, a bucket's load (t), the site's extent (m)
_OBS_HIGH = np.array([np.pi] * 5 + [10.0] * 4 + [10.0] * 3 + [5.0] + [30.0] * 6 + [np.pi, 2.0, 1.0, np.pi], np.float32)
_OBS_LOW = np.array(
    [-np.pi] * 5 + [-10.0] * 4 + [-10.0] * 3 + [0.0] + [-30.0] * 6 + [0.0, 0.0, 0.0, -np.pi], np.float32
)
_CLIP_LOW, _CLIP_HIGH = _OBS_LOW.astype(float), _OBS_HIGH.astype(float)  # the bounds as float64: clip before casting


PYTHON_SCENE = "scene_lean.xml"  # the learned model's default machine (hexgym.model.python_backend)


def make_machine(
    backend: str = "auto", scene_path: str | Path | None = None, table_set: str = DEFAULT_TABLE_SET
) -> LearnedModelBase:
    """The machine model that drives the environment, on the loading site.

    ``"python"``: :class:`hexgym.model.python_backend.LearnedModel` on the lean machine (``scene_lean.xml``:
    no cylinder bodies, 25 ms step); ``"native"``: the ``hexgym.mbl`` MuJoCo plugin on
    ``cat325_mbl.xml`` (:mod:`hexgym.model.native_backend`, needs the built plugin). ``scene_path`` overrides
    the scene (e.g. the full ``scene.xml``). ``"auto"``: :func:`hexgym.model.backend.resolve_backend`.
    ``table_set``: the learned model's tables, "extended" or "paper" (:mod:`hexgym.mbl.schema`).
    """
    backend = resolve_backend(backend)
    if backend == "native":
        from hexgym.model.native_backend import NativeLearnedModel

        return NativeLearnedModel(model=native_world_model(scene_path, table_set))
    model = build_world_model(scene_path if scene_path is not None else asset_path(PYTHON_SCENE))
    step = model.opt.timestep  # on a finer model than the lean machine's, the tables are asked every 10 ms
    tables = load_tables(table_set=table_set)
    return LearnedModel(tables, model=model, control_period=step * max(1, round(PYTHON_CONTROL_PERIOD / step)))


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


def _servo_bands(model: mujoco.MjModel) -> tuple[np.ndarray, ...]:
    """Per integrated-velocity servo: act, qpos and dof addresses, kv/kp, and forcerange/kp.

    Its force ``kp (act - q) - kv qd`` is within ``forcerange`` while ``act`` is within
    ``q + kv/kp qd +- forcerange/kp``.
    """
    servos = [
        i
        for i in range(model.nu)
        if model.actuator_plugin[i] < 0
        and model.actuator_dyntype[i] == mujoco.mjtDyn.mjDYN_INTEGRATOR
        and model.actuator_biastype[i] == mujoco.mjtBias.mjBIAS_AFFINE
    ]  # integrated-velocity servos (a plugin actuator keeps its own state)
    joints = model.actuator_trnid[servos, 0]
    kp = model.actuator_gainprm[servos, 0]
    kv = -model.actuator_biasprm[servos, 2]
    return (
        model.actuator_actadr[servos],
        model.jnt_qposadr[joints],
        model.jnt_dofadr[joints],
        kv / kp,
        model.actuator_forcerange[servos, 1] / kp,
    )


def _wrap(angle: float) -> float:
    return wrap_angle(float(angle))


def wrap_angle(angle: np.ndarray | float) -> np.ndarray | float:
    """Angle(s) wrapped to [-pi, pi) (floats or arrays: numpy's % is Python's for floats)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def sample_start(rng: np.random.Generator) -> tuple[Layout, np.ndarray]:
    """An episode's random site and the machine's start angles (rad), drawn from ``rng`` in a fixed order."""
    layout = sample_layout(rng)
    between = _wrap(layout.truck_direction - layout.pile_direction)
    q = _HOME.copy()
    q[0] = layout.pile_direction + rng.uniform(0.0, 1.0) * between
    q[1:] += rng.uniform(-START_NOISE, START_NOISE, 3)
    for i, name in enumerate(kinematics.JOINTS[1:], start=1):
        q[i] = np.clip(q[i], *kinematics.joint_range(name))
    return layout, q


def heap_for(layout: Layout) -> Pile:
    """The pile an episode on ``layout`` starts with."""
    return Pile.heap(
        layout.pile_centre, layout.pile_height, layout.pile_top_radius, PILE_GRID_POINTS, PILE_GRID_SPACING
    )


def task_spaces() -> tuple[spaces.Box, spaces.Box]:
    """HexLoading-v0's observation and action spaces, without building an environment."""
    return spaces.Box(_OBS_LOW, _OBS_HIGH, dtype=np.float32), spaces.Box(-1.0, 1.0, (4,), np.float32)


def _is_number(value: Any) -> bool:
    """A real number (Python or NumPy), not a bool."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


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
    | 9-11 | boom, stick, bucket cylinder force loads (+ = the cylinder pushes) | MN |
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
    | scene_path | None | MJCF scene to build the site on (default: the lean machine's ``scene_lean.xml``) |
    | backend | ``"auto"`` | ``"native"`` (MuJoCo plugin), ``"python"`` (LearnedModel), ``"auto"`` (native if built) |
    | earthwork_periods | 4 | control periods (25 ms) per dig (fill, pile cut, spill) near the pile; 1: every period |
    | tables | ``"paper"`` | the learned model's tables: ``"paper"`` (the paper's four) or ``"extended"`` (both pumps) |

    Metadata: ``render_fps`` = 10, the control rate.
    """

    metadata = {
        # "human" (a window) only where a display exists; offscreen modes everywhere (MUJOCO_GL=egl)
        "render_modes": ["rgb_array", "depth_array"] + (["human"] if _display_available() else []),
        "render_fps": round(1.0 / STEP_PERIOD),
    }

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
        scene_path: str | Path | None = None,
        backend: str = "auto",
        earthwork_periods: int = EARTHWORK_PERIODS,
        tables: str = DEFAULT_TABLE_SET,
    ) -> None:
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
        if not (math.isfinite(time_limit) and time_limit > 0 and math.isfinite(truck_capacity_kg)
                and truck_capacity_kg > 0):  # fmt: skip
            raise ValueError(
                f"time_limit and truck_capacity_kg must be finite and > 0, got {time_limit}, {truck_capacity_kg}"
            )
        if time_limit > MAX_TIME_LIMIT:
            raise ValueError(f"time_limit must be at most {MAX_TIME_LIMIT:.0f} s (a day), got {time_limit}")
        for name, size in (("width", width), ("height", height)):
            if not _is_number(size) or int(size) != size or size < 1:
                raise ValueError(f"{name} must be a whole number of pixels >= 1, got {size!r}")
        self.render_mode, self.camera, self.width, self.height = render_mode, camera, int(width), int(height)
        self.time_limit, self.truck_capacity_kg = float(time_limit), float(truck_capacity_kg)
        self.weights = {
            "delivery": delivery_weight, "fill": fill_weight, "time": time_weight,
            "fuel": fuel_weight, "spill": spill_weight, "contact": contact_weight,
        }  # fmt: skip
        for name, weight in self.weights.items():
            if not _is_number(weight) or not math.isfinite(weight):
                raise ValueError(f"{name}_weight must be a finite number, got {weight!r}")
        if tables not in TABLE_SETS:
            raise ValueError(f"tables must be one of {tuple(TABLE_SETS)}, got {tables!r}")
        self._scene_path, self._backend, self.tables = scene_path, backend, tables
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
        self.earth: Earthwork | None = None

    # -- simulation ----------------------------------------------------------------------------
    def _build(self) -> None:
        self.machine = make_machine(self._backend, self._scene_path, self.tables)
        self.physics = self.machine.physics
        model = self.physics.model
        self._period = self.machine.control_period  # s, one control period of the machine model
        self._periods = int(round(STEP_PERIOD / self._period))
        if abs(self._periods * self._period - STEP_PERIOD) > 1e-9:
            raise ValueError(f"the machine's control period {self._period} s does not divide the step {STEP_PERIOD} s")
        self._velocity_blend = 1.0 - np.exp(-self._period / p.DIG_VELOCITY_FILTER)
        self.world = World(model)
        self._bucket_body = model.body("bucket").id
        self._tip_site = model.site("tip").id
        self._servo_bands = _servo_bands(model)
        self._tool_geoms, self._obstacle_geoms = self.world.tool_geoms.tolist(), self.world.obstacle_geoms.tolist()
        self._renderer: Any = None
        self._view: tuple[mujoco.MjModel, mujoco.MjData, ModelMirror] | None = None  # see _render_view
        self._pile_shown = False  # the renderer's copy of the hfield is stale

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Start an episode on a new random site (see the class docstring)."""
        super().reset(seed=seed)
        self.layout, q = sample_start(self.np_random)
        pile = heap_for(self.layout)
        self.earth = Earthwork(pile)
        self._cut: tuple[int, float] | None = None  # (pile revision, fullest cut direction): fullest_cut_direction
        self.start_machine(q, self.layout)
        self.world.show_pile(pile.heights)
        self._pile_shown = False
        self._tip_before = self._bucket_pose()[0]
        self._tip_interval = math.inf  # s since _tip_before was taken: none yet, so the velocity reads 0
        self._tip_velocity = (0.0, 0.0, 0.0)  # low-passed, for the digging resistance
        self._tip_force_on = False
        self._dig_depth = 0.0  # m, the last dig's: the digging force follows the motion at it
        self.fuel_l = 0.0
        self.steps = 0
        self.elapsed = 0.0
        return self._observation(), self._info({})

    def start_machine(self, q: np.ndarray, layout: Layout) -> None:
        """Put the machine at rest at angles ``q`` with an empty bucket on a site laid out as ``layout``
        (the simulation part of :meth:`reset`; the batched environment starts its machines through it)."""
        mujoco.mj_resetData(self.physics.model, self.physics.data)  # warm starts too: same seed, same episode
        self.machine.reset(q, payload_kg=0.0)
        self.world.place(self.physics.data, layout)
        self.physics.data.qfrc_applied[:] = 0.0
        mujoco.mj_forward(self.physics.model, self.physics.data)

    def _bucket_pose(self) -> tuple[list[float], tuple[float, ...], tuple[float, ...], float]:
        """Teeth position, lateral and teeth directions (world) and the mouth's tilt from facing up.

        Plain floats: this runs every control period near the pile, where numpy's per-call cost on
        3-vectors would exceed the arithmetic.
        """
        d = self.physics.data
        r = d.xmat[self._bucket_body].tolist()  # row-major rotation, bucket frame -> world
        tilt = math.acos(min(max(r[6] * _MOUTH_NORMAL_X + r[8] * _MOUTH_NORMAL_Z, -1.0), 1.0))
        tx, tz = _TEETH_X, _TEETH_Z
        teeth = (r[0] * tx + r[2] * tz, r[3] * tx + r[5] * tz, r[6] * tx + r[8] * tz)
        return d.site_xpos[self._tip_site].tolist(), (r[1], r[4], r[7]), teeth, tilt

    def mouth_position(self) -> np.ndarray:
        """Centre of the bucket's mouth (where its contents pour from), world m."""
        d = self.physics.data
        return d.xpos[self._bucket_body] + d.xmat[self._bucket_body].reshape(3, 3) @ _MOUTH_CENTRE

    def _spill(self, tilt: float, dt: float, flows: dict[str, float]) -> None:
        """Let what the bucket cannot hold at ``tilt`` run out over ``dt`` s (into the bed if the mouth is over it)."""
        if self.earth.bucket_kg <= 0.0:
            return  # nothing to spill (the common case: skip the mouth's position)
        into_truck = self.world.in_bed(self.mouth_position(), self.layout)
        spilled = self.earth.spill(tilt, into_truck, dt)
        flows["delivered"] += spilled.to_truck_kg
        flows["spilled"] += spilled.to_ground_kg

    def _earthwork(self, seconds: float, flows: dict[str, float]) -> None:
        """Dig (fill, cut the pile) and spill over the next ``seconds``; apply the digging force; re-mass the bucket.

        The fill uses the teeth's mean velocity since the last sample (a backward difference).
        """
        tip, lateral, teeth, tilt = self._bucket_pose()
        velocity = self._sample_tip(tip)
        dug = self.earth.dig(tip, lateral, teeth, velocity, seconds, self._tip_velocity)
        self._dig_depth = dug.depth
        if dug.depth <= 0.0:
            self._spill(tilt, seconds, flows)
        if dug.taken_kg > 0:
            self._pile_shown = False
        if dug.depth > 0 or self._tip_force_on:
            self.physics.apply_tip_force(dug.force)
            self._tip_force_on = dug.depth > 0
        flows["dug"] += dug.taken_kg
        self._update_payload()

    def _sample_tip(self, tip: list[float]) -> tuple[float, ...]:
        """The teeth's mean velocity since the last sample (m/s), also folded into the low-passed one."""
        interval = self._tip_interval
        (x, y, z), (x0, y0, z0), (fx, fy, fz) = tip, self._tip_before, self._tip_velocity
        vx, vy, vz = (x - x0) / interval, (y - y0) / interval, (z - z0) / interval
        blend = self._velocity_blend if interval == self._period else 1.0 - math.exp(-interval / p.DIG_VELOCITY_FILTER)
        self._tip_velocity = (fx + (vx - fx) * blend, fy + (vy - fy) * blend, fz + (vz - fz) * blend)
        self._tip_before = tip  # (the caller sets _tip_interval to the time until the next sample)
        return vx, vy, vz

    def _follow_resistance(self) -> None:
        """Turn the digging force with the teeth's motion (at the depth of the last dig): every control period."""
        tip, lateral, teeth, _ = self._bucket_pose()
        self._sample_tip(tip)
        if self._tip_force_on:
            self.physics.apply_tip_force(self.earth.resistance(self._dig_depth, lateral, teeth, self._tip_velocity))

    def _update_payload(self) -> None:
        if abs(self.earth.bucket_kg - self.physics.payload_kg) > PAYLOAD_UPDATE_KG or (
            self.earth.bucket_kg < 1.0 < self.physics.payload_kg
        ):
            self.physics.set_payload(self.earth.bucket_kg)

    def _limit_servo_windup(self) -> None:
        """Keep each servo's integrated target where the servo is at most saturated (anti-windup).

        The machine's integrated-velocity servos integrate the tables' rate targets even while a
        joint is stalled (bucket against the truck, dig force above the swing's torque); released,
        the servo would then drive the joint to the stale target whatever the spools say. A stalled
        hydraulic actuator stores no such displacement (its reliefs open), so the target is held
        within the band where the servo force is at its limit.
        """
        d = self.physics.data
        act_adr, qpos_adr, dof_adr, ratio, slack = self._servo_bands
        if not len(act_adr):
            return  # a plugin backend: no integrated servo targets
        centre = d.qpos[qpos_adr] + ratio * d.qvel[dof_adr]
        d.act[act_adr] = np.clip(d.act[act_adr], centre - slack, centre + slack)

    def _hard_contact_force(self) -> float:
        """Bucket and stick contact force on the ground and the truck beyond HARD_CONTACT_FORCE (capped), N.

        Estimated from the contacts' depth (``CONTACT_STIFFNESS``): the lean machine's contacts are
        detected but inactive, the learned model stalls a joint that drives into one.
        """
        d = self.physics.data
        if d.ncon == 0:
            return 0.0
        contacts, tool, obstacle = d.contact, self._tool_geoms, self._obstacle_geoms
        # the contacts are inactive (the machine model stalls at them): their depth tells the force
        shallow = [
            min(dist, 0.0)
            for (g1, g2), dist in zip(contacts.geom.tolist(), contacts.dist.tolist(), strict=True)
            if (tool[g1] and obstacle[g2]) or (tool[g2] and obstacle[g1])
        ]  # plain floats: a few contacts, every step
        if not shallow:
            return 0.0
        depth = -(sum(shallow) if len(shallow) < 8 else float(np.sum(shallow)))  # as numpy: 8 or more pairwise
        total = p.CONTACT_STIFFNESS * depth
        # count at most what a real machine could press with: its weight
        return min(max(total - p.HARD_CONTACT_FORCE, 0.0), p.HARD_CONTACT_FORCE_CAP - p.HARD_CONTACT_FORCE)

    def _actuator_power(self, joint_loads: np.ndarray) -> float:
        """Mechanical power of the actuators (W) at the present state, whose joint loads are ``joint_loads``."""
        ph = self.physics
        rates = ph.joint_velocities()
        swing_torque = ph.swing_inertia() * self.machine.swing_acceleration
        return fuel.actuator_power(joint_loads[1:], rates[1:], swing_torque, rates[0])

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Hold the spools for 0.1 s (several control periods of the machine model)."""
        if self.earth is None:
            raise RuntimeError("call reset() before step()")
        spools = np.minimum(np.maximum(self._check_action(action), -1.0), 1.0) * p.SPOOL_STROKE  # (np.clip: slower)
        flows = {"dug": 0.0, "delivered": 0.0, "spilled": 0.0}
        fuel_l, contact_impulse, joint_loads = self._advance(spools, flows)
        self.fuel_l += fuel_l
        self.steps += 1
        self.elapsed = self.steps * STEP_PERIOD
        w = self.weights
        terms = {
            "delivery": w["delivery"] * flows["delivered"] / 1000.0,
            "fill": w["fill"] * flows["dug"] / 1000.0,
            "time": -w["time"] * STEP_PERIOD,
            "fuel": -w["fuel"] * fuel_l,
            "spill": -w["spill"] * flows["spilled"] / 1000.0,
            "contact": -w["contact"] * contact_impulse / 1000.0,
        }
        reward = float(sum(terms.values()))
        obs = self._observation(joint_loads)
        terminated = self.earth.truck_kg >= self.truck_capacity_kg
        truncated = self.elapsed >= self.time_limit - 1e-9
        info = self._info(terms) | {"fuel_l_step": fuel_l, "contact_impulse_ns": contact_impulse}
        if self.render_mode == "human":
            self.render()
        return obs, reward, terminated, truncated, info

    def _advance(self, spools: np.ndarray, flows: dict[str, float]) -> tuple[float, float, np.ndarray]:
        """Hold the spools for the step's control periods; return fuel (L), hard-contact impulse (N s), joint loads.

        Where the teeth may reach the pile, ``earthwork_periods`` periods at a time with the fill,
        spill, fuel and contacts of each such interval (the digging force turns with the motion
        every period); periods in which they surely stay clear of it, in one call of the machine
        model (the native backend's fast path).
        """
        fuel_l = contact_impulse = 0.0
        left = self._periods
        while left:
            clear = 0 if self._tip_force_on else min(self._clear_periods(), left)  # force on: in the pile
            if clear:
                periods = clear
                step_fuel, step_contact, joint_loads = self._advance_clear(spools, periods, flows)
            else:
                periods = min(self.earthwork_periods, left)
                step_fuel, step_contact, joint_loads = self._advance_in_pile(spools, periods, flows)
            fuel_l += step_fuel
            contact_impulse += step_contact
            left -= periods
        return fuel_l, contact_impulse, joint_loads

    def _clear_periods(self) -> int:
        """Control periods (up to a step's) within which the teeth surely stay out of the pile.

        The teeth travel at most ``_PILE_MARGIN`` per step, so within ``m`` periods at most
        ``m / periods`` of it; the dig samples lie within half a bucket width of them. ``m`` periods
        are clear when no grid point within half a width plus that travel (horizontally) stands
        higher than the teeth less that travel.
        """
        tip = self.physics.data.site_xpos[self._tip_site]
        pile, per_period = self.earth.pile, _PILE_MARGIN / self._periods
        # the usual case first: clear over the whole step is clear over each part (a smaller window, less travel)
        whole = self._periods * per_period  # (the loop's last travel, the same float)
        if pile.clearance(tip, p.BUCKET_WIDTH / 2.0 + whole, enough=whole) >= whole:
            return self._periods
        clear = 0
        while clear < self._periods:
            travel = (clear + 1) * per_period
            if pile.clearance(tip, p.BUCKET_WIDTH / 2.0 + travel, enough=travel) < travel:
                break
            clear += 1
        return clear

    def _advance_in_pile(
        self, spools: np.ndarray, periods: int, flows: dict[str, float]
    ) -> tuple[float, float, np.ndarray]:
        """``periods`` control periods with one dig (fill, spill, fuel, contacts over them all); while the edge
        cuts, its force is re-aimed every period (held for longer, a stalled cut chatters: the resistance,
        proportional to the speed below ``DIG_REFERENCE_SPEED``, would lag the motion by the interval)."""
        seconds = periods * self._period
        self._earthwork(seconds, flows)
        # cutting: the force is re-aimed every FORCE_PERIODS; not cutting: nothing to update until the next dig
        chunk = FORCE_PERIODS if self._tip_force_on else periods
        for start in range(0, periods, chunk):
            if start:
                self._follow_resistance()
            done = min(chunk, periods - start)
            self.machine.step(spools, n=done)
            self._limit_servo_windup()
            self._tip_interval = done * self._period
        joint_loads = self.machine.joint_loads()
        fuel_l = fuel.fuel_litres(self._actuator_power(joint_loads), seconds)
        return fuel_l, self._hard_contact_force() * seconds, joint_loads

    def _advance_clear(
        self, spools: np.ndarray, periods: int, flows: dict[str, float]
    ) -> tuple[float, float, np.ndarray]:
        """``periods`` control periods in one call of the machine model: clear of the pile nothing needs them apart.

        No digging force acts; the spill over them is its exact exponential at their end tilt; fuel
        and contacts are sampled at their end.
        """
        if self._tip_force_on:
            self.physics.apply_tip_force(np.zeros(3))
            self._tip_force_on = False
        seconds = periods * self._period
        tip_start = self._bucket_pose()[0]
        self.machine.step(spools, n=periods)
        self._limit_servo_windup()
        tip, _, _, tilt = self._bucket_pose()
        self._tip_velocity = tuple((end - start) / seconds for end, start in zip(tip, tip_start, strict=True))
        self._tip_before, self._tip_interval = tip_start, seconds
        self._spill(tilt, seconds, flows)
        self._update_payload()
        joint_loads = self.machine.joint_loads()
        fuel_l = fuel.fuel_litres(self._actuator_power(joint_loads), seconds)
        return fuel_l, self._hard_contact_force() * seconds, joint_loads

    def _check_action(self, action: np.ndarray) -> np.ndarray:
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (4,):
            raise ValueError(f"action must have shape (4,) (swing, boom, stick, bucket spools), got shape {a.shape}")
        if not math.isfinite(sum(a.tolist())) and not np.isfinite(a).all():  # a NaN or inf makes the sum one
            raise ValueError(
                f"action must be finite, got {a} (a NaN or inf in {list(np.flatnonzero(~np.isfinite(a)))})"
            )
        return a

    # -- observation and info ----------------------------------------------------------------
    def _observation(self, joint_loads: np.ndarray | None = None) -> np.ndarray:
        """The observation (see the class docstring); ``joint_loads``: the machine's, if already at hand."""
        ph, lay, earth = self.physics, self.layout, self.earth
        q, qd = ph.joint_positions().tolist(), ph.joint_velocities().tolist()
        if joint_loads is None:
            joint_loads = self.machine.joint_loads()
        arms = [table(angle) for table, angle in zip(kinematics.moment_arm_tables(), q[1:], strict=True)]
        loads = [load / arm / 1e6 for load, arm in zip(joint_loads[1:].tolist(), arms, strict=True)]  # MN
        tip, _, _, tilt = self._bucket_pose()
        pile_dir = lay.pile_direction
        c, s = math.cos(pile_dir), math.sin(pile_dir)
        rel_x, rel_y = tip[0] - lay.pile_centre[0], tip[1] - lay.pile_centre[1]
        above_pile = tip[2] - earth.pile.height_at_point(tip[0], tip[1])
        values = [
            *q[1:], _wrap(q[0] - pile_dir), _wrap(q[0] - lay.truck_direction), *qd, *loads,
            earth.bucket_kg / 1000.0, c * rel_x + s * rel_y, -s * rel_x + c * rel_y, above_pile,
            *bed_coordinates(tip[0], tip[1], lay), tip[2] - BED_RIM_HEIGHT,
            tilt, earth.truck_kg / self.truck_capacity_kg, max(1.0 - self.elapsed / self.time_limit, 0.0),
            _wrap(q[0] - self.fullest_cut_direction()),
        ]  # fmt: skip
        obs = np.array(values)
        if not math.isfinite(sum(values)):  # a NaN or an infinity anywhere makes the sum one
            raise RuntimeError(f"the simulation diverged (non-finite observation {obs}) at t = {self.elapsed:.1f} s")
        np.minimum(np.maximum(obs, _CLIP_LOW, out=obs), _CLIP_HIGH, out=obs)
        return obs.astype(np.float32)

    def fullest_cut_direction(self) -> float:
        """Swing angle (rad) of the pile's cut line with the most material (:func:`world.fullest_cut_direction`),
        recomputed only when the pile has changed."""
        pile = self.earth.pile
        if self._cut is None or self._cut[0] != pile.revision:
            self._cut = (pile.revision, fullest_cut_direction(pile.height_at, self.layout))
        return self._cut[1]

    def _info(self, terms: dict[str, float]) -> dict[str, Any]:
        earth = self.earth
        info: dict[str, Any] = {f"reward_{k}": terms.get(k, 0.0) for k in REWARD_TERMS}
        info |= {
            "pile_kg": earth.pile_kg, "bucket_kg": earth.bucket_kg, "truck_kg": earth.truck_kg,
            "spilled_kg": earth.spilled_kg, "fuel_l": self.fuel_l, "time_s": self.elapsed,
        }  # fmt: skip
        return info

    # -- rendering ----------------------------------------------------------------------------
    def render(self) -> np.ndarray | None:
        """A frame from ``camera`` (rgb_array: uint8 H x W x 3; depth_array: float32 H x W, m) or a window."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode to gymnasium.make")
            return None
        if self.earth is None:
            raise RuntimeError("call reset() before render()")
        self.world.show_loads(self.earth.truck_kg, self.earth.bucket_kg)
        if not self._pile_shown:
            self.world.show_pile(self.earth.pile.heights)
            self._pile_shown = True
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
        """Release the renderer's OpenGL context."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # -- pickling: everything but the renderer ----------------------------------------------
    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_renderer"] = None
        state["_view"] = None
        state["_pile_shown"] = False
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)

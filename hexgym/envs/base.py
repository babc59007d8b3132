"""The base of the tasks on the loading site: :class:`SiteEnv` owns the site, the machine and rendering, and
:class:`SiteConfig` what every such task is configured with.

``HexLoading-v0`` (:mod:`.loading`) and ``HexDig-v0`` (:mod:`.dig`) are siblings over :class:`SiteEnv`, as
Gymnasium's MuJoCo tasks are over ``MujocoEnv`` and MuJoCo Playground's over a robot's base: each names its
frozen config (a :class:`SiteConfig` with its own fields, checked once when made), draws its episodes'
starts (:meth:`SiteEnv.draw_start`) and makes its reward from the loading task's. The base builds the
machine model (learned or reference) on the site (pile, truck), runs the loading task of one site over it
(:class:`hexgym.envs.task.LoadingTask`: the action and the start go through the physics protocol,
:class:`hexgym.envs.task.SitePhysics`), and renders it.

A task is made from keyword arguments (``gymnasium.make("HexLoading-v0", time_limit=60.0)``), from a config
(``HexLoadingEnv(LoadingConfig(time_limit=60.0))``), or from a config with overrides; a bad value or an unknown
name is refused in one line naming it.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple, TypeVar

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces

from hexgym.checks import check_choice, check_path_type, check_positive
from hexgym.envs.earthwork import Earthwork
from hexgym.envs.sites import MachineSites, make_machine
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
    SiteStart,
)
from hexgym.envs.world import Layout, build_world_model
from hexgym.machine import parameters as p
from hexgym.machine.assets import SCENE_FILE, asset_path
from hexgym.machine.bucket import BUCKET
from hexgym.machine.names import CAMERAS, CHASE_CAMERA
from hexgym.machine.render import ModelMirror
from hexgym.mbl.schema import DEFAULT_TABLE_SET
from hexgym.mbl.table import resolve_tables
from hexgym.model.backend import backend_for

if TYPE_CHECKING:
    from hexgym.hydraulics.overrides import HydraulicsOverrides

MAX_TIME_LIMIT = 86_400.0  # s: an episode of at most a day (a longer one is a mistake that fills memory)
MODELS = ("learned", "reference")
_MOUTH_CENTRE = np.array(BUCKET.mouth_centre)  # bucket frame, m
_SITE = np.zeros(1, np.intp)  # a single environment is site 0 of a task of one


def _display_available() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


# "human" (a window) only where a display exists; offscreen modes everywhere (MUJOCO_GL=egl)
RENDER_MODES = ["rgb_array", "depth_array"] + (["human"] if _display_available() else [])


def is_number(value: Any) -> bool:
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


def task_spaces() -> tuple[spaces.Box, spaces.Box]:
    """The site tasks' observation and action spaces (``HexLoading-v0``'s), without building an environment."""
    return spaces.Box(OBS_LOW, OBS_HIGH, dtype=np.float32), spaces.Box(-1.0, 1.0, (4,), np.float32)


Config = TypeVar("Config")


def make_config(config_type: type[Config], env_id: str, config: Config | None, overrides: dict[str, Any]) -> Config:
    """``config`` (default: ``config_type``'s defaults) with ``overrides`` by field name, checked once as it is
    made; TypeError naming an argument ``env_id`` does not have."""
    names = {field.name for field in dataclasses.fields(config_type)}
    for name in overrides:
        if name not in names:
            raise TypeError(f"{env_id} got an unexpected keyword argument {name!r} (not one of its config's fields)")
    if config is None:
        return config_type(**overrides)
    if not isinstance(config, config_type):
        raise TypeError(f"{env_id}'s config must be a {config_type.__name__}, got {type(config).__name__}")
    return dataclasses.replace(config, **overrides) if overrides else config


class SiteRules(NamedTuple):
    """What the loading task under a site task counts: its episode's length (s), the truck's capacity (kg) and the
    weights of its reward terms (``REWARD_TERMS``)."""

    time_limit: float
    truck_capacity_kg: float
    weights: dict[str, float]


@dataclass(frozen=True)
class SiteConfig:
    """What every task on the loading site is configured with: rendering, the machine model and the loading
    task's schedule. Frozen; checked once when made (ValueError or TypeError naming the field and value).

    Attributes:
        render_mode: ``"rgb_array"``, ``"depth_array"`` (metric depth, m), ``"human"`` (needs a display) or None.
        camera: ``"chase"`` (the scene's) or ``"cab"`` (the operator's view).
        width, height: frame size in pixels.
        time_limit: episode length, s.
        scene_path: MJCF scene to build the site on (default ``scene_lean.xml``; reference: ``scene.xml``).
        backend: the learned model's: ``"native"`` (MuJoCo plugin), ``"python"``, ``"auto"`` (native if built).
        tables: the learned model's table set: ``"circuit"`` or ``"paper"`` (:mod:`hexgym.mbl.schema`), or a model
            directory fitted to a machine's logs (``hexgym fit --logs``; its ``provenance.json`` names its set).
        model: ``"learned"``, or ``"reference"``: the same task on the analytical circuit.
        earthwork_periods: control periods (25 ms) per dig near the pile; 1: every period.
    """

    render_mode: str | None = None
    camera: str = CHASE_CAMERA
    width: int = 640
    height: int = 384
    time_limit: float = 180.0
    scene_path: str | os.PathLike[str] | None = None
    backend: str = "auto"
    tables: str = DEFAULT_TABLE_SET
    model: str = "learned"
    earthwork_periods: int = EARTHWORK_PERIODS

    def __post_init__(self) -> None:
        self._check_model()
        if self.render_mode is not None and self.render_mode not in RENDER_MODES:
            why = " ('human' needs a display: DISPLAY is unset)" if self.render_mode == "human" else ""
            raise ValueError(f"render_mode must be one of {RENDER_MODES} or None, got {self.render_mode!r}{why}")
        if self.camera not in CAMERAS:
            raise ValueError(f"camera must be 'chase' or 'cab', got {self.camera!r}")
        periods = self.earthwork_periods
        if isinstance(periods, bool) or not isinstance(periods, int) or periods < 1:
            raise ValueError(f"earthwork_periods must be an integer >= 1, got {periods!r}")
        self._set("time_limit", check_positive("time_limit", self.time_limit, "s"))
        if self.time_limit > MAX_TIME_LIMIT:
            raise ValueError(f"time_limit must be at most {MAX_TIME_LIMIT:.0f} s (a day), got {self.time_limit}")
        for name in ("width", "height"):
            size = getattr(self, name)
            if not is_number(size) or int(size) != size or size < 1:
                raise ValueError(f"{name} must be a whole number of pixels >= 1, got {size!r}")
            self._set(name, int(size))
        resolve_tables(self.tables)  # a set's name or a fitted model's directory; else refused in one line
        if self.scene_path is not None:
            check_path_type("scene_path", self.scene_path)
        if self.model == "learned":
            backend_for(self.table_set, self.backend)  # a set the plugin does not run, with backend "native": refused

    @property
    def table_set(self) -> str:
        """The learned model's table set: ``tables`` itself, or the one a fitted model's directory holds."""
        return resolve_tables(self.tables)[0]

    @property
    def tables_dir(self) -> Path | None:
        """The learned model's tables' directory: None for a set's packaged tables, else the fitted model's."""
        return resolve_tables(self.tables)[1]

    @property
    def material_density(self) -> float:
        """The pile's material, kg/m^3 (``MATERIAL_DENSITY``; a task may make it heavier)."""
        return float(p.MATERIAL_DENSITY)

    @property
    def engine_power_w(self) -> float:
        """The engine's power, W (``ENGINE_POWER``; a task may make it weaker)."""
        return float(p.ENGINE_POWER)

    def hydraulics(self) -> HydraulicsOverrides | None:
        """The machine's circuit where it differs from the data sheet's and a fitted model's own (a task's weaker
        engine): None here."""
        return None

    def _check_model(self) -> None:
        """Refuse an unknown ``model``, and learned-model options given with ``model="reference"``."""
        check_choice("model", self.model, MODELS)
        for name, default in (("backend", "auto"), ("tables", DEFAULT_TABLE_SET)):
            value = getattr(self, name)
            if self.model == "reference" and value != default:
                raise ValueError(f"{name}={value!r} does not apply to model='reference' (it runs no learned model)")

    def _set(self, name: str, value: Any) -> None:
        """Store a checked field's normalised value (a float, an int) in the frozen config."""
        object.__setattr__(self, name, value)

    def site_rules(self) -> SiteRules:
        """What the loading task under this task counts (each task's config says)."""
        raise NotImplementedError


class SiteEnv(gym.Env):
    """A task on the loading site: the base of ``HexLoading-v0`` and ``HexDig-v0`` (see the module docstring).

    Subclasses set :attr:`env_id` and :attr:`config_type` and provide :meth:`draw_start`; they may rework
    :meth:`reset`'s and :meth:`step`'s returns (the loading task's observation, reward terms and ``info``) into
    their own reward and end. All state is in the machine's ``MjData`` and the loading task; the environment
    holds its configuration (:attr:`config`).

    Args:
        config: the task's config (default: its defaults).
        **overrides: config fields by name (what ``gymnasium.make`` passes).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": RENDER_MODES, "render_fps": round(1.0 / STEP_PERIOD)}
    env_id: ClassVar[str]  # what errors call it
    config_type: ClassVar[type[SiteConfig]]
    closed = False  # set by close()

    def __init__(self, config: SiteConfig | None = None, **overrides: Any) -> None:
        self.config = make_config(self.config_type, self.env_id, config, overrides)
        self.render_mode = self.config.render_mode
        self.observation_space, self.action_space = task_spaces()
        self._build()
        frame = self.physics.model.vis.global_
        c = self.config
        if c.render_mode in ("rgb_array", "depth_array") and (c.width > frame.offwidth or c.height > frame.offheight):
            raise ValueError(
                f"frames of {c.width} x {c.height} pixels exceed the scene's offscreen buffer "
                f"({frame.offwidth} x {frame.offheight})"
            )
        self.layout: Layout | None = None
        self.earth: Earthwork | None = None  # the site's material stores, a view of the task's (once reset)

    def _build(self) -> None:
        c = self.config
        if c.model == "reference":
            from hexgym.envs.reference_machine import ReferenceMachine, reference_world_model

            world = reference_world_model(c.scene_path, tool_contact_slots=CONTACT_SLOTS)
            self.machine = ReferenceMachine(world, hydraulics=c.hydraulics())
        else:
            self.machine = make_machine(
                c.backend, c.scene_path, c.table_set, tool_contact_slots=CONTACT_SLOTS, tables_dir=c.tables_dir,
                hydraulics=c.hydraulics(),
            )  # fmt: skip
        self.physics = self.machine.physics
        self.sites = MachineSites([self.machine])
        self.world = self.sites.worlds[0]
        self.task = LoadingTask(
            1, self.sites, *c.site_rules(), c.earthwork_periods, c.material_density, c.engine_power_w
        )
        self._period, self._periods = self.task.period, self.task.periods
        self._bucket_body, self._tip_site = self.sites.bucket_body, self.sites.tip_site
        self._renderer: Any = None
        self._view: tuple[mujoco.MjModel, mujoco.MjData, ModelMirror] | None = None  # see _render_view
        self._pile_shown = -1  # the pile revision the renderer's copy of the hfield shows

    @property
    def time_limit(self) -> float:
        """Episode length, s."""
        return self.config.time_limit

    # -- the task's part ------------------------------------------------------------------------
    def draw_start(self, rng: np.random.Generator) -> SiteStart:
        """An episode's start drawn from ``rng``: the site's layout, the machine's joint angles and payload."""
        raise NotImplementedError

    # -- Gymnasium API -------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """Start an episode on a new random site (:meth:`draw_start`)."""
        check_open(self.env_id, self.closed)
        super().reset(seed=seed)
        start = self.draw_start(self.np_random)
        self.layout = start.layout
        self.task.start(_SITE, [start])
        self.earth = self.task.earthwork(0)
        self.world.show_pile(self.earth.pile.heights)
        self._pile_shown = -1
        return self.task.observe(_SITE)[0], self._info(None, 0.0, 0.0)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Hold the spools for 0.1 s (several control periods of the machine model): the loading task's step."""
        check_open(self.env_id, self.closed)
        if self.earth is None:
            raise RuntimeError("call reset() before step()")
        task = self.task
        terms, rewards, ended = task.step(_SITE, spools_from_action(action)[None])
        obs = task.observe(_SITE)[0]
        info = self._info(terms[0].tolist(), float(task.step_fuel_l[0]), float(task.step_impulse[0]))
        if self.render_mode == "human":
            self.render()
        return obs, float(rewards[0]), bool(ended[0, 0]), bool(ended[0, 1]), info

    def start_machine(self, q: np.ndarray, layout: Layout, payload_kg: float = 0.0) -> None:
        """Put the machine at rest at angles ``q`` with ``payload_kg`` in the bucket on a site laid out as
        ``layout`` (the physics' start alone: the task's episode, its pile and stores, go on)."""
        self.sites.start(_SITE, [SiteStart(layout, np.asarray(q, dtype=float), payload_kg)])

    # -- the site -------------------------------------------------------------------------------
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
        scale = p.MATERIAL_DENSITY / self.config.material_density  # drawn by volume: kg of the nominal material
        self.world.show_loads(self.earth.truck_kg * scale, self.earth.bucket_kg * scale)
        self.world.aim_camera(self.layout, self.config.width / self.config.height)
        if self._pile_shown != self.task.revision[0]:
            self.world.show_pile(self.earth.pile.heights)
            self._pile_shown = int(self.task.revision[0])
        model, data, mirror = self._render_view()
        changed = mirror.sync(self.physics.data, data)
        if self.render_mode == "human":
            return self._render_window(model, data, changed)
        c = self.config
        if self._renderer is None:  # a new context uploads the present heightfield itself
            self._renderer = mujoco.Renderer(model, height=c.height, width=c.width)
            if self.render_mode == "depth_array":
                self._renderer.enable_depth_rendering()
        else:  # the renderer keeps its own copy of the hfield on the GPU side (private context attribute)
            for hfield in changed:
                mujoco.mjr_uploadHField(model, self._renderer._mjr_context, hfield)
        self._renderer.update_scene(data, camera=c.camera)
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

            c = self.config
            self._renderer = MujocoRenderer(model, data, width=c.width, height=c.height, camera_name=c.camera)
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

"""The loading site around the machine: the pile's hfield, the dump truck, their placement per episode.

:func:`build_world_model` adds to the machine's scene (via ``mujoco.MjSpec``):

- ``pile``: an hfield geom mirroring the environment's heightmap (:class:`hexgym.envs.earthwork.Pile`).
  It is drawn only (contype = conaffinity = 0): the bucket must enter it to dig; the digging
  resistance is applied by the environment.
- ``truck``: a mocap body (so that it moves between episodes without recompiling) with a bed
  whose floor and walls collide with the machine (contype 1 / conaffinity 2, like the ground), a
  chassis, a cab and wheels.
- ``truck_load``: a drawn-only hfield in the bed, the delivered material heaped at its angle of repose
  (:func:`bed_heights`); ``bucket_load_1`` ... ``bucket_load_{LOAD_LEVELS}``: drawn-only meshes of the soil in
  the bucket at as many fill levels (:func:`hexgym.machine.bucket.fill_mesh`), the nearest one shown.
- optionally ``tool_contacts``: a contact sensor of the stick's and bucket's contacts (the batched
  environment reads contacts through it).

:class:`World` holds the ids and moves things: :meth:`World.place` puts the truck and the pile
where a :class:`Layout` says, :meth:`World.show_pile` copies the heightmap into the hfield. The rest is for
pictures, and runs only when a frame is drawn: :meth:`World.show_loads` draws the material in the bed and in the
bucket, :meth:`World.aim_camera` frames the machine, the pile and the truck from the ``chase`` camera.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from hexgym.envs.earthwork import Pile
from hexgym.machine import parameters as p
from hexgym.machine.assets import SCENE_FILE, AssetError, asset_path
from hexgym.machine.bucket import BUCKET, fill_mesh
from hexgym.machine.names import BUCKET_BODY, CHASE_CAMERA, GROUND_GEOM, PILE_GEOM, TRUCK_BODY

PILE_GRID_POINTS = 81  # per side
PILE_GRID_SPACING = 0.1  # m: 8 m x 8 m, finer than the bucket's 1.5 m edge by 15x
_PILE_SINK = 0.02  # m: the hfield's zero sits this far below the ground so the two do not flicker
_WALL = 0.08  # m, thickness of the bed's floor and walls
TRUCK_CAB_LENGTH = 1.8  # m, truck cab ahead of the bed
_WHEEL_RADIUS = 0.5  # m
_SOLID = {"contype": 1, "conaffinity": 2}  # as the ground: collides with the machine's geoms
_DRAWN = {"contype": 0, "conaffinity": 0, "group": 1, "density": 0.0}
_SAND = [0.78, 0.66, 0.45, 1.0]
BED_GRID_SPACING = 0.1  # m between the drawn bed load's height samples
_BED_SINK = 0.02  # m: the bed load's zero sits this far inside the floor (an empty bed shows the floor)
_BED_HEAP_RATIO = 2.0  # the heap in the bed is this much longer than wide: loads are dumped along the bed
_BED_HEAP_MAX = 0.6  # m above the rim: the most a drawn heap rises (a truck is not loaded higher)
LOAD_LEVELS = 12  # drawn fill levels of the bucket: one mesh each, shown by the volume nearest the load's


@dataclass(frozen=True)
class Layout:
    """Where the pile and the truck are in one episode (world frame, m and rad)."""

    pile_centre: tuple[float, float]
    pile_height: float
    pile_top_radius: float
    truck_centre: tuple[float, float]
    truck_yaw: float  # the truck's x axis (towards its cab) from the world x axis

    # cached (every observation asks): a frozen dataclass has no slots, so functools stores them in __dict__
    @functools.cached_property
    def pile_direction(self) -> float:
        """Swing angle (rad) that points the arm at the pile's centre."""
        return float(np.arctan2(self.pile_centre[1], self.pile_centre[0]))

    @functools.cached_property
    def truck_direction(self) -> float:
        """Swing angle (rad) that points the arm at the bed's centre."""
        return float(np.arctan2(self.truck_centre[1], self.truck_centre[0]))

    @property
    def truck_distance(self) -> float:
        """Distance (m) from the swing axis to the bed's centre."""
        return float(np.hypot(*self.truck_centre))


# Cut lines: radial lines across the pile's flat top along which a bucket drags material towards the
# machine. The environment observes the fullest one (the swing angle to it); the scripted loader cuts it.
ENTRY_BEYOND_CENTRE = 0.8  # m: a cut starts this far beyond the pile's centre (where the teeth enter)
DRAG_BEYOND_TOP = 1.3  # m: and ends at the latest this far towards the machine from the flat top's near edge
CUT_SWING_RANGE = 0.3  # rad either side of the pile's direction: where cut lines lie
CUT_LINES = 9  # evenly over that range
CUT_SAMPLE_SPACING = 0.25  # m between a line's height samples
CENTRE_PREFERENCE = 1.0  # m^2 of cut cross-section per rad off the pile's centre line: ties go to the centre


def entry_radius(layout: Layout) -> float:
    """Where a cut starts: beyond the pile's centre, m from the swing axis."""
    return float(np.hypot(*layout.pile_centre)) + ENTRY_BEYOND_CENTRE


def inner_radius(layout: Layout) -> float:
    """Where a cut ends at the latest: DRAG_BEYOND_TOP inside the pile's near edge of the flat top."""
    return float(np.hypot(*layout.pile_centre)) - layout.pile_top_radius - DRAG_BEYOND_TOP


def fullest_cut_direction(height_at: Callable[[np.ndarray], np.ndarray], layout: Layout) -> float:
    """Swing angle (rad) of the cut line with the most material along it (from the entry to the inner radius).

    ``height_at``: the pile's surface height (m) at world points (..., 2). Cutting the same line every
    time would leave a trench: the material is where the pile still stands.
    """
    offsets = np.linspace(-CUT_SWING_RANGE, CUT_SWING_RANGE, CUT_LINES)
    radii = np.arange(inner_radius(layout), entry_radius(layout), CUT_SAMPLE_SPACING)
    angles = layout.pile_direction + offsets
    points = np.stack([np.outer(np.cos(angles), radii), np.outer(np.sin(angles), radii)], axis=-1)
    material = height_at(points).sum(axis=1) * CUT_SAMPLE_SPACING  # m^2: each line's cross-section
    return float(angles[np.argmax(material - CENTRE_PREFERENCE * np.abs(offsets))])


def heap_for(layout: Layout) -> Pile:
    """The pile an episode on ``layout`` starts with: a flat-topped heap at the angle of repose."""
    return Pile.heap(
        layout.pile_centre, layout.pile_height, layout.pile_top_radius, PILE_GRID_POINTS, PILE_GRID_SPACING
    )


SITE_RANGES = ("training", "shifted")  # what sample_layout draws from (HexLoading-v0's site_ranges)


def sample_layout(rng: np.random.Generator, ranges: str = "training") -> Layout:
    """A random site: pile ahead, truck alongside on either side, both within reach.

    ``ranges``: ``"training"`` draws from the parameters' ranges (``PILE_DISTANCE_RANGE``, ``PILE_SWING_RANGE``,
    ``TRUCK_DISTANCE_RANGE``, ``TRUCK_SWING_RANGE``); ``"shifted"`` draws every one of those four quantities from a
    band just outside its range (``SHIFTED_*`` in :mod:`hexgym.machine.parameters`), the pile turned away from the
    truck's side, for testing a policy on sites it never saw. The pile's height and top are drawn as in training.
    """
    if ranges == "shifted":
        return _sample_shifted_layout(rng)
    if ranges != "training":
        raise ValueError(f"site ranges must be one of {SITE_RANGES}, got {ranges!r}")
    pile_angle = rng.uniform(*p.PILE_SWING_RANGE)
    pile_distance = rng.uniform(*p.PILE_DISTANCE_RANGE)
    truck_angle = rng.uniform(*p.TRUCK_SWING_RANGE) * rng.choice((-1.0, 1.0))
    truck_distance = rng.uniform(*p.TRUCK_DISTANCE_RANGE)
    return _layout(rng, pile_angle, pile_distance, truck_angle, truck_distance)


def _sample_shifted_layout(rng: np.random.Generator) -> Layout:
    """:func:`sample_layout`'s ``"shifted"`` site: each band below or above its range by a fair coin (where it has
    two)."""
    side = rng.choice((-1.0, 1.0))  # the truck's side; the pile turns to the other
    pile_angle = -side * rng.uniform(*p.SHIFTED_PILE_SWING_BAND)
    pile_distance = rng.uniform(*p.SHIFTED_PILE_DISTANCE_BANDS[rng.integers(2)])
    truck_angle = side * rng.uniform(*p.SHIFTED_TRUCK_SWING_BANDS[rng.integers(2)])
    truck_distance = rng.uniform(*p.SHIFTED_TRUCK_DISTANCE_BANDS[rng.integers(len(p.SHIFTED_TRUCK_DISTANCE_BANDS))])
    return _layout(rng, pile_angle, pile_distance, truck_angle, truck_distance)


def _layout(
    rng: np.random.Generator, pile_angle: float, pile_distance: float, truck_angle: float, truck_distance: float
) -> Layout:
    """The layout with the pile and truck where given, the pile's height and flat top drawn from ``rng``."""
    return Layout(
        pile_centre=(pile_distance * np.cos(pile_angle), pile_distance * np.sin(pile_angle)),
        pile_height=float(rng.uniform(*p.PILE_HEIGHT_RANGE)),
        pile_top_radius=float(rng.uniform(*p.PILE_TOP_RADIUS_RANGE)),
        truck_centre=(truck_distance * np.cos(truck_angle), truck_distance * np.sin(truck_angle)),
        truck_yaw=float(truck_angle + np.pi / 2.0),  # parked across the arm's path: the long side faces it
    )


def _add_truck(spec: mujoco.MjSpec) -> None:
    box, cyl = mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_CYLINDER
    half_l, half_w = p.TRUCK_BED_LENGTH / 2, p.TRUCK_BED_WIDTH / 2
    floor, wall = p.TRUCK_BED_FLOOR_HEIGHT, p.TRUCK_BED_WALL_HEIGHT
    paint, dark = [0.75, 0.12, 0.1, 1.0], [0.15, 0.15, 0.15, 1.0]
    truck = spec.worldbody.add_body(name=TRUCK_BODY, mocap=True, pos=[0, 20, 0])
    bed = {"type": box, "rgba": paint, **_SOLID}
    floor_size = [half_l + _WALL, half_w + _WALL, _WALL / 2]
    truck.add_geom(name="truck_floor", size=floor_size, pos=[0, 0, floor - _WALL / 2], **bed)
    wall_z = floor + wall / 2
    for name, x in (("truck_headboard", half_l + _WALL / 2), ("truck_tailgate", -half_l - _WALL / 2)):
        truck.add_geom(name=name, size=[_WALL / 2, half_w + _WALL, wall / 2], pos=[x, 0, wall_z], **bed)
    for name, y in (("truck_left_wall", half_w + _WALL / 2), ("truck_right_wall", -half_w - _WALL / 2)):
        truck.add_geom(name=name, size=[half_l + _WALL, _WALL / 2, wall / 2], pos=[0, y, wall_z], **bed)
    chassis_top = floor - _WALL
    truck.add_geom(
        name="truck_chassis", type=box, rgba=dark, size=[half_l + TRUCK_CAB_LENGTH / 2, 0.5, (chassis_top - 0.6) / 2],
        pos=[TRUCK_CAB_LENGTH / 2, 0, (chassis_top + 0.6) / 2], **_SOLID,
    )  # fmt: skip
    truck.add_geom(
        name="truck_cab", type=box, rgba=paint, size=[TRUCK_CAB_LENGTH / 2 - 0.1, half_w, 0.8],
        pos=[half_l + _WALL + TRUCK_CAB_LENGTH / 2, 0, 1.9], **_SOLID,
    )  # fmt: skip
    for k, x in enumerate((-1.6, -0.3, half_l + TRUCK_CAB_LENGTH / 2)):
        for side in (-1, 1):
            truck.add_geom(
                name=f"truck_wheel_{k}_{'l' if side > 0 else 'r'}", type=cyl, rgba=dark,
                size=[_WHEEL_RADIUS, 0.2, 0], pos=[x, side * (half_w - 0.2), _WHEEL_RADIUS],
                quat=[np.sqrt(0.5), np.sqrt(0.5), 0, 0], **_DRAWN,
            )  # fmt: skip
    rows, cols = _bed_grid_shape()
    spec.add_hfield(
        name="truck_load", nrow=rows, ncol=cols, userdata=[0.0] * (rows * cols),
        size=[half_l - 0.01, half_w - 0.01, wall + _BED_HEAP_MAX + _BED_SINK, 0.01],
    )  # fmt: skip
    truck.add_geom(name="truck_load", type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname="truck_load", material="pile",
                   pos=[0, 0, floor - _BED_SINK], **_DRAWN)  # fmt: skip


def _add_pile(spec: mujoco.MjSpec) -> None:
    half = (PILE_GRID_POINTS - 1) * PILE_GRID_SPACING / 2.0
    elevation = p.PILE_HEIGHT_RANGE[1] + _PILE_SINK
    spec.add_hfield(
        name="pile", nrow=PILE_GRID_POINTS, ncol=PILE_GRID_POINTS, size=[half, half, elevation, 0.05],
        userdata=[0.0] * PILE_GRID_POINTS**2,
    )  # fmt: skip
    spec.add_material(name="pile", rgba=_SAND)
    spec.worldbody.add_geom(
        name="pile", type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname="pile", material="pile",
        pos=[0, 0, -_PILE_SINK], contype=0, conaffinity=0, group=1,
    )  # fmt: skip


@functools.cache
def _bucket_load_meshes() -> tuple[tuple[list[float], list[int]], ...]:
    """Vertices and faces (flat lists) of the drawn bucket load at each fill level (computed once)."""
    meshes = (fill_mesh(level / LOAD_LEVELS * BUCKET.heaped_capacity) for level in range(1, LOAD_LEVELS + 1))
    return tuple((vertices.ravel().tolist(), faces.ravel().tolist()) for vertices, faces in meshes)


def _add_bucket_load(spec: mujoco.MjSpec) -> None:
    """The soil in the bucket: a mesh per fill level (:data:`LOAD_LEVELS`, up to the heaped capacity) in the
    bucket's frame, all hidden (transparent) until :meth:`World.show_loads` shows one. Group 2, the machine's
    visual detail: a ray cast at the site's surfaces (group 1) does not meet a bucket's hidden load."""
    bucket = spec.body(BUCKET_BODY)
    if bucket is None:
        raise AssetError("the machine model has no body 'bucket'")
    for level, (vertices, faces) in enumerate(_bucket_load_meshes(), start=1):
        name = f"bucket_load_{level}"
        spec.add_mesh(name=name, uservert=vertices, userface=faces, inertia=mujoco.mjtMeshInertia.mjMESH_INERTIA_SHELL)
        bucket.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=name, material="pile",
                        rgba=[*_SAND[:3], 0.0], **{**_DRAWN, "group": 2})  # fmt: skip


def build_world_model(
    scene_path: str | Path | None = None,
    machine_file: str | None = None,
    tool_contact_slots: int = 0,
    machine_xml: str | None = None,
    customise: Callable[[mujoco.MjSpec], None] | None = None,
) -> mujoco.MjModel:
    """Compile the machine's scene (default: the packaged ``scene.xml``) with the pile, the truck and the loads.

    ``machine_file``: another packaged machine MJCF (e.g. ``cat325_mbl.xml``, the native plugin's)
    to include in place of the one the scene names; ``machine_xml``: a machine MJCF's text to include
    instead (e.g. the plugin's machine for other tables). ``tool_contact_slots`` > 0 adds a contact
    sensor ``tool_contacts`` (:func:`_add_tool_contact_sensor`) with that many slots. ``customise``: called
    with the site's spec before it compiles (e.g. the planner's clearance sensors, :mod:`hexgym.planning`).
    """
    path = Path(scene_path) if scene_path is not None else asset_path(SCENE_FILE)
    try:
        if machine_file is None and machine_xml is None:
            spec = mujoco.MjSpec.from_file(str(path))
        else:
            name = machine_file or "machine.xml"
            text = asset_path(machine_file).read_bytes() if machine_xml is None else machine_xml.encode()
            xml = re.sub(r'<include file="[^"]+"/>', f'<include file="{name}"/>', path.read_text(), count=1)
            spec = mujoco.MjSpec.from_string(xml, include={name: text})
            spec.meshdir = str(asset_path(SCENE_FILE).parent / "meshes")
        _add_pile(spec)
        _add_truck(spec)
        _add_bucket_load(spec)
        if tool_contact_slots > 0:
            _add_tool_contact_sensor(spec, tool_contact_slots)
        if customise is not None:
            customise(spec)
        return spec.compile()
    except ValueError as exc:
        raise AssetError(f"cannot build the loading site on {path}: {exc}") from exc


TOOL_CONTACT_SENSOR = "tool_contacts"


def _add_tool_contact_sensor(spec: mujoco.MjSpec, slots: int) -> None:
    """A contact sensor reporting, per slot, [number of matches, distance] of the contacts of the stick's subtree
    (stick, bucket) in ``data.contact``'s order, so that a batch of simulations reports them without ``data.contact``.

    The stick and bucket collide with the ground and the truck only (the machine's own geoms do not
    collide with each other), so these are the contacts :meth:`World.tool_geoms` selects.
    """
    fields = mujoco.mjtConDataField
    found_and_dist = (1 << int(fields.mjCONDATA_FOUND)) | (1 << int(fields.mjCONDATA_DIST))
    spec.add_sensor(
        name=TOOL_CONTACT_SENSOR, type=mujoco.mjtSensor.mjSENS_CONTACT, objtype=mujoco.mjtObj.mjOBJ_XBODY,
        objname="stick", intprm=[found_and_dist, 0, slots],
    )  # fmt: skip


def _geoms_of_bodies(model: mujoco.MjModel, bodies: tuple[str, ...]) -> np.ndarray:
    ids = {model.body(b).id for b in bodies}
    return np.array([g for g in range(model.ngeom) if model.geom_bodyid[g] in ids and model.geom_contype[g]], int)


class World:
    """Ids of the site's parts in a model from :func:`build_world_model`, and the moves that place them."""

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.pile_geom = model.geom(PILE_GEOM).id
        self.pile_hfield = model.hfield("pile").id
        self._hfield_slice = slice(
            model.hfield_adr[self.pile_hfield], model.hfield_adr[self.pile_hfield] + PILE_GRID_POINTS**2
        )
        self._elevation = float(model.hfield_size[self.pile_hfield, 2])
        self.truck_mocap = model.body(TRUCK_BODY).mocapid[0]
        self.truck_load = model.hfield("truck_load").id
        self._bed_slice = slice(model.hfield_adr[self.truck_load], model.hfield_adr[self.truck_load] + _bed_size())
        self._bed_elevation = float(model.hfield_size[self.truck_load, 2])
        self.bucket_loads = np.array([model.geom(f"bucket_load_{k}").id for k in range(1, LOAD_LEVELS + 1)])
        self._shown: tuple[float, int] = (-1.0, -1)  # the truck's kg and the bucket's level drawn
        chase = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, CHASE_CAMERA)
        self.chase_camera = chase if chase >= 0 else None
        self.tool_geoms = np.zeros(model.ngeom, bool)  # masks over geom ids: the stick's and bucket's
        self.tool_geoms[_geoms_of_bodies(model, ("stick", "bucket"))] = True
        self.obstacle_geoms = np.zeros(model.ngeom, bool)  # the ground's and the truck's
        self.obstacle_geoms[[model.geom(GROUND_GEOM).id, *_geoms_of_bodies(model, (TRUCK_BODY,))]] = True

    def place(self, data: mujoco.MjData, layout: Layout) -> None:
        """Move the truck (mocap) and the pile's hfield to ``layout``; call :func:`mujoco.mj_forward` after."""
        yaw = layout.truck_yaw
        data.mocap_pos[self.truck_mocap] = [*layout.truck_centre, 0.0]
        data.mocap_quat[self.truck_mocap] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
        self.model.geom_pos[self.pile_geom, :2] = layout.pile_centre

    def show_pile(self, heights: np.ndarray) -> None:
        """Copy the heightmap (m) into the hfield (its data are fractions of the elevation).

        Bare grid points go just below the ground (so the two surfaces do not flicker), the rest
        stand at their height.
        """
        drawn = np.where(heights > 0.0, heights + _PILE_SINK, 0.0)
        self.model.hfield_data[self._hfield_slice] = (drawn / self._elevation).ravel()

    def show_loads(self, truck_kg: float, bucket_kg: float) -> None:
        """Draw the material in the bed (its heap, :func:`bed_heights`) and in the bucket (the fill level
        nearest its volume): changes the model's hfield and colours only when what is drawn changes."""
        level = bucket_level(bucket_kg)
        if (truck_kg, level) == self._shown:
            return
        if truck_kg != self._shown[0]:
            heights = bed_heights(truck_kg / p.MATERIAL_DENSITY)
            drawn = np.where(heights > 0.0, heights + _BED_SINK, 0.0)
            self.model.hfield_data[self._bed_slice] = (drawn / self._bed_elevation).ravel()
        self.model.geom_rgba[self.bucket_loads, 3] = 0.0
        if level > 0:
            self.model.geom_rgba[self.bucket_loads[level - 1], 3] = 1.0
        self._shown = (truck_kg, level)

    def aim_camera(self, layout: Layout, aspect: float) -> None:
        """Point the ``chase`` camera (if the scene has one) so that its frames of ``aspect`` (width / height)
        hold the machine, its working arc, the pile and the truck of ``layout`` (:func:`site_camera`)."""
        cam = self.chase_camera
        if cam is None:
            return
        pos, quat = site_camera(layout, aspect, float(self.model.cam_fovy[cam]))
        self.model.cam_mode[cam] = mujoco.mjtCamLight.mjCAMLIGHT_FIXED
        self.model.cam_pos[cam], self.model.cam_quat[cam] = pos, quat

    def in_bed(self, xy: np.ndarray, layout: Layout) -> bool:
        """Whether world point ``xy`` is over the bed's floor (inside its walls)."""
        return bool(over_bed(*bed_coordinates(float(xy[0]), float(xy[1]), layout)))

    @staticmethod
    def truck_frame(point: np.ndarray, layout: Layout) -> np.ndarray:
        """World ``point`` in the bed's frame: along the truck, across it, height above the rim (m)."""
        along, across = bed_coordinates(float(point[0]), float(point[1]), layout)
        return np.array([along, across, float(point[2]) - BED_RIM_HEIGHT])


BED_RIM_HEIGHT = p.TRUCK_BED_FLOOR_HEIGHT + p.TRUCK_BED_WALL_HEIGHT  # m above the ground


# -- what the pictures show: the loads and the camera -------------------------------------------------------------
def _bed_grid_shape() -> tuple[int, int]:
    """Rows (across the bed) and columns (along it) of the drawn bed load's hfield."""
    return (round(p.TRUCK_BED_WIDTH / BED_GRID_SPACING) + 1, round(p.TRUCK_BED_LENGTH / BED_GRID_SPACING) + 1)


def _bed_size() -> int:
    rows, cols = _bed_grid_shape()
    return rows * cols


@functools.cache
def _bed_grid() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bed's sample points (along, across; m from its centre) and their trapezoid-rule areas (m^2)."""
    rows, cols = _bed_grid_shape()
    along = np.linspace(-p.TRUCK_BED_LENGTH / 2, p.TRUCK_BED_LENGTH / 2, cols)
    across = np.linspace(-p.TRUCK_BED_WIDTH / 2, p.TRUCK_BED_WIDTH / 2, rows)
    weights = np.outer(np.gradient(across), np.gradient(along))
    weights[[0, -1], :] /= 2.0  # np.gradient's end steps are whole steps: the trapezoid rule halves the rims
    weights[:, [0, -1]] /= 2.0
    return *np.meshgrid(along, across), weights


def bed_heights(volume: float) -> np.ndarray:
    """The material delivered to the truck (``volume`` m^3) as drawn: heights (m above the floor, rows across the
    bed, columns along it) of one heap at the angle of repose, centred in the bed and stretched along it (loads
    are dumped along the bed), cut off by the walls and topped off at :data:`_BED_HEAP_MAX` above the rim."""
    if volume <= 0.0:
        return np.zeros(_bed_grid_shape())
    along, across, weights = _bed_grid()
    slope = math.tan(p.MATERIAL_REPOSE_ANGLE)
    cone = slope * np.hypot(along / _BED_HEAP_RATIO, across)
    cap = p.TRUCK_BED_WALL_HEIGHT + _BED_HEAP_MAX

    def heights(peak: float) -> np.ndarray:
        return np.clip(peak - cone, 0.0, cap)

    top = cap + float(cone.max())
    if float((heights(top) * weights).sum()) <= volume:
        return heights(top)
    lo, hi = 0.0, top
    for _ in range(40):  # bisection on the peak's height: the heap's volume grows with it
        mid = (lo + hi) / 2.0
        lo, hi = (mid, hi) if float((heights(mid) * weights).sum()) < volume else (lo, mid)
    return heights(hi)


def bucket_level(bucket_kg: float) -> int:
    """The drawn fill level (0: empty, 1 ... :data:`LOAD_LEVELS`: heaped) nearest ``bucket_kg`` of material."""
    fraction = bucket_kg / p.MATERIAL_DENSITY / BUCKET.heaped_capacity
    return int(np.clip(round(fraction * LOAD_LEVELS), 1 if bucket_kg > 1.0 else 0, LOAD_LEVELS))


CAMERA_ELEVATION = math.radians(35.0)  # the chase camera looks down this much
CAMERA_TOWARDS_TRUCK = math.radians(20.0)  # and from this far round from the pile-truck corner, towards the truck
CAMERA_MARGIN = 1.08  # the frame's half-widths over those the site's points need


def site_points(layout: Layout) -> np.ndarray:
    """Points (n, 3; world m) a picture of the site must hold: the machine's tail-swing circle and cab height,
    the arm's working arc from the pile to the truck (bucket and boom), the pile's foot, the truck's corners."""
    ring = np.linspace(0.0, 2.0 * np.pi, 12, endpoint=False)
    r = p.TAIL_SWING_RADIUS
    machine = [(r * math.cos(a), r * math.sin(a), z) for a in ring for z in (0.0, 3.2)]
    arc = [
        (radius * math.cos(a), radius * math.sin(a), z)
        for a in np.linspace(layout.pile_direction, layout.truck_direction, 7)
        for radius, z in ((8.0, 6.2), (4.5, 7.4))
    ]  # fmt: skip
    foot = layout.pile_top_radius + layout.pile_height / math.tan(p.MATERIAL_REPOSE_ANGLE)
    pile = [(layout.pile_centre[0] + foot * math.cos(a), layout.pile_centre[1] + foot * math.sin(a), 0.0)
            for a in ring]  # fmt: skip
    c, s = math.cos(layout.truck_yaw), math.sin(layout.truck_yaw)
    half_w = p.TRUCK_BED_WIDTH / 2 + _WALL
    truck = [
        (layout.truck_centre[0] + c * u - s * v, layout.truck_centre[1] + s * u + c * v, z)
        for u in (-p.TRUCK_BED_LENGTH / 2 - _WALL, p.TRUCK_BED_LENGTH / 2 + TRUCK_CAB_LENGTH)
        for v in (-half_w, half_w)
        for z in (0.0, BED_RIM_HEIGHT + 0.4)
    ]  # fmt: skip
    return np.array(machine + arc + pile + truck)


def site_camera(layout: Layout, aspect: float, fovy_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """A camera (world position, orientation quaternion) whose frames of ``aspect`` (width / height) and vertical
    field of view ``fovy_deg`` hold :func:`site_points` with the least distance.

    It looks down at :data:`CAMERA_ELEVATION` from outside the corner the pile and the truck make at the machine
    (turned :data:`CAMERA_TOWARDS_TRUCK` towards the truck so that it looks into the bed): the bucket's way from
    the pile to the truck runs across the frame and nothing stands between the camera and the bed.
    """
    pile, truck = layout.pile_direction, layout.truck_direction
    outside = math.atan2(math.sin(pile) + math.sin(truck), math.cos(pile) + math.cos(truck))
    azimuth = outside + math.copysign(CAMERA_TOWARDS_TRUCK, math.sin(truck - pile))
    forward = -np.array([math.cos(azimuth) * math.cos(CAMERA_ELEVATION), math.sin(azimuth) * math.cos(CAMERA_ELEVATION),
                         math.sin(CAMERA_ELEVATION)])  # fmt: skip
    right = np.array([-math.sin(azimuth), math.cos(azimuth), 0.0])
    up = np.cross(right, forward)
    points = site_points(layout)
    # a frustum around the points: offsets x, y (along right, up) and distance d back from them; for each axis the
    # points' projections must lie within +-tan(half angle) * depth, which bounds d from below and fixes the offset
    slope_y = math.tan(math.radians(fovy_deg) / 2.0) / CAMERA_MARGIN
    depth = points @ forward
    offsets, least = [], 0.0
    for axis, slope in ((right, slope_y * aspect), (up, slope_y)):
        lateral = points @ axis
        least = max(least, (np.max(lateral - slope * depth) - np.min(lateral + slope * depth)) / (2.0 * slope))
        offsets.append((axis, lateral))
    position = -least * forward
    for axis, lateral in offsets:
        slope = slope_y * aspect if axis is right else slope_y
        span = (np.max(lateral - slope * (depth + least)), np.min(lateral + slope * (depth + least)))
        position = position + axis * (span[0] + span[1]) / 2.0
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.column_stack([right, up, -forward]).ravel())
    return position, quat


def bed_coordinates(x: float, y: float, layout: Layout) -> tuple[float, float]:
    """World point (x, y) along the truck and across it from the bed's centre, m (plain floats: called per step)."""
    c, s = math.cos(layout.truck_yaw), math.sin(layout.truck_yaw)
    return bed_frame(x, y, layout.truck_centre[0], layout.truck_centre[1], c, s)


def bed_frame(
    x: np.ndarray | float,
    y: np.ndarray | float,
    centre_x: np.ndarray | float,
    centre_y: np.ndarray | float,
    cos_yaw: np.ndarray | float,
    sin_yaw: np.ndarray | float,
) -> tuple[np.ndarray | float, np.ndarray | float]:
    """World point(s) (x, y) along and across a truck whose bed's centre and heading are given (floats or arrays)."""
    dx, dy = x - centre_x, y - centre_y
    return cos_yaw * dx + sin_yaw * dy, -sin_yaw * dx + cos_yaw * dy


def over_bed(along: np.ndarray | float, across: np.ndarray | float) -> np.ndarray | bool:
    """Whether bed-frame point(s) (:func:`bed_frame`) lie over the bed's floor, inside its walls."""
    return (abs(along) <= p.TRUCK_BED_LENGTH / 2) & (abs(across) <= p.TRUCK_BED_WIDTH / 2)

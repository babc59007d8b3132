"""The loading site around the machine: the pile's hfield, the dump truck, their placement per episode.

:func:`build_world_model` adds to the machine's scene (via ``mujoco.MjSpec``):

- ``pile``: an hfield geom mirroring the environment's heightmap (:class:`hexgym.envs.earthwork.Pile`).
  It is drawn only (contype = conaffinity = 0): the bucket must enter it to dig; the digging
  resistance is applied by the environment.
- ``truck``: a mocap body (so that it moves between episodes without recompiling) with a bed
  whose floor and walls collide with the machine (contype 1 / conaffinity 2, like the ground), a
  chassis, a cab and wheels.
- ``truck_load`` and ``bucket_load``: drawn-only boxes/ellipsoids sized to the material in the
  truck and in the bucket.
- optionally ``tool_contacts``: a contact sensor of the stick's and bucket's contacts (the batched
  environment reads contacts through it).

:class:`World` holds the ids and moves things: :meth:`World.place` puts the truck and the pile
where a :class:`Layout` says, :meth:`World.show_pile` copies the heightmap into the hfield.
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

PILE_GRID_POINTS = 81  # per side
PILE_GRID_SPACING = 0.1  # m: 8 m x 8 m, finer than the bucket's 1.5 m edge by 15x
_PILE_SINK = 0.02  # m: the hfield's zero sits this far below the ground so the two do not flicker
_WALL = 0.08  # m, thickness of the bed's floor and walls
TRUCK_CAB_LENGTH = 1.8  # m, truck cab ahead of the bed
_WHEEL_RADIUS = 0.5  # m
_SOLID = {"contype": 1, "conaffinity": 2}  # as the ground: collides with the machine's geoms
_DRAWN = {"contype": 0, "conaffinity": 0, "group": 1, "density": 0.0}
_SAND = [0.78, 0.66, 0.45, 1.0]
_HIDDEN_SIZE = 1e-4  # m: a load geom with nothing in it
_LOAD_HALF_WIDTH = 0.65  # m: the drawn bucket load spans the bucket's inside width


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


def sample_layout(rng: np.random.Generator) -> Layout:
    """A random site: pile ahead, truck alongside on either side, both within reach."""
    pile_angle = rng.uniform(*p.PILE_SWING_RANGE)
    pile_distance = rng.uniform(*p.PILE_DISTANCE_RANGE)
    truck_angle = rng.uniform(*p.TRUCK_SWING_RANGE) * rng.choice((-1.0, 1.0))
    truck_distance = rng.uniform(*p.TRUCK_DISTANCE_RANGE)
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
    truck = spec.worldbody.add_body(name="truck", mocap=True, pos=[0, 20, 0])
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
    truck.add_geom(name="truck_load", type=box, rgba=_SAND, size=[half_l - 0.05, half_w - 0.05, _HIDDEN_SIZE],
                   pos=[0, 0, floor], **_DRAWN)  # fmt: skip


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


def _add_bucket_load(spec: mujoco.MjSpec) -> None:
    payload = spec.body("payload")
    if payload is None:
        raise AssetError("the machine model has no body 'payload' (the bucket's contents)")
    # centred a little inside the mouth (bucket frame ~(0.72, -0.25)): the full load bulges out as a heap
    payload.add_geom(name="bucket_load", type=mujoco.mjtGeom.mjGEOM_ELLIPSOID, rgba=_SAND, pos=[-0.08, 0, 0.05],
                     size=[_HIDDEN_SIZE] * 3, **_DRAWN)  # fmt: skip


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
        self.pile_geom = model.geom("pile").id
        self.pile_hfield = model.hfield("pile").id
        self._hfield_slice = slice(
            model.hfield_adr[self.pile_hfield], model.hfield_adr[self.pile_hfield] + PILE_GRID_POINTS**2
        )
        self._elevation = float(model.hfield_size[self.pile_hfield, 2])
        self.truck_mocap = model.body("truck").mocapid[0]
        self.truck_load = model.geom("truck_load").id
        self.bucket_load = model.geom("bucket_load").id
        self.tool_geoms = np.zeros(model.ngeom, bool)  # masks over geom ids: the stick's and bucket's
        self.tool_geoms[_geoms_of_bodies(model, ("stick", "bucket"))] = True
        self.obstacle_geoms = np.zeros(model.ngeom, bool)  # the ground's and the truck's
        self.obstacle_geoms[[model.geom("ground").id, *_geoms_of_bodies(model, ("truck",))]] = True

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
        """Size the drawn material in the bed and in the bucket."""
        m = self.model
        depth = min(truck_kg / p.MATERIAL_DENSITY / (p.TRUCK_BED_LENGTH * p.TRUCK_BED_WIDTH), p.TRUCK_BED_WALL_HEIGHT)
        m.geom_size[self.truck_load, 2] = max(depth / 2.0, _HIDDEN_SIZE)
        m.geom_pos[self.truck_load, 2] = p.TRUCK_BED_FLOOR_HEIGHT + depth / 2.0
        volume = bucket_kg / p.MATERIAL_DENSITY
        # an ellipsoid across the bucket's width: the heap's length and height grow as sqrt(volume)
        if volume <= 0:
            m.geom_size[self.bucket_load] = _HIDDEN_SIZE
            return
        half = np.sqrt(3.0 * volume / (4.0 * np.pi * _LOAD_HALF_WIDTH))
        m.geom_size[self.bucket_load] = [half, _LOAD_HALF_WIDTH, half]

    def in_bed(self, xy: np.ndarray, layout: Layout) -> bool:
        """Whether world point ``xy`` is over the bed's floor (inside its walls)."""
        return bool(over_bed(*bed_coordinates(float(xy[0]), float(xy[1]), layout)))

    @staticmethod
    def truck_frame(point: np.ndarray, layout: Layout) -> np.ndarray:
        """World ``point`` in the bed's frame: along the truck, across it, height above the rim (m)."""
        along, across = bed_coordinates(float(point[0]), float(point[1]), layout)
        return np.array([along, across, float(point[2]) - BED_RIM_HEIGHT])


BED_RIM_HEIGHT = p.TRUCK_BED_FLOOR_HEIGHT + p.TRUCK_BED_WALL_HEIGHT  # m above the ground


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

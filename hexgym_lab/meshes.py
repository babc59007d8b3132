"""Visual meshes of the excavator, generated with trimesh from :mod:`hexgym.machine.parameters`.

Every mesh is expressed in the MuJoCo body frame it is attached to (metres; x forward, y to
the machine's left, z up; a link's planar ``(x, z)`` point maps to ``(x, 0, z)``):

- ``undercarriage``: world frame, ground at z = 0, swing axis = z axis.
- ``upper_deck``, ``cab``, ``engine_housing``, ``counterweight``: upper frame, origin on the
  swing axis at the top of the swing bearing.
- ``boom``, ``stick``, ``bucket``: the planar link frames of :mod:`hexgym.machine.parameters`.
- ``guide_link``, ``power_link``: origin at the first pin, x along the link to the second.

Hydraulic cylinders are not meshes (they are MuJoCo primitive geoms). Pins, lengths and
widths come from :mod:`hexgym.machine.parameters`; the purely cosmetic sizes (plate thicknesses,
chamfers, window insets ...) are the module constants below. The meshes are built only from
lofts of convex rings and trimesh primitives, so no boolean or triangulation engine is needed.
Each mesh is a union of closed, outward-facing pieces that may interpenetrate: fine to look at,
not meant for inertia or collision. Run ``python -m hexgym_lab.meshes`` to regenerate
``assets/meshes/``.
"""

from __future__ import annotations

import pathlib

import numpy as np
import trimesh

from hexgym.files import atomic_path
from hexgym.machine import parameters as p
from hexgym.machine.bucket import BUCKET, bucket_profile

# --------------------------------------------------------------------------------------------
# Cosmetic sizes, m (visual only, nothing physical depends on them) [est from photos of 20-30 t
# machines].
SECTIONS = 24  # facets of round bosses and wheels: looks round, costs few faces
WELD = 0.01  # welded pieces overlap by this much so no seam shows
BOSS_PROUD = 0.03  # pin bosses stand this far proud of the plates they pierce
PLATE = 0.04  # link and bracket plates
CHAMFER = 0.03  # corners of the boom and stick box sections
EYE_RADIUS = 0.17  # brackets round a cylinder pin
PIN_BOSS_RADIUS = 0.12  # bosses of the cylinder pins
BRACKET_REACH = (0.45, 0.35)  # cylinder brackets run along the flange this far behind / ahead of their pin
CYLINDER_PIN_HALF_LENGTH = 0.48  # boom-cylinder pins reach cylinders beside the boom (|y| <= ~0.4)

# Undercarriage
SHOE_PITCH = 0.19  # track pitch (325 class: 190 mm)
SHOE_THICKNESS = 0.05  # shoe plate; the grouser rib stands on it
GROUSER_HEIGHT = 0.03
TRACK_FRAME_WIDTH = 0.55  # roller frame inside the loop, fraction of the shoe width
WHEEL_WIDTH = 0.80  # idler and sprocket, fraction of the shoe width
HUB = (0.35, 0.90)  # their hubs: fraction of the wheel radius, fraction of the shoe width
TRACK_RAIL = (0.24, 0.04)  # rail along the frame's side: depth, how far it stands out
CARBODY_BOTTOM = 0.45  # ground clearance under the car body
CARBODY_RADIUS = 0.95  # octagonal centre section under the swing bearing
CARBODY_BEAMS = (0.45, 0.70, 0.10)  # beams to the track frames: x of centres (+-), length, top below frame
BEARING_RADII = (0.62, 0.85)  # swing bearing ring, inner / outer
BEARING_HEIGHT = 0.15

# Upper structure
UPPER_HALF_WIDTH = 1.50  # the revolving frame is ~3.0 m wide
UPPER_FRONT = 1.60  # x of the front of the deck
DECK_THICKNESS = 0.20
DECK_CHAMFER = 0.15  # front corners of the deck plate
COUNTERWEIGHT_FRONT = -2.25  # x of the counterweight's front face (the deck's rear)
COUNTERWEIGHT_BOTTOM = -0.05  # z, ~1.05 m above ground
COUNTERWEIGHT_ROUNDING = 0.30  # radius of its top rear edge
HOOD_TOP = 1.35  # z of the engine hood (~2.45 m above ground); the counterweight is a little higher
HOOD_CHAMFER = 0.15
SIDE_COMPARTMENT_TOP = 1.00  # z of the tank / tool-box compartment top, right front
SIDE_CHAMFER = 0.25
BOOM_GAP = 0.20  # between the boom and the right-front compartment
CAB_GAP = 0.05  # between the cab and the deck front / the hood
CAB_BELT = 0.75  # the cab's window sill above the deck
CAB_FRONT_SLOPE = 0.35  # set-back of the windscreen's top edge
CAB_WINDOW_INSET = 0.03  # glass recessed behind the pillars
CAB_PILLAR = 0.08
CAB_DOOR = 0.45  # the door's front pillar, fraction of the cab's length from its rear
CAB_ROOF = (0.08, 0.03)  # thickness, overhang
EXHAUST = (0.07, 0.50, -0.90, -0.90)  # radius, length, (x, y) on the hood's right
HOOD_VENTS = ((-1.50, -0.60), (-0.75, 0.30))  # x and y extents of the grille box on the hood
FOOT_BRACKET = (0.66, 0.44, 0.22)  # boom-foot brackets: reach behind / ahead of the pin, radius round it
FOOT_PIN_RADIUS = 0.15

# Front linkage
BOOM_WIDTH = 0.58
BOOM_DEPTH_END = 0.45  # box depth at the foot and at the stick pin ...
BOOM_DEPTH_KNEE = 0.70  # ... and at the knee
BOOM_BEND_RADIUS = 1.50  # centreline fillet at the knee
STICK_WIDTH = (0.45, 0.40)  # at the stick pin, at the bucket pin
STICK_DEPTH = (0.50, 0.32)
STICK_HEAD_REACH = 0.70  # the head plate runs this far down the stick from the stick pin
STICK_HEAD_RADIUS = 0.16  # round the stick-cylinder rod pin
LINK_RADIUS = 0.11  # rounded ends of the guide / power link plates
LINK_TUBE_RADIUS = 0.06  # the power link's cross tube
GUIDE_LINK_Y = 0.25  # plate centre planes at y = +-this: straddle the stick
POWER_LINK_Y = 0.30  # straddle the bucket's ears

# Bucket
BUCKET_EAR_Y = (0.21, 0.27)  # ear plates, inner / outer |y|: straddle the stick's end
BUCKET_EAR_RADIUS = 0.16
BUCKET_EAR_WELD = 0.25  # each ear sits on this much wrapper either side of its pin's foot
BUCKET_PIN_BOSS = (0.13, 0.11)  # boss radius at the bucket pin, at the link pin
BUCKET_LIP_BAR = 0.05  # radius of the top lip's reinforcing bar
CUTTING_EDGE = (0.30, 0.06)  # length along the floor, thickness
TOOTH_BASE = (0.15, 0.13)  # width, height at the adapter
TOOTH_TIP = (0.09, 0.03)
TOOTH_ADAPTER = 0.12  # adapters reach this far back over the cutting edge
TEETH = 5

MESH_NAMES = (
    "undercarriage",
    "upper_deck",
    "cab",
    "engine_housing",
    "counterweight",
    "boom",
    "stick",
    "bucket",
    "guide_link",
    "power_link",
)

Planar = tuple[float, float] | np.ndarray


# --------------------------------------------------------------------------------------------
# Building blocks
def _loft(rings: list[np.ndarray]) -> trimesh.Trimesh:
    """Closed solid through a sequence of planar, strictly convex (N, 3) rings of equal N."""
    rings = [np.asarray(r, dtype=float) for r in rings]
    k, n = len(rings), len(rings[0])
    i = np.arange(n)
    j = (i + 1) % n
    faces = []
    for s in range(k - 1):
        a, b = s * n, (s + 1) * n
        faces += [np.column_stack([a + i, a + j, b + j]), np.column_stack([a + i, b + j, b + i])]
    f = np.arange(1, n - 1)  # end caps: fans from each end ring's first vertex
    zero = np.zeros(n - 2, dtype=int)
    faces += [np.column_stack([zero, f + 1, f]), (k - 1) * n + np.column_stack([zero, f, f + 1])]
    mesh = trimesh.Trimesh(np.vstack(rings), np.vstack(faces), process=False)
    if mesh.volume < 0:  # the rings' sense decides the winding: make the normals point outward
        mesh.invert()
    return mesh


def _xz(points: np.ndarray, y: float) -> np.ndarray:
    """Planar (x, z) points to 3D at a given y."""
    points = np.asarray(points, dtype=float)
    return np.column_stack([points[:, 0], np.full(len(points), y), points[:, 1]])


def _xy(points: np.ndarray, z: float) -> np.ndarray:
    """Plan (x, y) points to 3D at a given z."""
    points = np.asarray(points, dtype=float)
    return np.column_stack([points[:, 0], points[:, 1], np.full(len(points), z)])


def _prism_xz(polygon: np.ndarray, y0: float, y1: float) -> trimesh.Trimesh:
    """Convex (x, z) polygon extruded along y from y0 to y1."""
    return _loft([_xz(polygon, y0), _xz(polygon, y1)])


def _prism_xy(polygon: np.ndarray, z0: float, z1: float) -> trimesh.Trimesh:
    """Convex plan (x, y) polygon extruded along z from z0 to z1."""
    return _loft([_xy(polygon, z0), _xy(polygon, z1)])


def _plate(points: np.ndarray, y0: float, y1: float) -> trimesh.Trimesh:
    """The convex hull of planar (x, z) points as a plate from y0 to y1."""
    return _prism_xz(_hull(points), y0, y1)


def _mirrored_plates(points: np.ndarray, y_in: float, y_out: float) -> list[trimesh.Trimesh]:
    """A pair of plates, the hull of planar ``points``, between |y| = y_in and y_out."""
    return [_plate(points, y_in, y_out), _plate(points, -y_out, -y_in)]


def _cross(a: np.ndarray, b: np.ndarray) -> float:
    """z component of the cross product of two planar vectors."""
    return float(a[0] * b[1] - a[1] * b[0])


def _hull(points: np.ndarray) -> np.ndarray:
    """2D convex hull (Andrew's monotone chain), counter-clockwise, no collinear points."""
    pts = sorted({(round(float(x), 9), round(float(y), 9)) for x, y in np.asarray(points)})

    def half(seq: list[tuple[float, float]]) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        for q in seq:
            while len(out) >= 2 and _cross(np.subtract(out[-1], out[-2]), np.subtract(q, out[-2])) <= 1e-12:
                out.pop()
            out.append(q)
        return out[:-1]

    return np.array(half(pts) + half(pts[::-1]))


def _circle(center: Planar, radius: float, n: int = SECTIONS) -> np.ndarray:
    """n planar points on a circle."""
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return np.asarray(center, dtype=float) + radius * np.column_stack([np.cos(a), np.sin(a)])


def _boss(center: Planar, radius: float, y0: float, y1: float) -> trimesh.Trimesh:
    """A pin boss: a cylinder along y through planar (x, z) ``center``, from y0 to y1."""
    x, z = center
    pose = trimesh.transformations.rotation_matrix(-np.pi / 2.0, [1.0, 0.0, 0.0])  # z axis -> y axis
    pose[:3, 3] = [x, (y0 + y1) / 2.0, z]
    return trimesh.creation.cylinder(radius=radius, height=y1 - y0, sections=SECTIONS, transform=pose)


def _box(lo: tuple[float, float, float], hi: tuple[float, float, float]) -> trimesh.Trimesh:
    """Axis-aligned box between two corners."""
    lo_a, hi_a = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    pose = trimesh.transformations.translation_matrix((lo_a + hi_a) / 2.0)
    return trimesh.creation.box(extents=hi_a - lo_a, transform=pose)


def _section(center: np.ndarray, tangent: np.ndarray, half_depth: float, half_width: float) -> np.ndarray:
    """Chamfered rectangular box section (8, 3) of a link, normal to the planar ``tangent``."""
    normal = np.array([-tangent[1], tangent[0]]) / np.hypot(*tangent)
    h, w, c = half_depth, half_width, CHAMFER
    local = [(h, -w + c), (h, w - c), (h - c, w), (-h + c, w)]
    local += [(-a, -b) for a, b in local]  # the lower half mirrors the upper
    return np.array([(center[0] + a * normal[0], b, center[1] + a * normal[1]) for a, b in local])


def _concat(parts: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """One mesh of several closed pieces (vertices are not merged, so each piece stays closed)."""
    return trimesh.util.concatenate(parts)


def _polyline_frame(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangents and cumulative arc length of a planar polyline."""
    d = np.gradient(points, axis=0)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    return d / np.hypot(d[:, 0], d[:, 1])[:, None], s


def _rotation2(angle: float) -> np.ndarray:
    """2x2 counter-clockwise rotation (x toward z in a link's plane)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


# --------------------------------------------------------------------------------------------
# Undercarriage
def _stadium(length: float, radius: float, z_center: float, n_arc: int = 12) -> np.ndarray:
    """Convex (x, z) stadium, counter-clockwise: straight runs joined by semicircles."""
    xc = length / 2.0 - radius
    front = np.linspace(-np.pi / 2.0, np.pi / 2.0, n_arc + 1)
    rear = front + np.pi
    return np.vstack(
        [
            np.column_stack([xc + radius * np.cos(front), z_center + radius * np.sin(front)]),
            np.column_stack([-xc + radius * np.cos(rear), z_center + radius * np.sin(rear)]),
        ]
    )


def _shoe_poses(radius: float, straight: float, z_center: float) -> list[tuple[np.ndarray, float]]:
    """(x, z) centre and direction angle of each track shoe, once round the loop."""
    arc = np.pi * radius
    perimeter = 2.0 * (straight + arc)
    count = round(perimeter / SHOE_PITCH)
    poses = []
    for s in np.arange(count) * perimeter / count:
        if s < straight:  # bottom run, heading forward
            poses.append((np.array([-straight / 2.0 + s, z_center - radius]), 0.0))
        elif straight + arc <= s < 2.0 * straight + arc:  # top run, heading back
            poses.append((np.array([straight / 2.0 - (s - straight - arc), z_center + radius]), np.pi))
        else:  # round the front idler (angle 0..pi) or the rear sprocket (pi..2 pi)
            a = (s - straight) / radius if s < straight + arc else np.pi + (s - 2.0 * straight - arc) / radius
            x_wheel = straight / 2.0 if a < np.pi else -straight / 2.0
            poses.append((np.array([x_wheel + radius * np.sin(a), z_center - radius * np.cos(a)]), a))
    return poses


def _track_shoes(y_center: float) -> list[trimesh.Trimesh]:
    """The loop of shoes, each a plate with a grouser rib, outer envelope TRACK_LENGTH x TRACK_HEIGHT."""
    radius = p.TRACK_HEIGHT / 2.0
    half_w = p.TRACK_SHOE_WIDTH / 2.0
    rib = 0.5 + GROUSER_HEIGHT / SHOE_THICKNESS
    # outlines in (along / SHOE_PITCH, out / SHOE_THICKNESS) units, centred on the plate
    shapes = (
        np.array([[-0.45, -0.5], [0.45, -0.5], [0.45, 0.5], [-0.45, 0.5]]),
        np.array([[-0.08, 0.45], [0.08, 0.45], [0.05, rib], [-0.05, rib]]),
    )
    parts = []
    shoe_r = radius - GROUSER_HEIGHT - SHOE_THICKNESS / 2.0
    for center, angle in _shoe_poses(shoe_r, p.TRACK_LENGTH - p.TRACK_HEIGHT, radius):
        along = np.array([np.cos(angle), np.sin(angle)])
        out = np.array([np.sin(angle), -np.cos(angle)])  # away from the loop
        for shape in shapes:
            pts = center + np.outer(shape[:, 0] * SHOE_PITCH, along)
            pts += np.outer(shape[:, 1] * SHOE_THICKNESS, out)
            parts.append(_prism_xz(pts, y_center - half_w, y_center + half_w))
    return parts


def _track(y_center: float) -> list[trimesh.Trimesh]:
    """One crawler: roller frame with a side rail, idler and sprocket, and the shoes."""
    radius = p.TRACK_HEIGHT / 2.0
    half_w = p.TRACK_SHOE_WIDTH / 2.0
    straight = p.TRACK_LENGTH - p.TRACK_HEIGHT
    inner_r = radius - GROUSER_HEIGHT - SHOE_THICKNESS
    frame_w = TRACK_FRAME_WIDTH * half_w
    frame = _stadium(straight + 2.0 * inner_r, inner_r, radius)
    parts = [_prism_xz(frame, y_center - frame_w, y_center + frame_w)]
    wheel_r = inner_r - 2.0 * WELD
    wheel_w, hub_w = WHEEL_WIDTH * half_w, HUB[1] * half_w
    for x in (-straight / 2.0, straight / 2.0):  # sprocket (rear) and idler (front)
        parts.append(_boss((x, radius), wheel_r, y_center - wheel_w, y_center + wheel_w))
        parts.append(_boss((x, radius), HUB[0] * wheel_r, y_center - hub_w, y_center + hub_w))
    rail_h, rail_w = TRACK_RAIL[0] / 2.0, frame_w + TRACK_RAIL[1]
    rail_lo = (-straight / 2.0, y_center - rail_w, radius - rail_h)
    parts.append(_box(rail_lo, (straight / 2.0, y_center + rail_w, radius + rail_h)))
    return parts + _track_shoes(y_center)


def _undercarriage() -> trimesh.Trimesh:
    """Two crawlers, the car body between them and the swing bearing ring on top."""
    half_gauge = p.TRACK_GAUGE / 2.0
    frame_inner = half_gauge - TRACK_FRAME_WIDTH * p.TRACK_SHOE_WIDTH / 2.0
    bearing_bottom = p.SWING_BEARING_HEIGHT - BEARING_HEIGHT
    octagon = _circle((0.0, 0.0), CARBODY_RADIUS / np.cos(np.pi / 8.0), 8) @ _rotation2(np.pi / 8.0).T
    parts = [*_track(half_gauge), *_track(-half_gauge), _prism_xy(octagon, CARBODY_BOTTOM, bearing_bottom)]
    x_beam, beam_len, beam_drop = CARBODY_BEAMS
    for x in (-x_beam, x_beam):  # the cross beams run into the track frames
        lo = (x - beam_len / 2.0, -frame_inner - 5 * WELD, CARBODY_BOTTOM + 5 * WELD)
        parts.append(_box(lo, (x + beam_len / 2.0, frame_inner + 5 * WELD, p.TRACK_HEIGHT - beam_drop)))
    ring = trimesh.creation.annulus(
        r_min=BEARING_RADII[0], r_max=BEARING_RADII[1], height=BEARING_HEIGHT, sections=2 * SECTIONS
    )
    ring.apply_translation([0.0, 0.0, p.SWING_BEARING_HEIGHT - BEARING_HEIGHT / 2.0])
    return _concat([*parts, ring])


# --------------------------------------------------------------------------------------------
# Upper structure
def _upper_deck() -> trimesh.Trimesh:
    """Revolving frame plate, the boom-foot brackets and the boom cylinders' base boss."""
    w, c = UPPER_HALF_WIDTH, DECK_CHAMFER
    xf, xr = UPPER_FRONT, COUNTERWEIGHT_FRONT
    plan = np.array([[xr, -w], [xf - c, -w], [xf, -w + c], [xf, w - c], [xf - c, w], [xr, w]])
    foot = np.array(p.BOOM_FOOT)
    behind, ahead, around = FOOT_BRACKET
    z_weld = DECK_THICKNESS - WELD
    bracket = np.vstack([_circle(foot, around), [[foot[0] - behind, z_weld], [foot[0] + ahead, z_weld]]])
    y_in = BOOM_WIDTH / 2.0 + 2 * WELD
    y_out = y_in + PLATE
    return _concat(
        [
            _prism_xy(plan, 0.0, DECK_THICKNESS),
            *_mirrored_plates(bracket, y_in, y_out),
            _boss(foot, FOOT_PIN_RADIUS, y_in - BOSS_PROUD, y_out + BOSS_PROUD),
            _boss(foot, FOOT_PIN_RADIUS, -y_out - BOSS_PROUD, -y_in + BOSS_PROUD),
            _boss(p.BOOM_CYLINDER_BASE, PIN_BOSS_RADIUS, -CYLINDER_PIN_HALF_LENGTH, CYLINDER_PIN_HALF_LENGTH),
        ]
    )


def _cab() -> trimesh.Trimesh:
    """Operator's cab, front left: lower body, recessed glass, pillars and roof."""
    x1 = UPPER_FRONT - CAB_GAP
    x0 = x1 - p.CAB_SIZE[0]
    y1 = UPPER_HALF_WIDTH
    y0 = y1 - p.CAB_SIZE[1]
    z0, z_belt = DECK_THICKNESS, DECK_THICKNESS + CAB_BELT
    z_roof = p.CAB_ROOF_HEIGHT - p.SWING_BEARING_HEIGHT
    roof_t, over = CAB_ROOF
    z_eave = z_roof - roof_t
    x_top = x1 - CAB_FRONT_SLOPE  # the windscreen's top edge
    i, q = CAB_WINDOW_INSET, CAB_PILLAR
    glass = np.array([[x0 + i, z_belt], [x1 - i, z_belt], [x_top - i, z_eave], [x0 + i, z_eave]])
    roof = np.array([[x0 - over, z_eave], [x_top + over, z_eave], [x_top, z_roof], [x0 - over, z_roof]])
    parts = [
        _box((x0, y0, z0), (x1, y1, z_belt)),
        _prism_xz(glass, y0 + i, y1 - i),
        _prism_xz(roof, y0 - over, y1 + over),
    ]
    square = np.array([[0.0, 0.0], [q, 0.0], [q, q], [0.0, q]])
    for y in (y0, y1 - q):  # A pillars follow the sloped windscreen, the rear pillars are upright
        for x_low, x_high in ((x1 - q, x_top - q), (x0, x0)):
            low = _xy(square + (x_low, y), z_belt - WELD)
            high = _xy(square + (x_high, y), z_eave + WELD)
            parts.append(_loft([low, high]))
    x_door = x0 + CAB_DOOR * p.CAB_SIZE[0]  # the door's front pillar splits the left side glass
    parts.append(_box((x_door, y1 - q, z_belt - WELD), (x_door + q, y1, z_eave + WELD)))
    return _concat(parts)


def _engine_housing() -> trimesh.Trimesh:
    """Engine hood behind the cab and the tank / tool-box compartments on the right front."""
    w = UPPER_HALF_WIDTH
    x_hood = UPPER_FRONT - 2.0 * CAB_GAP - p.CAB_SIZE[0]  # the hood's front, behind the cab
    x_front = UPPER_FRONT - CAB_GAP
    z0 = DECK_THICKNESS - WELD
    x_rear, top, cut = COUNTERWEIGHT_FRONT, HOOD_TOP, HOOD_CHAMFER
    hood = np.array([[x_rear, z0], [x_hood, z0], [x_hood, top - cut], [x_hood - cut, top], [x_rear, top]])
    x_rear, top, cut = x_hood - 2 * WELD, SIDE_COMPARTMENT_TOP, SIDE_CHAMFER
    side = np.array([[x_rear, z0], [x_front, z0], [x_front, top - cut], [x_front - cut, top], [x_rear, top]])
    exhaust = trimesh.creation.cylinder(radius=EXHAUST[0], height=EXHAUST[1], sections=SECTIONS // 2)
    exhaust.apply_translation([*EXHAUST[2:], HOOD_TOP + EXHAUST[1] / 2.0 - 5 * WELD])
    (vx0, vx1), (vy0, vy1) = HOOD_VENTS
    vents = _box((vx0, vy0, HOOD_TOP - WELD), (vx1, vy1, HOOD_TOP + 5 * WELD))
    return _concat(
        [
            _prism_xz(hood, -w + 2 * WELD, w - 2 * WELD),
            _prism_xz(side, -w + 2 * WELD, -(BOOM_WIDTH / 2.0 + BOOM_GAP)),
            vents,
            exhaust,
        ]
    )


def _counterweight() -> trimesh.Trimesh:
    """Counterweight with its rear on the tail-swing radius about the swing axis, top rear edge rounded."""
    w = UPPER_HALF_WIDTH
    r_top = COUNTERWEIGHT_ROUNDING
    z0, z1 = COUNTERWEIGHT_BOTTOM, HOOD_TOP + 5 * WELD
    # (z, set-back of the rear face from the tail-swing radius): a chamfer at the bottom, a round on top
    levels = [(z0, 8 * WELD), (z0 + 8 * WELD, 0.0)]
    quarter = np.linspace(0.0, np.pi / 2.0, 6)
    levels += [(z1 - r_top * (1.0 - np.sin(a)), r_top * (1.0 - np.cos(a))) for a in quarter]
    rings = []
    for z, setback in levels:
        r = p.TAIL_SWING_RADIUS - setback
        half = np.arcsin(w / r)
        arc = np.pi + np.linspace(-half, half, 17)  # +y (left) round the back to -y, through x = -r
        rear = np.column_stack([r * np.cos(arc), r * np.sin(arc)])
        rings.append(_xy(np.vstack([[[COUNTERWEIGHT_FRONT, w]], rear, [[COUNTERWEIGHT_FRONT, -w]]]), z))
    return _loft(rings)


# --------------------------------------------------------------------------------------------
# Boom and stick
def _boom_centreline() -> np.ndarray:
    """Foot pin -> knee -> stick pin, the knee rounded with BOOM_BEND_RADIUS."""
    a, k, b = np.zeros(2), np.array(p.BOOM_KNEE), np.array([p.BOOM_LENGTH, 0.0])
    u1, u2 = (k - a) / np.hypot(*(k - a)), (b - k) / np.hypot(*(b - k))
    cut = BOOM_BEND_RADIUS * np.tan(np.arccos(np.clip(u1 @ u2, -1.0, 1.0)) / 2.0)
    t1, t2 = k - cut * u1, k + cut * u2
    center = t1 + BOOM_BEND_RADIUS * np.array([u1[1], -u1[0]])  # below: the boom bends down at the knee
    angles = np.linspace(np.arctan2(*(t1 - center)[::-1]), np.arctan2(*(t2 - center)[::-1]), 8)
    arc = center + BOOM_BEND_RADIUS * np.column_stack([np.cos(angles), np.sin(angles)])
    leg1 = a + np.outer(np.linspace(0.0, 1.0, 4)[:-1], t1 - a)
    leg2 = t2 + np.outer(np.linspace(0.0, 1.0, 5)[1:], b - t2)
    return np.vstack([leg1, arc, leg2])


def _flange_points(line: np.ndarray, depth: np.ndarray, pin: np.ndarray, side: float) -> np.ndarray:
    """Two points just inside the top (side=+1) or bottom (-1) flange of a link, either side of a pin."""
    tangents, _ = _polyline_frame(line)
    out = []
    for x in (pin[0] - BRACKET_REACH[0], pin[0] + BRACKET_REACH[1]):
        i = int(np.argmin(np.abs(line[:, 0] - x)))
        center = np.array([x, np.interp(x, line[:, 0], line[:, 1])])
        normal = np.array([-tangents[i, 1], tangents[i, 0]])
        out.append(center + side * (np.interp(x, line[:, 0], depth) / 2.0 - 2 * WELD) * normal)
    return np.array(out)


def _boom() -> trimesh.Trimesh:
    """Box-section banana boom with bosses and the boom- and stick-cylinder brackets."""
    line = _boom_centreline()
    tangents, s = _polyline_frame(line)
    s_knee = s[np.argmin(np.hypot(*(line - np.array(p.BOOM_KNEE)).T))]
    depth = np.interp(s, [0.0, s_knee, s[-1]], [BOOM_DEPTH_END, BOOM_DEPTH_KNEE, BOOM_DEPTH_END])
    hw = BOOM_WIDTH / 2.0
    rod, base = np.array(p.BOOM_CYLINDER_ROD_PIN), np.array(p.STICK_CYLINDER_BASE)
    under = np.vstack([_circle(rod, EYE_RADIUS), _flange_points(line, depth, rod, -1.0)])
    over = np.vstack([_circle(base, EYE_RADIUS), _flange_points(line, depth, base, 1.0)])
    end_r, y_end = BOOM_DEPTH_END / 2.0, hw + BOSS_PROUD
    return _concat(
        [
            _loft([_section(c, t, d / 2.0, hw) for c, t, d in zip(line, tangents, depth, strict=True)]),
            _boss((0.0, 0.0), end_r, -y_end, y_end),
            _boss((p.BOOM_LENGTH, 0.0), end_r, -y_end, y_end),
            _plate(under, -hw + PLATE, hw - PLATE),  # boom cylinders' rod-end bracket, under the boom
            _boss(rod, PIN_BOSS_RADIUS, -CYLINDER_PIN_HALF_LENGTH, CYLINDER_PIN_HALF_LENGTH),
            _plate(over, -hw + 2 * PLATE, hw - 2 * PLATE),  # stick cylinder's base bracket, on top
            _boss(base, PIN_BOSS_RADIUS, -hw + PLATE, hw - PLATE),
        ]
    )


def _stick() -> trimesh.Trimesh:
    """Tapered box-section stick, its head up to the stick-cylinder pin, brackets and bosses."""
    length = p.STICK_LENGTH
    line = np.array([[0.0, 0.0], [length, 0.0]])
    depth, width = np.array(STICK_DEPTH), np.array(STICK_WIDTH)
    hw0, hw1 = width / 2.0
    rod, base, pivot = np.array([p.STICK_CYLINDER_ROD_PIN, p.BUCKET_CYLINDER_BASE, p.GUIDE_LINK_PIVOT])
    reach = STICK_HEAD_REACH
    half_depth = np.interp(reach, line[:, 0], depth) / 2.0 - WELD
    head = np.vstack(
        [
            _circle(rod, STICK_HEAD_RADIUS),
            _circle((0.0, 0.0), depth[0] / 2.0),
            [[reach, half_depth], [reach, -half_depth]],
        ]
    )
    base_bracket = np.vstack([_circle(base, PIN_BOSS_RADIUS + PLATE), _flange_points(line, depth, base, 1.0)])
    pivot_bracket = np.vstack([_circle(pivot, LINK_RADIUS + WELD), _flange_points(line, depth, pivot, 1.0)])
    hw_pivot = float(np.interp(pivot[0], line[:, 0], width)) / 2.0
    y_pivot = GUIDE_LINK_Y - PLATE / 2.0  # between the guide link's plates
    along = line[1] - line[0]
    box = [_section(c, along, d / 2.0, w / 2.0) for c, d, w in zip(line, depth, width, strict=True)]
    return _concat(
        [
            _loft(box),
            _plate(head, -hw0, hw0),
            _plate(base_bracket, -hw0 + PLATE, hw0 - PLATE),
            _plate(pivot_bracket, -hw_pivot, hw_pivot),
            _boss((0.0, 0.0), depth[0] / 2.0 - WELD, -hw0 - BOSS_PROUD, hw0 + BOSS_PROUD),
            _boss(rod, STICK_HEAD_RADIUS - 3 * WELD, -hw0 + PLATE, hw0 - PLATE),
            _boss(base, PIN_BOSS_RADIUS - WELD, -hw0 + PLATE, hw0 - PLATE),
            _boss(pivot, LINK_RADIUS - 2 * WELD, -y_pivot, y_pivot),
            _boss((length, 0.0), depth[1] / 2.0, -hw1 - WELD / 2.0, hw1 + WELD / 2.0),
        ]
    )


# --------------------------------------------------------------------------------------------
# Bucket
def _outward_normals(curve: np.ndarray) -> np.ndarray:
    """Unit normals of the (convex) wrapper curve, pointing away from the bucket's inside."""
    tangents, _ = _polyline_frame(curve)
    normals = np.column_stack([tangents[:, 1], -tangents[:, 0]])
    mid = len(curve) // 2
    return normals if normals[mid] @ (curve[mid] - curve.mean(axis=0)) > 0 else -normals


def _bucket() -> trimesh.Trimesh:
    """Bucket shell: wrapper plate, side plates, cutting edge, teeth, lip bar, ears and bosses."""
    prof = bucket_profile()
    inner, edge, floor = prof.inner, prof.edge, prof.floor
    normals = _outward_normals(inner)
    outer = inner + p.BUCKET_PLATE * normals
    yi, yo = prof.width / 2.0, p.BUCKET_WIDTH / 2.0
    wrapper = [
        np.array([(a[0], -yi, a[1]), (a[0], yi, a[1]), (b[0], yi, b[1]), (b[0], -yi, b[1])])
        for a, b in zip(inner, outer, strict=True)
    ]
    ce_len, ce_t = CUTTING_EDGE  # thicker plate at the front of the floor, bevelled to the edge
    back = edge + ce_len * floor
    thick = ce_t * normals[-1]
    cutting_edge = np.array([edge, back, back + thick, edge + 5 * WELD * floor + thick])
    lip_bar = prof.lip + (BUCKET_LIP_BAR - 2 * WELD) * normals[0]
    return _concat(
        [
            _loft(wrapper),
            *_mirrored_plates(np.vstack([outer, inner[[0, -1]]]), yi - WELD / 5.0, yo),
            _plate(cutting_edge, -yo, yo),
            *_teeth(edge, floor, normals[-1], yo),
            _boss(lip_bar, BUCKET_LIP_BAR, -yo, yo),
            *_bucket_ears(outer),
        ]
    )


def _teeth(edge: np.ndarray, floor: np.ndarray, normal: np.ndarray, half_w: float) -> list[trimesh.Trimesh]:
    """TEETH tapered teeth along the cutting edge, their tips on the tip line through BUCKET_TIP."""
    base = edge + TOOTH_ADAPTER * floor + CUTTING_EDGE[1] / 2.0 * normal  # on the cutting edge's mid-plane
    tip = np.array(p.BUCKET_TIP)
    y_first = -half_w + TOOTH_BASE[0]
    pitch = -2.0 * y_first / (TEETH - 1)
    out = []
    for y in y_first + pitch * np.arange(TEETH):
        rings = []
        for c, (w, h) in ((base, TOOTH_BASE), (tip, TOOTH_TIP)):
            corners = np.array([(-h, -w), (-h, w), (h, w), (h, -w)]) / 2.0  # (along normal, along y)
            rings.append(np.array([(c[0] + a * normal[0], y + b, c[1] + a * normal[1]) for a, b in corners]))
        out.append(_loft(rings))
    return out


def _bucket_ears(outer: np.ndarray) -> list[trimesh.Trimesh]:
    """Ear plates carrying the bucket pin and the link pin, welded on the wrapper, and their bosses."""
    pin, link = np.zeros(2), np.array(p.BUCKET_LINK_PIN)
    y_in, y_out = BUCKET_EAR_Y
    r = BUCKET_EAR_RADIUS
    parts = _mirrored_plates(np.vstack([_circle(pin, r), _circle(link, 0.9 * r)]), y_in, y_out)
    _, s = _polyline_frame(outer)
    for c in (pin, link):  # a hull over a short stretch of the wrapper stays within its thickness
        foot = int(np.argmin(np.hypot(*(outer - c).T)))
        into_plate = WELD * (outer[foot] - c) / np.hypot(*(outer[foot] - c))
        seat = outer[np.abs(s - s[foot]) < BUCKET_EAR_WELD] + into_plate
        parts += _mirrored_plates(np.vstack([_circle(c, 0.9 * r), seat]), y_in, y_out)
    y_boss = y_out + WELD
    bosses = zip((pin, link), BUCKET_PIN_BOSS, strict=True)
    return parts + [_boss(c, radius, -y_boss, y_boss) for c, radius in bosses]


# --------------------------------------------------------------------------------------------
# Bucket linkage
def _link(length: float, y_center: float, cross_tube: bool) -> trimesh.Trimesh:
    """Two dog-bone plates at y = +-y_center from (0,0,0) to (length,0,0), with bosses."""
    ends = np.vstack([_circle((0.0, 0.0), LINK_RADIUS), _circle((length, 0.0), LINK_RADIUS)])
    y_in, y_out = y_center - PLATE / 2.0, y_center + PLATE / 2.0
    parts = _mirrored_plates(ends, y_in, y_out)
    lo, hi = y_in - BOSS_PROUD / 2.0, y_out + BOSS_PROUD / 2.0
    for x in (0.0, length):
        parts += [_boss((x, 0.0), 0.75 * LINK_RADIUS, lo, hi), _boss((x, 0.0), 0.75 * LINK_RADIUS, -hi, -lo)]
    if cross_tube:  # the power link is an H
        parts.append(_boss((length / 2.0, 0.0), LINK_TUBE_RADIUS, -y_in - WELD / 2.0, y_in + WELD / 2.0))
    return _concat(parts)


def _guide_link() -> trimesh.Trimesh:
    """Guide link: its pivot on the stick at the origin, the bucket cylinder's rod joint at +x."""
    return _link(p.GUIDE_LINK_LENGTH, GUIDE_LINK_Y, cross_tube=False)


def _power_link() -> trimesh.Trimesh:
    """Power (H) link: the bucket cylinder's rod joint at the origin, the bucket's link pin at +x."""
    return _link(p.POWER_LINK_LENGTH, POWER_LINK_Y, cross_tube=True)


# --------------------------------------------------------------------------------------------
# Public API
_BUILDERS = {
    "undercarriage": _undercarriage,
    "upper_deck": _upper_deck,
    "cab": _cab,
    "engine_housing": _engine_housing,
    "counterweight": _counterweight,
    "boom": _boom,
    "stick": _stick,
    "bucket": _bucket,
    "guide_link": _guide_link,
    "power_link": _power_link,
}


def build_meshes() -> dict[str, trimesh.Trimesh]:
    """Build every visual mesh: name -> mesh in its MuJoCo body frame (see the module docstring)."""
    return {name: _BUILDERS[name]() for name in MESH_NAMES}


def write_meshes(directory: pathlib.Path) -> list[pathlib.Path]:
    """Write every mesh as binary ``<name>.stl`` into ``directory`` (created if missing).

    Each file goes to a temporary file beside it and is then renamed over the target, so a
    reader never sees a partial file; the bytes are the same on every run. Returns the paths in
    MESH_NAMES order.
    """
    directory = pathlib.Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, mesh in build_meshes().items():
        path = directory / f"{name}.stl"
        with atomic_path(path) as tmp:
            tmp.write_bytes(trimesh.exchange.stl.export_stl(mesh))
        paths.append(path)
    return paths


if __name__ == "__main__":
    out_dir = pathlib.Path(__file__).resolve().parents[1] / "assets" / "meshes"
    for written in write_meshes(out_dir):
        n_faces = (written.stat().st_size - 84) // 50  # binary STL: 84-byte header, 50 bytes a face
        print(f"{written}: {written.stat().st_size} bytes, {n_faces} faces")
    print(f"bucket struck volume {BUCKET.struck_capacity:.3f} m^3, heaped {BUCKET.heaped_capacity:.3f} m^3")

"""Earthwork of the loading task: the pile, digging, the bucket's contents, spills and the truck.

The bucket's pose and velocity come in (world frame, SI); the digging resistance and where
material went come out. Material lives in exactly four stores, the pile (a heightmap), the
bucket, the truck and the ground (spilled), and only moves between them, so their sum is constant
(:meth:`Earthwork.total_kg`).

- **Pile**: heights on a vertex grid (the MuJoCo hfield's layout), a flat-topped heap whose flanks
  stand at the angle of repose. Digging lowers the surface under the cutting edge; a local
  avalanche step then lets slopes steeper than the angle of repose slide.
- **Digging**: the edge takes material at ``width x depth x (edge speed along the teeth)``: the
  fill rate grows with the cutting depth and falls with the attack angle between the teeth and
  the motion (zero when the bucket moves backwards). Resistance is the fundamental earthmoving
  equation (Reece 1964, with McKyes' factors for a flat blade; no cohesion):
  ``F = w (gamma d^2 N_gamma + q d N_q)``, the surcharge ``q`` being the weight of the material
  already in the bucket over its mouth; the failure plane minimises the force. It acts against
  the edge's motion in the arm's plane; across it, a bucket pushed sideways meets the passive
  earth pressure on its leading side plate (Coulomb), so it cannot be swung through the pile.
- **Contents**: buried in the pile, the bucket fills to its heaped capacity whatever its tilt.
  Out of it, the bucket holds its heaped capacity with the mouth facing up, its struck
  capacity once tilted to the angle of repose, nothing once the mouth faces down past it. What it
  cannot hold leaves with a short time constant, into the truck when the caller says it falls
  in the bed, otherwise onto the ground.

The arithmetic is written once, as numba-compiled functions of one site of a stack of piles
(``heights[i]`` of an ``(N, n, n)`` array, its grid origin ``origin[i]``): the loading task
(:mod:`hexgym.envs.task`) calls them for each of its N sites, and :class:`Pile` and
:class:`Earthwork` are one-site handles on the same functions (an environment's ``earth``: a view of the task's
pile and stores; tests, tools, agents).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hexgym.envs.compiled import jit
from hexgym.machine import parameters as p
from hexgym.machine.bucket import BUCKET

_GRAVITY = float(p.GRAVITY)
EDGE_SAMPLES = 5  # points along the cutting edge where the depth is measured
RELAX_ITERATIONS = 3  # avalanche passes after each cut
_RAKE_LIMITS = np.radians((5.0, 90.0))  # rake angles outside this are treated as at the limit
EDGE_OFFSETS = np.linspace(-p.BUCKET_WIDTH / 2.0, p.BUCKET_WIDTH / 2.0, EDGE_SAMPLES)
_MOUTH_LENGTH = BUCKET.mouth_length  # strike line, m
# plain floats for the compiled functions (numba freezes globals at compile time)
_WIDTH = float(p.BUCKET_WIDTH)
_DENSITY = float(p.MATERIAL_DENSITY)
_HEAPED = float(p.BUCKET_HEAPED_CAPACITY)
_STRUCK = BUCKET.struck_capacity
_REPOSE = float(p.MATERIAL_REPOSE_ANGLE)
_SPILL_TIME = float(p.BUCKET_SPILL_TIME_CONSTANT)
_REFERENCE_SPEED = float(p.DIG_REFERENCE_SPEED)
# Coulomb's passive earth pressure coefficient of a vertical steel wall (friction delta) against level material:
# a side plate pushed sideways through the pile, K_p = cos^2 phi / (cos delta (1 - sqrt(sin(phi + delta) sin phi /
# cos delta))^2) (Rankine's tan^2(45 + phi/2) at delta = 0)
_PHI, _DELTA = float(p.MATERIAL_FRICTION_ANGLE), float(p.MATERIAL_TOOL_FRICTION_ANGLE)
_PASSIVE = math.cos(_PHI) ** 2 / (
    math.cos(_DELTA) * (1.0 - math.sqrt(math.sin(_PHI + _DELTA) * math.sin(_PHI) / math.cos(_DELTA))) ** 2
)
BUCKET_STORE, TRUCK_STORE, SPILLED_STORE = range(3)  # columns of a site's stores (kg): in the bucket, truck, spilled


def earthmoving_factors(
    rake: np.ndarray | float,
    friction: float = p.MATERIAL_FRICTION_ANGLE,
    tool_friction: float = p.MATERIAL_TOOL_FRICTION_ANGLE,
) -> tuple[np.ndarray, np.ndarray]:
    """N_gamma and N_q of the fundamental earthmoving equation for a flat blade at ``rake`` (rad).

    McKyes (1985): ``N_gamma = (cot b + cot r) / (2 [cos(b + d) + sin(b + d) cot(r + f)])`` and
    ``N_q`` twice that, minimised over the failure-plane angle ``r`` (the soil fails where it
    resists least).
    """
    rake = np.atleast_1d(np.asarray(rake, dtype=float))[:, None]
    failure = np.radians(np.linspace(1.0, 89.0, 177))[None, :]
    denominator = np.cos(rake + tool_friction) + np.sin(rake + tool_friction) / np.tan(failure + friction)
    wedge = 1.0 / np.tan(rake) + 1.0 / np.tan(failure)
    n_q = np.where(denominator > 1e-3, wedge / np.maximum(denominator, 1e-3), np.inf).min(axis=1)
    return n_q / 2.0, n_q


# N_gamma tabulated over the rake (the failure-plane search is too slow for every period)
_N_GAMMA = earthmoving_factors(np.linspace(*_RAKE_LIMITS, 171))[0]
_N_GAMMA_START, _N_GAMMA_STEP = float(_RAKE_LIMITS[0]), float((_RAKE_LIMITS[1] - _RAKE_LIMITS[0]) / 170)


@jit
def table_at(values: np.ndarray, start: float, step: float, x: float) -> float:
    """A function tabulated at ``start + k step`` (``values``), linearly interpolated at ``x``, clamped at the ends
    (:class:`hexgym.interpolation.UniformTable`'s arithmetic)."""
    u = (x - start) / step
    last = len(values) - 1
    if u <= 0.0:
        return values[0]
    if u >= last:
        return values[last]
    i = int(u)
    lo = values[i]
    return lo + (values[i + 1] - lo) * (u - i)


@jit
def earthmoving_force(depth: float, n_gamma: float, surcharge_pa: float, density: float = _DENSITY) -> float:
    """The fundamental earthmoving equation without cohesion: ``w (gamma d^2 N_gamma + q d N_q)`` with
    ``N_q = 2 N_gamma`` (McKyes' flat blade), N, for the bucket's edge in material of ``density`` (kg/m^3; its unit
    weight ``gamma``)."""
    return _WIDTH * (density * _GRAVITY * depth**2 * n_gamma + surcharge_pa * depth * 2.0 * n_gamma)


@jit
def surcharge_pressure(bucket_volume: float, density: float = _DENSITY) -> float:
    """Pressure (Pa) of the bucket's contents (m^3 of material of ``density``, kg/m^3) spread over its mouth: the
    earthmoving equation's surcharge."""
    return density * _GRAVITY * bucket_volume / (_WIDTH * _MOUTH_LENGTH)


@jit
def _magnitude(depth: float, rake: float, surcharge_pa: float, density: float) -> float:
    """The earthmoving force's magnitude (N) at ``depth`` and ``rake``, from the tabulated N_gamma."""
    if depth <= 0.0:
        return 0.0
    return earthmoving_force(depth, table_at(_N_GAMMA, _N_GAMMA_START, _N_GAMMA_STEP, rake), surcharge_pa, density)


def digging_resistance(depth: float, rake: float, surcharge_pa: float, density: float = p.MATERIAL_DENSITY) -> float:
    """Magnitude (N) of the earthmoving force on the bucket's edge cutting ``depth`` m deep at ``rake``
    (rakes outside 5-90 degrees count as at the limit) in material of ``density`` (kg/m^3)."""
    return float(_magnitude(float(depth), float(rake), float(surcharge_pa), float(density)))


@jit
def retained_volume(tilt: float) -> float:
    """Material (m^3) the bucket holds with its mouth tilted ``tilt`` rad from facing straight up: heaped
    mouth-up, struck at the angle of repose, nothing 90 degrees past it (linear between)."""
    if tilt <= 0.0:
        return _HEAPED
    if tilt <= _REPOSE:
        return _HEAPED + (_STRUCK - _HEAPED) * (tilt / _REPOSE)
    if tilt < math.pi / 2.0 + _REPOSE:
        return _STRUCK * (1.0 - (tilt - _REPOSE) / (math.pi / 2.0))
    return 0.0


def retained_volumes(tilt: np.ndarray) -> np.ndarray:
    """:func:`retained_volume` of an array of tilts (rad), elementwise (m^3; its three straight pieces)."""
    return np.interp(tilt, (0.0, _REPOSE, math.pi / 2.0 + _REPOSE), (_HEAPED, _STRUCK, 0.0))


@jit
def spill_out(bucket_kg: float, tilt: float, dt: float, density: float = _DENSITY) -> float:
    """Material (kg) that runs out of a bucket holding ``bucket_kg`` at ``tilt`` over ``dt`` s: the excess over
    :func:`retained_volume` (of material of ``density``, kg/m^3) with a time constant; the last kilogram goes too
    (not asymptotically)."""
    if bucket_kg <= 0.0:
        return 0.0
    excess = bucket_kg - retained_volume(tilt) * density
    if excess <= 0.0:
        return 0.0
    out = excess * (1.0 - math.exp(-dt / _SPILL_TIME))
    if bucket_kg - out < 1.0:
        out = bucket_kg
    return min(out, bucket_kg)


@jit
def resistance(
    depth: float, bucket_kg: float, lx: float, ly: float, lz: float, tx: float, ty: float, tz: float,
    vx: float, vy: float, vz: float, density: float = _DENSITY,
) -> tuple[float, float, float]:  # fmt: skip
    """The earthmoving force (N, world) on the bucket ``depth`` m deep in the pile with ``bucket_kg`` already in
    it, against its edge's velocity ``v`` (each part full above ``DIG_REFERENCE_SPEED``, in proportion below);
    ``l`` the unit vector along the edge, ``t`` the teeth's direction; the material of ``density`` (kg/m^3). In the
    arm's plane the edge cuts (the earthmoving equation); across it the leading side plate pushes the pile
    (:func:`side_plate_force`)."""
    speed = math.sqrt(vx * vx + vy * vy + vz * vz)
    ux, uy = (vx / speed, vy / speed) if speed > 1e-9 else (tx, ty)  # direction of travel
    horizontal = math.hypot(ux, uy)
    forward = (tx * ux + ty * uy) / horizontal if horizontal > 1e-9 else 0.0
    rake = math.atan2(-tz, forward)
    magnitude = _magnitude(depth, rake, surcharge_pressure(bucket_kg / density, density), density)
    scale = -magnitude / max(speed, _REFERENCE_SPEED)
    fx, fy, fz = scale * vx, scale * vy, scale * vz
    sideways = fx * lx + fy * ly + fz * lz
    across = vx * lx + vy * ly + vz * lz  # the edge's speed along itself: the side plate's push
    side = -side_plate_force(depth, density) * across / max(abs(across), _REFERENCE_SPEED)
    return fx + (side - sideways) * lx, fy + (side - sideways) * ly, fz + (side - sideways) * lz


@jit
def side_plate_force(depth: float, density: float = _DENSITY) -> float:
    """Passive earth force (N) on a side plate pushed sideways ``depth`` m deep into the pile of material of
    ``density`` (kg/m^3; Coulomb, with the steel's wall friction, no cohesion): ``K_p gamma d^2 / 2`` over the
    plate's length, the mouth's strike line."""
    if depth <= 0.0:
        return 0.0
    return 0.5 * _PASSIVE * density * _GRAVITY * depth * depth * _MOUTH_LENGTH


# -- the pile: site i of a stack of heightmaps ----------------------------------------------------
@jit
def height_at(heights: np.ndarray, origin: np.ndarray, spacing: float, i: int, x: float, y: float) -> float:
    """Surface height (m) of pile ``i`` at world (x, y), bilinear; 0 off the grid."""
    u, v = (x - origin[i, 0]) / spacing, (y - origin[i, 1]) / spacing
    last = heights.shape[1] - 1
    if not (0.0 <= u <= last and 0.0 <= v <= last):
        return 0.0
    j, k = min(int(u), last - 1), min(int(v), last - 1)
    fu, fv = u - j, v - k
    top = heights[i, k, j] * (1.0 - fu) + heights[i, k, j + 1] * fu
    bottom = heights[i, k + 1, j] * (1.0 - fu) + heights[i, k + 1, j + 1] * fu
    return top * (1.0 - fv) + bottom * fv


@jit
def heights_at(heights: np.ndarray, origin: np.ndarray, spacing: float, i: int, xy: np.ndarray) -> np.ndarray:
    """:func:`height_at` of pile ``i`` at world points ``xy`` (m, 2)."""
    out = np.empty(xy.shape[0])
    for k in range(xy.shape[0]):
        out[k] = height_at(heights, origin, spacing, i, xy[k, 0], xy[k, 1])
    return out


@jit
def window(n: int, spacing: float, x: float, y: float, radius: float) -> tuple[int, int, int, int]:
    """Rows ``r0:r1`` and columns ``c0:c1`` of the grid points within ``radius`` of grid-relative (x, y) (a square;
    empty where ``r1 <= r0`` or ``c1 <= c0``)."""
    inv = 1.0 / spacing
    c0, c1 = max(math.floor((x - radius) * inv), 0), min(math.ceil((x + radius) * inv) + 1, n)
    r0, r1 = max(math.floor((y - radius) * inv), 0), min(math.ceil((y + radius) * inv) + 1, n)
    return r0, r1, c0, c1


@jit
def clearance(
    heights: np.ndarray, origin: np.ndarray, spacing: float, top: float, i: int, x: float, y: float, z: float,
    radius: float, enough: float,
) -> float:  # fmt: skip
    """Height (m) of (x, y, z) above the highest point of pile ``i`` within ``radius`` (a square window).

    Negative where material stands higher; ``inf`` where none lies within ``radius``. Once the answer
    is sure to be at least ``enough``, it may be any value >= ``enough`` (``top`` bounds the surface).
    """
    if z - top >= enough:
        return z - top
    r0, r1, c0, c1 = window(heights.shape[1], spacing, x - origin[i, 0], y - origin[i, 1], radius)
    if r1 <= r0 or c1 <= c0:
        return math.inf
    highest = -math.inf
    for r in range(r0, r1):
        for c in range(c0, c1):
            highest = max(highest, heights[i, r, c])
    return z - highest


@jit
def relax(h: np.ndarray, limit: float, iterations: int) -> None:
    """Let slopes steeper than ``limit`` (height difference per grid step) slide, in place, mass-conserving:
    each pass moves a quarter of each excess difference from the higher point to the lower, rows then columns."""
    rows, cols = h.shape
    for _ in range(iterations):
        moved = False
        for axis in range(2):
            nr, nc = (rows - 1, cols) if axis == 0 else (rows, cols - 1)
            flow = np.zeros((max(nr, 0), max(nc, 0)))
            steep = False
            for r in range(nr):
                for c in range(nc):
                    dh = h[r + 1, c] - h[r, c] if axis == 0 else h[r, c + 1] - h[r, c]
                    excess = abs(dh) - limit
                    if excess > 0.0:
                        steep = True
                        flow[r, c] = math.copysign(excess, dh) * 0.25  # from higher to lower
            if not steep:
                continue
            moved = True
            for r in range(nr):
                for c in range(nc):
                    if axis == 0:
                        h[r + 1, c] -= flow[r, c]
                    else:
                        h[r, c + 1] -= flow[r, c]
            for r in range(nr):
                for c in range(nc):
                    h[r, c] += flow[r, c]
        if not moved:
            break  # settled: later passes would find the same slopes


@jit
def take(
    heights: np.ndarray, origin: np.ndarray, spacing: float, i: int, x: float, y: float, lx: float, ly: float,
    width: float, floor: float, volume: float,
) -> float:  # fmt: skip
    """Remove up to ``volume`` m^3 lying above height ``floor`` from pile ``i`` in the edge's footprint; return it.

    The footprint is the strip ``width`` wide along the unit vector (``lx``, ``ly``) and one grid spacing
    deep each side, centred on (x, y). Each point gives up the same fraction of its material above the
    floor, so the surface lowers evenly towards the edge; the window then relaxes (:func:`relax`).
    """
    if volume <= 0.0:
        return 0.0
    ox, oy = origin[i, 0], origin[i, 1]
    r0, r1, c0, c1 = window(heights.shape[1], spacing, x - ox, y - oy, width / 2.0 + spacing)
    if r1 <= r0 or c1 <= c0:
        return 0.0
    patch = heights[i, r0:r1, c0:c1]  # a view: the cut lands in the pile
    available = np.zeros(patch.shape)
    total = 0.0
    for r in range(r1 - r0):
        dy = oy + (r0 + r) * spacing - y
        for c in range(c1 - c0):
            dx = ox + (c0 + c) * spacing - x
            if abs(dx * lx + dy * ly) <= width / 2.0 and abs(dx * ly - dy * lx) <= spacing:
                available[r, c] = max(patch[r, c] - floor, 0.0)
                total += available[r, c]
    total *= spacing * spacing
    if total <= 0.0:
        return 0.0
    before = patch.sum()
    share = min(1.0, volume / total)
    for r in range(r1 - r0):
        for c in range(c1 - c0):
            patch[r, c] -= available[r, c] * share
    relax(patch, repose_limit(spacing), RELAX_ITERATIONS)
    # the relaxation moves material inside the window only, so the window's loss is the take
    return (before - patch.sum()) * spacing * spacing


@jit
def repose_limit(spacing: float) -> float:
    """Height difference (m) between neighbouring grid points ``spacing`` apart at the angle of repose."""
    return math.tan(_REPOSE) * spacing


@jit
def dig(
    heights: np.ndarray, origin: np.ndarray, spacing: float, top: float, i: int, bucket_kg: float,
    x: float, y: float, z: float, lx: float, ly: float, lz: float, tx: float, ty: float, tz: float,
    vx: float, vy: float, vz: float, dt: float, fx: float, fy: float, fz: float, density: float = _DENSITY,
) -> tuple[float, float, float, float, float]:  # fmt: skip
    """Cut pile ``i`` for ``dt`` s with the edge at (x, y, z) moving at ``v`` (m/s; the fill), the bucket holding
    ``bucket_kg``; ``l`` along the edge, ``t`` along the teeth, ``f`` the velocity the resistance opposes; the
    material of ``density`` (kg/m^3).

    Returns the resistance (N, world), the material taken (kg) and the cutting depth (m: the mean over
    ``EDGE_SAMPLES`` points along the edge of the material above it; 0: not cutting, no force).
    """
    if z >= top:
        return 0.0, 0.0, 0.0, 0.0, 0.0  # above the whole pile: kept cheap
    floor = max(z, 0.0)  # the pile stands on the ground: no material below it
    total = 0.0
    for offset in EDGE_OFFSETS:
        total += max(height_at(heights, origin, spacing, i, x + offset * lx, y + offset * ly) - floor, 0.0)
    depth = total / EDGE_SAMPLES
    if depth <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0
    # fill: the edge slices a layer `depth` thick as it moves along the teeth; buried, the pile holds the
    # contents whatever the tilt, so the bucket fills to its heap
    cut_speed = max(vx * tx + vy * ty + vz * tz, 0.0)
    room = max(_HEAPED - bucket_kg / density, 0.0)
    wanted = min(_WIDTH * depth * cut_speed * dt, room)
    taken_kg = take(heights, origin, spacing, i, x, y, lx, ly, _WIDTH, floor, wanted) * density
    rx, ry, rz = resistance(depth, bucket_kg + taken_kg, lx, ly, lz, tx, ty, tz, fx, fy, fz, density)
    return rx, ry, rz, taken_kg, depth


def frustum_heights(
    x: np.ndarray, y: np.ndarray, height: float, top_radius: float, repose: float = p.MATERIAL_REPOSE_ANGLE
) -> np.ndarray:
    """Heights of a flat-topped conical heap centred on (0, 0) at grid points ``x``, ``y`` (m)."""
    r = np.hypot(x, y)
    return np.clip(height - (r - top_radius) * np.tan(repose), 0.0, height)


def mouth_normal() -> np.ndarray:
    """Unit normal (bucket frame x, z) of the bucket's mouth, pointing out of the bucket."""
    lip, edge = np.array(BUCKET.lip), np.array(BUCKET.edge)
    d = edge - lip
    n = np.array([-d[1], d[0]]) / np.hypot(*d)
    mid = (lip + edge) / 2.0
    return -n if n @ (np.zeros(2) - mid) > 0 else n  # the pin is on the inside


# -- one-site handles ------------------------------------------------------------------------------
class Pile:
    """A heightmap of material on a square vertex grid, axis-aligned with the world: pile ``index`` of a stack.

    Args:
        heights: (n, n) heights above the ground, m; row ``i`` is at ``y = centre_y + (i - (n-1)/2) spacing``,
            column ``j`` at ``x = centre_x + (j - (n-1)/2) spacing`` (MuJoCo's hfield layout). Copied into a
            stack of one unless ``stack`` is given.
        centre: (x, y) of the grid's centre in the world, m.
        spacing: distance between grid points, m; each point stands for a ``spacing^2`` cell.
        stack, origins, index: a handle on pile ``index`` of a stack ``(N, n, n)`` whose grid origins are
            ``origins`` (N, 2) (the loading task's piles; ``heights`` and ``centre`` are then ignored).
        flags: integer arrays (N,) whose entry ``index`` this handle counts up when it changes the heights
            (the owner's caches).
    """

    def __init__(
        self,
        heights: np.ndarray | None,
        centre: tuple[float, float] | None,
        spacing: float,
        stack: np.ndarray | None = None,
        origins: np.ndarray | None = None,
        index: int = 0,
        flags: tuple[np.ndarray, ...] = (),
    ) -> None:
        if stack is None:
            heights = np.array(heights, dtype=float)
            if heights.ndim != 2 or heights.shape[0] != heights.shape[1] or not np.all(np.isfinite(heights)):
                raise ValueError(f"pile heights must be a finite square grid, got shape {heights.shape}")
            if np.any(heights < 0):
                raise ValueError("pile heights must be >= 0")
            half = (heights.shape[0] - 1) * spacing / 2.0
            stack = heights[None].copy()
            origins = (np.array(centre, dtype=float) - half)[None]
        self.stack, self.origins, self.index, self._flags = stack, origins, int(index), flags
        self.spacing = float(spacing)
        self.half_size = (stack.shape[1] - 1) * self.spacing / 2.0
        self.top = float(self.heights.max())  # an upper bound of the surface: digging only lowers it

    @classmethod
    def heap(cls, centre: tuple[float, float], height: float, top_radius: float, n: int, spacing: float) -> Pile:
        """A flat-topped heap at the angle of repose on an ``n x n`` grid."""
        offsets = (np.arange(n) - (n - 1) / 2.0) * spacing
        x, y = np.meshgrid(offsets, offsets)
        return cls(frustum_heights(x, y, height, top_radius), centre, spacing)

    @property
    def heights(self) -> np.ndarray:
        """The heightmap (n, n), m: a view of the stack."""
        return self.stack[self.index]

    @property
    def origin(self) -> np.ndarray:
        """World (x, y) of grid point [0, 0], m."""
        return self.origins[self.index]

    @property
    def centre(self) -> np.ndarray:
        """World (x, y) of the grid's centre, m."""
        return self.origin + self.half_size

    @property
    def cell_area(self) -> float:
        """Area each grid point stands for, m^2."""
        return self.spacing**2

    def volume(self) -> float:
        """Material in the pile, m^3."""
        return float(self.heights.sum()) * self.cell_area

    def height_at(self, xy: np.ndarray) -> np.ndarray | float:
        """Surface height (m) at world points ``xy`` (..., 2), bilinear; 0 off the grid."""
        xy = np.asarray(xy, dtype=float)
        flat = np.ascontiguousarray(xy.reshape(-1, 2))
        out = heights_at(self.stack, self.origins, self.spacing, self.index, flat).reshape(xy.shape[:-1])
        return float(out) if out.ndim == 0 else out

    def height_at_point(self, x: float, y: float) -> float:
        """:meth:`height_at` of one point (x, y)."""
        return float(height_at(self.stack, self.origins, self.spacing, self.index, float(x), float(y)))

    def clearance(self, point: np.ndarray, radius: float, enough: float = math.inf) -> float:
        """Height (m) of world ``point`` above the highest grid point within ``radius`` of it (:func:`clearance`)."""
        x, y, z = (float(v) for v in point)
        return float(clearance(self.stack, self.origins, self.spacing, self.top, self.index, x, y, z, radius, enough))

    def take(self, xy: np.ndarray, lateral: np.ndarray, width: float, floor: float, volume: float) -> float:
        """Remove up to ``volume`` m^3 above ``floor`` in the edge's footprint at ``xy``, ``lateral`` (:func:`take`)."""
        x, y = (float(v) for v in xy[:2])
        lx, ly = (float(v) for v in lateral[:2])
        self._changed()
        return float(take(self.stack, self.origins, self.spacing, self.index, x, y, lx, ly, width, floor, volume))

    def relax(self, iterations: int = RELAX_ITERATIONS) -> None:
        """Let slopes steeper than the angle of repose slide over the whole pile (mass-conserving)."""
        self._changed()
        relax(self.heights, repose_limit(self.spacing), iterations)

    def _changed(self) -> None:
        for flag in self._flags:
            flag[self.index] += 1


@dataclass
class DigResult:
    """What one digging interval did: the resistance on the edge (N, world), the material taken (kg), the depth."""

    force: np.ndarray
    taken_kg: float
    depth: float


@dataclass
class SpillResult:
    """Material that left the bucket in one interval (kg), by where it landed."""

    to_truck_kg: float
    to_ground_kg: float


class Earthwork:
    """The four material stores of one site and the moves between them, on :func:`dig` and :func:`spill_out`.

    The pile is a :class:`Pile`; the bucket's, truck's and ground's kilograms are a row ``stores`` (3,) in the
    order ``BUCKET_STORE``, ``TRUCK_STORE``, ``SPILLED_STORE``: its own, or a view of the loading task's (the
    environments' ``earth``: :meth:`hexgym.envs.task.LoadingTask.earthwork`), which its setters then change.

    Args:
        pile: the material heap.
        stores: the bucket, truck and spilled kilograms (default: a row of its own, empty).
        density: the material's, kg/m^3.
    """

    def __init__(self, pile: Pile, stores: np.ndarray | None = None, density: float = p.MATERIAL_DENSITY) -> None:
        self.pile = pile
        self.stores = np.zeros(3) if stores is None else stores
        self.density = float(density)

    @property
    def bucket_kg(self) -> float:
        """Material in the bucket, kg."""
        return float(self.stores[BUCKET_STORE])

    @bucket_kg.setter
    def bucket_kg(self, value: float) -> None:
        self.stores[BUCKET_STORE] = value

    @property
    def truck_kg(self) -> float:
        """Material in the truck, kg."""
        return float(self.stores[TRUCK_STORE])

    @truck_kg.setter
    def truck_kg(self, value: float) -> None:
        self.stores[TRUCK_STORE] = value

    @property
    def spilled_kg(self) -> float:
        """Material spilled on the ground, kg."""
        return float(self.stores[SPILLED_STORE])

    @spilled_kg.setter
    def spilled_kg(self, value: float) -> None:
        self.stores[SPILLED_STORE] = value

    @property
    def pile_kg(self) -> float:
        """Material in the pile, kg."""
        return self.pile.volume() * self.density

    def total_kg(self) -> float:
        """Pile + bucket + truck + spilled, kg: constant."""
        return self.pile_kg + self.bucket_kg + self.truck_kg + self.spilled_kg

    def dig(
        self,
        edge: np.ndarray,
        lateral: np.ndarray,
        teeth: np.ndarray,
        velocity: np.ndarray,
        dt: float,
        force_velocity: np.ndarray | None = None,
    ) -> DigResult:
        """Cut with the bucket's edge (world m) for ``dt`` s (:func:`dig`; ``force_velocity`` defaults to
        ``velocity``)."""
        f = velocity if force_velocity is None else force_velocity
        pile = self.pile
        values = [float(v) for v in (*edge, *lateral, *teeth, *velocity, dt, *f)]
        fx, fy, fz, taken_kg, depth = dig(
            pile.stack, pile.origins, pile.spacing, pile.top, pile.index, self.bucket_kg, *values, self.density
        )
        self.bucket_kg += taken_kg
        return DigResult(np.array([fx, fy, fz]), taken_kg, depth)

    def spill(self, tilt: float, into_truck: bool, dt: float) -> SpillResult:
        """Let what the bucket cannot hold at ``tilt`` run out for ``dt`` s, into the truck or onto the ground."""
        out = float(spill_out(self.bucket_kg, float(tilt), float(dt), self.density))
        self.bucket_kg -= out
        if into_truck:
            self.truck_kg += out
            return SpillResult(out, 0.0)
        self.spilled_kg += out
        return SpillResult(0.0, out)

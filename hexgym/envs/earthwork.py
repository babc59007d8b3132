"""Earthwork of the loading task: the pile, digging, the bucket's contents, spills and the truck.

Pure numpy: the environment hands in the bucket's pose and velocity (world frame, SI) and gets
back the digging resistance and where material went. Material lives in exactly four stores,
the pile (a heightmap), the bucket, the truck and the ground (spilled), and only moves between
them, so their sum is constant (:meth:`Earthwork.total_kg`).

- **Pile**: heights on a vertex grid (the MuJoCo hfield's layout), a flat-topped heap whose flanks
  stand at the angle of repose. Digging lowers the surface under the cutting edge; a local
  avalanche step then lets slopes steeper than the angle of repose slide.
- **Digging**: the edge takes material at ``width x depth x (edge speed along the teeth)``: the
  fill rate grows with the cutting depth and falls with the attack angle between the teeth and
  the motion (zero when the bucket moves backwards). Resistance is the fundamental earthmoving
  equation (Reece 1964, with McKyes' factors for a flat blade; no cohesion):
  ``F = w (gamma d^2 N_gamma + q d N_q)``, the surcharge ``q`` being the weight of the material
  already in the bucket over its mouth; the failure plane minimises the force. It acts against
  the edge's motion.
- **Contents**: buried in the pile, the bucket fills to its heaped capacity whatever its tilt.
  Out of it, the bucket holds its heaped capacity with the mouth facing up, its struck
  capacity once tilted to the angle of repose, nothing once the mouth faces down past it. What it
  cannot hold leaves with a short time constant, into the truck when the caller says it falls
  in the bed, otherwise onto the ground.

:class:`BatchedPiles` holds many sites' piles for the batched environment
(:mod:`hexgym.envs.vector`) and cuts them with the single :class:`Pile`'s arithmetic, element for
element (the helpers :func:`strip_mask`, :func:`relax_heights` and the array forms of the
formulas are shared by both).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hexgym.interpolation import UniformTable
from hexgym.machine import parameters as p

_GAMMA = p.MATERIAL_DENSITY * p.GRAVITY  # unit weight, N/m^3
EDGE_SAMPLES = 5  # points along the cutting edge where the depth is measured
_RELAX_ITERATIONS = 3  # avalanche passes after each cut
_RAKE_LIMITS = np.radians((5.0, 90.0))  # rake angles outside this are treated as at the limit
EDGE_OFFSETS = tuple(np.linspace(-p.BUCKET_WIDTH / 2.0, p.BUCKET_WIDTH / 2.0, EDGE_SAMPLES).tolist())


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


_N_GAMMA = UniformTable(*_RAKE_LIMITS, earthmoving_factors(np.linspace(*_RAKE_LIMITS, 171))[0])


def digging_resistance(depth: float, rake: float, surcharge_pa: float, width: float = p.BUCKET_WIDTH) -> float:
    """Magnitude (N) of the earthmoving force on an edge ``width`` wide cutting ``depth`` m deep."""
    if depth <= 0.0:
        return 0.0
    n_gamma = _N_GAMMA(float(rake))  # rakes outside the table's limits count as at them
    return float(earthmoving_force(depth, n_gamma, surcharge_pa, width))


def earthmoving_force(
    depth: np.ndarray | float, n_gamma: np.ndarray | float, surcharge_pa: np.ndarray | float, width: float
) -> np.ndarray | float:
    """The fundamental earthmoving equation without cohesion, for floats or arrays: ``w (gamma d^2 N_gamma +
    q d N_q)`` with ``N_q = 2 N_gamma`` (McKyes' flat blade), N."""
    return width * (_GAMMA * depth**2 * n_gamma + surcharge_pa * depth * 2.0 * n_gamma)


def n_gamma_at(rake: np.ndarray) -> np.ndarray:
    """N_gamma at rake angles ``rake`` (rad, an array), from the table :func:`digging_resistance` uses."""
    return _N_GAMMA.at(rake)


_RETAINED_TILTS = (0.0, p.MATERIAL_REPOSE_ANGLE, np.pi / 2.0 + p.MATERIAL_REPOSE_ANGLE)
_RETAINED_VOLUMES = (p.BUCKET_HEAPED_CAPACITY, p.BUCKET_STRUCK_CAPACITY, 0.0)


def retained_volume(tilt: float) -> float:
    """Material (m^3) the bucket holds with its mouth tilted ``tilt`` rad from facing straight up."""
    return float(np.interp(tilt, _RETAINED_TILTS, _RETAINED_VOLUMES))


def retained_volumes(tilts: np.ndarray) -> np.ndarray:
    """:func:`retained_volume` at each of ``tilts`` (an array)."""
    return np.interp(tilts, _RETAINED_TILTS, _RETAINED_VOLUMES)


def spilled_fraction(dt: np.ndarray | float) -> np.ndarray | float:
    """Share of the excess over what the bucket holds that runs out in ``dt`` s (float or array)."""
    return 1.0 - np.exp(-dt / p.BUCKET_SPILL_TIME_CONSTANT)


def surcharge_pressure(bucket_volume: np.ndarray | float) -> np.ndarray | float:
    """Pressure (Pa) of the bucket's contents (m^3) spread over its mouth: the earthmoving equation's surcharge."""
    return _GAMMA * bucket_volume / (p.BUCKET_WIDTH * _MOUTH_LENGTH)


def strip_mask(
    dx: np.ndarray, dy: np.ndarray, lx: np.ndarray | float, ly: np.ndarray | float, width: float, spacing: float
) -> np.ndarray:
    """Grid points (offsets ``dx``, ``dy`` from the edge's centre, broadcast) within the edge's footprint: ``width``
    along the unit vector (``lx``, ``ly``), one grid ``spacing`` across it (:meth:`Pile.take`)."""
    along = dx * lx + dy * ly
    across = np.abs(dx * ly - dy * lx)
    return (np.abs(along) <= width / 2.0) & (across <= spacing)


def relax_heights(h: np.ndarray, limit: float, iterations: int = _RELAX_ITERATIONS) -> None:
    """Let slopes steeper than ``limit`` (height difference per grid step) slide, in place, mass-conserving.

    ``h`` is one window ``(rows, cols)`` or a stack of equally shaped windows ``(..., rows, cols)`` relaxed
    independently (the batched environment): a window with no steep slope gets zero flows, which leave it
    unchanged, so each window ends as it would alone.
    """
    for _ in range(iterations):
        moved = False
        for axis in (-2, -1):
            dh = np.diff(h, axis=axis)
            excess = np.abs(dh)
            excess -= limit
            if excess.max() <= 0.0:
                continue  # no slope steeper than the repose angle along this axis: nothing slides
            moved = True
            np.maximum(excess, 0.0, out=excess)
            flow = np.copysign(excess, dh)  # from higher to lower
            flow *= 0.25
            if axis == -2:
                h[..., 1:, :] -= flow
                h[..., :-1, :] += flow
            else:
                h[..., :, 1:] -= flow
                h[..., :, :-1] += flow
        if not moved:
            break  # settled: later passes would find the same slopes


def frustum_heights(
    x: np.ndarray, y: np.ndarray, height: float, top_radius: float, repose: float = p.MATERIAL_REPOSE_ANGLE
) -> np.ndarray:
    """Heights of a flat-topped conical heap centred on (0, 0) at grid points ``x``, ``y`` (m)."""
    r = np.hypot(x, y)
    return np.clip(height - (r - top_radius) * np.tan(repose), 0.0, height)


class Pile:
    """A heightmap of material on a square vertex grid, axis-aligned with the world.

    Args:
        heights: (n, n) heights above the ground, m; row ``i`` is at ``y = centre_y + (i - (n-1)/2) spacing``,
            column ``j`` at ``x = centre_x + (j - (n-1)/2) spacing`` (MuJoCo's hfield layout).
        centre: (x, y) of the grid's centre in the world, m.
        spacing: distance between grid points, m; each point stands for a ``spacing^2`` cell.
    """

    def __init__(self, heights: np.ndarray, centre: tuple[float, float], spacing: float) -> None:
        heights = np.array(heights, dtype=float)
        if heights.ndim != 2 or heights.shape[0] != heights.shape[1] or not np.all(np.isfinite(heights)):
            raise ValueError(f"pile heights must be a finite square grid, got shape {heights.shape}")
        if np.any(heights < 0):
            raise ValueError("pile heights must be >= 0")
        self.heights = heights
        self.centre = np.array(centre, dtype=float)
        self.spacing = float(spacing)
        n = heights.shape[0]
        self.half_size = (n - 1) * spacing / 2.0
        self._origin = self.centre - self.half_size  # (x, y) of grid point [0, 0]
        self._origin_x, self._origin_y = self._origin.tolist()  # the same as floats, for scalar arithmetic
        self.top = float(heights.max())  # an upper bound of the surface: digging only lowers it
        self._volume: float | None = None  # cached sum of the heights x cell area; None once they change
        self.revision = 0  # counts the changes of ``heights`` (by take and relax): for caches of derived values

    @classmethod
    def heap(cls, centre: tuple[float, float], height: float, top_radius: float, n: int, spacing: float) -> Pile:
        """A flat-topped heap at the angle of repose on an ``n x n`` grid."""
        offsets = (np.arange(n) - (n - 1) / 2.0) * spacing
        x, y = np.meshgrid(offsets, offsets)
        return cls(frustum_heights(x, y, height, top_radius), centre, spacing)

    @property
    def cell_area(self) -> float:
        """Area each grid point stands for, m^2."""
        return self.spacing**2

    def volume(self) -> float:
        """Material in the pile, m^3 (cached: change ``heights`` only through :meth:`take` and :meth:`relax`)."""
        if self._volume is None:
            self._volume = float(self.heights.sum()) * self.cell_area
        return self._volume

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        """Surface height (m) at world points ``xy`` (..., 2), bilinear; 0 off the grid."""
        xy = np.asarray(xy, dtype=float)
        u = (xy[..., 0] - self._origin[0]) / self.spacing
        v = (xy[..., 1] - self._origin[1]) / self.spacing
        last = self.heights.shape[0] - 1
        inside = (u >= 0) & (v >= 0) & (u <= last) & (v <= last)
        # (np.minimum/maximum: np.clip costs several times more on these few points)
        j = np.minimum(np.maximum(np.floor(u), 0), last - 1).astype(int)
        i = np.minimum(np.maximum(np.floor(v), 0), last - 1).astype(int)
        fu = np.minimum(np.maximum(u - j, 0.0), 1.0)
        fv = np.minimum(np.maximum(v - i, 0.0), 1.0)
        h = self.heights
        top = h[i, j] * (1 - fu) + h[i, j + 1] * fu
        bottom = h[i + 1, j] * (1 - fu) + h[i + 1, j + 1] * fu
        return np.where(inside, top * (1 - fv) + bottom * fv, 0.0)

    def height_at_point(self, x: float, y: float) -> float:
        """:meth:`height_at` for one point, in plain Python (several times faster than numpy for one)."""
        u, v = (x - self._origin_x) / self.spacing, (y - self._origin_y) / self.spacing
        last = self.heights.shape[0] - 1
        if not (0.0 <= u <= last and 0.0 <= v <= last):
            return 0.0
        j, i = min(int(u), last - 1), min(int(v), last - 1)
        fu, fv = u - j, v - i
        h = self.heights
        top = h[i, j] * (1.0 - fu) + h[i, j + 1] * fu
        bottom = h[i + 1, j] * (1.0 - fu) + h[i + 1, j + 1] * fu
        return float(top * (1.0 - fv) + bottom * fv)

    def may_reach(self, point: np.ndarray, margin: float) -> bool:
        """Whether material may lie within a bucket's width of ``point`` (world) above ``point``'s height - margin.

        A cheap bound: the highest grid point within ``BUCKET_WIDTH`` (a square window).
        """
        return self.clearance(point, p.BUCKET_WIDTH, margin) < margin

    def clearance(self, point: np.ndarray, radius: float, enough: float = math.inf) -> float:
        """Height (m) of world ``point`` above the highest grid point within ``radius`` of it (a square window).

        Negative where material stands higher; ``inf`` where none lies within ``radius``. Once the
        answer is sure to be at least ``enough``, it may be any value >= ``enough`` (cheap bound).
        """
        z = float(point[2])
        if z - self.top >= enough:
            return z - self.top  # above the whole pile's (upper bound of the) top
        window = self._window(point, radius)
        return z - float(self.heights[window].max()) if window is not None else math.inf

    def _window(self, xy: np.ndarray, radius: float) -> tuple[slice, slice] | None:
        """Row and column slices of the grid points within ``radius`` of ``xy`` (a square), or None."""
        n, inv = self.heights.shape[0], 1.0 / self.spacing
        x, y = float(xy[0]) - self._origin_x, float(xy[1]) - self._origin_y
        c0, c1 = max(math.floor((x - radius) * inv), 0), min(math.ceil((x + radius) * inv) + 1, n)
        r0, r1 = max(math.floor((y - radius) * inv), 0), min(math.ceil((y + radius) * inv) + 1, n)
        if c1 <= c0 or r1 <= r0:
            return None
        return slice(r0, r1), slice(c0, c1)

    def take(self, xy: np.ndarray, lateral: np.ndarray, width: float, floor: float, volume: float) -> float:
        """Remove up to ``volume`` m^3 lying above height ``floor`` in the edge's footprint; return it.

        The footprint is the strip ``width`` wide along the unit vector ``lateral`` and one grid
        spacing deep each side, centred on ``xy``. Each point gives up the same fraction of its
        material above the floor, so the surface lowers evenly towards the edge.
        """
        if volume <= 0.0:
            return 0.0
        window = self._window(xy, width / 2.0 + self.spacing)
        if window is None:
            return 0.0
        rows, cols = window
        lx, ly = float(lateral[0]), float(lateral[1])
        dx = (self._origin_x + np.arange(cols.start, cols.stop) * self.spacing - float(xy[0]))[None, :]
        dy = (self._origin_y + np.arange(rows.start, rows.stop) * self.spacing - float(xy[1]))[:, None]
        in_strip = strip_mask(dx, dy, lx, ly, width, self.spacing)
        patch = self.heights[rows, cols]
        available = np.where(in_strip, np.maximum(patch - floor, 0.0), 0.0)
        total = float(available.sum()) * self.cell_area
        if total <= 0.0:
            return 0.0
        before = float(patch.sum())
        patch -= available * min(1.0, volume / total)
        self._volume = None
        self.relax((rows, cols))  # (counts the change in ``revision``)
        # the relaxation moves material inside the window only, so the window's loss is the take
        return (before - float(self.heights[rows, cols].sum())) * self.cell_area

    def relax(self, window: tuple[slice, slice] | None = None, iterations: int = _RELAX_ITERATIONS) -> None:
        """Let slopes steeper than the angle of repose slide (mass-conserving), inside ``window``."""
        rows, cols = window if window is not None else (slice(None), slice(None))
        self._volume = None
        self.revision += 1
        relax_heights(self.heights[rows, cols], repose_limit(self.spacing), iterations)  # a view: updates land


@dataclass
class DigResult:
    """What one digging interval did: the resistance on the edge (N, world) and the material taken (kg)."""

    force: np.ndarray
    taken_kg: float
    depth: float


@dataclass
class SpillResult:
    """Material that left the bucket in one interval (kg), by where it landed."""

    to_truck_kg: float
    to_ground_kg: float


class Earthwork:
    """The four material stores of the loading task and the moves between them.

    Args:
        pile: the material heap.
        density: bulk density of the material, kg/m^3.
    """

    def __init__(self, pile: Pile, density: float = p.MATERIAL_DENSITY) -> None:
        self.pile = pile
        self.density = float(density)
        self.bucket_kg = 0.0
        self.truck_kg = 0.0
        self.spilled_kg = 0.0
        self.initial_kg = self.total_kg()

    @property
    def pile_kg(self) -> float:
        """Material in the pile, kg."""
        return self.pile.volume() * self.density

    @property
    def bucket_volume(self) -> float:
        """Material in the bucket, m^3."""
        return self.bucket_kg / self.density

    def total_kg(self) -> float:
        """Pile + bucket + truck + spilled, kg: constant."""
        return self.pile_kg + self.bucket_kg + self.truck_kg + self.spilled_kg

    def stores(self) -> dict[str, float]:
        """Each store's material, kg."""
        return {"pile": self.pile_kg, "bucket": self.bucket_kg, "truck": self.truck_kg, "spilled": self.spilled_kg}

    def dig(
        self,
        edge: np.ndarray,
        lateral: np.ndarray,
        teeth: np.ndarray,
        velocity: np.ndarray,
        dt: float,
        force_velocity: np.ndarray | None = None,
    ) -> DigResult:
        """Cut with the bucket's edge for ``dt`` s.

        Args:
            edge: centre of the cutting edge (the teeth), world m.
            lateral: unit vector along the edge (the bucket's width), world.
            teeth: unit vector the teeth point along (out of the bucket along its floor), world.
            velocity: the edge's velocity, m/s, world (sets the fill).
            force_velocity: the velocity the resistance opposes (default ``velocity``); the
                environment passes a low-passed one so that the force does not chatter.
            dt: interval, s.
        """
        # plain floats: a handful of 3-vectors, where numpy's per-call overhead would dominate
        x, y, z = _floats(edge)
        floor = max(z, 0.0)  # the pile stands on the ground: no material below it
        if z >= self.pile.top:
            return DigResult(np.zeros(3), 0.0, 0.0)  # above the whole pile: kept cheap
        lx, ly, lz = _floats(lateral)
        depths = (self.pile.height_at_point(x + o * lx, y + o * ly) - floor for o in EDGE_OFFSETS)
        depth = sum(max(d, 0.0) for d in depths) / EDGE_SAMPLES
        if depth <= 0.0:
            return DigResult(np.zeros(3), 0.0, 0.0)
        tx, ty, tz = _floats(teeth)
        vx, vy, vz = _floats(velocity)
        # fill: the edge slices a layer `depth` thick as it moves along the teeth
        cut_speed = max(vx * tx + vy * ty + vz * tz, 0.0)
        # buried, the pile holds the contents in whatever the tilt: the bucket fills to its heap
        room = max(p.BUCKET_HEAPED_CAPACITY - self.bucket_volume, 0.0)
        wanted = min(p.BUCKET_WIDTH * depth * cut_speed * dt, room)
        taken_kg = self.pile.take((x, y), (lx, ly), p.BUCKET_WIDTH, floor, wanted) * self.density
        self.bucket_kg += taken_kg
        force = self.resistance(depth, lateral, teeth, velocity if force_velocity is None else force_velocity)
        return DigResult(force, taken_kg, depth)

    def resistance(self, depth: float, lateral: np.ndarray, teeth: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """The fundamental earthmoving equation's force (N, world) on the edge cutting ``depth`` m deep, against
        ``velocity`` (full above ``DIG_REFERENCE_SPEED``, in proportion below it); arguments as :meth:`dig`'s."""
        lx, ly, lz = _floats(lateral)
        tx, ty, tz = _floats(teeth)
        vx, vy, vz = _floats(velocity)
        speed = math.sqrt(vx * vx + vy * vy + vz * vz)
        ux, uy = (vx / speed, vy / speed) if speed > 1e-9 else (tx, ty)  # direction of travel
        horizontal = math.hypot(ux, uy)
        forward = (tx * ux + ty * uy) / horizontal if horizontal > 1e-9 else 0.0
        rake = math.atan2(-tz, forward)
        surcharge = surcharge_pressure(self.bucket_volume)
        scale = -digging_resistance(depth, rake, surcharge) / max(speed, p.DIG_REFERENCE_SPEED)
        fx, fy, fz = scale * vx, scale * vy, scale * vz
        sideways = fx * lx + fy * ly + fz * lz  # in the arm's plane: the edge cuts, its side plates do not
        return np.array([fx - sideways * lx, fy - sideways * ly, fz - sideways * lz])

    def spill(self, tilt: float, into_truck: bool, dt: float) -> SpillResult:
        """Let what the bucket cannot hold at ``tilt`` run out for ``dt`` s, into the truck or onto the ground.

        Call it only while the edge is out of the pile (inside, the pile holds the contents).
        """
        excess_kg = self.bucket_kg - retained_volume(tilt) * self.density
        if excess_kg <= 0.0:
            return SpillResult(0.0, 0.0)
        out = excess_kg * spilled_fraction(dt)
        if self.bucket_kg - out < 1.0:  # the last kilogram goes too, not asymptotically
            out = self.bucket_kg
        out = float(min(out, self.bucket_kg))
        self.bucket_kg -= out
        if into_truck:
            self.truck_kg += out
            return SpillResult(out, 0.0)
        self.spilled_kg += out
        return SpillResult(0.0, out)


_MOUTH_LENGTH = float(np.hypot(*np.subtract(p.BUCKET_EDGE, p.BUCKET_LIP)))  # strike line, m


def repose_limit(spacing: float) -> float:
    """Height difference (m) between neighbouring grid points ``spacing`` apart at the angle of repose."""
    return math.tan(p.MATERIAL_REPOSE_ANGLE) * spacing


def _floats(vector: np.ndarray | tuple[float, ...]) -> tuple[float, ...]:
    """A short vector's components as Python floats (a tuple or list passes through)."""
    return vector if isinstance(vector, tuple | list) else tuple(np.asarray(vector, dtype=float).tolist())


def mouth_normal() -> np.ndarray:
    """Unit normal (bucket frame x, z) of the bucket's mouth, pointing out of the bucket."""
    lip, edge = np.array(p.BUCKET_LIP), np.array(p.BUCKET_EDGE)
    d = edge - lip
    n = np.array([-d[1], d[0]]) / np.hypot(*d)
    mid = (lip + edge) / 2.0
    return -n if n @ (np.zeros(2) - mid) > 0 else n  # the pin is on the inside


class BatchedPiles:
    """The heightmaps of ``count`` piles on equal square grids (``n`` points a side, ``spacing`` apart).

    Args:
        count: number of piles.
        n: grid points per side.
        spacing: distance between grid points, m.
    """

    def __init__(self, count: int, n: int, spacing: float) -> None:
        self.heights = np.zeros((count, n, n))
        self.origin = np.zeros((count, 2))  # world (x, y) of each grid's point [0, 0]
        self.top = np.zeros(count)  # upper bound of each surface (its first maximum: digging only lowers it)
        self.n, self.spacing = int(n), float(spacing)
        self.cell_area = self.spacing**2  # as Pile.cell_area
        self._inv = 1.0 / self.spacing  # as Pile._window
        self._limit = repose_limit(self.spacing)
        self._volume = np.zeros(count)
        self._stale = np.ones(count, bool)  # volumes to recompute (heights changed)
        self.changed = np.ones(count, bool)  # heights changed since the owner last cleared the flag (its caches)

    def load(self, index: int, pile: Pile) -> None:
        """Make pile ``index`` a copy of ``pile`` (same grid size and spacing)."""
        if pile.heights.shape != (self.n, self.n) or pile.spacing != self.spacing:
            raise ValueError(f"pile grid {pile.heights.shape} at {pile.spacing} m is not this batch's")
        self.heights[index] = pile.heights
        self.origin[index] = pile.centre - pile.half_size  # as Pile._origin
        self.top[index] = pile.top
        self._stale[index] = self.changed[index] = True

    def volumes(self) -> np.ndarray:
        """Material in each pile, m^3 (recomputed only where the heights changed; a view, do not modify)."""
        stale = np.flatnonzero(self._stale)
        if len(stale):
            # each row summed alone, as Pile.volume sums one contiguous grid: the same floats
            self._volume[stale] = self.heights[stale].reshape(len(stale), -1).sum(axis=1) * self.cell_area
            self._stale[stale] = False
        return self._volume

    def height_at(self, ids: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Surface heights (m) of piles ``ids`` at world points (``x``, ``y``): :meth:`Pile.height_at_point`."""
        u = (x - self.origin[ids, 0]) / self.spacing
        v = (y - self.origin[ids, 1]) / self.spacing
        last = self.n - 1
        inside = (u >= 0.0) & (u <= last) & (v >= 0.0) & (v <= last)
        j = np.minimum(np.maximum(np.floor(u), 0.0), last - 1).astype(np.intp)  # int(u) inside the grid
        i = np.minimum(np.maximum(np.floor(v), 0.0), last - 1).astype(np.intp)
        fu, fv = u - j, v - i
        h = self.heights
        top = h[ids, i, j] * (1.0 - fu) + h[ids, i, j + 1] * fu
        bottom = h[ids, i + 1, j] * (1.0 - fu) + h[ids, i + 1, j + 1] * fu
        return np.where(inside, top * (1.0 - fv) + bottom * fv, 0.0)

    def windows(self, ids: np.ndarray, x: np.ndarray, y: np.ndarray, radius: float | np.ndarray) -> tuple:
        """Row and column bounds ``(r0, r1, c0, c1)`` of the grid points within ``radius`` of (``x``, ``y``)
        (a square), as :meth:`Pile._window`; a window is empty where ``r1 <= r0`` or ``c1 <= c0``. The
        arguments broadcast (e.g. ``ids``, ``x``, ``y`` as (k, 1) and ``radius`` (m,) for k x m windows)."""
        cx, cy = x - self.origin[ids, 0], y - self.origin[ids, 1]
        c0 = np.maximum(np.floor((cx - radius) * self._inv), 0).astype(np.intp)
        c1 = np.minimum(np.ceil((cx + radius) * self._inv) + 1, self.n).astype(np.intp)
        r0 = np.maximum(np.floor((cy - radius) * self._inv), 0).astype(np.intp)
        r1 = np.minimum(np.ceil((cy + radius) * self._inv) + 1, self.n).astype(np.intp)
        return r0, r1, c0, c1

    def first_blocked_window(
        self, ids: np.ndarray, z: np.ndarray, bounds: tuple[np.ndarray, ...], travels: np.ndarray
    ) -> np.ndarray:
        """For each pile ``ids`` (k,) and height ``z``, the first of its nested windows ``bounds`` = (r0, r1, c0, c1),
        each (k, m) from :meth:`windows` (window j inside window j + 1), that holds a grid point ``h`` with
        ``z - h < travels[j]`` (:meth:`Pile.clearance` below ``travels[j]``); ``m`` where none does.

        ``z - h`` falls as ``h`` rises, so a window's highest point decides as any of its points: window j
        is blocked by a point that lies in it (from window ``w`` on) and is high enough (from travel ``t`` on)
        when ``j >= max(w, t)``; the first blocked window is the least of those over the points.
        """
        r0, r1, c0, c1 = bounds
        count = r0.shape[1]
        first = np.full(len(ids), count, np.intp)
        read = np.flatnonzero((r1[:, -1] > r0[:, -1]) & (c1[:, -1] > c0[:, -1]))  # the widest window holds points
        if not len(read):
            return first
        ids, z, r0, r1, c0, c1 = ids[read], z[read], r0[read], r1[read], c0[read], c1[read]
        size = int(max((r1[:, -1] - r0[:, -1]).max(), (c1[:, -1] - c0[:, -1]).max()))
        offsets = np.arange(size)
        rows, cols = r0[:, -1:] + offsets, c0[:, -1:] + offsets  # (k, size): the widest window's and beyond
        n = self.n
        row_starts = (ids * n * n)[:, None] + np.minimum(rows, n - 1) * n
        patch = self.heights.reshape(-1).take(row_starts[:, :, None] + np.minimum(cols, n - 1)[:, None, :])
        # the windows a row (column) is outside of: the first window holding it (count: none does)
        row_from = ((rows[:, None, :] < r0[:, :, None]) | (rows[:, None, :] >= r1[:, :, None])).sum(axis=1)
        col_from = ((cols[:, None, :] < c0[:, :, None]) | (cols[:, None, :] >= c1[:, :, None])).sum(axis=1)
        high_from = np.searchsorted(travels, z[:, None, None] - patch, side="right")  # travels <= z - h: not blocking
        blocked_from = np.maximum(np.maximum(row_from[:, :, None], col_from[:, None, :]), high_from)
        first[read] = blocked_from.min(axis=(1, 2))
        return first

    def take(
        self, ids: np.ndarray, x: np.ndarray, y: np.ndarray, lx: np.ndarray, ly: np.ndarray, width: float,
        floor: np.ndarray, volume: np.ndarray,
    ) -> np.ndarray:  # fmt: skip
        """Cut up to ``volume`` m^3 above ``floor`` from each pile ``ids`` along its edge and relax (:meth:`Pile.take`).

        Returns the volume each pile gave up, m^3.
        """
        taken = np.zeros(len(ids))
        r0, r1, c0, c1 = self.windows(ids, x, y, width / 2.0 + self.spacing)
        wanted = (volume > 0.0) & (r1 > r0) & (c1 > c0)
        shapes = (r1 - r0) * (self.n + 1) + (c1 - c0)  # one code per window shape
        for shape in np.unique(shapes[wanted]):
            group = np.flatnonzero(wanted & (shapes == shape))
            taken[group] = self._take_group(
                ids[group], r0[group], c0[group], int(r1[group[0]] - r0[group[0]]), int(c1[group[0]] - c0[group[0]]),
                x[group], y[group], lx[group], ly[group], width, floor[group], volume[group],
            )  # fmt: skip
        return taken

    def _take_group(
        self, ids: np.ndarray, r0: np.ndarray, c0: np.ndarray, n_rows: int, n_cols: int, x: np.ndarray,
        y: np.ndarray, lx: np.ndarray, ly: np.ndarray, width: float, floor: np.ndarray, volume: np.ndarray,
    ) -> np.ndarray:  # fmt: skip
        """:meth:`take` for piles whose windows share one shape (n_rows, n_cols), from rows ``r0`` and cols ``c0``."""
        rows = (r0[:, None] + np.arange(n_rows))[:, :, None]
        cols = (c0[:, None] + np.arange(n_cols))[:, None, :]
        patch = self.heights[ids[:, None, None], rows, cols]  # (k, n_rows, n_cols), a copy
        dx = self.origin[ids, 0][:, None, None] + cols * self.spacing - x[:, None, None]
        dy = self.origin[ids, 1][:, None, None] + rows * self.spacing - y[:, None, None]
        in_strip = strip_mask(dx, dy, lx[:, None, None], ly[:, None, None], width, self.spacing)
        available = np.where(in_strip, np.maximum(patch - floor[:, None, None], 0.0), 0.0)
        total = available.sum(axis=(1, 2)) * self.cell_area
        cut = np.flatnonzero(total > 0.0)  # the others give nothing and stay as they are (no relaxation)
        if not len(cut):
            return np.zeros(len(ids))
        patch, available, total = patch[cut], available[cut], total[cut]
        before = patch.sum(axis=(1, 2))
        patch -= available * np.minimum(1.0, volume[cut] / total)[:, None, None]
        relax_heights(patch, self._limit)
        after = patch.sum(axis=(1, 2))
        self.heights[ids[cut][:, None, None], rows[cut], cols[cut]] = patch
        self._stale[ids[cut]] = self.changed[ids[cut]] = True
        taken = np.zeros(len(ids))
        taken[cut] = (before - after) * self.cell_area
        return taken

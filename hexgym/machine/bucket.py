"""The bucket's geometry, computed from its profile: the mouth (top lip M, cutting edge E), the teeth's direction
and the struck and heaped capacities that the earthwork and the planner use, and the inner profile the bucket
mesh is built on (:mod:`hexgym_lab.meshes`).

The profile is designed from the pins and sizes in :mod:`hexgym.machine.parameters`: the top plate leaves the lip
M parallel to the pin line (bucket pin -> link pin), offset by ``BUCKET_PIN_STANDOFF`` so that ears carry both
pins; the floor meets the cutting edge E at ``BUCKET_FLOOR_ANGLE`` to the strike line M-E, and the teeth continue
the floor to ``BUCKET_TIP``. A cubic Bezier with those end tangents makes the wrapper round the heel; its one free
size (the tangent length) is solved so that struck volume + 1:1 heap = ``BUCKET_HEAPED_CAPACITY``.
"""

from __future__ import annotations

from functools import cache
from typing import NamedTuple

import numpy as np
from scipy.optimize import brentq
from scipy.spatial import ConvexHull

from hexgym.machine import parameters as p

PROFILE_POINTS = 40  # stations along the wrapper
_MM = 3  # decimals the geometry is kept to: the millimetre of a drawing, the litre of a capacity


class BucketProfile(NamedTuple):
    """The bucket's inner (struck) profile in the bucket frame (x, z), m."""

    inner: np.ndarray  # (PROFILE_POINTS, 2) inside of the wrapper, top lip -> cutting edge
    lip: np.ndarray  # top lip M
    edge: np.ndarray  # cutting edge E (the teeth continue the floor to BUCKET_TIP)
    floor: np.ndarray  # unit direction from the cutting edge into the bucket, along the floor
    opening: float  # strike-line length M -> E
    width: float  # inside width between the side plates


class BucketGeometry(NamedTuple):
    """What the earthwork and the planner use of the bucket, in the bucket frame (x, z), m (to the millimetre)."""

    lip: tuple[float, float]  # the top lip M of the mouth
    edge: tuple[float, float]  # the cutting edge E (teeth root)
    teeth_direction: tuple[float, float]  # unit vector, edge -> out along the floor
    struck_capacity: float  # m^3: the inner profile closed by the strike line, times the inside width
    heaped_capacity: float  # m^3: struck plus the 1:1 heap over the opening (ISO 7451 / SAE J296)

    @property
    def mouth_centre(self) -> tuple[float, float, float]:
        """The mouth's centre, the strike line's midpoint (x, y, z) in the bucket frame."""
        return ((self.lip[0] + self.edge[0]) / 2, 0.0, (self.lip[1] + self.edge[1]) / 2)

    @property
    def mouth_length(self) -> float:
        """The strike line's length M -> E, m."""
        return float(np.hypot(self.edge[0] - self.lip[0], self.edge[1] - self.lip[1]))


def polygon_area(points: np.ndarray) -> float:
    """Shoelace area of a closed planar polygon (absolute)."""
    x, z = np.asarray(points).T
    return float(abs(x @ np.roll(z, -1) - z @ np.roll(x, -1)) / 2.0)


def heap_volume(opening: float, width: float) -> float:
    """Heap above the strike plane at a 1:1 repose (ISO 7451 / SAE J296), m^3."""
    return opening**2 * width / 4.0 - opening**3 / 12.0


def _rotation2(angle: float) -> np.ndarray:
    """2x2 counter-clockwise rotation (x toward z in a link's plane)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


@cache
def bucket_profile() -> BucketProfile:
    """The bucket's inner (struck) profile, top lip M -> cutting edge E (see the module's docstring)."""
    pin, link, tip = np.zeros(2), np.array(p.BUCKET_LINK_PIN), np.array(p.BUCKET_TIP)
    e = (link - pin) / np.hypot(*(link - pin))
    n = np.array([e[1], -e[0]])  # from the pin line toward the bucket's inside (the tip's side)
    if n @ (tip - pin) < 0:
        n = -n
    lip = pin + p.BUCKET_PIN_STANDOFF * n - p.BUCKET_LIP_AHEAD * e
    back = (lip - tip) / np.hypot(*(lip - tip))
    turns = (_rotation2(a) @ back for a in (p.BUCKET_FLOOR_ANGLE, -p.BUCKET_FLOOR_ANGLE))
    floor = max(turns, key=lambda d: d @ (link - tip))  # turned from the strike line toward the inside
    edge = tip + p.TOOTH_LENGTH * floor
    width = p.BUCKET_WIDTH - 2.0 * p.BUCKET_PLATE
    t = np.linspace(0.0, 1.0, PROFILE_POINTS)[:, None]

    def wrapper(h: float) -> np.ndarray:
        c = [lip, lip + h * e, edge + h * p.BUCKET_FLOOR_HANDLE * floor, edge]
        return (1 - t) ** 3 * c[0] + 3 * (1 - t) ** 2 * t * c[1] + 3 * (1 - t) * t**2 * c[2] + t**3 * c[3]

    opening = float(np.hypot(*(edge - lip)))
    target_area = (p.BUCKET_HEAPED_CAPACITY - heap_volume(opening, width)) / width
    h = brentq(lambda h: polygon_area(wrapper(h)) - target_area, 0.05, 3.0, xtol=1e-12)
    return BucketProfile(wrapper(h), lip, edge, floor, opening, width)


def struck_volume(profile: BucketProfile) -> float:
    """Struck capacity (m^3) of a profile: its convex inside closed by the strike line, times the inside width."""
    return float(ConvexHull(profile.inner).volume) * profile.width  # a 2-D hull's volume is its area


def bucket_geometry() -> BucketGeometry:
    """The bucket's mouth, teeth direction and capacities from :func:`bucket_profile`, to the millimetre."""
    prof = bucket_profile()
    struck = struck_volume(prof)

    def mm(v: np.ndarray) -> tuple[float, float]:
        return (round(float(v[0]), _MM), round(float(v[1]), _MM))

    return BucketGeometry(
        lip=mm(prof.lip),
        edge=mm(prof.edge),
        teeth_direction=mm(-prof.floor),
        struck_capacity=round(struck, _MM),
        heaped_capacity=round(struck + heap_volume(prof.opening, prof.width), _MM),
    )


BUCKET = bucket_geometry()


# -- the load as drawn: soil filling the bucket -------------------------------------------------------------------
FILL_STATIONS = 18  # grid points along the strike line (lip -> cutting edge) of a drawn load
FILL_ACROSS = 9  # and across the bucket's width


def _cavity_depths(profile: BucketProfile, s: np.ndarray) -> np.ndarray:
    """Depth (m) of the bucket's inside below the strike line at distances ``s`` from the lip along it, measured
    along the mouth's inward normal to the wrapper (0 at the lip and the cutting edge)."""
    along = (profile.edge - profile.lip) / profile.opening
    inward = np.array([-along[1], along[0]])
    if inward @ (profile.inner.mean(axis=0) - profile.lip) < 0:
        inward = -inward
    a, b = profile.inner[:-1], profile.inner[1:]  # wrapper segments
    depths = np.zeros(len(s))
    for k, origin in enumerate(profile.lip + np.outer(s, along)):
        # ray origin + h * inward against each segment a + u (b - a), u in [0, 1]
        d = b - a
        den = inward[0] * -d[:, 1] + inward[1] * d[:, 0]
        rel = a - origin
        with np.errstate(divide="ignore", invalid="ignore"):
            h = (rel[:, 0] * -d[:, 1] + rel[:, 1] * d[:, 0]) / den
            u = (inward[0] * rel[:, 1] - inward[1] * rel[:, 0]) / den
        hits = h[(np.abs(den) > 1e-12) & (u >= 0.0) & (u <= 1.0) & (h > 0.0)]
        depths[k] = hits.min() if hits.size else 0.0
    return depths


def fill_surface(volume: float, profile: BucketProfile | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The soil holding ``volume`` m^3 in the bucket, as heights over the mouth: (s, t, top, bottom).

    ``s`` (FILL_STATIONS,) runs along the strike line from the lip, ``t`` (FILL_ACROSS,) across the inside width;
    ``top`` and ``bottom`` (FILL_STATIONS, FILL_ACROSS) are heights out of the mouth (m, negative: into the bucket).
    The bottom is the wrapper (half a plate into it, so that no sliver of soil shows where there is none); the
    top is a level surface parallel to the strike line while the bucket holds less than its struck capacity, then
    the 1:1 heap of ISO 7451 (a hip roof over the mouth) cut flat at the height that holds ``volume``. Heaped
    capacity is the whole roof.
    """
    prof = bucket_profile() if profile is None else profile
    s = np.linspace(0.0, prof.opening, FILL_STATIONS)
    half = prof.width / 2.0
    t = np.linspace(-half, half, FILL_ACROSS)
    bottom = np.repeat((-_cavity_depths(prof, s) - p.BUCKET_PLATE / 2.0)[:, None], FILL_ACROSS, axis=1)
    roof = np.minimum(np.minimum(s, prof.opening - s)[:, None], np.minimum(t + half, half - t)[None, :])

    def top_at(level: float) -> np.ndarray:
        return np.maximum(np.minimum(level, roof), bottom)

    def held(level: float) -> float:
        return float(np.trapezoid(np.trapezoid(top_at(level) - bottom, t, axis=1), s))

    level = brentq(lambda c: held(c) - volume, bottom.min(), prof.opening / 2.0, xtol=1e-6) if volume > 0 else (
        bottom.min())  # fmt: skip
    return s, t, top_at(level), bottom


def fill_mesh(volume: float) -> tuple[np.ndarray, np.ndarray]:
    """A closed triangle mesh of the soil holding ``volume`` m^3 (:func:`fill_surface`) in the bucket frame, m:
    (vertices (n, 3), faces (m, 3), outward winding). Where there is no soil its top and bottom meet inside the
    wrapper plate."""
    prof = bucket_profile()
    s, t, top, bottom = fill_surface(volume, prof)
    along = (prof.edge - prof.lip) / prof.opening
    outward = np.array([along[1], -along[0]])
    if outward @ (prof.inner.mean(axis=0) - prof.lip) > 0:
        outward = -outward
    ns, nt = top.shape

    def points(height: np.ndarray) -> np.ndarray:
        planar = prof.lip + s[:, None, None] * along + height[..., None] * outward  # (ns, nt, 2): x, z
        y = np.broadcast_to(t[None, :], height.shape)
        return np.stack([planar[..., 0], y, planar[..., 1]], axis=-1).reshape(-1, 3)

    grid = np.arange(ns * nt).reshape(ns, nt)
    a, b, c, d = grid[:-1, :-1].ravel(), grid[1:, :-1].ravel(), grid[1:, 1:].ravel(), grid[:-1, 1:].ravel()
    quads = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    n = ns * nt
    loop = np.concatenate([grid[:, 0], grid[-1, 1:], grid[-2::-1, -1], grid[0, -2:0:-1]])  # the grid's rim, in order
    first, second = loop, np.roll(loop, -1)
    sides = np.concatenate([np.stack([second, first, first + n], 1), np.stack([second, first + n, second + n], 1)])
    faces = np.concatenate([quads, quads[:, ::-1] + n, sides])
    vertices = np.concatenate([points(top), points(bottom)])
    tri = vertices[faces]
    if np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() < 0:  # 6x the signed volume
        faces = faces[:, ::-1]
    return vertices, faces

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

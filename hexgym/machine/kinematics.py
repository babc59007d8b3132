"""Machine kinematics: cylinder lengths and moment arms, the bucket four-bar, tip position.

Joint vector ``q = [swing, boom, stick, bucket]`` in rad, signs as everywhere in hexgym: a positive
angle is the direction a positive spool (cylinder extension) moves the joint, so every moment
arm ``dC/dq`` (the paper's Eqn 5) is positive inside the joint range.

The front linkage moves in the upper structure's x-z plane. Planar points are ``(x, z)`` in
the upper frame (origin on the swing axis at the top of the swing bearing). The geometry comes
from :mod:`hexgym.machine.parameters`; ``assets/cat325.xml`` is generated from the same numbers by
:mod:`hexgym.machine.mjcf`, and the tests check that MuJoCo and this module agree.
"""

from __future__ import annotations

import functools
import math
from functools import cache

import numpy as np
from scipy.optimize import brentq, least_squares

from hexgym.interpolation import UniformTable
from hexgym.machine import parameters as p

JOINTS = ("swing", "boom", "stick", "bucket")
FRONT_CYLINDERS = ("boom", "stick", "bucket")

# Relative in-plane rotation of each link's frame to its parent's at joint angle 0, and the
# sign of rotation per unit joint angle (+1 counter-clockwise in the x-z plane, seen from +y
# looking along -y ... i.e. x towards z).
_STICK_FRAME_OFFSET = -np.pi / 2.0
_SIGN = {"boom": 1.0, "stick": -1.0, "bucket": -1.0}


def rotation(angle: float) -> np.ndarray:
    """2x2 rotation taking x towards z by ``angle`` (counter-clockwise in the x-z plane)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


def _perp(v: np.ndarray) -> np.ndarray:
    """d/dangle of a vector rotated counter-clockwise: (x, z) -> (-z, x)."""
    return np.array([-v[1], v[0]])


# --------------------------------------------------------------------------------------------
# The bucket four-bar (stick frame). The guide link pivots on the stick at G, the power link
# joins the bucket at K; the bucket cylinder's rod end is the joint J of the two links.
_G = np.array(p.GUIDE_LINK_PIVOT)
_P_BUCKET = np.array([p.STICK_LENGTH, 0.0])
_K_BUCKET = np.array(p.BUCKET_LINK_PIN)
_C_BUCKET = np.array(p.BUCKET_CYLINDER_BASE)
# J lies on the stick's outer side of the line G -> K (the H-link's assembly mode).
_J_SIDE = 1.0
# the same points as plain floats, for _four_bar's scalar arithmetic
_G_XZ, _P_XZ, _K_XZ, _C_XZ = (tuple(v.tolist()) for v in (_G, _P_BUCKET, _K_BUCKET, _C_BUCKET))


def _four_bar(q_bucket: float) -> tuple[float, float, float, float, float, float]:
    """The bucket four-bar at ``q_bucket`` in the stick frame: J, K and dJ/dq as (jx, jz, kx, kz, djx, djz).
    Plain floats (no small numpy arrays): the Python models solve it twice per control period."""
    (gx, gz), (px, pz), (kx0, kz0) = _G_XZ, _P_XZ, _K_XZ
    c, s = math.cos(q_bucket), math.sin(q_bucket)
    kx = px + c * kx0 + s * kz0  # P + rotation(-q) K
    kz = pz - s * kx0 + c * kz0
    # J: where the guide link's circle about G meets the power link's about K, on the _J_SIDE of G -> K
    r1, r2 = p.GUIDE_LINK_LENGTH, p.POWER_LINK_LENGTH
    dx, dz = kx - gx, kz - gz
    d = math.hypot(dx, dz)
    a = (r1 * r1 - r2 * r2 + d * d) / (2.0 * d)
    h2 = r1 * r1 - a * a
    if h2 < 0.0:
        raise ValueError(f"linkage cannot close: circles r={r1:.3f}, r={r2:.3f} at distance {d:.3f}")
    ux, uz, h = dx / d, dz / d, _J_SIDE * math.sqrt(h2)
    jx, jz = gx + a * ux - h * uz, gz + a * uz + h * ux
    # |J - G| = const and |J - K| = const  =>  (J-G).dJ = 0 and (J-K).(dJ - dK) = 0, with dK = -perp(K - P)
    dkx, dkz = kz - pz, px - kx
    a11, a12, a21, a22 = jx - gx, jz - gz, jx - kx, jz - kz
    det = a11 * a22 - a12 * a21
    if det == 0.0:
        raise ValueError(f"the bucket four-bar is singular at {q_bucket:.4f} rad")
    b2 = a21 * dkx + a22 * dkz
    return jx, jz, kx, kz, -a12 * b2 / det, a11 * b2 / det


def bucket_link_points(q_bucket: float) -> tuple[np.ndarray, np.ndarray]:
    """Return (J, K) in the stick frame: the link joint and the bucket's link pin."""
    jx, jz, kx, kz, _, _ = _four_bar(q_bucket)
    return np.array([jx, jz]), np.array([kx, kz])


# --------------------------------------------------------------------------------------------
# Cylinder length C(q) and moment arm dC/dq per front joint.
def _triangle(name: str) -> tuple[np.ndarray, np.ndarray, float]:
    """Base pin (parent frame, relative to the joint), rod pin (child frame), frame offset."""
    if name == "boom":
        foot = np.array(p.BOOM_FOOT)
        return np.array(p.BOOM_CYLINDER_BASE) - foot, np.array(p.BOOM_CYLINDER_ROD_PIN), 0.0
    if name == "stick":
        stick_pin = np.array([p.BOOM_LENGTH, 0.0])
        return (
            np.array(p.STICK_CYLINDER_BASE) - stick_pin,
            np.array(p.STICK_CYLINDER_ROD_PIN),
            _STICK_FRAME_OFFSET,
        )
    raise KeyError(name)


@cache
def _triangle_floats(name: str) -> tuple[float, ...]:
    """:func:`_triangle` and the joint's sign as plain floats: (base x, z, rod x, z, offset, sign)."""
    base, rod, offset = _triangle(name)
    return (*base.tolist(), *rod.tolist(), float(offset), _SIGN[name])


def cylinder_geometry(name: str, angle: float) -> tuple[float, float]:
    """Pin-to-pin length (m) and moment arm dC/dq (m/rad) of cylinder ``name`` at its joint's angle (rad)."""
    if name == "bucket":
        jx, jz, _, _, djx, djz = _four_bar(angle)
        dx, dz = jx - _C_XZ[0], jz - _C_XZ[1]
        length = math.hypot(dx, dz)
        return length, (dx * djx + dz * djz) / length
    bx, bz, rx, rz, offset, sign = _triangle_floats(name)
    c, s = math.cos(offset + sign * angle), math.sin(offset + sign * angle)
    px, pz = c * rx - s * rz, s * rx + c * rz  # the rod pin in the parent frame
    dx, dz = px - bx, pz - bz
    length = math.hypot(dx, dz)
    return length, sign * (dx * -pz + dz * px) / length  # d . perp(rod pin), perp(v) = (-v_z, v_x)


def cylinder_length(name: str, angle: float) -> float:
    """Pin-to-pin length (m) of cylinder ``name`` at its joint's angle (rad)."""
    return cylinder_geometry(name, angle)[0]


def moment_arm(name: str, angle: float) -> float:
    """dC/dq (m/rad): cylinder force times this is the joint torque (the paper's Eqn 5)."""
    return cylinder_geometry(name, angle)[1]


@cache
def _monotone_bracket(name: str) -> tuple[float, float]:
    """The widest interval around 0 on which the cylinder length rises with the angle."""
    grid = np.linspace(-np.pi, np.pi, 3601)
    arms = np.array([_safe_arm(name, a) for a in grid])
    i0 = int(np.argmin(np.abs(grid)))
    lo = hi = i0
    while lo > 0 and arms[lo - 1] > 0:
        lo -= 1
    while hi < len(grid) - 1 and arms[hi + 1] > 0:
        hi += 1
    return float(grid[lo]), float(grid[hi])


def _safe_arm(name: str, angle: float) -> float:
    try:
        return moment_arm(name, angle)
    except (ValueError, np.linalg.LinAlgError):
        return -1.0


def joint_angle(name: str, length: float) -> float:
    """Inverse of :func:`cylinder_length`: the joint angle (rad) at a cylinder length (m)."""
    lo, hi = _monotone_bracket(name)
    f_lo, f_hi = cylinder_length(name, lo) - length, cylinder_length(name, hi) - length
    if f_lo > 0 or f_hi < 0:
        raise ValueError(f"{name} cylinder length {length:.4f} m is outside the linkage's reach")
    return float(brentq(lambda a: cylinder_length(name, a) - length, lo, hi, xtol=1e-13))


@cache
def joint_range(name: str) -> tuple[float, float]:
    """The joint's range (rad) as the cylinder's stroke allows; swing is unlimited."""
    if name == "swing":
        return (-np.inf, np.inf)
    cyl = p.CYLINDERS[name]
    return joint_angle(name, cyl.retracted_length), joint_angle(name, cyl.extended_length)


# --------------------------------------------------------------------------------------------
# Link poses, tip position and Jacobian.
def link_angles(q: np.ndarray) -> tuple[float, float, float]:
    """Absolute in-plane angles of the boom, stick and bucket frames' x axes."""
    boom = q[1]
    stick = boom + _STICK_FRAME_OFFSET - q[2]
    bucket = stick - q[3]
    return boom, stick, bucket


def planar_pins(q: np.ndarray) -> dict[str, np.ndarray]:
    """All pins and the tip as (x, z) in the upper frame for joint vector ``q``."""
    boom, stick, _ = link_angles(q)
    foot = np.array(p.BOOM_FOOT)
    r_boom, r_stick = rotation(boom), rotation(stick)
    stick_pin = foot + r_boom @ np.array([p.BOOM_LENGTH, 0.0])
    j, k = bucket_link_points(q[3])
    in_stick = lambda v: stick_pin + r_stick @ v  # noqa: E731 - local frame change
    bucket_rot = rotation(-q[3])
    return {
        "boom_foot": foot,
        "boom_cylinder_base": np.array(p.BOOM_CYLINDER_BASE),
        "boom_cylinder_rod": foot + r_boom @ np.array(p.BOOM_CYLINDER_ROD_PIN),
        "stick_cylinder_base": foot + r_boom @ np.array(p.STICK_CYLINDER_BASE),
        "stick_pin": stick_pin,
        "stick_cylinder_rod": in_stick(np.array(p.STICK_CYLINDER_ROD_PIN)),
        "bucket_cylinder_base": in_stick(_C_BUCKET),
        "guide_link_pivot": in_stick(_G),
        "bucket_cylinder_rod": in_stick(j),
        "bucket_link_pin": in_stick(k),
        "bucket_pin": in_stick(_P_BUCKET),
        "tip": in_stick(_P_BUCKET + bucket_rot @ np.array(p.BUCKET_TIP)),
    }


def _to_world(planar: np.ndarray, swing: float) -> np.ndarray:
    x, z = planar
    c, s = np.cos(swing), np.sin(swing)
    return np.array([c * x, s * x, z + p.SWING_BEARING_HEIGHT])


def tip_position(q: np.ndarray) -> np.ndarray:
    """Bucket teeth position (m) in the world frame."""
    q = np.asarray(q, dtype=float)
    return _to_world(planar_pins(q)["tip"], q[0])


def front_angles_for(radius: float, height: float, bucket_angle: float, guess: np.ndarray) -> tuple[np.ndarray, float]:
    """Boom, stick and bucket angles (rad) that put the teeth ``radius`` m from the swing axis, ``height`` m above
    the ground, with the bucket frame at absolute angle ``bucket_angle`` (:func:`link_angles`' third), within the
    joints' ranges; searched from ``guess`` (the three angles). Returns them and the teeth's miss (m)."""
    ranges = np.array([joint_range(name) for name in FRONT_CYLINDERS])

    def miss(front: np.ndarray) -> np.ndarray:
        q = np.array([0.0, *front])
        tip = tip_position(q)
        return np.array([tip[0] - radius, tip[2] - height, link_angles(q)[2] - bucket_angle])

    start = np.clip(np.asarray(guess, dtype=float), ranges[:, 0] + 1e-6, ranges[:, 1] - 1e-6)
    found = least_squares(miss, start, bounds=(ranges[:, 0], ranges[:, 1]), xtol=1e-10)
    return found.x, float(np.hypot(*miss(found.x)[:2]))


def tip_jacobian(q: np.ndarray) -> np.ndarray:
    """d(tip)/dq, 3x4, world frame."""
    q = np.asarray(q, dtype=float)
    pins = planar_pins(q)
    tip = pins["tip"]
    planar_cols = [
        _perp(tip - pins["boom_foot"]),
        -_perp(tip - pins["stick_pin"]),
        -_perp(tip - pins["bucket_pin"]),
    ]
    c, s = np.cos(q[0]), np.sin(q[0])
    jac = np.zeros((3, 4))
    jac[:, 0] = [-s * tip[0], c * tip[0], 0.0]
    for col, (dx, dz) in enumerate(planar_cols, start=1):
        jac[:, col] = [c * dx, s * dx, dz]
    return jac


# --------------------------------------------------------------------------------------------
# Closed-chain assembly: the passive joints of the MJCF model for given main joint angles.
def passive_joints(q: np.ndarray) -> dict[str, float]:
    """In-plane angles (rad, counter-clockwise) and cylinder extensions (m) of the passive parts.

    Angles are of each part's axis in its parent link's frame: the cylinder barrels point from
    base pin to rod pin; the guide link from its pivot to J; the power link from J to K,
    relative to the guide link. Extensions are measured from fully retracted.
    """
    q = np.asarray(q, dtype=float)
    out: dict[str, float] = {}
    for name in ("boom", "stick"):
        base, rod, offset = _triangle(name)
        d = rotation(offset + _SIGN[name] * q[JOINTS.index(name)]) @ rod - base
        out[f"{name}_barrel"] = float(np.arctan2(d[1], d[0]))
        out[f"{name}_extension"] = float(np.hypot(*d)) - p.CYLINDERS[name].retracted_length
    j, k = bucket_link_points(q[3])
    d = j - _C_BUCKET
    out["bucket_barrel"] = float(np.arctan2(d[1], d[0]))
    out["bucket_extension"] = float(np.hypot(*d)) - p.BUCKET_CYLINDER.retracted_length
    guide = float(np.arctan2(*(j - _G)[::-1]))
    out["guide_link"] = guide
    out["power_link"] = float(np.arctan2(*(k - j)[::-1])) - guide
    return out


@functools.cache
def moment_arm_tables() -> tuple[UniformTable, ...]:
    """Each front cylinder's moment arm (m/rad) sampled over its joint range every ~1 mrad.

    The arm depends on its own joint angle only; interpolating this is ~50x faster than the
    four-bar solution of :func:`moment_arm` and within 5e-6 m of it (a test).
    """
    tables = []
    for name in FRONT_CYLINDERS:
        lower, upper = joint_range(name)
        angles = np.linspace(lower, upper, 2001)
        tables.append(UniformTable(lower, upper, np.array([moment_arm(name, a) for a in angles])))
    return tuple(tables)


def tabulated_moment_arms(q: np.ndarray) -> np.ndarray:
    """[boom, stick, bucket] moment arms (m/rad) at main joint angles ``q``, from the sampled tables."""
    return np.array([table(float(q[i + 1])) for i, table in enumerate(moment_arm_tables())])


def check_joint_angles(q: np.ndarray, what: str = "joint angles") -> np.ndarray:
    """Four finite joint angles (rad; swing, boom, stick, bucket) within the joints' ranges (:func:`joint_range`),
    as an array; ValueError naming ``what`` and the joint otherwise."""
    q = np.asarray(q, dtype=float)
    if q.shape != (len(JOINTS),) or not np.all(np.isfinite(q)):
        raise ValueError(f"{what}: need four finite angles {','.join(JOINTS)} (rad), got {np.array2string(q)}")
    for name, angle in zip(JOINTS, q, strict=True):
        lo, hi = joint_range(name)
        if not lo - 1e-9 <= angle <= hi + 1e-9:
            raise ValueError(f"{what}: {name} {angle:.4g} rad is outside its range {lo:.4f} to {hi:.4f} rad")
    return q

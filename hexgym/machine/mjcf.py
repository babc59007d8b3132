"""Writes ``assets/cat325.xml`` from :mod:`hexgym.machine.parameters` and :mod:`hexgym.machine.kinematics`.

The MJCF is generated so the pins, masses, joint ranges and the closed-chain assembly can
never drift from the kinematics module; the generated file is committed and a test checks it
matches this generator. Run ``hexgym build-assets`` after changing a parameter.

Structure: the four main hinges form a kinematic tree; every hydraulic cylinder is a barrel
body (hinged at its base pin) with a rod body on a slide joint, and the bucket's four-bar is a
guide link and a power link; each loop is closed by a ``connect`` equality between two pin
sites. Body frames are chosen so that qpos0 (all joints at their ``ref``) is an assembled
configuration with the main joints at 0.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hexgym.files import atomic_path
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.names import BOOM_BODY, BUCKET_BODY, PAYLOAD_BODY, STICK_BODY, TIP_SITE, UPPER_BODY

CYLINDER_RGBA = "0.15 0.15 0.15 1"
ROD_RGBA = "0.85 0.85 0.88 1"
# The four actuators are integrated-velocity servos on the main hinges: ctrl is the commanded
# joint rate (rad/s), the activation integrates it into a position target that a stiff, damped
# spring tracks, so a zero command holds the joint as a closed spool does. The hydraulic models
# turn cylinder speeds into joint rates with the moment arms of hexgym.machine.kinematics (Eqn 5). Acting
# on the tree joints (not on the cylinder slides, which are closed to the links by soft
# constraints) keeps the servos stable. (kp, kv) per joint: kp is integrated explicitly, so it is
# capped by omega*dt <= 0.3 at the smallest joint inertia over the workspace (swing 8.3e4,
# boom 8.8e4, stick 1.35e4, bucket 7.6e2 kg m^2; up to 5.1e5, 4.5e5, 6.8e4, 6.9e3 with 2 t in
# the bucket); kv (integrated implicitly) damps near-critically at a typical inertia.
SERVO_GAINS = {"swing": (2e8, 1.3e7), "boom": (1e9, 2.8e7), "stick": (1.5e8, 4.2e6), "bucket": (1e7, 3.5e5)}
MAX_JOINT_RATE = {"swing": 1.5, "boom": 1.0, "stick": 1.0, "bucket": 2.0}  # rad/s, ctrl range
PAYLOAD_CENTRE = (0.80, -0.30)  # bucket frame: centroid of a heaped load in the shell [est]
# operator's eye in the upper frame: cab on the left (+y), seated height below the roof [est]
CAB_EYE = (0.85, 1.0, p.CAB_ROOF_HEIGHT - p.SWING_BEARING_HEIGHT - 0.5)
HOME = np.array([0.0, 0.35, 0.85, 0.75])  # main joints of keyframe "home": bucket near the ground
TIMESTEP = 0.002  # s, the full model (the reference hydraulics need it: oil-spring modes of ~2 Hz and stiffer)
LEAN_TIMESTEP = 0.025  # s, the lean model: quasi-steady velocities from the tables, no stiff dynamics
LEAN_SERVO_DAMPING = 1e12  # N m s/rad, see _lean_actuators
# m: a lean machine's contacts are reported while penetrating up to this deep, and never active
# (MuJoCo: detected within margin + gap, active below margin; margin = -this, gap = this). The stall
# stops a joint within one 25 ms step of touching (< 0.1 m at the teeth at full rate).
LEAN_CONTACT_DEPTH = 0.5


def _fmt(*values: float) -> str:
    return " ".join(f"{v:.12g}" if abs(v) > 1e-12 else "0" for v in values)


def _planar(xz: tuple[float, float] | np.ndarray) -> str:
    return _fmt(xz[0], 0.0, xz[1])


def _quat(angle: float) -> str:
    """Quaternion of an in-plane rotation by ``angle`` (x towards z, i.e. about -y)."""
    return _fmt(np.cos(angle / 2.0), 0.0, -np.sin(angle / 2.0), 0.0)


def _box_diag(mass: float, size: tuple[float, float, float]) -> np.ndarray:
    x, y, z = size
    return np.array([mass * (y * y + z * z) / 12, mass * (x * x + z * z) / 12, mass * (x * x + y * y) / 12])


def _box_inertia(mass: float, size: tuple[float, float, float]) -> str:
    return _fmt(*_box_diag(mass, size))


def _inertial(pos: tuple[float, float, float], mass: float, size: tuple[float, float, float]) -> str:
    return f'<inertial pos="{_fmt(*pos)}" mass="{_fmt(mass)}" diaginertia="{_box_inertia(mass, size)}"/>'


def _cylinder(name: str, base: tuple[float, float] | np.ndarray, parent_angle0: dict[str, float], indent: str) -> str:
    """Barrel body at ``base`` (parent frame) with the rod body on the slide joint ``name_cylinder``."""
    cyl = p.CYLINDERS[name]
    ext0 = parent_angle0[f"{name}_extension"]
    length0 = cyl.retracted_length + ext0
    barrel_len = cyl.retracted_length - 0.15  # barrel ends short of the rod clevis when retracted
    ys = [0.0] if cyl.count == 1 else [-0.42, 0.42]  # the boom's pair straddles the boom
    barrel_geoms = "".join(
        f'\n{indent}    <geom class="barrel" size="{_fmt(cyl.bore / 2 + 0.03)}" '
        f'fromto="{_fmt(0.05, y, 0, barrel_len, y, 0)}"/>'
        for y in ys
    )
    rod_geoms = "".join(
        f'\n{indent}      <geom class="rod" size="{_fmt(cyl.rod / 2)}" '
        f'fromto="{_fmt(-cyl.stroke - 0.05, y, 0, -0.05, y, 0)}"/>'
        f'\n{indent}      <geom class="clevis" pos="{_fmt(0, y, 0)}"/>'
        for y in ys
    )
    rod_mass = cyl.rod_mass * cyl.count
    barrel_mass = cyl.barrel_mass * cyl.count
    return f"""
{indent}<body name="{name}_cylinder_barrel" pos="{_planar(base)}" quat="{_quat(parent_angle0[f"{name}_barrel"])}">
{indent}  {_inertial((barrel_len / 2, 0, 0), barrel_mass, (barrel_len, 0.25, 0.25))}
{indent}  <joint name="{name}_cylinder_pivot" class="passive"/>{barrel_geoms}
{indent}  <body name="{name}_cylinder_rod" pos="{_fmt(length0, 0, 0)}">
{indent}    {_inertial((-cyl.stroke / 2, 0, 0), rod_mass, (cyl.stroke, 0.15, 0.15))}
{indent}    <joint name="{name}_cylinder" class="cylinder" ref="{_fmt(ext0)}" range="0 {_fmt(cyl.stroke)}"/>
{indent}    <site name="{name}_cylinder_rod_end" class="pin"/>{rod_geoms}
{indent}  </body>
{indent}</body>"""


_EQUALITIES = """  <equality>
    <connect name="boom_cylinder" class="cat325" site1="boom_cylinder_rod_end" site2="boom_cylinder_rod_pin"/>
    <connect name="stick_cylinder" class="cat325" site1="stick_cylinder_rod_end" site2="stick_cylinder_rod_pin"/>
    <connect name="bucket_cylinder" class="cat325" site1="bucket_cylinder_rod_end" site2="bucket_cylinder_rod_pin"/>
    <connect name="power_link" class="cat325" site1="power_link_bucket_end" site2="bucket_link_pin"/>
  </equality>
"""


_CYLINDER_BASES = {"boom": p.BOOM_CYLINDER_BASE, "stick": p.STICK_CYLINDER_BASE, "bucket": p.BUCKET_CYLINDER_BASE}


def _four_bar(a0: dict[str, float], power_link_pos: np.ndarray) -> str:
    """The bucket linkage's guide and power link bodies (full model only)."""
    return f"""            <body name="guide_link" pos="{_planar(p.GUIDE_LINK_PIVOT)}" quat="{_quat(a0["guide_link"])}">
              {_inertial((p.GUIDE_LINK_LENGTH / 2, 0, 0), p.GUIDE_LINK_MASS, (p.GUIDE_LINK_LENGTH, 0.5, 0.15))}
              <joint name="guide_link" class="passive"/>
              <geom class="visual" mesh="guide_link"/>
              <site name="bucket_cylinder_rod_pin" class="pin" pos="{_planar(power_link_pos)}"/>
              <body name="power_link" pos="{_planar(power_link_pos)}" quat="{_quat(a0["power_link"])}">
                {_inertial((p.POWER_LINK_LENGTH / 2, 0, 0), p.POWER_LINK_MASS, (p.POWER_LINK_LENGTH, 0.6, 0.15))}
                <joint name="power_link" class="passive"/>
                <geom class="visual" mesh="power_link"/>
                <site name="power_link_bucket_end" class="pin" pos="{_fmt(p.POWER_LINK_LENGTH, 0, 0)}"/>
              </body>
            </body>
"""


def _lumped_masses() -> dict[str, list[tuple[str, np.ndarray, float]]]:
    """Point masses that stand in for the cylinders and the four-bar in the lean model.

    Per carrying link: (name, planar position in its frame, mass). A cylinder pinned at both ends
    hangs its weight on its two pins in the ratio of its centre of mass along it (at HOME), so its
    mass is split between its base pin (on the link it pushes from) and its rod pin (on the link
    it pushes); the bucket cylinder's rod pin and the guide link sit on the stick; the power link
    is split between its two ends. Frozen at HOME: the cylinders' swing across the stroke and the
    links' rotational inertia are left out (the cylinders are ~13 % of the front's mass; the
    difference in the joint loads is measured in tests/test_model.py).
    """
    a_home = kinematics.passive_joints(HOME)
    j_home, k_home = kinematics.bucket_link_points(HOME[3])
    rod_pins = {
        "boom": ("boom", np.array(p.BOOM_CYLINDER_ROD_PIN)),
        "stick": ("stick", np.array(p.STICK_CYLINDER_ROD_PIN)),
        "bucket": ("stick", j_home),
    }
    base_links = {"boom": "upper", "stick": "boom", "bucket": "stick"}
    out: dict[str, list[tuple[str, np.ndarray, float]]] = {"upper": [], "boom": [], "stick": [], "bucket": []}
    for name, cyl in p.CYLINDERS.items():
        length = cyl.retracted_length + a_home[f"{name}_extension"]
        barrel_len = cyl.retracted_length - 0.15
        centre = (cyl.barrel_mass * barrel_len / 2 + cyl.rod_mass * (length - cyl.stroke / 2)) / (
            cyl.barrel_mass + cyl.rod_mass
        )
        mass = (cyl.barrel_mass + cyl.rod_mass) * cyl.count
        rod_link, rod = rod_pins[name]
        base = np.array(_CYLINDER_BASES[name])
        out[base_links[name]].append((f"{name}_cylinder_base_mass", base, mass * (1 - centre / length)))
        out[rod_link].append((f"{name}_cylinder_rod_mass", rod, mass * centre / length))
    guide_mid = (np.array(p.GUIDE_LINK_PIVOT) + j_home) / 2
    out["stick"].append(("guide_link_mass", guide_mid, p.GUIDE_LINK_MASS))
    out["stick"].append(("power_link_mass", j_home, p.POWER_LINK_MASS / 2))
    out["bucket"].append(("power_link_bucket_mass", np.array(p.BUCKET_LINK_PIN), p.POWER_LINK_MASS / 2))
    return out


_POINT_MASS_SIZE = 0.3  # m: each lumped mass is a small box, so that no inertia is exactly zero


def _merged_inertial(
    pos: tuple[float, float, float], mass: float, diag: np.ndarray, points: list[tuple[str, np.ndarray, float]]
) -> str:
    """One ``<inertial>`` for a link and the point masses it carries (lean model), about their centre.

    MuJoCo's ``fusestatic`` would merge jointless bodies the same way, but it would also merge the
    ``payload`` body, whose mass the environment changes; merging here keeps the lean model at
    seven bodies (a step costs ~10 % less than with one body per point mass).
    """
    masses = np.array([mass] + [m for _, _, m in points])
    centres = np.array([pos] + [(x[0], 0.0, x[1]) for _, x, _ in points], dtype=float)
    box = np.diag(np.full(3, _POINT_MASS_SIZE**2 / 6))  # a cube's inertia per kg
    inertias = [np.diag(diag)] + [m * box for _, _, m in points]
    total = masses.sum()
    com = masses @ centres / total
    inertia = np.zeros((3, 3))
    for m, c, i in zip(masses, centres, inertias, strict=True):
        r = c - com
        inertia += i + m * (r @ r * np.eye(3) - np.outer(r, r))
    full = (inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2])
    return f'<inertial pos="{_fmt(*com)}" mass="{_fmt(total)}" fullinertia="{_fmt(*full)}"/>'


def _range(name: str) -> str:
    lo, hi = kinematics.joint_range(name)
    return _fmt(lo, hi)


def model_xml(home_key: str | None = None, lean: bool = False) -> str:
    """The MJCF text of the machine; ``home_key`` is the ``<key>`` element of keyframe ``home``.

    ``lean``: the fast variant for the learned model (see :func:`_lumped_masses`): no cylinder or
    four-bar bodies, no equalities, a ``LEAN_TIMESTEP`` step.
    """
    a0 = kinematics.passive_joints(np.zeros(4))
    lumped = _lumped_masses() if lean else {}
    # lean: the machine's contacts are detected but inactive (any depth lies within the gap): the
    # learned model stalls a joint that drives into one (hexgym/model/python_backend.py, blocked_by_contact);
    # solved against its stiff velocity servos they would kick the links (README, contact kicks)
    collision_extra = f' margin="{_fmt(-LEAN_CONTACT_DEPTH)}" gap="{_fmt(LEAN_CONTACT_DEPTH)}"' if lean else ""

    def chain(cylinder: str) -> str:
        """The cylinder's bodies (full model; the lean model has its mass in the links)."""
        indent = " " * {"boom": 8, "stick": 10, "bucket": 12}[cylinder]
        return "" if lean else _cylinder(cylinder, _CYLINDER_BASES[cylinder], a0, indent) + "\n"

    def link_inertial(link: str, pos: tuple[float, float, float], mass: float, size: tuple[float, float, float]) -> str:
        """The link's inertial; in the lean model merged with the point masses it carries."""
        if lean:
            return _merged_inertial(pos, mass, _box_diag(mass, size), lumped[link])
        return _inertial(pos, mass, size)

    four_bar = "" if lean else _four_bar(a0, np.array([p.GUIDE_LINK_LENGTH, 0.0]))
    upper_diag = np.array([0.45, 0.75, 1.0]) * p.UPPER_YAW_INERTIA
    upper_inertial = (
        _merged_inertial((-0.55, 0, 0.55), p.UPPER_MASS, upper_diag, lumped["upper"])
        if lean
        else f'<inertial pos="-0.55 0 0.55" mass="{_fmt(p.UPPER_MASS)}"\n          diaginertia="{_fmt(*upper_diag)}"/>'
    )

    boom_pin = np.array([p.BOOM_LENGTH, 0.0])
    bucket_pin = np.array([p.STICK_LENGTH, 0.0])
    upper_z = p.SWING_BEARING_HEIGHT
    key = "" if home_key is None else f"\n  <keyframe>\n    {home_key}\n  </keyframe>\n"
    return f"""<mujoco model="{"cat325_lean" if lean else "cat325"}">
  <!-- Generated by hexgym/machine/mjcf.py from hexgym/machine/parameters.py;
       edit those, then run `hexgym build-assets`. -->
  <compiler angle="radian" meshdir="meshes" autolimits="true"/>

  <option timestep="{_fmt(LEAN_TIMESTEP if lean else TIMESTEP)}" integrator="implicitfast"/>

  <default>
    <default class="cat325">
      <joint damping="0" armature="0"/>
      <equality solref="0.004 1" solimp="0.99 0.999 0.001"/>
      <default class="front_joint">
        <joint type="hinge" axis="0 1 0" damping="2000" limited="true"/>
      </default>
      <default class="passive">
        <joint type="hinge" axis="0 -1 0"/>
      </default>
      <default class="cylinder">
        <joint type="slide" axis="1 0 0" limited="true"/>
      </default>
      <default class="visual">
        <geom type="mesh" contype="0" conaffinity="0" group="2" density="0" material="cat_yellow"/>
        <default class="barrel">
          <geom type="cylinder" material="cylinder_black"/>
        </default>
        <default class="rod">
          <geom type="cylinder" material="chrome"/>
        </default>
        <default class="clevis">
          <geom type="sphere" size="0.09" material="cylinder_black"/>
        </default>
      </default>
      <default class="collision">
        <geom group="3" contype="2" conaffinity="1" density="0" condim="3" friction="0.8 0.02 0.001"{collision_extra}/>
      </default>
      <default class="pin">
        <site type="sphere" size="0.05" group="4" rgba="0.9 0.2 0.2 1"/>
      </default>
    </default>
  </default>

  <asset>
    <material name="cat_yellow" rgba="0.96 0.72 0.06 1" specular="0.3" shininess="0.4"/>
    <material name="cylinder_black" rgba="{CYLINDER_RGBA}" specular="0.2"/>
    <material name="chrome" rgba="{ROD_RGBA}" specular="0.9" shininess="0.9"/>
    <material name="track_black" rgba="0.12 0.12 0.12 1" specular="0.1"/>
    <material name="steel" rgba="0.35 0.35 0.37 1" specular="0.4"/>
    <material name="glass" rgba="0.25 0.35 0.45 0.85" specular="0.8" shininess="0.9"/>
    <mesh name="undercarriage" file="undercarriage.stl"/>
    <mesh name="upper_deck" file="upper_deck.stl"/>
    <mesh name="cab" file="cab.stl"/>
    <mesh name="engine_housing" file="engine_housing.stl"/>
    <mesh name="counterweight" file="counterweight.stl"/>
    <mesh name="boom" file="boom.stl"/>
    <mesh name="stick" file="stick.stl"/>
    <mesh name="bucket" file="bucket.stl"/>
    <mesh name="guide_link" file="guide_link.stl"/>
    <mesh name="power_link" file="power_link.stl"/>
  </asset>

  <worldbody>
    <body name="undercarriage" childclass="cat325">
      {_inertial((0, 0, 0.5), p.UNDERCARRIAGE_MASS, (p.TRACK_LENGTH, p.TRACK_GAUGE + p.TRACK_SHOE_WIDTH, 1.0))}
      <geom class="visual" mesh="undercarriage" material="track_black"/>
      <geom class="collision" type="box" size="{_fmt(p.TRACK_LENGTH / 2, p.TRACK_SHOE_WIDTH / 2, p.TRACK_HEIGHT / 2)}"
        pos="{_fmt(0, p.TRACK_GAUGE / 2, p.TRACK_HEIGHT / 2)}"/>
      <geom class="collision" type="box" size="{_fmt(p.TRACK_LENGTH / 2, p.TRACK_SHOE_WIDTH / 2, p.TRACK_HEIGHT / 2)}"
        pos="{_fmt(0, -p.TRACK_GAUGE / 2, p.TRACK_HEIGHT / 2)}"/>
      <body name="{UPPER_BODY}" pos="0 0 {_fmt(upper_z)}">
        {upper_inertial}
        <joint name="swing" type="hinge" axis="0 0 1" damping="5000"/>
        <geom class="visual" mesh="upper_deck"/>
        <geom class="visual" mesh="cab"/>
        <geom class="visual" mesh="engine_housing"/>
        <geom class="visual" mesh="counterweight"/>
        <site name="boom_foot_pin" class="pin" pos="{_planar(p.BOOM_FOOT)}"/>
        <site name="boom_cylinder_base_pin" class="pin" pos="{_planar(p.BOOM_CYLINDER_BASE)}"/>
        <camera name="cab" pos="{_fmt(*CAB_EYE)}" xyaxes="0 -1 0 0.25 0 1" fovy="75"/>
{chain("boom")}        <body name="{BOOM_BODY}" pos="{_planar(p.BOOM_FOOT)}">
          {link_inertial("boom", (2.9, 0, 0.55), p.BOOM_MASS, (6.2, 0.6, 0.75))}
          <joint name="boom" class="front_joint" axis="0 -1 0" range="{_range("boom")}"/>
          <geom class="visual" mesh="boom"/>
          <geom class="collision" type="capsule" size="0.3"
            fromto="0.3 0 0.2 {_fmt(p.BOOM_KNEE[0], 0, p.BOOM_KNEE[1])}"/>
          <geom class="collision" type="capsule" size="0.3"
            fromto="{_fmt(p.BOOM_KNEE[0], 0, p.BOOM_KNEE[1], p.BOOM_LENGTH - 0.3, 0, 0.05)}"/>
          <site name="boom_cylinder_rod_pin" class="pin" pos="{_planar(p.BOOM_CYLINDER_ROD_PIN)}"/>
          <site name="stick_cylinder_base_pin" class="pin" pos="{_planar(p.STICK_CYLINDER_BASE)}"/>
          <site name="stick_pin" class="pin" pos="{_planar(boom_pin)}"/>
{chain("stick")}          <body name="{STICK_BODY}" pos="{_planar(boom_pin)}" quat="{_quat(-np.pi / 2)}">
            {link_inertial("stick", (1.3, 0, 0.1), p.STICK_MASS, (3.6, 0.45, 0.5))}
            <joint name="stick" class="front_joint" range="{_range("stick")}"/>
            <geom class="visual" mesh="stick"/>
            <geom class="collision" type="capsule" size="0.25"
              fromto="0.2 0 0.1 {_fmt(p.STICK_LENGTH - 0.3, 0, 0.05)}"/>
            <site name="stick_cylinder_rod_pin" class="pin" pos="{_planar(p.STICK_CYLINDER_ROD_PIN)}"/>
            <site name="bucket_cylinder_base_pin" class="pin" pos="{_planar(p.BUCKET_CYLINDER_BASE)}"/>
            <site name="guide_link_pivot_pin" class="pin" pos="{_planar(p.GUIDE_LINK_PIVOT)}"/>
            <site name="bucket_pin" class="pin" pos="{_planar(bucket_pin)}"/>
{chain("bucket")}{four_bar}            <body name="{BUCKET_BODY}" pos="{_planar(bucket_pin)}">
              {link_inertial("bucket", (0.75, 0, -0.3), p.BUCKET_MASS, (1.4, p.BUCKET_WIDTH, 1.0))}
              <joint name="bucket" class="front_joint" range="{_range("bucket")}"/>
              <geom class="visual" mesh="bucket"/>
              <geom name="bucket_collision" class="collision" type="mesh" mesh="bucket"/>
              <site name="bucket_link_pin" class="pin" pos="{_planar(p.BUCKET_LINK_PIN)}"/>
              <site name="{TIP_SITE}" class="pin" pos="{_planar(p.BUCKET_TIP)}"/>
              <body name="{PAYLOAD_BODY}" pos="{_planar(PAYLOAD_CENTRE)}">
                <site name="{PAYLOAD_BODY}" class="pin"/>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>

{"" if lean else _EQUALITIES}
  <actuator>
    <!-- Joint-rate servos (ctrl: rad/s) that hold their pose at zero command, torque-limited at
         the line reliefs; the hydraulic models (reference or learned) set them. -->
{_lean_actuators() if lean else _actuators()}
  </actuator>
{key}</mujoco>
"""


def _max_torque(name: str) -> float:
    """Largest torque the line relief allows over the joint's range (servo force limit), N m."""
    if name == "swing":  # the motor at its crossover relief, through the reduction
        return p.SWING_TORQUE_AT_RELIEF
    cyl = p.CYLINDERS[name]
    lo, hi = kinematics.joint_range(name)
    arm = max(kinematics.moment_arm(name, a) for a in np.linspace(lo, hi, 201))
    return p.LINE_RELIEF[name] * cyl.head_area * arm


def _actuators() -> str:
    lines = []
    for name in kinematics.JOINTS:
        kp, kv = SERVO_GAINS[name]
        rate, torque = MAX_JOINT_RATE[name], _max_torque(name)
        actrange = "" if name == "swing" else f' actrange="{_range(name)}"'
        lines.append(
            f'    <intvelocity name="{name}" joint="{name}" kp="{_fmt(kp)}" kv="{_fmt(kv)}"{actrange}\n'
            f'      ctrlrange="{_fmt(-rate, rate)}" forcerange="{_fmt(-torque, torque)}"/>'
        )
    return "\n".join(lines)


def _lean_actuators() -> str:
    """Velocity servos of the lean model: ctrl is the joint rate the tables ask for, rad/s.

    With the damping ``LEAN_SERVO_DAMPING`` integrated implicitly, the joint reaches the commanded
    rate within one step (damping x step >> the largest joint inertia, ~5e5 kg m^2) at any step
    size, so the joints integrate the tables' velocities as the paper does; a zero command holds a
    joint with a creep of load / damping (< 1e-6 rad/s). The force limits are the line reliefs', as
    in the full model: a cylinder pushing into the ground or the truck stalls at its relief.
    """
    lines = []
    for name in kinematics.JOINTS:
        rate = MAX_JOINT_RATE[name]
        lines.append(
            f'    <velocity name="{name}" joint="{name}" kv="{_fmt(LEAN_SERVO_DAMPING)}"\n'
            f'      ctrlrange="{_fmt(-rate, rate)}"/>'
        )
    return "\n".join(lines)


def home_keyframe(model_xml_text: str, meshdir: str) -> str:
    """The ``<key name="home">`` element: assembled qpos and matching actuator activations."""
    import mujoco

    from hexgym.machine.physics import assembled_state

    spec = mujoco.MjSpec.from_string(model_xml_text)
    spec.meshdir = meshdir
    qpos, act = assembled_state(spec.compile(), HOME)
    act_attr = f'\n      act="{_fmt(*act)}"' if len(act) else ""  # the lean model's servos have no activation
    return f'<key name="home" qpos="{_fmt(*qpos)}"{act_attr}/>'


def scene_xml_around(scene_text: str, machine_file: str) -> str:
    """The scene around another machine file: ``scene.xml`` with its include of the machine swapped.

    ``assets/scene_lean.xml`` (the lean machine) is generated from the hand-written
    ``assets/scene.xml`` by this, so the two worlds cannot drift apart.
    """
    include = '<include file="cat325.xml"/>'
    if include not in scene_text:
        raise ValueError(f"scene does not include the machine as {include}")
    header = "<!-- Generated by hexgym/machine/mjcf.py from scene.xml; edit that, then run `hexgym build-assets`. -->\n"
    return header + scene_text.replace(include, f'<include file="{machine_file}"/>')


def write_model(path: Path, lean: bool = False) -> None:
    """Generate the MJCF (with its ``home`` keyframe) and write it atomically to ``path``."""
    text = model_xml(home_keyframe(model_xml(lean=lean), str(path.parent / "meshes")), lean=lean)
    with atomic_path(path) as tmp:
        tmp.write_text(text)

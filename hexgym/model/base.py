"""What the learned model's two backends share, and the protocol every machine model follows.

:class:`MachineModel` is what replay, the environment and the planner ask of a machine model (the
reference model, :class:`hexgym.hydraulics.reference.ReferenceModel`, follows it too).
:class:`LearnedModelBase` holds what the Python backend (:mod:`hexgym.model.python_backend`) and the
native one (:mod:`hexgym.model.native_backend`) have in common: the limits both apply (the plugin gets
them through its config, :mod:`hexgym.model.plugin_mjcf`), the cylinder loads from the joint loads
(the paper's Eqn 5) and the trajectory row.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from hexgym.machine import kinematics, trajectory
from hexgym.machine import parameters as p
from hexgym.machine.physics import ExcavatorPhysics

END_MARGIN = p.STROKE_END_MARGIN  # m from a stroke end: the cylinder is at its stop
STROKES = np.array([p.CYLINDERS[n].stroke for n in kinematics.FRONT_CYLINDERS])
# The most a cylinder can push (head side) or pull (rod side) at its line relief, N
PUSH_LIMIT = np.array([p.LINE_RELIEF[n] * p.CYLINDERS[n].head_area for n in kinematics.FRONT_CYLINDERS])
PULL_LIMIT = np.array([p.LINE_RELIEF[n] * p.CYLINDERS[n].rod_area for n in kinematics.FRONT_CYLINDERS])
SWING_REST_RATE = 0.01  # rad/s: below this a swing with its spool closed is at rest
LEARNED_COLUMNS = trajectory.COMMON_COLUMNS + (trajectory.SWING_ACCELERATION,)  # the common ones, the swing table's
LEARNED_DTYPE = trajectory.row_dtype(LEARNED_COLUMNS)


def next_swing_rate(
    rate: float, acceleration: float, dt: float, spool_closed: bool, slowest: float, fastest: float
) -> tuple[float, float]:
    """The swing's rate after ``dt`` at ``acceleration``, and the acceleration applied (rad/s, rad/s^2).

    Beyond its table's rate axis (``slowest``..``fastest``, the fastest swings in its data) the swing
    does not accelerate further: the table would keep giving its edge's value. With its spool closed
    the crossover reliefs brake it to rest: it stops, it does not turn back.
    """
    if not slowest < rate < fastest and acceleration * rate > 0.0:
        acceleration = 0.0
    new_rate = rate + acceleration * dt
    if spool_closed and (new_rate * rate <= 0.0 or abs(new_rate) < SWING_REST_RATE):
        new_rate = 0.0
    return new_rate, acceleration


class MachineModel(Protocol):
    """What replay, the environment and the planner need of a machine model."""

    spools_m: np.ndarray  # the spools in force (swing, boom, stick, bucket), m

    @property
    def control_period(self) -> float:
        """Seconds one :meth:`step` advances."""
        ...

    def reset(self, start: str | np.ndarray = "home", payload_kg: float = 0.0) -> None:
        """Start at a keyframe name or joint angles (rad), at rest, spools neutral."""
        ...

    def step(self, spools_m: np.ndarray, n: int = 1) -> None:
        """Advance ``n`` control periods with the spools held."""
        ...

    def observe(self) -> np.ndarray:
        """One structured trajectory row."""
        ...

    def joint_loads(self) -> np.ndarray:
        """Torque each main joint's actuator must supply to hold the present motion, N m."""
        ...


class LearnedModelBase:
    """The learned model on either backend: MuJoCo's linkage (``physics``) driven by the tables.

    Subclasses set ``physics`` and ``spools_m`` and provide :attr:`control_period`,
    :attr:`swing_acceleration`, :meth:`reset`, :meth:`step` and :meth:`joint_loads`.
    """

    physics: ExcavatorPhysics
    spools_m: np.ndarray

    @property
    def control_period(self) -> float:
        """Seconds between table queries (one :meth:`step`)."""
        raise NotImplementedError

    @property
    def swing_acceleration(self) -> float:
        """The swing table's last acceleration, rad/s^2."""
        raise NotImplementedError

    def take_fuel_l(self) -> float:
        """Diesel (L) the machine's engine burnt since the last call, where the model measures it (the reference:
        its pumps' pressures and flows); NaN where it does not (the learned tables know no pressures: the task
        estimates the fuel from the motion, :mod:`hexgym.hydraulics.fuel`)."""
        return math.nan

    def joint_loads(self) -> np.ndarray:
        """Torque each main joint's actuator must supply to hold the present motion (N m); joint-limit
        forces are not part of it: at a stroke end the cylinder's stop carries the load, not its oil."""
        raise NotImplementedError

    def cylinder_loads(self, arms: np.ndarray | None = None) -> np.ndarray:
        """[boom, stick, bucket] cylinder force loads, N (+ = the cylinder must push; paper Eqn 5).

        ``arms``: the present moment arms, if the caller already has them.
        """
        return self.joint_loads()[1:] / (self.physics.moment_arms() if arms is None else arms)

    def observe(self) -> np.ndarray:
        """One trajectory row (``LEARNED_DTYPE``): the common columns (spools, cylinders, loads), the swing table's
        acceleration."""
        ph = self.physics
        arms = ph.moment_arms()  # once: the cylinders' speeds and loads both need them (the costliest part)
        rates = ph.joint_velocities()
        values = (
            [ph.time, *ph.joint_positions(), *rates, *ph.tip_position()]
            + [*(self.spools_m * 1e3), *ph.cylinder_extensions(), *(arms * rates[1:])]
            + [*self.cylinder_loads(arms), ph.swing_inertia(), self.swing_acceleration]
        )
        return np.array(tuple(values), dtype=LEARNED_DTYPE)

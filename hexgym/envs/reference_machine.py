"""The reference model (the real machine's stand-in) on the loading site, as the task's machine.

``HexLoading-v0`` with ``model="reference"`` runs the same task — pile, truck, digging force,
payload, spill, contacts, fuel — on the analytical open-centre circuit driving the full
MuJoCo machine (:class:`hexgym.hydraulics.reference.ReferenceModel`) instead of the learned tables.
It is slow (a few times real time) and meant for checking what an agent or a plan learned on the
fast model does on the "real" machine, not for training.

:class:`ReferenceMachine` presents the reference model with the learned model's interface
(:class:`hexgym.model.base.LearnedModelBase`): a 25 ms control period made of ``STEPS_PER_PERIOD``
reference steps, the joint loads as the learned model's (the loads the machine's dynamic model computes
from its state: :meth:`ExcavatorPhysics.holding_loads`, so the observation means the same on every model),
the swing's acceleration as its motor torque over the swing inertia, and the fuel its engine burns for the
pumps' pressures and flows (:meth:`ReferenceMachine.take_fuel_l`; the task estimates a learned model's
from its motion).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from hexgym.envs.world import build_world_model
from hexgym.hydraulics.overrides import HydraulicsOverrides
from hexgym.hydraulics.reference import ReferenceModel
from hexgym.machine.physics import to_force_inputs
from hexgym.model.base import LearnedModelBase

CONTROL_PERIOD = 0.025  # s: the learned model's, so the task's schedule (four periods a step) is the same
STEPS_PER_PERIOD = 12  # reference steps of 2.08 ms: next to the 2 ms its accuracy was measured at


def reference_world_model(scene_path: str | Path | None = None, tool_contact_slots: int = 0) -> mujoco.MjModel:
    """The loading site around the full machine (default ``scene.xml``) with force inputs for the circuit."""
    return build_world_model(scene_path, tool_contact_slots=tool_contact_slots, customise=to_force_inputs)


class ReferenceMachine(LearnedModelBase):
    """The reference model on a loading site, stepped in the learned model's 25 ms control periods.

    Args:
        model: a site model with force inputs (:func:`reference_world_model`).
        hydraulics: a unit's circuit (:class:`hexgym.hydraulics.overrides.HydraulicsOverrides`, e.g. a weaker
            engine's power limit); default the data sheet's.
    """

    def __init__(self, model: mujoco.MjModel, hydraulics: HydraulicsOverrides | None = None) -> None:
        self.reference = ReferenceModel(model, timestep=CONTROL_PERIOD / STEPS_PER_PERIOD, hydraulics=hydraulics)
        self.physics = self.reference.physics
        self.physics.tracks_constraint_load = True  # joint_loads reads it
        self.spools_m = self.reference.spools_m
        self._fuel_l = 0.0  # burnt since take_fuel_l last asked

    @property
    def control_period(self) -> float:
        """Seconds one :meth:`step` advances."""
        return CONTROL_PERIOD

    @property
    def swing_acceleration(self) -> float:
        """The swing motor's torque over the swing inertia, rad/s^2."""
        return float(self.reference.joint_torques()[0]) / self.physics.swing_inertia()

    def reset(self, start: str | np.ndarray = "home", payload_kg: float = 0.0) -> None:
        """Start at rest at a keyframe or joint angles with a payload, the circuit holding the pose."""
        self.reference.reset(start, payload_kg)
        self.spools_m = self.reference.spools_m
        self._fuel_l = 0.0
        self._hold_start()

    def _hold_start(self) -> None:
        """The start's constraint load with the oil holding the pose: the reset's solve had no actuator force,
        so the links were falling in it. The warm start is kept: the trajectory stays the reference's own."""
        d = self.physics.data
        warm_start = d.qacc_warmstart.copy()
        d.ctrl[:] = self.reference.joint_torques()  # at rest the affine actuators' torque is their ctrl
        mujoco.mj_forward(self.physics.model, d)
        self.physics.record_constraint_load()
        d.qacc_warmstart[:] = warm_start

    def step(self, spools_m: np.ndarray, n: int = 1) -> None:
        """Hold the spools (m, order swing, boom, stick, bucket) for ``n`` control periods; the engine's fuel rate
        at the end of each counts for the period (as :class:`hexgym.planning.check.PlanReplay` counts it)."""
        for _ in range(n):
            self.reference.step(spools_m, STEPS_PER_PERIOD)
            self._fuel_l += self.reference.fuel_rate_l_per_h() * CONTROL_PERIOD / 3600.0
        self.spools_m = self.reference.spools_m

    def take_fuel_l(self) -> float:
        """Diesel (L) the engine burnt since the last call: its pumps' pressures and flows through the BSFC map."""
        litres, self._fuel_l = self._fuel_l, 0.0
        return litres

    def joint_loads(self) -> np.ndarray:
        """Torque each main joint's actuator must supply to hold the present motion (N m), from the state, as
        on the learned model (:meth:`ExcavatorPhysics.holding_loads`), not the oil's torques: those also
        carry the links' acceleration and the circuit's transients, which no learned model has."""
        return self.physics.holding_loads()

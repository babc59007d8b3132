"""The env's fuel estimate (:mod:`hexgym.hydraulics.fuel`) against the reference circuit's fuel on one
command sequence: ``python -m hexgym.tools.fuel_check``."""

from __future__ import annotations

import numpy as np

from hexgym.hydraulics.fuel import actuator_power, fuel_litres
from hexgym.hydraulics.reference import ReferenceModel
from hexgym.model.commandlog import CommandLog
from hexgym.model.python_backend import LearnedModel
from hexgym.model.replay import replay

CHECK_SEQUENCE = np.array(
    [
        [0.0, 0, 0, 0, 0],
        [0.5, 0, 8, -11, -11],
        [3.0, 0, -9, 0, 0],
        [5.0, 0, 0, 11, 8],
        [7.5, 11, 11, 0, 6],
        [10.5, 0, 0, -6, -11],
        [12.0, -11, -6, 0, 8],
        [15.0, 0, 0, 0, 0],
    ],
    dtype=float,
)


def compare_with_reference(duration: float = 16.0, payload_kg: float = 1000.0) -> dict[str, float]:
    """Fuel (L) of :data:`CHECK_SEQUENCE`: the reference circuit's (pump pressures x flows through
    the BSFC map) against this module's estimate on the learned model."""
    commands = CommandLog(CHECK_SEQUENCE[:, 0], CHECK_SEQUENCE[:, 1:])
    dt = 0.01
    reference = replay(ReferenceModel(), commands, payload_kg=payload_kg, dt_out=dt, duration=duration)
    reference_l = float(np.sum(reference["fuel_rate_l_per_h"]) * dt / 3600.0)
    learned = LearnedModel()
    learned.reset("home", payload_kg=payload_kg)
    estimate_l = 0.0
    while learned.physics.time < duration - 1e-9:
        learned.step(commands.spools_at(learned.physics.time) * 1e-3)
        loads, rates = learned.joint_loads(), learned.physics.joint_velocities()
        swing_torque = learned.physics.swing_inertia() * learned.swing_acceleration
        estimate_l += fuel_litres(actuator_power(loads[1:], rates[1:], swing_torque, rates[0]), learned.control_period)
    return {"reference_l": reference_l, "estimate_l": estimate_l, "ratio": estimate_l / reference_l}


if __name__ == "__main__":
    print(compare_with_reference())

"""A summary of the compiled machine model: what a user checks first (mass, ranges, reach)."""

from __future__ import annotations

import mujoco
import numpy as np

from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.machine.physics import ExcavatorPhysics


def model_summary() -> dict[str, object]:
    """Operating mass, joint ranges, cylinders, tip at ``home`` and the reach envelope."""
    physics = ExcavatorPhysics()
    model = physics.model
    ranges = {}
    for name in kinematics.JOINTS:
        jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        ranges[name] = (
            [round(float(np.degrees(v)), 2) for v in model.jnt_range[jid]] if model.jnt_limited[jid] else None
        )
    cylinders = {
        name: {
            "bore_mm": c.bore * 1e3,
            "rod_mm": c.rod * 1e3,
            "stroke_m": c.stroke,
            "count": c.count,
            "retracted_m": c.retracted_length,
            "moment_arm_m": [round(kinematics.moment_arm(name, a), 3) for a in kinematics.joint_range(name)],
        }
        for name, c in p.CYLINDERS.items()
    }
    return {
        "operating_mass_kg": round(float(model.body_subtreemass[1]), 1),
        "joint_range_deg": ranges,
        "cylinders": cylinders,
        "tip_at_home_m": [round(float(v), 3) for v in physics.tip_position()],
        "swing_inertia_at_home_kgm2": round(physics.swing_inertia(), 0),
        **_envelope(),
    }


def _envelope(samples: int = 25) -> dict[str, float]:
    """Max reach, dig depth and cutting height of the tip over a grid of the joint ranges."""
    grids = [np.linspace(*kinematics.joint_range(n), samples) for n in kinematics.FRONT_CYLINDERS]
    tips = np.array(
        [kinematics.tip_position(np.array([0.0, b, s, k])) for b in grids[0] for s in grids[1] for k in grids[2]]
    )
    return {
        "max_reach_m": round(float(np.hypot(tips[:, 0], tips[:, 1]).max()), 2),
        "max_dig_depth_m": round(float(-tips[:, 2].min()), 2),
        "max_cutting_height_m": round(float(tips[:, 2].max()), 2),
    }

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


def model_table(summary: dict[str, object] | None = None) -> str:
    """:func:`model_summary` as a table a person reads: each figure named, with its unit and what it is."""
    s = summary if summary is not None else model_summary()
    x, y, z = s["tip_at_home_m"]
    rows = [
        ("operating mass", f"{s['operating_mass_kg']:,.0f} kg", "the whole machine as simulated, bucket empty"),
        ("teeth at home", f"x {x:.2f}, y {y:.2f}, z {z:.2f} m", "keyframe home; x forward from the swing axis, z up"),
        ("swing inertia at home", f"{s['swing_inertia_at_home_kgm2']:,.0f} kg m^2", "about the swing axis"),
        ("max reach", f"{s['max_reach_m']:.2f} m", "teeth from the swing axis, over the joint ranges"),
        ("max dig depth", f"{s['max_dig_depth_m']:.2f} m", "teeth below the ground"),
        ("max cutting height", f"{s['max_cutting_height_m']:.2f} m", "teeth above the ground"),
    ]
    lines = ["machine", *_columns(rows)]
    joints = [
        (name, "unlimited" if r is None else f"{r[0]:+.1f} to {r[1]:+.1f} deg")
        for name, r in s["joint_range_deg"].items()
    ]
    lines += ["", "joint ranges (the joint angle's limits)", *_columns(joints)]
    header = ("cylinder", "count", "bore", "rod", "stroke", "retracted length", "moment arm at the joint's limits")
    cylinders = [
        (
            name,
            str(c["count"]),
            f"{c['bore_mm']:.0f} mm",
            f"{c['rod_mm']:.0f} mm",
            f"{c['stroke_m']:.3f} m",
            f"{c['retracted_m']:.3f} m",
            " / ".join(f"{arm:.3f}" for arm in c["moment_arm_m"]) + " m",
        )
        for name, c in s["cylinders"].items()
    ]
    lines += ["", "cylinders (moment arm: joint torque per unit cylinder force, at the joint's lower / upper limit)"]
    lines += _columns([header, *cylinders])
    return "\n".join(lines)


def _columns(rows: list[tuple[str, ...]]) -> list[str]:
    """Rows of cells, left-aligned in columns two spaces apart, indented two."""
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    return ["  " + "  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip() for row in rows]

"""The trajectory format: the columns every machine model's rows (``observe()``, ``hexgym simulate``'s CSV) carry.

Every model writes :data:`COMMON_COLUMNS` first, in this order, then what it alone knows (pressures, flows, power,
fuel; ``docs/hydraulics.md``, "Trajectory format", lists each model's). Every name carries its unit: ``_rad``,
``_radps`` (rad/s), ``_m``, ``_mps``, ``_mm``, ``_n``, ``_pa``... except ``t`` (s), the command log's own column.

Names before this format (``q_swing``, ``qd_boom``, ``tip_x``, ``swing_acceleration_target``) stay readable:
:data:`OLD_NAMES` maps them, :func:`row_dtype` gives a row's fields them as numpy titles (``rows["q_swing"]`` is
``rows["q_swing_rad"]``) and :func:`current_name` renames a CSV header's.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from hexgym.machine.kinematics import FRONT_CYLINDERS, JOINTS

TIME = "t"  # s, as in the command log
JOINT_ANGLES = tuple(f"q_{j}_rad" for j in JOINTS)  # swing, boom, stick, bucket
JOINT_RATES = tuple(f"qd_{j}_radps" for j in JOINTS)
TIP = ("tip_x_m", "tip_y_m", "tip_z_m")  # the bucket's teeth in the world frame
SPOOLS = tuple(f"{j}_spool_mm" for j in JOINTS)  # the spools in force
CYLINDER_EXTENSIONS = tuple(f"{c}_extension_m" for c in FRONT_CYLINDERS)
CYLINDER_VELOCITIES = tuple(f"{c}_velocity_mps" for c in FRONT_CYLINDERS)
CYLINDER_FORCES = tuple(f"{c}_force_n" for c in FRONT_CYLINDERS)  # + pushes (the load the cylinder carries)
COMMON_COLUMNS = (
    (TIME,) + JOINT_ANGLES + JOINT_RATES + TIP + SPOOLS + CYLINDER_EXTENSIONS + CYLINDER_VELOCITIES + CYLINDER_FORCES
) + ("swing_inertia_kgm2",)
# what a model with pumps knows (the reference's circuit; the circuit model its power and fuel)
PUMP_COLUMNS = ("pump1_pressure_pa", "pump2_pressure_pa", "pump1_flow_m3s", "pump2_flow_m3s")
POWER_COLUMNS = ("pump_power_w", "fuel_rate_l_per_h")
# the learned models' swing: its table's acceleration
SWING_ACCELERATION = "swing_acceleration_target_radps2"

OLD_NAMES = dict(
    zip(
        tuple(f"q_{j}" for j in JOINTS) + tuple(f"qd_{j}" for j in JOINTS) + ("tip_x", "tip_y", "tip_z"),
        JOINT_ANGLES + JOINT_RATES + TIP,
        strict=True,
    )
) | {"swing_acceleration_target": SWING_ACCELERATION}
"""Each column's name before this format -> its name now."""
_TITLES = {new: old for old, new in OLD_NAMES.items()}


def current_name(name: str) -> str:
    """A trajectory column's name now (``q_swing`` -> ``q_swing_rad``; a current or unknown name as it is)."""
    return OLD_NAMES.get(name, name)


def row_dtype(columns: Iterable[str]) -> np.dtype:
    """The structured dtype (float64 fields) of rows with ``columns``; a renamed column also answers to its old
    name (a numpy title: ``dtype.names`` holds the current names only)."""
    return np.dtype([((_TITLES[c], c), np.float64) if c in _TITLES else (c, np.float64) for c in columns])

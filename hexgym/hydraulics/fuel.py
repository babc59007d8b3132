"""Fuel of the learned machine model: actuator power -> pump power -> engine brake power -> BSFC.

The MBL tables give velocities, not pressures, so the pumps' power is estimated from the
mechanical power the actuators deliver (the linkage's joint loads times the joint rates; for
the swing its inertia x acceleration x rate), divided by the open-centre valves' efficiency,
plus the standby flow's power through the centre bypass. The engine supplies that through the
pumps' efficiency and drives the accessories; :func:`hexgym.hydraulics.circuit.fuel_rate` turns brake
power into litres per hour through the BSFC map.
"""

from __future__ import annotations

import functools

import numpy as np

from hexgym.hydraulics.circuit import fuel_rate
from hexgym.interpolation import UniformTable
from hexgym.machine import parameters as p

# Brake power grid of the fuel-rate table: every 100 W, so that the BSFC map's knots (every 10 % of
# rated power) are grid points and the table is exact wherever the rate is linear in power.
_FUEL_TABLE_POINTS = 1251


def actuator_power(
    front_joint_loads: np.ndarray, front_joint_rates: np.ndarray, swing_torque: float, swing_rate: float
) -> float:
    """Mechanical power (W) the four actuators deliver or absorb (each counted as drawing from the pumps)."""
    loads, rates = np.asarray(front_joint_loads, dtype=float), np.asarray(front_joint_rates, dtype=float)
    if loads.shape != (3,) or rates.shape != (3,):
        raise ValueError(f"need 3 front joint loads and 3 rates, got shapes {loads.shape} and {rates.shape}")
    # plain floats: called every control period, where numpy's per-call cost on 3 values dominates
    front = sum(abs(load * rate) for load, rate in zip(loads.tolist(), rates.tolist(), strict=True))
    return front + abs(float(swing_torque) * float(swing_rate))


def brake_power(actuator_power_w: float) -> float:
    """Engine brake power (W) for ``actuator_power_w`` at the cylinders and the swing motor, capped at rated."""
    return min(_uncapped_brake_power(actuator_power_w), p.ENGINE_POWER)


def _uncapped_brake_power(actuator_power_w: np.ndarray | float) -> np.ndarray | float:
    """Brake power (W) the engine would need for ``actuator_power_w`` (float or array), before its rating caps it."""
    hydraulic = actuator_power_w / p.HYDRAULIC_VALVE_EFFICIENCY + p.STANDBY_HYDRAULIC_POWER
    return p.ACCESSORY_POWER + hydraulic / p.PUMP_OVERALL_EFFICIENCY


def actuator_powers(
    front_joint_loads: np.ndarray, front_joint_rates: np.ndarray, swing_torques: np.ndarray, swing_rates: np.ndarray
) -> np.ndarray:
    """:func:`actuator_power` of many machines at once: loads and rates (n, 3), swing torques and rates (n,), W."""
    each = np.abs(front_joint_loads * front_joint_rates)
    front = each[:, 0] + each[:, 1] + each[:, 2]  # summed in actuator_power's order, so the same floats
    return front + np.abs(swing_torques * swing_rates)


def fuel_litres_many(actuator_power_w: np.ndarray, seconds: np.ndarray) -> np.ndarray:
    """:func:`fuel_litres` of many machines at once (arrays of actuator powers, W, and intervals, s)."""
    brake = np.minimum(_uncapped_brake_power(actuator_power_w), p.ENGINE_POWER)
    return _fuel_rate_table().at(brake) * seconds / 3600.0


@functools.cache
def _fuel_rate_table() -> UniformTable:
    """:func:`hexgym.hydraulics.circuit.fuel_rate` (L/h) tabulated over brake power 0 W to rated
    (within 1e-5 of it: a test)."""
    powers = np.linspace(0.0, p.ENGINE_POWER, _FUEL_TABLE_POINTS)
    return UniformTable(0.0, p.ENGINE_POWER, np.array([fuel_rate(w) for w in powers]))


def fuel_litres(actuator_power_w: float, seconds: float) -> float:
    """Diesel (L) burnt in ``seconds`` at a constant actuator power (through the tabulated BSFC fuel rate)."""
    return _fuel_rate_table()(brake_power(actuator_power_w)) * seconds / 3600.0


# A loading-like spool sequence (t s, swing, boom, stick, bucket mm): reach, lower, dig, lift and
# swing, dump, return; the same one the first demo replayed.

"""The error-source analysis' counterfactual circuit and its rate lookup."""

import numpy as np
import pytest

from hexgym.hydraulics.circuit import HydraulicCircuit
from hexgym.machine import parameters as p
from hexgym.tools.swing_analysis import OwnPressureCircuit, acceleration_at_rate

FULL = np.ones(2)  # both regulators asking for full displacement


def test_own_pressure_pumps_ignore_the_other_pump():
    q_low, _, _ = OwnPressureCircuit.pump_flows(np.array([30e6, 5e6]), FULL)
    q_high, _, dq_dp = OwnPressureCircuit.pump_flows(np.array([30e6, 30e6]), FULL)
    assert q_low[0] == q_high[0]  # pump 1 does not see pump 2's pressure...
    assert q_high[0] == pytest.approx(p.PUMP_POWER_LIMIT / (30e6 + p.NFC_PRESSURE_IDLE))  # ...but its idle one
    real, _, _ = HydraulicCircuit.pump_flows(np.array([30e6, 30e6]), FULL)
    assert real[0] < 0.75 * q_high[0]  # the real machine shares the power: pump 1 gives less
    assert dq_dp[0, 1] == dq_dp[1, 0] == 0.0


def test_own_pressure_pumps_match_the_real_ones_with_the_other_pump_idle():
    pressures = np.array([25e6, p.NFC_PRESSURE_IDLE])
    own, own_dd, _ = OwnPressureCircuit.pump_flows(pressures, np.array([1.0, 0.3]))
    real, real_dd, _ = HydraulicCircuit.pump_flows(pressures, np.array([1.0, 0.3]))
    np.testing.assert_allclose(own, real)
    np.testing.assert_allclose(own_dd, real_dd)


def test_own_pressure_flow_derivative_matches_a_finite_difference():
    pressures, h = np.array([28e6, 12e6]), 1e3
    q, _, dq_dp = OwnPressureCircuit.pump_flows(pressures, FULL)
    for j in (0, 1):
        bumped = pressures.copy()
        bumped[j] += h
        numeric = (OwnPressureCircuit.pump_flows(bumped, FULL)[0] - q) / h
        np.testing.assert_allclose(dq_dp[:, j], numeric, rtol=1e-3, atol=1e-16)


def test_acceleration_at_rate_reads_the_first_crossing():
    t = np.arange(0.0, 1.0001, 0.02)
    traj = np.zeros(len(t), dtype=[("t", float), ("qd_swing", float)])
    traj["t"], traj["qd_swing"] = t, 0.5 * t**2  # acceleration = t
    assert acceleration_at_rate(traj, 0.125) == pytest.approx(0.5, abs=0.02)
    with pytest.raises(ValueError, match="never reached 0.6"):
        acceleration_at_rate(traj, 0.6)


def test_reference_with_own_pressure_pumps_gives_one_pump_more_flow_when_both_work():
    from hexgym.hydraulics.reference import ReferenceModel
    from hexgym.tools.validate import POSE_CYCLE

    flows = {}
    for name, circuit in (("real", HydraulicCircuit()), ("own", OwnPressureCircuit())):
        model = ReferenceModel()
        model.circuit = circuit
        model.reset(POSE_CYCLE)
        model.step(np.array([0.011, 0.011, 0.0, 0.0]), 400)  # full swing and boom raise, 0.8 s
        flows[name] = model.observe()[["pump1_flow_m3s", "pump2_flow_m3s"]]
    assert flows["own"]["pump1_flow_m3s"] > 1.1 * flows["real"]["pump1_flow_m3s"]
    assert flows["own"]["pump2_flow_m3s"] > 1.1 * flows["real"]["pump2_flow_m3s"]

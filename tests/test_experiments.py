"""The one-off analyses in ``experiments/`` (not installed, run by no command) keep working: the swing error
analysis' counterfactual circuit and rate lookup, the fuel check, the cluster benchmark's options; and each has
its line in ``experiments/README.md``."""

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from hexgym.hydraulics.circuit import HydraulicCircuit
from hexgym.machine import parameters as p

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"


def _experiment(name: str) -> ModuleType:
    """``experiments/<name>.py`` as the module ``experiments.<name>`` (the folder is no installed package)."""
    spec = importlib.util.spec_from_file_location(f"experiments.{name}", EXPERIMENTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


swing_analysis = _experiment("swing_analysis")
fuel_check = _experiment("fuel_check")
OwnPressureCircuit, acceleration_at_rate = swing_analysis.OwnPressureCircuit, swing_analysis.acceleration_at_rate
FULL = np.ones(2)  # both regulators asking for full displacement


def test_every_experiment_has_its_readme_line():
    readme = (EXPERIMENTS / "README.md").read_text()
    scripts = sorted(path.name for path in EXPERIMENTS.glob("*.py"))
    assert scripts == ["cluster_bench.py", "fuel_check.py", "robustness.py", "swing_analysis.py"]
    assert [name for name in scripts if f"- `{name}`:" not in readme] == []


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
    traj = np.zeros(len(t), dtype=[("t", float), ("qd_swing_radps", float)])
    traj["t"], traj["qd_swing_radps"] = t, 0.5 * t**2  # acceleration = t
    assert acceleration_at_rate(traj, 0.125) == pytest.approx(0.5, abs=0.02)
    with pytest.raises(ValueError, match="never reached 0.6"):
        acceleration_at_rate(traj, 0.6)


def test_reference_with_own_pressure_pumps_gives_one_pump_more_flow_when_both_work():
    from hexgym.hydraulics.circuit import PAPER_VALVE
    from hexgym.hydraulics.reference import ReferenceModel
    from hexgym_lab.validate import POSE_CYCLE

    flows = {}  # on the paper's valve, one pump per function: swing on pump 2, boom on pump 1
    for name, circuit in (
        ("real", HydraulicCircuit(layout=PAPER_VALVE)),
        ("own", OwnPressureCircuit(layout=PAPER_VALVE)),
    ):
        model = ReferenceModel(valve="paper")
        model.circuit = circuit
        model.reset(POSE_CYCLE)
        model.step(np.array([0.011, 0.011, 0.0, 0.0]), 400)  # full swing and boom raise, 0.8 s
        flows[name] = model.observe()[["pump1_flow_m3s", "pump2_flow_m3s"]]
    assert flows["own"]["pump1_flow_m3s"] > 1.1 * flows["real"]["pump1_flow_m3s"]
    assert flows["own"]["pump2_flow_m3s"] > 1.1 * flows["real"]["pump2_flow_m3s"]


def test_fuel_estimate_tracks_the_reference_circuit():
    result = fuel_check.compare_with_reference()
    assert 0.8 < result["ratio"] < 1.25  # measured 1.10 on the loading-like sequence


def test_fuel_check_suite_compares_the_estimate_with_the_reference(tmp_path):
    result = fuel_check.suite_comparison(suite_seed=7, count=1)
    log = result["per_log"][0]
    assert log["reference_l"] > 0.0
    for key in ("estimate_on_reference_motion", "estimate_on_learned_model"):
        error = log[f"{key}_l"] / log["reference_l"] - 1.0
        assert result["summary"][key]["median_error"] == pytest.approx(error)
        assert abs(error) < 0.5  # measured: 16-19 % median over 16 logs of two suites (docs/hydraulics.md)
    for bad in (["--suite", "-2"], ["--suite", "1", "--suite-seed", "-1"]):
        with pytest.raises(SystemExit) as exit_info:
            fuel_check.main(bad)
        assert exit_info.value.code == 2


def test_cluster_bench_refuses_an_unknown_way():
    cluster_bench = _experiment("cluster_bench")
    with pytest.raises(SystemExit) as exit_info:
        cluster_bench.main(["--ways", "pool2,carrier-pigeon"])
    assert exit_info.value.code == 2

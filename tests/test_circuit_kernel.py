"""The circuit model's compiled control period (hexgym.model.circuit_kernel) against the numpy circuit it mirrors."""

from __future__ import annotations

import dataclasses

import numba
import numpy as np
import pytest
from numba.core.caching import NullCache

from hexgym.hydraulics.circuit import HydraulicCircuit
from hexgym.mbl.table import MBLTable, load_tables
from hexgym.mbl.valve import LearnedValve
from hexgym.model import circuit_kernel as ck
from hexgym.model.circuit_model import STOP_CLEARANCE, CircuitModel
from hexgym.model.commandlog import CommandLog
from hexgym.model.replay import replay

RTOL = 1e-10


@pytest.fixture(scope="module")
def circuit() -> HydraulicCircuit:
    return HydraulicCircuit(valve=LearnedValve(load_tables(table_set="circuit")))


@pytest.fixture(scope="module")
def constants(circuit: HydraulicCircuit) -> tuple[tuple, tuple]:
    return ck.pack(circuit, circuit.valve, STOP_CLEARANCE)


def _areas(constants: tuple[tuple, tuple], spools: np.ndarray, ext: np.ndarray) -> np.ndarray:
    k, valve = constants
    return ck.branch_areas(k, *ck.valve_areas(valve, spools), ext)


def _cases(circuit: HydraulicCircuit, n: int, seed: int = 0):
    """Random states (near holding and anywhere from vacuum to relief), spools (some in the dead band or closed),
    extensions (some beyond the strokes), cylinder velocities and swing rates."""
    rng = np.random.default_rng(seed)
    for i in range(n):
        y = circuit.initial_state(rng.uniform(-3e5, 3e5, 3))
        if i % 2:
            y[:12] = rng.uniform(-0.09e6, 32e6, 12)
        else:
            y[:12] += rng.uniform(0.0, 3e6, 12)
        y[12:] = rng.uniform(0.0, 1.0, 2)
        spools = rng.uniform(-11e-3, 11e-3, 4) * (rng.uniform(size=4) < 0.7)
        spools[rng.uniform(size=4) < 0.1] = 1e-3  # in the dead band
        ext = rng.uniform(-0.01, 1.01, 3) * circuit.stroke
        yield y, spools, ext, rng.uniform(-0.4, 0.4, 3), float(rng.uniform(-0.8, 0.8))


def _close(got: np.ndarray, want: np.ndarray) -> None:
    """Agreement to RTOL of each entry, or of the largest where an entry is a cancellation's remainder."""
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=RTOL * 1e-3 * np.max(np.abs(want)))


def test_valve_and_branch_areas_are_the_learned_valves(circuit, constants) -> None:
    for _, spools, ext, _, _ in _cases(circuit, 200):
        passages, pump_bypass = ck.valve_areas(constants[1], spools)
        want = circuit.valve(spools)
        for row, key in enumerate(ck.PASSAGES):
            _close(passages[row], getattr(want, key))
        _close(pump_bypass, want.pump_bypass)
        _close(_areas(constants, spools, ext), circuit.branch_areas(spools, ext))


def test_derivatives_jacobian_and_forces_are_the_circuits(circuit, constants) -> None:
    for y, spools, ext, vel, rate in _cases(circuit, 200, seed=1):
        k = ck.Circuit(*constants[0])
        f, jac, _ = ck.evaluate(constants[0], y, _areas(constants, spools, ext), ext, vel, rate)
        f_ref, jac_ref = circuit.jacobian(y, spools, ext, vel, rate)
        _close(f, f_ref)
        _close(jac, jac_ref)
        forces, torque = ck.oil_loads(k.laws, k.cylinder, k.cylinder_index, y, vel, rate)
        forces_ref, torque_ref = circuit.actuator_forces(y, ext, vel, rate, end_stops=False)
        _close(forces, forces_ref)
        assert torque == pytest.approx(torque_ref, rel=RTOL, abs=1e-6)


def test_step_splitting_and_sensitivity_are_the_circuits(circuit, constants) -> None:
    splits = 0
    for y, spools, ext, vel, rate in _cases(circuit, 200, seed=2):
        k = ck.Circuit(*constants[0])
        circuit.split_count = 0
        new, sens, n = ck.advance(constants[0], y, 0.005, _areas(constants, spools, ext), ext, vel, rate)
        new_ref, sens_ref = circuit.step_with_sensitivity(y, 0.005, spools, ext, vel, rate)
        assert n == circuit.split_count
        splits += n
        _close(new, new_ref)
        _close(sens, sens_ref)
        dforce, dtorque = ck.coupling(k.laws, k.cylinder, k.cylinder_index, sens, vel)
        dforce_ref, dtorque_ref = circuit.coupling_derivatives(sens_ref, vel, rate)
        _close(dforce, dforce_ref)
        assert dtorque == pytest.approx(dtorque_ref, rel=RTOL)
    assert splits > 100  # the splitting was exercised


def test_linear_solve_is_lapacks() -> None:
    rng = np.random.default_rng(3)
    for n in (1, 3, 4, 14):
        a, b = rng.normal(size=(n, n)), rng.normal(size=(n, 5))
        a[rng.uniform(size=(n, n)) < 0.5] = 0.0
        a += np.diag(rng.uniform(0.5, 2.0, n))
        _close(ck.solve(a.copy(), b.copy()), np.linalg.solve(a, b))


def test_any_one_input_tables_are_read(circuit) -> None:
    """Refitted tables may have other grids, uneven ones too: the lookup is the tables' own."""
    rng = np.random.default_rng(4)
    tables = {}
    for name, table in load_tables(table_set="circuit").items():
        lo, hi = table.axes[0][0], table.axes[0][-1]
        even = name.startswith(("boom", "swing"))
        axis = np.linspace(lo, hi, 31) if even else np.sort(np.r_[lo, hi, rng.uniform(lo, hi, 40)])
        values = table(axis[:, None]) * rng.uniform(0.8, 1.2) + rng.normal(0.0, 1e-6, len(axis))
        tables[name] = dataclasses.replace(table, axes=(axis,), values=values, confidence=np.ones(len(axis)))
    valve = LearnedValve(tables)
    _, packed = ck.pack(HydraulicCircuit(valve=valve), valve, STOP_CLEARANCE)
    inv_step = ck.Valve(*packed).inv_step
    assert np.any(inv_step > 0.0) and np.any(inv_step == 0.0)  # even and uneven axes
    for _, spools, _, _, _ in _cases(circuit, 200, seed=5):
        passages, pump_bypass = ck.valve_areas(packed, spools)
        want = valve(spools)
        for row, key in enumerate(ck.PASSAGES):
            _close(passages[row], getattr(want, key))
        _close(pump_bypass, want.pump_bypass)


def test_tables_of_more_inputs_are_refused() -> None:
    tables = load_tables(table_set="circuit")
    table = tables["boom_pa"]
    axes = (table.axes[0], np.array([0.0, 1.0]))
    values = np.repeat(table.values[:, None], 2, axis=1)
    params = dataclasses.replace(table.params, input_scales=(*table.params.input_scales, 1.0))
    tables["boom_pa"] = MBLTable(
        table.name, (*table.inputs, "x"), table.output, axes, values, np.ones_like(values), params
    )
    valve = LearnedValve(tables)
    with pytest.raises(ValueError, match="boom_pa"):
        ck.pack(HydraulicCircuit(valve=valve), valve, STOP_CLEARANCE)


def test_compiled_period_follows_the_numpy_period() -> None:
    """Four functions for 4 s, the bucket into its stroke end (held) and steps split: the same tip path to 1e-6 m,
    the same circuit state and splits."""
    t = np.arange(0.0, 4.0001, 0.05)
    spools = np.zeros((len(t), 4))
    spools[(t > 0.2) & (t < 3.0), 0] = 8.0
    spools[(t > 0.2) & (t < 2.5), 1] = 11.0
    spools[t > 1.5, 2] = -9.0
    spools[t > 0.3, 3] = 11.0
    log = CommandLog(t, spools)
    compiled, reference = CircuitModel(), CircuitModel()
    reference._control_period = reference._control_period_numpy
    runs = {}
    for name, model in (("compiled", compiled), ("numpy", reference)):
        model.circuit.split_count = 0
        runs[name] = replay(model, log, start="home", payload_kg=1000.0, dt_out=0.05)
    tip = {name: np.column_stack([run[f"tip_{c}"] for c in "xyz"]) for name, run in runs.items()}
    assert np.max(np.linalg.norm(tip["compiled"] - tip["numpy"], axis=1)) <= 1e-6
    assert np.ptp(runs["numpy"]["q_swing"]) > 0.3 and np.ptp(runs["numpy"]["q_boom"]) > 0.2  # it moved
    stroke = compiled.circuit.stroke[2] - STOP_CLEARANCE
    assert runs["numpy"]["bucket_extension_m"][-1] == pytest.approx(stroke, abs=1e-4)  # held at the stop
    assert compiled.circuit.split_count == reference.circuit.split_count > 0
    np.testing.assert_allclose(compiled.state, reference.state, rtol=1e-6, atol=1.0)
    np.testing.assert_allclose(compiled.rates, reference.rates, rtol=1e-6, atol=1e-9)


def test_compiled_functions_are_cached_and_documented() -> None:
    found = {name: f for name, f in vars(ck).items() if isinstance(f, numba.core.registry.CPUDispatcher)}
    assert {"control_period", "substep", "advance", "evaluate", "valve_areas", "solve"} <= set(found)
    for name, function in found.items():
        assert not isinstance(function._cache, NullCache), f"{name} is compiled without cache=True"
        assert not function.targetoptions.get("fastmath"), f"{name}: fastmath would change the circuit's floats"
        assert function.__doc__, f"{name} has no docstring"


def test_a_non_finite_state_is_refused() -> None:
    model = CircuitModel()
    model.reset("home")
    model.state[4] = np.nan
    with pytest.raises(ValueError, match="finite"):
        model.step(np.zeros(4))

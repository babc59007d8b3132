"""The circuit model's native kernel (native/circuit.cc, through hexgym.model.circuit_kernel) against the numpy
circuit it mirrors (hexgym.hydraulics.circuit, the definition), on each valve layout: the Cat two-pump valve (boom 2,
stick 2, priority valves, regeneration, the stick unloading valve piloted by the head pressure) with the packaged
tables, and the paper's one section per function with those of its passages."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hexgym.hydraulics.circuit import NODES, HydraulicCircuit, valve_layout
from hexgym.mbl.schema import CIRCUIT_TABLE_SETS, valve_tables
from hexgym.mbl.table import MBLTable, load_tables
from hexgym.mbl.valve import LearnedValve
from hexgym.model import circuit_kernel as ck
from hexgym.model.circuit_model import STOP_CLEARANCE, CircuitModel
from hexgym.model.commandlog import CommandLog
from hexgym.model.replay import replay

pytestmark = pytest.mark.skipif(bool(ck.native_reason()), reason="the native library is not built")

RTOL = 1e-10


@pytest.fixture(scope="module", params=("cat", "paper"))
def circuit(request) -> HydraulicCircuit:
    return _circuit(request.param)


def _circuit(valve: str) -> HydraulicCircuit:
    """A circuit of layout ``valve`` with the packaged tables of its passages."""
    layout = valve_layout(valve)
    packaged = load_tables(table_set="circuit")
    tables = {name: packaged[name] for name in valve_tables(layout)}
    return HydraulicCircuit(valve=LearnedValve(tables, layout), layout=layout)


@pytest.fixture(scope="module")
def kernel(circuit: HydraulicCircuit) -> ck.NativeCircuit:
    return ck.NativeCircuit(circuit, circuit.valve.tables, STOP_CLEARANCE)


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


def test_branch_areas_are_the_learned_valves(circuit, kernel) -> None:
    for _, spools, ext, _, _ in _cases(circuit, 200):
        _close(kernel.branch_areas(spools, ext), circuit.branch_areas(spools, ext))
    if circuit.layout.name == "cat":  # each of its own passages was open somewhere: priorities, regeneration
        index, opened = circuit.branch_index, set()
        for _, spools, ext, _, _ in _cases(circuit, 200):
            area = kernel.branch_areas(spools, ext)
            opened |= {name for name in ("boom2_pa", "stick2_pb", *circuit.layout.regeneration_passages)
                       if area[index[name]] > 0.0}  # fmt: skip
        assert opened == {"boom2_pa", "stick2_pb", *circuit.layout.regeneration_passages}


def test_the_cat_valves_own_rules_are_the_definitions() -> None:
    """A section with passages on one side stays at neutral on the other (boom 2 while the boom lowers: pump 2's
    centre open as at neutral), and a regeneration passage's oil leaves through its cylinder end's cushion."""
    circuit = _circuit("cat")
    kernel = ck.NativeCircuit(circuit, circuit.valve.tables, STOP_CLEARANCE)
    index, mid = circuit.branch_index, 0.5 * circuit.stroke
    lowering, neutral = (
        kernel.branch_areas(np.array([0.0, -0.011, 0.0, 0.0]), mid),
        kernel.branch_areas(np.zeros(4), mid),
    )
    assert lowering[index["bypass2"]] == neutral[index["bypass2"]] > 0.0
    assert lowering[index["boom_regeneration"]] > 0.0
    stick_in = np.array([0.0, 0.0, 0.011, 0.0])
    for ext in (mid, np.r_[mid[0], circuit.stroke[1] - 0.002, mid[2]]):  # the stick's rod end in its cushion
        _close(kernel.branch_areas(stick_in, ext), circuit.branch_areas(stick_in, ext))
    cushioned = kernel.branch_areas(stick_in, np.r_[mid[0], circuit.stroke[1] - 0.002, mid[2]])
    for passage in ("stick_regeneration", "stick_unloading"):
        assert 0.0 < cushioned[index[passage]] < kernel.branch_areas(stick_in, mid)[index[passage]]


def test_the_piloted_valve_has_its_jacobian_column(circuit, kernel) -> None:
    """The stick unloading valve (rod -> tank) opens with the head's pressure: d(rod pdot)/d(head pressure) holds
    its flow's change with the opening, as the definition's; the paper's layout has no such column."""
    head, rod = NODES.index("stick_head"), NODES.index("stick_rod")
    y = circuit.initial_state()
    y[head], y[rod] = 7e6, 12e6  # the unloading valve part open, the rod's oil under pressure
    spools, ext, vel = np.array([0.0, 0.0, 9e-3, 0.0]), 0.5 * circuit.stroke, np.array([0.0, 0.05, 0.0])
    f, jac = kernel.derivatives(y, spools, ext, vel, 0.0)
    f_ref, jac_ref = circuit.jacobian(y, spools, ext, vel, 0.0)
    _close(jac, jac_ref)
    eps = 10.0  # Pa: the column is the derivative of the rates
    up, down = y.copy(), y.copy()
    up[head], down[head] = y[head] + eps, y[head] - eps
    column = kernel.derivatives(up, spools, ext, vel, 0.0)[0] - kernel.derivatives(down, spools, ext, vel, 0.0)[0]
    assert column[rod] / (2.0 * eps) == pytest.approx(jac[rod, head], rel=1e-5)
    piloted = circuit.pilot_conductance(y[:12], circuit.branch_areas(spools, ext))
    assert piloted.size == (circuit.layout.name == "cat") and np.all(piloted > 0.0)  # the state opens it part way


def test_step_splitting_and_sensitivity_are_the_circuits(circuit, kernel) -> None:
    splits = 0
    for y, spools, ext, vel, rate in _cases(circuit, 200, seed=2):
        circuit.split_count = 0
        new, sens, n = kernel.step(y, spools, ext, vel, rate, 0.005)
        new_ref, sens_ref = circuit.step_with_sensitivity(y, 0.005, spools, ext, vel, rate)
        assert n == circuit.split_count
        splits += n
        _close(new, new_ref)
        _close(sens, sens_ref)
        dforce, dtorque = kernel.coupling(sens, vel)
        dforce_ref, dtorque_ref = circuit.coupling_derivatives(sens_ref, vel, rate)
        _close(dforce, dforce_ref)
        assert dtorque == pytest.approx(dtorque_ref, rel=RTOL)
    assert splits > 100  # the splitting was exercised


def test_any_one_input_tables_are_read(circuit) -> None:
    """Refitted tables may have other grids, uneven ones too: the lookup is the tables' own."""
    rng = np.random.default_rng(4)
    tables = {}
    for name, table in circuit.valve.tables.items():
        lo, hi = table.axes[0][0], table.axes[0][-1]
        even = name.startswith(("boom", "swing"))
        axis = np.linspace(lo, hi, 31) if even else np.sort(np.r_[lo, hi, rng.uniform(lo, hi, 40)])
        values = table(axis[:, None]) * rng.uniform(0.8, 1.2) + rng.normal(0.0, 1e-6, len(axis))
        tables[name] = dataclasses.replace(table, axes=(axis,), values=values, confidence=np.ones(len(axis)))
    other = HydraulicCircuit(valve=LearnedValve(tables, circuit.layout), layout=circuit.layout)
    kernel = ck.NativeCircuit(other, tables, STOP_CLEARANCE)
    for _, spools, ext, _, _ in _cases(circuit, 200, seed=5):
        _close(kernel.branch_areas(spools, ext), other.branch_areas(spools, ext))


def test_tables_of_more_inputs_are_refused(circuit) -> None:
    tables = dict(circuit.valve.tables)
    table = tables["boom_pa"]
    axes = (table.axes[0], np.array([0.0, 1.0]))
    values = np.repeat(table.values[:, None], 2, axis=1)
    params = dataclasses.replace(table.params, input_scales=(*table.params.input_scales, 1.0))
    tables["boom_pa"] = MBLTable(
        table.name, (*table.inputs, "x"), table.output, axes, values, np.ones_like(values), params
    )
    with pytest.raises(ValueError, match="boom_pa"):
        ck.NativeCircuit(circuit, tables, STOP_CLEARANCE)


def test_the_circuit_is_data_to_the_kernel(circuit, kernel) -> None:
    """The structure comes from the numbers, not from C++: the same circuit with its nodes renumbered (the swing
    ports first, the pumps last) gives the same derivatives, renumbered; numbers of a wrong length or a node out of
    range are refused, naming the field."""
    nodes = 12
    order = np.r_[10, 11, 4:10, 2, 3, 0, 1]  # new node k is old node order[k]
    new_of = np.empty(nodes + 1, dtype=int)
    new_of[order], new_of[nodes] = np.arange(nodes), nodes  # the tank stays last
    fields = ck.circuit_fields(circuit, STOP_CLEARANCE)
    for name in ("branch_from", "branch_to", "pump_node", "signal_node", "head_node", "rod_node"):
        fields[name] = new_of[fields[name]]
    fields["branch_pilot"] = np.where(fields["branch_pilot"] >= 0, new_of[fields["branch_pilot"]], -1)
    fields["node_volume"], fields["displacement"] = fields["node_volume"][order], fields["displacement"][order]
    laws = fields["laws"].copy()
    for law in ("swing_a", "swing_b"):
        i = ck.CIRCUIT_LAWS.index(law)
        laws[i] = new_of[int(laws[i])]
    fields["laws"] = laws
    renumbered = _kernel_of(ck.pack_fields(fields, ck.circuit_counts(circuit)), circuit)
    state_order = np.r_[order, 12, 13]
    for y, spools, ext, vel, rate in _cases(circuit, 50, seed=6):
        f, jac = kernel.derivatives(y, spools, ext, vel, rate)
        f2, jac2 = renumbered.derivatives(y[state_order], spools, ext, vel, rate)
        _close(f2, f[state_order])
        _close(jac2, jac[np.ix_(state_order, state_order)])
    numbers = ck.circuit_numbers(circuit, STOP_CLEARANCE)
    with pytest.raises(ValueError, match="numbers where the layout"):
        _kernel_of(np.append(numbers, 0.0), circuit)
    broken = numbers.copy()
    broken[len(ck.CIRCUIT_COUNTS) + len(ck.CIRCUIT_LAWS)] = 99.0  # the first branch's "from" node
    with pytest.raises(ValueError, match="branch_from"):
        _kernel_of(broken, circuit)
    fields = ck.circuit_fields(circuit, STOP_CLEARANCE)
    fields["section_table"] = fields["section_table"].copy()
    fields["section_table"][1, 1] = fields["section_table"][0, 1]  # boom's pump->a reads the swing's table
    with pytest.raises(ValueError, match="table .* is used by 2 passages"):
        _kernel_of(ck.pack_fields(fields, ck.circuit_counts(circuit)), circuit)


def test_tables_of_another_layout_are_refused() -> None:
    """The Cat valve's numbers with the paper valve's tables (or the reverse) are no circuit."""
    cat, paper = _circuit("cat"), _circuit("paper")
    for numbers_of, tables_of in ((cat, paper), (paper, cat)):
        numbers = ck.circuit_numbers(numbers_of, STOP_CLEARANCE)
        kernel = ck.NativeCircuit.__new__(ck.NativeCircuit)
        with pytest.raises(ValueError, match="refuses the circuit model: .*table"):
            kernel._init(numbers, tables_of.valve.tables, int(numbers[1]), tables_of.layout)


def _kernel_of(numbers: np.ndarray, circuit: HydraulicCircuit) -> ck.NativeCircuit:
    """A kernel of these circuit numbers and ``circuit``'s valve tables (NativeCircuit packs the numbers from a
    HydraulicCircuit)."""
    kernel = ck.NativeCircuit.__new__(ck.NativeCircuit)
    kernel._init(numbers, circuit.valve.tables, int(numbers[1]), circuit.layout)
    return kernel


@pytest.mark.parametrize("table_set", CIRCUIT_TABLE_SETS)
def test_native_period_follows_the_numpy_period(table_set: str) -> None:
    """Four functions for 4 s, the bucket into its stroke end (held) and steps split: the same tip path to 1e-6 m,
    the same circuit state and splits."""
    t = np.arange(0.0, 4.0001, 0.05)
    spools = np.zeros((len(t), 4))
    spools[(t > 0.2) & (t < 3.0), 0] = 8.0
    spools[(t > 0.2) & (t < 2.5), 1] = 11.0
    spools[t > 1.5, 2] = -9.0
    spools[t > 0.3, 3] = 11.0
    log = CommandLog(t, spools)
    compiled, reference = CircuitModel(table_set=table_set), CircuitModel(table_set=table_set)
    assert compiled._kernel is not None
    reference._control_period = reference._control_period_numpy
    runs = {}
    for name, model in (("native", compiled), ("numpy", reference)):
        model.circuit.split_count = 0
        runs[name] = replay(model, log, start="home", payload_kg=1000.0, dt_out=0.05)
    tip = {name: np.column_stack([run[f"tip_{c}"] for c in "xyz"]) for name, run in runs.items()}
    assert np.max(np.linalg.norm(tip["native"] - tip["numpy"], axis=1)) <= 1e-6
    assert np.ptp(runs["numpy"]["q_swing_rad"]) > 0.3 and np.ptp(runs["numpy"]["q_boom_rad"]) > 0.2  # it moved
    stroke = compiled.circuit.stroke[2] - STOP_CLEARANCE
    assert runs["numpy"]["bucket_extension_m"][-1] == pytest.approx(stroke, abs=1e-4)  # held at the stop
    assert compiled.circuit.split_count == reference.circuit.split_count > 0
    np.testing.assert_allclose(compiled.state, reference.state, rtol=1e-6, atol=1.0)
    np.testing.assert_allclose(compiled.rates, reference.rates, rtol=1e-6, atol=1e-9)


def test_a_non_finite_state_is_refused() -> None:
    model = CircuitModel()
    model.reset("home")
    model.state[4] = np.nan
    with pytest.raises(ValueError, match="finite"):
        model.step(np.zeros(4))

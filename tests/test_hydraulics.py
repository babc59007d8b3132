"""The analytical open-centre circuit against a simple prescribed mechanical load.

Each cylinder drives a mass against a constant load force (positive resists extension, like
the weight on the boom) and the swing drives a plain inertia; the test integrates them with
symplectic Euler around the circuit's own step, the way the reference model couples MuJoCo.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from hexgym.hydraulics.circuit import (
    CAT_VALVE,
    CYLINDER_NAMES,
    N_NODES,
    NODES,
    PAPER_VALVE,
    STATE_SIZE,
    VALVE_LAYOUTS,
    HydraulicCircuit,
    compliance,
    fuel_rate,
    spool_areas,
)
from hexgym.machine import parameters as p

MM = 1e-3
DT = 1e-3
Q_MAX = p.PUMP_MAX_FLOW


@pytest.fixture(scope="module")
def circuit() -> HydraulicCircuit:
    """The paper's valve: one section per function, pump 1 boom and bucket, pump 2 swing and stick."""
    return HydraulicCircuit(layout=PAPER_VALVE)


@pytest.fixture(scope="module")
def cat() -> HydraulicCircuit:
    return HydraulicCircuit(layout=CAT_VALVE)


@pytest.fixture(scope="module", params=["paper", "cat"])
def any_circuit(request: pytest.FixtureRequest) -> HydraulicCircuit:
    """The circuit with each valve layout: what holds for any circuit."""
    return HydraulicCircuit(layout=VALVE_LAYOUTS[request.param])


def run(
    circuit: HydraulicCircuit,
    spools_mm: Callable[[float], list[float]] | list[float],
    duration: float,
    load_n=(150e3, 50e3, 30e3),
    ext=(0.3, 0.4, 0.3),
    mass=(3000.0, 2000.0, 1000.0),
    inertia: float = 60000.0,
) -> dict[str, np.ndarray]:
    """Simulate; returns time series (first row = initial state) of mechanics, state, outputs."""
    load, mass = np.asarray(load_n, float), np.asarray(mass, float)
    x, v, w = np.array(ext, float), np.zeros(3), 0.0
    y = circuit.initial_state(load)
    command = spools_mm if callable(spools_mm) else (lambda t: spools_mm)
    rec: dict[str, list] = {k: [] for k in ("t", "x", "v", "w", "y", "out")}

    def record(t: float, u: np.ndarray) -> None:
        for key, val in (("t", t), ("x", x), ("v", v), ("w", w), ("y", y)):
            rec[key].append(np.copy(val))
        rec["out"].append(circuit.outputs(y, u, x, v, w))

    record(0.0, np.asarray(command(0.0), float) * MM)
    for k in range(int(round(duration / DT))):
        u = np.asarray(command(k * DT), float) * MM
        force, torque = circuit.actuator_forces(y, x, v, w)
        v = v + DT * (force - load) / mass
        x = x + DT * v
        w = w + DT * torque / inertia
        y = circuit.step(y, DT, u, x, v, w)
        record((k + 1) * DT, u)
    series = {k: np.array(val) for k, val in rec.items() if k != "out"}
    for key in rec["out"][0]:
        series[key] = np.array([o[key] for o in rec["out"]])
    return series


def test_jacobian_matches_finite_differences(any_circuit: HydraulicCircuit) -> None:
    rng = np.random.default_rng(1)
    y = any_circuit.initial_state([3e5, 1e5, -5e4])
    y[:N_NODES] += rng.uniform(0.0, 5e6, N_NODES)
    y[N_NODES:] = [0.5, 0.7]
    args = (np.array([3, 6, -8, 11]) * MM, np.array([0.5, 0.02, 1.13]), np.array([0.1, -0.05, 0.2]), 0.3)
    _, jac = any_circuit.jacobian(y, *args)
    numeric = np.zeros_like(jac)
    for i in range(STATE_SIZE):
        e = np.zeros(STATE_SIZE)
        e[i] = 1.0 if i < N_NODES else 1e-6
        numeric[:, i] = (any_circuit.derivatives(y + e, *args) - any_circuit.derivatives(y - e, *args)) / (2 * e[i])
    scale = np.abs(numeric).max(axis=1, keepdims=True)
    assert np.allclose(jac, numeric, rtol=1e-4, atol=1e-6 * scale.max())


def test_valve_areas_open_centre() -> None:
    neutral = spool_areas(np.zeros(4), PAPER_VALVE)
    full = spool_areas(np.array([11, -11, 11, -11]) * MM, PAPER_VALVE)
    assert np.all(neutral.pa == 0) and np.all(neutral.at == 0) and np.all(neutral.bypass > 0)
    assert np.all(full.bypass == 0)
    assert full.pa[0] > 0 and full.bt[0] > 0 and full.pb[1] > 0 and full.at[1] > 0
    inside_dead_band = spool_areas(np.full(4, 0.9 * p.SPOOL_DEAD_BAND), PAPER_VALVE)
    assert np.all(inside_dead_band.pa == 0)


def test_neutral_spools_idle_flow_goes_to_tank(any_circuit: HydraulicCircuit) -> None:
    s = run(any_circuit, [0, 0, 0, 0], 1.0)
    for pump in ("pump1", "pump2"):
        flow = s[f"{pump}_flow_m3s"][-1]
        assert 0.10 * Q_MAX <= flow <= 0.20 * Q_MAX
        assert s[f"bypass{pump[-1]}_flow_m3s"][-1] == pytest.approx(flow, rel=1e-3)
    total = s["pump1_flow_m3s"][-1] + s["pump2_flow_m3s"][-1]
    assert s["tank_return_m3s"][-1] == pytest.approx(total, rel=1e-3)
    assert np.abs(s["v"][-1]).max() < 1e-4  # the loads are held


@pytest.mark.parametrize("name", CYLINDER_NAMES)
def test_single_function_full_spool_speed(circuit: HydraulicCircuit, name: str) -> None:
    u = [0, 0, 0, 0]
    u[1 + CYLINDER_NAMES.index(name)] = 11
    s = run(circuit, u, 1.5)
    i = CYLINDER_NAMES.index(name)
    expected = Q_MAX / p.CYLINDERS[name].head_area  # boom 0.144, stick 0.217, bucket 0.289 m/s
    assert s["v"][-1, i] == pytest.approx(expected, rel=0.03)


def test_swing_full_spool_speed(circuit: HydraulicCircuit) -> None:
    s = run(circuit, [11, 0, 0, 0], 5.0)
    rpm = s["w"][-1] * 60.0 / (2.0 * np.pi)
    flow_limited = Q_MAX / p.SWING_MOTOR_DISPLACEMENT / p.SWING_REDUCTION * 60.0
    assert rpm == pytest.approx(flow_limited, rel=0.05)  # ~10.3 rpm with the present parameters
    assert 8.0 < rpm < 12.5


def test_two_functions_on_one_pump_share_flow_by_load(circuit: HydraulicCircuit) -> None:
    """Boom (heavy) and bucket (light) on pump 1 at full spool: the bucket takes the flow."""
    both = run(circuit, [0, 11, 0, 11], 1.5, load_n=(300e3, 50e3, 30e3))
    boom_alone = run(circuit, [0, 11, 0, 0], 1.5, load_n=(300e3, 50e3, 30e3))
    v_boom, v_bucket = both["v"][-1, 0], both["v"][-1, 2]
    assert boom_alone["v"][-1, 0] > 0.13
    assert v_boom < 0.1 * boom_alone["v"][-1, 0]
    assert v_bucket > 0.9 * Q_MAX / p.BUCKET_CYLINDER.head_area


def test_load_check_holds_a_hanging_load(circuit: HydraulicCircuit) -> None:
    """Boom holding 400 kN; the bucket runs light at full spool (pump pressure ~4 MPa) and the
    boom spool is opened part way: the load check keeps the head oil from the pump."""

    def command(t: float) -> list[float]:
        return [0, 5 if t > 0.3 else 0, 0, 11]

    s = run(circuit, command, 1.5, load_n=(400e3, 50e3, 30e3), ext=(0.6, 0.4, 0.3))
    assert s["pump1_pressure_pa"][-1] < 8e6 < s["boom_head_pressure_pa"][-1]
    drop = s["x"][0, 0] - s["x"][:, 0].min()
    assert drop < 2e-3  # compressibility only: the head pressure rises as the rod is vented
    assert s["v"][-1, 0] > -1e-4  # piston-seal leakage drift only


def test_power_limit_and_pressure_bounds(any_circuit: HydraulicCircuit) -> None:
    """Heavy loads on all functions, full spools, stalls at the ends, reversals, swing stops."""

    def command(t: float) -> list[float]:
        if t < 1.5:
            return [11, 11, 11, 11]
        if t < 2.0:
            return [0, -11, -11, -11]  # swing brakes on its crossover reliefs
        return [-11, 11, 11, 11]

    s = run(any_circuit, command, 3.0, load_n=(450e3, 250e3, 120e3), ext=(0.9, 1.2, 0.8))
    assert s["x"][:, 2].max() > p.BUCKET_CYLINDER.stroke - 0.01  # the bucket hit its end
    assert np.all(s["pump_power_w"] <= p.PUMP_POWER_LIMIT * (1.0 + 1e-9))
    assert s["pump_power_w"].max() > 0.95 * p.PUMP_POWER_LIMIT  # the limit was reached
    pressures = s["y"][:, :N_NODES]
    assert pressures.min() > -0.1e6
    ceiling = {"pump": p.MAIN_RELIEF, "bypass": p.NFC_RELIEF, "swing": p.SWING_RELIEF}
    for i, node in enumerate(NODES):
        limit = ceiling.get(node.rstrip("12").split("_")[0], max(p.LINE_RELIEF.values()))
        assert pressures[:, i].max() < limit + p.RELIEF_OVERRIDE + 0.5e6, node


def test_volume_is_conserved(any_circuit: HydraulicCircuit) -> None:
    """Pump delivery = cylinder volume change + compression + tank return + leak."""

    def command(t: float) -> list[float]:
        return [8 if t < 1.0 else -11, 11 if t < 0.8 else -7, -9 if t < 1.2 else 11, 11 if t < 0.6 else -11]

    s = run(any_circuit, command, 2.0, load_n=(200e3, 80e3, 30e3), ext=(0.3, 0.8, 0.5))
    trapz = lambda f: float(np.sum(0.5 * (f[1:] + f[:-1])) * DT)  # noqa: E731
    pumped = trapz(s["pump1_flow_m3s"] + s["pump2_flow_m3s"])
    cylinders = float((any_circuit.head_area - any_circuit.rod_area) @ (s["x"][-1] - s["x"][0]))
    pressures = s["y"][:, :N_NODES]
    capacity = np.array([any_circuit.volumes(x) for x in s["x"]]) * compliance(pressures)[0]  # V / beta
    compression = float(np.sum(0.5 * (capacity[1:] + capacity[:-1]) * np.diff(pressures, axis=0)))
    returned = trapz(s["tank_return_m3s"]) + trapz(s["external_leak_m3s"])
    assert pumped > 0.01 and returned > 0.01
    assert pumped == pytest.approx(cylinders + compression + returned, rel=0.015)


def test_fuel_rate_is_plausible() -> None:
    assert 3.0 < fuel_rate(p.ACCESSORY_POWER + 4e3) < 8.0  # idle, standby flow
    assert 25.0 < fuel_rate(p.ENGINE_POWER) < 35.0
    assert fuel_rate(0.5 * p.ENGINE_POWER) < 0.6 * fuel_rate(p.ENGINE_POWER)


@pytest.mark.parametrize(
    ("spools", "match"),
    [
        ([0.0, np.nan, 0.0, 0.0], "'boom'.*not a finite"),
        ([0.0, 0.0, 0.012, 0.0], "'stick' = 12.000 mm is beyond"),
        ([0.0, 0.0, 0.0, -0.0111], "'bucket'.*beyond"),
        ([0.0, 0.0, 0.0], "shape"),
    ],
)
def test_bad_spools_are_refused(circuit: HydraulicCircuit, spools, match: str) -> None:
    y, x, v = circuit.initial_state(), np.full(3, 0.5), np.zeros(3)
    with pytest.raises(ValueError, match=match):
        circuit.step(y, DT, np.array(spools), x, v, 0.0)
    with pytest.raises(ValueError, match=match):
        circuit.derivatives(y, np.array(spools), x, v, 0.0)


def test_bad_mechanics_are_refused(circuit: HydraulicCircuit) -> None:
    y, u = circuit.initial_state(), np.zeros(4)
    with pytest.raises(ValueError, match="'stick'"):
        circuit.step(y, DT, u, np.array([0.5, np.inf, 0.5]), np.zeros(3), 0.0)
    with pytest.raises(ValueError, match="swing rate"):
        circuit.step(y, DT, u, np.full(3, 0.5), np.zeros(3), float("nan"))


def test_step_sensitivity_matches_finite_differences(any_circuit: HydraulicCircuit) -> None:
    y = any_circuit.initial_state([2e5, 5e4, 2e4])
    u, x = np.array([6, 11, -8, 9]) * MM, np.array([0.5, 0.8, 0.6])
    mech = np.array([0.1, -0.2, 0.15, 0.4])
    _, sens = any_circuit.step_with_sensitivity(y, DT, u, x, mech[:3], mech[3])
    for j in range(4):
        e = np.zeros(4)
        e[j] = 1e-4
        plus = any_circuit.step(y, DT, u, x, (mech + e)[:3], (mech + e)[3])
        minus = any_circuit.step(y, DT, u, x, (mech - e)[:3], (mech - e)[3])
        numeric = (plus - minus) / 2e-4
        # the sensitivity leaves out the velocity's effect on the step's own Jacobian (through
        # the entrained-air bulk modulus, noticeable below ~2 MPa): a first-order estimate
        assert np.abs(sens[:, j] - numeric).max() < 0.25 * np.abs(numeric).max()
    dforce, dtorque = any_circuit.coupling_derivatives(sens, mech[:3], mech[3])
    assert np.all(dforce < 0) and dtorque < 0  # the any_circuit resists (damps) motion over a step


# ---- the Cat two-pump valve: flow combining, swing priority, regeneration ----
def test_both_pumps_raise_the_boom_and_move_the_stick(circuit: HydraulicCircuit, cat: HydraulicCircuit) -> None:
    """Boom 2 and stick 2 sections add the other pump's flow: each function alone runs at about twice the speed
    of one pump's flow, the pumps' power limit still bounding them."""
    for j, name in ((1, "boom"), (2, "stick")):
        u = [0, 0, 0, 0]
        u[j] = -11 if name == "stick" else 11  # stick out: no regeneration, only the pumps' oil
        one, two = run(circuit, u, 1.2, ext=(0.2, 1.4, 0.3)), run(cat, u, 1.2, ext=(0.2, 1.4, 0.3))
        area = p.CYLINDERS[name].head_area if name == "boom" else p.CYLINDERS[name].rod_area
        single = Q_MAX / area
        assert abs(one["v"][-1, j - 1]) == pytest.approx(single, rel=0.05), name
        assert 1.6 * single < abs(two["v"][-1, j - 1]) < 2.0 * single, name
        assert min(two["pump1_flow_m3s"][-1], two["pump2_flow_m3s"][-1]) > 0.8 * Q_MAX, name
        assert two["pump_power_w"].max() < p.PUMP_POWER_LIMIT * 1.001, name


def test_swing_has_priority_over_the_stick(circuit: HydraulicCircuit, cat: HydraulicCircuit) -> None:
    """Swing and stick out together: on the paper's valve the stick takes pump 2's oil from the swing; the swing
    priority valve keeps most of it for the swing, the stick running on pump 1's stick 2 section."""
    alone = run(cat, [11, 0, 0, 0], 2.0)["w"][-1]
    paper = run(circuit, [11, 0, -11, 0], 2.0, load_n=(150e3, -20e3, 30e3), ext=(0.3, 1.5, 0.3))
    both = run(cat, [11, 0, -11, 0], 2.0, load_n=(150e3, -20e3, 30e3), ext=(0.3, 1.5, 0.3))
    assert paper["w"][-1] < 0.6 * alone
    assert both["w"][-1] > 0.85 * alone
    assert both["v"][-1, 1] < -0.8 * Q_MAX / p.STICK_CYLINDER.rod_area  # the stick still moves, on pump 1


def _regeneration_flows(cat: HydraulicCircuit, head: float, rod: float) -> tuple[float, float]:
    """(regeneration flow rod -> head, unloading flow rod -> tank) at full stick-in spool and these pressures."""
    y = cat.initial_state()
    y[NODES.index("stick_head")], y[NODES.index("stick_rod")] = head, rod
    q, _ = cat.branch_flows(y[:N_NODES], cat.branch_areas(np.array([0, 0, 11, 0]) * MM, np.full(3, 0.5)))
    index = cat.branch_index
    return float(q[index["stick_regeneration"]]), float(q[index["stick_unloading"]])


def test_stick_regenerates_while_its_weight_pulls_it_in(cat: HydraulicCircuit) -> None:
    """The rod's oil goes to the head while the rod's pressure is the higher (the stick's weight pulling); pushing
    against a load, the check closes and the unloading valve returns the rod's oil to tank."""
    regen, unload = _regeneration_flows(cat, head=1e6, rod=5e6)
    assert regen > 1e-3 and unload == pytest.approx(0.0, abs=1e-6)
    regen, unload = _regeneration_flows(cat, head=15e6, rod=2e6)
    assert regen == pytest.approx(0.0, abs=1e-6) and unload > 1e-3
    assert "stick_regeneration" not in HydraulicCircuit(layout=PAPER_VALVE).branch_index  # the paper's valve has none


def test_stick_in_is_faster_with_regeneration(cat: HydraulicCircuit) -> None:
    """Stick in, lightly loaded: the restricted return lifts the rod's pressure over the head's and the rod's oil
    joins both pumps' at the head. Pushing hard (digging), the unloading valve opens and both pumps alone feed it."""
    both_pumps = 2.0 * Q_MAX / p.STICK_CYLINDER.head_area
    light = run(cat, [0, 0, 11, 0], 1.5, load_n=(150e3, 0.0, 30e3))
    heavy = run(cat, [0, 0, 11, 0], 1.5, load_n=(150e3, 80e3, 30e3))
    regen = cat.branch_index["stick_regeneration"]

    def regeneration_flow(s: dict) -> float:
        area = cat.branch_areas(np.array([0, 0, 11, 0]) * MM, s["x"][-1])
        return float(cat.branch_flows(s["y"][-1][:N_NODES], area)[0][regen])

    assert light["v"][-1, 1] > 1.2 * both_pumps and regeneration_flow(light) > 0.5 * Q_MAX
    assert heavy["v"][-1, 1] < both_pumps and regeneration_flow(heavy) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize(
    "change, match",
    [
        ({"pump": 2}, "section 'boom2': pump 2 is not 0 or 1"),
        ({"areas": {"pa": -1e-4, "bypass": 2.5e-4}}, "section 'boom2': area 'pa' = -0.0001 m\\^2 is not a positive"),
        ({"areas": {"pa": 1e-4}}, "section 'boom2': areas must be a bypass"),
        ({"function": "arm"}, "section 'boom2': function 'arm' is not one of"),
    ],
)
def test_an_inconsistent_valve_layout_is_refused(change: dict, match: str) -> None:
    import dataclasses

    sections = list(CAT_VALVE.sections)
    sections[4] = dataclasses.replace(sections[4], **change)
    with pytest.raises(ValueError, match=match):
        dataclasses.replace(CAT_VALVE, sections=tuple(sections))
    only_pump1 = tuple(dataclasses.replace(s, pump=0) for s in CAT_VALVE.sections)
    with pytest.raises(ValueError, match="pump 2 feeds no section"):
        dataclasses.replace(CAT_VALVE, sections=only_pump1)


@pytest.mark.parametrize(
    "name, value, match",
    [
        ("MAIN_RELIEF", 2.0e6, "MAIN_RELIEF = 2 MPa is not above the pumps' standby pressure NFC_PRESSURE_IDLE"),
        ("SWING_RELIEF", float("nan"), "SWING_RELIEF = nan MPa is not above"),
        ("PUMP_MAX_FLOW", 0.0, "PUMP_MAX_FLOW = 0.0 is not a positive number"),
        ("BYPASS_VOLUME", -1e-3, "BYPASS_VOLUME = -0.001 is not a positive number"),
    ],
)
def test_inconsistent_circuit_parameters_are_refused(
    monkeypatch: pytest.MonkeyPatch, name: str, value: float, match: str
) -> None:
    monkeypatch.setattr(p, name, value)
    with pytest.raises(ValueError, match=match):
        HydraulicCircuit()


def test_the_native_kernel_takes_either_layout_as_numbers(cat: HydraulicCircuit) -> None:
    from hexgym.model.circuit_kernel import circuit_counts, circuit_numbers

    paper = HydraulicCircuit(layout=PAPER_VALVE)
    for circuit, sections, regenerations in ((paper, 4, 0), (cat, 6, 3)):
        counts = {"nodes": 12, "branches": len(circuit.branches.names), "sections": sections}
        assert circuit_counts(circuit) == counts | {"regenerations": regenerations}
    assert circuit_numbers(cat, 0.005).size > circuit_numbers(paper, 0.005).size > 100


def test_a_raise_only_section_leaves_its_pumps_bypass_open_on_lowering(cat: HydraulicCircuit) -> None:
    """The boom 2 section is piloted for boom raise only: lowering the boom leaves pump 2 at standby, not at its
    main relief behind a closed bypass."""
    s = run(cat, [0, -11, 0, 0], 1.0, load_n=(150e3, 50e3, 30e3), ext=(0.9, 0.4, 0.3))
    assert s["v"][-1, 0] < -0.1  # the boom lowers
    assert s["pump2_pressure_pa"][-1] < p.NFC_PRESSURE_IDLE + 1e6
    assert s["pump2_flow_m3s"][-1] < 0.25 * Q_MAX  # pump 2 destroked to its standby flow by its open centre

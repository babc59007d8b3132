"""A machine that is not the packaged one: a hydraulics file overriding the reference's passages, pumps, reliefs and
leakage; without it, or with an identity file, the reference runs exactly as before."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hexgym.hydraulics.circuit import CAT_VALVE, PAPER_VALVE, HydraulicCircuit
from hexgym.hydraulics.overrides import overridden_circuit, parse_hydraulics, passage_names, read_hydraulics_file
from hexgym.hydraulics.reference import ReferenceModel
from hexgym.machine import parameters as p
from hexgym.model.commandlog import CommandLog
from hexgym.model.replay import replay
from hexgym_lab.cli import main

# boom raise with the bucket curling, then the swing: both pumps at work (s, mm)
COMMANDS = CommandLog(np.array([0.0, 0.8, 1.6]), np.array([[0, 11, 0, 8], [9, 0, -6, 0], [0, 0, 0, 0]], float))


def identity(layout=PAPER_VALVE) -> dict:
    """A hydraulics file that names every value as the packaged circuit has it."""
    return {
        "valve": {"passage_area_scale": dict.fromkeys(passage_names(layout), 1.0)},
        "pump": {"max_flow_m3s": p.PUMP_MAX_FLOW, "power_limit_w": p.PUMP_POWER_LIMIT,
                 "nfc_pressure_full_flow_pa": p.NFC_PRESSURE_FULL_FLOW,
                 "nfc_pressure_min_flow_pa": p.NFC_PRESSURE_MIN_FLOW},
        "relief": {"main_pa": p.MAIN_RELIEF, "swing_pa": p.SWING_RELIEF, "line_pa": dict(p.LINE_RELIEF)},
        "leakage": {"cylinder_scale": 1.0, "swing_motor_scale": 1.0},
    }  # fmt: skip


@pytest.fixture(scope="module")
def packaged() -> np.ndarray:
    return replay(ReferenceModel(), COMMANDS, dt_out=0.02)


def test_without_a_file_the_circuit_is_the_packaged_one():
    assert type(ReferenceModel().circuit) is HydraulicCircuit
    d = np.array([0.7, 1.0])
    for pressures in (np.array([5e6, 8e6]), np.array([30e6, 31e6])):  # below and on the power limit
        ours = HydraulicCircuit.pump_flows(pressures, d, p.PUMP_MAX_FLOW, p.PUMP_POWER_LIMIT)
        for a, b in zip(HydraulicCircuit.pump_flows(pressures, d), ours, strict=True):
            assert np.array_equal(a, b)


def test_an_identity_file_runs_bit_identical(packaged, tmp_path):
    path = tmp_path / "unit.json"
    path.write_text(json.dumps(identity(ReferenceModel().circuit.layout)))  # the default valve's passages
    again = replay(ReferenceModel(hydraulics=str(path)), COMMANDS, dt_out=0.02)
    assert again.tobytes() == packaged.tobytes()


def test_the_cat_valves_identity_file_runs_bit_identical():
    packaged = replay(ReferenceModel(valve="cat"), COMMANDS, dt_out=0.04)
    again = replay(ReferenceModel(valve="cat", hydraulics=identity(CAT_VALVE)), COMMANDS, dt_out=0.04)
    assert again.tobytes() == packaged.tobytes()


def test_less_pump_flow_slows_the_bucket_and_more_speeds_it():
    """The bucket's curl takes one pump's whole flow below its power limit: its speed follows the pump's flow."""
    curl = CommandLog(np.array([0.0, 1.0]), np.array([[0, 0, 0, 11], [0, 0, 0, 11]], float))
    speed = {}
    for scale in (0.7, 1.0, 1.2):
        rows = replay(ReferenceModel(hydraulics={"pump": {"max_flow_scale": scale}}), curl, dt_out=0.05)
        early = (rows["t"] > 0.2) & (rows["t"] < 0.6)  # before the cylinder reaches its stop
        speed[scale] = rows["bucket_velocity_mps"][early].mean()
    assert speed[0.7] < 0.85 * speed[1.0] and speed[1.2] > 1.1 * speed[1.0], speed


def test_a_smaller_passage_and_a_lower_relief_act_where_they_should():
    circuit = overridden_circuit({"valve": {"passage_area_scale": {"boom_pa": 0.5}}, "relief": {"main_pa": 25e6}})
    packaged = HydraulicCircuit()
    u = np.array([0.0, 0.011, 0.0, 0.0])
    assert np.isclose(circuit.valve(u).pa[1], 0.5 * packaged.valve(u).pa[1])
    assert np.array_equal(circuit.valve(u).bt, packaged.valve(u).bt)
    i = circuit.branch_index["main_relief1"]
    assert circuit.branches.crack[list(circuit.branches.valve).index(i)] == 25e6
    assert circuit.branches.area[i] > packaged.branches.area[i]  # rated flow at a lower pressure: a larger seat


@pytest.mark.parametrize(
    "content,message",
    [
        ({"pumps": {}}, r"unit\.yaml: unknown key 'pumps'"),
        ({"pump": {"max_flow": 1}}, r"unit\.yaml: unknown key pump\.'max_flow'"),
        ({"pump": {"max_flow_scale": "lots"}}, r"unit\.yaml: pump\.max_flow_scale must be a finite number"),
        ({"pump": {"max_flow_scale": True}}, r"pump\.max_flow_scale must be a finite number \(a factor\), got True"),
        ({"pump": {"max_flow_m3s": 230}}, r"pump\.max_flow_m3s = 230 is out of range"),
        ({"relief": {"main_pa": 343}}, r"relief\.main_pa = 343 is out of range"),
        ({"relief": {"line_pa": {"arm": 30e6}}}, r"unknown key relief\.line_pa\.arm"),
        ({"valve": {"passage_area_scale": {"boom_pq": 1}}}, r"unknown key valve\.passage_area_scale\.boom_pq"),
        ({"pump": {"max_flow_scale": 1.0, "max_flow_m3s": 4e-3}}, r"give one of them"),
        ([1, 2], r"unit\.yaml: the file must be a mapping"),
    ],
)
def test_a_bad_file_is_refused_naming_file_and_key(content, message):
    with pytest.raises(ValueError, match=message):
        parse_hydraulics(content, "unit.yaml")


def test_a_passage_the_valve_lacks_is_refused_naming_the_valve():
    with pytest.raises(ValueError, match=r"passage_area_scale\.boom2_pa: the 'paper' valve has no such passage"):
        ReferenceModel(valve="paper", hydraulics={"valve": {"passage_area_scale": {"boom2_pa": 1.1}}})


def test_yaml_files_read_with_safe_load_numbers_as_yaml_writes_them(tmp_path):
    pytest.importorskip("yaml")
    path = tmp_path / "unit.yaml"
    path.write_text("pump:\n  max_flow_scale: 0.9\n  nfc_pressure_full_flow_pa: 0.7e6\nrelief:\n  swing_pa: 28e6\n")
    unit = read_hydraulics_file(path)
    assert unit.max_flow_m3s == pytest.approx(0.9 * p.PUMP_MAX_FLOW) and unit.nfc_pressure_full_flow_pa == 0.7e6
    path.write_text("pump: !!python/object/apply:os.system ['true']\n")
    with pytest.raises(ValueError, match=r"unit\.yaml: not readable YAML"):
        read_hydraulics_file(path)


def test_simulate_takes_the_file_and_refuses_a_bad_one_in_one_line(tmp_path, capsys):
    log = tmp_path / "log.csv"
    log.write_text("t,swing,boom,stick,bucket\n0,0,11,0,0\n0.4,0,0,0,0\n")
    (tmp_path / "unit.json").write_text(json.dumps({"pump": {"max_flow_scale": 0.5}}))
    argv = ["simulate", "--commands", str(log), "--out", str(tmp_path / "t.csv"), "--hydraulics"]
    assert main([*argv, str(tmp_path / "unit.json")]) == 0
    (tmp_path / "bad.json").write_text(json.dumps({"leakage": {"cylinder_scale": -1}}))
    assert main([*argv, str(tmp_path / "bad.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("hexgym simulate: error: ") and "bad.json: leakage.cylinder_scale = -1 is out of range" in err
    assert main([*argv, str(tmp_path / "unit.json"), "--model", "learned"]) == 2
    assert "--hydraulics (the reference's hydraulics) does not apply with --model learned" in capsys.readouterr().err

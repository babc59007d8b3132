"""A model of your own machine from its logs: what a log gives the valve's identification (velocities, pressure rates,
pump flows), the excitation log, ``hexgym fit --logs`` refusing what it cannot trust, a fitted model's directory
used as tables, and (slow) a fit to a unit that is not the packaged one, closer to it than the packaged model."""

from __future__ import annotations

import json
import shutil

import gymnasium
import numpy as np
import pytest

import hexgym  # noqa: F401 - registers the environments
from hexgym.hydraulics.reference import ReferenceModel
from hexgym.machine import parameters as p
from hexgym.mbl.table import TableFileError, load_tables, packaged_tables_dir, resolve_tables
from hexgym.model.commandlog import CommandLog
from hexgym.model.replay import replay
from hexgym_lab.cli import main
from hexgym_lab.machine_logs import derive
from hexgym_lab.machine_logs.csv_log import write_csv_log
from hexgym_lab.machine_logs.excitation import excitation_log, functions_with_gaps, max_travel_m, start_pose
from hexgym_lab.machine_logs.fit import fit_logs
from hexgym_lab.machine_logs.signals import MachineLog
from hexgym_lab.machine_logs.synthetic import machine_log_of
from hexgym_lab.machine_logs.unit_logs import drawn_unit

# the boom raising and the bucket curling, then the stick and the swing, a few seconds each (s, mm)
COMMANDS = CommandLog(
    np.array([0.0, 0.5, 3.0, 3.5, 6.0, 8.0]),
    np.array([[0, 0, 0, 0], [0, 8, 0, 9], [0, 0, 0, 0], [7, 0, -9, 0], [0, 0, 0, 0], [0, 0, 0, 0]], float),
)
UNIT = {  # another unit: boom and stick passages x0.8 / x1.2, pumps -10 %
    "valve": {"passage_area_scale": {"boom_pa": 0.8, "boom2_pa": 0.8, "boom_at": 1.2, "stick_pa": 1.2,
                                     "stick2_pa": 1.2, "stick_pb": 0.8, "stick2_pb": 0.8, "stick_bt": 1.2}},
    "pump": {"max_flow_scale": 0.9},
}  # fmt: skip


@pytest.fixture(scope="module")
def truth() -> np.ndarray:
    return replay(ReferenceModel(), COMMANDS, dt_out=0.002)


@pytest.fixture(scope="module")
def rows(truth) -> derive.LogRows:
    t, signals = machine_log_of(truth, rate_hz=100.0, jitter=0.2, seed=5)
    return derive.log_rows(MachineLog("clean", t, signals))


def _at(rows: derive.LogRows, truth: np.ndarray, name: str) -> np.ndarray:
    return np.interp(rows.t, truth["t"], truth[name])


def test_velocities_and_pressures_from_a_noisy_log_follow_the_machine(rows, truth):
    """Angles with 0.1 deg of noise give the cylinders' speeds within a few mm/s (the spool steps' transients, which
    the smoothing rounds off, within 4 cm/s), pressures with 0.2 MPa of noise within 0.1 MPa."""
    inner = rows.usable
    for j, cyl in enumerate(("boom", "stick", "bucket")):
        error = np.abs(rows.vel[inner, j] - _at(rows, truth, f"{cyl}_velocity_mps")[inner])
        assert np.median(error) < 0.008 and np.percentile(error, 90) < 0.04, cyl
        assert np.max(np.abs(rows.ext[inner, j] - _at(rows, truth, f"{cyl}_extension_m")[inner])) < 0.005
    swing = np.abs(rows.swing_rate[inner] - _at(rows, truth, "qd_swing_radps")[inner])
    assert np.median(swing) < 0.01
    pump1 = rows.pressures[inner, 0] - _at(rows, truth, "pump1_pressure_pa")[inner]
    assert np.median(np.abs(pump1)) < 0.1e6


def test_pump_flows_by_the_regulator_law_follow_the_machine(rows, truth):
    """No pump flow is logged: the regulator's law on the estimated NFC signal gives it (within 10 % of the
    maximum in most rows; the packaged bypass tables are the reference's own here)."""
    flows = rows.pump_flows(p.PUMP_MAX_FLOW)[rows.usable]
    for k in (0, 1):
        error = np.abs(flows[:, k] - _at(rows, truth, f"pump{k + 1}_flow_m3s")[rows.usable]) / p.PUMP_MAX_FLOW
        assert np.median(error) < 0.05 and np.percentile(error, 90) < 0.15, k


def test_the_excitation_log_sweeps_each_function_both_ways_within_the_stroke(tmp_path):
    log = excitation_log()
    for j in range(4):
        assert log.spools_mm[:, j].max() == pytest.approx(11.0) and log.spools_mm[:, j].min() == pytest.approx(-11.0)
    travel = max_travel_m(log)
    for cyl, stroke in travel["strokes"].items():
        assert travel[cyl] < 0.5 * stroke, cyl  # from mid-stroke, at the nominal speeds
    assert np.all(np.isfinite(start_pose()))
    assert main(["excitation", "--out", str(tmp_path / "x.csv")]) == 0
    assert (tmp_path / "x.csv").read_text().startswith("t,swing,boom,stick,bucket")
    model = _model_dir(tmp_path)
    provenance = {
        "table_set": "circuit",
        "tables": {
            "boom_pa": {"gaps_mm": [[2, 3]]},
            "stick_pb": {"kept": "few"},
            "swing_pa": {"gaps_mm": []},
            "swing_bypass": {"kept": "nfc"},
        },
    }
    (model / "provenance.json").write_text(json.dumps(provenance))
    assert functions_with_gaps(model) == ("boom", "stick")
    assert main(["excitation", "--out", str(tmp_path / "y.csv"), "--model", str(model)]) == 0
    assert excitation_log(("boom", "stick")).duration < log.duration


def test_fit_refuses_a_log_it_cannot_trust_in_one_line_and_fits_nothing_from_none(tmp_path, truth, capsys):
    t, signals = machine_log_of(truth, rate_hz=100.0, seed=1)
    signals["q_boom_rad"] = -signals["q_boom_rad"] + 2 * np.mean(signals["q_boom_rad"])  # a flipped sign
    write_csv_log(tmp_path / "logs" / "flipped.csv", t, signals)
    t, signals = machine_log_of(truth, rate_hz=100.0, seed=2)
    signals["q_stick_rad"] = np.degrees(signals["q_stick_rad"])  # degrees
    write_csv_log(tmp_path / "logs" / "degrees.csv", t, signals)
    assert main(["fit", "--logs", str(tmp_path / "logs"), "--out", str(tmp_path / "model")]) == 2
    out, err = capsys.readouterr()
    assert "flipped.csv: error: q_boom_rad" in out and "flipped.csv: not used: cannot be trusted" in out
    assert "degrees.csv: error: q_stick_rad" in out and "degrees.csv: not used: cannot be trusted" in out
    assert "none of the 2 logs can be used" in err and err.count("\n") == 1
    assert not (tmp_path / "model").exists()


@pytest.mark.parametrize(
    "argv,match",
    [(["--tables", "paper"], "fits the circuit tables"), (["--only", "boom_pa"], "--only does not apply with --logs")],
)
def test_fit_logs_refuses_options_that_do_not_apply(tmp_path, capsys, argv, match):
    (tmp_path / "logs").mkdir()
    assert main(["fit", "--logs", str(tmp_path / "logs"), "--out", str(tmp_path / "m"), *argv]) == 2
    assert match in capsys.readouterr().err


def test_validate_needs_model_and_logs_together(tmp_path, capsys):
    assert main(["validate", "--model", str(tmp_path), "--out", str(tmp_path / "v")]) == 2
    assert "--model and --logs go together" in capsys.readouterr().err


def _model_dir(tmp_path, table_set: str = "circuit"):
    model = tmp_path / f"model_{table_set}"
    shutil.copytree(packaged_tables_dir("circuit"), model)
    (model / "provenance.json").write_text(json.dumps({"table_set": table_set}))
    return model


def test_a_fitted_model_directory_is_a_tables_directory_of_its_set(tmp_path):
    model = _model_dir(tmp_path)
    assert resolve_tables(str(model)) == ("circuit", model)
    assert set(load_tables(model, "circuit")) == set(load_tables(None, "circuit"))
    env = gymnasium.make("HexLoading-v0", tables=str(model), backend="python")
    try:
        env.reset(seed=0)
        env.step(env.action_space.sample())
    finally:
        env.close()
    commands = tmp_path / "c.csv"
    commands.write_text("t,swing,boom,stick,bucket\n0,0,5,0,0\n1,0,0,0,0\n")
    argv = ["simulate", "--model", "learned", "--backend", "python", "--commands", str(commands), "--out"]
    assert main([*argv, str(tmp_path / "run.csv"), "--tables-dir", str(model)]) == 0
    other = _model_dir(tmp_path, "paper")
    with pytest.raises(TableFileError, match=r"a model of the paper table set \(provenance.json\); the circuit"):
        load_tables(other, "circuit")
    assert main([*argv, str(tmp_path / "run2.csv"), "--tables-dir", str(other)]) == 2
    with pytest.raises(ValueError, match=r"tables must be one of .*, got .* \(or a fitted model's directory"):
        gymnasium.make("HexLoading-v0", tables=str(tmp_path))  # a directory without provenance.json


def test_a_fitted_model_carries_its_pumps_on_both_backends_and_every_tables_option(tmp_path):
    """A model whose provenance names the unit's pump flow: the python and native circuit models run it alike and
    differently from the packaged pumps; the batched env and HexReach-v0 take the directory too."""
    from hexgym.model.backend import make_learned_model
    from hexgym.model.plugin import load_plugin

    model = _model_dir(tmp_path)
    provenance = json.loads((model / "provenance.json").read_text())
    provenance["hydraulics"] = {"pump": {"max_flow_m3s": 0.9 * p.PUMP_MAX_FLOW}}
    (model / "provenance.json").write_text(json.dumps(provenance))
    commands = CommandLog(np.array([0.0, 8.0]), np.array([[11.0, 0, 0, 0], [11.0, 0, 0, 0]]))
    backends = ("python", "native") if not load_plugin() else ("python",)
    runs = {b: replay(make_learned_model(b, tables_dir=model), commands, dt_out=0.05) for b in backends}
    packaged = replay(make_learned_model("python"), commands, dt_out=0.05)
    speed = [r["qd_swing_radps"][-1] for r in (runs["python"], packaged)]  # at full speed: the pump's flow
    assert 0.85 < speed[0] / speed[1] < 0.95
    for b in backends[1:]:
        np.testing.assert_allclose(runs[b]["q_swing_rad"], runs["python"]["q_swing_rad"], atol=1e-9)
    vec = gymnasium.make_vec("HexLoading-v0", num_envs=2, backend="python", tables=str(model))
    try:
        vec.reset(seed=0)
        vec.step(np.zeros((2, 4), np.float32))
    finally:
        vec.close()
    reach = gymnasium.make("HexReach-v0", tables=str(model), backend="python")
    try:
        reach.reset(seed=0)
    finally:
        reach.close()


@pytest.mark.slow
@pytest.mark.parametrize("unit_of", [lambda: UNIT, lambda: drawn_unit(7)], ids=["fixed", "drawn"])
def test_a_fit_to_another_unit_is_closer_to_it_than_the_packaged_model(tmp_path, unit_of):
    """Logs of a unit that is not the packaged one (boom and stick passages x0.8 / x1.2, pumps -10 %; or one drawn
    within the documented ranges, reliefs included): the fitted model replays held-out logs of that unit closer than
    the packaged model does (both numbers reported), and finds its pumps' flow and its main and swing reliefs."""
    from hexgym_lab.machine_logs.unit_logs import write_unit_logs
    from hexgym_lab.machine_logs.validate_logs import summary_text, validate_on_logs

    unit_hydraulics = unit_of()
    unit = tmp_path / "unit.json"
    unit.write_text(json.dumps(unit_hydraulics))
    logs, held = tmp_path / "logs", tmp_path / "held"
    write_unit_logs(logs, str(unit), suite_seed=31, count=8, duration_s=35.0)
    write_unit_logs(logs, str(unit), suite_seed=0, count=1, style="excitation")
    write_unit_logs(held, str(unit), suite_seed=32, count=3, duration_s=30.0)
    provenance = fit_logs(logs, tmp_path / "model", seed=0)
    assert provenance["scalars"]["pump_max_flow"]["identified"]
    pump = unit_hydraulics["pump"]["max_flow_scale"]
    assert provenance["scalars"]["pump_max_flow"]["relative_to_packaged"] == pytest.approx(pump, abs=0.05)
    assert "boom_bypass" in provenance["kept_from_package"]
    reliefs = provenance["scalars"]["relief_settings"]
    for name, key in (("main", "main_pa"), ("swing", "swing_pa")):
        true = unit_hydraulics.get("relief", {}).get(key, getattr(p, f"{name.upper()}_RELIEF"))
        assert reliefs[name]["identified"] and reliefs[name]["value_pa"] == pytest.approx(true, rel=0.01), name
    assert provenance["hydraulics"]["relief"]["main_pa"] == reliefs["main"]["value_pa"]
    gaps = functions_with_gaps(tmp_path / "model")
    assert set(gaps) <= {"swing", "boom", "stick", "bucket"}
    assert excitation_log(gaps).duration <= excitation_log().duration
    result = validate_on_logs(tmp_path / "model", held)
    print(summary_text(result))
    fitted, packaged = (result["summary"][m]["tip_error_mean_median_m"] for m in ("fitted", "packaged"))
    assert fitted < packaged


def test_a_relief_setting_from_its_flow_inverts_the_circuits_relief_law():
    from hexgym.hydraulics.circuit import orifice_law, relief_area, smoothstep
    from hexgym_lab.machine_logs.reliefs import setting_from_flow

    setting = np.array([28e6, 33e6, 36e6])
    dp = setting + np.array([0.2, 0.7, 0.95]) * p.RELIEF_OVERRIDE  # partly open: the flow tells the setting
    law = p.DISCHARGE_COEFFICIENT * relief_area(setting, p.PUMP_MAX_FLOW) * orifice_law(dp)[0]
    q = law * smoothstep((dp - setting) / p.RELIEF_OVERRIDE)[0]
    np.testing.assert_allclose(setting_from_flow(dp, q, p.PUMP_MAX_FLOW), setting, rtol=1e-6)


def test_the_swing_and_main_relief_settings_are_found_in_a_units_logs():
    """A unit with its swing relief 6 % and its main relief 5 % below the data sheet's: two short logs of the swing
    started and stopped at full spool and the boom raised into its stroke end give both settings within 1 %; the
    port reliefs, never reached, are not identified and say why."""
    from hexgym_lab.machine_logs.reliefs import identify_reliefs

    unit = {"relief": {"swing_pa": 0.94 * p.SWING_RELIEF, "main_pa": 0.95 * p.MAIN_RELIEF}}
    commands = CommandLog(
        np.array([0.0, 0.3, 2.5, 2.6, 5.0, 5.3, 9.5]),
        np.array(
            [[0, 0, 0, 0], [11, 0, 0, 0], [11, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0], [0, 11, 0, 0], [0, 11, 0, 0]],
            float,
        ),
    )
    run = replay(ReferenceModel(hydraulics=unit), commands, dt_out=0.002)
    rows = [derive.log_rows(MachineLog(f"log{s}", *machine_log_of(run, rate_hz=100.0, seed=s))) for s in (1, 2)]
    found = identify_reliefs(rows, p.PUMP_MAX_FLOW)
    assert found["swing"]["value_pa"] == pytest.approx(unit["relief"]["swing_pa"], rel=0.01)
    assert found["main"]["value_pa"] == pytest.approx(unit["relief"]["main_pa"], rel=0.01)
    assert not found["line_bucket"]["identified"] and "rows" in found["line_bucket"]["why"]

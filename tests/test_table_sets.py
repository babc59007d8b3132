"""The two table sets: both load; the extended set runs on both backends alike, here on small
synthetic tables with its schema; a set's files are refused where the other set's are expected,
naming the file and what differs."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from hexgym.mbl import table
from hexgym.mbl.lwr_params import LWRParams
from hexgym.mbl.schema import NATIVE_TABLE_SETS, TABLE_SETS, table_set_of
from hexgym.mbl.table import MBLTable, load_tables, packaged_tables_dir
from hexgym.model.plugin import native_available
from hexgym.model.replay import replay
from hexgym.tools.scenarios import scenarios

needs_plugin = pytest.mark.skipif(not native_available(), reason="native plugin not built")
# Synthetic axes per quantity (3-5 nodes) and outputs: plausible magnitudes, every input matters.
_AXES = {
    "_spool_m": np.linspace(-0.011, 0.011, 5),
    "_force_n": np.array([-4e5, 0.0, 4e5]),
    "swing_inertia_kgm2": np.array([8e4, 2.5e5, 5e5]),
    "swing_rate_radps": np.array([-1.2, 0.0, 1.2]),
    "_pressure_pa": np.array([0.0, 1e7, 3.5e7]),
}
_SCALE = {"_velocity_mps": 0.3, "swing_torque_nm": 8e4, "_pressure_pa": 1e7}


def _axis(quantity: str) -> np.ndarray:
    return next(axis for suffix, axis in _AXES.items() if quantity.endswith(suffix))


def _synthetic_table(name: str, inputs: tuple[str, ...], output: str, rng: np.random.Generator) -> MBLTable:
    axes = tuple(_axis(q) for q in inputs)
    grids = np.meshgrid(*[a / np.abs(a).max() for a in axes], indexing="ij")
    weights = rng.uniform(0.2, 1.0, len(axes))
    scale = next(s for suffix, s in _SCALE.items() if output.endswith(suffix))
    values = scale * np.tanh(sum(w * g for w, g in zip(weights, grids, strict=True)))
    if output.endswith("_pressure_pa"):
        values = np.abs(values) + 2e6
    params = LWRParams(bandwidth=1.0, input_scales=tuple(float(np.ptp(a)) for a in axes))
    return MBLTable(name, inputs, output, axes, values, np.ones_like(values), params, {"n_points": 0}, "synthetic")


@pytest.fixture(scope="module")
def extended_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("extended")
    rng = np.random.default_rng(0)
    for name, spec in TABLE_SETS["extended"].items():
        _synthetic_table(name, spec.inputs, spec.output, rng).save(directory / f"{name}.npz")
    return directory


@pytest.mark.parametrize("table_set", list(TABLE_SETS))
def test_each_set_ships_and_loads(table_set):
    tables = load_tables(table_set=table_set)
    assert table_set_of(tables) == table_set
    for name, spec in TABLE_SETS[table_set].items():
        assert (tables[name].inputs, tables[name].output) == (spec.inputs, spec.output)


def test_a_set_that_is_not_shipped_says_how_to_make_it(monkeypatch, tmp_path):
    monkeypatch.setattr(table, "packaged_tables_dir", lambda table_set: tmp_path / table_set)
    with pytest.raises(FileNotFoundError, match=r"extended tables are not shipped: .*hexgym collect --tables extended"):
        load_tables(table_set="extended")


def test_a_paper_file_where_an_extended_one_is_expected_is_refused(extended_dir, tmp_path):
    for path in extended_dir.glob("*.npz"):
        shutil.copy(path, tmp_path)
    shutil.copy(packaged_tables_dir("paper") / "swing.npz", tmp_path / "swing.npz")
    with pytest.raises(ValueError, match=r"swing\.npz: table 'swing' does not match the 'extended' schema: missing"):
        load_tables(tmp_path, "extended")
    with pytest.raises(ValueError, match=r"paper/swing\.npz: table 'swing' does not match the 'extended' schema"):
        load_tables(packaged_tables_dir("paper"), "extended")
    (tmp_path / "pump2.npz").unlink()
    shutil.copy(extended_dir / "swing.npz", tmp_path)
    with pytest.raises(FileNotFoundError, match="pump2.npz"):
        load_tables(tmp_path, "extended")


def test_the_extended_model_reads_pump_2s_pressure_first(extended_dir):
    from hexgym.model.python_backend import LearnedModel

    model = LearnedModel(load_tables(extended_dir, "extended"))
    log, pose = scenarios()["test3"]
    model.reset(pose)
    assert model._pressures == (0.0, 0.0)
    spools = log.spools_at(3.0) * 1e-3
    model.step(spools)
    pressure = model._pressures[1]
    q = {"swing_spool_m": spools[0], "stick_spool_m": spools[2], "swing_rate_radps": 0.0, "stick_drive_force_n": 0.0}
    assert pressure > 1e6 and model._pressures[0] == 0.0  # pump 2's table; pump 1 has none
    assert pressure != model.tables["pump2"](tuple(q[i] for i in TABLE_SETS["extended"]["pump2"].inputs))


def test_a_torque_table_keeps_the_swings_angular_momentum(extended_dir, tmp_path):
    from hexgym.model.python_backend import LearnedModel

    for path in extended_dir.glob("*.npz"):
        shutil.copy(path, tmp_path)
    torque = load_tables(extended_dir, "extended")["swing"]
    free = MBLTable("swing", torque.inputs, torque.output, torque.axes, 0.0 * torque.values, torque.confidence,
                    torque.params, {"n_points": 0}, "synthetic")  # fmt: skip
    free.save(tmp_path / "swing.npz")
    model = LearnedModel(load_tables(tmp_path, "extended"))
    log, pose = scenarios()["test3"]
    model.reset(pose)
    model._swing_rate_target = 0.5
    inertia, momentum = [], []
    for _ in range(40):  # no torque: as the stick moves the inertia changes, and the rate with it
        model.step(np.array([0.005, 0.0, 0.011, 0.0]))
        inertia.append(model.physics.swing_inertia())
        momentum.append(model._swing_rate_target * inertia[-1])
    assert np.ptp(inertia) / inertia[0] > 0.05
    assert np.ptp(momentum) / momentum[0] < 0.005


@needs_plugin
@pytest.mark.parametrize("table_set", NATIVE_TABLE_SETS)
def test_python_and_native_agree_on_each_set(table_set, extended_dir):
    from hexgym.model.backend import python_learned_model
    from hexgym.model.native_backend import NativeLearnedModel

    directory = extended_dir if table_set == "extended" else None
    log, pose = scenarios()["test3"]
    python = replay(python_learned_model(table_set, directory), log, start=pose, duration=20.0)
    native = replay(NativeLearnedModel(tables_dir=directory, table_set=table_set), log, start=pose, duration=20.0)
    tip = [np.column_stack([r["tip_x"], r["tip_y"], r["tip_z"]]) for r in (python, native)]
    assert np.abs(tip[0] - tip[1]).max() < 1e-6
    assert np.ptp(python["q_swing"]) > 0.05  # it moved


@needs_plugin
def test_the_plugin_refuses_an_unknown_table_set():
    from hexgym.model.native_backend import load_mbl_model

    with pytest.raises(ValueError, match="unknown table set 'nosuch'"):
        load_mbl_model(packaged_tables_dir("paper"), table_set="nosuch")


def test_the_env_refuses_an_unknown_table_set():
    from hexgym.envs.loading import HexLoadingEnv

    with pytest.raises(ValueError, match="tables must be one of"):
        HexLoadingEnv(tables="nosuch")

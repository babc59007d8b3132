"""The table sets (``paper``, ``circuit``): each ships and loads and runs on both backends alike; a file
that does not match its set's schema is refused naming the file and what differs; an unknown set's name
is refused listing the sets."""

import re
import shutil

import numpy as np
import pytest

from hexgym.mbl import table
from hexgym.mbl.schema import NATIVE_TABLE_SETS, TABLE_SETS, table_set_of
from hexgym.mbl.table import MBLTable, load_tables, packaged_tables_dir
from hexgym.model.plugin import native_available
from hexgym.model.replay import replay
from hexgym_lab.scenarios import scenarios

needs_plugin = pytest.mark.skipif(not native_available(), reason="native plugin not built")


def _relabelled(source: MBLTable, inputs: tuple[str, ...] | None = None, output: str | None = None) -> MBLTable:
    """``source`` with other input or output names (its grid unchanged)."""
    return MBLTable(source.name, inputs or source.inputs, output or source.output, source.axes, source.values,
                    source.confidence, source.params, {"n_points": 0}, "synthetic")  # fmt: skip


@pytest.mark.parametrize("table_set", list(TABLE_SETS))
def test_each_set_ships_and_loads(table_set):
    tables = load_tables(table_set=table_set)
    assert table_set_of(tables) == table_set
    for name, spec in TABLE_SETS[table_set].items():
        assert (tables[name].inputs, tables[name].output) == (spec.inputs, spec.output)


def test_a_set_that_is_not_shipped_says_how_to_make_it(monkeypatch, tmp_path):
    monkeypatch.setattr(table, "packaged_tables_dir", lambda table_set: tmp_path / table_set)
    with pytest.raises(FileNotFoundError, match=r"paper tables are not shipped: .*hexgym collect --tables paper"):
        load_tables(table_set="paper")


def test_a_file_that_does_not_match_its_sets_schema_is_refused(tmp_path):
    paper, circuit = tmp_path / "paper", tmp_path / "circuit"
    shutil.copytree(packaged_tables_dir("paper"), paper)
    shutil.copytree(packaged_tables_dir("circuit"), circuit)
    swing = load_tables(table_set="paper")["swing"]
    _relabelled(swing, inputs=(*swing.inputs[:-1], "boom_force_n")).save(paper / "swing.npz")
    with pytest.raises(ValueError, match=r"swing\.npz: table 'swing' does not match the 'paper' schema: missing"):
        load_tables(paper, "paper")
    (paper / "swing.npz").unlink()
    with pytest.raises(FileNotFoundError, match="swing.npz"):
        load_tables(paper, "paper")
    valve = load_tables(table_set="circuit")["boom_pa"]
    _relabelled(valve, output="boom_pb_area_m2").save(circuit / "boom_pa.npz")
    with pytest.raises(ValueError, match=r"boom_pa\.npz: .*output 'boom_pb_area_m2' instead of 'boom_pa_area_m2'"):
        load_tables(circuit, "circuit")
    with pytest.raises(FileNotFoundError, match=r"paper/swing_bypass\.npz does not exist"):  # the other set's folder
        load_tables(packaged_tables_dir("paper"), "circuit")


@needs_plugin
@pytest.mark.parametrize("table_set", NATIVE_TABLE_SETS)
def test_python_and_native_agree_on_each_set(table_set):
    from hexgym.model.backend import python_learned_model
    from hexgym.model.native_backend import NativeLearnedModel

    log, pose = scenarios()["test3"]
    python = replay(python_learned_model(table_set), log, start=pose, duration=20.0)
    native = replay(NativeLearnedModel(table_set=table_set), log, start=pose, duration=20.0)
    tip = [np.column_stack([r["tip_x_m"], r["tip_y_m"], r["tip_z_m"]]) for r in (python, native)]
    assert np.abs(tip[0] - tip[1]).max() < 1e-6
    assert np.ptp(python["q_swing_rad"]) > 0.05  # it moved


@needs_plugin
@pytest.mark.parametrize("name", ["nosuch", "extended"])
def test_the_plugin_refuses_an_unknown_table_set(name):
    from hexgym.model.native_backend import load_mbl_model

    with pytest.raises(ValueError, match=f"unknown table set '{name}'"):
        load_mbl_model(packaged_tables_dir("paper"), table_set=name)


@pytest.mark.parametrize("name", ["nosuch", "extended"])
def test_an_unknown_table_set_is_refused_listing_the_sets(name, capsys):
    from hexgym.envs.loading import HexLoadingEnv
    from hexgym.model.backend import make_learned_model
    from hexgym_lab import cli

    listed = re.escape(f"one of {tuple(TABLE_SETS)}, got '{name}'")
    with pytest.raises(ValueError, match="tables must be " + listed):
        HexLoadingEnv(tables=name)
    with pytest.raises(ValueError, match="table set must be " + listed):
        load_tables(table_set=name)
    for backend in ("python", "native", "auto"):
        with pytest.raises(ValueError, match="table set must be " + listed):
            make_learned_model(backend, table_set=name)
    with pytest.raises(SystemExit):
        cli.main(["simulate", "--model", "learned", "--tables", name, "--commands", "x.csv", "--out", "y.csv"])
    choices = ", ".join(f"'{s}'" for s in TABLE_SETS)
    assert f"invalid choice: '{name}' (choose from {choices})" in capsys.readouterr().err

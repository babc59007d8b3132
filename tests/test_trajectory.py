"""The trajectory format: every model's rows lead with the same unit-suffixed columns; old names still read."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hexgym.hydraulics.reference import TRAJECTORY_DTYPE
from hexgym.machine import trajectory
from hexgym.model.base import LEARNED_DTYPE
from hexgym.model.circuit_model import CIRCUIT_DTYPE
from hexgym.model.commandlog import read_trajectory_csv, write_trajectory_csv


@pytest.mark.parametrize(
    "dtype", [TRAJECTORY_DTYPE, LEARNED_DTYPE, CIRCUIT_DTYPE], ids=["reference", "paper", "circuit"]
)
def test_every_model_leads_with_the_common_columns(dtype: np.dtype) -> None:
    names = dtype.names
    assert names[: len(trajectory.COMMON_COLUMNS)] == trajectory.COMMON_COLUMNS
    assert len(set(names)) == len(names)
    units = ("_rad", "_radps", "_radps2", "_m", "_mps", "_mm", "_n", "_nm", "_pa", "_m3s", "_w", "_kgm2", "_l_per_h")
    assert all(n == "t" or n.endswith(units) for n in names), [n for n in names if not n.endswith(units)]


def test_the_models_know_what_they_know() -> None:
    pumps = set(trajectory.PUMP_COLUMNS)
    assert pumps | set(trajectory.POWER_COLUMNS) <= set(TRAJECTORY_DTYPE.names)
    assert pumps | set(trajectory.POWER_COLUMNS) <= set(CIRCUIT_DTYPE.names)
    assert len(TRAJECTORY_DTYPE.names) == 42 and len(LEARNED_DTYPE.names) == 27 and len(CIRCUIT_DTYPE.names) == 33


def test_old_names_index_the_rows() -> None:
    rows = np.zeros(3, dtype=CIRCUIT_DTYPE)
    rows["q_boom_rad"], rows["tip_z_m"], rows["swing_acceleration_target_radps2"] = 0.5, 2.0, -1.0
    assert np.all(rows["q_boom"] == 0.5) and np.all(rows["tip_z"] == 2.0)
    assert np.all(rows["swing_acceleration_target"] == -1.0)
    assert set(trajectory.OLD_NAMES.values()) <= set(CIRCUIT_DTYPE.names)
    assert trajectory.current_name("qd_swing") == "qd_swing_radps" and trajectory.current_name("t") == "t"


def test_a_csv_with_old_or_new_names_reads_under_the_new(tmp_path: Path) -> None:
    rows = np.zeros(2, dtype=TRAJECTORY_DTYPE)
    rows["t"], rows["qd_swing_radps"], rows["fuel_rate_l_per_h"] = [0.0, 0.05], [0.1, np.nan], [9.5, 10.0]
    write_trajectory_csv(tmp_path / "new.csv", rows)
    again = read_trajectory_csv(tmp_path / "new.csv")
    assert again.dtype.names == TRAJECTORY_DTYPE.names
    assert np.array_equal(again["qd_swing_radps"], rows["qd_swing_radps"], equal_nan=True)
    old = tmp_path / "old.csv"
    old.write_text("t,q_swing,qd_swing,tip_x,pump_power_w\n0,0.25,0.5,7.0,1e4\n0.05,0.3,0.5,7.1,2e4\n")
    read = read_trajectory_csv(old)
    assert read.dtype.names == ("t", "q_swing_rad", "qd_swing_radps", "tip_x_m", "pump_power_w")
    assert read["q_swing_rad"].tolist() == [0.25, 0.3] and read["tip_x"].tolist() == [7.0, 7.1]
    (tmp_path / "bad.csv").write_text("t,q_swing,q_swing_rad\n0,1,1\n")
    with pytest.raises(ValueError, match="repeated"):
        read_trajectory_csv(tmp_path / "bad.csv")
    (tmp_path / "short.csv").write_text("t,q_swing\n0,x\n")
    with pytest.raises(ValueError, match="row 2"):
        read_trajectory_csv(tmp_path / "short.csv")

"""The reference model (circuit + MuJoCo linkage), the command log reader and the trajectory writer."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from hexgym.hydraulics.reference import TRAJECTORY_COLUMNS, ReferenceModel
from hexgym.machine import mjcf
from hexgym.machine import parameters as p
from hexgym.machine.assets import AssetError, asset_path, assets_dir
from hexgym.machine.physics import force_actuated_model
from hexgym.machine.trajectory import COMMON_COLUMNS
from hexgym.model.commandlog import CommandLog, read_command_log, write_trajectory_csv
from hexgym.model.replay import replay

REQUIRED = (
    "t,q_swing_rad,q_boom_rad,q_stick_rad,q_bucket_rad,qd_swing_radps,qd_boom_radps,qd_stick_radps,qd_bucket_radps,"
    "tip_x_m,tip_y_m,tip_z_m"
)
HYDRAULIC = "pump1_pressure_pa,pump2_pressure_pa,pump1_flow_m3s,pump2_flow_m3s,pump_power_w,fuel_rate_l_per_h"


@pytest.fixture(scope="module")
def model_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The packaged machine; generated next to a link to the meshes if not built yet."""
    try:
        return asset_path("cat325.xml")
    except AssetError:
        folder = tmp_path_factory.mktemp("assets")
        (folder / "meshes").symlink_to(assets_dir() / "meshes")
        mjcf.write_model(folder / "cat325.xml")
        return folder / "cat325.xml"


@pytest.fixture(scope="module")
def reference(model_path: Path) -> ReferenceModel:
    return ReferenceModel(force_actuated_model(model_path))


def log(rows: list[list[float]]) -> CommandLog:
    table = np.array(rows, dtype=float)
    return CommandLog(table[:, 0], table[:, 1:])


def test_trajectory_columns_and_sampling(reference: ReferenceModel) -> None:
    traj = replay(reference, log([[0, 0, 0, 0, 0], [0.2, 0, 11, 0, 0]]), dt_out=0.05)
    names = list(traj.dtype.names)
    assert names[:12] == REQUIRED.split(",") and names[26:32] == HYDRAULIC.split(",")
    assert tuple(names[:26]) == COMMON_COLUMNS  # the leading columns every model writes
    assert {"boom_head_pressure_pa", "swing_b_pressure_pa", "boom_force_n"} <= set(names)
    assert tuple(names) == TRAJECTORY_COLUMNS
    assert np.allclose(traj["t"], np.arange(5) * 0.05)
    assert all(np.all(np.isfinite(traj[n])) for n in names)


def test_holds_still_with_neutral_spools(reference: ReferenceModel) -> None:
    traj = replay(reference, log([[0, 0, 0, 0, 0]]), duration=1.0, payload_kg=2000.0)
    q = np.column_stack([traj[f"q_{j}_rad"] for j in ("swing", "boom", "stick", "bucket")])
    assert np.abs(q - q[0]).max() < 2e-4  # rad: the start pressures hold the loads, ports closed
    for pump in ("pump1", "pump2"):
        assert traj[f"{pump}_flow_m3s"][-1] == pytest.approx(p.PUMP_IDLE_FLOW_FRACTION * p.PUMP_MAX_FLOW)


def test_payload_loads_the_boom(reference: ReferenceModel) -> None:
    empty = replay(reference, log([[0, 0, 0, 0, 0]]), duration=0.1)
    full = replay(reference, log([[0, 0, 0, 0, 0]]), duration=0.1, payload_kg=2000.0)
    assert full["boom_head_pressure_pa"][-1] > empty["boom_head_pressure_pa"][-1] + 1e6


def test_boom_raises_at_pump_flow(reference: ReferenceModel) -> None:
    """Boom alone at full spool: both pumps feed it (boom 1 and boom 2), so the cylinder extends at about their
    flow / head area, a little less where their shared power limit takes over."""
    traj = replay(reference, log([[0, 0, 11, 0, 0], [2.0, 0, 11, 0, 0]]), start=np.array([0.0, -0.6, 0.3, 0.3]))
    late = traj["t"] > 1.0
    assert traj["boom_extension_m"][-1] < p.BOOM_CYLINDER.stroke - 0.05  # still short of its stroke's end
    speed = traj["boom_velocity_mps"][late].mean()
    both_pumps = 2.0 * p.PUMP_MAX_FLOW / p.BOOM_CYLINDER.head_area
    assert 0.8 * both_pumps < speed < 1.02 * both_pumps
    assert traj["tip_z_m"][-1] > traj["tip_z_m"][0] + 0.3
    assert traj["pump_power_w"].max() <= p.PUMP_POWER_LIMIT * (1 + 1e-9)
    assert 5.0 < traj["fuel_rate_l_per_h"][-1] < 35.0


def test_dt_out_must_be_a_multiple_of_the_step(reference: ReferenceModel) -> None:
    with pytest.raises(ValueError, match="dt_out"):
        replay(reference, log([[0, 0, 0, 0, 0]]), dt_out=0.0031)


# --------------------------------------------------------------------------------------------
# Command log CSV
def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "commands.csv"
    path.write_text(text)
    return path


def test_read_command_log_holds_each_row(tmp_path: Path) -> None:
    commands = read_command_log(write(tmp_path, "t,swing,boom,stick,bucket\n0,0,0,0,0\n1.5,11,-5,0,2.5\n2,0,0,0,0\n"))
    assert commands.t.tolist() == [0.0, 1.5, 2.0] and commands.duration == 2.0
    assert commands.spools_at(1.49).tolist() == [0, 0, 0, 0]
    assert commands.spools_at(1.5).tolist() == [11, -5, 0, 2.5]
    assert commands.spools_at(9.0).tolist() == [0, 0, 0, 0]


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("t,swing,boom,bucket\n0,0,0,0\n", "missing column.*stick"),
        ("t,swing,boom,stick,bucket\n0,0,0,0,0\n1,0,0,0,0\n0.5,0,0,0,0\n", "row 3, column 't'.*ascend"),
        ("t,swing,boom,stick,bucket\n0,0,0,0,0\n1,0,nan,0,0\n", "row 2, column 'boom'.*finite"),
        ("t,swing,boom,stick,bucket\n0,0,0,0,0\n1,0,0,-11.5,0\n", "row 2, column 'stick'.*beyond"),
        ("t,swing,boom,stick,bucket\n0.1,0,0,0,0\n", "row 1, column 't'.*start at t = 0"),
        ("t,swing,boom,stick,bucket\n0,0,0,0,x\n", "row 1, column 'bucket'.*not a number"),
        ("t,swing,boom,stick,bucket\n0,0,0,0\n", "row 1, column 'bucket'.*missing"),
        ("t,swing,boom,stick,bucket\n", "no rows"),
        ("t,swing,boom,stick,bucket,arm\n0,0,0,0,0,0\n", "unexpected"),
    ],
)
def test_malformed_command_logs_are_refused(tmp_path: Path, text: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        read_command_log(write(tmp_path, text))


def test_command_log_object_is_checked_too() -> None:
    with pytest.raises(ValueError, match="row 2, column 'swing'"):
        CommandLog(np.array([0.0, 1.0]), np.array([[0, 0, 0, 0], [12.0, 0, 0, 0]]))


# --------------------------------------------------------------------------------------------
# Trajectory CSV
def test_trajectory_csv_is_written_atomically(tmp_path: Path) -> None:
    traj = np.zeros(3, dtype=[("t", float), ("q_swing_rad", float)])
    traj["t"] = [0.0, 0.05, 0.1]
    path = tmp_path / "out.csv"
    write_trajectory_csv(path, traj)
    lines = path.read_text().splitlines()
    assert lines[0] == "t,q_swing_rad" and lines[2] == "0.05,0" and len(lines) == 4
    bad = np.zeros(2, dtype=[("t", float), ("q_swing_rad", object)])  # fails while writing
    bad["q_swing_rad"] = [1.0, "x"]
    with pytest.raises((TypeError, ValueError)):
        write_trajectory_csv(path, bad)
    assert path.read_text().splitlines() == lines  # the old file is untouched
    assert os.listdir(tmp_path) == ["out.csv"]  # and no temporary file is left

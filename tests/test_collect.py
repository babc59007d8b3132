"""Training-data collection on the reference model: shapes, determinism, resumption, physics sanity."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hexgym.hydraulics.reference import ReferenceModel
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.mbl.schema import DEFAULT_TABLE_SET, TABLE_SETS
from hexgym_lab.mbl.collect import (
    CollectConfig,
    _chunk_task,
    chunk_path,
    collect,
    episode_rng,
    episode_setup,
    load_dataset,
    model_fingerprint,
    run_segment,
    tip_force_world,
)

TABLES = TABLE_SETS["paper"]
# Short segments and episodes: a few seconds per collection, every code path.
TINY = CollectConfig(
    table_set="paper",
    segments_per_episode=3,
    episodes_per_chunk=1,
    hold_s=(0.7, 0.8),
    windows_per_segment=1,
    operator_duration_s=6.0,
)
SAMPLES = 4
SEED = 6


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """An uninterrupted one-worker collection."""
    out = tmp_path_factory.mktemp("tiny")
    return collect(out, samples_per_group=SAMPLES, seed=SEED, workers=1, progress=False, config=TINY)


@pytest.fixture(scope="module")
def sim() -> ReferenceModel:
    return ReferenceModel()


def assert_same(a: dict[str, Path], b: dict[str, Path]) -> None:
    assert a.keys() == b.keys() == TABLES.keys()
    for table in TABLES:
        da, db = load_dataset(a[table]), load_dataset(b[table])
        for key in ("X", "y", "episode", "segment"):
            np.testing.assert_array_equal(da[key], db[key], err_msg=f"{table} {key}")


def test_tiny_collection_has_finite_samples_with_names(tiny: dict[str, Path]) -> None:
    for table, spec in TABLES.items():
        assert tiny[table] == tiny[table].parent / f"{table}.npz"
        ds = load_dataset(tiny[table])
        n, d = ds["X"].shape
        assert d == len(spec.inputs) and ds["y"].shape == (n,) and n >= (SAMPLES if table != "swing" else 10)
        assert ds["inputs"] == spec.inputs and ds["output"] == spec.output
        assert ds["X"].dtype == ds["y"].dtype == np.float64
        assert np.all(np.isfinite(ds["X"])) and np.all(np.isfinite(ds["y"]))
        assert ds["seed"] == SEED and ds["generator_version"] >= 1 and ds["meta"]["table"] == table
        assert np.all(np.diff(ds["episode"]) >= 0)  # merged in episode order
        spools = ds["X"][:, [i for i, name in enumerate(spec.inputs) if name.endswith("_spool_m")]]
        assert np.abs(spools).max() <= p.SPOOL_STROKE + 1e-12
        np.testing.assert_allclose(spools * 1e3, np.round(spools * 1e3), atol=1e-9)  # the 1 mm grid
    files = sorted(f.name for f in tiny["boom"].parent.rglob("*") if f.is_file())
    assert not [f for f in files if f.endswith(".tmp")]  # atomic writes leave no temporary files


def test_data_sets_name_the_reference_model(tiny: dict[str, Path], tmp_path: Path) -> None:
    fingerprint = model_fingerprint()
    assert len(fingerprint) == 16 and int(fingerprint, 16) >= 0
    assert all(load_dataset(path)["meta"]["model_fingerprint"] == fingerprint for path in tiny.values())
    task = (str(tmp_path), "boom_bucket", 0, SEED, TINY.to_json(), "0" * 16)
    with pytest.raises(RuntimeError, match="reference model"):  # a worker with another model refuses
        _chunk_task(task)


def test_two_workers_give_the_same_data(tiny: dict[str, Path], tmp_path: Path) -> None:
    two = collect(tmp_path, samples_per_group=SAMPLES, seed=SEED, workers=2, progress=False, config=TINY)
    assert_same(tiny, two)


def test_interrupted_collection_resumes_to_the_same_data(tiny: dict[str, Path], tmp_path: Path) -> None:
    kwargs = {"samples_per_group": SAMPLES, "seed": SEED, "workers": 1, "progress": False, "config": TINY}
    assert collect(tmp_path, **kwargs, max_chunks=1) == {}  # stopped before the data sets were complete
    assert len(list((tmp_path / "chunks").glob("*.npz"))) == 1 and not (tmp_path / "boom.npz").exists()
    first = chunk_path(tmp_path, "boom_bucket", 0).read_bytes()
    resumed = collect(tmp_path, **kwargs)
    assert chunk_path(tmp_path, "boom_bucket", 0).read_bytes() == first  # reused, not recomputed
    assert_same(tiny, resumed)
    with pytest.raises(ValueError, match="seed"):  # chunks of another run are never mixed in
        collect(tmp_path, **(kwargs | {"seed": SEED + 1}))


def test_episodes_are_seeded_individually() -> None:
    config = CollectConfig(table_set="paper")
    a = episode_setup(episode_rng(0, "boom_bucket", 5), 5, config)
    b = episode_setup(episode_rng(0, "boom_bucket", 5), 5, config)
    c = episode_setup(episode_rng(1, "boom_bucket", 5), 5, config)
    d = episode_setup(episode_rng(0, "stick_swing", 5), 5, config)
    np.testing.assert_array_equal(a.q, b.q)
    assert not np.array_equal(a.q, c.q) and not np.array_equal(a.q, d.q)


def test_episode_starts_cover_poses_payloads_and_tip_forces() -> None:
    config = CollectConfig(table_set="paper")
    setups = [episode_setup(episode_rng(0, "boom_bucket", e), e, config) for e in range(300)]
    for i, name in enumerate(kinematics.FRONT_CYLINDERS):  # uniform over the stroke, clear of the ends
        stroke = p.CYLINDERS[name].stroke
        ext = (
            np.array([kinematics.cylinder_length(name, s.q[i + 1]) for s in setups])
            - p.CYLINDERS[name].retracted_length
        )
        assert config.start_margin_m - 1e-9 < ext.min() < 0.25 * stroke
        assert 0.75 * stroke < ext.max() < stroke - config.start_margin_m + 1e-9
    assert sorted({s.payload_kg for s in setups}) == [0.0, 1000.0, 2000.0]
    forces = np.array([s.tip_force_arm for s in setups if s.tip_force_arm is not None])
    assert 0.55 < len(forces) / len(setups) < 0.8  # none in about a third
    assert np.linalg.norm(forces, axis=1).max() <= config.tip_force_max_n
    assert np.mean(forces[:, 1] > 0) > 0.8  # mostly resisting a bucket moving down into material
    np.testing.assert_allclose(tip_force_world(np.array([3.0, 2.0]), np.pi / 2), [0.0, 3.0, 2.0], atol=1e-12)


def start(sim: ReferenceModel, payload_kg: float) -> None:
    """Mid-stroke cylinders, at rest."""
    q = np.zeros(4)
    for i, name in enumerate(kinematics.FRONT_CYLINDERS):
        cyl = p.CYLINDERS[name]
        q[i + 1] = kinematics.joint_angle(name, cyl.retracted_length + 0.5 * cyl.stroke)
    sim.reset(q, payload_kg)


def test_full_boom_spool_without_load_moves_at_both_pumps_flow(sim: ReferenceModel) -> None:
    start(sim, 0.0)
    result = run_segment(sim, np.array([0.0, p.SPOOL_STROKE, 0.0, 0.0]), 750, CollectConfig(table_set="paper"))
    assert not result.limited and len(result.windows) == 2
    both_pumps = 2.0 * p.PUMP_MAX_FLOW / p.BOOM_CYLINDER.head_area  # about 0.289 m/s: boom 1 and boom 2
    for window in result.windows:
        assert 0.8 * both_pumps < window.velocity[0] < 1.02 * both_pumps  # below it where the power limit holds
        assert abs(window.velocity[2]) < 0.02  # the bucket's spool is neutral
        assert window.force[0] > 0  # the boom cylinder pushes against gravity


def test_neutral_spools_hold_a_loaded_machine_under_a_tip_force(sim: ReferenceModel) -> None:
    start(sim, 2000.0)
    result = run_segment(sim, np.zeros(4), 600, CollectConfig(table_set="paper"), tip_force_arm=np.array([-40e3, 40e3]))
    assert not result.limited
    for window in result.windows:
        assert np.abs(window.velocity).max() < 0.01  # m/s: ports closed, only the oil's compliance


def test_swing_samples_accelerate_at_about_the_rated_torque(sim: ReferenceModel) -> None:
    start(sim, 1000.0)
    config = CollectConfig(table_set="paper")
    result = run_segment(sim, np.array([p.SPOOL_STROKE, 0.0, 0.0, 0.0]), 500, config, swing_samples=True)
    rows = np.array(result.swing_rows)  # stick force, inertia, swing rate, acceleration
    assert len(rows) == 9 and result.swing_rejected == 0  # every 0.1 s from 0.1 s to 0.9 s
    rated = p.SWING_TORQUE / rows[:, 1]
    assert np.all(rows[:, 3] > 0.5 * rated) and np.all(rows[:, 3] < 2.0 * rated)
    assert np.all(np.diff(rows[:, 2]) > 0)  # speeding up
    # the acceleration is the swing rate's slope: integrating it recovers the rate
    np.testing.assert_allclose(np.diff(rows[:, 2]), 0.1 * 0.5 * (rows[1:, 3] + rows[:-1, 3]), rtol=0.05)


def test_dataset_physics_sanity(tiny: dict[str, Path]) -> None:
    boom, bucket = load_dataset(tiny["boom"]), load_dataset(tiny["bucket"])
    idle = np.all(np.abs(boom["X"][:, :2]) < p.SPOOL_DEAD_BAND, axis=1)  # both spools inside the dead band
    assert np.all(np.abs(boom["y"][idle]) < 0.03) and np.all(np.abs(bucket["y"][idle]) < 0.03)
    assert np.abs(boom["y"]).max() < 1.0 and np.abs(bucket["y"]).max() < 1.5  # m/s, cylinder speeds
    swing = load_dataset(tiny["swing"])
    assert np.abs(swing["X"][:, 4]).max() < 1.5 and np.abs(swing["y"]).max() < 2.0  # rad/s, rad/s^2


def test_cli_parser_defaults() -> None:
    from hexgym_lab.cli import build_parser

    parser = build_parser()
    args = parser.parse_args(["collect"])
    assert (args.out, args.seed, args.workers, args.tables, args.ray) == ("data", 0, 2, DEFAULT_TABLE_SET, None)
    assert args.samples >= 5500
    args = parser.parse_args(["collect", "--out", "x", "--samples", "10", "--seed", "3", "--workers", "1"])
    assert (args.out, args.samples, args.seed, args.workers) == ("x", 10, 3, 1)


def test_circuit_collection_replays_sweep_logs_named_as_the_schema_says(tmp_path: Path) -> None:
    config = CollectConfig(**{**TINY.__dict__, "table_set": "circuit"})
    paths = collect(tmp_path, samples_per_group=SAMPLES, seed=SEED, workers=1, progress=False, config=config)
    assert paths.keys() == TABLE_SETS["circuit"].keys()
    for table, spec in TABLE_SETS["circuit"].items():
        ds = load_dataset(paths[table])
        assert ds["inputs"] == spec.inputs and ds["output"] == spec.output and np.isfinite(ds["X"]).all()
    counted = load_dataset(paths[next(iter(TABLE_SETS["circuit"]))])
    assert len(counted["y"]) >= config.target("operator", SAMPLES)

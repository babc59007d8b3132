"""hexgym fit / tables on a small synthetic flow-sharing data set (the real data: `hexgym collect`)."""

# ruff: noqa: N806 - X follows the statistics notation

import numpy as np
import pytest

from hexgym.mbl.schema import TABLE_SETS
from hexgym_lab.mbl import fit
from hexgym_lab.mbl.baselines import synthetic_flow_sharing

TABLES = TABLE_SETS["paper"]  # the set fit and tables default to


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    directory = tmp_path_factory.mktemp("data")
    X, y = synthetic_flow_sharing(700, seed=3)
    rng = np.random.default_rng(4)
    for name, spec in TABLES.items():
        inputs, output = spec.inputs, spec.output
        Xn = X if len(inputs) == 4 else np.column_stack([X, rng.uniform(-1, 1, len(y))])
        episode = np.arange(len(y)) // 10  # ten rows per episode
        np.savez(
            directory / f"{name}.npz", X=Xn, y=y, episode=episode, inputs=np.array(inputs), output=np.array(output)
        )
    return directory


@pytest.fixture(scope="module")
def fitted(data_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("tables")
    fit.fit_all(data_dir, out, seed=0, table_set="paper")
    return out


def test_fit_writes_every_table_with_its_metrics(fitted):
    summary = {t["name"]: t for t in fit.tables_summary(fitted, table_set="paper")}
    assert set(summary) == set(TABLES)
    for name, t in summary.items():
        assert (tuple(t["inputs"]), t["output"]) == (TABLES[name].inputs, TABLES[name].output)
        assert t["n_points"] == 700
        assert 0 < t["loo_rmse_rel"] < 0.1 and 0 < t["holdout_rmse_rel"] < 0.1
        assert t["holdout_rmse_rel"] < t["baselines_holdout_rmse_rel"]["global_linear"]
        assert set(t["params"]) >= {"bandwidth", "input_scales", "ridge"}


def test_fit_is_deterministic(data_dir, fitted, tmp_path):
    fit.fit_all(data_dir, tmp_path, seed=0, names=("boom",), table_set="paper")
    assert (tmp_path / "boom.npz").read_bytes() == (fitted / "boom.npz").read_bytes()


def test_tables_answer_queries(fitted):
    tables = fit.load_tables(fitted, table_set="paper")
    boom = tables["boom"]
    value, confidence = boom.lookup(np.array([[0.011, 0.0, 1e5, 1e4]]), return_confidence=True)
    assert np.isfinite(value).all() and confidence.shape == (1,)
    with pytest.raises(ValueError):
        boom.lookup(np.array([[np.nan, 0.0, 0.0, 0.0]]))


def test_wrong_or_missing_data_is_named(data_dir, tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing.npz"):
        fit.load_table_data(tmp_path / "nothing.npz", "boom", table_set="paper")
    with pytest.raises(ValueError, match="swing.npz"):
        fit.load_table_data(data_dir / "swing.npz", "boom", table_set="paper")


def test_fitted_points_subsample_only_above_the_limit():
    from hexgym_lab.mbl.fit import MAX_POINTS, TableData, fitted_points

    def data(n: int) -> TableData:
        return TableData(np.arange(2.0 * n).reshape(-1, 2), np.arange(float(n)), np.arange(n) // 7)

    small = data(10)
    assert fitted_points(small) is small
    kept = fitted_points(data(MAX_POINTS + 50), seed=3)
    assert len(kept.y) == MAX_POINTS and np.all(np.diff(kept.y) > 0)  # distinct rows, in their order
    np.testing.assert_array_equal(kept.X[:, 1], 2 * kept.y + 1)  # rows stay paired with their outputs
    np.testing.assert_array_equal(kept.episode, kept.y.astype(int) // 7)  # and with their episodes
    np.testing.assert_array_equal(fitted_points(data(MAX_POINTS + 50), seed=3).y, kept.y)  # seeded
    assert not np.array_equal(fitted_points(data(MAX_POINTS + 50), seed=4).y, kept.y)


def test_episode_split_holds_out_whole_episodes():
    from hexgym_lab.mbl.fit import episode_split

    episode = np.repeat(np.arange(50), 3)
    train, test = episode_split(episode, 0.2, seed=1)
    assert len(test) == 30 and not set(episode[train]) & set(episode[test])
    assert np.array_equal(np.sort(np.concatenate([train, test])), np.arange(150))

"""Locally weighted regression: exactness, exact leave-one-out, model selection, confidence, errors."""

# ruff: noqa: N803, N806  (matrix names X, Xq, A, Q as in the module under test)

import numpy as np
import pytest

from hexgym_lab.mbl.baselines import compare_baselines, synthetic_flow_sharing
from hexgym_lab.mbl.lwr import (
    LocallyWeightedRegression,
    LWRParams,
    default_scales,
    holdout_split,
    loo_predictions,
    loo_residuals,
    rmse,
    select_params,
)


def _smooth(X: np.ndarray) -> np.ndarray:
    return np.sin(2.0 * X[:, 0]) + X[:, 1] * X[:, 2] + 0.3 * X[:, 0] ** 2


@pytest.fixture(scope="module")
def flow_data() -> tuple[np.ndarray, np.ndarray]:
    return synthetic_flow_sharing(1200, seed=3)


@pytest.mark.parametrize("bandwidth", [0.3, 1.0, 3.0, 100.0])
@pytest.mark.parametrize("max_neighbours", [None, 12])
def test_recovers_linear_function_exactly(bandwidth: float, max_neighbours: int | None) -> None:
    rng = np.random.default_rng(0)
    X = rng.uniform(-1.0, 1.0, (300, 4)) * [0.011, 0.011, 2e5, 1e5]  # SI-like units, very different
    coef = np.array([10.0, -5.0, 1e-6, 3e-6])
    y = X @ coef + 0.2
    params = LWRParams(bandwidth, (0.011, 0.011, 2e5, 1e5), ridge=0.0, max_neighbours=max_neighbours)
    Xq = rng.uniform(-0.9, 0.9, (100, 4)) * [0.011, 0.011, 2e5, 1e5]
    pred = LocallyWeightedRegression(params).fit(X, y).predict(Xq)
    np.testing.assert_allclose(pred, Xq @ coef + 0.2, rtol=0, atol=1e-10)
    np.testing.assert_allclose(loo_residuals(X, y, params), 0.0, atol=1e-10)


@pytest.mark.parametrize("params", [LWRParams(0.4, (1.0, 1.0, 2.0), 0.05), LWRParams(0.7, (1.0, 0.5, 1.0), 0.0, 15)])
def test_loo_equals_brute_force_refit(params: LWRParams) -> None:
    rng = np.random.default_rng(1)
    X = rng.uniform(-1.0, 1.0, (60, 3))
    X[10] = X[11]  # a duplicate: the other copy must stay in the fit
    y = _smooth(X) + 0.05 * rng.standard_normal(60)
    y[10] = y[11]  # so that a k-nearest tie between the copies cannot change the fit
    brute = np.array(
        [
            LocallyWeightedRegression(params).fit(np.delete(X, i, 0), np.delete(y, i)).predict(X[i : i + 1])[0]
            for i in range(60)
        ]
    )
    np.testing.assert_allclose(loo_predictions(X, y, params), brute, rtol=0, atol=1e-11)
    rows = np.array([3, 10, 59])
    np.testing.assert_allclose(loo_residuals(X, y, params, rows=rows), y[rows] - brute[rows], atol=1e-11)


def test_batch_single_and_threads_agree() -> None:
    rng = np.random.default_rng(2)
    X = rng.uniform(-1.0, 1.0, (500, 3))
    y = _smooth(X)
    params = LWRParams(0.3, (1.0, 1.0, 1.0), 1e-3)
    Xq = rng.uniform(-1.0, 1.0, (40, 3))
    one = LocallyWeightedRegression(params, workers=1).fit(X, y).predict(Xq)
    two = LocallyWeightedRegression(params, workers=2).fit(X, y).predict(Xq)
    single = [LocallyWeightedRegression(params).fit(X, y).predict(x)[0] for x in Xq]
    np.testing.assert_array_equal(one, two)
    np.testing.assert_allclose(one, single, rtol=0, atol=1e-12)


def test_cutoff_truncation_is_negligible() -> None:
    rng = np.random.default_rng(4)
    X = rng.uniform(-1.0, 1.0, (2000, 4))
    y = _smooth(X)
    Xq = rng.uniform(-0.8, 0.8, (200, 4))
    near = LocallyWeightedRegression(LWRParams(0.3, (1.0,) * 4, 1e-4)).fit(X, y).predict(Xq)
    full = LocallyWeightedRegression(LWRParams(0.3, (1.0,) * 4, 1e-4, cutoff=12.0)).fit(X, y).predict(Xq)
    assert np.max(np.abs(near - full)) < 0.005 * np.ptp(y)


def test_confidence_low_far_from_data(flow_data: tuple[np.ndarray, np.ndarray]) -> None:
    X, y = flow_data
    params = LWRParams(0.3, tuple(default_scales(X)), 1e-3)
    lwr = LocallyWeightedRegression(params).fit(X, y)
    inside = np.array([[0.005, -0.003, 1.5e5, 0.5e5], [-0.008, 0.0, 0.0, 1.0e5]])
    far = inside.copy()
    far[:, 2] = 3.0e6  # ten times the largest load in the data
    pred_in, conf_in = lwr.predict(inside, return_confidence=True)
    pred_far, conf_far = lwr.predict(far, return_confidence=True)
    assert np.all(conf_in.n_eff > 10) and np.all(np.isfinite(conf_in.variance))
    assert np.all(conf_far.n_eff < 2)
    assert np.all(np.isfinite(pred_far)) and np.all(np.abs(pred_far) <= np.abs(y).max() * 1.5)  # no wild extrapolation
    assert np.all(conf_in.variance < np.var(y))


def test_max_neighbours_caps_the_fit() -> None:
    rng = np.random.default_rng(5)
    X = rng.uniform(-1.0, 1.0, (400, 2))
    lwr = LocallyWeightedRegression(LWRParams(10.0, (1.0, 1.0), 0.0, max_neighbours=7)).fit(X, X.sum(axis=1))
    _, conf = lwr.predict(np.zeros((1, 2)), return_confidence=True)
    assert 6.0 < conf.n_eff[0] <= 7.0 + 1e-9


def _global_linear_loo_rmse(X: np.ndarray, y: np.ndarray) -> float:
    A = np.column_stack([np.ones(len(y)), X])
    Q, _ = np.linalg.qr(A)
    resid = y - Q @ (Q.T @ y)
    return rmse(resid / (1.0 - np.sum(Q * Q, axis=1)))  # exact for ordinary least squares


def test_select_params_improves_on_bad_guess_and_beats_linear(flow_data: tuple[np.ndarray, np.ndarray]) -> None:
    X, y = flow_data
    bad = LWRParams(3.0, tuple(default_scales(X) * [1.0, 0.05, 1.0, 1.0]), 1.0)
    best, report = select_params(X, y, seed=0, initial=bad, n_search_rows=600, max_refine=25)
    assert report.loo_rmse_initial == pytest.approx(rmse(loo_residuals(X, y, bad)))
    assert report.loo_rmse == pytest.approx(rmse(loo_residuals(X, y, best)))
    assert report.loo_rmse < 0.6 * report.loo_rmse_initial
    assert report.loo_rmse < 0.6 * _global_linear_loo_rmse(X, y)
    assert report.n_evaluations == len(report.history) > 10


def test_select_params_is_deterministic() -> None:
    X, y = synthetic_flow_sharing(300, seed=7)
    kwargs = dict(seed=11, n_search_rows=150, n_random=4, max_refine=10)
    a, ra = select_params(X, y, **kwargs)
    b, rb = select_params(X, y, **kwargs)
    assert a == b and ra.loo_rmse == rb.loo_rmse


def test_holdout_split() -> None:
    train, test = holdout_split(101, 0.2, seed=3)
    assert len(test) == 20 and len(train) == 81
    assert np.array_equal(np.sort(np.r_[train, test]), np.arange(101))
    again = holdout_split(101, 0.2, seed=3)
    assert np.array_equal(train, again[0]) and np.array_equal(test, again[1])
    assert not np.array_equal(test, holdout_split(101, 0.2, seed=4)[1])
    with pytest.raises(ValueError):
        holdout_split(10, 1.0, seed=0)


def test_baselines_rank_lwr_first(flow_data: tuple[np.ndarray, np.ndarray]) -> None:
    X, y = flow_data
    params = LWRParams(0.2, tuple(default_scales(X) * [0.6, 0.9, 1.0, 1.5]), 0.05)
    scores = compare_baselines(X, y, fraction=0.25, seed=1, lwr_params=params)
    assert set(scores) == {"global_linear", "knn_8", "cubic_ridge", "lwr"}
    assert scores["lwr"] < scores["global_linear"] and scores["lwr"] < scores["knn_8"]


def test_non_finite_and_shape_errors_name_the_place() -> None:
    X = np.zeros((5, 2))
    X[:, 0] = np.arange(5.0)
    y = np.arange(5.0)
    params = LWRParams(1.0, (1.0, 1.0))
    bad = X.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"X contains NaN at row 3, column 1"):
        LocallyWeightedRegression(params).fit(bad, y)
    with pytest.raises(ValueError, match=r"y contains inf at row 2"):
        LocallyWeightedRegression(params).fit(X, np.where(np.arange(5) == 2, np.inf, y))
    lwr = LocallyWeightedRegression(params).fit(X, y)
    with pytest.raises(ValueError, match=r"query contains NaN at row 1, column 0"):
        lwr.predict([[0.0, 0.0], [np.nan, 0.0]])
    with pytest.raises(ValueError, match="3 columns, expected 2"):
        lwr.predict(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="one value per row"):
        LocallyWeightedRegression(params).fit(X, y[:4])
    with pytest.raises(ValueError, match="input_scales"):
        LocallyWeightedRegression(params).fit(np.zeros((5, 3)), y)
    with pytest.raises(ValueError, match="bandwidth"):
        LWRParams(0.0, (1.0,))
    with pytest.raises(ValueError, match="input_scales"):
        LWRParams(1.0, (1.0, -2.0))


def test_params_dict_round_trip() -> None:
    p = LWRParams(0.2, (1e-3, 2e5), 1e-4, 50, 3.5)
    assert LWRParams.from_dict(p.to_dict()) == p


def test_variance_estimate_matches_noise_replicates() -> None:
    rng = np.random.default_rng(6)
    X = rng.uniform(-1.0, 1.0, (300, 2))
    truth = X @ [1.0, -2.0]
    params = LWRParams(0.4, (1.0, 1.0), 1e-3)
    q = np.array([[0.2, -0.3]])
    preds, variances = [], []
    for _ in range(200):
        lwr = LocallyWeightedRegression(params).fit(X, truth + 0.1 * rng.standard_normal(300))
        pred, conf = lwr.predict(q, return_confidence=True)
        preds.append(pred[0])
        variances.append(conf.variance[0])
    assert 0.7 < np.mean(variances) / np.var(preds) < 1.4

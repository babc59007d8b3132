"""Baselines for the memory-based learner, and a synthetic data set shaped like the real problem.

:func:`compare_baselines` fits, on one seeded train/test split, a global linear model, k nearest
neighbours, a cubic polynomial ridge regression and (given its parameters) LWR, and returns each
one's RMSE on the held-out points: the numbers that justify LWR over simpler learners.

:func:`synthetic_flow_sharing` is an analytical stand-in for a boom (or bucket) table: two spools
and two cylinder loads on one pump, flow shared by the orifice law, a power-limited pump and a
centre bypass. It is saturating and interacting like the real steady-state response, so the tests
and benchmarks of :mod:`hexgym_lab.mbl.lwr` and :mod:`hexgym.mbl.table` run without the slow reference model.
"""

# Matrix names (X, Xq) follow the statistics notation, hence N803/N806 off.
# ruff: noqa: N803, N806

from __future__ import annotations

from itertools import combinations_with_replacement
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from hexgym_lab.mbl.lwr import LocallyWeightedRegression, LWRParams, as_training_data, holdout_split, rmse

SPOOL_MAX = 0.011  # m
SPOOL_STEP = 0.001  # m: the paper's sampling resolution along spool axes
SYNTH_INPUTS = ("spool_boom", "spool_bucket", "force_boom", "force_bucket")


def synthetic_flow_sharing(
    n: int, seed: int, *, noise: float = 0.01, spool_step: float | None = SPOOL_STEP
) -> tuple[np.ndarray, np.ndarray]:
    """A data set (X (n, 4), y (n,)) like the boom table: spools (m), loads (N) -> boom velocity (m/s).

    Spools are drawn on ``spool_step`` levels within ±11 mm (continuous if None), loads uniformly;
    Gaussian noise of ``noise`` times the clean output's range is added.
    """
    rng = np.random.default_rng(seed)
    s = rng.uniform(-SPOOL_MAX, SPOOL_MAX, size=(n, 2))
    if spool_step:
        s = np.round(s / spool_step) * spool_step
    f = np.column_stack([rng.uniform(-1.0e5, 4.0e5, n), rng.uniform(-0.5e5, 2.0e5, n)])
    X = np.column_stack([s, f])
    y = flow_sharing_velocity(X)
    return X, y + noise * np.ptp(y) * rng.standard_normal(n)


def flow_sharing_velocity(X: np.ndarray) -> np.ndarray:
    """Steady-state velocity of function 1 in a two-function open-centre circuit (the synthetic law).

    Pump pressure p solves ``sum_i Cd a_i sqrt(p - p_i)+ + bypass(p) = min(Q_max, P_max / p)`` (by
    bisection), ``a_i`` opens past a 1.5 mm dead band, ``p_i`` is the load pressure against the
    motion, and the check valve stops flow when ``p < p_i``.
    """
    X = np.asarray(X, dtype=np.float64)
    s, f = X[:, :2], X[:, 2:]
    area_cyl = np.array([0.03, 0.015])  # m^2, boom (two cylinders), bucket
    opening = np.clip((np.abs(s) - 0.0015) / 0.0095, 0.0, 1.0) ** 1.5
    a = 4.0e-4 * opening  # m^2 metering area
    p_load = np.maximum(np.sign(s) * f / area_cyl + 1.0e6, 0.0)  # Pa, resisting load + back pressure
    q_max, power = 0.004, 110e3  # m^3/s, W
    k_orifice = 0.62 * np.sqrt(2.0 / 860.0)
    bypass = 3.0e-4 * (1.0 - opening[:, 0]) * (1.0 - opening[:, 1]) + 2e-6

    def excess(p: np.ndarray) -> np.ndarray:
        q_fun = k_orifice * a * np.sqrt(np.maximum(p[:, None] - p_load, 0.0))
        supply = np.minimum(q_max, power / np.maximum(p, 1.0))
        return q_fun.sum(axis=1) + k_orifice * bypass * np.sqrt(p) - supply

    lo, hi = np.zeros(len(X)), np.full(len(X), 35e6)
    for _ in range(60):  # demand rises and supply falls with p: one root, bisection is robust
        mid = 0.5 * (lo + hi)
        up = excess(mid) < 0.0
        lo, hi = np.where(up, mid, lo), np.where(up, hi, mid)
    p = 0.5 * (lo + hi)
    q1 = k_orifice * a[:, 0] * np.sqrt(np.maximum(p - p_load[:, 0], 0.0))
    return np.sign(s[:, 0]) * q1 / area_cyl[0]


def _standardise(X_train: np.ndarray, X: np.ndarray) -> np.ndarray:
    mu, sd = X_train.mean(axis=0), X_train.std(axis=0)
    return (X - mu) / np.where(sd > 0, sd, 1.0)


def _linear_fit_predict(F_train: np.ndarray, y: np.ndarray, F_test: np.ndarray, ridge: float) -> np.ndarray:
    """Ridge least squares with an unpenalised intercept (features centred)."""
    mu = F_train.mean(axis=0)
    A = F_train - mu
    G = A.T @ A + ridge * len(y) * np.eye(A.shape[1])
    coef = np.linalg.solve(G, A.T @ (y - y.mean()))
    return y.mean() + (F_test - mu) @ coef


def _cubic_features(Z: np.ndarray) -> np.ndarray:
    """All monomials of degree 1..3 of the (standardised) inputs."""
    cols = [
        Z[:, list(c)].prod(axis=1) for deg in (1, 2, 3) for c in combinations_with_replacement(range(Z.shape[1]), deg)
    ]
    return np.column_stack(cols)


def knn_predict(X_train: np.ndarray, y_train: np.ndarray, X_test: np.ndarray, k: int = 8) -> np.ndarray:
    """Mean of the k nearest training outputs, distances on standardised inputs."""
    Z_train, Z_test = _standardise(X_train, X_train), _standardise(X_train, X_test)
    _, idx = cKDTree(Z_train).query(Z_test, k=min(k, len(y_train)))
    return y_train[idx.reshape(len(Z_test), -1)].mean(axis=1)


def compare_baselines(
    X: Any,
    y: Any,
    *,
    fraction: float = 0.2,
    seed: int = 0,
    lwr_params: LWRParams | None = None,
    split: tuple[np.ndarray, np.ndarray] | None = None,
) -> dict[str, float]:
    """Held-out RMSE of simple learners (and of LWR with ``lwr_params``) on one seeded split (or ``split``:
    (train, test) row indices)."""
    X, y = as_training_data(X, y)
    tr, te = split if split is not None else holdout_split(len(y), fraction, seed)
    Xa, ya, Xb, yb = X[tr], y[tr], X[te], y[te]
    out = {
        "global_linear": rmse(yb - _linear_fit_predict(Xa, ya, Xb, 0.0)),
        "knn_8": rmse(yb - knn_predict(Xa, ya, Xb, 8)),
        "cubic_ridge": rmse(
            yb
            - _linear_fit_predict(
                _cubic_features(_standardise(Xa, Xa)), ya, _cubic_features(_standardise(Xa, Xb)), 1e-6
            )
        ),
    }
    if lwr_params is not None:
        out["lwr"] = rmse(yb - LocallyWeightedRegression(lwr_params).fit(Xa, ya).predict(Xb))
    return out

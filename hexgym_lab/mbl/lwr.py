"""Locally weighted linear regression (LWR) with exact leave-one-out model selection.

The memory-based learner of the paper's Sec III: each hydraulic function's steady-state velocity
is predicted from the stored data by a weighted linear fit around the query, and the fit's
parameters are chosen by leave-one-out (LOO) cross-validation, as Vizier's "blackbox" did.

Model. Inputs are divided by per-input ``input_scales`` (so spools in m and forces in N become
comparable); ``d`` is the Euclidean distance in these scaled units. A training point gets the
Gaussian weight ``w = exp(-d^2 / (2 h^2))`` with ``h = bandwidth``. Around each query the model
fits ``y ~ a + b . (z - zbar)`` by weighted least squares, with the ridge penalty
``ridge * W * h^2 * |b|^2`` on the slopes only (``W = sum w``). Scaling the penalty by ``W h^2``,
the kernel's own second moment, makes ``ridge`` dimensionless: 1e-3 is mild, 1 roughly halves the
slopes in dense data, whatever the bandwidth or the amount of data. Centring on the weighted mean
``zbar`` decouples the intercept, so only a d x d symmetric system is solved, by a batched
eigen-decomposition; eigenvalues below 1e-10 of the largest are dropped (minimum-norm slopes), so
a locally degenerate input (all neighbours on one spool level) gets a zero slope, not a blow-up.

Neighbours. A ``scipy.spatial.cKDTree`` on the scaled inputs returns, per query, the points within
``cutoff * h`` (default 4 h), capped at the ``max_neighbours`` nearest. A point beyond the cutoff
would weigh less than ``exp(-cutoff^2 / 2)`` = 3.4e-4 of a point at the query; in uniformly dense
data the kernel mass left out is ``P(chi2_d > cutoff^2)``: 0.3 % for d = 4, 0.7 % for d = 5, so
the prediction (nearly a weighted average) moves by about that fraction of the output's variation
over the kernel (a test bounds the change against cutoff = 12 at 0.5 % of the output range).
Where fewer than ``d + 2`` points lie within the cutoff, the ``d + 2`` nearest are used whatever
their distance, so every query has an answer (in effect the nearest point's value, slopes along
unsupported directions being dropped); its effective sample size then tells the caller that it
lies outside the data. Weights are computed relative to the nearest neighbour (the
fit is invariant to a common factor), so they never underflow.

Confidence. ``predict(..., return_confidence=True)`` also returns, per query, the effective sample
size ``n_eff = W^2 / sum w^2`` (about 1 far from the data; treat < 2 as "outside") and an estimate
of the prediction's variance ``s^2 sum l_i^2``, where ``l_i`` are the weights of the linear smoother
(``yhat = sum l_i y_i``) and ``s^2`` the local weighted residual variance with an ``n_eff``
degrees-of-freedom correction (infinite when ``n_eff`` does not exceed the fitted parameters).

Leave-one-out. :func:`loo_residuals` is exact: for every training point the local model at that
point is refitted with the point's own weight set to zero (and, with ``max_neighbours``, the next
neighbour taking its place). This is a direct refit, not the hat-matrix shortcut
``e_i / (1 - L_ii)``, which is not exact here: the ridge term and the neighbour set both depend on
the left-out point. It costs the same as one prediction per training point (n = 6000, 4 inputs: about 0.5 s on 2 cores).

Model selection. :func:`select_params` minimises the exact LOO RMSE over bandwidth, per-input
scales and ridge (coarse grid, seeded random search, Nelder-Mead, all in log space); for 6000
points with 4-5 inputs it takes 12-14 s on 2 cores (84 LOO evaluations at 1500 rows each, then
the exact LOO over all points). Vectorisation: queries go in chunks through one cKDTree search
and batched numpy fits (einsum / matmul / eigh over a stack of d x d systems), on a thread per
core (numpy and cKDTree release the GIL; 2 threads halve the time on 2 cores).
"""

# Matrix names (X, W, M, Zq) follow the statistics notation of the docstrings, hence N803/N806 off.
# ruff: noqa: N803, N806

from __future__ import annotations

import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import minimize
from scipy.spatial import cKDTree

from hexgym.mbl.lwr_params import LWRParams, as_queries, as_training_data

_EIG_RTOL = 1e-10  # relative eigenvalue floor of the local normal matrix
_CHUNK_ELEMENTS = 400_000  # queries x neighbours per batched solve: bounds memory, keeps caches warm


def _workers(workers: int | None) -> int:
    """The number of threads: the argument, else the cores this process may use (at most 8)."""
    if workers is not None:
        return max(1, int(workers))
    try:
        return max(1, min(8, len(os.sched_getaffinity(0))))
    except AttributeError:  # not Linux
        return max(1, min(8, os.cpu_count() or 1))


class LocalConfidence(NamedTuple):
    """Per-query confidence of an LWR prediction."""

    n_eff: np.ndarray  # effective sample size (sum w)^2 / sum w^2; < 2 means outside the data
    variance: np.ndarray  # estimated variance of the prediction (inf where not estimable)


class _Fit(NamedTuple):
    pred: np.ndarray
    n_eff: np.ndarray
    variance: np.ndarray | None


def _neighbours(
    tree: cKDTree, Zq: np.ndarray, params: LWRParams, exclude: np.ndarray | None, workers: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Squared distances, indices and a validity mask (q, k) of each query's neighbours.

    With ``exclude`` (one training index per query) that point is dropped from its row and the next
    neighbour takes its place, so the rows are exactly the neighbour sets without it.
    """
    n, d = tree.n, tree.m
    extra = 0 if exclude is None else 1
    min_k = min(n, d + 2 + extra)
    max_k = n if params.max_neighbours is None else min(n, params.max_neighbours + extra)
    radius = params.cutoff * params.bandwidth
    counts = tree.query_ball_point(Zq, radius, return_length=True, workers=workers)
    k_row = np.clip(counts, min_k, max(min_k, max_k))
    k = int(k_row.max())
    dist, idx = tree.query(Zq, k=k, workers=workers)
    dist, idx = dist.reshape(len(Zq), k), idx.reshape(len(Zq), k)
    valid = np.arange(k)[None, :] < k_row[:, None]
    if exclude is not None:
        valid &= idx != exclude[:, None]
        valid &= np.cumsum(valid, axis=1) <= (k_row - 1)[:, None]  # if the point was not found, drop the farthest
    return np.where(valid, dist * dist, np.inf), idx, valid


def _solve_local(
    Zn: np.ndarray, yn: np.ndarray, w: np.ndarray, zq: np.ndarray, ridge: float, h: float, with_variance: bool
) -> _Fit:
    """Batched weighted ridge linear fits, one per query: neighbours (q, k, d), weights (q, k)."""
    W = w.sum(axis=1)
    zbar = np.einsum("qk,qkd->qd", w, Zn) / W[:, None]
    ybar = np.einsum("qk,qk->q", w, yn) / W
    Zc = Zn - zbar[:, None, :]
    yc = yn - ybar[:, None]
    wZc = Zc * w[:, :, None]
    M = np.matmul(wZc.transpose(0, 2, 1), Zc)
    d = Zn.shape[2]
    M[:, np.arange(d), np.arange(d)] += (ridge * h * h) * W[:, None]
    g = np.einsum("qkd,qk->qd", wZc, yc)
    evals, evecs = np.linalg.eigh(M)
    floor = _EIG_RTOL * evals[:, -1:]
    keep = (evals > floor) & (evals > 0)
    inv = np.where(keep, 1.0 / np.where(keep, evals, 1.0), 0.0)
    dq = zq - zbar
    # M^+ v = V diag(inv) V^T v, for the gradient (slopes) and for the query offset
    slopes = np.einsum("qij,qj->qi", evecs, inv * np.einsum("qji,qj->qi", evecs, g))
    pred = ybar + np.einsum("qd,qd->q", slopes, dq)
    sum_w2 = np.einsum("qk,qk->q", w, w)
    n_eff = W * W / sum_w2
    if not with_variance:
        return _Fit(pred, n_eff, None)
    u = np.einsum("qij,qj->qi", evecs, inv * np.einsum("qji,qj->qi", evecs, dq))
    lsm = w / W[:, None] + w * np.einsum("qkd,qd->qk", Zc, u)  # smoother weights: pred = sum l y
    resid = yc - np.einsum("qkd,qd->qk", Zc, slopes)
    n_par = keep.sum(axis=1) + 1
    s2 = np.einsum("qk,qk->q", w, resid * resid) / W
    dof_ok = n_eff > n_par + 1e-9
    s2 = np.where(dof_ok, s2 * n_eff / np.where(dof_ok, n_eff - n_par, 1.0), np.inf)
    variance = s2 * np.einsum("qk,qk->q", lsm, lsm)
    return _Fit(pred, n_eff, variance)


def _predict_scaled(
    Z: np.ndarray,
    y: np.ndarray,
    tree: cKDTree,
    Zq: np.ndarray,
    params: LWRParams,
    *,
    exclude: np.ndarray | None = None,
    with_variance: bool = False,
    workers: int | None = None,
) -> _Fit:
    """LWR predictions at scaled queries ``Zq``, in chunks (several threads if there are cores)."""
    nq = len(Zq)
    pred, n_eff = np.empty(nq), np.empty(nq)
    variance = np.empty(nq) if with_variance else None
    if nq == 0:
        return _Fit(pred, n_eff, variance)
    nw = _workers(workers)
    h = params.bandwidth
    rows = 1024  # queries per neighbour search; each is split further to respect the element budget
    starts = range(0, nq, rows)

    def run(start: int) -> None:
        sl = np.arange(start, min(nq, start + rows))
        ex = None if exclude is None else exclude[sl]
        d2, idx, valid = _neighbours(tree, Zq[sl], params, ex, 1)
        k_row = valid.shape[1] - np.argmax(valid[:, ::-1], axis=1)  # last valid column + 1
        for sub in _budget_groups(k_row):
            kk = int(k_row[sub].max())
            dd = d2[sub, :kk]
            w = np.exp(-(dd - dd.min(axis=1, keepdims=True)) / (2.0 * h * h))  # relative to nearest: no underflow
            ii = idx[sub, :kk]
            fit = _solve_local(Z[ii], y[ii], w, Zq[sl[sub]], params.ridge, h, with_variance)
            pred[sl[sub]], n_eff[sl[sub]] = fit.pred, fit.n_eff
            if variance is not None:
                variance[sl[sub]] = fit.variance

    if nw == 1 or len(starts) == 1:
        for s in starts:
            run(s)
    else:
        with ThreadPoolExecutor(nw) as pool:  # numpy and cKDTree release the GIL in the heavy parts
            list(pool.map(run, starts))
    return _Fit(pred, n_eff, variance)


def _budget_groups(k_row: np.ndarray) -> list[np.ndarray]:
    """Rows grouped by neighbour count (least padding), each group under the element budget."""
    order = np.argsort(k_row, kind="stable")
    k_sorted = k_row[order]
    groups, i = [], 0
    while i < len(order):
        # ascending k: rows x (largest k in the group) grows monotonically, so a search finds the cut
        cost = k_sorted[i:] * np.arange(1, len(order) - i + 1)
        j = i + max(1, int(np.searchsorted(cost, _CHUNK_ELEMENTS, side="right")))
        groups.append(order[i:j])
        i = j
    return groups


class LocallyWeightedRegression:
    """Locally weighted linear regression: a memory of (X, y) and a local fit per query.

    Example::

        lwr = LocallyWeightedRegression(LWRParams(0.5, (1e-3, 1e5))).fit(X, y)
        v, conf = lwr.predict(Xq, return_confidence=True)
        outside = conf.n_eff < 2
    """

    def __init__(self, params: LWRParams, *, workers: int | None = None) -> None:
        self.params = params
        self.workers = workers
        self._Z: np.ndarray | None = None
        self._y: np.ndarray | None = None
        self._tree: cKDTree | None = None

    @property
    def n_points(self) -> int:
        """The number of stored training points (0 before :meth:`fit`)."""
        return 0 if self._y is None else len(self._y)

    def fit(self, X: Any, y: Any) -> LocallyWeightedRegression:
        """Store the training data (n, d) and (n,) and build the neighbour tree; returns self."""
        X, y = as_training_data(X, y)
        if X.shape[1] != self.params.n_inputs:
            raise ValueError(f"X has {X.shape[1]} columns but the parameters have {self.params.n_inputs} input_scales")
        self._Z = X / np.asarray(self.params.input_scales)
        self._y = y.copy()
        self._tree = cKDTree(self._Z)
        return self

    def predict(self, Xq: Any, return_confidence: bool = False) -> np.ndarray | tuple[np.ndarray, LocalConfidence]:
        """Predictions at queries ``Xq`` (q, d) (a single query may be 1-D).

        With ``return_confidence`` also a :class:`LocalConfidence` (effective sample size, variance).
        """
        if self._tree is None:
            raise RuntimeError("LocallyWeightedRegression.predict called before fit")
        Xq = as_queries("query", Xq, self.params.n_inputs)
        Zq = Xq / np.asarray(self.params.input_scales)
        fit = _predict_scaled(
            self._Z, self._y, self._tree, Zq, self.params, with_variance=return_confidence, workers=self.workers
        )
        if return_confidence:
            return fit.pred, LocalConfidence(fit.n_eff, fit.variance)
        return fit.pred


def loo_predictions(X: Any, y: Any, params: LWRParams, *, rows: Any = None, workers: int | None = None) -> np.ndarray:
    """Exact leave-one-out predictions: at each training point (or at ``rows``), the fit without it."""
    X, y = as_training_data(X, y)
    Z = X / np.asarray(params.input_scales)
    rows = np.arange(len(y)) if rows is None else np.asarray(rows, dtype=np.intp)
    if len(y) < 2:
        raise ValueError("leave-one-out needs at least 2 points")
    tree = cKDTree(Z)
    return _predict_scaled(Z, y, tree, Z[rows], params, exclude=rows, workers=workers).pred


def loo_residuals(X: Any, y: Any, params: LWRParams, *, rows: Any = None, workers: int | None = None) -> np.ndarray:
    """Exact leave-one-out residuals ``y_i - yhat_{-i}(x_i)`` for every training point (or ``rows``)."""
    X, y = as_training_data(X, y)
    rows_ = np.arange(len(y)) if rows is None else np.asarray(rows, dtype=np.intp)
    return y[rows_] - loo_predictions(X, y, params, rows=rows_, workers=workers)


def rmse(residuals: np.ndarray) -> float:
    """Root mean square of residuals."""
    return float(np.sqrt(np.mean(np.square(residuals))))


def holdout_split(n: int, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random (train, test) index arrays, each sorted, with ``round(fraction * n)`` test points."""
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction must be in (0, 1), got {fraction}")
    n_test = int(round(fraction * n))
    if n_test < 1 or n_test >= n:
        raise ValueError(f"a holdout of {fraction} of {n} points leaves an empty train or test set")
    perm = np.random.default_rng(seed).permutation(n)
    return np.sort(perm[n_test:]), np.sort(perm[:n_test])


# ---------------------------------------------------------------- model selection


@dataclass
class SelectionReport:
    """What :func:`select_params` did and found."""

    loo_rmse: float  # exact LOO RMSE on the full data with the chosen parameters
    loo_rmse_initial: float  # the same for the initial guess
    search_rmse: float  # the objective at the optimum (LOO RMSE at the search rows)
    n_evaluations: int
    n_search_rows: int
    seconds: float
    history: list[tuple[dict[str, Any], float]] = field(default_factory=list)  # (params, search RMSE)


def default_scales(X: np.ndarray) -> np.ndarray:
    """Per-input standard deviations (1 for a constant input): the search's starting scales."""
    s = np.std(X, axis=0)
    return np.where(s > 0, s, 1.0)


def _zero_sum_basis(d: int) -> np.ndarray:
    """An orthonormal (d, d-1) basis of zero-sum vectors: relative scales without the redundant overall factor."""
    if d == 1:
        return np.zeros((1, 0))
    q, _ = np.linalg.qr(np.eye(d) - 1.0 / d)
    return q[:, : d - 1]


class _Objective:
    """LOO RMSE at fixed search rows as a function of theta = (log h, log ridge, relative log scales)."""

    def __init__(self, X: np.ndarray, y: np.ndarray, rows: np.ndarray, base: np.ndarray, template: LWRParams, workers):
        self.X, self.y, self.rows, self.base = X, y, rows, base
        self.basis = _zero_sum_basis(X.shape[1])
        self.template = template
        self.workers = workers
        self.history: list[tuple[dict[str, Any], float]] = []
        self.cache: dict[tuple[float, ...], float] = {}

    def params(self, theta: np.ndarray) -> LWRParams:
        log_h, log_r = np.clip(theta[:2], [-7.0, -25.0], [3.0, 3.0])
        scales = self.base * np.exp(np.clip(self.basis @ theta[2:], -12.0, 12.0))
        t = self.template
        return LWRParams(math.exp(log_h), tuple(scales), math.exp(log_r), t.max_neighbours, t.cutoff)

    def __call__(self, theta: np.ndarray) -> float:
        key = tuple(np.round(theta, 12))
        if key not in self.cache:
            p = self.params(np.asarray(theta, dtype=np.float64))
            value = rmse(loo_residuals(self.X, self.y, p, rows=self.rows, workers=self.workers))
            self.cache[key] = value
            self.history.append((p.to_dict(), value))
        return self.cache[key]


def select_params(
    X: Any,
    y: Any,
    *,
    seed: int,
    initial: LWRParams | None = None,
    n_search_rows: int = 1500,
    bandwidths: tuple[float, ...] = (0.05, 0.1, 0.2, 0.35, 0.6, 1.0),
    ridges: tuple[float, ...] = (1e-6, 1e-2),
    n_random: int = 12,
    max_refine: int = 60,
    workers: int | None = None,
) -> tuple[LWRParams, SelectionReport]:
    """Choose bandwidth, per-input scales and ridge by minimising the leave-one-out RMSE.

    Like Vizier's blackbox, in three stages, all in log space and deterministic given ``seed``:
    (1) a coarse grid over bandwidth x ridge with the starting scales (the input standard deviations,
    or ``initial.input_scales``), plus ``initial`` itself; (2) ``n_random`` seeded random points
    around the best (bandwidth x/÷ 2, each scale x/÷ 3, ridge x/÷ 30); (3) Nelder-Mead from the best,
    at most ``max_refine`` evaluations. The overall scale factor is redundant with the bandwidth,
    so the scales are searched with their geometric mean fixed.

    The objective is the exact LOO RMSE at ``n_search_rows`` seeded random training points, each
    left out of a fit on all the others (the full data stays in memory, so the estimate is unbiased
    for the full LOO RMSE; no subsampling bias in the bandwidth). The report's ``loo_rmse`` is the
    exact LOO RMSE over every point with the chosen parameters.
    """
    t0 = time.perf_counter()
    X, y = as_training_data(X, y)
    n, d = X.shape
    if n < d + 3:
        raise ValueError(f"model selection needs more than {d + 2} points, got {n}")
    rng = np.random.default_rng(seed)
    rows = np.sort(rng.choice(n, size=min(n, n_search_rows), replace=False))
    template = initial or LWRParams(0.3, tuple(default_scales(X)))
    if template.n_inputs != d:
        raise ValueError(f"initial has {template.n_inputs} input_scales, X has {d} columns")
    base = np.asarray(template.input_scales) / _geo_mean_ratio(np.asarray(template.input_scales), default_scales(X))
    obj = _Objective(X, y, rows, base, template, workers)
    theta0 = _theta_of(template, base, obj.basis)

    best = theta0.copy()
    best_val = obj(theta0)
    for h in bandwidths:  # stage 1: coarse grid, rescaled to the starting parameters' units
        for r in ridges:
            th = theta0.copy()
            th[0], th[1] = math.log(h), math.log(r)
            if (v := obj(th)) < best_val:
                best, best_val = th, v
    centre = best.copy()
    for _ in range(n_random):  # stage 2: random search around the best grid point
        th = centre.copy()
        th[0] += rng.uniform(-math.log(2.0), math.log(2.0))
        th[1] += rng.uniform(-math.log(30.0), math.log(30.0))
        th[2:] = obj.basis.T @ rng.uniform(-math.log(3.0), math.log(3.0), size=d) + centre[2:]
        if (v := obj(th)) < best_val:
            best, best_val = th, v
    if max_refine > 0:  # stage 3: local Nelder-Mead refinement
        simplex = _initial_simplex(best, steps=np.r_[0.25, 1.5, np.full(d - 1, 0.4)])
        res = minimize(
            obj,
            best,
            method="Nelder-Mead",
            options={"maxfev": max_refine, "initial_simplex": simplex, "xatol": 0.02, "fatol": 1e-4 * best_val},
        )
        if res.fun < best_val:
            best, best_val = res.x, float(res.fun)

    chosen = obj.params(best)
    report = SelectionReport(
        loo_rmse=rmse(loo_residuals(X, y, chosen, workers=workers)),
        loo_rmse_initial=rmse(loo_residuals(X, y, template, workers=workers)),
        search_rmse=best_val,
        n_evaluations=len(obj.history),
        n_search_rows=len(rows),
        seconds=0.0,
        history=obj.history,
    )
    report.seconds = time.perf_counter() - t0
    return chosen, report


def _geo_mean_ratio(scales: np.ndarray, ref: np.ndarray) -> float:
    """Geometric mean of scales / ref: the overall factor the bandwidth absorbs."""
    return float(np.exp(np.mean(np.log(scales / ref))))


def _theta_of(params: LWRParams, base: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """Search coordinates of ``params``, with the scales' overall factor moved into the bandwidth."""
    rel = np.log(np.asarray(params.input_scales) / base)
    factor = float(np.mean(rel))  # scales = base * exp(factor + zero-sum part); h absorbs the factor
    ridge = max(params.ridge, 1e-11)
    return np.r_[math.log(params.bandwidth) + factor, math.log(ridge), basis.T @ (rel - factor)]


def _initial_simplex(x0: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Nelder-Mead start: x0 and one step along each coordinate."""
    simplex = np.tile(x0, (len(x0) + 1, 1))
    simplex[1:] += np.diag(steps[: len(x0)])
    return simplex

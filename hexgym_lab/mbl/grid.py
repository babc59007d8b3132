"""Building an MBL table: a fitted LWR evaluated on a grid over its inputs, and measured (offline).

See :mod:`hexgym.mbl.table` for the grid's design, the file format and the lookup.
"""

# ruff: noqa: N803, N806 - X follows the statistics notation

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from hexgym.mbl.lwr_params import LWRParams
from hexgym.mbl.table import MBLTable, dataset_hash
from hexgym_lab.mbl.lwr import (
    LocallyWeightedRegression,
    as_queries,
    as_training_data,
    holdout_split,
    loo_residuals,
    rmse,
)


def suggest_axes(
    X: Any,
    params: LWRParams,
    *,
    steps: tuple[float | None, ...] | None = None,
    nodes_per_bandwidth: float = 1.0,
    max_nodes: int = 41,
    max_total: int = 500_000,
) -> tuple[np.ndarray, ...]:
    """Uniform grid axes over the data's range, one per input.

    An input with a ``steps`` entry (e.g. 0.001 m for spools) gets nodes on multiples of that step
    covering its data; the others get ``nodes_per_bandwidth`` nodes per kernel width
    (``bandwidth * input_scale``), between 2 and ``max_nodes``. If the grid would exceed
    ``max_total`` nodes, the axes without a step are thinned in proportion.
    """
    X = as_queries("X", X, params.n_inputs)
    d = X.shape[1]
    steps = steps or (None,) * d
    if len(steps) != d:
        raise ValueError(f"steps has {len(steps)} entries, X has {d} columns")
    lo, hi = X.min(axis=0), X.max(axis=0)
    counts = [
        _stepped_count(lo[j], hi[j], steps[j])
        if steps[j]
        else _free_count(hi[j] - lo[j], params.bandwidth * params.input_scales[j] / nodes_per_bandwidth, max_nodes)
        for j in range(d)
    ]
    free = [j for j in range(d) if not steps[j]]
    total = math.prod(counts)
    if total > max_total and free:
        shrink = (max_total / total) ** (1.0 / len(free))
        for j in free:
            counts[j] = max(2, int(counts[j] * shrink))
    return tuple(
        _stepped_axis(lo[j], hi[j], steps[j]) if steps[j] else np.linspace(lo[j], hi[j], counts[j]) for j in range(d)
    )


def _free_count(span: float, spacing: float, max_nodes: int) -> int:
    return int(np.clip(math.ceil(span / spacing) + 1 if span > 0 else 2, 2, max_nodes))


def _stepped_axis(lo: float, hi: float, step: float) -> np.ndarray:
    """Multiples of ``step`` covering [lo, hi] (a tolerance keeps 0.011 / 0.001 at 11, not 12)."""
    i0, i1 = math.floor(lo / step + 1e-6), math.ceil(hi / step - 1e-6)
    return np.arange(i0, max(i1, i0 + 1) + 1) * step


def _stepped_count(lo: float, hi: float, step: float) -> int:
    return len(_stepped_axis(lo, hi, step))


def grid_points(axes: tuple[np.ndarray, ...]) -> np.ndarray:
    """All grid nodes as rows (N, d), in the C order of the values array."""
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.column_stack([m.reshape(-1) for m in mesh])


def build_table(
    name: str,
    inputs: tuple[str, ...],
    output: str,
    X: Any,
    y: Any,
    params: LWRParams,
    axes: tuple[np.ndarray, ...] | None = None,
    *,
    holdout_fraction: float = 0.2,
    seed: int = 0,
    split: tuple[np.ndarray, np.ndarray] | None = None,
    workers: int | None = None,
) -> MBLTable:
    """Fit LWR to (X, y), evaluate it on the grid ``axes`` (default :func:`suggest_axes`), measure it.

    Metrics: ``loo_rmse_rel`` (exact LOO on all points), ``holdout_rmse_rel`` (LWR fitted without a
    seeded ``holdout_fraction`` of the points, or the test rows of ``split`` = (train, test) indices,
    tested on them), ``grid_rmse_rel`` (table vs direct
    LWR at the held-out points, each moved by a random fraction of a grid cell so that the test
    does not sit on nodes), ``grid_min_confidence``, ``n_points``, ``n_nodes``, ``output_range``;
    every ``*_rel`` is divided by ``output_range`` (max - min of y).
    """
    X, y = as_training_data(X, y)
    if len(inputs) != X.shape[1]:
        raise ValueError(f"{len(inputs)} input names for {X.shape[1]} columns of X")
    axes = suggest_axes(X, params) if axes is None else tuple(np.asarray(a, dtype=np.float64) for a in axes)
    lwr = LocallyWeightedRegression(params, workers=workers).fit(X, y)
    values, conf = lwr.predict(grid_points(axes), return_confidence=True)
    shape = tuple(len(a) for a in axes)
    table = MBLTable(name, tuple(inputs), output, axes, values.reshape(shape), conf.n_eff.reshape(shape), params)
    span = float(np.ptp(y)) or 1.0
    train, test = split if split is not None else holdout_split(len(y), holdout_fraction, seed)
    held = LocallyWeightedRegression(params, workers=workers).fit(X[train], y[train]).predict(X[test])
    probe = _jitter_in_cells(X[test], axes, np.random.default_rng(seed + 1))
    metrics = {
        "loo_rmse_rel": rmse(loo_residuals(X, y, params, workers=workers)) / span,
        "holdout_rmse_rel": rmse(y[test] - held) / span,
        "grid_rmse_rel": rmse(table.lookup(probe) - lwr.predict(probe)) / span,
        "grid_min_confidence": float(conf.n_eff.min()),
        "n_points": len(y),
        "n_nodes": int(values.size),
        "output_range": span,
    }
    return MBLTable(
        name, tuple(inputs), output, axes, table.values, table.confidence, params, metrics, dataset_hash(X, y)
    )


def _jitter_in_cells(X: np.ndarray, axes: tuple[np.ndarray, ...], rng: np.random.Generator) -> np.ndarray:
    """Points moved by up to ±half a local grid cell per axis, kept inside the grid."""
    out = X.copy()
    for j, a in enumerate(axes):
        i = np.clip(np.searchsorted(a, X[:, j]) - 1, 0, len(a) - 2)
        out[:, j] += rng.uniform(-0.5, 0.5, len(X)) * (a[i + 1] - a[i])
        out[:, j] = np.clip(out[:, j], a[0], a[-1])
    return out


def benchmark_lookup(
    table: MBLTable, lwr: LocallyWeightedRegression, Xq: np.ndarray, *, repeats: int = 200
) -> dict[str, float]:
    """Seconds per query: direct LWR and table, batched over ``Xq`` and one query at a time.

    Also scipy's RegularGridInterpolator (the reference) per single query, for comparison.
    """
    from scipy.interpolate import RegularGridInterpolator

    Xq = as_queries("Xq", Xq, len(table.inputs))
    rgi = RegularGridInterpolator(table.axes, table.values, method="linear", bounds_error=False, fill_value=None)
    singles = [row.tolist() for row in Xq[: max(1, min(len(Xq), repeats))]]

    def per_call(fn: Any, items: list[Any]) -> float:
        t0 = time.perf_counter()
        for item in items:
            fn(item)
        return (time.perf_counter() - t0) / len(items)

    t0 = time.perf_counter()
    lwr.predict(Xq)
    direct_batch = (time.perf_counter() - t0) / len(Xq)
    t0 = time.perf_counter()
    table.lookup(Xq)
    grid_batch = (time.perf_counter() - t0) / len(Xq)
    return {
        "direct_batch_s": direct_batch,
        "grid_batch_s": grid_batch,
        "direct_single_s": per_call(lambda x: lwr.predict(np.asarray([x])), singles[:50]),
        "grid_single_s": per_call(table, singles),
        "grid_single_numpy_s": per_call(lambda x: table.lookup(np.asarray([x])), singles),
        "rgi_single_s": per_call(lambda x: rgi(np.asarray([x])), singles),
    }

"""Fit the four MBL tables from the collected data sets: ``hexgym fit`` and ``hexgym tables``.

Per table (paper Sec III): split off a seeded held-out set; choose the LWR's kernel width,
per-input scales and ridge by exact leave-one-out on the rest (:func:`hexgym.mbl.lwr.select_params`);
evaluate the LWR on a grid and store it (:func:`hexgym.mbl.grid.build_table`), recording the exact
LOO error, the held-out error of the LWR fitted without the held-out points, the grid's
interpolation loss and the same split's baselines (global linear, k nearest neighbours, cubic
ridge). The shipped table is built from all points. Deterministic for a given data set and seed.
"""

# ruff: noqa: N803, N806 - X follows the statistics notation

from __future__ import annotations

from pathlib import Path

import numpy as np

from hexgym.mbl.baselines import compare_baselines
from hexgym.mbl.grid import build_table, suggest_axes
from hexgym.mbl.lwr import holdout_split, select_params
from hexgym.mbl.schema import TABLES, check_table_schema
from hexgym.mbl.table import MBLTable, load_tables, table_path

SPOOL_STEP = 0.001  # m: the data's spool levels (1 mm, as the paper sampled)
HOLDOUT_FRACTION = 0.2
# Grid nodes per table: spool axes at 1 mm take 23 x 23 nodes; the rest share what is left.
# The five-input swing table needs more to resolve its loads and rate (measured: grid_rmse_rel).
MAX_GRID_NODES = {"boom": 60_000, "bucket": 60_000, "stick": 60_000, "swing": 200_000}
MAX_POINTS = 12_000  # a seeded subsample above this: LOO selection and the grid stay minutes, not hours


def load_table_data(path: str | Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(X, y) of a collected data set, checked against the table's expected inputs and output."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"data set for table {name!r} not found: {path} (run `hexgym collect`)")
    with np.load(path, allow_pickle=False) as data:
        inputs, output = tuple(str(s) for s in data["inputs"]), str(data["output"])
        X, y = np.asarray(data["X"], dtype=float), np.asarray(data["y"], dtype=float)
    check_table_schema(str(path), name, inputs, output)
    return X, y


def fit_table(name: str, X: np.ndarray, y: np.ndarray, seed: int = 0) -> MBLTable:
    """Select parameters by LOO on the training split, build the table, measure it."""
    inputs, output = TABLES[name].inputs, TABLES[name].output
    train, _ = holdout_split(len(y), HOLDOUT_FRACTION, seed)
    params, _ = select_params(X[train], y[train], seed=seed)
    steps = tuple(SPOOL_STEP if n.endswith("_spool_m") else None for n in inputs)
    axes = suggest_axes(X, params, steps=steps, max_total=MAX_GRID_NODES[name])
    table = build_table(name, inputs, output, X, y, params, axes, holdout_fraction=HOLDOUT_FRACTION, seed=seed)
    span = table.metrics["output_range"]
    baselines = compare_baselines(X, y, fraction=HOLDOUT_FRACTION, seed=seed)
    table.metrics.update({f"baseline_{k}_rmse_rel": v / span for k, v in baselines.items()})
    return table


def fit_all(
    data_dir: str | Path, out_dir: str | Path | None = None, seed: int = 0, names: tuple[str, ...] = tuple(TABLES)
) -> dict[str, Path]:
    """Fit every table from ``data_dir/<name>.npz`` and write ``out_dir/<name>.npz``."""
    written = {}
    for name in names:
        X, y = fitted_points(*load_table_data(Path(data_dir) / f"{name}.npz", name), seed=seed)
        written[name] = fit_table(name, X, y, seed=seed).save(table_path(name, out_dir))
    return written


def fitted_points(X: np.ndarray, y: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The points a table is fitted from: all of them, or a seeded ``MAX_POINTS`` subsample."""
    if len(y) <= MAX_POINTS:  # the swing table is sampled along trajectories: many more points
        return X, y
    keep = np.sort(np.random.default_rng(seed).choice(len(y), MAX_POINTS, replace=False))
    return X[keep], y[keep]


def tables_summary(directory: str | Path | None = None) -> list[dict[str, object]]:
    """Per table: inputs, output, n_points, chosen parameters and the accuracy figures."""
    out = []
    for name, table in load_tables(directory).items():
        metrics = table.metrics
        out.append(
            {
                "name": name,
                "inputs": list(table.inputs),
                "output": table.output,
                "n_points": int(metrics["n_points"]),
                "params": table.params.to_dict(),
                "loo_rmse_rel": metrics["loo_rmse_rel"],
                "holdout_rmse_rel": metrics["holdout_rmse_rel"],
                "grid_rmse_rel": metrics["grid_rmse_rel"],
                "baselines_holdout_rmse_rel": {
                    k.removeprefix("baseline_").removesuffix("_rmse_rel"): v
                    for k, v in metrics.items()
                    if k.startswith("baseline_")
                },
                "grid_shape": list(table.shape),
                "data_hash": table.data_hash,
            }
        )
    return out


def lookup_benchmark(data_dir: str | Path, directory: str | Path | None = None, seed: int = 0) -> dict[str, dict]:
    """Seconds per query of each table against its direct LWR, at held-out data points."""
    from hexgym.mbl.grid import benchmark_lookup
    from hexgym.mbl.lwr import LocallyWeightedRegression

    out = {}
    for name, table in load_tables(directory).items():
        X, y = load_table_data(Path(data_dir) / f"{name}.npz", name)
        train, test = holdout_split(len(y), HOLDOUT_FRACTION, seed)
        lwr = LocallyWeightedRegression(table.params).fit(X[train][:MAX_POINTS], y[train][:MAX_POINTS])
        out[name] = benchmark_lookup(table, lwr, X[test][:200], repeats=3)
    return out

"""Fit the four MBL tables from the collected data sets: ``hexgym fit`` and ``hexgym tables``.

Per table (paper Sec III): split off a seeded held-out set; choose the LWR's kernel width,
per-input scales and ridge by exact leave-one-out on the rest (:func:`hexgym_lab.mbl.lwr.select_params`);
evaluate the LWR on a grid and store it (:func:`hexgym_lab.mbl.grid.build_table`), recording the exact
LOO error, the held-out error of the LWR fitted without the held-out points, the grid's
interpolation loss and the same split's baselines (global linear, k nearest neighbours, cubic
ridge). The shipped table is built from all points. Deterministic for a given data set and seed.
"""

# ruff: noqa: N803, N806 - X follows the statistics notation

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hexgym.mbl.schema import DEFAULT_TABLE_SET, TABLE_SETS, check_table_schema
from hexgym.mbl.table import MBLTable, load_tables, table_path
from hexgym_lab.mbl.baselines import compare_baselines
from hexgym_lab.mbl.grid import build_table, suggest_axes
from hexgym_lab.mbl.lwr import select_params

SPOOL_STEP = 0.001  # m: the data's spool levels (1 mm, as the paper sampled)
HOLDOUT_FRACTION = 0.2  # of the episodes
# Grid nodes per table: spool axes at 1 mm take 23 x 23 nodes; the rest share what is left. The
# swing tables need more to resolve their loads and rate (measured: grid_rmse_rel).
MAX_GRID_NODES = {
    "paper": {"boom": 60_000, "bucket": 60_000, "stick": 60_000, "swing": 200_000},
}
# A one-input table (the circuit set's valve passages over their spool, sampled at any spool position
# along operator-like motion) gets this many nodes per kernel width, up to ONE_INPUT_NODES in all
# (instead of a MAX_GRID_NODES budget): 0.02 mm apart over +-11 mm, since the leave-one-out picks kernels
# of 0.02-0.12 mm and the bypass falls from 143 to 15 mm^2 within 1.5 mm of spool.
ONE_INPUT_NODES_PER_WIDTH = 4.0
ONE_INPUT_NODES = 1101
MAX_POINTS = 12_000  # a seeded subsample above this: LOO selection and the grid stay minutes, not hours


@dataclass(frozen=True)
class TableData:
    """A table's collected samples: inputs X (n, d), output y (n,), and each row's episode."""

    X: np.ndarray
    y: np.ndarray
    episode: np.ndarray


def load_table_data(path: str | Path, name: str, table_set: str = DEFAULT_TABLE_SET) -> TableData:
    """A collected data set, checked against the table's inputs and output in ``table_set``."""
    from hexgym_lab.mbl.datafile import check_dataset_file

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"data set for table {name!r} not found: {path} (run `hexgym collect`)")
    check_dataset_file(path)  # arrays, shapes, finite numbers, two episodes at least: named, before the work
    with np.load(path, allow_pickle=False) as data:
        inputs, output = tuple(str(s) for s in data["inputs"]), str(data["output"])
        X, y = np.asarray(data["X"], dtype=float), np.asarray(data["y"], dtype=float)
        episode = np.asarray(data["episode"], dtype=np.int64)
    check_table_schema(str(path), name, inputs, output, table_set)
    return TableData(X, y, episode)


def episode_split(episode: np.ndarray, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(train, test) row indices holding out a seeded ``fraction`` of whole episodes: rows of one
    episode (two windows of a segment, swing samples 0.1 s apart) are correlated, so a split by rows
    would test on near-copies of training rows."""
    episodes = np.unique(episode)
    n_test = max(1, round(fraction * len(episodes))) if len(episodes) > 1 else 0
    held = np.random.default_rng(seed).permutation(episodes)[:n_test]
    test = np.isin(episode, held)
    return np.flatnonzero(~test), np.flatnonzero(test)


def fit_table(
    name: str,
    data: TableData,
    seed: int = 0,
    table_set: str = DEFAULT_TABLE_SET,
    split: tuple[np.ndarray, np.ndarray] | None = None,
) -> MBLTable:
    """Select parameters by LOO within the training episodes, build the table from all rows, measure it
    on the held-out episodes (``split``: the (train, test) row indices, default a seeded
    :data:`HOLDOUT_FRACTION` of the episodes)."""
    spec = TABLE_SETS[table_set][name]
    X, y = data.X, data.y
    split = episode_split(data.episode, HOLDOUT_FRACTION, seed) if split is None else split
    params, _ = select_params(X[split[0]], y[split[0]], seed=seed)
    if len(spec.inputs) == 1:
        axes = suggest_axes(X, params, nodes_per_bandwidth=ONE_INPUT_NODES_PER_WIDTH, max_nodes=ONE_INPUT_NODES)
    else:
        steps = tuple(SPOOL_STEP if n.endswith("_spool_m") else None for n in spec.inputs)
        axes = suggest_axes(X, params, steps=steps, max_total=MAX_GRID_NODES[table_set][name])
    table = build_table(name, spec.inputs, spec.output, X, y, params, axes, seed=seed, split=split)
    span = table.metrics["output_range"]
    baselines = compare_baselines(X, y, seed=seed, split=split)
    table.metrics.update({f"baseline_{k}_rmse_rel": v / span for k, v in baselines.items()})
    table.metrics["holdout"] = "episodes"
    return table


def fit_all(
    data_dir: str | Path,
    out_dir: str | Path | None = None,
    seed: int = 0,
    names: tuple[str, ...] | None = None,
    table_set: str = DEFAULT_TABLE_SET,
) -> dict[str, Path]:
    """Fit every table of ``table_set`` (or ``names``) from ``data_dir/<name>.npz``; write ``out_dir/<name>.npz``.

    The tables are written together once all are fitted (:func:`hexgym.files.staged_dir`): a fit that fails or
    is interrupted on one table leaves the folder's previous set as it was, never a mix of old and new. A
    folder holding collected data sets of these names is refused (they would be replaced).
    """
    from hexgym.files import staged_dir
    from hexgym_lab.mbl.datafile import refuse_other_npz
    from hexgym_lab.progress import track

    names = names or tuple(TABLE_SETS[table_set])
    directory = table_path(names[0], out_dir, table_set).parent
    refuse_other_npz(directory, names, "table")
    fitted = {}
    for name in track(names, "fit", "table"):
        data = fitted_points(load_table_data(Path(data_dir) / f"{name}.npz", name, table_set), seed=seed)
        fitted[name] = fit_table(name, data, seed=seed, table_set=table_set)
    with staged_dir(directory) as staging:
        for name, table in fitted.items():
            table.save(staging / f"{name}.npz")
    return {name: directory / f"{name}.npz" for name in fitted}


def fitted_points(data: TableData, seed: int = 0) -> TableData:
    """The rows a table is fitted from: all of them, or a seeded ``MAX_POINTS`` subsample."""
    if len(data.y) <= MAX_POINTS:  # the swing tables are sampled along trajectories: many more rows
        return data
    keep = np.sort(np.random.default_rng(seed).choice(len(data.y), MAX_POINTS, replace=False))
    return TableData(data.X[keep], data.y[keep], data.episode[keep])


def tables_summary(directory: str | Path | None = None, table_set: str = DEFAULT_TABLE_SET) -> list[dict[str, object]]:
    """Per table: inputs, output, n_points, chosen parameters and the accuracy figures (``holdout``: how the
    held-out rows were chosen, whole ``episodes`` or single ``rows``)."""
    out = []
    for name, table in load_tables(directory, table_set).items():
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
                "holdout": metrics.get("holdout", "rows"),
                "grid_shape": list(table.shape),
                "data_hash": table.data_hash,
            }
        )
    return out


def lookup_benchmark(
    data_dir: str | Path, directory: str | Path | None = None, seed: int = 0, table_set: str = DEFAULT_TABLE_SET
) -> dict[str, dict]:
    """Seconds per query of each table against its direct LWR, at held-out data points."""
    from hexgym_lab.mbl.grid import benchmark_lookup
    from hexgym_lab.mbl.lwr import LocallyWeightedRegression

    out = {}
    for name, table in load_tables(directory, table_set).items():
        data = load_table_data(Path(data_dir) / f"{name}.npz", name, table_set)
        X, y = data.X, data.y
        train, test = episode_split(data.episode, HOLDOUT_FRACTION, seed)
        lwr = LocallyWeightedRegression(table.params).fit(X[train][:MAX_POINTS], y[train][:MAX_POINTS])
        out[name] = benchmark_lookup(table, lwr, X[test][:200], repeats=3)
    return out

"""``hexgym fit --logs DIR``: the circuit model's learned valve fitted to a machine's own logs.

Each log in ``DIR`` (CSV machine logs, :mod:`.signals`) is read and checked (:func:`.checks.check_log`); one that
cannot be trusted is left out, its errors printed one a line. The rest become rows for the valve's identification
(:mod:`.derive`: smoothed rates, the NFC signal and pump flows estimated), each row one sample of the passages that
meter clearly at that instant (:func:`hexgym.mbl.valve.identify_areas`). Each passage's table is fitted by the same
LWR and leave-one-out selection as ``hexgym fit --data`` (:func:`hexgym_lab.mbl.fit.fit_table`), a seeded share of
whole logs held out for its error. Where the logs do not reach (spool bins of :data:`BIN_MM` with fewer than
:data:`MIN_BIN_SAMPLES` samples) the packaged table's values, scaled by the measured-to-packaged ratio of the passage
(:func:`packaged_ratio`), stand in as points, so a table never extrapolates;
a passage with fewer than :data:`MIN_SAMPLES` samples or from fewer than :data:`MIN_LOGS` logs keeps the packaged
table, and the bypass tables are always kept (no NFC signal pressure is logged). The model directory (``.npz``
tables of the ``circuit`` set and ``provenance.json``) is written as a whole (:func:`hexgym.files.staged_dir`).
"""

# ruff: noqa: N803, N806 - X follows the statistics notation

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hexgym.files import staged_dir
from hexgym.machine import parameters as p
from hexgym.mbl.schema import TABLE_SETS
from hexgym.mbl.table import MBLTable, load_tables, packaged_tables_dir
from hexgym.mbl.valve import ReliefSettings
from hexgym_lab.machine_logs import MCAP_SUFFIXES, derive
from hexgym_lab.machine_logs.checks import check_log, trusted
from hexgym_lab.machine_logs.reliefs import identify_reliefs, relief_hydraulics
from hexgym_lab.mbl.fit import HOLDOUT_FRACTION, MAX_POINTS, TableData, fit_table
from hexgym_lab.progress import track

TABLE_SET = "circuit"
PROVENANCE = "provenance.json"
MIN_SAMPLES = 60  # a passage's measured samples: fewer keep the packaged table
MIN_LOGS = 3  # ... from at least this many logs (one held out, one for the leave-one-out to see another log)
BIN_MM = 0.5  # spool bins of the coverage and of the packaged stand-in points
MIN_BIN_SAMPLES = 3  # a bin with fewer measured samples is a gap (the packaged table's points fill it)
PRIOR_PER_BIN = 3  # the packaged table's points per gap bin
POOR_HOLDOUT = 0.10  # a table whose held-out error exceeds this share of its range is warned of
LOG_SUFFIXES = (".csv", *MCAP_SUFFIXES)
TOE_MM = 1.0  # mm of spool past the dead band where the packaged table's shape stands in (see _past_toe)
LEAKAGE_NOT_IDENTIFIED = "not determined by the logs: the packaged leaks stand"


def _relief_settings(unit_reliefs: dict) -> ReliefSettings:
    """The settings the identification keeps clear of: the identified ones, the data sheet's for the rest."""
    line = dict(p.LINE_RELIEF) | unit_reliefs.get("line_pa", {})
    main, swing = unit_reliefs.get("main_pa", p.MAIN_RELIEF), unit_reliefs.get("swing_pa", p.SWING_RELIEF)
    return ReliefSettings(main, swing, line)


def log_files(directory: str | Path) -> list[Path]:
    """The machine logs in ``directory`` (CSV and MCAP, by name); ValueError naming it where there are none."""
    if not Path(directory).is_dir():
        raise ValueError(f"--logs {directory}: not a directory of machine logs")
    paths = sorted(q for q in Path(directory).iterdir() if q.suffix.lower() in LOG_SUFFIXES and q.is_file())
    if not paths:
        raise ValueError(f"--logs {directory}: no machine logs (*.csv, *.mcap) in the directory")
    return paths


def read_logs(
    paths: list[Path], say: Callable[[str], object] = print, mapping: str | Path | None = None
) -> tuple[list[derive.LogRows], list[dict]]:
    """The trusted logs' rows, and per log left out its name and why (each error is said in one line); ``mapping``:
    the MCAP logs' topics and fields (:mod:`.mcap_log`)."""
    from hexgym_lab.machine_logs import read_machine_log

    used, left = [], []
    for path in track(paths, "fit: read and check", "log"):
        try:
            log = read_machine_log(path, mapping)
            findings = check_log(log)
            if not trusted(findings):
                for f in findings:
                    if f.severity == "error":
                        say(f.line())
                raise ValueError("cannot be trusted (the errors above)")
            rows = derive.log_rows(log, derive.file_sha256(path))
            rows.warnings = tuple(f.line() for f in findings if f.severity == "warning")
            used.append(rows)
        except ValueError as exc:
            text = str(exc)
            say(f"{path}: not used: {text.removeprefix(str(path) + ': ')}")
            left.append({"log": str(path), "why": text})
    warned = sum(bool(r.warnings) for r in used)
    if warned:
        say(
            f"{warned} of the {len(used)} logs used have check-log warnings (too little motion to learn a passage, "
            "a short NaN run, ...): provenance.json lists them; the coverage report shows what the logs give"
        )
    return used, left


def _held_out_logs(n_logs: int, seed: int) -> np.ndarray:
    """The log indices held out for the error report: a seeded :data:`HOLDOUT_FRACTION`, at least one of 2+."""
    n_test = max(1, round(HOLDOUT_FRACTION * n_logs)) if n_logs > 1 else 0
    return np.sort(np.random.default_rng(seed).permutation(n_logs)[:n_test])


def _samples(rows: list[derive.LogRows], max_flow: float, reliefs: ReliefSettings) -> dict[str, TableData]:
    """Each table's measured samples (spool, area) with each sample's log index."""
    per_table: dict[str, list] = {name: [] for name in TABLE_SETS[TABLE_SET]}
    for i, r in enumerate(track(rows, "fit: identify", "log")):
        for q in derive.area_samples(r, max_flow, reliefs):
            for name, spec in TABLE_SETS[TABLE_SET].items():
                if np.isfinite(q[spec.output]):
                    per_table[name].append((q[spec.inputs[0]], q[spec.output], i))
    out = {}
    for name, items in per_table.items():
        a = np.array(items, dtype=float).reshape(-1, 3)
        out[name] = TableData(a[:, :1], a[:, 1], a[:, 2].astype(np.int64))
    return out


def _bins(table: MBLTable) -> np.ndarray:
    """Bin edges (m) of :data:`BIN_MM` over the packaged table's spool axis."""
    lo, hi = float(table.axes[0][0]), float(table.axes[0][-1])
    return np.linspace(lo, hi, max(2, int(round((hi - lo) / (BIN_MM * 1e-3))) + 1))


def coverage(data: TableData, packaged: MBLTable) -> dict[str, object]:
    """Which of the packaged table's spool range the samples cover: their range (mm), the share of bins with
    :data:`MIN_BIN_SAMPLES` samples, and the gaps (mm ranges)."""
    edges = _bins(packaged)
    counts, _ = np.histogram(data.X[:, 0], edges)
    full = counts >= MIN_BIN_SAMPLES
    gaps, start = [], None
    for k, ok in enumerate([*full, True]):
        if not ok and start is None:
            start = k
        elif ok and start is not None:
            gaps.append([round(edges[start] * 1e3, 2), round(edges[k] * 1e3, 2)])
            start = None
    sampled = [round(float(data.X[:, 0].min()) * 1e3, 2), round(float(data.X[:, 0].max()) * 1e3, 2)] if len(
        data.y) else None  # fmt: skip
    return {"samples": int(len(data.y)), "logs": int(len(np.unique(data.episode))), "spool_mm_sampled": sampled,
            "table_range_mm": [round(edges[0] * 1e3, 2), round(edges[-1] * 1e3, 2)],
            "covered_share": float(full.mean()), "gaps_mm": gaps}  # fmt: skip


def packaged_ratio(data: TableData, packaged: MBLTable) -> float:
    """The median ratio of the measured areas to the packaged table's at the same spools (1 without samples where
    the packaged passage is open): how much larger this unit's passage is."""
    reference = np.asarray(packaged.lookup(data.X), dtype=float)
    open_ = reference > 0.05 * max(float(np.max(packaged.values)), 1e-12)
    return float(np.median(data.y[open_] / reference[open_])) if open_.sum() >= MIN_BIN_SAMPLES else 1.0


def _with_prior(data: TableData, packaged: MBLTable) -> TableData:
    """The samples and, in each bin with too few of them, :data:`PRIOR_PER_BIN` points of the packaged table times
    :func:`packaged_ratio` (log index -1: always trained on, never held out)."""
    edges = _bins(packaged)
    counts, _ = np.histogram(data.X[:, 0], edges)
    gap = np.flatnonzero(counts < MIN_BIN_SAMPLES)
    if not len(gap):
        return data
    width = edges[1] - edges[0]
    x = (edges[gap][:, None] + width * (np.arange(PRIOR_PER_BIN) + 0.5) / PRIOR_PER_BIN).ravel()
    y = np.asarray(packaged.lookup(x[:, None]), dtype=float) * packaged_ratio(data, packaged)
    return TableData(np.vstack([data.X, x[:, None]]), np.concatenate([data.y, y]),
                     np.concatenate([data.episode, np.full(len(x), -1)]))  # fmt: skip


def _past_toe(data: TableData) -> TableData:
    """The samples past the metering toe (:data:`TOE_MM` beyond the dead band): nearer it the passage passes so
    little that the logs' speed noise, of which only the positive flows give samples, biases the areas up
    (x1.5-3 at 0.5-1 mm past the dead band on a drawn unit); the packaged table's shape stands in there."""
    keep = np.abs(data.X[:, 0]) >= p.SPOOL_DEAD_BAND + TOE_MM * 1e-3
    return TableData(data.X[keep], data.y[keep], data.episode[keep])


def _subsample(data: TableData, seed: int) -> TableData:
    if len(data.y) <= MAX_POINTS:
        return data
    keep = np.sort(np.random.default_rng(seed).choice(len(data.y), MAX_POINTS, replace=False))
    return TableData(data.X[keep], data.y[keep], data.episode[keep])


def _rmse_rel(table: MBLTable, X: np.ndarray, y: np.ndarray, span: float) -> float | None:
    return float(np.sqrt(np.mean((np.asarray(table.lookup(X), dtype=float) - y) ** 2)) / span) if len(y) else None


def fit_passage(name: str, data: TableData, packaged: MBLTable, held: np.ndarray, seed: int) -> tuple[MBLTable, dict]:
    """One passage's table from its samples (see the module) and its report: coverage, held-out errors of the
    fitted and the packaged table on the held-out logs (RMSE / the samples' range), or why it is kept."""
    report = coverage(data, packaged)
    if name.endswith("_bypass"):
        return packaged, report | {"kept": "no NFC signal pressure is logged: the bypass flow is not measured"}
    logs = report["logs"]
    if report["samples"] < MIN_SAMPLES or logs < MIN_LOGS:
        why = f"{report['samples']} samples from {logs} logs; {MIN_SAMPLES} from {MIN_LOGS} needed"
        return packaged, report | {"kept": why}
    report["ratio_to_packaged"] = packaged_ratio(data, packaged)
    data = _subsample(_with_prior(_past_toe(data), packaged), seed)
    test = np.isin(data.episode, held)
    if not test.any():  # the held-out logs do not meter this passage: hold out a share of those that do
        measured = np.unique(data.episode[data.episode >= 0])
        test = np.isin(data.episode, measured[_held_out_logs(len(measured), seed)])
    split = (np.flatnonzero(~test), np.flatnonzero(test))
    table = fit_table(name, data, seed=seed, table_set=TABLE_SET, split=split)
    span = float(np.ptp(data.y[data.episode >= 0])) or 1.0
    X, y = data.X[test], data.y[test]
    report |= {"holdout_rmse_rel": table.metrics["holdout_rmse_rel"] if len(y) else None,
               "holdout_samples": int(len(y)), "packaged_holdout_rmse_rel": _rmse_rel(packaged, X, y, span),
               "fitted_all_holdout_rmse_rel": _rmse_rel(table, X, y, span),
               "loo_rmse_rel": table.metrics["loo_rmse_rel"]}  # fmt: skip
    return table, report


def fit_logs(
    log_dir: str | Path,
    out_dir: str | Path,
    seed: int = 0,
    say: Callable[[str], object] = print,
    mapping: str | Path | None = None,
) -> dict:
    """Fit the ``circuit`` tables to the logs in ``log_dir`` (CSV; MCAP through ``mapping``) and write ``out_dir``
    (tables + provenance.json); returns the provenance. ValueError where no log can be used."""
    t0 = time.perf_counter()
    paths = log_files(log_dir)
    rows, left = read_logs(paths, say, mapping)
    if not rows:
        raise ValueError(f"--logs {log_dir}: none of the {len(paths)} logs can be used (see above)")
    pump = derive.identify_pump_max_flow(rows)
    max_flow = pump["value_m3s"] if pump["identified"] else p.PUMP_MAX_FLOW
    relief_settings = identify_reliefs(rows, max_flow)
    unit_reliefs = relief_hydraulics(relief_settings)
    samples = _samples(rows, max_flow, _relief_settings(unit_reliefs))
    held = _held_out_logs(len(rows), seed)
    packaged = load_tables(None, TABLE_SET)
    tables, reports = {}, {}
    for name in track(TABLE_SETS[TABLE_SET], "fit: tables", "table"):
        tables[name], reports[name] = fit_passage(name, samples[name], packaged[name], held, seed)
    provenance = {
        "table_set": TABLE_SET,
        "seed": seed,
        "logs": [
            {
                "log": r.name,
                "sha256": r.sha256,
                "seconds": float(r.t[-1] - r.t[0]),
                "held_out": bool(i in held),
                "warnings": list(r.warnings),
            }
            for i, r in enumerate(rows)
        ],  # fmt: skip
        "logs_not_used": left,
        "signals_used": list(derive.SIGNALS_USED),
        "signals_estimated": {
            "nfc_signal_pressures": "from the pump pressures and the packaged bypass tables",
            "pump_flows": "the regulator's law (NFC through its lag, horsepower limit) at "
            f"{max_flow * 60000:.1f} L/min",
        },  # fmt: skip
        "tables": reports,
        "kept_from_package": {n: r["kept"] for n, r in reports.items() if "kept" in r},
        "hydraulics": ({"pump": {"max_flow_m3s": max_flow}} if pump["identified"] else {})
        | ({"relief": unit_reliefs} if unit_reliefs else {}),
        "scalars": {
            "pump_max_flow": pump | {"applied_by_model": bool(pump["identified"])},
            "relief_settings": {k: v | {"applied_by_model": v["identified"]} for k, v in relief_settings.items()},
            "leakage": {"identified": False, "why": LEAKAGE_NOT_IDENTIFIED},
        },  # fmt: skip
        "fit_seconds": round(time.perf_counter() - t0, 1),
    }
    write_model(out_dir, tables, provenance)
    return provenance


def write_model(out_dir: str | Path, tables: dict[str, MBLTable], provenance: dict) -> Path:
    """The model directory, as a whole: each table's .npz (a kept one copied from the package) and provenance.json."""
    source = packaged_tables_dir(TABLE_SET)
    with staged_dir(out_dir, keep=False) as staging:
        for name, table in tables.items():
            if name in provenance["kept_from_package"]:
                shutil.copyfile(source / f"{name}.npz", staging / f"{name}.npz")
            else:
                table.save(staging / f"{name}.npz")
        (staging / PROVENANCE).write_text(json.dumps(provenance, indent=2))
    return Path(out_dir)


def coverage_report(provenance: dict) -> str:
    """The fit's per-table lines: samples, logs, spool range sampled, covered share, gaps, held-out errors (fitted
    vs packaged) or why the packaged table was kept; the pump's maximum flow; the warnings."""
    lines = [f"{'table':20s} {'samples':>7s} {'logs':>4s} {'sampled mm':>15s} {'covered':>7s}  held-out: fitted / "
             "packaged (RMSE / range)"]  # fmt: skip
    warnings = []
    for name, r in provenance["tables"].items():
        rng = r["spool_mm_sampled"]
        sampled = f"{rng[0]:.1f}..{rng[1]:.1f}" if rng else "-"
        head = f"{name:20s} {r['samples']:7d} {r['logs']:4d} {sampled:>15s} {r['covered_share']:7.0%}  "
        if "kept" in r:
            lines.append(head + f"packaged kept: {r['kept']}")
            continue
        fitted, packaged = r["holdout_rmse_rel"], r["packaged_holdout_rmse_rel"]
        lines.append(head + (f"{fitted:.3f} / {packaged:.3f}" if fitted is not None else "no held-out samples"))
        if r["gaps_mm"]:
            lines.append(f"{'':20s} gaps (packaged x {r['ratio_to_packaged']:.2f} stands in), mm: "
                         + ", ".join(f"{a:g}..{b:g}" for a, b in r["gaps_mm"][:6]))  # fmt: skip
        if fitted is not None and fitted > POOR_HOLDOUT:
            warnings.append(f"warning: {name}: held-out error {fitted:.1%} of its range (> {POOR_HOLDOUT:.0%}): "
                            "more logs of that passage, or check its signals")  # fmt: skip
    pump = provenance["scalars"]["pump_max_flow"]
    if pump["identified"]:
        lines.append(f"pump max flow: {pump['value_l_min']:.1f} L/min ({pump['relative_to_packaged']:.3f} x packaged, "
                     f"standard error {pump['standard_error_m3s'] * 60000:.2f} L/min, {pump['rows']} rows of "
                     f"{pump['logs']} logs): the model's pumps")  # fmt: skip
    else:
        lines.append(f"pump max flow: not identified: {pump['why']}")
    for name, r in provenance["scalars"]["relief_settings"].items():
        if r["identified"]:
            lines.append(f"relief {name}: {r['value_pa'] / 1e6:.2f} MPa ({r['relative_to_packaged']:.3f} x packaged, "
                         f"standard error {r['standard_error_pa'] / 1e6:.2f} MPa, {r['rows']} rows of {r['logs']} "
                         "logs): the model's")  # fmt: skip
        else:
            lines.append(f"relief {name}: not identified ({r['why']}): the packaged {r['packaged_pa'] / 1e6:.1f} MPa")
    lines.append(f"leakage: {provenance['scalars']['leakage']['why']}")
    return "\n".join(lines + warnings)

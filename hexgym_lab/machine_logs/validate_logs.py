"""``hexgym validate --model MODEL_DIR --logs DIR``: a fitted model against the machine's own (held-out) logs.

Each log's spools are replayed on the fitted model from the log's first measured pose (at rest there, with the
log's payload if it records one) and the run is scored against the log's measured joints by
:func:`hexgym_lab.compare.compare_logs` (tip error mean and worst, joint errors); the packaged model runs the same
replay beside it. No reference model is needed: the log is the truth.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from hexgym.machine.kinematics import check_joint_angles
from hexgym.model.commandlog import CommandLog
from hexgym_lab.compare import compare_logs
from hexgym_lab.machine_logs import read_machine_log
from hexgym_lab.machine_logs import signals as s
from hexgym_lab.machine_logs.fit import log_files
from hexgym_lab.progress import track

MODELS = ("fitted", "packaged")


def log_commands(log: s.MachineLog) -> tuple[CommandLog, np.ndarray, float]:
    """The log's spools as a command log (t from its first sample with a pose), its first measured pose (rad) and
    its payload (kg; 0 where it records none)."""
    q, u = log.angles(), log.spools_mm()
    if q is None or u is None:
        raise ValueError(f"{log.name}: no joint angles or no spools: nothing to replay")
    good = np.flatnonzero(np.isfinite(log.t) & np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(u), axis=1))
    if len(good) < 2:
        raise ValueError(f"{log.name}: fewer than two samples with every joint angle and spool")
    t = log.t[good] - log.t[good[0]]
    keep = np.concatenate([[True], np.diff(t) > 0])
    start = check_joint_angles(q[good[0]], f"{log.name} (its first pose)")
    payload = log.signals.get(s.PAYLOAD)
    payload_kg = float(np.nanmedian(payload)) if payload is not None and np.any(np.isfinite(payload)) else 0.0
    spools = np.clip(u[good][keep], -11.0, 11.0)
    return CommandLog(t[keep], spools), start, payload_kg


def _run_log(model, log: s.MachineLog, what: str) -> dict:
    """One model's replay of ``log`` scored against it."""
    from hexgym.model.replay import replay

    commands, start, payload = log_commands(log)
    dt_out = model.control_period * max(1, round(0.05 / model.control_period))
    rows = replay(model, commands, start=start, payload_kg=payload, dt_out=dt_out)
    run = s.MachineLog(f"{what} model", rows["t"] + float(log.t[np.isfinite(log.t)][0]),
                       {n: rows[n] for n in s.JOINT_ANGLES})  # fmt: skip
    result = compare_logs(run, log)
    return {k: v for k, v in result.items() if k not in ("series", "a", "b")}


def validate_on_logs(
    model_dir: str | Path, log_dir: str | Path, backend: str = "auto", mapping: str | Path | None = None
) -> dict:
    """Per log in ``log_dir`` (CSV; MCAP through ``mapping``): the fitted model's (``model_dir``) and the packaged
    model's tip and joint errors against the log; and over the logs the median and worst of the per-log mean tip
    errors, and the worst tip error anywhere."""
    from hexgym.model.backend import make_learned_model

    models = {"fitted": make_learned_model(backend, tables_dir=model_dir), "packaged": make_learned_model(backend)}
    t0 = time.perf_counter()
    per_log = []
    for path in track(log_files(log_dir), "validate: logs", "log"):
        log = read_machine_log(path, mapping)
        per_log.append({"log": str(path)} | {name: _run_log(m, log, name) for name, m in models.items()})
    summary = {name: _suite(per_log, name) for name in MODELS}
    return {"model": str(model_dir), "logs": str(log_dir), "summary": summary, "per_log": per_log,
            "seconds": round(time.perf_counter() - t0, 1)}  # fmt: skip


def _suite(per_log: list[dict], name: str) -> dict:
    means = np.array([r[name]["tip_error_mean_m"] for r in per_log])
    worst = np.array([r[name]["tip_error_max_m"] for r in per_log])
    return {"tip_error_mean_median_m": float(np.median(means)), "tip_error_mean_worst_m": float(np.max(means)),
            "tip_error_max_m": float(np.max(worst)), "logs": len(per_log)}  # fmt: skip


def summary_text(result: dict) -> str:
    """A line per log (mean / worst tip error, fitted and packaged) and the suite's figures."""
    lines = [f"{'log':40s} {'fitted mean / worst m':>22s} {'packaged mean / worst m':>24s}"]
    for r in result["per_log"]:
        f, pk = r["fitted"], r["packaged"]
        lines.append(f"{Path(r['log']).name:40s} {f['tip_error_mean_m']:10.3f} / {f['tip_error_max_m']:.3f} "
                     f"{pk['tip_error_mean_m']:12.3f} / {pk['tip_error_max_m']:.3f}")  # fmt: skip
    for name in MODELS:
        su = result["summary"][name]
        lines.append(f"{name}: per-log mean tip error median {su['tip_error_mean_median_m']:.3f} m, worst "
                     f"{su['tip_error_mean_worst_m']:.3f} m; worst tip error {su['tip_error_max_m']:.3f} m "
                     f"({su['logs']} logs)")  # fmt: skip
    return "\n".join(lines)

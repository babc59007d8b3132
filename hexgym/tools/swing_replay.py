"""The swing alone: how far a table set's swing model ends from the reference's on operator-like logs.
``python -m hexgym.tools.swing_replay --suite-seed S --logs N [--json OUT]``.

The suite's logs (:func:`hexgym.mbl.operator_logs.suite_log`) run on the reference model; then each
swing model integrates the swing alone, every 20 ms, fed the reference's other joints and inputs
(spools, the stick's force, the swing inertia, pump 2's pressure) and its own swing rate. So the
figure is the swing model's error without the boom's, stick's and bucket's, and without their
feedback on the swing. The error is the swing angle's difference times the tip's horizontal reach,
averaged over each log.

Models:

- ``paper``: the paper set's swing table, its acceleration integrated as the learned model does;
- ``extended``: pump 2's pressure from its table, the swing torque from it, the angular momentum
  integrated (``d(I w)/dt = torque``);
- ``extended_true_pressure``: the same torque table at the reference's own pump-2 pressure: what
  a perfect pressure model would give;
- ``..._exact_braking`` / ``..._exact_driving``: that, with the swing's own momentum change (the
  reference's ``d(I w)/dt``) wherever its spool is closed (braking, coasting) / open (driving): which of
  the two parts of the swing model the remaining error comes from.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

import numpy as np

from hexgym.checks import check_count, check_seed
from hexgym.files import write_json
from hexgym.hydraulics.reference import ReferenceModel
from hexgym.machine import parameters as p
from hexgym.mbl.operator_logs import suite_log
from hexgym.mbl.schema import TABLE_SETS
from hexgym.mbl.table import MBLTable, load_tables
from hexgym.model.base import next_swing_rate
from hexgym.model.commandlog import CommandLog
from hexgym.model.replay import replay
from hexgym.parallel import executor

ROW_S = 0.01  # s between the reference's rows
EVERY = 2  # rows per swing step: 20 ms
MODELS = (
    "paper", "extended", "extended_true_pressure", "extended_true_pressure_exact_braking",
    "extended_true_pressure_exact_driving",
)  # fmt: skip


def reference_rows(suite_seed: int, index: int) -> np.ndarray:
    """Log ``index`` of the suite replayed on the reference model, a row every 10 ms."""
    drawn = suite_log(suite_seed, index)
    log = CommandLog(drawn.t, drawn.spools_mm)
    return replay(ReferenceModel(), log, start=drawn.start_pose, payload_kg=drawn.payload_kg, dt_out=ROW_S)


def _query(table: MBLTable, q: dict[str, float], spec_inputs: tuple[str, ...]) -> float:
    return table(tuple(q[name] for name in spec_inputs))


def _swing_step(model: str, tables: dict[str, dict[str, MBLTable]]) -> Callable[[dict[str, float]], float]:
    """The swing's acceleration (rad/s^2) from one row's quantities, for ``model``."""
    paper, extended = TABLE_SETS["paper"], TABLE_SETS["extended"]
    if model == "paper":
        table = tables["paper"]["swing"]
        return lambda q: _query(table, q, paper["swing"].inputs)
    torque, pressure = tables["extended"]["swing"], tables["extended"]["pump2"]

    def acceleration(q: dict[str, float]) -> float:
        if model == "extended":
            q = q | {"pump2_pressure_pa": _query(pressure, q, extended["pump2"].inputs)}
        return _query(torque, q, extended["swing"].inputs) / q["swing_inertia_kgm2"]

    return acceleration


def swing_errors(rows: np.ndarray, model: str, tables: dict[str, dict[str, MBLTable]]) -> np.ndarray:
    """Tip error (m) of ``model``'s swing alone along the reference's ``rows``, every 20 ms."""
    r = rows[::EVERY]
    dt = EVERY * ROW_S
    spools = np.column_stack([r[f"{j}_spool_mm"] for j in ("swing", "stick")]) * 1e-3
    closed = np.abs(spools) < p.SPOOL_DEAD_BAND
    swing_set = "paper" if model == "paper" else "extended"
    rate_axis = tables[swing_set]["swing"].axes[tables[swing_set]["swing"].inputs.index("swing_rate_radps")]
    acceleration = _swing_step(model.replace("_exact_braking", "").replace("_exact_driving", ""), tables)
    momentum = model != "paper"  # a torque: the angular momentum is what it changes
    # the reference's own momentum change over each step, where the model takes it as given (N m)
    momentum_change = np.diff(r["swing_inertia_kgm2"] * r["qd_swing"]) / dt
    exact = closed[:, 0] if model.endswith("_exact_braking") else ~closed[:, 0]
    exact &= model.endswith(("_exact_braking", "_exact_driving"))
    angle, rate = float(r["q_swing"][0]), 0.0
    angles = np.empty(len(r))
    for k in range(len(r)):
        angles[k] = angle
        if k == len(r) - 1:
            break
        inertia = float(r["swing_inertia_kgm2"][k])
        if exact[k]:
            new_rate = (inertia * rate + momentum_change[k] * dt) / float(r["swing_inertia_kgm2"][k + 1])
            angle += 0.5 * (rate + new_rate) * dt
            rate = new_rate
            continue
        q = {
            "swing_spool_m": spools[k, 0],
            "stick_spool_m": spools[k, 1],
            "stick_force_n": float(r["stick_force_n"][k]),
            "stick_drive_force_n": 0.0 if closed[k, 1] else float(r["stick_force_n"][k]),
            "swing_inertia_kgm2": inertia,
            "swing_rate_radps": rate,
            "pump2_pressure_pa": float(r["pump2_pressure_pa"][k]),
        }
        new_rate, _ = next_swing_rate(rate, acceleration(q), dt, bool(closed[k, 0]), rate_axis[0], rate_axis[-1])
        if momentum:
            new_rate *= inertia / float(r["swing_inertia_kgm2"][k + 1])
        angle += 0.5 * (rate + new_rate) * dt
        rate = new_rate
    return np.abs(angles - r["q_swing"]) * np.hypot(r["tip_x"], r["tip_y"])


def _log_figures(task: tuple[int, int]) -> dict[str, object]:
    suite_seed, index = task
    rows = reference_rows(suite_seed, index)
    tables = {name: load_tables(table_set=name) for name in ("paper", "extended")}
    return {"index": index} | {m: float(swing_errors(rows, m, tables).mean()) for m in MODELS}


def run(suite_seed: int, logs: int, workers: int | None = None) -> dict[str, object]:
    """Per log and over the logs: each swing model's mean tip error (m)."""
    with executor(workers or 2) as pool:
        per_log = list(pool.map(_log_figures, [(suite_seed, i) for i in range(logs)]))
    summary = {
        m: {
            "median_m": float(np.median([e[m] for e in per_log])),
            "mean_m": float(np.mean([e[m] for e in per_log])),
            "worst_m": float(np.max([e[m] for e in per_log])),
        }
        for m in MODELS
    }
    return {"suite_seed": suite_seed, "logs": logs, "models": summary, "per_log": per_log}


def main(argv: list[str] | None = None) -> int:
    """Command line: print the figures, optionally write them as JSON."""
    parser = argparse.ArgumentParser(prog="python -m hexgym.tools.swing_replay", description=__doc__.split("\n")[0])
    parser.add_argument("--suite-seed", type=int, default=3, help="the suite's seed (default: 3)")
    parser.add_argument("--logs", type=int, default=20, help="logs of the suite (default: 20)")
    parser.add_argument("--workers", type=int, default=None, help="processes (default: 2)")
    parser.add_argument("--json", default=None, help="write the figures here")
    args = parser.parse_args(argv)
    try:
        check_seed("--suite-seed", args.suite_seed)
        check_count("--logs", args.logs)
    except ValueError as exc:
        parser.error(str(exc))
    out = run(args.suite_seed, args.logs, args.workers)
    for model, figures in out["models"].items():
        median, mean, worst = figures["median_m"], figures["mean_m"], figures["worst_m"]
        print(f"{model:24s} median {median:.2f} m, mean {mean:.2f} m, worst {worst:.2f} m")
    if args.json:
        write_json(args.json, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())

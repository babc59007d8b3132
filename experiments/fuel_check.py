"""The env's fuel estimate (:mod:`hexgym.hydraulics.fuel`) against the reference circuit's fuel (its pumps'
pressures and flows through the BSFC map): on one loading-like command sequence, or on a seeded suite of
operator-like logs (:func:`hexgym_lab.mbl.operator_logs.suite_log`), where the estimate is taken both from the
reference's own motion (the estimate's own error) and from the learned model's replay of the log (what
the environment reports)::

    python experiments/fuel_check.py                                  # the loading-like sequence
    python experiments/fuel_check.py --suite 16 --suite-seed 202 [--json OUT]
"""

from __future__ import annotations

import argparse
import statistics
import sys

import numpy as np

from hexgym.files import PathError, check_output_file, write_json
from hexgym.hydraulics.fuel import actuator_powers, fuel_litres_many
from hexgym.hydraulics.reference import ReferenceModel
from hexgym.machine.kinematics import FRONT_CYLINDERS
from hexgym.model.commandlog import CommandLog
from hexgym.model.python_backend import LearnedModel
from hexgym.model.replay import replay
from hexgym_lab.mbl.operator_logs import suite_log

CHECK_SEQUENCE = np.array(
    [
        [0.0, 0, 0, 0, 0],
        [0.5, 0, 8, -11, -11],
        [3.0, 0, -9, 0, 0],
        [5.0, 0, 0, 11, 8],
        [7.5, 11, 11, 0, 6],
        [10.5, 0, 0, -6, -11],
        [12.0, -11, -6, 0, 8],
        [15.0, 0, 0, 0, 0],
    ],
    dtype=float,
)
SUITE_LOG_S = 30.0  # s of each suite log
_REFERENCE_ROW_S = 0.02  # s: a multiple of the reference's 2 ms step


def compare_with_reference(duration: float = 16.0, payload_kg: float = 1000.0) -> dict[str, float]:
    """Fuel (L) of :data:`CHECK_SEQUENCE`: the reference circuit's (pump pressures x flows through
    the BSFC map) against this module's estimate on the learned model."""
    commands = CommandLog(CHECK_SEQUENCE[:, 0], CHECK_SEQUENCE[:, 1:])
    dt = 0.01
    reference = replay(ReferenceModel(), commands, payload_kg=payload_kg, dt_out=dt, duration=duration)
    reference_l = float(np.sum(reference["fuel_rate_l_per_h"]) * dt / 3600.0)
    estimate_l = _learned_estimate_l(commands, {"payload_kg": payload_kg}, duration)
    return {"reference_l": reference_l, "estimate_l": estimate_l, "ratio": estimate_l / reference_l}


def _learned_estimate_l(commands: CommandLog, start: dict, duration: float | None = None) -> float:
    """The estimate (L) on the learned model's replay of ``commands`` from ``start`` (``replay``'s start and
    payload), its power at the end of each control period held over the period."""
    model = LearnedModel()
    rows = replay(model, commands, dt_out=model.control_period, duration=duration, **start)
    return _estimate_l(
        rows, rows["swing_inertia_kgm2"] * rows["swing_acceleration_target_radps2"], model.control_period
    )


def _estimate_l(rows: np.ndarray, swing_torque: np.ndarray, dt: float) -> float:
    """The estimate (L) over trajectory rows every ``dt`` s: cylinder forces x velocities, swing torque x rate."""
    forces = np.stack([rows[f"{c}_force_n"] for c in FRONT_CYLINDERS], axis=1)
    speeds = np.stack([rows[f"{c}_velocity_mps"] for c in FRONT_CYLINDERS], axis=1)
    power = actuator_powers(forces, speeds, swing_torque, rows["qd_swing_radps"])
    return float(fuel_litres_many(power[1:], np.full(len(rows) - 1, dt)).sum())


def suite_log_fuel(suite_seed: int, index: int) -> dict[str, float]:
    """One suite log's fuel (L): the reference's, and the estimate on its motion and on the learned model's."""
    log = suite_log(suite_seed, index, SUITE_LOG_S)
    commands = CommandLog(log.t, log.spools_mm)
    start = {"start": log.start_pose, "payload_kg": log.payload_kg}
    reference = replay(ReferenceModel(), commands, dt_out=_REFERENCE_ROW_S, **start)
    return {
        "reference_l": float(np.sum(reference["fuel_rate_l_per_h"][1:]) * _REFERENCE_ROW_S / 3600.0),
        "estimate_on_reference_motion_l": _estimate_l(reference, reference["swing_torque_nm"], _REFERENCE_ROW_S),
        "estimate_on_learned_model_l": _learned_estimate_l(commands, start),
    }


def suite_comparison(suite_seed: int, count: int) -> dict[str, object]:
    """:func:`suite_log_fuel` of logs 0..count-1 and the medians of the estimates' relative errors."""
    logs = [suite_log_fuel(suite_seed, i) for i in range(count)]

    def errors(key: str) -> list[float]:
        return [log[key] / log["reference_l"] - 1.0 for log in logs]

    summary = {}
    for key in ("estimate_on_reference_motion_l", "estimate_on_learned_model_l"):
        e = errors(key)
        summary[key.removesuffix("_l")] = {
            "median_abs_error": statistics.median(abs(x) for x in e),
            "median_error": statistics.median(e),
            "worst_abs_error": max(abs(x) for x in e),
        }
    return {"suite_seed": suite_seed, "logs": count, "log_s": SUITE_LOG_S, "summary": summary, "per_log": logs}


def main(argv: list[str] | None = None) -> int:
    """Print (and write) the comparison; bad options get one line naming them."""
    parser = argparse.ArgumentParser(prog="python experiments/fuel_check.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--suite", type=int, default=0, help="operator-like logs to compare (0: the loading sequence)")
    parser.add_argument("--suite-seed", type=int, default=202, help="the suite's seed (default: 202)")
    parser.add_argument("--json", metavar="OUT", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    if args.suite < 0:
        parser.exit(2, f"--suite must be >= 0, got {args.suite}\n")
    if args.suite_seed < 0:
        parser.exit(2, f"--suite-seed must be >= 0, got {args.suite_seed}\n")
    try:
        if args.json:
            check_output_file(args.json, "--json")
    except PathError as err:
        parser.exit(2, f"{err}\n")
    result = suite_comparison(args.suite_seed, args.suite) if args.suite else compare_with_reference()
    print(result["summary"] if args.suite else result)
    if args.json:
        write_json(args.json, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())

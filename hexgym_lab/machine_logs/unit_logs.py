"""Machine logs of a reference unit on operator-like command logs: what the fitting's tests and its measured target
run on (``docs/machine-logs.md``, "Fitting your machine"). The same as ``hexgym simulate --model reference
--hydraulics FILE --start ... --payload-kg ... --machine-log OUT.csv --rate 100 --sensor-noise default`` on each
of a suite's logs (:func:`hexgym_lab.mbl.operator_logs.suite_log`), in worker processes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hexgym.model.commandlog import CommandLog, write_command_log
from hexgym_lab.mbl.operator_logs import suite_log

RATE_HZ = 100.0
JITTER = 0.2
# How far a drawn unit differs from the packaged one (docs/machine-logs.md): each learned metering passage's area,
# the pumps' maximum flow, each relief's setting (main, swing crossover, each cylinder's port reliefs)
AREA_SCALE_RANGE = (0.8, 1.2)
PUMP_FLOW_SCALE_RANGE = (0.85, 1.05)
RELIEF_SCALE_RANGE = (0.93, 1.07)


def drawn_unit(seed: int) -> dict:
    """A unit drawn within the documented ranges, as a hydraulics file's content: every learned metering passage's
    area (the unloading valve and the bypasses as packaged), the pumps' maximum flow and every relief setting, each
    uniform in its range; leakage as packaged."""
    from hexgym.hydraulics.circuit import DEFAULT_LAYOUT
    from hexgym.hydraulics.overrides import passage_names
    from hexgym.machine import parameters as p
    from hexgym.mbl.schema import TABLE_SETS

    rng = np.random.default_rng(seed)
    learned = set(TABLE_SETS["circuit"])
    passages = [n for n in passage_names(DEFAULT_LAYOUT) if n in learned and not n.endswith("_bypass")]
    scales = {n: round(float(rng.uniform(*AREA_SCALE_RANGE)), 3) for n in passages}
    pump = round(float(rng.uniform(*PUMP_FLOW_SCALE_RANGE)), 3)

    def relief(setting: float) -> float:
        return round(setting * float(rng.uniform(*RELIEF_SCALE_RANGE)), -4)

    return {
        "valve": {"passage_area_scale": scales},
        "pump": {"max_flow_scale": pump},
        "relief": {"main_pa": relief(p.MAIN_RELIEF), "swing_pa": relief(p.SWING_RELIEF),
                   "line_pa": {k: relief(v) for k, v in p.LINE_RELIEF.items()}},
    }  # fmt: skip


def _one(task: tuple[str, str | None, int, int, str, float | None]) -> str:
    out_dir, hydraulics, suite_seed, index, style, duration = task
    from hexgym.hydraulics.reference import ReferenceModel
    from hexgym.model.replay import replay
    from hexgym_lab.machine_logs.csv_log import write_csv_log
    from hexgym_lab.machine_logs.synthetic import machine_log_of

    if style == "excitation":
        from hexgym_lab.machine_logs.excitation import excitation_log, start_pose

        commands, start, payload = excitation_log(), start_pose(), 0.0
    else:
        drawn = suite_log(suite_seed, index, duration, style)
        commands, start, payload = CommandLog(drawn.t - drawn.t[0], drawn.spools_mm), drawn.start_pose, drawn.payload_kg
    name = f"{style}_{suite_seed}_{index:03d}"
    write_command_log(Path(out_dir) / "commands" / f"{name}.csv", commands)
    model = ReferenceModel(hydraulics=hydraulics)
    rows = replay(model, commands, start=start, payload_kg=payload, dt_out=model.control_period)
    t, signals = machine_log_of(rows, RATE_HZ, None, JITTER, seed=1000 * suite_seed + index, payload_kg=payload)
    return str(write_csv_log(Path(out_dir) / f"{name}.csv", t, signals))


def write_unit_logs(
    out_dir: str | Path,
    hydraulics: str | dict | None,
    suite_seed: int,
    count: int,
    style: str = "operator",
    duration_s: float | None = None,
    workers: int = 2,
) -> list[Path]:
    """``count`` machine logs of the reference with ``hydraulics`` on suite ``suite_seed``'s logs in ``style``
    (a :data:`hexgym_lab.mbl.operator_logs.STYLES` key, or ``excitation``: :mod:`.excitation`'s log), as
    ``out_dir/<style>_<seed>_<i>.csv`` (their command logs under ``out_dir/commands``)."""
    from hexgym.parallel import executor

    (Path(out_dir) / "commands").mkdir(parents=True, exist_ok=True)
    tasks = [(str(out_dir), hydraulics, suite_seed, i, style, duration_s) for i in range(count)]
    with executor(workers) as pool:
        return [Path(x) for x in pool.map(_one, tasks)]


def main(argv: list[str] | None = None) -> int:
    """``python -m hexgym_lab.machine_logs.unit_logs OUT --hydraulics FILE --suite-seed S --count N``."""
    import argparse

    parser = argparse.ArgumentParser(description="machine logs of a reference unit on a suite's operator-like logs")
    parser.add_argument("out", metavar="DIR", help="output directory: <style>_<seed>_<i>.csv and commands/")
    unit = parser.add_mutually_exclusive_group()
    unit.add_argument("--hydraulics", default=None, metavar="FILE", help="the unit (default: the packaged one)")
    unit.add_argument(
        "--drawn-unit",
        type=int,
        default=None,
        metavar="SEED",
        help="a unit drawn within the documented ranges (drawn_unit), written to DIR/unit.json",
    )
    parser.add_argument("--suite-seed", type=int, default=0, help="the suite's seed (default: 0)")
    parser.add_argument("--count", type=int, default=1, help="logs (default: 1)")
    parser.add_argument("--style", default="operator", help="operator, bucket_stick or excitation (default: operator)")
    parser.add_argument("--workers", type=int, default=2, help="processes (default: 2)")
    args = parser.parse_args(argv)
    hydraulics = args.hydraulics
    if args.drawn_unit is not None:
        import json

        Path(args.out).mkdir(parents=True, exist_ok=True)
        hydraulics = str(Path(args.out) / "unit.json")
        Path(hydraulics).write_text(json.dumps(drawn_unit(args.drawn_unit), indent=2))
    for path in write_unit_logs(args.out, hydraulics, args.suite_seed, args.count, args.style, None, args.workers):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

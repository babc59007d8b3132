"""The ``hexgym`` command line: one subcommand per job, each with ``--help``."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path


def _cmd_demo(args: argparse.Namespace) -> int:
    from hexgym.demo import run_demo

    paths = run_demo(args.out, fps=args.fps, width=args.width, height=args.height)
    for kind, path in paths.items():
        print(f"{kind}: {path}")
    return 0


def _cmd_model(args: argparse.Namespace) -> int:
    from hexgym.model_info import model_summary

    summary = model_summary()
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        for key, value in summary.items():
            print(f"{key}: {value}")
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    from hexgym.commandlog import read_command_log, write_trajectory_csv
    from hexgym.replay import replay

    commands = read_command_log(args.commands)
    if args.model == "reference":
        from hexgym.reference import ReferenceModel

        model = ReferenceModel()
    else:
        from hexgym.learned import LearnedModel

        model = LearnedModel()
    trajectory = replay(model, commands, start=args.start, payload_kg=args.payload_kg, dt_out=args.dt_out)
    write_trajectory_csv(args.out, trajectory)
    print(f"wrote {args.out}: {len(trajectory)} rows, {commands.duration:g} s simulated")
    return 0


def _cmd_reference_report(args: argparse.Namespace) -> int:
    from hexgym.reference_report import run_report

    print(json.dumps(run_report(args.out), indent=2))
    print(f"plots: {Path(args.out) / 'interactions.png'}")
    return 0


def _cmd_fit(args: argparse.Namespace) -> int:
    from hexgym.fit import TABLES, fit_all

    names = tuple(args.tables.split(",")) if args.tables else tuple(TABLES)
    unknown = set(names) - set(TABLES)
    if unknown:
        raise ValueError(f"unknown table(s) {sorted(unknown)}; choose from {list(TABLES)}")
    for name, path in fit_all(args.data, args.out, seed=args.seed, names=names).items():
        print(f"{name}: {path}")
    return 0


def _cmd_tables(args: argparse.Namespace) -> int:
    from hexgym.fit import tables_summary

    summary = tables_summary(args.dir)
    if args.bench:
        from hexgym.fit import lookup_benchmark

        for item in summary:
            item["seconds_per_query"] = lookup_benchmark(args.bench, args.dir)[item["name"]]
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    for t in summary:
        print(
            f"{t['name']:7s} {t['n_points']:6d} points  LOO {t['loo_rmse_rel']:.4f}  "
            f"held-out {t['holdout_rmse_rel']:.4f}  grid {t['grid_rmse_rel']:.4f}  <- {', '.join(t['inputs'])}"
        )
    return 0


def _cmd_validate(args: argparse.Namespace) -> int:
    from hexgym.validate import run_validation

    print(json.dumps(run_validation(args.out), indent=2))
    print(f"plots: {Path(args.out)}/test1.png, test2.png, test3.png")
    return 0


def _cmd_build_assets(args: argparse.Namespace) -> int:
    from hexgym import meshes, mjcf
    from hexgym.files import atomic_path

    directory = Path(args.dir)
    for path in meshes.write_meshes(directory / "meshes"):
        print(f"wrote {path} ({path.stat().st_size} bytes)")
    for name, lean in (("cat325.xml", False), ("cat325_lean.xml", True)):
        mjcf.write_model(directory / name, lean=lean)
        print(f"wrote {directory / name}")
    scene_lean = directory / "scene_lean.xml"
    with atomic_path(scene_lean) as tmp:
        tmp.write_text(mjcf.lean_scene_xml((directory / "scene.xml").read_text()))
    print(f"wrote {scene_lean}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with all subcommands."""
    from hexgym.collect import add_collect_parser

    parser = argparse.ArgumentParser(
        prog="hexgym", description="A hydraulic excavator (Cat 325 class) simulator for robot learning."
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    demo = sub.add_parser("demo", help="replay a scripted spool sequence and write an MP4 and a PNG")
    demo.add_argument("--out", default="out", help="output directory (default: out)")
    demo.add_argument("--fps", type=float, default=20.0, help="video frame rate (default: 20)")
    demo.add_argument("--width", type=int, default=960, help="frame width in pixels (default: 960)")
    demo.add_argument("--height", type=int, default=544, help="frame height in pixels (default: 544)")
    demo.set_defaults(func=_cmd_demo)

    model = sub.add_parser("model", help="print the machine model's masses, joint ranges and cylinders")
    model.add_argument("--json", action="store_true", help="print JSON")
    model.set_defaults(func=_cmd_model)

    simulate = sub.add_parser("simulate", help="replay a spool command log (CSV) and write the trajectory (CSV)")
    simulate.add_argument(
        "--model", choices=["reference", "learned"], default="reference", help="machine model (default: reference)"
    )
    simulate.add_argument("--commands", required=True, help="command log CSV: t,swing,boom,stick,bucket (s, mm)")
    simulate.add_argument("--out", required=True, help="trajectory CSV to write")
    simulate.add_argument("--start", default="home", help="keyframe to start from (default: home)")
    simulate.add_argument("--payload-kg", type=float, default=0.0, help="material in the bucket, kg (default: 0)")
    simulate.add_argument("--dt-out", type=float, default=0.05, help="output row interval, s (default: 0.05)")
    simulate.set_defaults(func=_cmd_simulate)

    report = sub.add_parser(
        "reference-report", help="reference model: full-spool speeds, interaction plots (Figs 5-8), speed"
    )
    report.add_argument("--out", default="out/reference", help="output directory (default: out/reference)")
    report.set_defaults(func=_cmd_reference_report)

    add_collect_parser(sub)

    fit = sub.add_parser("fit", help="fit the four MBL tables (LWR + leave-one-out selection) from collected data")
    fit.add_argument("--data", default="data", help="directory with <table>.npz data sets (default: data)")
    fit.add_argument("--out", default=None, help="where to write the tables (default: the packaged tables)")
    fit.add_argument("--seed", type=int, default=0, help="seed of the held-out split and the search (default: 0)")
    fit.add_argument("--tables", default="", help="comma-separated subset, e.g. boom,stick (default: all)")
    fit.set_defaults(func=_cmd_fit)

    tables = sub.add_parser("tables", help="the fitted tables: inputs, output, points, parameters, accuracy")
    tables.add_argument("--json", action="store_true", help="print JSON")
    tables.add_argument("--dir", default=None, help="table directory (default: the packaged tables)")
    tables.add_argument("--bench", metavar="DATA", default=None, help="also time lookups vs direct LWR on DATA")
    tables.set_defaults(func=_cmd_tables)

    validate = sub.add_parser(
        "validate", help="learned vs reference model on the paper's three tests: plots, tip errors, speed"
    )
    validate.add_argument("--out", default="out/validate", help="output directory (default: out/validate)")
    validate.set_defaults(func=_cmd_validate)

    build = sub.add_parser("build-assets", help="regenerate assets/meshes and assets/cat325.xml (developers)")
    build.add_argument("--dir", default=str(Path(__file__).resolve().parent.parent / "assets"), help="assets dir")
    build.set_defaults(func=_cmd_build_assets)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``hexgym`` console command."""
    os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen rendering without a display
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError, RuntimeError) as exc:
        print(f"hexgym {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())

"""The ``hexgym`` command line: one subcommand per job, each with ``--help``.

Errors a user can cause (a bad option value, a file that is missing, malformed or cannot be
written, a policy or table that does not fit) end as one line on stderr, ``hexgym <command>: error:
...`` naming the file, option or value and what is wrong, with exit status 2 and no traceback;
``--debug`` (anywhere on the line) or ``HEXGYM_DEBUG=1`` shows the traceback instead. Options and
paths are checked before a command starts its work (:func:`check_arguments`): outputs that cannot
be written (a directory, under a file, read-only, the same file as an input) are refused up front.
An unexpected exception is one line with status 2 too, naming its type, with a pointer to ``--debug``
(an input hexgym does not check yet, or a bug).

Standard output carries a command's result alone (its figures, a JSON document or a table); standard error carries
its progress (:mod:`hexgym_lab.progress`: one style for every long command, off with ``--quiet`` anywhere on the
line or when standard error is not a terminal) and, at the end, a ``wrote PATH (what)`` line for each output. An
``--out`` is a file where a command makes one file and a directory where it makes several; each help says which.
No command writes inside the installed package unless it is named as an output.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from hexgym.agents import POLICY_NAMES  # names only: no MuJoCo
from hexgym.hydraulics.circuit import DEFAULT_VALVE, VALVE_LAYOUTS  # names only: no MuJoCo
from hexgym.mbl.schema import DEFAULT_TABLE_SET, TABLE_SETS  # names only: no MuJoCo

_REPOSITORY = Path(__file__).resolve().parents[1]
_REPOSITORY_ASSETS = _REPOSITORY / "assets"  # where build-assets writes by default, in a source checkout


DEFAULT_FIT_DIR = "tables"  # hexgym fit writes <this>/<table set>/ under the working directory by default


def _source_checkout() -> bool:
    """Whether hexgym runs from its source tree (a git checkout, editable install), not an installed copy."""
    return all((_REPOSITORY / name).exists() for name in ("pyproject.toml", "native", "assets"))


def _cmd_demo(args: argparse.Namespace) -> int:
    from hexgym_lab.agents.demo import run_demo
    from hexgym_lab.progress import wrote

    result = run_demo(args.out, fps=args.fps, width=args.width, height=args.height, duration=args.seconds)
    metrics = result["metrics"]
    print(f"scripted loader: {metrics['delivered_t']:.2f} t delivered in {metrics['sim_seconds']:g} s, "
          f"{metrics['dumps']} dumps, {metrics['fuel_l']:.2f} L fuel")  # fmt: skip
    wrote(result["video"], "the film")
    wrote(result["snapshot"], "a frame of it")
    return 0


def _cmd_bench(args: argparse.Namespace) -> int:
    from hexgym_lab.bench import print_bench, run_bench

    print_bench(run_bench(steps=args.steps, seed=args.seed, seconds=args.seconds), args.json)
    return 0


def _cmd_scripted(args: argparse.Namespace) -> int:
    from hexgym.agents.scripted import load_settings, run_scripted
    from hexgym.envs.loading import HexLoadingEnv
    from hexgym.files import write_json
    from hexgym_lab.progress import Progress, wrote

    settings = load_settings(args.loader_settings)
    env = HexLoadingEnv(time_limit=args.seconds)
    runs = []
    with Progress(args.episodes, "scripted", "episode") as progress:
        for i in range(args.episodes):
            runs.append(run_scripted(env, seed=args.seed + i, settings=settings))
            progress.update()
            print(json.dumps({k: v for k, v in runs[-1].items() if k != "return_terms"}), flush=True)
    if args.json:
        wrote(write_json(args.json, runs), "the runs' figures")
    return 0


def _cmd_tune_loader(args: argparse.Namespace) -> int:
    from dataclasses import asdict

    from hexgym.agents.scripted import load_settings
    from hexgym.checks import parse_seeds
    from hexgym_lab.agents.loader_search import tune_loader

    start = load_settings(args.loader_settings)
    settings, score = tune_loader(args.out, parse_seeds(args.seeds), generations=args.generations,
                                  population=args.population, spill_target=args.spill_target,
                                  seed=args.seed, start=start)  # fmt: skip
    from hexgym_lab.progress import wrote

    print(json.dumps({"settings": asdict(settings), "score": asdict(score)}, indent=2))
    wrote(args.out, "the best settings found")
    return 0


def _cmd_model(args: argparse.Namespace) -> int:
    from hexgym_lab.model_info import model_summary, model_table

    summary = model_summary()
    print(json.dumps(summary, indent=2) if args.json else model_table(summary))
    return 0


def _cmd_simulate(args: argparse.Namespace) -> int:
    from hexgym.model.commandlog import read_command_log, write_trajectory_csv
    from hexgym.model.replay import check_replay_size, replay

    _check_simulate_outputs(args)
    commands = read_command_log(args.commands)
    start = _start_pose(args)
    check_replay_size(commands.duration, args.dt_out)  # before building the model
    if args.model == "reference":
        from hexgym.hydraulics.reference import ReferenceModel

        model = ReferenceModel(hydraulics=args.hydraulics)
    else:
        from hexgym.model.backend import make_learned_model

        model = make_learned_model(args.backend, tables_dir=args.tables_dir, table_set=args.tables)
    from hexgym_lab.progress import wrote

    if args.machine_log is None:
        trajectory = replay(model, commands, start=start, payload_kg=args.payload_kg, dt_out=args.dt_out)
    else:  # every step for the logger's samples; the trajectory's rows are every dt_out / step-th of them
        fine = replay(model, commands, start=start, payload_kg=args.payload_kg, dt_out=model.control_period)
        _write_machine_log(args, fine)
        steps = int(round(args.dt_out / model.control_period))
        trajectory = fine[::steps][: check_replay_size(commands.duration, args.dt_out)]
    if args.out is not None:
        write_trajectory_csv(args.out, trajectory)
        wrote(args.out, f"the trajectory: {len(trajectory)} rows, {commands.duration:g} s simulated")
    if args.machine_log is not None:
        wrote(args.machine_log, f"the run as a machine log at {args.rate or 100:g} Hz")
    return 0


def _check_simulate_outputs(args: argparse.Namespace) -> None:
    """At least one output; the machine log's options only with it; one start."""
    if args.out is None and args.machine_log is None:
        raise ValueError("give --out (the trajectory), --machine-log (the run as a machine log) or both")
    if args.machine_log is None:
        for name in ("rate", "jitter", "sensor_noise", "seed"):
            if getattr(args, name) is not None:
                raise ValueError(f"--{name.replace('_', '-')} (the machine log's) does not apply without --machine-log")
    if args.jitter is not None and not 0.0 <= args.jitter < 1.0:
        raise ValueError(f"--jitter must be from 0 to below 1 (a share of the sample period), got {args.jitter!r}")
    if args.start is not None and args.start_from is not None:
        raise ValueError("--start and --start-from: give one of them")
    if args.mapping is not None and args.start_from is None:
        raise ValueError("--mapping (an MCAP log's topics) applies only with --start-from")


def _start_pose(args: argparse.Namespace):
    """The start: a keyframe name, four angles (rad) or a log's first measured pose, checked against the joints'
    ranges."""
    from hexgym.machine.kinematics import check_joint_angles

    if args.start_from is not None:
        import numpy as np

        from hexgym_lab.machine_logs import read_machine_log

        log = read_machine_log(args.start_from, args.mapping)
        q = log.angles()
        good = np.flatnonzero(np.isfinite(log.t) & np.all(np.isfinite(q), axis=1)) if q is not None else []
        if not len(good):
            raise ValueError(f"--start-from {args.start_from}: no sample with all four joint angles (or the swing "
                             "angle and the cylinder strokes)")  # fmt: skip
        first = good[int(np.argmin(log.t[good]))]
        return check_joint_angles(q[first], f"--start-from {args.start_from} (its pose at t {log.t[first]:g} s)")
    from hexgym_lab.view import parse_start

    return parse_start(args.start or "home")


def _write_machine_log(args: argparse.Namespace, rows) -> None:
    from hexgym_lab.machine_logs.csv_log import write_csv_log
    from hexgym_lab.machine_logs.synthetic import machine_log_of, parse_noise

    noise = parse_noise(args.sensor_noise or "default")
    t, signals = machine_log_of(rows, rate_hz=args.rate or 100.0, noise=noise, jitter=args.jitter or 0.0,
                                seed=args.seed or 0, payload_kg=args.payload_kg)  # fmt: skip
    write_csv_log(args.machine_log, t, signals)


def _cmd_check_log(args: argparse.Namespace) -> int:
    from hexgym_lab.machine_logs import read_machine_log
    from hexgym_lab.machine_logs.checks import check_log, trusted
    from hexgym_lab.progress import track

    status, report = 0, []
    for path in track(args.logs, "check-log", "log"):
        log = read_machine_log(path, args.mapping)
        findings = check_log(log)
        status = status if trusted(findings) else 1
        if args.json:
            report.append({"log": str(path), "trusted": trusted(findings), "findings": [f.as_dict() for f in findings]})
            continue
        for finding in findings:
            print(finding.line())
        rate = (len(log.t) - 1) / max(float(log.t[-1] - log.t[0]), 1e-9)
        verdict = "trusted" if trusted(findings) else "cannot be trusted"
        print(f"{path}: {verdict}: {len(log.t)} samples, t {log.t[0]:g}-{log.t[-1]:g} s (~{rate:.0f} Hz), "
              f"{sum(f.severity == 'error' for f in findings)} errors, "
              f"{sum(f.severity == 'warning' for f in findings)} warnings")  # fmt: skip
    if args.json:
        print(json.dumps(report, indent=2))
    return status


def _cmd_compare(args: argparse.Namespace) -> int:
    from hexgym_lab.compare import compare_logs, plot_comparison, require_plotting, summary_text
    from hexgym_lab.machine_logs import read_machine_log
    from hexgym_lab.progress import wrote

    if args.out:
        require_plotting()
    result = compare_logs(read_machine_log(args.a, args.mapping), read_machine_log(args.b, args.mapping))
    summary = {k: v for k, v in result.items() if k != "series"}
    print(json.dumps(summary, indent=2) if args.json else summary_text(result))
    if args.out:
        wrote(plot_comparison(result, args.out), "tip error and joints over time")
    return 0


def _cmd_reference_report(args: argparse.Namespace) -> int:
    from hexgym_lab.progress import wrote
    from hexgym_lab.reference_report import figures_table, run_report

    summary = run_report(args.out, valve=args.valve)
    print(json.dumps(summary, indent=2))
    print(figures_table(summary["published_figures"]), file=sys.stderr)  # stdout: the JSON document alone
    wrote(Path(args.out) / "summary.json", "the figures")
    wrote(Path(args.out) / "interactions.png", "the interaction plots")
    return 0


def _cmd_collect(args: argparse.Namespace) -> int:
    import time

    from hexgym_lab.mbl.collect import CollectConfig, collect, coverage_report
    from hexgym_lab.progress import wrote

    t0 = time.perf_counter()
    paths = collect(args.out, samples_per_group=args.samples, seed=args.seed, workers=args.workers,
                    config=CollectConfig(table_set=args.tables), ray=args.ray)  # fmt: skip
    print(f"collected in {time.perf_counter() - t0:.0f} s")
    print(coverage_report(paths))
    sys.stdout.flush()
    for table, path in paths.items():
        wrote(path, f"the {table} table's data set")
    wrote(Path(args.out) / "chunks", "the finished chunks a rerun resumes from")
    return 0


def _cmd_fit(args: argparse.Namespace) -> int:
    if args.logs is not None:
        return _fit_logs(args)
    from hexgym.files import check_input_dir
    from hexgym.mbl.schema import TABLE_SETS

    if args.data is None:
        args.data = str(check_input_dir("data", "input directory --data"))
    from hexgym_lab.mbl.fit import fit_all
    from hexgym_lab.progress import wrote

    tables = TABLE_SETS[args.tables]
    names = tuple(args.only.split(",")) if args.only else tuple(tables)
    unknown = set(names) - set(tables)
    if unknown:
        raise ValueError(f"--only: unknown table(s) {sorted(unknown)}; the {args.tables} tables are {list(tables)}")
    out = args.out or str(Path(DEFAULT_FIT_DIR) / args.tables)  # under the working directory, never the package
    from hexgym_lab.mbl.datafile import refuse_other_npz

    refuse_other_npz(out, names, "table")  # data sets where the tables go: refused before anything is read
    _check_data_files(args.data, names)
    for name, path in fit_all(args.data, out, seed=args.seed, names=names, table_set=args.tables).items():
        wrote(path, f"the {name} table")
    return 0


def _fit_logs(args: argparse.Namespace) -> int:
    """``fit --logs DIR --out MODEL_DIR``: the circuit tables fitted to a machine's logs."""
    from hexgym_lab.machine_logs.fit import coverage_report, fit_logs
    from hexgym_lab.progress import wrote

    given = getattr(args, "given", set())
    if args.out is None:
        raise ValueError("--logs: give --out MODEL_DIR, the fitted model's directory")
    if args.tables != "circuit":
        raise ValueError(f"--logs fits the circuit tables (the learned valve), not --tables {args.tables}")
    for option in ("data", "only"):
        if option in given:
            raise ValueError(f"--{option} does not apply with --logs (the logs are the data; every table is fitted)")
    provenance = fit_logs(args.logs, args.out, seed=args.seed, mapping=args.mapping)
    print(coverage_report(provenance))
    print(f"fitted in {provenance['fit_seconds']:.0f} s from {len(provenance['logs'])} logs "
          f"({len(provenance['logs_not_used'])} not used)")  # fmt: skip
    sys.stdout.flush()
    wrote(args.out, "the fitted model: the circuit tables and provenance.json (use it as --tables-dir or tables=)")
    return 0


def _cmd_excitation(args: argparse.Namespace) -> int:
    from hexgym_lab.machine_logs.excitation import ORDER, functions_with_gaps, start_pose, write_excitation
    from hexgym_lab.progress import wrote

    if args.functions and args.model:
        raise ValueError("--functions and --model: give one of them (--model sweeps the functions with gaps)")
    functions = tuple(f.strip() for f in args.functions.split(",")) if args.functions else ORDER
    if args.model:
        functions = functions_with_gaps(args.model)
        print(f"functions with gaps in {args.model}: {', '.join(functions) or 'none (only the pump-flow moves)'}")
    log = write_excitation(args.out, functions)
    pose = ",".join(f"{q:.4f}" for q in start_pose())
    wrote(args.out, f"the excitation command log: {log.duration:.0f} s from the pose --start {pose} (mid-stroke)")
    return 0


def _cmd_tables(args: argparse.Namespace) -> int:
    from hexgym_lab.mbl.fit import tables_summary

    summary = tables_summary(args.dir, args.tables)
    if args.bench:
        _check_data_files(args.bench, [t["name"] for t in summary])
        from hexgym_lab.mbl.fit import lookup_benchmark

        timings = lookup_benchmark(args.bench, args.dir, table_set=args.tables)
        for item in summary:
            item["seconds_per_query"] = timings[item["name"]]
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
    if args.logs is not None or args.model is not None:
        return _validate_logs(args)
    from hexgym_lab.validate import run_validation

    summary = run_validation(
        args.out,
        suite=args.suite,
        suite_seed=args.suite_seed,
        workers=args.workers,
        suite_only=args.suite_only,
        table_set=args.tables,
        tables_dir=args.tables_dir,
        ray=args.ray,
        payload_kg=args.payload_kg,
        suite_style=args.suite_style,
    )
    from hexgym_lab.progress import wrote

    print(json.dumps(summary, indent=2))
    plots = {} if args.suite_only else {f"test{i}.png": f"the paper's test {i}" for i in (1, 2, 3)}
    plots |= {} if args.suite_only else {"interactions.png": "the interactions, both models"}
    plots |= {"suite_worst.png": "the suite's worst log"} if args.suite else {}
    wrote(Path(args.out) / "summary.json", "the figures")
    for name, what in plots.items():
        wrote(Path(args.out) / name, what)
    return 0


def _validate_logs(args: argparse.Namespace) -> int:
    """``validate --model MODEL_DIR --logs DIR``: a fitted model and the packaged one against a machine's logs."""
    from hexgym.files import staged_dir
    from hexgym_lab.machine_logs.validate_logs import summary_text, validate_on_logs
    from hexgym_lab.progress import wrote

    if args.logs is None or args.model is None:
        raise ValueError("--model and --logs go together: the fitted model's directory and the logs to replay")
    result = validate_on_logs(args.model, args.logs, mapping=args.mapping)
    print(summary_text(result))
    with staged_dir(args.out, keep=False) as staging:
        (staging / "summary.json").write_text(json.dumps(result, indent=2))
    sys.stdout.flush()
    wrote(Path(args.out) / "summary.json", "the figures per log, fitted and packaged")
    return 0


def _cmd_build_assets(args: argparse.Namespace) -> int:
    from hexgym.files import atomic_path, staged_dir
    from hexgym.machine import mjcf
    from hexgym.machine.assets import LEAN_MODEL_FILE, LEAN_SCENE_FILE, SCENE_FILE, asset_path
    from hexgym.model.plugin import HEADER, write_interface_header
    from hexgym.model.plugin_mjcf import MBL_FULL_MODEL_FILE, MBL_MODEL_FILE, write_mbl_model
    from hexgym_lab import meshes
    from hexgym_lab.progress import wrote

    if args.dir is None:
        raise ValueError("--dir: give the directory to write (an installed hexgym has no assets/ of a source tree "
                         "to regenerate, and its package is not written)")  # fmt: skip
    directory = Path(args.dir)
    scene = directory / SCENE_FILE if (directory / SCENE_FILE).is_file() else asset_path(SCENE_FILE)
    written = []
    with staged_dir(directory) as staging:  # all of it or nothing: a failure leaves the directory as it was
        written += meshes.write_meshes(staging / "meshes")
        for name, lean in (("cat325.xml", False), ("cat325_lean.xml", True)):
            mjcf.write_model(staging / name, lean=lean)
            written.append(staging / name)
        written.append(write_mbl_model(staging / MBL_MODEL_FILE))
        written.append(write_mbl_model(staging / MBL_FULL_MODEL_FILE, full=True))
        if not (directory / SCENE_FILE).is_file():  # a new directory gets the packaged site
            with atomic_path(staging / SCENE_FILE) as tmp:
                tmp.write_text(scene.read_text())
            written.append(staging / SCENE_FILE)
        with atomic_path(staging / LEAN_SCENE_FILE) as tmp:
            tmp.write_text(mjcf.scene_xml_around(scene.read_text(), LEAN_MODEL_FILE))
        written.append(staging / LEAN_SCENE_FILE)
    for path in written:
        wrote(directory / Path(path).relative_to(staging))
    header = directory.resolve().parent / HEADER
    if _source_checkout() and directory.resolve() == _REPOSITORY_ASSETS:  # the plugin's interface, in native/
        wrote(write_interface_header(header), "the plugin's interface header, beside the repository's assets")
    return 0


def _cmd_train(args: argparse.Namespace) -> int:
    if args.framework == "rllib":
        if args.init_from is not None or args.n_envs is not None or args.vec_env != "auto":
            raise ValueError("--init-from, --n-envs and --vec-env are for --framework sb3 (RLlib: --num-env-runners)")
        from hexgym_lab.agents.rllib import train_rllib

        path = train_rllib(args.algo, args.env, timesteps=args.timesteps, seed=args.seed, log_dir=args.log_dir,
                           hyperparams=args.hyperparams, num_env_runners=args.num_env_runners, ray=args.ray,
                           checkpoint_every=args.checkpoint_every)  # fmt: skip
        from hexgym_lab.progress import wrote

        wrote(path, "the RLlib checkpoint")
        return 0
    if args.num_env_runners is not None or args.ray is not None:
        raise ValueError("--num-env-runners and --ray are for --framework rllib")
    from hexgym.agents.policy_files import normalizer_path
    from hexgym_lab.agents.training import train
    from hexgym_lab.progress import wrote

    path = train(args.algo, args.env, timesteps=args.timesteps, seed=args.seed, log_dir=args.log_dir,
                 hyperparams=args.hyperparams, n_envs=args.n_envs, init_from=args.init_from,
                 checkpoint_every=args.checkpoint_every, progress_bar=not args.no_progress,
                 vec_env=args.vec_env)  # fmt: skip
    wrote(path, "the trained model")
    wrote(normalizer_path(path), "its observation normaliser")
    wrote(Path(path).parent / "curve.csv", "the learning curve")
    wrote(Path(path).parent / "checkpoints", "the checkpoints a rerun resumes from")
    return 0


def _cmd_clone(args: argparse.Namespace) -> int:
    from hexgym_lab.agents.training import clone_scripted

    path = clone_scripted(args.out, episodes=args.episodes, dagger_rounds=args.dagger_rounds,
                          dagger_episodes=args.dagger_episodes, epochs=args.epochs, seed=args.seed, noise=args.noise,
                          hyperparams=args.hyperparams, select_episodes=args.select_episodes,
                          rounds_dir=args.rounds_dir, loss=args.loss, tables=args.tables,
                          loader_settings=args.loader_settings)  # fmt: skip
    from hexgym.agents.policy_files import normalizer_path
    from hexgym_lab.progress import wrote

    wrote(path, "the cloned model")
    wrote(normalizer_path(path), "its observation normaliser")
    if args.rounds_dir:
        wrote(args.rounds_dir, "each round's clone, round<k>.zip")
    return 0


def _cmd_select(args: argparse.Namespace) -> int:
    from hexgym.agents.policy_files import normalizer_path
    from hexgym.checks import parse_seeds
    from hexgym.files import write_json
    from hexgym_lab.agents.select import select_checkpoint
    from hexgym_lab.progress import wrote

    sets = [parse_seeds(part) for part in args.seeds.split(",")]
    rows = select_checkpoint(args.checkpoints, args.out, [(seeds[0], len(seeds)) for seeds in sets])
    kept = next(row for row in rows if row["selected"])
    print(json.dumps({"selected": kept, "checkpoints": rows}, indent=2))
    wrote(args.out, f"the selected checkpoint ({kept['steps']} steps)")
    wrote(normalizer_path(args.out), "its observation normaliser")
    if args.json:
        wrote(write_json(args.json, {"selected": kept, "checkpoints": rows}), "every checkpoint's figures")
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from hexgym.envs import ENV_ID
    from hexgym.files import write_json
    from hexgym_lab.agents.evaluate import evaluate, evaluate_success
    from hexgym_lab.progress import wrote

    if args.env != ENV_ID:
        if args.policy == "shipped" or args.model != "learned" or args.ray or args.workers != 1 or args.loader_settings:
            raise ValueError(f"--env {args.env}: give a model .zip trained on it (--policy PATH; 'scripted' on "
                             "HexDig-v0); --model, --ray, --workers and --loader-settings are for "
                             "HexLoading-v0")  # fmt: skip
        env_kwargs = {"time_limit": args.seconds} if args.seconds is not None else None
        result = evaluate_success(args.policy, args.env, args.episodes, args.seed, env_kwargs)
        print(json.dumps(result, indent=2))
        if args.json:
            wrote(write_json(args.json, result), "the figures")
        return 0
    env_kwargs = {"model": args.model} | ({"time_limit": args.seconds} if args.seconds is not None else {})
    if args.tables != DEFAULT_TABLE_SET:  # with --model reference, the environment refuses it in one line
        env_kwargs["tables"] = args.tables
    env_kwargs |= _robustness_options(args, env_kwargs)
    result = evaluate(args.policy, episodes=args.episodes, seed=args.seed, env_kwargs=env_kwargs, json_out=args.json,
                      workers=args.workers, ray=args.ray, loader_settings=args.loader_settings)  # fmt: skip
    print(json.dumps({k: v for k, v in result.items() if k != "per_episode"}, indent=2))
    if args.json:
        wrote(args.json, "the figures, per episode too")
    return 0


ROBUSTNESS_OPTIONS = ("site_ranges", "material_density_scale", "engine_power_scale")  # HexLoading-v0's, by flag


def _robustness_options(args: argparse.Namespace, env_kwargs: dict) -> dict:
    """The robustness options given (``--site-ranges``, ``--material-density-scale``, ``--engine-power-scale``) as
    HexLoading-v0's keywords, checked here: ValueError naming the flag and the value."""
    from hexgym.envs.loading import LoadingConfig

    given = {name: getattr(args, name) for name in ROBUSTNESS_OPTIONS if getattr(args, name) is not None}
    for name, value in given.items():
        try:
            LoadingConfig(**{k: v for k, v in env_kwargs.items() if k != "time_limit"}, **{name: value})
        except ValueError as exc:
            raise ValueError(f"--{name.replace('_', '-')} {value}: {exc}") from None
    return given


def _cmd_curves(args: argparse.Namespace) -> int:
    from hexgym.files import write_json
    from hexgym_lab.agents.curves import plot_curves, read_curve, summarise
    from hexgym_lab.progress import wrote

    curves = {str(run): read_curve(run) for run in args.runs}
    summary = summarise(curves, args.success_level)
    print(json.dumps(summary, indent=2))
    wrote(plot_curves(curves, args.out, args.title), "the figure")
    if args.json:
        wrote(write_json(args.json, summary), "the summary")
    return 0


def _cmd_shield(args: argparse.Namespace) -> int:
    from hexgym_lab.progress import wrote
    from hexgym_lab.shield import compare, print_comparison

    result = compare(args.policy, args.episodes, args.seed, args.seconds, args.horizon, json_out=args.json)
    print_comparison(result)
    if args.json:
        wrote(args.json, "the figures, per episode too")
    if args.plot:
        from hexgym_lab.shield import plot_comparison

        wrote(plot_comparison(result, args.plot), "the figures per episode")
    return 0


def _cmd_plan(args: argparse.Namespace) -> int:
    from hexgym.checks import parse_seeds
    from hexgym_lab.plan import run_plan
    from hexgym_lab.progress import wrote

    if args.video is not None and not args.video.endswith(".mp4"):
        raise ValueError(f"--video must be an .mp4 file, got {args.video}")
    seeds = parse_seeds(args.seeds) if args.seeds is not None else [args.seed]
    result = run_plan(args.task, seeds, w_fuel=args.w_fuel, budget=args.budget, nthread=args.threads,
                      json_out=args.json, margin_m=args.margin, ray=args.ray, check=not args.no_check,
                      swing=args.swing, workers=args.workers, population=args.population)  # fmt: skip
    shown = result.get("summary", {k: v for k, v in result.items() if not k.endswith("_mm") and k != "paths"})
    print(json.dumps(shown, indent=2))
    if args.plot:
        from hexgym_lab.plan import plot_plan

        wrote(plot_plan(result.get("per_seed", [result])[0], args.plot), "the (first) seed's plan")
    if args.video:
        from hexgym_lab.plan import plan_video

        wrote(plan_video(result.get("per_seed", [result])[0], args.video), "the (first) seed's move, filmed")
    if args.json:
        wrote(args.json, "the figures, every seed's")
    return 0


def _cmd_video(args: argparse.Namespace) -> int:
    from hexgym_lab.agents.video import record_video

    result = record_video(
        args.policy, args.out, camera=args.camera, episodes=args.episodes, seed=args.seed, seconds=args.seconds,
        width=args.width, height=args.height, snapshot=args.snapshot, model=args.model, env_id=args.env,
    )  # fmt: skip
    from hexgym_lab.progress import wrote

    wrote(result["video"], f"the film, {result['frames']} frames")
    if "snapshot" in result:
        wrote(result["snapshot"], "a frame from the first episode's middle")
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    from hexgym_lab.view import ViewSite, key_help, parse_start, run_viewer

    site = ViewSite(parse_start(args.start), payload_kg=args.payload_kg, seed=args.seed)
    print(key_help())
    limits = {"seconds": args.seconds, "frames": args.frames, "screenshot": args.screenshot}
    result = run_viewer(site, **limits, camera=args.camera, panels=args.panels)
    spools = ", ".join(f"{v:+.2f}" for v in result["spools_mm"])
    print(f"viewer closed after {result['sim_seconds']:.2f} s simulated, {result['frames']} frames; spools {spools} mm")
    if args.screenshot:
        from hexgym_lab.progress import wrote

        wrote(args.screenshot, "the window before it closed")
    return 0


def _cmd_convert_normalizer(args: argparse.Namespace) -> int:
    from hexgym.agents.policy_files import convert_pickled_normalizer
    from hexgym_lab.progress import wrote

    wrote(convert_pickled_normalizer(args.pkl, args.out), "the normaliser as JSON")
    return 0


def _check_data_files(directory: str, names: list[str] | tuple[str, ...]) -> None:
    """Each table's data set in ``directory`` exists and is well formed (before minutes of fitting)."""
    from hexgym.files import check_input_dir
    from hexgym_lab.mbl.datafile import check_dataset_file

    check_input_dir(directory, "data directory")
    for name in names:
        check_dataset_file(Path(directory) / f"{name}.npz")


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line: the command, the option and the problem."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} (see {self.prog} --help)\n")


_MACHINE_MODEL_OPTION = {  # --model of the commands that run a policy on HexLoading-v0
    "choices": ["learned", "reference"],
    "default": "learned",
    "help": "machine model: the learned one (default) or the reference (the real machine's stand-in: the same "
    "task on the analytical circuit; a few times real time)",
}
_TABLES_OPTION = {  # --tables of the commands that use the learned model's tables
    "choices": tuple(TABLE_SETS),
    "default": DEFAULT_TABLE_SET,
    "help": "the learned model's table set: paper (the paper's four tables) or circuit (the open-centre circuit "
    f"with a learned valve) (default: {DEFAULT_TABLE_SET})",
}

_LOADER_SETTINGS_OPTION = {  # --loader-settings of the commands that run the scripted loader
    "dest": "loader_settings",
    "default": None,
    "metavar": "FILE",
    "help": "the scripted loader's settings (JSON, e.g. from hexgym tune-loader; default: its hand-set ones)",
}


def add_ray_option(parser: argparse.ArgumentParser, what: str = "the tasks") -> None:
    """Add ``--ray [ADDRESS]`` to a command's parser (dest ``ray``: None, "local" or the address; no Ray is
    imported until a command runs with it, :mod:`hexgym.parallel`)."""
    parser.add_argument(
        "--ray",
        nargs="?",
        const="local",
        default=None,
        metavar="ADDRESS",
        help=f"run {what} as Ray tasks: alone, on a Ray started here with this machine's cores; with "
        "HOST:PORT (or auto), on that running cluster (needs hexgym[cluster]; default: a local process pool)",
    )


def _add_mapping_option(parser: argparse.ArgumentParser, applies_to: str) -> None:
    """Add ``--mapping FILE.yaml`` (an MCAP log's topics and fields to the machine-log signals) to a command."""
    parser.add_argument("--mapping", default=None, metavar="FILE.yaml", help=f"{applies_to}: their topics and fields "
                        "to signals (docs/machine-logs.md)")  # fmt: skip


def _whole_number(text: str) -> int:
    """An integer option's value: digits and a sign only (``int`` also takes ``1_0``)."""
    from hexgym.checks import parse_int

    try:
        return parse_int(text, "value")
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid int value: {text!r} (a whole number: digits only)") from None


def _decimal_number(text: str) -> float:
    """A float option's value: digits, a point and an exponent (``float`` also takes ``1_0``, ``0x``-less hex
    words, spaces); ``nan`` and ``inf`` are read, and refused by the option's range check, which names it."""
    from hexgym.checks import parse_float

    try:
        return parse_float(text, "value", finite=False)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"invalid float value: {text!r} (digits, a point and an exponent: no underscores, hex or words)"
        ) from None


def _strict_numbers(parser: argparse.ArgumentParser) -> None:
    """Every ``type=int``/``type=float`` option of ``parser`` and its subcommands parsed strictly."""
    for action in parser._actions:
        if action.type is int:
            action.type = _whole_number
        elif action.type is float:
            action.type = _decimal_number
        for sub in (action.choices or {}).values() if isinstance(action, argparse._SubParsersAction) else ():
            _strict_numbers(sub)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with all subcommands (numbers parsed strictly: :func:`_strict_numbers`)."""
    from hexgym_lab.agents.loader_search import MIN_POPULATION
    from hexgym_lab.mbl.collect import DEFAULT_SAMPLES

    parser = _Parser(prog="hexgym", description="A hydraulic excavator (Cat 325 class) simulator for robot learning.")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error (or HEXGYM_DEBUG=1)")
    parser.add_argument("--quiet", action="store_true", help="no progress on standard error (anywhere on the "
                        "line; also when it is not a terminal; HEXGYM_PROGRESS=bar|lines|off chooses)")  # fmt: skip
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    demo = sub.add_parser("demo", help="the scripted loader on HexLoading-v0, filmed: an MP4 and a PNG")
    demo.add_argument("--out", default="out", metavar="DIR", help="output directory: demo.mp4 (the film) and "
                      "demo.png (a frame of it) (default: out)")  # fmt: skip
    demo.add_argument(
        "--fps", type=float, default=None, help="playback rate; frames are taken at 10 Hz (default: 10, real time)"
    )
    demo.add_argument("--seconds", type=float, default=60.0, help="simulated time (default: 60)")
    demo.add_argument("--width", type=int, default=960, help="frame width in pixels (default: 960)")
    demo.add_argument("--height", type=int, default=544, help="frame height in pixels (default: 544)")
    demo.set_defaults(func=_cmd_demo)

    bench = sub.add_parser("bench", help="HexLoading-v0 vs Gymnasium Hopper-v5 steps per second, one process")
    bench.add_argument("--steps", type=int, default=2000, help="random steps per environment (default: 2000)")
    bench.add_argument("--seed", type=int, default=0, help="seed of the resets and actions (default: 0)")
    bench.add_argument("--seconds", type=float, default=2.0, help="wall seconds per real-time factor (default: 2)")
    bench.add_argument("--json", metavar="OUT", default=None, help="also write the figures to this JSON file")
    bench.set_defaults(func=_cmd_bench)

    scripted = sub.add_parser("scripted", help="run the scripted loader on HexLoading-v0: cycles, t/h, fuel")
    scripted.add_argument("--episodes", type=int, default=1, help="episodes, seeds seed..seed+N-1 (default: 1)")
    scripted.add_argument("--seed", type=int, default=0, help="first seed (default: 0)")
    scripted.add_argument("--seconds", type=float, default=180.0, help="episode time budget, s (default: 180)")
    scripted.add_argument("--json", metavar="OUT", default=None, help="also write the runs to this JSON file")
    scripted.add_argument("--loader-settings", **_LOADER_SETTINGS_OPTION)
    scripted.set_defaults(func=_cmd_scripted)

    tune = sub.add_parser("tune-loader", help="search the scripted loader's settings (CMA-ES) for t/h at low spill")
    tune.add_argument("--out", required=True, metavar="FILE.json", help="output file: the best settings found "
                      "(JSON, for --loader-settings), rewritten after each generation")  # fmt: skip
    tune.add_argument("--seeds", default="100-105", metavar="A-B", help="episode seeds scored (default: 100-105)")
    tune.add_argument("--generations", type=int, default=14, help="CMA-ES generations (default: 14)")
    tune.add_argument("--population", type=int, default=10, help=f"candidates per generation, at least "
                      f"{MIN_POPULATION}: CMA-ES learns its covariance from them (default: 10)")  # fmt: skip
    tune.add_argument("--spill-target", type=float, default=0.05, help="spilled fraction above which the score "
                      "is penalised (default: 0.05)")  # fmt: skip
    tune.add_argument("--seed", type=int, default=1, help="the search's own seed (default: 1)")
    tune.add_argument("--loader-settings", dest="loader_settings", default=None, metavar="FILE",
                      help="the search's start (JSON, e.g. an earlier search's --out; default: the hand-set "
                      "settings); its settings for teaching are held, not searched")  # fmt: skip
    tune.set_defaults(func=_cmd_tune_loader)

    model = sub.add_parser("model", help="print the machine model's masses, joint ranges and cylinders: a table")
    model.add_argument("--json", action="store_true", help="print JSON (the same figures, SI units, for programs)")
    model.set_defaults(func=_cmd_model)

    simulate = sub.add_parser("simulate", help="replay a spool command log (CSV) and write the trajectory (CSV)")
    simulate.add_argument(
        "--model", choices=["reference", "learned"], default="reference", help="machine model (default: reference)"
    )
    simulate.add_argument("--commands", required=True, help="command log CSV: t,swing,boom,stick,bucket (s, mm)")
    simulate.add_argument("--out", default=None, metavar="FILE.csv", help="output file: the trajectory (CSV, "
                          "a row per --dt-out; columns: docs/machine.md, trajectory format)")  # fmt: skip
    simulate.add_argument("--start", default=None, help="keyframe to start from, or four joint angles "
                          "'q_swing,q_boom,q_stick,q_bucket' (rad, within the joints' ranges) "
                          "(default: home)")  # fmt: skip
    simulate.add_argument("--start-from", default=None, metavar="LOG", help="start at a machine log's first "
                          "measured pose (CSV, or MCAP with --mapping; docs/machine-logs.md)")  # fmt: skip
    _add_mapping_option(simulate, "--start-from an MCAP log")
    simulate.add_argument("--hydraulics", default=None, metavar="FILE", help="reference: a unit that is not the "
                          "packaged one, YAML or JSON (passage areas, pumps, reliefs, leakage; "
                          "docs/machine-logs.md)")  # fmt: skip
    simulate.add_argument("--machine-log", default=None, metavar="FILE.csv", help="reference: also an output file: "
                          "the run as a machine log (CSV, docs/machine-logs.md)")  # fmt: skip
    simulate.add_argument("--rate", type=float, default=None, help="--machine-log: samples per second (default: 100)")
    simulate.add_argument("--jitter", type=float, default=None, help="--machine-log: each sample time moved by up "
                          "to ±jitter/2 of a period, uniformly (0 to below 1; default: 0)")  # fmt: skip
    simulate.add_argument("--sensor-noise", default=None, metavar="SPEC", help="--machine-log: Gaussian noise, "
                          "'default' (pressure_pa=2e5,angle_rad=0.001745,spool_mm=0), 'off' or kind=sigma,... "
                          "(default: default)")  # fmt: skip
    simulate.add_argument("--seed", type=int, default=None, help="--machine-log: the noise's and jitter's seed "
                          "(default: 0)")  # fmt: skip
    simulate.add_argument("--payload-kg", type=float, default=0.0, help="material in the bucket, kg (default: 0)")
    simulate.add_argument("--dt-out", type=float, default=0.05, help="output row interval, s (default: 0.05)")
    simulate.add_argument("--tables", **_TABLES_OPTION)
    simulate.add_argument("--tables-dir", default=None, metavar="DIR", help="learned model: the tables' directory, "
                          "e.g. a model fitted by `hexgym fit --logs` (default: the packaged ones)")  # fmt: skip
    simulate.add_argument(
        "--backend",
        choices=("auto", "python", "native"),
        default="auto",
        help="learned model: native plugin or Python (default: auto = native when built)",
    )
    simulate.set_defaults(func=_cmd_simulate)

    check_log = sub.add_parser("check-log", help="check machine logs: time, missing signals, NaN runs, units, stuck "
                               "sensors, signs, motion; exit 1 when one cannot be trusted")  # fmt: skip
    check_log.add_argument("logs", nargs="+", metavar="LOG", help="machine logs: CSV, or MCAP with --mapping")
    _add_mapping_option(check_log, "MCAP logs")
    check_log.add_argument("--json", action="store_true", help="print the findings as JSON")
    check_log.set_defaults(func=_cmd_check_log)

    compare = sub.add_parser("compare", help="score two runs (trajectories or machine logs): tip and joint errors "
                             "over their common time")  # fmt: skip
    compare.add_argument("a", metavar="A", help="a trajectory CSV or a machine log")
    compare.add_argument("b", metavar="B", help="another, compared with A")
    _add_mapping_option(compare, "MCAP logs")
    compare.add_argument("--out", default=None, metavar="FILE.png", help="output file: a plot of the tip error and "
                         "the joints over time (needs matplotlib)")  # fmt: skip
    compare.add_argument("--json", action="store_true", help="print the figures as JSON")
    compare.set_defaults(func=_cmd_compare)

    report = sub.add_parser(
        "reference-report", help="reference model: full-spool speeds, interaction plots (Figs 5-8), speed"
    )
    report.add_argument("--out", default="out/reference", metavar="DIR", help="output directory: summary.json "
                        "(the figures) and interactions.png (default: out/reference)")  # fmt: skip
    report.add_argument(
        "--valve",
        choices=tuple(VALVE_LAYOUTS),
        default=DEFAULT_VALVE,
        help="main valve: a Cat two-pump valve (both pumps on boom and stick, swing and boom priority, "
        f"regeneration), or the paper's simplified schematic (default: {DEFAULT_VALVE})",
    )
    report.set_defaults(func=_cmd_reference_report)

    collect = sub.add_parser(
        "collect", help="drive the reference model through motion sequences: MBL training data (slow, resumable)"
    )
    collect.add_argument("--out", default="data", metavar="DIR", help="output directory: <table>.npz (a data set "
                         "per table) and chunks/ (what a rerun resumes from) (default: data)")  # fmt: skip
    collect.add_argument(
        "--samples",
        type=int,
        default=DEFAULT_SAMPLES,
        help=f"samples per group: of the boom/bucket and of the stick tables (default: {DEFAULT_SAMPLES})",
    )
    collect.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    collect.add_argument("--workers", type=int, default=2, help="worker processes (default: 2)")
    add_ray_option(collect, "the chunks")
    collect.add_argument(
        "--tables",
        choices=tuple(TABLE_SETS),
        default=DEFAULT_TABLE_SET,
        help="which table set's data: paper (held-spool segments) or circuit (the valve's passages, from logs "
        "that sweep the spools) "
        f"(default: {DEFAULT_TABLE_SET})",
    )
    collect.set_defaults(func=_cmd_collect)

    fit = sub.add_parser("fit", help="fit the four MBL tables (LWR + leave-one-out selection) from collected data")
    fit.add_argument("--data", default=None, help="directory with <table>.npz data sets (default: data)")
    fit.add_argument("--out", default=None, metavar="DIR", help="output directory: <table>.npz, a fitted table "
                     f"each (default: {DEFAULT_FIT_DIR}/<--tables> in the working directory; to replace the packaged "
                     "tables, name their directory, hexgym/mbl_tables/<--tables>)")  # fmt: skip
    fit.add_argument("--seed", type=int, default=0, help="seed of the held-out split and the search (default: 0)")
    fit.add_argument("--tables", **_TABLES_OPTION)
    fit.add_argument("--only", default="", help="comma-separated subset, e.g. boom,stick (default: all)")
    fit.add_argument("--logs", default=None, metavar="DIR", help="instead of --data: a directory of machine logs "
                     "(CSV, or MCAP with --mapping) of your machine; fits the circuit tables to them, --out "
                     "MODEL_DIR gets the tables and provenance.json (docs/machine-logs.md)")  # fmt: skip
    _add_mapping_option(fit, "--logs with MCAP logs")
    fit.set_defaults(func=_cmd_fit)

    excitation = sub.add_parser("excitation", help="a command log of slow spool sweeps (each function, both ways) "
                                "that fills a fit's gaps")  # fmt: skip
    excitation.add_argument("--out", required=True, metavar="FILE.csv", help="output file: the command log "
                            "(t,swing,boom,stick,bucket; s, mm)")  # fmt: skip
    excitation.add_argument("--functions", default=None, help="comma-separated functions to sweep, e.g. boom,stick "
                            "(default: all four)")  # fmt: skip
    excitation.add_argument("--model", default=None, metavar="MODEL_DIR", help="sweep only the functions whose "
                            "passages a fitted model's logs left gaps in (its provenance.json)")  # fmt: skip
    excitation.set_defaults(func=_cmd_excitation)

    tables = sub.add_parser("tables", help="the fitted tables: inputs, output, points, parameters, accuracy")
    tables.add_argument("--json", action="store_true", help="print JSON")
    tables.add_argument("--dir", default=None, help="table directory (default: the packaged tables)")
    tables.add_argument("--tables", **_TABLES_OPTION)
    tables.add_argument("--bench", metavar="DATA", default=None, help="also time lookups vs direct LWR on DATA")
    tables.set_defaults(func=_cmd_tables)

    validate = sub.add_parser(
        "validate",
        help="learned vs reference model on the paper's three tests, the interactions both ways and "
        "(--suite N) N random operator-like logs: plots, tip errors, speed",
    )
    validate.add_argument("--out", default="out/validate", metavar="DIR", help="output directory: summary.json, "
                          "test1-3.png, interactions.png and with --suite suite_worst.png "
                          "(default: out/validate)")  # fmt: skip
    validate.add_argument("--suite", type=int, default=0, help="random operator-like logs to add (default: 0)")
    validate.add_argument("--suite-seed", type=int, default=0, help="seed of the suite's logs (default: 0)")
    validate.add_argument("--workers", type=int, default=None, help="processes (default: one per CPU)")
    validate.add_argument("--suite-only", action="store_true", help="run the suite alone (no tests, interactions)")
    validate.add_argument(
        "--suite-style",
        choices=("operator", "bucket_stick"),
        default="operator",
        help="the suite's logs: operator-like, or only the bucket at full spool with the stick moving (default: "
        "operator)",
    )
    add_ray_option(validate, "the interactions and the suite")
    validate.add_argument("--tables", **_TABLES_OPTION)
    validate.add_argument("--tables-dir", default=None, help="the tables' directory (default: the packaged ones)")
    validate.add_argument("--model", default=None, metavar="MODEL_DIR", help="with --logs: a model fitted by "
                          "`hexgym fit --logs`, replayed on each log from its first pose beside the packaged "
                          "one")  # fmt: skip
    validate.add_argument("--logs", default=None, metavar="DIR", help="with --model: machine logs (CSV, or MCAP "
                          "with --mapping) to replay and score against (held out of the fit)")  # fmt: skip
    _add_mapping_option(validate, "--logs with MCAP logs")
    validate.add_argument(
        "--payload-kg",
        type=float,
        default=None,
        help="material in the bucket, kg, for every run of both models: the tests, the interactions and each suite "
        "log (default: the tests empty, the interactions at 0 and 2 t, each suite log its drawn 0, 1 or 2 t)",
    )
    validate.set_defaults(func=_cmd_validate)

    build = sub.add_parser("build-assets", help="regenerate assets/meshes and assets/cat325.xml (developers)")
    build.add_argument(
        "--dir",
        default=str(_REPOSITORY_ASSETS) if _source_checkout() else None,
        metavar="DIR",
        help="output directory: meshes/, the MJCF models and scenes (a new one gets the packaged scene.xml); "
        "nothing is written outside it, but for the source tree's own assets/: native/plugin_interface.h "
        "(default: a source tree's assets/; an installed hexgym needs --dir)",
    )
    build.set_defaults(func=_cmd_build_assets)

    from hexgym_lab.view import key_help

    view = sub.add_parser("view", help="MuJoCo's viewer on the loading site; drive the spools with keys or sliders",
                          epilog=key_help(), formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    view.add_argument("--start", default="home", help="keyframe (home), 'site' (the env's start pose for --seed) "
                      "or angles 'swing,boom,stick,bucket' in rad (default: home)")  # fmt: skip
    view.add_argument("--payload-kg", type=float, default=0.0, help="material in the bucket, kg (default: 0)")
    view.add_argument("--seed", type=int, default=0, help="the site's layout, as HexLoading-v0 seeds it (default: 0)")
    view.add_argument("--camera", choices=("free", "chase", "cab"), default="free", help="camera (default: free)")
    view.add_argument("--panels", action="store_true", help="open with the viewer's side panels (Tab, Shift+Tab "
                      "toggle them; default: the site fills the window)")  # fmt: skip
    view.add_argument("--seconds", type=float, default=None, help="close after this much simulated time")
    view.add_argument("--frames", type=int, default=None, help="close after this many frames")
    view.add_argument("--screenshot", metavar="PNG", default=None, help="save the window before closing")
    view.set_defaults(func=_cmd_view)

    _add_agent_parsers(sub)
    _add_planning_parsers(sub)
    _strict_numbers(parser)
    return parser


def given_options(argv: list[str]) -> set[str]:
    """The options (dest names) the command line ``argv`` gives, defaults aside."""
    parser = build_parser()

    def suppress(p: argparse.ArgumentParser) -> None:
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub in action.choices.values():
                    suppress(sub)
            elif action.dest not in ("help", "command"):
                action.default = argparse.SUPPRESS
        p._defaults.clear()

    suppress(parser)
    return set(vars(parser.parse_args(argv))) - {"command", "func"}


def _add_planning_parsers(sub: argparse._SubParsersAction) -> None:
    """``shield``: the collision shield (:mod:`hexgym.wrappers`) on seeded episodes of a policy."""
    shield = sub.add_parser("shield", help="the same seeded episodes of a policy with and without the collision shield")
    shield.add_argument("--policy", default="random", help="'random', 'shipped', 'scripted' or a model .zip "
                        "(default: random)")  # fmt: skip
    shield.add_argument("--episodes", type=int, default=4, help="episodes, seeds seed..seed+N-1 (default: 4)")
    shield.add_argument("--seed", type=int, default=0, help="first seed (default: 0)")
    shield.add_argument("--seconds", type=float, default=None, help="episode time limit, s (default: the env's)")
    shield.add_argument("--horizon", type=float, default=1.5, help="prediction horizon, s (default: 1.5)")
    shield.add_argument("--json", metavar="OUT", default=None, help="also write the figures to this JSON file")
    shield.add_argument("--plot", metavar="PNG", default=None, help="also plot the figures per episode to this PNG")
    shield.set_defaults(func=_cmd_shield)

    plan = sub.add_parser("plan", help="plan a time-and-fuel-optimal dump or return move on the fast model; replay "
                          "it on the reference; compare with the scripted loader")  # fmt: skip
    plan.add_argument("--task", choices=("dump", "return"), required=True, help="the move to plan")
    plan.add_argument("--seed", type=int, default=0, help="the HexLoading-v0 seed of the site (default: 0)")
    plan.add_argument(
        "--seeds", default=None, metavar="A-B", help="plan on seeds A..B and summarise (overrides --seed)"
    )
    plan.add_argument("--w-fuel", type=float, default=1.0, help="seconds per litre in the cost (default: 1)")
    plan.add_argument("--budget", type=int, default=600, help="rollouts the planner may simulate (default: 600)")
    plan.add_argument("--population", type=int, default=30, help="candidates per batch of the search (default: 30)")
    plan.add_argument("--threads", type=int, default=2, help="rollout threads (default: 2)")
    plan.add_argument("--workers", type=int, default=1, help="seeds planned at once, one process each (default: 1; "
                      "plans sharing cores miss the 2 s wall)")  # fmt: skip
    plan.add_argument("--plot", metavar="PNG", default=None, help="also plot the (first) seed's plan to this PNG")
    plan.add_argument("--video", metavar="MP4", default=None, help="also film the (first) seed's planned move and "
                      "the scripted loader's (the learned model, chase camera) to this MP4")  # fmt: skip
    plan.add_argument("--margin", type=float, default=None, help="clearance (m) the plan keeps from truck and ground "
                      "(default: 0.2)")  # fmt: skip
    plan.add_argument(
        "--no-check",
        action="store_true",
        help="plan in one round on the native batch alone (default: two rounds, each plan checked on the circuit model "
        "in Python, trimmed and mended there)",
    )
    plan.add_argument("--swing", choices=("knots", "bang-bang"), default=None, help="the swing searched per knot "
                      "as the other spools, or turned as fast as it can (full spool, then closed: the crossover "
                      "reliefs brake it) with its switch fitted to the circuit model (default: knots for dump, "
                      "bang-bang for return)")  # fmt: skip
    plan.add_argument("--json", metavar="OUT", default=None, help="also write the figures to this JSON file")
    add_ray_option(plan, "the seeds (each with --threads cores)")
    plan.set_defaults(func=_cmd_plan)


def _add_agent_parsers(sub: argparse._SubParsersAction) -> None:
    """``train``, ``clone``, ``evaluate`` and ``video``: agents for HexLoading-v0."""
    policy_help = (
        "'shipped' (packaged agent), 'scripted' (the scripted loader), 'planner' (the scripted dig with "
        "planned dumps and returns) or a model .zip"
    )
    train = sub.add_parser("train", help="train a PPO or SAC agent (rl-zoo3 hyperparameters; resumes checkpoints)")
    train.add_argument("--framework", choices=("sb3", "rllib"), default="sb3", help="Stable-Baselines3, or RLlib's "
                       "PPO with env runners on Ray (needs hexgym[cluster]) (default: sb3)")  # fmt: skip
    train.add_argument("--num-env-runners", type=int, default=None, help="rllib: env runner actors (default: "
                       "the Ray cluster's cores less one)")  # fmt: skip
    add_ray_option(train, "rllib's env runners")
    train.add_argument("--algo", choices=("ppo", "sac"), default="ppo", help="algorithm (default: ppo)")
    train.add_argument("--env", default="HexLoading-v0", help="environment id (default: HexLoading-v0)")
    train.add_argument("--timesteps", type=int, default=None, help="total steps (default: the YAML's n_timesteps)")
    train.add_argument("--seed", type=int, default=0, help="seed (default: 0)")
    train.add_argument("-f", "--log-dir", default="logs", metavar="DIR", help="output directory: the run's "
                       "<algo>_<env>/ (model.zip, its normaliser, curve.csv, checkpoints/, tb/) "
                       "(default: logs)")  # fmt: skip
    train.add_argument("--hyperparams", default=None, help="rl-zoo3 YAML (default: hexgym_lab/hyperparams/<algo>.yml)")
    train.add_argument("--n-envs", type=int, default=None, help="parallel environments (default: the YAML's n_envs "
                       "on the batched environment, else one per core)")  # fmt: skip
    train.add_argument("--vec-env", choices=("auto", "batch", "subproc"), default="auto",
                       help="batch: the task's batched environment (HexLoading-v0: MuJoCo batch threads in one "
                       "process, several times faster); subproc: one process per environment; auto: batch where "
                       "there is one (default: auto)")  # fmt: skip
    train.add_argument("--init-from", default=None, help="start from this model .zip, e.g. from `hexgym clone`")
    train.add_argument("--checkpoint-every", type=int, default=20000, help="steps between checkpoints")
    train.add_argument("--no-progress", action="store_true", help="no step count (the line per rollout stays; "
                       "--quiet: neither)")  # fmt: skip
    train.set_defaults(func=_cmd_train)

    clone = sub.add_parser("clone", help="behaviour-clone the scripted loader (with DAgger) into a PPO model")
    clone.add_argument("--out", required=True, metavar="FILE.zip", help="output file: the model (its "
                       "observation normaliser beside it, <name>_vecnormalize.json)")  # fmt: skip
    clone.add_argument("--episodes", type=int, default=16, help="scripted episodes (default: 16)")
    clone.add_argument("--dagger-rounds", type=int, default=4, help="DAgger rounds (default: 4)")
    clone.add_argument("--dagger-episodes", type=int, default=8, help="episodes per DAgger round (default: 8)")
    clone.add_argument("--epochs", type=int, default=30, help="fitting epochs per round (default: 30)")
    clone.add_argument("--noise", type=float, default=0.0, help="DART: spool noise std (default: 0)")
    clone.add_argument("--seed", type=int, default=1000, help="first episode seed (default: 1000)")
    clone.add_argument("--select-episodes", type=int, default=0, help="score each round's clone on N more "
                       "episodes and keep the best (default: 0: the last)")  # fmt: skip
    clone.add_argument("--rounds-dir", default=None, metavar="DIR", help="also an output directory: each round's "
                       "clone, round<k>.zip")  # fmt: skip
    clone.add_argument("--hyperparams", default=None, help="PPO YAML giving the network (default: ppo.yml)")
    clone.add_argument("--tables", choices=tuple(TABLE_SETS), default=None,
                       help="the learned model the episodes run on (default: the environment's, circuit); the "
                       "shipped agent was cloned on circuit")  # fmt: skip
    clone.add_argument(
        "--loss",
        choices=("mse", "l1"),
        default="mse",
        help="the actor's fit to the labels: mse "
        "(their mean) or l1 (their median: one side of a phase change, not the average)",
    )
    clone.add_argument("--loader-settings", **_LOADER_SETTINGS_OPTION)
    clone.set_defaults(func=_cmd_clone)

    select = sub.add_parser("select", help="keep the checkpoint of a training run that loads most on selection seeds")
    select.add_argument("checkpoints", metavar="DIR", help="a run's checkpoints (<log-dir>/<algo>_<env>/checkpoints)")
    select.add_argument("--out", required=True, metavar="FILE.zip", help="output file: the selected model (its "
                        "observation normaliser beside it, <name>_vecnormalize.json)")  # fmt: skip
    select.add_argument("--seeds", default="0-19,100-109", metavar="A-B[,C-D]", help="selection seed sets, each "
                        "evaluated deterministically; the highest mean t/h over the sets is kept (default: "
                        "0-19,100-109)")  # fmt: skip
    select.add_argument("--json", default=None, metavar="OUT", help="also write every checkpoint's figures here")
    select.set_defaults(func=_cmd_select)

    curves = sub.add_parser("curves", help="learning curves of hexgym train runs (seeds): figure and summary")
    curves.add_argument("runs", nargs="+", help="run directories (<log-dir>/<algo>_<env>) or their curve.csv")
    curves.add_argument("--out", required=True, metavar="FILE.png", help="output file: the figure, mean and "
                        "min-max band over the runs")  # fmt: skip
    curves.add_argument("--json", default=None, metavar="OUT", help="also write the summary to this JSON file")
    curves.add_argument("--title", default="", help="the figure's title")
    curves.add_argument("--success-level", type=float, default=0.9, help="report the steps to reach this "
                        "smoothed success rate (default: 0.9)")  # fmt: skip
    curves.set_defaults(func=_cmd_curves)

    evaluate = sub.add_parser("evaluate", help="measure a policy on HexLoading-v0: success, t/h, cycle, fuel")
    evaluate.add_argument("--policy", default="shipped", help=policy_help + " or an RLlib checkpoint directory "
                          "(default: shipped)")  # fmt: skip
    evaluate.add_argument("--episodes", type=int, default=20, help="episodes, seeds seed..seed+N-1 (default: 20)")
    evaluate.add_argument("--seed", type=int, default=0, help="first seed (default: 0)")
    evaluate.add_argument("--seconds", type=float, default=None, help="episode time limit, s (default: the env's)")
    evaluate.add_argument("--json", metavar="OUT", default=None, help="also write the figures to this JSON file")
    evaluate.add_argument("--workers", type=int, default=1, help="processes running the episodes (default: 1)")
    evaluate.add_argument("--model", **_MACHINE_MODEL_OPTION)
    evaluate.add_argument("--tables", **_TABLES_OPTION)
    evaluate.add_argument("--env", default="HexLoading-v0", help="environment id (default: HexLoading-v0; others, "
                          "e.g. HexReach-v0: success rate, mean return, time to success of a model .zip)")  # fmt: skip
    evaluate.add_argument("--loader-settings", **_LOADER_SETTINGS_OPTION)
    evaluate.add_argument("--site-ranges", choices=("training", "shifted"), default=None,
                          help="HexLoading-v0's site_ranges: 'shifted' places the pile and truck just outside their "
                          "training ranges (default: training)")  # fmt: skip
    evaluate.add_argument("--material-density-scale", type=float, default=None, metavar="X",
                          help="the material's density times X, 0.5-1.5 (default: 1)")  # fmt: skip
    evaluate.add_argument("--engine-power-scale", type=float, default=None, metavar="X",
                          help="the engine's power times X, 0.5-1 (its pump power limit; default: 1)")  # fmt: skip
    add_ray_option(evaluate, "the episodes")
    evaluate.set_defaults(func=_cmd_evaluate)

    video = sub.add_parser("video", help="render rollouts of a policy to an MP4 with a time/payload overlay")
    video.add_argument("--policy", default="shipped", help=policy_help + " (default: shipped)")
    video.add_argument("--out", required=True, metavar="FILE.mp4", help="output file: the film (MP4)")
    video.add_argument("--camera", choices=("chase", "cab"), default="chase", help="camera (default: chase)")
    video.add_argument("--episodes", type=int, default=1, help="episodes (default: 1)")
    video.add_argument("--seed", type=int, default=0, help="first seed (default: 0)")
    video.add_argument(
        "--seconds",
        type=float,
        default=None,
        help="film this long, s (the episode keeps the env's 180 s budget; default: all of it)",
    )
    video.add_argument("--width", type=int, default=640, help="frame width (default: 640)")
    video.add_argument("--height", type=int, default=384, help="frame height (default: 384)")
    video.add_argument("--snapshot", default=None, help="also write a PNG of a mid-episode frame")
    video.add_argument("--model", **_MACHINE_MODEL_OPTION)
    video.add_argument("--env", default="HexLoading-v0", help="HexLoading-v0 (default) or HexDig-v0 (--policy: a "
                       "model trained on it, or scripted)")  # fmt: skip
    video.set_defaults(func=_cmd_video)

    convert = sub.add_parser("convert-normalizer", help="convert a pickled VecNormalize (*_vecnormalize.pkl) to "
                             "the JSON normaliser hexgym reads (nothing in the pickle is run)")  # fmt: skip
    convert.add_argument("pkl", help="the pickled normaliser, e.g. model_vecnormalize.pkl")
    convert.add_argument("--out", default=None, metavar="FILE.json", help="output file: the normaliser (JSON) "
                         "(default: beside the pickle, .json)")  # fmt: skip
    convert.set_defaults(func=_cmd_convert_normalizer)


# -- checks before any work -------------------------------------------------------------------------
# Option values, by option name, whatever the command: (check, argument) for hexgym.checks.
_COUNTS = {"episodes": 1, "steps": 1, "samples": 1, "epochs": 1, "workers": 1, "n_envs": 1, "timesteps": 1,
           "frames": 1, "dagger_episodes": 1, "checkpoint_every": 1, "suite": 0, "dagger_rounds": 0,
           "select_episodes": 0, "width": 1, "height": 1, "num_env_runners": 1, "generations": 1}  # fmt: skip
_SEEDS = ("seed", "suite_seed")
_POSITIVE = {"seconds": "s", "dt_out": "s", "rate": "Hz"}
# Paths, by (command, option): files and directories written, files and directories read.
_OUTPUT_FILES = {("simulate", "out"), ("video", "out"), ("video", "snapshot"), ("evaluate", "json"),
                 ("bench", "json"), ("scripted", "json"), ("clone", "out"), ("view", "screenshot"),
                 ("convert-normalizer", "out"), ("shield", "json"), ("shield", "plot"),
                 ("plan", "json"), ("plan", "plot"), ("plan", "video"), ("curves", "out"),
                 ("curves", "json"), ("simulate", "machine_log"), ("compare", "out"),
                ("excitation", "out"), ("select", "out"), ("select", "json")}  # fmt: skip
_OUTPUT_DIRS = {("demo", "out"), ("reference-report", "out"), ("validate", "out"), ("collect", "out"),
                ("fit", "out"), ("build-assets", "dir"), ("clone", "rounds_dir"), ("train", "log_dir")}  # fmt: skip
_INPUT_FILES = {("simulate", "commands"), ("train", "hyperparams"), ("train", "init_from"), ("clone", "hyperparams"),
                ("convert-normalizer", "pkl"), ("scripted", "loader_settings"), ("evaluate", "loader_settings"),
                ("clone", "loader_settings"), ("tune-loader", "loader_settings"), ("simulate", "hydraulics"),
                ("simulate", "start_from"),
                ("simulate", "mapping"), ("check-log", "mapping"), ("compare", "mapping"), ("compare", "a"),
                ("compare", "b"), ("fit", "mapping"), ("validate", "mapping")}  # fmt: skip
# Options that apply only in one mode: (command, option) -> (the mode's option, its value, what the option is for).
# Given in another mode they are refused, not ignored.
_ONLY_WITH = {
    ("simulate", "tables"): ("model", "learned", "the learned model's tables"),
    ("simulate", "backend"): ("model", "learned", "the learned model's backend"),
    ("simulate", "tables_dir"): ("model", "learned", "the learned model's tables"),
    ("evaluate", "tables"): ("model", "learned", "the learned model's tables"),
    ("simulate", "hydraulics"): ("model", "reference", "the reference's hydraulics"),
    ("simulate", "machine_log"): ("model", "reference", "the reference's pressures as a machine log"),
}
# Options that cannot be given together: the second is ignored by the first.
_EXCLUSIVE = {
    ("evaluate", "ray", "workers"), ("validate", "ray", "workers"), ("collect", "ray", "workers"),
    ("plan", "ray", "workers"),
}  # fmt: skip
_INPUT_DIRS = {("fit", "data"), ("tables", "dir"), ("tables", "bench"), ("fit", "logs"), ("validate", "logs"),
               ("validate", "model"), ("excitation", "model"), ("simulate", "tables_dir"),
               ("select", "checkpoints")}  # fmt: skip


def check_arguments(args: argparse.Namespace, given: set[str] | None = None) -> None:
    """Refuse bad option values and unusable paths before a command starts (ValueError, FileNotFoundError).

    ``given``: the options the command line gave (:func:`given_options`); an option that does not apply
    with the others given is refused.
    """
    from hexgym.checks import check_count, check_positive, check_range, check_seed
    from hexgym.files import check_input_dir, check_input_file, check_output_dir, check_output_file
    from hexgym.machine.physics import MAX_PAYLOAD_KG

    values = {k: v for k, v in vars(args).items() if v is not None}
    for name, value in values.items():
        option = "--" + name.replace("_", "-")
        if name in _COUNTS:
            check_count(option, value, _COUNTS[name])
        elif name in _SEEDS:
            check_seed(option, value)
        elif name in _POSITIVE:
            check_positive(option, value, _POSITIVE[name])
        elif name == "payload_kg":
            check_range(option, value, 0.0, MAX_PAYLOAD_KG, "kg (a heaped bucket)")
        elif name == "fps":
            from hexgym.machine.render import MAX_FPS, MIN_FPS

            if not (math.isfinite(value) and MIN_FPS <= value <= MAX_FPS):
                raise ValueError(f"{option} must be a finite number > 0, from {MIN_FPS:g} to {MAX_FPS:g} frames/s "
                                 f"(an MP4's playback rate), got {value!r}")  # fmt: skip
        elif name == "ray" and not value.strip():
            raise ValueError("--ray '': give HOST:PORT, ray://HOST:PORT or auto, or --ray alone for a Ray started here")
        elif name in ("noise", "success_level"):
            check_range(option, value, 0.0, 1.0, "(spool fraction)" if name == "noise" else "(a share of episodes)")
        elif isinstance(value, float) and not math.isfinite(value):  # every other number option
            raise ValueError(f"{option} must be a finite number, got {value!r}")
    command = args.command
    for (cmd, name), (mode, wanted, what) in _ONLY_WITH.items():
        if cmd == command and name in (given or ()) and values.get(mode) != wanted:
            raise ValueError(f"--{name.replace('_', '-')} ({what}) does not apply with --{mode} {values.get(mode)}")
    for cmd, first, second in _EXCLUSIVE:
        if cmd == command and {first, second} <= (given or set()) and values.get(first) is not None:
            raise ValueError(f"--{second} does not apply with --{first}: the Ray cluster's cores run the tasks")
    policy = values.get("policy")  # checked where it is loaded, which says what a policy may be
    inputs = [policy] if policy is not None and policy not in POLICY_NAMES else []
    for (cmd, name), check, what in (
        *((k, check_input_file, "input file") for k in _INPUT_FILES),
        *((k, check_input_dir, "input directory") for k in _INPUT_DIRS),
    ):
        value = values.get(name) if cmd == command else None
        if value is None:
            continue
        check(value, f"{what} --{name.replace('_', '-')}" if name not in ("pkl", "a", "b") else what)  # positional
        inputs.append(value)
    outputs: list[str] = []
    for cmd, name in sorted(_OUTPUT_FILES | _OUTPUT_DIRS):
        value = values.get(name) if cmd == command else None
        if value is None:
            continue
        what = f"output --{name.replace('_', '-')}"
        if (cmd, name) in _OUTPUT_FILES:
            check_output_file(value, what, inputs=(*inputs, *outputs))
        else:
            check_output_dir(value, what, inputs=tuple(inputs))
        outputs.append(value)


def _one_line(exc: BaseException) -> str:
    """The error as one line, naming the file of an OS error."""
    if isinstance(exc, OSError) and exc.strerror:
        where = exc.filename if exc.filename is not None else ""
        text = f"{where}: {exc.strerror}" if where else exc.strerror
    elif isinstance(exc, MemoryError):
        text = f"not enough memory ({exc or 'the input asks for more than this machine has'})"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())


_USER_ERRORS = (ValueError, OSError, RuntimeError, MemoryError, LookupError, EOFError)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``hexgym`` console command (exit status 0, 2 for an error, 130 for Ctrl-C)."""
    os.environ.setdefault("MUJOCO_GL", "egl")  # offscreen rendering without a display
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv or os.environ.get("HEXGYM_DEBUG", "") not in ("", "0")
    quiet = "--quiet" in argv
    argv = [a for a in argv if a not in ("--debug", "--quiet")]
    args = build_parser().parse_args(argv)
    try:
        from hexgym_lab import progress

        progress.configure(quiet=quiet)
        progress.mode()  # a bad HEXGYM_PROGRESS is refused before the work starts
        args.given = given_options(argv)
        check_arguments(args, args.given)
        return args.func(args)
    except KeyboardInterrupt:
        print(f"hexgym {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if debug:
            raise
        if isinstance(exc, _USER_ERRORS):
            print(f"hexgym {args.command}: error: {_one_line(exc)}", file=sys.stderr)
        else:  # not a check's refusal: an input no check foresaw, or a bug
            print(f"hexgym {args.command}: error: unexpected {type(exc).__name__}: {_one_line(exc)} (--debug "
                  "shows the traceback; please report it if the input is right)", file=sys.stderr)  # fmt: skip
        return 2


if __name__ == "__main__":
    raise SystemExit(main())

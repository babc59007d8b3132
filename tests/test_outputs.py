"""What the commands write and print: only under the paths they were given (an installed, read-only package is
never written), progress on standard error in one style, a result on standard output that stays parseable."""

import io
import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hexgym_lab import progress
from hexgym_lab.cli import main

ROOT = Path(__file__).resolve().parent.parent

# A driver run in a fresh interpreter on the installed copy: each command line in turn, its exit status, standard
# output and standard error kept apart (JSON on the driver's own standard output).
DRIVER = """
import contextlib, io, json, sys
from hexgym_lab.cli import main
results = []
for argv in json.loads(sys.argv[1]):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(argv)
    results.append({"argv": argv, "status": status, "out": out.getvalue(), "err": err.getvalue()})
print(json.dumps(results))
"""


def _installed_copy(site: Path) -> None:
    """The two packages laid out as a wheel installs them (assets inside hexgym), made read-only."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(ROOT / "hexgym", site / "hexgym", ignore=ignore)
    shutil.copytree(ROOT / "hexgym_lab", site / "hexgym_lab", ignore=ignore)
    shutil.copytree(ROOT / "assets", site / "hexgym" / "assets", ignore=ignore)
    _set_writable(site, False)


def _set_writable(tree: Path, writable: bool) -> None:
    for path in [tree, *tree.rglob("*")]:
        mode = path.stat().st_mode
        path.chmod(mode | stat.S_IWUSR if writable else mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))


def _snapshot(tree: Path) -> dict[str, tuple[int, int]]:
    """Every file under ``tree``: size and modification time. As root, whom no permission stops, the caches that go
    into a writable package's ``__pycache__`` (numba's, and its stamp) are left out: a read-only package keeps
    them elsewhere."""
    files = [p for p in tree.rglob("*") if p.is_file() and (os.geteuid() != 0 or "__pycache__" not in p.parts)]
    return {str(p.relative_to(tree)): (p.stat().st_size, p.stat().st_mtime_ns) for p in files}


def _synthetic_data(directory: Path) -> None:
    """Small data sets for the paper's tables (the shape ``hexgym collect`` writes)."""
    from hexgym.mbl.schema import TABLE_SETS
    from hexgym_lab.mbl.baselines import synthetic_flow_sharing

    directory.mkdir()
    X, y = synthetic_flow_sharing(120, seed=3)  # noqa: N806
    rng = np.random.default_rng(4)
    for name, spec in TABLE_SETS["paper"].items():
        Xn = X if len(spec.inputs) == 4 else np.column_stack([X, rng.uniform(-1, 1, len(y))])  # noqa: N806
        np.savez(directory / f"{name}.npz", X=Xn, y=y, episode=np.arange(len(y)) // 10,
                 inputs=np.array(spec.inputs), output=np.array(spec.output))  # fmt: skip


def _run_installed(tmp_path: Path, commands: list[list[str]]) -> tuple[list[dict], Path]:
    """Run ``commands`` on a read-only installed copy, in a working directory of their own; the package must not
    change and nothing may appear beside the working directory."""
    site, work = tmp_path / "site", tmp_path / "work"
    _installed_copy(site)
    work.mkdir()
    (work / "commands.csv").write_text("t,swing,boom,stick,bucket\n0,0,5,0,0\n0.5,0,0,0,0\n")
    _synthetic_data(work / "data")
    before = _snapshot(site)
    env = {**os.environ, "PYTHONPATH": str(site), "PYTHONDONTWRITEBYTECODE": "1", "HEXGYM_PROGRESS": "lines",
           "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache"), "MUJOCO_GL": "egl"}  # fmt: skip
    try:
        run = subprocess.run([sys.executable, "-c", DRIVER, json.dumps(commands)], cwd=work, env=env,
                             capture_output=True, text=True, timeout=900)  # fmt: skip
        assert run.returncode == 0, run.stderr[-3000:]
        assert _snapshot(site) == before  # nothing in the package was written, added or removed
    finally:
        _set_writable(site, True)
    assert {p.name for p in tmp_path.iterdir()} <= {"numba-cache", "site", "work"}  # nothing beside
    results = json.loads(run.stdout)
    for result in results:
        assert result["status"] == 0 or result["argv"] == ["build-assets"], result
    return results, work


def test_writing_commands_leave_a_read_only_package_alone(tmp_path):
    commands = [
        ["build-assets"],  # an installed copy has no source tree: --dir is asked for, nothing written
        ["build-assets", "--dir", "new-assets"],
        ["simulate", "--commands", "commands.csv", "--out", "trajectory.csv"],
        ["scripted", "--seconds", "1", "--json", "scripted.json"],
        ["demo", "--seconds", "0.5", "--width", "64", "--height", "48"],
        ["video", "--policy", "scripted", "--seconds", "0.5", "--width", "64", "--height", "48", "--out", "v.mp4",
         "--snapshot", "v.png"],
        ["evaluate", "--policy", "scripted", "--episodes", "2", "--seconds", "1", "--json", "evaluate.json"],
        ["shield", "--episodes", "1", "--seconds", "1", "--json", "shield.json", "--plot", "shield.png"],
        ["fit", "--data", "data", "--tables", "paper", "--only", "boom"],
    ]  # fmt: skip
    results, work = _run_installed(tmp_path, commands)
    refused = results[0]
    assert refused["status"] == 2 and "--dir: give the directory to write" in refused["err"]
    assert {p.name for p in (work / "new-assets").iterdir()} >= {"scene.xml", "cat325.xml", "meshes"}
    for name in ("trajectory.csv", "scripted.json", "out/demo.mp4", "out/demo.png", "v.mp4", "v.png",
                 "evaluate.json", "shield.json", "shield.png", "tables/paper/boom.npz"):  # fmt: skip
        assert (work / name).is_file(), name
    by_command = {r["argv"][0]: r for r in results[1:]}
    for command, outputs in (("simulate", ["trajectory.csv"]), ("demo", ["out/demo.mp4", "out/demo.png"]),
                             ("video", ["v.mp4", "v.png"]), ("fit", ["tables/paper/boom.npz"])):  # fmt: skip
        for output in outputs:  # each output named at the end, on standard error
            assert f"wrote {output} (" in by_command[command]["err"], (command, output)
    evaluated = by_command["evaluate"]
    assert json.loads(evaluated["out"])["episodes"] == 2  # standard output: the JSON document alone
    assert "evaluate: 2/2 episodes (100 %)" in evaluated["err"]  # progress: lines on standard error
    assert "demo: 5/5 frames (100 %)" in by_command["demo"]["err"]


@pytest.mark.slow
def test_slow_writing_commands_leave_a_read_only_package_alone(tmp_path):
    commands = [
        ["reference-report", "--out", "report"],
        ["validate", "--suite-only", "--suite", "1", "--workers", "1", "--out", "validate"],
        ["collect", "--samples", "20", "--workers", "1", "--out", "collected"],
        ["tune-loader", "--out", "tuned.json", "--seeds", "1-1", "--generations", "1", "--population", "4"],
        ["plan", "--task", "return", "--budget", "64", "--no-check", "--json", "plan.json"],
    ]
    results, work = _run_installed(tmp_path, commands)
    for name in ("report/summary.json", "validate/summary.json", "tuned.json", "plan.json"):
        assert (work / name).is_file(), name
    for result in results:
        if result["argv"][0] in ("reference-report", "validate", "tune-loader", "plan"):
            json.loads(result["out"])  # standard output: the JSON document alone


# -- progress ---------------------------------------------------------------------------------------
def _terminal(monkeypatch, columns: int, rows: int = 24) -> None:
    monkeypatch.setattr(progress, "_stderr_is_terminal", lambda: True)
    monkeypatch.setattr(progress, "_terminal_size", lambda: (columns, rows))
    monkeypatch.delenv(progress.ENV_VAR, raising=False)
    monkeypatch.delenv("TERM", raising=False)


def test_progress_mode_follows_the_terminal(monkeypatch):
    monkeypatch.delenv(progress.ENV_VAR, raising=False)
    progress.configure(quiet=False)
    assert progress.mode() == "off"  # pytest's standard error is not a terminal
    _terminal(monkeypatch, 120)
    assert progress.mode() == "bar"
    _terminal(monkeypatch, 40)
    assert progress.mode() == "lines"  # too narrow for a bar with its rate and time left
    _terminal(monkeypatch, 120, rows=0)
    assert progress.mode() == "lines"  # a terminal of unknown size
    _terminal(monkeypatch, 120)
    monkeypatch.setenv("TERM", "dumb")
    assert progress.mode() == "lines"
    progress.configure(quiet=True)
    try:
        assert progress.mode() == "off"
    finally:
        progress.configure(quiet=False)
    monkeypatch.setenv(progress.ENV_VAR, "lines")
    assert progress.mode() == "lines"  # chosen, whatever the terminal
    monkeypatch.setenv(progress.ENV_VAR, "loud")
    with pytest.raises(ValueError, match="HEXGYM_PROGRESS='loud'"):
        progress.mode()


def test_progress_lines_and_bar_go_to_standard_error(monkeypatch, capsys):
    monkeypatch.setenv(progress.ENV_VAR, "lines")
    monkeypatch.setattr(progress, "LINE_INTERVAL_S", 0.0)
    with progress.Progress(3, "work", "item") as bar:
        for _ in range(3):
            bar.update(best="1.0")
        bar.note("a note")
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.splitlines()
    assert lines[0].startswith("work: 1/3 items (33 %), ") and "left" in lines[0] and lines[0].endswith("| best 1.0")
    assert lines[2].startswith("work: 3/3 items (100 %)") and lines[3] == "a note"
    _terminal(monkeypatch, 100)
    fake = io.StringIO()
    monkeypatch.setattr(sys, "stderr", fake)
    assert list(progress.track(range(4), "bar", "step")) == [0, 1, 2, 3]
    assert "4/4" in fake.getvalue() and "step/s" in fake.getvalue()  # tqdm's bar: count, rate
    assert capsys.readouterr().out == ""


def test_quiet_anywhere_on_the_line_silences_progress(monkeypatch, capsys, tmp_path):
    monkeypatch.setenv(progress.ENV_VAR, "lines")
    try:
        assert main(["scripted", "--seconds", "0.5", "--quiet", "--json", str(tmp_path / "r.json")]) == 0
        captured = capsys.readouterr()
        assert captured.err == f"wrote {tmp_path / 'r.json'} (the runs' figures)\n"  # where it went, no progress
        json.loads(captured.out)
    finally:
        progress.configure(quiet=False)


def test_fit_defaults_under_the_working_directory(tmp_path, monkeypatch):
    _synthetic_data(tmp_path / "data")
    monkeypatch.chdir(tmp_path)
    assert main(["fit", "--data", "data", "--tables", "paper", "--only", "stick"]) == 0
    assert (tmp_path / "tables" / "paper" / "stick.npz").is_file()


def test_model_prints_a_table_with_units(capsys):
    assert main(["model"]) == 0
    text = capsys.readouterr().out
    assert "operating mass" in text and " kg " in text and "moment arm" in text
    assert "{" not in text and "moment_arm_m" not in text  # no Python dicts
    for line in text.splitlines():
        if line.startswith("  boom ") and "mm" in line:
            assert line.split()[1] == "2" and line.rstrip().endswith(" m")  # count, then figures with units


@pytest.mark.parametrize(
    "command,kind",
    [("demo", "directory"), ("collect", "directory"), ("fit", "directory"), ("validate", "directory"),
     ("reference-report", "directory"), ("simulate", "file"), ("video", "file"), ("clone", "file"),
     ("curves", "file"), ("tune-loader", "file"), ("convert-normalizer", "file"), ("compare", "file")],
)  # fmt: skip
def test_each_out_says_whether_it_is_a_file_or_a_directory(command, kind, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert f"--out {'DIR' if kind == 'directory' else 'FILE'}" in text
    assert f"output {kind}:" in text

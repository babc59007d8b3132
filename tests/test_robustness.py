"""Bad input and faults: a clear error every time, nothing lost, no code run from a data file.

A corpus of bad inputs and faults across every ``hexgym`` command and every file format hexgym reads
(command logs, MBL tables, policy zips, observation normalisers, collected data sets and chunks,
hyperparameter YAML, output paths, option values, environment and API arguments). Each case asserts
the exact kind of error (exit status 2 and one line naming the problem on the command line; the
exception class from Python) and that no existing file changed (a snapshot of the case's folder
before and after: no file altered, created or removed), and that no code from a data file ran (a
crafted pickle that would create a marker folder). The tables' corruptions are tried on both
loaders (Python and the native plugin) with the same files.

``python tests/test_robustness.py`` prints the corpus's size by kind (docs/robustness.md quotes it).
"""

from __future__ import annotations

import base64
import errno
import hashlib
import json
import os
import pickle
import re
import resource
import shutil
import signal
import stat
import subprocess
import sys
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hexgym.agents.policy_files import PolicyFileError
from hexgym.files import PathError
from hexgym.mbl.table import TableFileError

ROOT = Path(__file__).resolve().parent.parent
LOG = "t,swing,boom,stick,bucket\n0,0,0,0,0\n0.2,5,0,0,0\n0.4,0,0,0,0\n"
TINY_YAML = """HexLoading-v0:
  n_timesteps: 256
  policy: 'MlpPolicy'
  normalize: "dict(norm_obs=True, norm_reward=False)"
  n_steps: 64
  batch_size: 64
  n_epochs: 1
  policy_kwargs: "dict(net_arch=dict(pi=[16], vf=[16]))"
  env_kwargs: {time_limit: 2.0}
"""


# -- the corpus ------------------------------------------------------------------------------------
@dataclass
class Case:
    """One bad input or fault.

    ``setup(tmp)`` builds the case's files in ``tmp`` and returns the command line (a list: exit
    status 2 and one error line on stderr matching ``match``) or a Python call (raising ``error``
    matching ``match``; ``error`` None: the call must succeed). ``kind`` says what is bad, for the
    counts; ``creates`` names files the case may write (an input that is accepted); ``marker``: a
    crafted file's code would create the folder MARKER.
    """

    kind: str
    name: str
    setup: Callable[[Path], list[str] | Callable[[], Any]]
    match: str = ""
    error: type[BaseException] | None = None
    creates: tuple[str, ...] = ()
    exit_code: int = 2
    needs: str = ""  # "native", "view": skipped where that is not available
    marker: bool = field(default=False)


CORPUS: list[Case] = []


def case(kind: str, name: str, match: str = "", **kwargs: Any) -> Callable:
    def register(setup: Callable) -> Callable:
        CORPUS.append(Case(kind, name, setup, match, **kwargs))
        return setup

    return register


def write(path: Path, content: str | bytes, mode: int | None = None) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(content.encode() if isinstance(content, str) else content)
    if mode is not None:
        path.chmod(mode)
    return path


def simulate(tmp: Path, log: str | bytes | None = LOG, *extra: str, out: str = "traj.csv") -> list[str]:
    """``hexgym simulate`` of ``log`` (written to log.csv unless None) into ``out``."""
    if log is not None:
        write(tmp / "log.csv", log)
    return ["simulate", "--commands", str(tmp / "log.csv"), "--out", str(tmp / out), *extra]


class _Mkdir:
    """What a crafted data file would run: a folder appears if its pickle is ever loaded."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)

    def __reduce__(self) -> tuple:
        return (os.mkdir, (self.path,))


def evil_pickle(tmp: Path) -> bytes:
    return pickle.dumps(_Mkdir(tmp / "MARKER"))


# -- command logs (hexgym simulate) -----------------------------------------------------------------
_LOG_CASES = {
    "extra field": (LOG + "0.6,0,0,0,0,7\n", r"row 4: 6 fields, the header has 5 \(line 5\)"),
    "missing field": (LOG + "0.6,0,0,0\n", r"row 4, column 'bucket': value missing \(line 5\)"),
    "blank lines, row and line": (
        "t,swing,boom,stick,bucket\n\n0,0,0,0,0\n\n\n0.1,0,0,0,0\n0.05,0,0,0,0\n",
        r"row 3, column 't': 0.05 s does not come after 0.1 s \(times must ascend\) \(line 7\)",
    ),
    "missing column": ("t,swing,boom,stick\n0,0,0,0\n", r"missing column\(s\) bucket"),
    "repeated column": ("t,swing,boom,stick,bucket,boom\n0,0,0,0,0,0\n", r"unexpected or repeated"),
    "semicolons": ("t;swing;boom;stick;bucket\n0;0;0;0;0\n", r"missing column\(s\) t, swing"),
    "empty file": ("", r"empty file"),
    "header only": ("t,swing,boom,stick,bucket\n", r"header but no rows"),
    "start not at 0": ("t,swing,boom,stick,bucket\n0.5,0,0,0,0\n", r"must start at t = 0"),
    "time goes back": ("t,swing,boom,stick,bucket\n0,0,0,0,0\n0.2,0,0,0,0\n0.1,0,0,0,0\n", r"does not come after"),
    "repeated time": ("t,swing,boom,stick,bucket\n0,0,0,0,0\n0,1,0,0,0\n", r"does not come after"),
    "NaN spool": ("t,swing,boom,stick,bucket\n0,0,nan,0,0\n", r"column 'boom': nan is not a finite spool"),
    "infinite time": ("t,swing,boom,stick,bucket\n0,0,0,0,0\ninf,0,0,0,0\n", r"inf is not a finite time"),
    "spool beyond stroke": ("t,swing,boom,stick,bucket\n0,0,0,12,0\n", r"column 'stick': 12.0 mm is beyond"),
    "text for a number": ("t,swing,boom,stick,bucket\n0,0,abc,0,0\n", r"'abc' is not a number"),
    "empty value": ("t,swing,boom,stick,bucket\n0,0,,0,0\n", r"column 'boom': value missing"),
    "duration of 1e7 s": ("t,swing,boom,stick,bucket\n0,0,0,0,0\n1e7,0,0,0,0\n", r"2e\+08 trajectory rows"),
    "binary garbage": (bytes(range(256)) * 8, r"log.csv: not a UTF-8 text file"),
    "UTF-16 (Excel Unicode text)": (LOG.encode("utf-16"), r"log.csv: not a UTF-8 text file"),
    "NUL byte": ("t,swing,boom,stick,bucket\n0,0,0\x00,0,0\n", r"log.csv: line 2 holds a NUL byte: not a text file"),
    "huge field": ("t,swing,boom,stick,bucket\n0," + "1" * 200_000 + ",0,0,0\n", r"not a readable CSV file"),
}
for _name, (_body, _match) in _LOG_CASES.items():
    case("command log", _name, _match)(lambda tmp, body=_body: simulate(tmp, body))


@case("command log", "a directory", r"input file --commands .*log.csv is a directory")
def _(tmp):
    (tmp / "log.csv").mkdir()
    return simulate(tmp, None)


@case("command log", "missing", r"input file --commands .*log.csv does not exist")
def _(tmp):
    return simulate(tmp, None)


@case("command log", "unreadable", r"log.csv is not readable")
def _(tmp):
    write(tmp / "log.csv", LOG, mode=0)
    return simulate(tmp, None)


@case("command log", "UTF-8 BOM (Excel CSV UTF-8): accepted", creates=("traj.csv",), exit_code=0)
def _(tmp):
    return simulate(tmp, "\ufeff" + LOG)


def _read_log_with_limit(path: Path, limit: str, value: int) -> Callable[[], object]:
    """Reading ``path`` with ``hexgym.model.commandlog``'s ``limit`` set to ``value`` for the call."""
    from hexgym.model import commandlog

    def call():
        original = getattr(commandlog, limit)
        setattr(commandlog, limit, value)
        try:
            commandlog.read_command_log(path)
        finally:
            setattr(commandlog, limit, original)

    return call


@case("command log", "more rows than the limit", r"more than 3 rows", error=ValueError)
def _(tmp):
    return _read_log_with_limit(write(tmp / "log.csv", LOG + "0.6,0,0,0,0\n"), "MAX_ROWS", 3)


@case("command log", "a file beyond the size limit", r"log.csv: \d+ bytes; .* at most 100", error=ValueError)
def _(tmp):
    return _read_log_with_limit(write(tmp / "log.csv", LOG + "0.6,0,0,0,0\n" * 10), "MAX_BYTES", 100)


@case("command log", "non-finite time in code", r"row 2, column 't': nan is not a finite time", error=ValueError)
def _(tmp):
    from hexgym.model.commandlog import CommandLog

    return lambda: CommandLog(np.array([0.0, np.nan]), np.zeros((2, 4)))


# -- option values ---------------------------------------------------------------------------------
for _name, _extra, _match in (
    ("--start unknown keyframe", ["--start", "nosuchkey"], r"no keyframe 'nosuchkey' in the model; it has home"),
    ("--payload-kg 1e9", ["--payload-kg", "1e9"], r"--payload-kg must be a finite number from 0 to 2145 kg"),
    ("--payload-kg negative", ["--payload-kg", "-5"], r"--payload-kg must be a finite number from 0"),
    ("--payload-kg nan", ["--payload-kg", "nan"], r"--payload-kg must be a finite number from 0"),
    ("--dt-out 0", ["--dt-out", "0"], r"--dt-out must be a finite number > 0 s, got 0.0"),
    ("--dt-out inf", ["--dt-out", "inf"], r"--dt-out must be a finite number > 0 s"),
    ("--dt-out off the period", ["--dt-out", "0.013"], r"multiple of the model's control period"),
    ("--dt-out not a number", ["--dt-out", "abc"], r"argument --dt-out: invalid float value: 'abc'"),
    ("--model unknown", ["--model", "bogus"], r"argument --model: invalid choice: 'bogus'"),
):
    case("option", "simulate " + _name, _match)(lambda tmp, extra=_extra: simulate(tmp, LOG, *extra))

for _argv, _match in (
    (["evaluate", "--seed", "-1"], r"--seed must be a whole number from 0"),
    (["evaluate", "--episodes", "0"], r"--episodes must be a whole number >= 1, got 0"),
    (["evaluate", "--seconds", "0"], r"--seconds must be a finite number > 0 s"),
    (["evaluate", "--seconds", "nan"], r"--seconds must be a finite number > 0 s"),
    (["video", "--out", "v.mp4", "--episodes", "0"], r"--episodes must be a whole number >= 1"),
    (["video", "--out", "v.mp4", "--seed", "-3"], r"--seed must be a whole number from 0"),
    (["demo", "--seconds", "0"], r"--seconds must be a finite number > 0 s"),
    (["demo", "--seconds", "-1"], r"--seconds must be a finite number > 0 s"),
    (["demo", "--fps", "0"], r"--fps must be a finite number > 0"),
    (["scripted", "--episodes", "0"], r"--episodes must be a whole number >= 1"),
    (["scripted", "--seconds", "inf"], r"--seconds must be a finite number > 0 s"),
    (["scripted", "--seed", "-1"], r"--seed must be a whole number from 0"),
    (["bench", "--steps", "0"], r"--steps must be a whole number >= 1"),
    (["bench", "--seconds", "-2"], r"--seconds must be a finite number > 0"),
    (["collect", "--samples", "0"], r"--samples must be a whole number >= 1"),
    (["collect", "--workers", "0"], r"--workers must be a whole number >= 1"),
    (["collect", "--seed", "-1"], r"--seed must be a whole number from 0"),
    (["validate", "--suite", "-1"], r"--suite must be a whole number >= 0"),
    (["validate", "--workers", "0"], r"--workers must be a whole number >= 1"),
    (["train", "--timesteps", "0"], r"--timesteps must be a whole number >= 1"),
    (["train", "--n-envs", "0"], r"--n-envs must be a whole number >= 1"),
    (["train", "--checkpoint-every", "0"], r"--checkpoint-every must be a whole number >= 1"),
    (["clone", "--out", "bc.zip", "--episodes", "0"], r"--episodes must be a whole number >= 1"),
    (["clone", "--out", "bc.zip", "--noise", "nan"], r"--noise must be a finite number from 0 to 1"),
    (["clone", "--out", "bc.zip", "--dagger-rounds", "-1"], r"--dagger-rounds must be a whole number >= 0"),
    (["evaluate", "--seed", "x"], r"argument --seed: invalid int value: 'x'"),
    (["nosuchcommand"], r"argument COMMAND: invalid choice: 'nosuchcommand'"),
    (["model", "--bogus"], r"unrecognized arguments: --bogus"),
):
    case("option", " ".join(_argv), _match)(lambda tmp, argv=_argv: list(argv))


@case("option", "view --payload-kg 1e9", r"--payload-kg must be a finite number from 0 to 2145", needs="view")
def _(tmp):
    return ["view", "--payload-kg", "1e9"]


# -- output paths ----------------------------------------------------------------------------------
@case("output path", "simulate --out a directory", r"output --out .*traj.csv is a directory")
def _(tmp):
    (tmp / "traj.csv").mkdir()
    return simulate(tmp)


@case("output path", "simulate --out under a file", r"output --out .*: .*afile is a file, not a directory")
def _(tmp):
    write(tmp / "afile", "x")
    return simulate(tmp, LOG, out="afile/traj.csv")


@case("output path", "simulate --out read-only file", r"output --out .*traj.csv is read-only")
def _(tmp):
    write(tmp / "traj.csv", "old trajectory\n", mode=0o444)
    return simulate(tmp)


@case("output path", "simulate --out in a read-only folder", r"cannot write in .*ro \(read-only\)")
def _(tmp):
    (tmp / "ro").mkdir()
    (tmp / "ro").chmod(0o555)
    return simulate(tmp, LOG, out="ro/traj.csv")


@case("output path", "simulate --out is --commands", r"output --out .*log.csv is also an input or another output")
def _(tmp):
    return simulate(tmp, LOG, out="log.csv")


@case("output path", "simulate --out a hard link to --commands", r"is also an input or another output")
def _(tmp):
    write(tmp / "log.csv", LOG)
    os.link(tmp / "log.csv", tmp / "traj.csv")
    return simulate(tmp, None)


@case("output path", "simulate --out a symlink to --commands", r"is also an input or another output")
def _(tmp):
    write(tmp / "log.csv", LOG)
    (tmp / "traj.csv").symlink_to(tmp / "log.csv")
    return simulate(tmp, None)


@case("output path", "video --width 0 over a good MP4", r"--width must be a whole number >= 1, got 0")
def _(tmp):
    write(tmp / "v.mp4", b"\x00\x00\x00\x18ftypmp42 a good video")
    return ["video", "--policy", "scripted", "--out", str(tmp / "v.mp4"), "--width", "0", "--height", "0"]


@case("output path", "video --out not an MP4", r"the video must be an .mp4 file")
def _(tmp):
    return ["video", "--policy", "scripted", "--out", str(tmp / "v.avi")]


@case("output path", "video --snapshot is --out", r"output --snapshot .*v.mp4 is also an input or another output")
def _(tmp):
    return ["video", "--policy", "scripted", "--out", str(tmp / "v.mp4"), "--snapshot", str(tmp / "v.mp4")]


@case("output path", "video --out a directory", r"output --out .*v.mp4 is a directory")
def _(tmp):
    (tmp / "v.mp4").mkdir()
    return ["video", "--policy", "scripted", "--out", str(tmp / "v.mp4")]


@case("output path", "demo --width 0 over a good demo.mp4", r"--width must be a whole number >= 1, got 0")
def _(tmp):
    write(tmp / "out" / "demo.mp4", b"a good video")
    return ["demo", "--out", str(tmp / "out"), "--width", "0", "--height", "0"]


@case("output path", "demo --out a file", r"output --out .*out is a file, not a directory")
def _(tmp):
    write(tmp / "out", "x")
    return ["demo", "--out", str(tmp / "out")]


@case("output path", "demo --seconds below one step", r"seconds must be at least one control step", error=ValueError)
def _(tmp):
    from hexgym_lab.agents.demo import run_demo

    return lambda: run_demo(tmp / "out", duration=0.01)


@case("output path", "demo's demo.png is a directory", r"demo output .*demo.png is a directory")
def _(tmp):
    (tmp / "out" / "demo.png").mkdir(parents=True)
    return ["demo", "--out", str(tmp / "out")]


@case("output path", "evaluate --json a directory", r"output --json .*e.json is a directory")
def _(tmp):
    (tmp / "e.json").mkdir()
    return ["evaluate", "--policy", "scripted", "--json", str(tmp / "e.json")]


@case("output path", "evaluate --json read-only", r"output --json .*e.json is read-only")
def _(tmp):
    write(tmp / "e.json", "{}", mode=0o444)
    return ["evaluate", "--policy", "scripted", "--json", str(tmp / "e.json")]


@case("output path", "bench --json under a file", r"afile is a file, not a directory")
def _(tmp):
    write(tmp / "afile", "x")
    return ["bench", "--json", str(tmp / "afile" / "b.json")]


@case("output path", "scripted --json a directory", r"is a directory")
def _(tmp):
    (tmp / "s.json").mkdir()
    return ["scripted", "--json", str(tmp / "s.json")]


@case("output path", "reference-report --out a file", r"output --out .* is a file, not a directory")
def _(tmp):
    return ["reference-report", "--out", str(write(tmp / "rep", "x"))]


@case("output path", "reference-report --out read-only", r"output --out .*rep is read-only")
def _(tmp):
    (tmp / "rep").mkdir(mode=0o555)
    return ["reference-report", "--out", str(tmp / "rep")]


@case("output path", "validate --out a file", r"output --out .* is a file, not a directory")
def _(tmp):
    return ["validate", "--out", str(write(tmp / "val", "x"))]


@case("output path", "build-assets --dir a file", r"output --dir .* is a file, not a directory")
def _(tmp):
    return ["build-assets", "--dir", str(write(tmp / "assets", "x"))]


@case("output path", "collect --out a file", r"output --out .*data is a file, not a directory")
def _(tmp):
    return ["collect", "--out", str(write(tmp / "data", "x"))]


@case("output path", "fit --out a file", r"output --out .*tables is a file, not a directory")
def _(tmp):
    return ["fit", "--data", str(tmp), "--out", str(write(tmp / "tables", "x"))]


@case("output path", "train --log-dir a file", r"output --log-dir .*logs is a file, not a directory")
def _(tmp):
    return ["train", "--log-dir", str(write(tmp / "logs", "x"))]


@case("output path", "clone --out a directory", r"output --out .*bc.zip is a directory")
def _(tmp):
    (tmp / "bc.zip").mkdir()
    return ["clone", "--out", str(tmp / "bc.zip")]


@case("output path", "clone --out not a zip", r"the model must be a .zip file", error=ValueError)
def _(tmp):
    from hexgym_lab.agents.training import clone_scripted

    return lambda: clone_scripted(tmp / "bc.pt")


@case("output path", "clone normaliser read-only", r"observation normaliser .*bc_vecnormalize.json is read-only")
def _(tmp):
    write(tmp / "bc_vecnormalize.json", "{}", mode=0o444)
    return ["clone", "--out", str(tmp / "bc.zip")]


@case("output path", "view --screenshot a directory", r"output --screenshot .* is a directory", needs="view")
def _(tmp):
    (tmp / "shot.png").mkdir()
    return ["view", "--screenshot", str(tmp / "shot.png")]


@case("output path", "fit --out is --data", r"output --out .*data is also an input of this command")
def _(tmp):
    (tmp / "data").mkdir()
    return ["fit", "--data", str(tmp / "data"), "--out", str(tmp / "data")]


@case("output path", "convert-normalizer over its own input", r"normaliser .*x.json is also an input")
def _(tmp):
    return ["convert-normalizer", str(write(tmp / "x.json", evil_pickle(tmp)))]


@case("output path", "video frames beyond memory", r"the video would hold 1801 frames of 1920 x 1080")
def _(tmp):
    return ["video", "--policy", "scripted", "--out", str(tmp / "v.mp4"), "--seconds", "86400", "--width", "1920",
            "--height", "1080"]  # fmt: skip


@case("output path", "demo frames beyond memory", r"the demo would hold 36002 frames of 1920 x 1080")
def _(tmp):
    return ["demo", "--out", str(tmp / "out"), "--seconds", "3600", "--width", "1920", "--height", "1080"]


@case("option", "evaluate --seconds beyond a day", r"time_limit must be at most 86400 s")
def _(tmp):
    return ["evaluate", "--policy", "scripted", "--seconds", "1e6", "--episodes", "1"]


# -- collected data: chunks (collect, resuming) and data sets (fit, tables --bench) ----------------
def _chunk(tmp: Path, content: bytes | None = None) -> Path:
    """Chunk 0 of the boom/bucket group in ``tmp/data``: ``content``, or an npz whose metadata is no JSON."""
    from hexgym_lab.mbl.collect import chunk_path

    path = chunk_path(tmp / "data", "boom_bucket", 0)
    if content is not None:
        return write(path, content)
    path.parent.mkdir(parents=True)
    with path.open("wb") as f:
        np.savez(f, meta=np.array("not json {"), boom_X=np.zeros((2, 2)))
    return path


@case("data chunk", "resume over a truncated chunk", r"chunk .*boom_bucket_00000.npz is unreadable .* delete it")
def _(tmp):
    buffer = __import__("io").BytesIO()
    np.savez(buffer, meta=np.array("{}"), boom_X=np.zeros((50, 4)))
    _chunk(tmp, buffer.getvalue()[:600])
    return ["collect", "--out", str(tmp / "data"), "--samples", "10", "--workers", "1", "--tables", "paper"]


@case("data chunk", "resume over a chunk with bad metadata", r"is unreadable \(JSONDecodeError.* delete it")
def _(tmp):
    _chunk(tmp)
    return ["collect", "--out", str(tmp / "data"), "--samples", "10", "--workers", "1", "--tables", "paper"]


@case("data chunk", "resume (default set) over a truncated chunk", r"chunk \S*_00000.npz is unreadable .* delete it")
def _(tmp):
    from hexgym.mbl.schema import DEFAULT_TABLE_SET
    from hexgym_lab.mbl.collect import CollectConfig, chunk_path

    buffer = __import__("io").BytesIO()
    np.savez(buffer, meta=np.array("{}"), swing_bypass_X=np.zeros((50, 1)))
    write(chunk_path(tmp / "data", CollectConfig(table_set=DEFAULT_TABLE_SET).groups()[0], 0), buffer.getvalue()[:600])
    return ["collect", "--out", str(tmp / "data"), "--samples", "10", "--workers", "1"]


@case("data chunk", "resume over a text file", r"chunk .* is unreadable .* delete it to recompute it", error=ValueError)
def _(tmp):
    from hexgym_lab.mbl.collect import CollectConfig, collect

    _chunk(tmp, b"not an npz\n")
    config = CollectConfig(table_set="paper")
    return lambda: collect(tmp / "data", samples_per_group=10, seed=0, workers=1, progress=False, config=config)


def _valid_chunk(tmp: Path, change: Callable[[dict], None]) -> Callable[[], Any]:
    """Chunk 0 made with this run's settings (so its metadata fits), then ``change``d; the resuming call."""
    from hexgym_lab.mbl import collect as c

    config = c.CollectConfig(table_set="paper")
    tables = config.tables("boom_bucket")
    arrays = {f"{t}_{k}": np.zeros((3, 4)) if k == "X" else np.zeros(3) for t in tables for k in ("X", "y")}
    arrays |= {f"{t}_{k}": np.zeros(3, np.int64) for t in tables for k in ("episode", "segment")}
    arrays["episode_index"] = np.arange(config.episodes_per_chunk)
    change(arrays)
    meta = c._chunk_meta("boom_bucket", 0, 0, config, c.model_fingerprint()) | {"wall_seconds": 1.0, "errors": []}
    arrays["meta"] = np.array(json.dumps(meta, sort_keys=True))
    path = c.chunk_path(tmp / "data", "boom_bucket", 0)
    path.parent.mkdir(parents=True)
    with path.open("wb") as f:
        np.savez(f, **arrays)
    return lambda: c.collect(tmp / "data", samples_per_group=10, seed=0, workers=1, progress=False, config=config)


@case("data chunk", "resume over a chunk lacking an array", r"chunk .* lacks 'boom_y'; delete it", error=ValueError)
def _(tmp):
    return _valid_chunk(tmp, lambda a: a.pop("boom_y"))


@case("data chunk", "resume over a chunk with a NaN", r"holds non-finite numbers in 'boom_X'", error=ValueError)
def _(tmp):
    return _valid_chunk(tmp, lambda a: a["boom_X"].__setitem__((1, 2), np.nan))


@case("data chunk", "resume over a chunk with text for numbers", r"has 'boom_X' of the wrong type", error=ValueError)
def _(tmp):
    return _valid_chunk(tmp, lambda a: a.update(boom_X=np.full((3, 4), "x")))


def _dataset(tmp: Path, **arrays: Any) -> list[str]:
    n = 5
    base = {"X": np.zeros((n, 4)), "y": np.zeros(n), "inputs": np.array(["a", "b", "c", "d"]),
            "output": np.array("v"), "episode": np.arange(n)}  # fmt: skip
    base.update(arrays)
    (tmp / "data").mkdir(exist_ok=True)
    with (tmp / "data" / "boom.npz").open("wb") as f:
        np.savez(f, **{k: v for k, v in base.items() if v is not None})
    return ["fit", "--data", str(tmp / "data"), "--out", str(tmp / "fitted"), "--tables", "paper"]


for _name, _arrays, _match in (
    ("X with a NaN", {"X": np.array([[0.0] * 4] * 4 + [[0, np.nan, 0, 0]])}, r"'X' holds a non-finite number at row 4"),
    ("y with an inf", {"y": np.array([0, 0, np.inf, 0, 0])}, r"'y' holds a non-finite number at row 2"),
    ("no y", {"y": None}, r"lacks the array\(s\) \['y'\]"),
    ("y too short", {"y": np.zeros(3)}, r"'y' must be 5 floats"),
    ("X of text", {"X": np.array([["a"] * 4] * 5)}, r"'X' must be a float array"),
    ("object array (a pickle)", {"X": np.array([None] * 5, dtype=object)}, r"corrupt or not an .npz data set"),
):
    case("data set", "fit " + _name, _match)(lambda tmp, arrays=_arrays: _dataset(tmp, **arrays))


@case("data set", "fit --data missing", r"input directory --data .*nodata does not exist")
def _(tmp):
    return ["fit", "--data", str(tmp / "nodata"), "--out", str(tmp / "fitted")]


@case("data set", "fit, boom.npz garbage", r"data set .*boom.npz is corrupt or not an .npz data set")
def _(tmp):
    write(tmp / "data" / "boom.npz", b"PK\x03\x04 garbage")
    return ["fit", "--data", str(tmp / "data"), "--out", str(tmp / "fitted"), "--tables", "paper"]


@case("data set", "fit, boom.npz missing", r"data set .*boom.npz does not exist \(run `hexgym collect`\)")
def _(tmp):
    (tmp / "data").mkdir()
    return ["fit", "--data", str(tmp / "data"), "--out", str(tmp / "fitted"), "--tables", "paper"]


@case(
    "data set", "fit (default set), swing_bypass.npz garbage", r"data set .*swing_bypass.npz is corrupt or not an .npz"
)
def _(tmp):
    write(tmp / "data" / "swing_bypass.npz", b"PK\x03\x04 garbage")
    return ["fit", "--data", str(tmp / "data"), "--out", str(tmp / "fitted")]


@case("data set", "fit (default set), swing_bypass.npz missing", r"data set .*swing_bypass.npz does not exist \(run")
def _(tmp):
    (tmp / "data").mkdir()
    return ["fit", "--data", str(tmp / "data"), "--out", str(tmp / "fitted")]


@case("data set", "collect's report of a table left without samples: accepted")
def _(tmp):
    from hexgym_lab.mbl.collect import coverage_report

    stats = {"episodes": 1, "segments": 1.0, "rejected_fraction": 0.0, "rejected_windows": 0.0, "sim_seconds": 38.0}
    arrays = {"X": np.zeros((0, 1)), "y": np.zeros(0), "episode": np.zeros(0, np.int64),
              "segment": np.zeros(0, np.int64), "inputs": np.array(["boom_spool_m"]),
              "output": np.array("boom_pb_area_m2"), "seed": np.array(0), "generator_version": np.array(1),
              "meta": np.array(json.dumps({"stats": stats}))}  # fmt: skip
    (tmp / "data").mkdir()
    with (tmp / "data" / "boom_pb.npz").open("wb") as f:
        np.savez(f, **arrays)

    def call() -> None:  # a short collection of the circuit set leaves some passages' data sets empty
        report = coverage_report({"boom_pb": tmp / "data" / "boom_pb.npz"})
        assert "boom_pb: 0 samples" in report and "no samples: collect more" in report, report

    return call


@case("data set", "tables --bench missing", r"input directory --bench .* does not exist")
def _(tmp):
    return ["tables", "--bench", str(tmp / "nodata")]


# -- MBL tables through the command line (both loaders: test_table_damage_both_backends below) ------
def _tables(tmp: Path, table_set: str) -> Path:
    """A copy of ``table_set``'s packaged tables in ``tmp/tables``."""
    from hexgym.mbl.table import packaged_tables_dir

    return Path(shutil.copytree(packaged_tables_dir(table_set), tmp / "tables"))


@case("table", "tables --dir --tables paper with an edited value", r"MBL table file .*boom.npz: content hash mismatch")
def _(tmp):
    _rewrite_table(_tables(tmp, "paper") / "boom.npz", values=lambda v: v + 1e-6)
    return ["tables", "--dir", str(tmp / "tables"), "--tables", "paper"]


@case("table", "tables --dir missing", r"input directory --dir .*nosuch does not exist")
def _(tmp):
    return ["tables", "--dir", str(tmp / "nosuch")]


@case("table", "table file is a directory", r"MBL table file .*boom.npz is not a regular file", error=TableFileError)
def _(tmp):
    from hexgym.mbl.table import load_table

    (tmp / "boom.npz").mkdir()
    return lambda: load_table(tmp / "boom.npz")


# The default (circuit) set's one-input valve tables through the commands that take a tables directory
# (``tables --dir`` and ``validate --tables-dir``, which runs the default model on them): one line naming the file.
# (validate's --out is put in the case's folder: a refused validate still makes its --out's parent folder.)
def _paper_table_in_place(path: Path) -> None:
    from hexgym.mbl.table import packaged_tables_dir

    shutil.copyfile(packaged_tables_dir("paper") / "boom.npz", path)


_CIRCUIT_FILE_DAMAGE = {
    "an edited value": (lambda p: _rewrite_table(p, values=lambda v: v * 1.001), r": content hash mismatch"),
    "a wrong hash": (lambda p: _rewrite_table(p, meta={"content_sha256": "0" * 64}), r": content hash mismatch"),
    "truncated": (lambda p: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2]), r" is corrupt or not a table"),
    "missing": (Path.unlink, r" does not exist"),
    "a paper table in its place": (_paper_table_in_place, r" holds table 'boom', expected 'boom_pa'"),
}


def _damaged_circuit_tables(tmp: Path, argv: list[str], spoil: Callable[[Path], None]) -> list[str]:
    spoil(_tables(tmp, "circuit") / "boom_pa.npz")
    return [*(_validate(tmp) if argv[0] == "validate" else argv), str(tmp / "tables")]


def _validate(tmp: Path) -> list[str]:
    return ["validate", "--out", str(tmp / "report"), "--tables-dir"]


for _argv in (["tables", "--dir"], ["validate", "--tables-dir"]):
    for _name, (_spoil, _match) in _CIRCUIT_FILE_DAMAGE.items():
        case(
            "table", f"{' '.join(_argv)}, default set: boom_pa.npz {_name}", r"MBL table file \S*boom_pa.npz" + _match
        )(lambda tmp, argv=_argv, spoil=_spoil: _damaged_circuit_tables(tmp, argv, spoil))


@case("table", "validate --tables-dir of the paper set", r"MBL table file \S*tables/swing_bypass.npz does not exist")
def _(tmp):
    return [*_validate(tmp), str(_tables(tmp, "paper"))]


@case(
    "table", "tables --dir of the circuit set with --tables paper", r"MBL table file \S*tables/boom.npz does not exist"
)
def _(tmp):
    return ["tables", "--dir", str(_tables(tmp, "circuit")), "--tables", "paper"]


@case(
    "table",
    "validate --tables-dir missing",
    r"(input directory --tables-dir \S*nosuch|MBL table file \S*nosuch/swing_bypass.npz) does not exist",
)
def _(tmp):
    return [*_validate(tmp), str(tmp / "nosuch")]


# -- policies: the model zip ------------------------------------------------------------------------
def _policy(tmp: Path, normalizer: bool = True) -> Path:
    from hexgym.agents.policies import SHIPPED_POLICY
    from hexgym.agents.policy_files import normalizer_path

    path = Path(shutil.copy(SHIPPED_POLICY, tmp / "policy.zip"))
    if normalizer:
        shutil.copy(normalizer_path(SHIPPED_POLICY), normalizer_path(path))
    return path


def _rewrite_zip(path: Path, change: Callable[[dict[str, bytes]], None]) -> Path:
    with zipfile.ZipFile(path) as z:
        members = {n: z.read(n) for n in z.namelist()}
    change(members)
    with zipfile.ZipFile(path, "w") as z:
        for name, data in members.items():
            z.writestr(name, data)
    return path


def _rewrite_data(path: Path, change: Callable[[dict], None]) -> Path:
    def edit(members: dict[str, bytes]) -> None:
        data = json.loads(members["data"])
        change(data)
        members["data"] = json.dumps(data).encode()

    return _rewrite_zip(path, edit)


def _evaluate(path: Path) -> list[str]:
    return ["evaluate", "--policy", str(path), "--episodes", "1"]


def _pickled(tmp: Path, **readable: Any) -> dict:
    return {":type:": "<class 'object'>", ":serialized:": base64.b64encode(evil_pickle(tmp)).decode(), **readable}


@case("policy", "missing", r"no policy file .*nope.zip")
def _(tmp):
    return _evaluate(tmp / "nope.zip")


@case("policy", "a directory, no RLlib checkpoint", r"policy.zip is not an RLlib checkpoint .*\(no learner_group")
def _(tmp):
    (tmp / "policy.zip").mkdir()
    return _evaluate(tmp / "policy.zip")


@case("policy", "a text file", r"policy.zip is not a Stable-Baselines3 model zip")
def _(tmp):
    return _evaluate(write(tmp / "policy.zip", "hello"))


@case("policy", "a zip without data", r"is not a Stable-Baselines3 model zip \(.*data")
def _(tmp):
    return _evaluate(_rewrite_zip(_policy(tmp), lambda m: m.pop("data")))


@case("policy", "data that is not JSON", r"is not a Stable-Baselines3 model zip")
def _(tmp):
    return _evaluate(_rewrite_zip(_policy(tmp), lambda m: m.update(data=b"\x80\x04 not json")))


@case("policy", "a truncated zip", r"is not a Stable-Baselines3 model zip")
def _(tmp):
    path = _policy(tmp)
    path.write_bytes(path.read_bytes()[:4000])
    return _evaluate(path)


@case("policy", "an extra pickled entry", r"its 'evil' is pickled; hexgym does not unpickle", marker=True)
def _(tmp):
    return _evaluate(_rewrite_data(_policy(tmp), lambda d: d.update(evil=_pickled(tmp))))


@case("policy", "policy_class not an SB3 policy", r"neither a PPO nor a SAC MlpPolicy model", marker=True)
def _(tmp):
    return _evaluate(_rewrite_data(_policy(tmp), lambda d: d.update(policy_class=_pickled(tmp, __module__="os"))))


@case("policy", "a crafted policy_class pickle is never loaded: accepted", marker=True)
def _(tmp):
    from hexgym.agents.policies import load_policy

    def craft(data: dict) -> None:
        data["policy_class"][":serialized:"] = _pickled(tmp)[":serialized:"]  # readable fields say PPO's

    path = _rewrite_data(_policy(tmp), craft)
    return lambda: load_policy(str(path)) and None


@case("policy", "observations of another shape", r"the policy takes observations of shape \(22,\)")
def _(tmp):
    return _evaluate(_rewrite_data(_policy(tmp), lambda d: d["observation_space"].update(_shape=[22])))


@case("policy", "actions of another shape", r"the policy takes actions of shape \(3,\)")
def _(tmp):
    return _evaluate(_rewrite_data(_policy(tmp), lambda d: d["action_space"].update(_shape=[3])))


@case("policy", "weights that are garbage", r"policy.zip: the model does not load")
def _(tmp):
    return _evaluate(_rewrite_zip(_policy(tmp), lambda m: m.update({"policy.pth": b"garbage"})))


@case("policy", "weights that are a crafted pickle", r"policy.zip: the model does not load", marker=True)
def _(tmp):
    return _evaluate(_rewrite_zip(_policy(tmp), lambda m: m.update({"policy.pth": evil_pickle(tmp)})))


@case("policy", "policy_kwargs naming an unknown class", r"policy_kwargs name .*os.system.* hexgym does not load")
def _(tmp):
    kwargs = {":type:": "<class 'dict'>", ":serialized:": "AAAA", "activation_fn": "<class 'os.system'>"}
    return _evaluate(_rewrite_data(_policy(tmp), lambda d: d.update(policy_kwargs=kwargs)))


@case("policy", "a pickled schedule hexgym cannot read", r"the clip_range is a pickled schedule", marker=True)
def _(tmp):
    schedule = _pickled(tmp, value_schedule="<function <lambda>>")
    return _evaluate(_rewrite_data(_policy(tmp), lambda d: d.update(clip_range=schedule)))


def _sac(tmp: Path) -> Path:
    """A small SAC model saved as ``hexgym train`` saves one (its train_freq is pickled by SB3)."""
    import gymnasium as gym
    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from hexgym_lab.agents.training import save_model

    venv = VecNormalize(DummyVecEnv([lambda: gym.make("HexLoading-v0", time_limit=1.0)]))
    model = SAC(
        "MlpPolicy", venv, device="cpu", policy_kwargs={"net_arch": [8]}, buffer_size=10, train_freq=(2, "step")
    )
    path = save_model(model, tmp / "sac.zip")
    venv.close()
    return path


@case("policy", "SAC with a crafted train_freq pickle", r"its train_freq is not one hexgym can read", marker=True)
def _(tmp):
    path = _sac(tmp)
    return _evaluate(_rewrite_data(path, lambda d: d["train_freq"].update(_pickled(tmp))))


@case("policy", "SAC and a PPO with a pickled activation: accepted", marker=True)
def _(tmp):
    from hexgym.agents.policies import load_trained

    sac, ppo = _sac(tmp), _relu_ppo(tmp)

    def call() -> None:
        assert load_trained(sac).model.train_freq.frequency == 2
        assert load_trained(ppo).model.policy.activation_fn.__name__ == "ReLU"

    return call


def _relu_ppo(tmp: Path) -> Path:
    import gymnasium as gym
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv

    from hexgym_lab.agents.hyperparams import parse_kwargs
    from hexgym_lab.agents.training import save_model

    venv = DummyVecEnv([lambda: gym.make("HexLoading-v0", time_limit=1.0)])
    kwargs = parse_kwargs("dict(activation_fn=nn.ReLU, net_arch=dict(pi=[8], vf=[8]))")
    model = PPO("MlpPolicy", venv, device="cpu", policy_kwargs=kwargs, n_steps=8, batch_size=8)
    return save_model(model, tmp / "p.zip")


@case("policy", "video with a policy lacking its normaliser", r"has no observation normaliser")
def _(tmp):
    return ["video", "--policy", str(_policy(tmp, normalizer=False)), "--out", str(tmp / "v.mp4")]


@case("policy", "train --init-from a text file", r"init.zip is not a Stable-Baselines3 model zip")
def _(tmp):
    write(tmp / "h.yml", TINY_YAML)
    init = write(tmp / "init.zip", "not a model")
    return ["train", "--hyperparams", str(tmp / "h.yml"), "--init-from", str(init), "-f", str(tmp / "logs")]


@case("policy", "train --init-from a policy without its normaliser", r"has no observation normaliser")
def _(tmp):
    write(tmp / "h.yml", TINY_YAML)
    init = _policy(tmp, normalizer=False)
    return ["train", "--hyperparams", str(tmp / "h.yml"), "--init-from", str(init), "-f", str(tmp / "logs")]


# -- policies: the observation normaliser ----------------------------------------------------------
def _normalizer(tmp: Path, change: Callable[[dict], None] | None = None, raw: bytes | None = None) -> list[str]:
    from hexgym.agents.policy_files import normalizer_path

    path = _policy(tmp)
    stats = normalizer_path(path)
    if raw is not None:
        stats.write_bytes(raw)
    elif change is not None:
        data = json.loads(stats.read_text())
        change(data)
        stats.write_text(json.dumps(data))
    return _evaluate(path)


def _drop_last(data: dict) -> None:
    data["obs"]["mean"].pop()
    data["obs"]["var"].pop()


for _name, _change, _match in (
    ("another format", lambda d: d.update(format="sb3"), r"format 'sb3', expected 'hexgym.vecnormalize'"),
    ("version 2", lambda d: d.update(version=2), r"version 2; this hexgym reads 1"),
    ("a negative variance", lambda d: d["obs"]["var"].__setitem__(3, -1.0), r"a variance in 'obs.var' is negative"),
    ("22 entries for 23 observations", _drop_last, r"has 22 entries, the policy's observations 23"),
    ("mean and variance of different lengths", lambda d: d["obs"]["var"].pop(), r"lists of the same length"),
    ("an unknown key", lambda d: d.update(eval="__import__('os')"), r"unknown key\(s\) \['eval'\]"),
    ("a boolean clip", lambda d: d.update(clip_obs=True), r"'clip_obs' must be a finite number, got True"),
    ("a number as text", lambda d: d["obs"]["mean"].__setitem__(0, "1.0"), r"'obs.mean\[0\]' must be a finite"),
    ("epsilon 0", lambda d: d.update(epsilon=0), r"'epsilon' must be > 0"),
    ("an unknown dtype", lambda d: d["obs"].update(dtype="float16"), r"'obs.dtype' must be one of"),
    ("not an object", lambda d: d.clear(), r"format None, expected"),
):
    case("normaliser", _name, _match)(lambda tmp, change=_change: _normalizer(tmp, change))

for _name, _raw, _match in (
    ("a NaN", b'{"format": "hexgym.vecnormalize", "version": 1, "clip_obs": NaN}', r"NaN is not a finite number"),
    ("not JSON", b"mean: 1, var: 2\n", r"observation normaliser .* is not a JSON file"),
    ("binary", bytes(range(256)), r"observation normaliser .* is not a JSON file"),
    ("a JSON list", b"[1, 2, 3]", r"not a JSON object"),
    ("deeply nested", b"[" * 100_000, r"is not a JSON file"),
):
    case("normaliser", _name, _match)(lambda tmp, raw=_raw: _normalizer(tmp, raw=raw))


@case("normaliser", "a pickle under the .json name", r"is a pickle, not JSON: convert it once", marker=True)
def _(tmp):
    return _normalizer(tmp, raw=evil_pickle(tmp))


@case("normaliser", "missing: the policy is refused, not run raw", r"policy .*policy.zip has no observation normaliser")
def _(tmp):
    return _evaluate(_policy(tmp, normalizer=False))


@case("normaliser", "only an old pickled one (crafted)", r"is a pickle, which hexgym no longer reads", marker=True)
def _(tmp):
    path = _policy(tmp, normalizer=False)
    write(tmp / "policy_vecnormalize.pkl", evil_pickle(tmp))
    return _evaluate(path)


@case("normaliser", "a directory", r"observation normaliser .* is a directory")
def _(tmp):
    from hexgym.agents.policy_files import normalizer_path

    path = _policy(tmp, normalizer=False)
    normalizer_path(path).mkdir()
    return _evaluate(path)


# -- policies: what they were trained on (the normaliser's trained_on) ----------------------------------
def _trained_on(tmp: Path, env_id: str = "HexLoading-v0", tables: str | None = "circuit", **more: Any) -> Path:
    """The shipped agent's copy, its normaliser recording that it was trained on ``env_id`` and ``tables``."""
    from hexgym.agents.policy_files import normalizer_path
    from hexgym.envs.loading import OBSERVATION_NAMES

    path = _policy(tmp)
    stats = normalizer_path(path)
    data = json.loads(stats.read_text())
    data["trained_on"] = {"env_id": env_id, "obs_names": list(OBSERVATION_NAMES)} | more
    if tables is not None:
        data["trained_on"]["tables"] = tables
    stats.write_text(json.dumps(data))
    return path


def _short(path: Path, *extra: str) -> list[str]:
    return [*_evaluate(path), "--seconds", "0.5", *extra]


@case("policy", "a HexDig-v0 policy on HexLoading-v0", r"policy.zip: trained on HexDig-v0, used on HexLoading-v0$")
def _(tmp):
    return _evaluate(_trained_on(tmp, "HexDig-v0"))


@case("policy", "a HexLoading-v0 policy on HexDig-v0", r"policy.zip: trained on HexLoading-v0, used on HexDig-v0$")
def _(tmp):
    return [*_evaluate(_trained_on(tmp)), "--env", "HexDig-v0"]


@case("policy", "a paper-tables policy on circuit", r"policy.zip: trained on the paper tables, used on the circuit")
def _(tmp):
    return _evaluate(_trained_on(tmp, tables="paper"))


@case("policy", "a fitted model's policy on circuit", r"trained on the fitted model 'unit5', used on the circuit")
def _(tmp):
    return _evaluate(_trained_on(tmp, tables="model:unit5"))


@case("policy", "trained on circuit, used on paper", r"trained on the circuit tables, used on the paper tables")
def _(tmp):
    return [*_evaluate(_trained_on(tmp)), "--tables", "paper"]


@case("policy", "another observation layout", r"observation 0 is 'stick_angle' in the policy, 'boom_angle' here")
def _(tmp):
    from hexgym.envs.loading import OBSERVATION_NAMES

    names = list(OBSERVATION_NAMES)
    names[0], names[1] = names[1], names[0]
    return _evaluate(_trained_on(tmp, obs_names=names))


@case("policy", "video of a policy trained on HexDig-v0", r"policy.zip: trained on HexDig-v0, used on HexLoading-v0")
def _(tmp):
    return ["video", "--policy", str(_trained_on(tmp, "HexDig-v0")), "--out", str(tmp / "v.mp4")]


@case("policy", "train --init-from a policy trained on paper", r"trained on the paper tables, used on the circuit")
def _(tmp):
    write(tmp / "h.yml", TINY_YAML)
    init = _trained_on(tmp, tables="paper")
    return ["train", "--hyperparams", str(tmp / "h.yml"), "--init-from", str(init), "-f", str(tmp / "logs")]


@case("policy", "trained on its task and tables: accepted", exit_code=0)
def _(tmp):
    return _short(_trained_on(tmp))


@case("policy", "trained on paper, on the reference model: accepted", exit_code=0)
def _(tmp):
    return _short(_trained_on(tmp, tables="paper"), "--model", "reference")


@case("policy", "nothing recorded (an older file): accepted", exit_code=0)
def _(tmp):
    return _short(_policy(tmp))


for _name, _value, _match in (
    ("not an object", "HexDig-v0", r"'trained_on' must be an object with 'env_id'"),
    ("no env_id", {"tables": "circuit"}, r"'trained_on' must be an object with 'env_id'"),
    ("an unknown key", {"env_id": "HexLoading-v0", "seed": 1}, r"'trained_on' must be an object with 'env_id'"),
    ("tables a number", {"env_id": "HexLoading-v0", "tables": 3}, r"'trained_on.tables' must be a non-empty string"),
    ("obs_names not names", {"env_id": "HexLoading-v0", "obs_names": [1]}, r"'trained_on.obs_names' must be a non"),
):
    case("normaliser", "trained_on " + _name, _match)(
        lambda tmp, value=_value: _normalizer(tmp, lambda d: d.update(trained_on=value))
    )


@case(
    "normaliser", "convert-normalizer of a crafted pickle", r"refers to posix.mkdir, which a VecNormalize", marker=True
)
def _(tmp):
    return ["convert-normalizer", str(write(tmp / "x_vecnormalize.pkl", evil_pickle(tmp)))]


@case("normaliser", "convert-normalizer of a text file", r"is not a pickled VecNormalize hexgym can convert")
def _(tmp):
    return ["convert-normalizer", str(write(tmp / "x_vecnormalize.pkl", "hello"))]


@case("normaliser", "convert-normalizer --out read-only", r"output --out .*x.json is read-only")
def _(tmp):
    write(tmp / "x.json", "{}", mode=0o444)
    return ["convert-normalizer", str(write(tmp / "x_vecnormalize.pkl", b"x")), "--out", str(tmp / "x.json")]


# -- hyperparameter YAML (train, clone) -----------------------------------------------------------
def _train_yaml(tmp: Path, text: str | bytes, *extra: str) -> list[str]:
    write(tmp / "h.yml", text)
    return ["train", "--hyperparams", str(tmp / "h.yml"), "-f", str(tmp / "logs"), "--n-envs", "2", *extra]


for _name, _text, _match in (
    ("not YAML", "HexLoading-v0: [1, 2\n", r"h.yml is not a readable YAML file"),
    ("a list", "- 1\n- 2\n", r"h.yml must map env ids to hyperparameters, not hold a list"),
    ("no entry for the env", "Other-v0: {}\n", r"h.yml has no entry for 'HexLoading-v0'"),
    ("an entry that is a number", "HexLoading-v0: 3\n", r"the entry for 'HexLoading-v0' must be a mapping"),
    (
        "code in policy_kwargs",
        TINY_YAML.replace("dict(net_arch=dict(pi=[16], vf=[16]))", "__import__('os').mkdir('MARKER')"),
        r"cannot read the hyperparameter .* is not allowed: only dict\(...\), literals and nn.<activation>",
    ),
    (
        "an unknown activation",
        TINY_YAML.replace("dict(net_arch=dict(pi=[16], vf=[16]))", "dict(activation_fn=nn.Evil)"),
        r"nn.Evil is not an activation hexgym knows",
    ),
    (
        "a python/object tag",
        "HexLoading-v0: !!python/object/apply:os.mkdir ['MARKER']\n",
        r"h.yml is not a readable YAML file: could not determine a constructor",
    ),
    ("binary", b"HexLoading-v0:\n  gamma: \xff\xfe\x00", r"h.yml is not a readable YAML file"),
):
    case("YAML", _name, _match, marker=True)(lambda tmp, text=_text: _train_yaml(tmp, text))


@case("YAML", "an unknown hyperparameter", r"hyperparameter\(s\) \['learning_rat'\] are not arguments of PPO")
def _(tmp):
    return _train_yaml(tmp, TINY_YAML + "  learning_rat: 0.1\n")


@case("YAML", "env_kwargs with a NaN weight", r"fuel_weight must be a finite number, got nan")
def _(tmp):
    return _train_yaml(tmp, TINY_YAML.replace("{time_limit: 2.0}", "{time_limit: 2.0, fuel_weight: .nan}"))


@case("YAML", "env_kwargs with an unknown keyword", r"env_kwargs: .*unexpected keyword argument 'bogus'")
def _(tmp):
    return _train_yaml(tmp, TINY_YAML.replace("{time_limit: 2.0}", "{time_limit: 2.0, bogus: 1}"))


@case("YAML", "a value of the wrong type", r"hyperparameter n_epochs must be a whole number \(default 10\), got 'many'")
def _(tmp):
    return _train_yaml(tmp, TINY_YAML.replace("n_epochs: 1", "n_epochs: many"))


@case("YAML", "values SB3 refuses", r"the hyperparameters do not make a PPO model: .*batch_size")
def _(tmp):
    return _train_yaml(tmp, TINY_YAML.replace("batch_size: 64", "batch_size: 1"))[:-2] + ["--n-envs", "1"]


@case("YAML", "an alias bomb", r"expands to more than 100000 values")
def _(tmp):
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 9)]
    return _train_yaml(tmp, "\n".join(lines) + "\nHexLoading-v0: {n_steps: *a8}\n")


@case("YAML", "train --hyperparams missing", r"input file --hyperparams .*none.yml does not exist")
def _(tmp):
    return ["train", "--hyperparams", str(tmp / "none.yml"), "-f", str(tmp / "logs")]


@case("YAML", "checkpoints more often than one rollout", r"checkpoint_every must be at least one rollout \(128 steps")
def _(tmp):
    return _train_yaml(tmp, TINY_YAML, "--checkpoint-every", "100")


@case("YAML", "clone --hyperparams not YAML", r"is not a readable YAML file")
def _(tmp):
    return ["clone", "--out", str(tmp / "bc.zip"), "--hyperparams", str(write(tmp / "h.yml", "a: [\n"))]


# -- environment and Python API arguments ----------------------------------------------------------
def _env(**kwargs: Any) -> Callable[[Path], Callable[[], Any]]:
    def setup(tmp: Path) -> Callable[[], Any]:
        from hexgym.envs.loading import HexLoadingEnv

        return lambda: HexLoadingEnv(**kwargs)

    return setup


for _name, _kwargs, _match in (
    ("fuel_weight=nan", {"fuel_weight": float("nan")}, r"fuel_weight must be a finite number, got nan"),
    ("time_weight=inf", {"time_weight": float("inf")}, r"time_weight must be a finite number"),
    ("delivery_weight as text", {"delivery_weight": "1"}, r"delivery_weight must be a finite number, got '1'"),
    ("time_limit=inf", {"time_limit": float("inf")}, r"time_limit must be a finite number > 0 s, got inf"),
    ("truck_capacity_kg=nan", {"truck_capacity_kg": float("nan")}, r"truck_capacity_kg must be a finite number > 0 kg"),
    ("time_limit as text", {"time_limit": "10"}, r"time_limit must be a finite number > 0 s, got '10'"),
    ("time_limit=True", {"time_limit": True}, r"time_limit must be a finite number > 0 s, got True"),
    (
        "truck_capacity_kg=None",
        {"truck_capacity_kg": None},
        r"truck_capacity_kg must be a finite number > 0 kg, got None",
    ),
    ("tables as a list", {"tables": ["paper"]}, r"tables must be one of \('paper', .*\), got \['paper'\]"),
    ("model as a list", {"model": ["learned"]}, r"model must be one of \('learned', 'reference'\), got \['learned'\]"),
    ("render width 0", {"render_mode": "rgb_array", "width": 0}, r"width must be a whole number of pixels >= 1"),
    ("render height 2.5", {"render_mode": "rgb_array", "height": 2.5}, r"height must be a whole number of pixels"),
    ("render width 5000", {"render_mode": "rgb_array", "width": 5000}, r"exceed the scene's offscreen buffer"),
):
    case("API argument", "HexLoadingEnv " + _name, _match, error=ValueError)(_env(**_kwargs))


@case("API argument", "HexLoadingEnv scene_path=5", r"scene_path must be a path \(str or os.PathLike\), got int 5",
      error=TypeError)  # fmt: skip
def _(tmp):
    return _env(scene_path=5)(tmp)


@case("API argument", "HexReachEnv tables as a list", r"tables must be one of .*, got \['paper'\]", error=ValueError)
def _(tmp):
    from hexgym.envs.reach import HexReachEnv

    return lambda: HexReachEnv(tables=["paper"])


def _step(action: Any) -> Callable[[Path], Callable[[], Any]]:
    def setup(tmp: Path) -> Callable[[], Any]:
        from hexgym.envs.loading import HexLoadingEnv

        env = HexLoadingEnv()
        env.reset(seed=0)
        return lambda: env.step(action)

    return setup


for _name, _action in (
    ("a dict", {"swing": 1}),
    ("text", "1,0,0,0"),
    ("None", None),
    ("a word among numbers", [1, 0, 0, "x"]),
):
    _kind = type(_action).__name__
    case("API argument", f"HexLoadingEnv.step of {_name}", rf"action must be an array of 4 numbers .*, got {_kind} ",
         error=TypeError)(_step(_action))  # fmt: skip
case("API argument", "HexLoadingEnv.step of ragged lists", r"action must be an array of 4 numbers .*: setting an array",
     error=ValueError)(_step([[1, 0], [0]]))  # fmt: skip


def _closed(env_id: str, call: Callable[[Any], Any]) -> Callable[[Path], Callable[[], Any]]:
    """``call(env)`` on a single environment (``gymnasium.make``'s, wrappers included) after a reset and two
    ``close`` calls (closing twice is allowed)."""

    def setup(tmp: Path) -> Callable[[], Any]:
        import gymnasium as gym

        import hexgym  # noqa: F401  (registers the ids)

        env = gym.make(env_id)
        env.reset(seed=0)
        env.close()
        env.close()
        return lambda: call(env)

    return setup


for _id in ("HexLoading-v0", "HexDig-v0", "HexReach-v0"):
    for _what, _call in (("step", lambda env: env.step(np.zeros(4, np.float32))), ("reset", lambda env: env.reset())):
        case("API argument", f"{_id}: {_what} after close", rf"^{_id} is closed: make a new one",
             error=RuntimeError)(_closed(_id, _call))  # fmt: skip


def _vector(call: Callable[[Any], Any], backend: str = "auto", close: bool = False, **kwargs: Any) -> Callable:
    """``call(env)`` on a batched HexLoading-v0 of 2 sites after its reset (and its ``close``)."""

    def setup(tmp: Path) -> Callable[[], Any]:
        from hexgym.envs.vector import HexLoadingVectorEnv

        env = HexLoadingVectorEnv(2, backend=backend, **kwargs)
        env.reset(seed=0)
        if close:
            env.close()
        return lambda: call(env)

    return setup


for _backend in ("auto", "python"):
    for _what, _call in (("step", lambda env: env.step(np.zeros((2, 4)))), ("reset", lambda env: env.reset(seed=1))):
        case("API argument", f"batched env ({_backend}): {_what} after close", r"HexLoading-v0 is closed",
             error=RuntimeError)(_vector(_call, _backend, close=True))  # fmt: skip
case("API argument", "batched env: step of a dict", r"actions must be an array of shape \(2, 4\) of numbers, got dict",
     error=TypeError)(_vector(lambda env: env.step({"swing": 1})))  # fmt: skip


@case("API argument", "batched env nthread as text", r"nthread must be a whole number >= 1, got 'x'", error=ValueError)
def _(tmp):
    from hexgym.envs.vector import HexLoadingVectorEnv

    return lambda: HexLoadingVectorEnv(2, nthread="x")


@case("API argument", "batched env tables as a list", r"tables must be one of .*, got \['paper'\]", error=ValueError)
def _(tmp):
    from hexgym.envs.vector import HexLoadingVectorEnv

    return lambda: HexLoadingVectorEnv(2, tables=["paper"])


@case("API argument", "set_payload(1e9)", r"payload must be a finite mass from 0 to 3218 kg", error=ValueError)
def _(tmp):
    from hexgym.hydraulics.reference import ReferenceModel

    return lambda: ReferenceModel().reset("home", 1e9)


@case("API argument", "replay from an unknown keyframe", r"no keyframe 'nosuch'", error=ValueError)
def _(tmp):
    from hexgym.hydraulics.reference import ReferenceModel
    from hexgym.model.commandlog import CommandLog
    from hexgym.model.replay import replay

    log = CommandLog(np.array([0.0, 0.1]), np.zeros((2, 4)))
    return lambda: replay(ReferenceModel(), log, start="nosuch")


@case("API argument", "replay of a log lasting 1e7 s", r"would make 2e\+08 trajectory rows", error=ValueError)
def _(tmp):
    from hexgym.hydraulics.reference import ReferenceModel
    from hexgym.model.commandlog import CommandLog
    from hexgym.model.replay import replay

    log = CommandLog(np.array([0.0, 1e7]), np.zeros((2, 4)))
    return lambda: replay(ReferenceModel(), log)


@case("API argument", "write_mp4 of no frames over a good file", r"no frames to write", error=ValueError)
def _(tmp):
    from hexgym.machine.render import write_mp4

    write(tmp / "v.mp4", b"a good video")
    return lambda: write_mp4([], tmp / "v.mp4", fps=10)


@case("API argument", "write_mp4 of 0 x 0 frames", r"cannot write an image of shape \(0, 0, 3\)", error=ValueError)
def _(tmp):
    from hexgym.machine.render import write_mp4

    return lambda: write_mp4([np.zeros((0, 0, 3), np.uint8)] * 3, tmp / "v.mp4", fps=10)


@case("API argument", "evaluate(seed=-1)", r"seed must be a whole number from 0", error=ValueError)
def _(tmp):
    from hexgym_lab.agents.evaluate import evaluate

    return lambda: evaluate("scripted", episodes=1, seed=-1)


@case("API argument", "record_video(width=0)", r"width must be a whole number >= 1", error=ValueError)
def _(tmp):
    from hexgym_lab.agents.video import record_video

    return lambda: record_video("scripted", tmp / "v.mp4", width=0)


@case("API argument", "run_demo(duration=nan)", r"seconds must be a finite number > 0 s, got nan", error=ValueError)
def _(tmp):
    from hexgym_lab.agents.demo import run_demo

    return lambda: run_demo(tmp / "out", duration=float("nan"))


@case("API argument", "check_output_file under a file", r"afile is a file, not a directory", error=PathError)
def _(tmp):
    from hexgym.files import check_output_file

    write(tmp / "afile", "x")
    return lambda: check_output_file(tmp / "afile" / "x.csv")


@case("API argument", "load_trained of a pickled normaliser", r"is a pickle, which hexgym", error=PolicyFileError,
      marker=True)  # fmt: skip
def _(tmp):
    from hexgym.agents.policies import load_trained

    path = _policy(tmp, normalizer=False)
    write(tmp / "policy_vecnormalize.pkl", evil_pickle(tmp))
    return lambda: load_trained(path)


# -- untrusted files: RLlib checkpoints and YAML env_wrapper run nothing -------------------------
def _rllib_checkpoint(tmp: Path, state: bytes | None = None, hidden: tuple[int, ...] = (8,), n_obs: int = 23) -> Path:
    """An RLlib checkpoint directory as `train --framework rllib` writes it: its module's weights pickled
    (or ``state``), and a crafted ``class_and_ctor_args.pkl`` (RLlib's own loader would run it)."""
    from collections import OrderedDict

    rng = np.random.default_rng(0)
    weights: OrderedDict[str, np.ndarray] = OrderedDict()
    size = n_obs
    for i, h in enumerate(hidden):
        weights[f"encoder.actor_encoder.net.mlp.{2 * i}.weight"] = rng.normal(size=(h, size)).astype(np.float32)
        weights[f"encoder.actor_encoder.net.mlp.{2 * i}.bias"] = np.zeros(h, np.float32)
        size = h
    weights["pi.net.mlp.0.weight"] = rng.normal(size=(8, size)).astype(np.float32)
    weights["pi.net.mlp.0.bias"] = np.zeros(8, np.float32)
    weights["vf.net.mlp.0.weight"] = rng.normal(size=(1, size)).astype(np.float32)
    weights["vf.net.mlp.0.bias"] = np.zeros(1, np.float32)
    module = tmp / "ck" / "learner_group" / "learner" / "rl_module" / "default_policy"
    write(module / "module_state.pkl", state if state is not None else pickle.dumps(weights, protocol=5))
    write(module / "class_and_ctor_args.pkl", evil_pickle(tmp))
    write(module / "metadata.json", '{"state_file": "module_state", "checkpoint_version": "2.1"}')
    return tmp / "ck"


@case("RLlib checkpoint", "weights with a crafted class file load without it", marker=True)
def _(tmp):
    from hexgym.agents.policies import load_rllib_policy

    checkpoint = _rllib_checkpoint(tmp)

    def load() -> None:
        policy = load_rllib_policy(checkpoint)
        action = policy.act(np.ones(23, np.float32), None)
        assert action.shape == (4,) and np.all(np.abs(action) <= 1)

    return load


for _name, _state, _match in (
    ("a crafted module_state.pkl", "evil", r"module_state.pkl is not an RL module's weights: it refers to posix.mkdir"),
    ("garbage weights", b"\x80\x05garbage", r"module_state.pkl is not an RL module's weights"),
    ("an object array", "object", r"not an RL module's weights|is not an array of finite numbers"),
    ("a list, not a mapping", "list", r"is not a mapping of names to arrays"),
    ("NaN weights", "nan", r"pi.net.mlp.0.weight is not an array of finite numbers"),
):
    case("RLlib checkpoint", _name, _match, marker=True)(
        lambda tmp, state=_state: _evaluate_rllib(tmp, _crafted_state(tmp, state))
    )


def _crafted_state(tmp: Path, kind: str) -> bytes:
    if isinstance(kind, bytes):
        return kind
    if kind == "evil":
        return evil_pickle(tmp)
    if kind == "object":
        return pickle.dumps({"pi.net.mlp.0.weight": np.array([object()] * 2, dtype=object)})
    if kind == "list":
        return pickle.dumps([np.zeros(3)])
    bad = {"pi.net.mlp.0.weight": np.full((8, 4), np.nan), "pi.net.mlp.0.bias": np.zeros(8)}
    return pickle.dumps(bad)


def _evaluate_rllib(tmp: Path, state: bytes) -> list[str]:
    return ["evaluate", "--policy", str(_rllib_checkpoint(tmp, state)), "--episodes", "1", "--seconds", "1"]


@case("RLlib checkpoint", "weights for other observations", r"is for 7 observations and 4 actions, HexLoading-v0 has",
      marker=True)  # fmt: skip
def _(tmp):
    return ["video", "--policy", str(_rllib_checkpoint(tmp, n_obs=7)), "--out", str(tmp / "v.mp4")]


@case("RLlib checkpoint", "no actor encoder", r"is not RLlib PPO's default module", marker=True)
def _(tmp):
    return ["evaluate", "--policy", str(_rllib_checkpoint(tmp, hidden=())), "--episodes", "1"]


@case("YAML", "env_wrapper naming a module to import", r"h.yml: env_wrapper 'os.mkdir' is not a registered wrapper",
      marker=True)  # fmt: skip
def _(tmp):
    return _train_yaml(tmp, TINY_YAML + "  env_wrapper: os.mkdir\n")


@case("YAML", "env_wrapper that is a mapping", r"env_wrapper must be the name of a registered wrapper", marker=True)
def _(tmp):
    return _train_yaml(tmp, TINY_YAML + "  env_wrapper: {gymnasium.wrappers.TimeLimit: {max_episode_steps: 3}}\n")


@case("YAML", "env_wrapper of a module in the working folder", r"'evilmod.Wrapper' is not a registered wrapper",
      marker=True)  # fmt: skip
def _(tmp):
    write(tmp / "evilmod.py", "import os\nos.mkdir('MARKER')\nWrapper = None\n")
    return _train_yaml(tmp, TINY_YAML + "  env_wrapper: evilmod.Wrapper\n")


# -- strict numbers: as a data file writes them -----------------------------------------------------
for _name, _body, _match in (
    ("a spool with an underscore", LOG.replace("0.2,5,", "0.2,1_0,"), r"row 2, column 'swing': '1_0' is not a number"),
    ("a hex time", LOG.replace("0.4,", "0x1,"), r"row 3, column 't': '0x1' is not a number"),
    ("a Unicode digit", LOG.replace("0.2,5,", "0.2,\u0665,"), r"column 'swing': '\u0665' is not a number"),
):
    case("command log", _name, _match)(lambda tmp, body=_body: simulate(tmp, body))

for _argv, _match in (
    (["simulate", "--commands", "log.csv", "--out", "t.csv", "--payload-kg", "1_0"], r"invalid float value: '1_0'"),
    (["evaluate", "--episodes", "1_0"], r"argument --episodes: invalid int value: '1_0'"),
    (["evaluate", "--seed", "0x10"], r"argument --seed: invalid int value: '0x10'"),
    (["plan", "--task", "dump", "--w-fuel", "nan"], r"--w-fuel must be a finite number, got nan"),
    (["plan", "--task", "dump", "--seeds", "0-100000000000"], r"100000000001 seeds; at most 1000000"),
    (["plan", "--task", "dump", "--seeds", "1_0-12"], r"--seeds must be A-B \(whole numbers"),
    (["tune-loader", "--out", "s.json", "--seeds", "0-"], r"--seeds must be A-B"),
):
    case("option", " ".join(_argv[:1] + _argv[-2:]), _match)(lambda tmp, argv=_argv: argv)


def _curve(tmp: Path, rows: str | bytes) -> list[str]:
    from hexgym_lab.agents.training import CURVE_COLUMNS

    rows = rows if isinstance(rows, bytes) else rows.encode()
    write(tmp / "run" / "curve.csv", (",".join(CURVE_COLUMNS) + "\n").encode() + rows)
    return ["curves", str(tmp / "run"), "--out", str(tmp / "c.png")]


for _name, _rows, _match in (
    ("truncated", "64,1.0,2,0.5,0.5,1.0\n128,2.0,3", r"curve.csv: row 2 \(line 3\) has 3 fields, not 6"),
    ("an underscore", "6_4,1.0,2,0.5,0.5,1.0\n", r"a row is not numbers: row 1 \(line 2\), column 'steps': '6_4'"),
    ("nan in a number", "64,nan,2,0.5,0.5,1.0\n", r"column 'wall_s': 'nan' is not a finite number"),
    ("binary", b"64,1.0,\xff\xfe\n", r"not a learning curve \(not a CSV text file"),
):
    case("learning curve", _name, _match)(lambda tmp, rows=_rows: _curve(tmp, rows))


@case("learning curve", "a named pipe", r"learning curve .*curve.csv is not a regular file")
def _(tmp):
    (tmp / "run").mkdir()
    os.mkfifo(tmp / "run" / "curve.csv")
    return ["curves", str(tmp / "run"), "--out", str(tmp / "c.png")]


@case("option", "scripted --loader-settings a named pipe", r"--loader-settings .*s.json is not a regular file")
def _(tmp):
    os.mkfifo(tmp / "s.json")
    return ["scripted", "--loader-settings", str(tmp / "s.json")]


@case("option", "evaluate --loader-settings a device", r"--loader-settings /dev/zero is not a regular file")
def _(tmp):
    return ["evaluate", "--policy", "scripted", "--loader-settings", "/dev/zero"]


@case("option", "loader settings with NaN", r"s.json: not a readable JSON file of loader settings \(NaN is not")
def _(tmp):
    write(tmp / "s.json", '{"dig_depth": NaN}')
    return ["scripted", "--loader-settings", str(tmp / "s.json")]


# -- options that do not apply are refused, not ignored ----------------------------------------------
for _argv, _match in (
    (["simulate", "--tables", "circuit"], r"--tables \(the learned model's tables\) does not apply with --model refer"),
    (["simulate", "--backend", "native"], r"--backend .* does not apply with --model reference"),
    (["simulate", "--model", "reference", "--tables", "paper"], r"--tables .* does not apply with --model reference"),
):
    case("option", "simulate " + " ".join(_argv[1:]), _match)(lambda tmp, argv=_argv: simulate(tmp, LOG, *argv[1:]))

for _argv, _match in (
    (["evaluate", "--model", "reference", "--tables", "circuit"], r"--tables .* does not apply with --model reference"),
    (["evaluate", "--ray="], r"--ray '': give HOST:PORT"),
    (["validate", "--ray", " "], r"--ray '': give HOST:PORT"),
    (["validate", "--ray", "auto", "--workers", "2"], r"--workers does not apply with --ray"),
    (["collect", "--ray", "--workers", "3"], r"--workers does not apply with --ray"),
    (["demo", "--fps", "1e-6"], r"--fps must be a finite number > 0, from 0.1 to 1000 frames/s"),
    (["demo", "--fps", "1e9"], r"--fps must be a finite number > 0, from 0.1 to 1000"),
):
    case("option", " ".join(_argv), _match)(lambda tmp, argv=_argv: argv)


@case("API argument", "ObsNormalizer(clip_obs=-1)", r"'clip_obs' must be > 0, got -1", error=ValueError)
def _(tmp):
    from hexgym.agents.policy_files import ObsNormalizer

    return lambda: ObsNormalizer(clip_obs=-1)


@case("API argument", "ObsNormalizer(epsilon='1')", r"epsilon must be a number, got '1'", error=TypeError)
def _(tmp):
    from hexgym.agents.policy_files import ObsNormalizer

    return lambda: ObsNormalizer(epsilon="1")


@case("API argument", "write_mp4 at 1e-6 frames/s", r"the frame rate must be from 0.1 to 1000", error=ValueError)
def _(tmp):
    from hexgym.machine.render import write_mp4

    return lambda: write_mp4([np.zeros((8, 8, 3), np.uint8)] * 2, tmp / "v.mp4", fps=1e-6)


@case("API argument", "a wrapper registered without a name", r"register_wrapper needs a name", error=TypeError)
def _(tmp):
    from hexgym_lab.agents.hyperparams import register_wrapper

    return lambda: register_wrapper("", print)


# -- errors name their input -----------------------------------------------------------------------
@case("data set", "fit, a data set of one episode", r"boom.npz: 1 episode\(s\); fitting holds out whole episodes")
def _(tmp):
    return [*_dataset(tmp, episode=np.zeros(5, np.int64)), "--tables", "paper"]


@case("data set", "tables --bench, a data set of one episode", r"boom.npz: 1 episode\(s\)")
def _(tmp):
    _dataset(tmp, episode=np.zeros(5, np.int64))
    return ["tables", "--bench", str(tmp / "data"), "--tables", "paper"]


@case("policy zip", "a data record nested 200000 deep", r"policy.zip is not a Stable-Baselines3 model zip \(its data "
      "record is nested too deeply")  # fmt: skip
def _(tmp):
    return _evaluate(_rewrite_zip(_policy(tmp), lambda m: m.update(data=b"[" * 200_000 + b"]" * 200_000)))


@case("output path", "fit --out a folder of data sets", r"fitted/boom.npz is a collected data set; this command "
      "writes tables")  # fmt: skip
def _(tmp):
    argv = _dataset(tmp)
    shutil.copytree(tmp / "data", tmp / "fitted")
    return [*argv, "--tables", "paper"]


@case("output path", "collect --out a folder of tables", r"tables/boom.npz is a fitted table; this command writes "
      "data sets")  # fmt: skip
def _(tmp):
    from hexgym.mbl.table import packaged_tables_dir

    shutil.copytree(packaged_tables_dir("paper"), tmp / "tables")
    return ["collect", "--out", str(tmp / "tables"), "--samples", "10", "--workers", "1", "--tables", "paper"]


# -- running the corpus ----------------------------------------------------------------------------
def snapshot(root: Path) -> dict[str, tuple[str, int]]:
    """Every path under ``root``: its content's digest (or kind) and permission bits."""
    out = {}
    for path in sorted(root.rglob("*")):
        info = path.lstat()
        if stat.S_ISLNK(info.st_mode):
            digest = "link:" + os.readlink(path)
        elif path.is_dir():
            digest = "dir"
        elif not stat.S_ISREG(info.st_mode):  # a named pipe: opening it would wait for a writer
            digest = "special"
        else:
            digest = hashlib.sha256(path.read_bytes()).hexdigest()
        out[str(path.relative_to(root))] = (digest, stat.S_IMODE(info.st_mode))
    return out


def _available(needs: str) -> bool:
    if needs == "native":
        from hexgym.model import plugin

        return plugin.native_available()
    if needs == "view":
        from hexgym_lab.cli import build_parser

        return "view" in build_parser()._subparsers._group_actions[0].choices
    return True


def _restore_permissions(root: Path) -> None:
    for path in [root, *root.rglob("*")]:
        if not path.is_symlink():
            path.chmod(path.stat().st_mode | stat.S_IRWXU)


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    work = tmp_path / "case"
    work.mkdir()
    monkeypatch.chdir(work)  # default outputs (out/, logs/, data/) land where the snapshot sees them
    yield work
    _restore_permissions(tmp_path)


_PROGRESS = re.compile(r"\d+%\|")  # a progress bar's line (collect's tqdm) is not an error line


@pytest.mark.filterwarnings("ignore:Detected pickle protocol")  # torch, refusing a crafted policy.pth
@pytest.mark.parametrize("case", CORPUS, ids=[f"{c.kind}: {c.name}" for c in CORPUS])
def test_bad_input_is_refused_and_nothing_changes(case, workdir, capsys):
    from hexgym_lab import cli

    if case.needs and not _available(case.needs):
        pytest.skip(f"needs {case.needs}")
    action = case.setup(workdir)
    before = snapshot(workdir)
    if isinstance(action, list):
        try:
            code = cli.main(action)
        except SystemExit as exit_:  # argparse's usage errors exit from parse_args
            code = exit_.code
        err = capsys.readouterr().err
        lines = [line for line in err.splitlines() if line.strip() and not _PROGRESS.search(line)]
        assert "Traceback" not in err, err
        assert code == case.exit_code, err
        if case.exit_code == 2:
            assert len(lines) == 1, f"not one line: {err}"
            assert re.match(r"hexgym( \S+)?: error: ", lines[0]), lines[0]
            assert re.search(case.match, lines[0]), lines[0]
    elif case.error is None:
        action()
    else:
        with pytest.raises(case.error, match=case.match):
            action()
    after = snapshot(workdir)
    new = {k: v for k, v in after.items() if k not in before}
    assert {k: after.get(k) for k in before} == before, "an existing file changed"
    assert sorted(new) == sorted(case.creates), f"unexpected new files {sorted(new)}"
    if case.marker:
        assert not (workdir / "MARKER").exists(), "code from a data file ran"


# -- MBL tables: the same damaged files through both loaders ---------------------------------------
def _rewrite_table(
    path: Path, rehash: bool = False, meta: dict | None = None, meta_text: str | None = None, **arrays: Any
) -> None:
    """Rewrite table ``path``: arrays replaced (a value, None to drop it, or a function of the old),
    metadata updated (or replaced by ``meta_text``); with ``rehash`` the content hash is made to fit
    again (a well-formed file)."""
    from hexgym.mbl.table import content_sha256

    with np.load(path, allow_pickle=False) as z:
        content = {k: z[k] for k in z.files}
    info = json.loads(str(content["meta"][0]))
    info.update(meta or {})
    for name, value in arrays.items():
        if value is None:
            content.pop(name, None)
        else:
            content[name] = value(content[name]) if callable(value) else value
    if rehash:
        d = len(info["inputs"])
        hashed = {k: content[k] for k in ("values", "confidence", *(f"axis_{j}" for j in range(d)))}
        info["content_sha256"] = content_sha256(info, hashed)
    content["meta"] = np.array([meta_text if meta_text is not None else json.dumps(info, sort_keys=True)])
    with path.open("wb") as f:
        np.savez_compressed(f, **content)


def _nan_at(index: int) -> Callable[[np.ndarray], np.ndarray]:
    def spoil(a: np.ndarray) -> np.ndarray:
        a = a.copy()
        a.reshape(-1)[index] = np.nan
        return a

    return spoil


def _flip(a: np.ndarray) -> np.ndarray:
    a = a.copy()
    a[[0, 1]] = a[[1, 0]]
    return a


def _object_array(path: Path) -> None:
    with np.load(path, allow_pickle=False) as z:
        content = {k: z[k] for k in z.files}
    content["evil"] = np.array([_Mkdir(path.parent / "MARKER")], dtype=object)
    with path.open("wb") as f:
        np.savez(f, allow_pickle=True, **content)


TABLE_DAMAGE: dict[str, tuple[Callable[[Path], None], str]] = {
    "a value edited": (lambda p: _rewrite_table(p, values=lambda v: v * 1.001), r"content hash mismatch"),
    "metrics edited": (lambda p: _rewrite_table(p, meta={"metrics": {"loo_rmse_rel": 0.0}}), r"content hash mismatch"),
    "parameters edited": (
        lambda p: _rewrite_table(p, meta={"params": {**_meta(p)["params"], "bandwidth": 9.0}}),
        r"content hash mismatch",
    ),
    "the hash edited": (lambda p: _rewrite_table(p, meta={"content_sha256": "0" * 64}), r"content hash mismatch"),
    "no hash": (lambda p: _rewrite_table(p, meta={"content_sha256": 5}), r"metadata lacks .?'?content_sha256"),
    "format version 2": (lambda p: _rewrite_table(p, meta={"format_version": 2}), r"has format version 2"),
    "NaN in values (rehashed)": (lambda p: _rewrite_table(p, True, values=_nan_at(7)), r"'values' holds non-finite"),
    "inf in confidence (rehashed)": (
        lambda p: _rewrite_table(p, True, confidence=lambda c: c * np.inf),
        r"'confidence' holds non-finite",
    ),
    "NaN on an axis (rehashed)": (lambda p: _rewrite_table(p, True, axis_2=_nan_at(1)), r"'axis_2' holds non-finite"),
    "an axis out of order (rehashed)": (lambda p: _rewrite_table(p, True, axis_0=_flip), r"not strictly increasing"),
    "float32 values": (lambda p: _rewrite_table(p, values=lambda v: v.astype(np.float32)), r"dtype <f4, expected <f8"),
    "big-endian values": (lambda p: _rewrite_table(p, values=lambda v: v.astype(">f8")), r"dtype >f8, expected <f8"),
    "an extra integer array": (lambda p: _rewrite_table(p, extra=np.arange(3)), r"dtype <i8, expected <f8"),
    "Fortran-order values (rehashed)": (
        lambda p: _rewrite_table(p, True, values=np.asfortranarray),
        r"not in C order",
    ),
    "confidence missing": (lambda p: _rewrite_table(p, confidence=None), r"'confidence' is missing"),
    "values of the wrong shape": (
        lambda p: _rewrite_table(p, values=lambda v: v[..., :-1].copy()),
        r"'values' has shape",
    ),
    "metadata not JSON": (lambda p: _rewrite_table(p, meta_text="{not json"), r"metadata is not valid JSON"),
    "another table's name (rehashed)": (
        lambda p: _rewrite_table(p, True, meta={"name": "stick"}),
        r"holds table 'stick', expected 'swing'",
    ),
    "inputs reordered (rehashed)": (
        lambda p: _rewrite_table(p, True, meta={"inputs": _meta(p)["inputs"][::-1]}),
        r"inputs",
    ),
    "a negative bandwidth (rehashed)": (
        lambda p: _rewrite_table(p, True, meta={"params": {**_meta(p)["params"], "bandwidth": -1.0}}),
        r"holds an invalid table",
    ),
    "input_scales of another length (rehashed)": (
        lambda p: _rewrite_table(p, True, meta={"params": {**_meta(p)["params"], "input_scales": [1.0]}}),
        r"holds an invalid table",
    ),
    "an unknown parameter (rehashed)": (
        lambda p: _rewrite_table(p, True, meta={"params": {**_meta(p)["params"], "kernel": "box"}}),
        r"holds an invalid table",
    ),
    "a shape of floats (rehashed)": (
        lambda p: _rewrite_table(p, True, meta={"shape": [float(n) for n in _meta(p)["shape"]]}),
        r"shape",
    ),
    "truncated": (lambda p: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2]), r"is corrupt or not a table file"),
    "not a zip": (lambda p: p.write_text("swing table\n"), r"is corrupt or not a table file"),
    "a pickled object inside": (_object_array, r"MBL table file"),
    "missing": (Path.unlink, r"does not exist"),
}


def _meta(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as z:
        return json.loads(str(z["meta"][0]))


def _paper_swing_in_place(path: Path) -> None:
    from hexgym.mbl.table import packaged_tables_dir

    shutil.copyfile(packaged_tables_dir("paper") / "swing.npz", path)


# The circuit set's tables have one input (a spool): the damages to a second input or a 2-D layout become these.
_SEVERAL_INPUTS = ("NaN on an axis (rehashed)", "Fortran-order values (rehashed)", "inputs reordered (rehashed)",
                   "input_scales of another length (rehashed)", "another table's name (rehashed)")  # fmt: skip
CIRCUIT_TABLE_DAMAGE: dict[str, tuple[Callable[[Path], None], str]] = {
    **{name: damage for name, damage in TABLE_DAMAGE.items() if name not in _SEVERAL_INPUTS},
    "NaN on its axis (rehashed)": (lambda p: _rewrite_table(p, True, axis_0=_nan_at(1)), r"'axis_0' holds non-finite"),
    "another input (rehashed)": (
        lambda p: _rewrite_table(p, True, meta={"inputs": ["boom_spool_m"]}),
        r"boom_spool_m.*swing_spool_m|swing_spool_m.*boom_spool_m",
    ),
    "two input_scales (rehashed)": (
        lambda p: _rewrite_table(p, True, meta={"params": {**_meta(p)["params"], "input_scales": [1.0, 1.0]}}),
        r"holds an invalid table",
    ),
    "another table's name (rehashed)": (
        lambda p: _rewrite_table(p, True, meta={"name": "stick_bypass"}),
        r"holds table 'stick_bypass', expected 'swing_bypass'",
    ),
    "a paper table in its place": (_paper_swing_in_place, r"holds table 'swing', expected 'swing_bypass'"),
}
TABLE_SET_DAMAGE = {"paper": ("swing.npz", TABLE_DAMAGE), "circuit": ("swing_bypass.npz", CIRCUIT_TABLE_DAMAGE)}


@pytest.mark.parametrize("backend", ["python", "native"])
@pytest.mark.parametrize(
    ("table_set", "damage"), [(s, d) for s, (_, damages) in TABLE_SET_DAMAGE.items() for d in damages]
)
def test_table_damage_both_backends(table_set, damage, backend, workdir):
    """The same damaged file is refused by the Python loader and by the native plugin, each naming
    the file and the same problem (FileNotFoundError from Python for a missing file, as documented);
    the paper set's four tables and the circuit set's one-input valve tables."""
    from hexgym.mbl.table import TableFileError, load_tables

    if backend == "native" and not _available("native"):
        pytest.skip("native plugin not built")
    directory = _tables(workdir, table_set)
    name, damages = TABLE_SET_DAMAGE[table_set]
    path = directory / name
    spoil, match = damages[damage]
    spoil(path)
    before = snapshot(workdir)
    if backend == "python":
        error = FileNotFoundError if damage == "missing" else TableFileError
        with pytest.raises(error, match=match) as info:
            load_tables(directory, table_set)
    else:
        from hexgym.model.native_backend import load_mbl_model

        with pytest.raises(ValueError, match=match) as info:
            load_mbl_model(directory, table_set=table_set)
    assert f"MBL table file {path}" in str(info.value), str(info.value)
    assert snapshot(workdir) == before
    assert not (directory / "MARKER").exists()


@pytest.mark.parametrize(("table_set", "name"), [("paper", "boom"), ("circuit", "boom_pa")])
def test_both_loaders_agree_on_the_hash_of_unusual_metadata(table_set, name, workdir):
    """The native loader's canonical JSON (Python's json.dumps) on floats, escapes and big integers:
    a table saved by Python with such metadata loads on both backends."""
    from hexgym.mbl.table import load_table, load_tables

    directory = _tables(workdir, table_set)
    path = directory / f"{name}.npz"
    table = load_table(path)
    metrics = {"tiny": 1e-05, "small": 0.0001, "big": 1e16, "almost": 1e15, "neg": -0.0, "third": 1 / 3,
               "int": 12345678901234567890, "text": "tab\tquote\" \u00e9 \U0001f600", "none": None, "flag": True,
               "list": [1.5, -2, 3e-300], "nan": float("nan")}  # fmt: skip
    object.__setattr__(table, "metrics", metrics)
    table.save(path)
    assert load_tables(directory, table_set)[name].metrics["text"] == metrics["text"]
    if _available("native"):
        from hexgym.model.native_backend import load_mbl_model

        load_mbl_model(directory, table_set=table_set)


# -- faults ----------------------------------------------------------------------------------------
FAULTS = ["disk full", "no space (ENOSPC) at the rename", "interrupted", "unexpected error", "--debug", "HEXGYM_DEBUG"]


def test_full_disk_keeps_the_old_file(tmp_path):
    """A write that fails for space (the file size limit, as a full disk fails it) ends as one line,
    exit 2, and leaves the old trajectory as it was and no temporary file behind."""
    rows = "".join(f"{0.1 * k:.1f},{(k % 5) - 2},0,0,0\n" for k in range(1, 30))
    log = write(tmp_path / "log.csv", "t,swing,boom,stick,bucket\n0,0,0,0,0\n" + rows)
    out = write(tmp_path / "traj.csv", "old trajectory\n")
    before = snapshot(tmp_path)

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (4000, 4000))

    argv = ["simulate", "--commands", str(log), "--out", str(out), "--dt-out", "0.05"]
    result = subprocess.run([sys.executable, "-m", "hexgym_lab.cli", *argv], capture_output=True, text=True,
                            preexec_fn=limit, cwd=tmp_path, env={**os.environ, "MUJOCO_GL": "egl"})  # fmt: skip
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2 and len(lines) == 1, result.stderr
    assert lines[0].startswith("hexgym simulate: error: ") and "File too large" in lines[0], lines[0]
    assert snapshot(tmp_path) == before


def test_no_space_at_the_rename_keeps_the_old_file(workdir, capsys, monkeypatch):
    from hexgym import files
    from hexgym_lab import cli

    argv = simulate(workdir)
    write(workdir / "traj.csv", "old trajectory\n")
    before = snapshot(workdir)

    def full(*args: Any) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(args[1]))

    monkeypatch.setattr(files.os, "replace", full)
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "traj.csv: No space left on device" in err, err
    assert snapshot(workdir) == before


def test_interrupt_is_one_line_and_keeps_the_old_file(workdir, capsys, monkeypatch):
    from hexgym.model import replay
    from hexgym_lab import cli

    argv = simulate(workdir)
    write(workdir / "traj.csv", "old trajectory\n")
    before = snapshot(workdir)

    def interrupted(*args: Any, **kwargs: Any) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(replay, "replay", interrupted)
    assert cli.main(argv) == 130
    assert capsys.readouterr().err.strip() == "hexgym simulate: interrupted"
    assert snapshot(workdir) == before


def test_an_unexpected_error_is_one_line_and_debug_shows_the_traceback(workdir, capsys, monkeypatch):
    from hexgym.model import replay
    from hexgym_lab import cli

    argv = simulate(workdir)

    def bug(*args: Any, **kwargs: Any) -> None:
        raise TypeError("unsupported operand")

    monkeypatch.setattr(replay, "replay", bug)
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "error: unexpected TypeError: unsupported operand" in err and "--debug" in err
    with pytest.raises(TypeError):
        cli.main([*argv, "--debug"])
    monkeypatch.undo()
    monkeypatch.setenv("HEXGYM_DEBUG", "1")
    with pytest.raises(ValueError, match="no keyframe"):
        cli.main([*argv, "--start", "nosuch"])


# -- multi-file outputs, full disk, concurrency, Ctrl-C with workers, a Ray address that is no Ray ----------
FAULTS += ["a fit failing on its third table", "Ctrl-C in a staged output", "a private file replaced",
           "a video cut short by a full disk", "two runs into one directory", "Ctrl-C with worker processes",
           "a Ray address that answers but is no Ray"]  # fmt: skip
FAULTS += ["a full disk at demo's picture (the pair kept)", "Ctrl-C at demo's picture (the pair kept)",
           "a JSON output on a full disk", "a full disk in a staged folder", "a pair's second rename failing",
           "Ctrl-C in tune-loader with workers", "Ctrl-C in clone with workers"]  # fmt: skip


def test_a_fit_failing_on_its_third_table_keeps_the_old_set(tmp_path, monkeypatch):
    from hexgym_lab.mbl import fit

    out = tmp_path / "tables"
    for name in ("boom", "bucket", "stick", "swing"):
        write(out / f"{name}.npz", f"old {name}")
    write(out / "notes.txt", "mine")
    before = snapshot(tmp_path)

    class Fitted:
        def __init__(self, name: str) -> None:
            self.name = name

        def save(self, path: Path) -> Path:
            return write(path, f"new {self.name}")

    fitted: list[str] = []

    def fit_table(name: str, *args: Any, **kwargs: Any) -> Fitted:
        fitted.append(name)
        if len(fitted) == 3:
            raise ValueError(f"cannot fit {name}")
        return Fitted(name)

    monkeypatch.setattr(fit, "load_table_data", lambda *a, **k: None)
    monkeypatch.setattr(fit, "fitted_points", lambda data, seed=0: data)
    monkeypatch.setattr(fit, "fit_table", fit_table)
    with pytest.raises(ValueError, match="cannot fit stick"):
        fit.fit_all(tmp_path, out, table_set="paper")
    assert snapshot(tmp_path) == before  # no new table beside old ones, no staging folder left
    fitted.clear()
    monkeypatch.setattr(fit, "fit_table", lambda name, *a, **k: Fitted(name))
    fit.fit_all(tmp_path, out, table_set="paper")
    assert [(out / f"{n}.npz").read_text() for n in ("boom", "swing")] == ["new boom", "new swing"]
    assert (out / "notes.txt").read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == ["tables"]


def test_ctrl_c_in_a_staged_output_keeps_the_old_set_and_permissions(tmp_path):
    from hexgym.files import atomic_path, staged_dir

    out = tmp_path / "report"
    write(out / "summary.json", "old", mode=0o600)
    write(out / "plot.png", "old plot")
    before = snapshot(tmp_path)
    with pytest.raises(KeyboardInterrupt), staged_dir(out) as staging:
        with atomic_path(staging / "plot.png") as tmp:
            tmp.write_text("new plot")
        raise KeyboardInterrupt
    assert snapshot(tmp_path) == before
    with staged_dir(out) as staging, atomic_path(staging / "summary.json") as tmp:
        tmp.write_text("new")
    assert (out / "summary.json").read_text() == "new" and (out / "plot.png").read_text() == "old plot"
    assert stat.S_IMODE((out / "summary.json").stat().st_mode) == 0o600  # a private file stays private


def test_a_replaced_file_keeps_its_permissions(workdir, capsys):
    from hexgym_lab import cli

    argv = simulate(workdir)
    write(workdir / "traj.csv", "old trajectory\n", mode=0o600)
    assert cli.main(argv) == 0, capsys.readouterr().err
    assert stat.S_IMODE((workdir / "traj.csv").stat().st_mode) == 0o600
    assert (workdir / "traj.csv").read_text().startswith("t,")


def test_a_video_cut_short_by_a_full_disk_keeps_the_old_one(tmp_path):
    write(tmp_path / "v.mp4", "the old video")
    code = (
        "import numpy as np, sys\nfrom hexgym.machine.render import write_mp4\n"
        "frames = [np.random.default_rng(i).integers(0, 255, (128, 128, 3), dtype=np.uint8) for i in range(40)]\n"
        "try:\n    write_mp4(frames, sys.argv[1], fps=10)\nexcept OSError as exc:\n    print('refused:', exc)\n"
    )

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))

    result = subprocess.run([sys.executable, "-c", code, str(tmp_path / "v.mp4")], capture_output=True, text=True,
                            preexec_fn=limit, cwd=tmp_path, timeout=60)  # fmt: skip
    assert "refused:" in result.stdout and "could not write it whole" in result.stdout, result.stdout + result.stderr
    assert (tmp_path / "v.mp4").read_text() == "the old video"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.mp4"]


def _no_space(*args: Any, **kwargs: Any) -> None:
    """A write on a full disk: OSError ENOSPC naming no file, as a write to an open file raises it."""
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


@pytest.mark.parametrize("fault", ["full disk", "Ctrl-C"])
def test_demo_replaces_its_video_and_snapshot_as_a_pair(fault, workdir, capsys, monkeypatch):
    """The picture is written after the video: a fault there leaves the old pair, not a new video beside an old
    picture; a full disk is one line naming the picture."""
    import imageio.v3 as iio

    from hexgym_lab import cli

    write(workdir / "out" / "demo.mp4", "the old video")
    write(workdir / "out" / "demo.png", "the old picture")
    before = snapshot(workdir)
    argv = ["demo", "--seconds", "0.5", "--width", "64", "--height", "48"]

    def interrupted(*args: Any, **kwargs: Any) -> None:
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(iio, "imwrite", _no_space if fault == "full disk" else interrupted)
        code = cli.main(argv)
    err = capsys.readouterr().err.strip()
    if fault == "full disk":
        assert code == 2 and err == f"hexgym demo: error: {Path('out') / 'demo.png'}: No space left on device", err
    else:
        assert code == 130 and err == "hexgym demo: interrupted", err
    assert snapshot(workdir) == before  # the old pair, no temporary left
    assert cli.main(argv) == 0
    assert (workdir / "out" / "demo.mp4").read_bytes()[4:8] == b"ftyp"
    assert (workdir / "out" / "demo.png").read_bytes()[1:4] == b"PNG"


def test_a_json_output_on_a_full_disk_is_one_line_naming_it(workdir, capsys, monkeypatch):
    from hexgym_lab import cli

    write(workdir / "runs.json", "the old runs")
    before = snapshot(workdir)
    monkeypatch.setattr(Path, "write_text", _no_space)
    code = cli.main(["scripted", "--seconds", "0.5", "--json", "runs.json"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and lines == ["hexgym scripted: error: runs.json: No space left on device"], lines
    assert snapshot(workdir) == before


def test_a_full_disk_in_a_staged_folder_names_the_output_not_the_staging(tmp_path):
    from hexgym.files import atomic_path, staged_dir

    out = tmp_path / "tables"
    write(out / "boom.npz", "old")
    before = snapshot(tmp_path)
    with pytest.raises(OSError) as raised, staged_dir(out) as staging, atomic_path(staging / "boom.npz"):
        _no_space()
    assert raised.value.errno == errno.ENOSPC and raised.value.filename == str(out / "boom.npz")
    assert snapshot(tmp_path) == before


def test_a_pair_whose_second_rename_fails_says_the_set_is_mixed(tmp_path, monkeypatch):
    from hexgym import files

    write(tmp_path / "a.mp4", "old video")
    write(tmp_path / "a.png", "old picture")
    renames = []
    replace = os.replace

    def second_fails(source: Any, target: Any) -> None:
        renames.append(target)
        if len(renames) == 2:
            raise OSError(errno.EIO, os.strerror(errno.EIO), str(source))
        replace(source, target)

    monkeypatch.setattr(files.os, "replace", second_fails)
    with pytest.raises(OSError, match=r"a\.mp4 already replaced, the rest not: a mixed set") as raised:
        with files.atomic_paths(tmp_path / "a.mp4", tmp_path / "a.png") as (video, picture):
            video.write_text("new video")
            picture.write_text("new picture")
    assert raised.value.filename == str(tmp_path / "a.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mp4", "a.png"]  # no temporary left


def test_two_runs_into_one_directory_are_refused(workdir, capsys):
    from hexgym.files import run_lock
    from hexgym_lab import cli

    write(workdir / "h.yml", TINY_YAML)
    with run_lock(workdir / "logs" / "ppo_HexLoading-v0"):
        before = snapshot(workdir)
        code = cli.main(["train", "--hyperparams", str(workdir / "h.yml"), "-f", str(workdir / "logs"),
                         "--n-envs", "1", "--no-progress"])  # fmt: skip
        err = capsys.readouterr().err.strip()
        assert code == 2 and err.count("\n") == 0 and "is in use by another run" in err, err
        assert snapshot(workdir) == before


_POOL_SCRIPT = """
import sys, time
from hexgym.parallel import LocalPool
try:
    with LocalPool(2) as pool:
        print("started", flush=True)
        list(pool.map_unordered(time.sleep, [60, 60, 60]))
except KeyboardInterrupt:
    print("interrupted", flush=True)
    sys.exit(130)
"""


def _interrupt_pool(cwd: Path, delay_s: float) -> tuple[int, str, str, float]:
    """Run :data:`_POOL_SCRIPT` in its own process group and press Ctrl-C (SIGINT to the group, as a terminal
    does) ``delay_s`` after its pool starts; returns (exit status, stdout, stderr, seconds from Ctrl-C to exit)."""
    import time

    process = subprocess.Popen([sys.executable, "-c", _POOL_SCRIPT], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, start_new_session=True, cwd=cwd)  # fmt: skip
    assert process.stdout.readline().strip() == "started"
    time.sleep(delay_s)
    start = time.monotonic()
    os.killpg(process.pid, signal.SIGINT)
    try:
        out, err = process.communicate(timeout=15)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    return process.returncode, out, err, time.monotonic() - start


def test_ctrl_c_ends_worker_processes_at_once_without_tracebacks(tmp_path):
    """Ctrl-C reaches every process of the command (the terminal signals its process group): the workers
    leave it to the parent, which stops them and ends at once, without a traceback from any of them."""
    code, out, err, seconds = _interrupt_pool(tmp_path, 2.5)  # the workers have started and sleep in their tasks
    assert code == 130 and "interrupted" in out, (out, err)
    assert seconds < 5 and "Traceback" not in err, err


@pytest.mark.parametrize("delay_s", [0.05, 0.3, 0.8])
def test_ctrl_c_while_the_workers_start_ends_without_tracebacks(tmp_path, delay_s):
    """A Ctrl-C while the pool's fresh interpreters are still starting (before they could ignore it) is held back
    from them: the parent alone ends, in one line."""
    code, out, err, _ = _interrupt_pool(tmp_path, delay_s)
    assert code == 130 and "interrupted" in out, (out, err)
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err


def _busy_workers(parent: int, n: int) -> bool:
    """Whether ``parent`` has ``n`` pool workers that have loaded MuJoCo (past their start: running a task)."""
    found = 0
    for entry in Path("/proc").iterdir():
        try:
            if not entry.name.isdigit() or int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1]) != parent:
                continue
            if b"spawn_main" in (entry / "cmdline").read_bytes() and "mujoco" in (entry / "maps").read_text():
                found += 1
        except (OSError, IndexError, ValueError):
            continue
    return found >= n


def _interrupt_command(argv: list[str], cwd: Path, workers: int = 2) -> tuple[int, str, float]:
    """Run ``hexgym argv`` in its own process group, press Ctrl-C (SIGINT to the group, as a terminal does) once
    ``workers`` pool workers run their episodes; returns (exit status, stderr, seconds from Ctrl-C to exit)."""
    import time

    code = "import sys\nfrom hexgym_lab.cli import main\nsys.exit(main(sys.argv[1:]))"
    process = subprocess.Popen([sys.executable, "-c", code, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, start_new_session=True, cwd=cwd)  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while not _busy_workers(process.pid, workers):
            assert process.poll() is None and time.monotonic() < deadline, process.communicate()
            time.sleep(0.2)
        time.sleep(1.0)
        start = time.monotonic()
        os.killpg(process.pid, signal.SIGINT)
        _, err = process.communicate(timeout=20)
        return process.returncode, err, time.monotonic() - start
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="finds the workers in /proc")
def test_ctrl_c_ends_tune_loader_and_its_workers_keeping_the_old_settings(tmp_path):
    pytest.importorskip("cmaes")
    write(tmp_path / "best.json", "the old settings")
    argv = ["tune-loader", "--out", "best.json", "--seeds", "100-101", "--generations", "1", "--population", "4"]
    code, err, seconds = _interrupt_command(argv, tmp_path)
    assert code == 130 and err.strip() == "hexgym tune-loader: interrupted", err
    assert seconds < 5, seconds
    # interrupted while scoring the defaults: no generation finished, the old file is kept, nothing beside it
    assert (tmp_path / "best.json").read_text() == "the old settings"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["best.json"]


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="finds the workers in /proc")
def test_ctrl_c_ends_clone_and_its_workers_keeping_the_old_model(tmp_path):
    pytest.importorskip("stable_baselines3")
    write(tmp_path / "h.yml", TINY_YAML.replace("time_limit: 2.0", "time_limit: 120.0"))
    write(tmp_path / "bc.zip", "the old model")
    argv = ["clone", "--out", "bc.zip", "--hyperparams", "h.yml", "--episodes", "2", "--dagger-rounds", "0",
            "--epochs", "1"]  # fmt: skip
    code, err, seconds = _interrupt_command(argv, tmp_path)
    assert code == 130 and err.strip() == "hexgym clone: interrupted", err
    assert seconds < 5, seconds
    assert (tmp_path / "bc.zip").read_text() == "the old model"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bc.zip", "h.yml"]


@pytest.mark.parametrize("reply", [b"HTTP/1.1 400 Bad Request\r\n\r\n", b""], ids=["HTTP", "silent"])
def test_a_ray_address_that_answers_but_is_no_ray_is_refused_in_seconds(reply, monkeypatch):
    import socket
    import threading
    import time

    from hexgym import parallel

    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    held = []

    def serve() -> None:
        connection, _ = server.accept()
        held.append(connection)
        if reply:
            connection.sendall(reply)

    threading.Thread(target=serve, daemon=True).start()
    monkeypatch.setattr(parallel, "CONNECT_TIMEOUT_S", 1.0)
    start = time.monotonic()
    with pytest.raises(parallel.ClusterError, match=rf"127.0.0.1:{port} answers but is no Ray cluster"):
        parallel._check_reachable(f"127.0.0.1:{port}")
    assert time.monotonic() - start < 3
    server.close()
    for connection in held:
        connection.close()


def corpus_counts() -> dict[str, int]:
    """Inputs tried by kind: the corpus, the table damages (each on both loaders) and the faults."""
    counts: dict[str, int] = {}
    for c in CORPUS:
        counts[c.kind] = counts.get(c.kind, 0) + 1
    counts["table"] = counts.get("table", 0) + sum(len(damages) for _, damages in TABLE_SET_DAMAGE.values())
    counts["fault"] = len(FAULTS)
    return counts


if __name__ == "__main__":
    counts = corpus_counts()
    for kind, n in sorted(counts.items()):
        print(f"{kind:12s} {n:4d}")
    print(f"{'total':12s} {sum(counts.values()):4d}")


def test_json_figures_write_numpy_scalars_and_refuse_other_objects_without_touching_the_file(tmp_path):
    """Figures computed with numpy (an int64 count, a float64 time, a bool_) are written as the numbers they hold;
    an object json cannot write leaves the existing file as it was."""
    from hexgym.files import write_json

    out = tmp_path / "figures.json"
    write_json(out, {"count": np.int64(3), "time_s": np.float64(1.5), "ok": np.bool_(True)})
    assert json.loads(out.read_text()) == {"count": 3, "time_s": 1.5, "ok": True}
    with pytest.raises(TypeError, match="not JSON serializable"):
        write_json(out, {"bad": object()})
    assert json.loads(out.read_text())["count"] == 3

"""Replay files: the command log CSV read and checked, the trajectory CSV written and read.

A command log has the header ``t,swing,boom,stick,bucket``: time in s, ascending from 0, and
spool positions in mm (within the ±11 mm stroke), each row held until the next. A log that is
malformed is refused with a ValueError that names the file, the row and the column.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hexgym.checks import parse_float
from hexgym.files import atomic_path, check_input_file
from hexgym.machine import parameters as p
from hexgym.machine.trajectory import current_name, row_dtype

COLUMNS = ("t", "swing", "boom", "stick", "bucket")
SPOOL_LIMIT_MM = p.SPOOL_STROKE * 1e3


@dataclass(frozen=True)
class CommandLog:
    """Spool commands held piecewise constant: ``t`` (n,) in s, ``spools_mm`` (n, 4) in mm."""

    t: np.ndarray
    spools_mm: np.ndarray

    def __post_init__(self) -> None:
        validate_commands(self.t, self.spools_mm)

    def spools_at(self, time: float) -> np.ndarray:
        """The spools (mm, order swing, boom, stick, bucket) in force at ``time`` (s)."""
        i = int(np.searchsorted(self.t, time, side="right")) - 1
        return self.spools_mm[max(i, 0)].copy()

    @property
    def duration(self) -> float:
        """Time of the last row, s."""
        return float(self.t[-1])


MAX_ROWS = 1_000_000  # rows a command log may have (~40 MB of CSV): more is refused before it fills memory
MAX_BYTES = 256 * 2**20  # a command log's file size (a line is read whole: one huge line could fill memory)


def validate_commands(t: np.ndarray, spools_mm: np.ndarray, source: str = "command log") -> None:
    """Raise ValueError naming the row and column of the first problem in a command table."""
    t, u = np.asarray(t, dtype=float), np.asarray(spools_mm, dtype=float)
    if t.ndim != 1 or t.size == 0 or u.shape != (t.size, 4):
        raise ValueError(f"{source}: need n >= 1 times and an (n, 4) spool table, got {t.shape} and {u.shape}")
    for row in range(t.size):
        _check_row(f"{source}: row {row + 1}", t[row], u[row], t[row - 1] if row else None)


def _check_row(where: str, t: float, spools: np.ndarray, previous: float | None) -> None:
    if not math.isfinite(t):
        raise ValueError(f"{where}, column 't': {t} is not a finite time")
    if previous is None and t != 0.0:
        raise ValueError(f"{where}, column 't': the log must start at t = 0, not {t}")
    if previous is not None and t <= previous:
        raise ValueError(f"{where}, column 't': {t} s does not come after {previous} s (times must ascend)")
    for name, value in zip(COLUMNS[1:], spools, strict=True):
        if not math.isfinite(value):
            raise ValueError(f"{where}, column {name!r}: {value} is not a finite spool position")
        if abs(value) > SPOOL_LIMIT_MM:
            raise ValueError(
                f"{where}, column {name!r}: {value} mm is beyond the spool stroke ±{SPOOL_LIMIT_MM:.0f} mm"
            )


def read_command_log(path: str | Path) -> CommandLog:
    """Read and check a command log CSV (header ``t,swing,boom,stick,bucket``, any column order).

    The file must be UTF-8 text (a byte-order mark, as Excel's "CSV UTF-8" writes, is allowed). Blank
    lines are skipped; errors name the row and column (data rows counted from 1, blank lines not
    counted) and, at the end, the file's line. Every problem is a ValueError (FileNotFoundError for a
    missing file) naming the file: a directory, an unreadable or binary file, a header without the
    five columns, a row with more fields than the header or a value missing, a value that is no
    finite number (written as digits, a point and an exponent: ``1_0`` or ``0x1`` is refused, not read),
    times that do not start at 0 or do not ascend, a spool beyond the stroke, more than :data:`MAX_ROWS`
    rows or :data:`MAX_BYTES` bytes.
    """
    path = check_input_file(path, "command log")
    if path.stat().st_size > MAX_BYTES:
        raise ValueError(f"{path}: {path.stat().st_size} bytes; a command log may have at most {MAX_BYTES} bytes")
    t: list[float] = []
    spools: list[list[float]] = []
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            reader = csv.reader(f)
            header = [h.strip() for h in next(reader, [])]
            if any("\x00" in h for h in header):
                raise ValueError(f"{path}: line 1 holds a NUL byte: not a text file")
            index = _column_index(path, header)
            for fields in reader:
                if any("\x00" in x for x in fields):
                    raise ValueError(f"{path}: line {reader.line_num} holds a NUL byte: not a text file")
                if not fields or all(not x.strip() for x in fields):
                    continue  # blank line
                if len(t) >= MAX_ROWS:
                    raise ValueError(f"{path}: more than {MAX_ROWS} rows; split the log")
                where, line = f"{path}: row {len(t) + 1}", f" (line {reader.line_num})"
                if len(fields) > len(header):
                    raise ValueError(f"{where}: {len(fields)} fields, the header has {len(header)}{line}")
                try:
                    values = [_number(where, name, fields, i) for name, i in index.items()]
                    _check_row(where, values[0], np.array(values[1:]), t[-1] if t else None)
                except ValueError as exc:
                    raise ValueError(f"{exc}{line}") from None
                t.append(values[0])
                spools.append(values[1:])
    except UnicodeDecodeError as exc:
        raise ValueError(
            f"{path}: not a UTF-8 text file (byte 0x{exc.object[exc.start]:02x} at offset {exc.start}); "
            f"a command log is a CSV file with the header {','.join(COLUMNS)}"
        ) from None
    except csv.Error as exc:
        raise ValueError(f"{path}: not a readable CSV file ({exc})") from None
    except OSError as exc:
        raise ValueError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if not t:
        raise ValueError(f"{path}: the command log has a header but no rows")
    return CommandLog(np.array(t), np.array(spools))


def _column_index(path: Path, header: list[str]) -> dict[str, int]:
    if not header or header == [""]:
        raise ValueError(f"{path}: empty file; expected the header {','.join(COLUMNS)}")
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise ValueError(
            f"{path}: missing column(s) {', '.join(missing)} in the header {','.join(header)[:80]!r}; "
            f"expected {','.join(COLUMNS)}"
        )
    extra = [h for h in header if h not in COLUMNS]
    if extra or len(header) != len(COLUMNS):
        raise ValueError(f"{path}: unexpected or repeated column(s) {extra or header}; expected {','.join(COLUMNS)}")
    return {c: header.index(c) for c in COLUMNS}


def _number(where: str, name: str, fields: list[str], i: int) -> float:
    if i >= len(fields) or not fields[i].strip():
        raise ValueError(f"{where}, column {name!r}: value missing")
    return parse_float(fields[i], f"{where}, column {name!r}", finite=False)  # NaN, inf: refused by the row check


def write_command_log(path: str | Path, log: CommandLog) -> None:
    """Write a command log CSV atomically."""
    rows = np.column_stack([log.t, log.spools_mm])
    _write_csv_atomic(Path(path), COLUMNS, rows)


def write_trajectory_csv(path: str | Path, trajectory: np.ndarray) -> None:
    """Write a structured trajectory array (fields = columns) as CSV, atomically.

    The file appears complete or not at all: it is written next to its destination under a
    temporary name, then renamed over it.
    """
    names = trajectory.dtype.names
    if not names:
        raise ValueError("trajectory must be a structured array with named fields")
    rows = np.column_stack([trajectory[n] for n in names]) if len(trajectory) else np.empty((0, len(names)))
    _write_csv_atomic(Path(path), names, rows)


def read_trajectory_csv(path: str | Path) -> np.ndarray:
    """A trajectory CSV (:func:`write_trajectory_csv`'s, or one of any model's) as a structured array of its columns
    (float64), under their current names: a file with the names before the format (``q_swing``, ``tip_x``...,
    :data:`hexgym.machine.trajectory.OLD_NAMES`) reads as one with the names now; either name indexes the rows."""
    path = check_input_file(path, "trajectory")
    with path.open(newline="") as f:
        reader = csv.reader(f)
        header = [current_name(name.strip()) for name in next(reader, [])]
        if not header or header == [""]:
            raise ValueError(f"{path}: empty file; expected a trajectory's header (t, q_swing_rad, ...)")
        if len(set(header)) != len(header):
            raise ValueError(f"{path}: repeated column(s) in the header {','.join(header)[:80]!r}")
        rows = []
        for number, fields in enumerate(reader, start=2):
            if len(fields) != len(header):
                raise ValueError(f"{path}, row {number}: {len(fields)} values for {len(header)} columns")
            rows.append(
                tuple(
                    parse_float(v, f"{path}, row {number}, column {n!r}", finite=False)
                    for n, v in zip(header, fields, strict=True)
                )
            )
    return np.array(rows, dtype=row_dtype(header))


def _write_csv_atomic(path: Path, header: tuple[str, ...], rows: np.ndarray) -> None:
    with atomic_path(path) as tmp, tmp.open("w", newline="") as f:
        f.write(",".join(header) + "\n")
        for row in rows:
            f.write(",".join(f"{v:.9g}" for v in row) + "\n")

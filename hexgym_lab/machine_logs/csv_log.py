"""Machine logs as CSV: a header of signal names (:mod:`.signals`), a row per sample, an empty cell for a sample
a sensor did not give (read as NaN). Columns the format does not name are ignored (:attr:`CsvLog.ignored` lists
them); the trajectory format's old names (``q_swing``) read as the current ones, so a trajectory is a log too."""

from __future__ import annotations

import csv
import io
import re
import warnings
from pathlib import Path

import numpy as np

from hexgym.files import atomic_path, check_input_file
from hexgym.machine.trajectory import current_name
from hexgym_lab.machine_logs.signals import SIGNALS, TIME, MachineLog

MAX_BYTES = 1 << 30  # a CSV log's size: 8 h at 200 Hz with every signal is about 1 GiB of text


def read_csv_log(path: str | Path) -> MachineLog:
    """A CSV machine log; ValueError naming the file (and the row and column) of what cannot be read."""
    path = check_input_file(path, "machine log")
    if path.stat().st_size > MAX_BYTES:
        raise ValueError(f"{path}: {path.stat().st_size} bytes; a CSV log may have at most {MAX_BYTES} (split it)")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not a UTF-8 text file (byte at offset {exc.start}); a CSV log is text") from None
    head, _, body = text.partition("\n")
    header = [current_name(h.strip()) for h in head.strip("\r").split(",")]
    columns = _columns(path, header)
    values = _fast_numbers(body, header, columns)
    if values is None:  # something the fast reader cannot take: read it cell by cell, naming the first bad one
        values = _numbers(path, header, _rows(path, body), columns)
    signals = {name: values[:, k] for k, name in enumerate(columns) if name != TIME}
    ignored = tuple(h for h in header if h not in columns)
    return MachineLog(str(path), values[:, list(columns).index(TIME)], signals, ignored=ignored)


_EMPTY_CELL = re.compile(r"(?<=,)(?=,|\r?$)|^(?=,)", re.MULTILINE)


def _fast_numbers(body: str, header: list[str], columns: dict[str, int]) -> np.ndarray | None:
    """The known columns' values by numpy's C reader (empty cells as NaN), or None where it cannot read them."""
    if ",," in body or "\n," in body or ",\n" in body or body.startswith(",") or body.rstrip().endswith(","):
        body = _EMPTY_CELL.sub("nan", body)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # an empty input warns: let the careful reader say so
            values = np.loadtxt(io.StringIO(body), delimiter=",", usecols=list(columns.values()), ndmin=2)
    except (ValueError, UserWarning):
        return None
    width = body.partition("\n")[0].count(",") + 1
    return values if len(values) and width == len(header) else None


def _rows(path: Path, body: str) -> list[list[str]]:
    try:
        return [r for r in csv.reader(io.StringIO(body)) if r and any(x.strip() for x in r)]
    except csv.Error as exc:
        raise ValueError(f"{path}: not a readable CSV file ({exc})") from None


def _columns(path: Path, header: list[str]) -> dict[str, int]:
    if not header or header == [""]:
        raise ValueError(f"{path}: empty file; a machine log's header starts with {TIME!r}")
    repeated = sorted({h for h in header if header.count(h) > 1})
    if repeated:
        raise ValueError(f"{path}: column {repeated[0]!r} appears more than once in the header")
    if TIME not in header:
        raise ValueError(f"{path}: no time column {TIME!r} in the header {','.join(header)[:80]!r}")
    return {h: i for i, h in enumerate(header) if h in SIGNALS}


def _numbers(path: Path, header: list[str], rows: list[list[str]], columns: dict[str, int]) -> np.ndarray:
    """The rows' values in the known columns as floats (an empty cell: NaN); ValueError naming a bad cell."""
    if not rows:
        raise ValueError(f"{path}: the log has a header but no rows")
    short = next((i for i, r in enumerate(rows) if len(r) != len(header)), None)
    if short is not None:
        raise ValueError(f"{path}: row {short + 1}: {len(rows[short])} values for {len(header)} columns")
    index = list(columns.values())
    cells = np.array(rows, dtype=object)[:, index].astype(str)
    cells = np.char.strip(cells)
    cells[cells == ""] = "nan"
    try:
        return cells.astype(float)
    except ValueError:
        for r, row in enumerate(cells):
            for c, cell in zip(columns, row, strict=True):
                try:
                    float(cell)
                except ValueError:
                    raise ValueError(f"{path}: row {r + 1}, column {c!r}: {cell[:30]!r} is not a number") from None
        raise


def write_csv_log(path: str | Path, t: np.ndarray, signals: dict[str, np.ndarray]) -> Path:
    """Write a machine log as CSV, atomically: ``t`` first, then the signals in the format's order (NaN: ``nan``)."""
    names = [n for n in SIGNALS if n in signals]
    table = np.column_stack([t, *(signals[n] for n in names)])
    with atomic_path(path) as tmp:
        np.savetxt(tmp, table, fmt="%.9g", delimiter=",", header=",".join([TIME, *names]), comments="")
    return Path(path)

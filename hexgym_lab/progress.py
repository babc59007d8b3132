"""Progress of the lab's long work, one style for every command, and the lines that say where outputs went.

Everything here writes to standard error, never standard output, so a JSON document or CSV a command prints stays
whole. How progress shows (:func:`mode`):

- ``bar``: a tqdm bar with the count, rate and time left, when standard error is a terminal at least
  :data:`MIN_BAR_COLUMNS` wide (and tqdm is installed);
- ``lines``: one plain line per item (at most one every :data:`LINE_INTERVAL_S` seconds, and the last), when the
  terminal is narrower or of unknown size, a ``dumb`` terminal, or tqdm is missing;
- ``off``: nothing, with ``--quiet`` (:func:`configure`) or when standard error is not a terminal (a pipe, a log).

``HEXGYM_PROGRESS=bar|lines|off`` chooses the mode whatever the terminal (``lines`` for a log file); ``--quiet``
still silences it. The lines
that say where a command's outputs went (:func:`wrote`) are printed in every mode.
"""

from __future__ import annotations

import importlib.util
import os
import sys
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from types import TracebackType
from typing import Any, TypeVar

MODES = ("bar", "lines", "off")
MIN_BAR_COLUMNS = 60  # narrower, a bar with its rate and time left would wrap: lines instead
LINE_INTERVAL_S = 5.0  # the most often a line is printed in lines mode (items, frames, steps)
ENV_VAR = "HEXGYM_PROGRESS"

_quiet = False
T = TypeVar("T")


def configure(quiet: bool = False) -> None:
    """Set by the command line: ``quiet`` turns progress off (``--quiet``)."""
    global _quiet
    _quiet = bool(quiet)


def mode() -> str:
    """How progress shows now: "bar", "lines" or "off" (the module's docstring)."""
    chosen = os.environ.get(ENV_VAR, "").strip().lower()
    if chosen and chosen not in MODES:
        raise ValueError(f"{ENV_VAR}={chosen!r}: give one of {', '.join(MODES)}")
    if _quiet:
        return "off"
    if chosen:
        return "lines" if chosen == "bar" and not _have_tqdm() else chosen
    if not _stderr_is_terminal():
        return "off"
    columns, rows = _terminal_size()  # a terminal of unknown height: tqdm would draw nothing
    if os.environ.get("TERM") == "dumb" or columns < MIN_BAR_COLUMNS or rows < 1 or not _have_tqdm():
        return "lines"
    return "bar"


def _stderr_is_terminal() -> bool:
    try:
        return sys.stderr is not None and sys.stderr.isatty()
    except (AttributeError, ValueError):  # closed or replaced by an object without isatty
        return False


def _terminal_size() -> tuple[int, int]:
    """Standard error's terminal columns (``COLUMNS`` where it is a number) and rows; 0 where unknown."""
    try:
        columns, rows = os.get_terminal_size(sys.stderr.fileno())
    except (OSError, AttributeError, ValueError):
        columns, rows = 0, 0
    given = os.environ.get("COLUMNS", "")
    return (int(given) if given.isdigit() and int(given) > 0 else columns), rows


def _have_tqdm() -> bool:
    return importlib.util.find_spec("tqdm") is not None


def _clock(seconds: float) -> str:
    """Seconds as m:ss or h:mm:ss."""
    seconds = int(round(max(seconds, 0.0)))
    hours, rest = divmod(seconds, 3600)
    return f"{hours}:{rest // 60:02d}:{rest % 60:02d}" if hours else f"{rest // 60}:{rest % 60:02d}"


def _number(value: float) -> str:
    return f"{value:,.0f}" if float(value).is_integer() or abs(value) >= 100 else f"{value:.3g}"


class Progress:
    """Progress of one piece of work of ``total`` ``unit``s (None: unknown), named ``desc``.

    Use as a context manager; :meth:`update` after each item (or :meth:`set` a count), with named figures to
    show beside it; :meth:`note` prints a line above the bar (shown in bar and lines mode). ``initial``: the
    count it starts from (a resumed run); ``count=False``: no count is shown, only the notes.
    """

    def __init__(self, total: float | None, desc: str, unit: str = "item", initial: float = 0,
                 count: bool = True) -> None:  # fmt: skip
        self.total, self.desc, self.unit = total, desc, unit
        self.n: float = initial
        self.mode = mode()
        self._count = count and self.mode != "off"
        self._postfix: dict[str, Any] = {}
        self._start = self._last_line = time.perf_counter()
        self._initial = self._printed = initial  # the count it started from; the count the last line showed
        self._bar: Any = None
        if self.mode == "bar" and count:
            from tqdm import tqdm

            self._bar = tqdm(total=total, desc=desc, unit=unit, initial=initial, file=sys.stderr, dynamic_ncols=True,
                             smoothing=0.1, leave=True)  # fmt: skip

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        self.close(finished=kind is None)

    def update(self, n: float = 1, **figures: Any) -> None:
        """``n`` more done; ``figures`` shown beside the count (name=value)."""
        self.set(self.n + n, **figures)

    def set(self, n: float, **figures: Any) -> None:
        """``n`` done in all."""
        self._postfix.update(figures)
        step, self.n = n - self.n, n
        if self._bar is not None:
            if self._postfix:
                self._bar.set_postfix(self._postfix, refresh=False)
            self._bar.update(step)
        elif self.mode == "lines" and self._count:
            now = time.perf_counter()
            if now - self._last_line >= LINE_INTERVAL_S or (self.total is not None and n >= self.total):
                self._last_line = now
                self._line()

    def note(self, text: str) -> None:
        """A line of its own (above the bar), unless progress is off."""
        if self._bar is not None:
            self._bar.write(text, file=sys.stderr)
        elif self.mode != "off":
            print(text, file=sys.stderr, flush=True)

    def close(self, finished: bool = True) -> None:
        """End the bar (in lines mode: a last line when the count moved since the last one)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        elif self.mode == "lines" and self._count and finished and self.n != self._printed:
            self._line()
        self.mode = "off"

    def text(self) -> str:
        """The line lines mode prints: ``desc: n/total unit (pct), rate, time left | figures``."""
        elapsed = time.perf_counter() - self._start
        rate = (self.n - self._initial) / elapsed if elapsed > 0 else 0.0
        count = f"{_number(self.n)}/{_number(self.total)}" if self.total else _number(self.n)
        parts = [f"{self.desc}: {count} {self.unit if self.unit.endswith('s') else self.unit + 's'}"]
        if self.total:
            parts[0] += f" ({100.0 * self.n / self.total:.0f} %)"
        parts.append(f"{_number(rate)} {self.unit}/s, {_clock(elapsed)} elapsed")
        if self.total and rate > 0 and self.n < self.total:
            parts.append(f"{_clock((self.total - self.n) / rate)} left")
        line = ", ".join(parts)
        if self._postfix:
            line += " | " + ", ".join(f"{k} {v}" for k, v in self._postfix.items())
        return line

    def _line(self) -> None:
        self._printed = self.n
        print(self.text(), file=sys.stderr, flush=True)


def track(items: Iterable[T], desc: str, unit: str = "item", total: int | None = None) -> Iterator[T]:
    """``items``, one at a time, counted in a :class:`Progress` (total: ``len(items)`` where it has one)."""
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    with Progress(total, desc, unit) as progress:
        for item in items:
            yield item
            progress.update()


class CountingList(list):
    """A list that counts each item appended to it in ``progress`` (frames, as a film is rendered)."""

    def __init__(self, progress: Progress) -> None:
        super().__init__()
        self._progress = progress

    def append(self, item: Any) -> None:
        """Append ``item`` and count it."""
        super().append(item)
        self._progress.update()


def wrote(path: str | os.PathLike[str], what: str = "") -> Path:
    """Say where an output went: ``wrote PATH (what)`` on standard error, in every mode; returns the path."""
    path = Path(path)
    print(f"wrote {path}" + (f" ({what})" if what else ""), file=sys.stderr, flush=True)
    return path

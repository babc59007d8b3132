"""Checks of a user's numbers (seeds, counts, durations), shared by the Python API and the command line.

Each raises ValueError naming the argument, the value and what it must be, so that a bad value is
refused where it enters, before any work, with the same words from Python and from ``hexgym``.
"""

from __future__ import annotations

import math
import numbers
import os
import re
from collections.abc import Iterable
from typing import Any

MAX_SEED = 2**63 - 1  # numpy's and gymnasium's seeds are non-negative integers


def _real(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def check_seed(name: str, value: Any) -> int:
    """A seed: a whole number from 0 to 2**63 - 1."""
    if not _real(value) or not math.isfinite(value) or int(value) != value or not 0 <= value <= MAX_SEED:
        raise ValueError(f"{name} must be a whole number from 0 to 2**63 - 1, got {value!r}")
    return int(value)


def check_count(name: str, value: Any, minimum: int = 1) -> int:
    """A whole number >= ``minimum``."""
    if not _real(value) or not math.isfinite(value) or int(value) != value or value < minimum:
        raise ValueError(f"{name} must be a whole number >= {minimum}, got {value!r}")
    return int(value)


def check_positive(name: str, value: Any, unit: str = "") -> float:
    """A finite number > 0."""
    if not _real(value) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a finite number > 0{' ' + unit if unit else ''}, got {value!r}")
    return float(value)


def check_choice(name: str, value: Any, choices: Iterable[str]) -> str:
    """One of the names ``choices``: ValueError naming the argument for anything else (a list included)."""
    choices = tuple(choices)
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"{name} must be one of {choices}, got {value!r}")
    return value


def check_path_type(name: str, value: Any) -> str | os.PathLike[str]:
    """A path given as text or an ``os.PathLike``: TypeError naming the argument otherwise."""
    if not isinstance(value, str | os.PathLike):
        raise TypeError(f"{name} must be a path (str or os.PathLike), got {type(value).__name__} {value!r:.60}")
    return value


def check_range(name: str, value: Any, lo: float, hi: float, unit: str = "") -> float:
    """A finite number in [lo, hi]."""
    if not _real(value) or not math.isfinite(value) or not lo <= value <= hi:
        raise ValueError(f"{name} must be a finite number from {lo:g} to {hi:g}{' ' + unit if unit else ''}, "
                         f"got {value!r}")  # fmt: skip
    return float(value)


# Numbers as a data file writes them: ASCII digits, an optional point and exponent. Python's float() and
# int() also take '1_0' (10), ' 1 ', Unicode digits, 'nan' and 'infinity'; a data file holding those was
# not written as a number and is refused, not read as something else.
_DECIMAL = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_WHOLE = re.compile(r"[+-]?[0-9]+")
_NUMBER_RULE = "digits, a point and an exponent only: no underscores, hex or words"
MAX_SEEDS = 1_000_000  # seeds a --seeds range may name (each is an episode or a plan)


def parse_float(text: str, what: str = "value", finite: bool = True) -> float:
    """``text`` as a float, written as a data file writes numbers (see above); ValueError naming ``what``.

    ``finite``: refuse NaN and infinity (also an exponent too large for a float); otherwise ``nan``,
    ``inf`` and ``-inf`` (any case) are read too.
    """
    if not isinstance(text, str):
        raise TypeError(f"{what} must be text, got {type(text).__name__}")
    word = text.strip()
    if _DECIMAL.fullmatch(word):
        value = float(word)
        if finite and not math.isfinite(value):
            raise ValueError(f"{what}: {text[:40]!r} is too large for a number")
        return value
    if not finite and word.lower() in ("nan", "inf", "+inf", "-inf"):
        return float(word)
    kind = "a finite number" if finite else "a number"
    raise ValueError(f"{what}: {text[:40]!r} is not {kind} ({_NUMBER_RULE})")


def parse_int(text: str, what: str = "value") -> int:
    """``text`` as a whole number (ASCII digits and a sign only); ValueError naming ``what``."""
    if not isinstance(text, str):
        raise TypeError(f"{what} must be text, got {type(text).__name__}")
    if not _WHOLE.fullmatch(text.strip()) or len(text.strip()) > 30:
        raise ValueError(f"{what}: {text[:40]!r} is not a whole number (digits and a sign only)")
    return int(text.strip())


def parse_seeds(text: str, option: str = "--seeds") -> list[int]:
    """``"A-B"`` (inclusive) or ``"A"`` -> seeds (``--seeds`` of the commands that run many), at most
    :data:`MAX_SEEDS` of them."""
    first, dash, last = text.partition("-")
    if not re.fullmatch(r"[0-9]+", first) or (dash and not re.fullmatch(r"[0-9]+", last)):
        raise ValueError(f"{option} must be A-B (whole numbers, 0 <= A <= B), got {text!r}")
    a, b = int(first), int(last or first)
    if b < a:
        raise ValueError(f"{option} must be A-B with 0 <= A <= B, got {text!r}")
    check_seed(option, b)
    if b - a + 1 > MAX_SEEDS:
        raise ValueError(f"{option} {text}: {b - a + 1} seeds; at most {MAX_SEEDS} may be run at once")
    return list(range(a, b + 1))

"""Checks of a user's numbers (seeds, counts, durations), shared by the Python API and the command line.

Each raises ValueError naming the argument, the value and what it must be, so that a bad value is
refused where it enters, before any work, with the same words from Python and from ``hexgym``.
"""

from __future__ import annotations

import math
import numbers
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


def check_range(name: str, value: Any, lo: float, hi: float, unit: str = "") -> float:
    """A finite number in [lo, hi]."""
    if not _real(value) or not math.isfinite(value) or not lo <= value <= hi:
        raise ValueError(f"{name} must be a finite number from {lo:g} to {hi:g}{' ' + unit if unit else ''}, "
                         f"got {value!r}")  # fmt: skip
    return float(value)


def parse_seeds(text: str) -> list[int]:
    """``"A-B"`` (inclusive) or ``"A"`` -> seeds (``--seeds`` of the commands that run many)."""
    try:
        first, _, last = text.partition("-")
        a, b = int(first), int(last or first)
    except ValueError:
        raise ValueError(f"--seeds must be A-B (integers, A <= B), got {text!r}") from None
    if a < 0 or b < a:
        raise ValueError(f"--seeds must be A-B with 0 <= A <= B, got {text!r}")
    return list(range(a, b + 1))

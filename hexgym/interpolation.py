"""Scalar functions tabulated on an even grid, for lookups in the step loop."""

from __future__ import annotations

import numpy as np


class UniformTable:
    """A function tabulated on an evenly spaced grid, linearly interpolated at one point (clamped at the ends).

    For scalar lookups in the step loop: plain Python, several times faster than ``np.interp`` on one value.
    """

    def __init__(self, start: float, stop: float, values: np.ndarray) -> None:
        values = np.asarray(values, dtype=float)
        if values.ndim != 1 or len(values) < 2 or not stop > start:
            raise ValueError(f"need >= 2 values on an increasing range, got {values.shape} on [{start}, {stop}]")
        self.start, self.stop = float(start), float(stop)
        self.step = (self.stop - self.start) / (len(values) - 1)
        self.values = values.tolist()
        self._array = values  # for :meth:`at`

    def at(self, x: np.ndarray) -> np.ndarray:
        """The interpolated values at the points ``x`` (an array): the arithmetic of ``__call__``, element-wise."""
        u = (np.asarray(x, dtype=float) - self.start) / self.step
        last = len(self._array) - 1
        i = np.minimum(np.maximum(np.floor(u), 0.0), last - 1).astype(np.intp)  # int(u) where 0 < u < last
        lo = self._array[i]
        inner = lo + (self._array[i + 1] - lo) * (u - i)
        return np.where(u <= 0.0, self._array[0], np.where(u >= last, self._array[last], inner))

    def __call__(self, x: float) -> float:
        """The interpolated value at ``x``."""
        u = (x - self.start) / self.step
        last = len(self.values) - 1
        if u <= 0.0:
            return self.values[0]
        if u >= last:
            return self.values[last]
        i = int(u)
        lo = self.values[i]
        return lo + (self.values[i + 1] - lo) * (u - i)

"""The parameters of a locally weighted regression and the checks of its arrays.

Apart from :mod:`hexgym_lab.mbl.lwr` (which fits and predicts) so that a fitted table, which records
the parameters it was built with, loads without the regression's machinery.
"""

# ruff: noqa: N803, N806 - X follows the statistics notation

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

DEFAULT_CUTOFF = 4.0  # kernel widths: neighbours beyond are ignored (truncation of the Gaussian)


def check_finite(name: str, array: np.ndarray) -> None:
    """Raise ValueError naming ``name`` and the first row/column holding NaN or inf."""
    bad = ~np.isfinite(array)
    if not bad.any():
        return
    where = np.argwhere(bad)[0]
    kind = "NaN" if np.isnan(array[tuple(where)]) else "inf"
    if array.ndim == 1:
        raise ValueError(f"{name} contains {kind} at row {where[0]} ({int(bad.sum())} non-finite values)")
    raise ValueError(
        f"{name} contains {kind} at row {where[0]}, column {where[1]} ({int(bad.sum())} non-finite values)"
    )


def as_queries(name: str, X: Any, n_inputs: int | None = None) -> np.ndarray:
    """``X`` as a float64 (n, d) array, checked for shape and finiteness."""
    X = np.asarray(X, dtype=np.float64)
    if X.ndim == 1 and n_inputs is not None and X.shape[0] == n_inputs:
        X = X[None, :]
    if X.ndim != 2:
        raise ValueError(f"{name} must be a 2-D array (points x inputs), got shape {X.shape}")
    if n_inputs is not None and X.shape[1] != n_inputs:
        raise ValueError(f"{name} has {X.shape[1]} columns, expected {n_inputs} inputs")
    check_finite(name, X)
    return X


def as_training_data(X: Any, y: Any) -> tuple[np.ndarray, np.ndarray]:
    """Training inputs and outputs, checked for shapes and finiteness."""
    X = as_queries("X", X)
    y = np.asarray(y, dtype=np.float64)
    if y.ndim != 1 or y.shape[0] != X.shape[0]:
        raise ValueError(f"y must be 1-D with one value per row of X ({X.shape[0]}), got shape {y.shape}")
    check_finite("y", y)
    if X.shape[0] == 0:
        raise ValueError("X and y hold no points")
    return X, y


@dataclass(frozen=True)
class LWRParams:
    """Parameters of a locally weighted linear regression.

    Attributes:
        bandwidth: kernel width ``h`` in scaled input units.
        input_scales: one positive scale per input; inputs are divided by them.
        ridge: dimensionless ridge on the local slopes (not the intercept), relative to ``W h^2``.
        max_neighbours: optional cap: only the k nearest points (scaled distance) enter a fit.
        cutoff: neighbours beyond ``cutoff * bandwidth`` are ignored (truncation of the Gaussian).
    """

    bandwidth: float
    input_scales: tuple[float, ...]
    ridge: float = 1e-6
    max_neighbours: int | None = None
    cutoff: float = DEFAULT_CUTOFF

    def __post_init__(self) -> None:
        scales = tuple(float(s) for s in np.atleast_1d(np.asarray(self.input_scales, dtype=np.float64)))
        object.__setattr__(self, "input_scales", scales)
        object.__setattr__(self, "bandwidth", float(self.bandwidth))
        object.__setattr__(self, "ridge", float(self.ridge))
        object.__setattr__(self, "cutoff", float(self.cutoff))
        if not scales or not all(math.isfinite(s) and s > 0 for s in scales):
            raise ValueError(f"input_scales must be positive and finite, got {scales}")
        if not (math.isfinite(self.bandwidth) and self.bandwidth > 0):
            raise ValueError(f"bandwidth must be positive and finite, got {self.bandwidth}")
        if not (math.isfinite(self.ridge) and self.ridge >= 0):
            raise ValueError(f"ridge must be >= 0 and finite, got {self.ridge}")
        if not (math.isfinite(self.cutoff) and self.cutoff > 0):
            raise ValueError(f"cutoff must be positive and finite, got {self.cutoff}")
        if self.max_neighbours is not None:
            if int(self.max_neighbours) < 1:
                raise ValueError(f"max_neighbours must be >= 1 or None, got {self.max_neighbours}")
            object.__setattr__(self, "max_neighbours", int(self.max_neighbours))

    @property
    def n_inputs(self) -> int:
        """The number of inputs these parameters are for."""
        return len(self.input_scales)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (inverse of :meth:`from_dict`)."""
        d = asdict(self)
        d["input_scales"] = list(self.input_scales)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> LWRParams:
        """Parameters from a dict written by :meth:`to_dict`."""
        return cls(**d)

"""Collision prediction: simulate a spool command on the fast model before it is executed.

The paper's second use of its fast model: "since the dynamics can make the response quite different
from a linear extrapolation", a command is simulated over a horizon and its first contact of bucket or
stick with truck or ground is reported (:func:`predict`).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from hexgym.mbl.schema import DEFAULT_TABLE_SET
from hexgym.planning.rollouts import PAIRS, MachineState, RolloutBatch, RolloutModel


@dataclasses.dataclass(frozen=True)
class Contact:
    """A predicted contact: when (s from now), which (tool, obstacle), where (world m) and how deep (m, > 0)."""

    time_s: float
    bodies: tuple[str, str]
    point: np.ndarray
    depth_m: float


@dataclasses.dataclass(frozen=True)
class Prediction:
    """A predicted motion: per control period ``times_s`` (T,), joint angles ``q`` (T, 4) rad, the teeth ``tip``
    (T, 3) m, the clearances ``clearance_m`` (T, 4) to :data:`hexgym.planning.rollouts.PAIRS` (negative:
    penetration), and the first contact (None: no contact within the horizon)."""

    times_s: np.ndarray
    q: np.ndarray
    tip: np.ndarray
    clearance_m: np.ndarray
    first_contact: Contact | None

    @property
    def min_clearance_m(self) -> float:
        """The least clearance of bucket and stick to truck and ground over the horizon (m; negative = contact)."""
        return float(self.clearance_m.min())


@functools.lru_cache(maxsize=4)
def default_model(table_set: str = DEFAULT_TABLE_SET) -> RolloutModel:
    """A shared one-thread :class:`RolloutModel` per table set (built on first use)."""
    return RolloutModel(table_set=table_set)


def first_contact(batch: RolloutBatch, index: int, model: RolloutModel) -> Contact | None:
    """Rollout ``index``'s first period at which a pair's clearance is negative, as a :class:`Contact` (None: none)."""
    clearance = batch.clearance_m[index]
    periods = np.flatnonzero((clearance < 0.0).any(axis=1))
    if not len(periods):
        return None
    t = int(periods[0])
    pair = int(np.argmin(clearance[t]))
    point, _ = model.closest_point(batch.states[index, t], pair)
    return Contact(float(batch.times_s[t]), PAIRS[pair], point, float(-clearance[t, pair]))


def predict(
    state: MachineState, spools_m: np.ndarray, horizon_s: float, model: RolloutModel | None = None
) -> Prediction:
    """Predict the motion under ``spools_m`` (m: (4,) held, or (T, 4) per 25 ms control period, the last row
    held) from ``state`` over ``horizon_s`` seconds on the native learned model, and its first contact.

    Raises ValueError for a horizon <= 0 or too long for memory, spools of a wrong shape or beyond the
    stroke, and (when ``state`` is made) a state outside the joint ranges.
    """
    model = default_model() if model is None else model
    batch = model.rollout(state, np.asarray(spools_m, float), horizon_s)
    return Prediction(batch.times_s, batch.q[0], batch.tip[0], batch.clearance_m[0], first_contact(batch, 0, model))

"""The planning vocabulary: a :class:`Goal` (``dump``, ``return``, a teeth target), its builders
(:func:`dump_goal`, :func:`return_goal`, :func:`tip_goal`) and the clearance a plan keeps (:func:`margin_for`).

Goals: ``dump``: the mouth's centre over the truck's bed (inside its walls by ``BED_MARGIN_M``), between 0.3 and
2.5 m above the rim, the swing at rest (< 0.1 rad/s): ready to open; ``return`` / ``tip``: the teeth within
``tolerance_m`` of a point (``return``: above the pile's fullest cut at the scripted loader's dig start), the swing
at rest. The planner (:mod:`hexgym.planning.planner`) searches towards them; its check
(:mod:`hexgym.planning.check`) replays plans against them.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import numpy as np

from hexgym.envs.world import Layout, bed_frame, entry_radius
from hexgym.machine import parameters as p
from hexgym.planning.rollouts import MachineState

if TYPE_CHECKING:
    from hexgym.planning.rollouts import RolloutBatch

TASKS = ("dump", "return", "tip")
BED_MARGIN_M = 0.5  # m: the mouth's centre this far inside the bed's walls
DUMP_HEIGHT_M = (0.3, 2.5)  # m above the rim: where the mouth may be to dump
APPROACH_HEIGHT_M = 0.6  # m above the pile's top: the dig start (as the scripted loader's)
REST_RATE = 0.1  # rad/s: the swing slower than this is at rest
# m of clearance a plan keeps from truck and ground, loaded or not: chosen over 0.1 / 0.2 / 0.3 m on the selection
# seeds 20-29 (docs/planning.md); the circuit model follows the reference within centimetres
MARGIN_M = 0.2
MAX_REACH_M = 10.5  # m from the swing axis: beyond the teeth's reach (Cat 325 class: ~10.2 m at full reach)
MAX_HEIGHT_M = 10.0  # m: above the teeth's highest point (~9.5 m)


@dataclasses.dataclass(frozen=True)
class Goal:
    """A planning goal: ``task`` (:data:`TASKS`), ``point`` (world m: the bed's centre at the rim for ``dump``,
    the teeth's target otherwise), ``tolerance_m`` (``return``/``tip``) and the site's ``layout``."""

    task: str
    point: np.ndarray
    layout: Layout
    tolerance_m: float = 0.3

    def __post_init__(self) -> None:
        if self.task not in TASKS:
            raise ValueError(f"goal task must be one of {TASKS}, got {self.task!r}")
        point = np.asarray(self.point, float)
        if point.shape != (3,) or not np.isfinite(point).all():
            raise ValueError(f"goal point must be 3 finite coordinates (m), got {self.point!r}")
        if math.hypot(point[0], point[1]) > MAX_REACH_M or not -1.0 <= point[2] <= MAX_HEIGHT_M:
            raise ValueError(f"goal point {point.round(2).tolist()} is out of the machine's reach")
        if not (math.isfinite(self.tolerance_m) and self.tolerance_m > 0):
            raise ValueError(f"goal tolerance_m must be > 0, got {self.tolerance_m}")
        object.__setattr__(self, "point", point)

    def error_m(self, mouth: np.ndarray, tip: np.ndarray) -> np.ndarray:
        """Distance (m) from the goal region: of the mouth to the dump box, or of the teeth to the point (...,)."""
        return np.linalg.norm(self.miss(mouth, tip), axis=-1)

    def miss(self, mouth: np.ndarray, tip: np.ndarray, inset_m: float = 0.0) -> np.ndarray:
        """(..., 3) world vector from the goal region's nearest point to the mouth (``dump``; zero inside its box,
        shrunk by ``inset_m`` on every side) or to the teeth (the point)."""
        if self.task != "dump":
            return tip - self.point
        lay = self.layout
        c, s = math.cos(lay.truck_yaw), math.sin(lay.truck_yaw)
        along, across = bed_frame(mouth[..., 0], mouth[..., 1], lay.truck_centre[0], lay.truck_centre[1], c, s)
        half_l = p.TRUCK_BED_LENGTH / 2 - BED_MARGIN_M - inset_m
        half_w = p.TRUCK_BED_WIDTH / 2 - BED_MARGIN_M - inset_m
        height = mouth[..., 2] - self.point[2]
        out_along = np.sign(along) * np.maximum(np.abs(along) - half_l, 0.0)
        out_across = np.sign(across) * np.maximum(np.abs(across) - half_w, 0.0)
        low, high = DUMP_HEIGHT_M[0] + inset_m, DUMP_HEIGHT_M[1] - inset_m
        out_up = np.minimum(height - low, 0.0) + np.maximum(height - high, 0.0)
        return np.stack([c * out_along - s * out_across, s * out_along + c * out_across, out_up], axis=-1)

    def reached(self, batch: RolloutBatch) -> np.ndarray:
        """(B, T): at the goal with the swing at rest."""
        at = self.error_m(batch.mouth, batch.tip) <= (0.0 if self.task == "dump" else self.tolerance_m)
        return at & (np.abs(batch.qd[..., 0]) < REST_RATE)


def margin_for(state: MachineState) -> float:
    """The clearance (m) a plan from ``state`` keeps from truck and ground by default: ``MARGIN_M``, loaded or
    not (the rollouts' model shares the pumps as the machine does: a loaded boom rises there as slowly)."""
    return MARGIN_M


def dump_goal(layout: Layout) -> Goal:
    """The mouth over the truck's bed, ready to open."""
    return Goal("dump", np.array([*layout.truck_centre, p.TRUCK_BED_FLOOR_HEIGHT + p.TRUCK_BED_WALL_HEIGHT]), layout)


def return_goal(layout: Layout, cut_direction: float, tolerance_m: float = 0.3) -> Goal:
    """The teeth above the pile's cut at ``cut_direction`` (rad) where the scripted loader starts a dig."""
    radius = entry_radius(layout)
    point = np.array([radius * math.cos(cut_direction), radius * math.sin(cut_direction), 0.0])
    point[2] = layout.pile_height + APPROACH_HEIGHT_M
    return Goal("return", point, layout, tolerance_m)


def tip_goal(point: np.ndarray, layout: Layout, tolerance_m: float = 0.3) -> Goal:
    """The teeth within ``tolerance_m`` of ``point`` (world m)."""
    return Goal("tip", np.asarray(point, float), layout, tolerance_m)

"""Planning and prediction on batched rollouts of the native learned model (the paper's two uses of it).

- :mod:`hexgym.planning.rollouts`: :class:`RolloutModel`, batched ``mujoco.rollout`` runs of the native
  learned model on the loading site (truck, ground) from a :class:`MachineState`, returning the teeth's
  path and the bucket's and stick's clearance to truck and ground (negative = contact).
- :mod:`hexgym.planning.predict`: :func:`predict`, the motion under a spool command and its first
  predicted contact (time, bodies, point, depth); :class:`hexgym.wrappers.CollisionShield` builds on it.
- :mod:`hexgym.planning.goals`: the vocabulary: a :class:`Goal` (``dump``, ``return``, a teeth target), its
  builders and the clearance a plan keeps.
- :mod:`hexgym.planning.planner`: :func:`plan_motion`, time-and-fuel-optimal spool sequences to a
  :class:`Goal` by the cross-entropy method on batched rollouts; :func:`~hexgym.planning.planner.plan_checked`,
  with each plan checked, trimmed and mended on the circuit model in Python (:mod:`hexgym.planning.check`).

Needs the native plugin (``hexgym.mbl``). Imports nothing above the environments' layer.
"""

from hexgym.planning.goals import Goal, dump_goal, return_goal, tip_goal
from hexgym.planning.planner import Plan, plan_motion
from hexgym.planning.predict import Contact, Prediction, predict
from hexgym.planning.rollouts import PAIRS, MachineState, RolloutBatch, RolloutModel

__all__ = [
    "PAIRS", "Contact", "Goal", "MachineState", "Plan", "Prediction", "RolloutBatch", "RolloutModel", "dump_goal",
    "plan_motion", "predict", "return_goal", "tip_goal",
]  # fmt: skip

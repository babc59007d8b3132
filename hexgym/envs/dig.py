"""``HexDig-v0``: fill the bucket from the pile and lift it clear, starting with the open bucket over it.

The second rung of hexgym's tasks for learning, between reaching (``HexReach-v0``) and the whole cycle
(``HexLoading-v0``): the same site, pile, digging forces, machine and observation as ``HexLoading-v0``
(this is that environment with another start, reward and end), so a digging policy learnt here acts on
the loading task's observations.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from hexgym.envs import DIG_ENV_ID
from hexgym.envs.loading import OBSERVATION_NAMES, HexLoadingEnv, _is_number, dig_start_pose
from hexgym.envs.world import Layout, sample_layout
from hexgym.machine import parameters as p

HEAPED_BUCKET_KG = p.BUCKET_HEAPED_CAPACITY * p.MATERIAL_DENSITY
CARRIED_TILT = 0.6  # rad: a mouth this close to facing up holds its load (the material's repose angle: 0.59)
_PAYLOAD, _ABOVE_PILE, _TILT = (OBSERVATION_NAMES.index(n) for n in ("payload", "tip_above_pile", "bucket_tilt"))
DIG_REWARD_TERMS = ("load", "lift", "success", "time", "spill", "contact")


class HexDigEnv(HexLoadingEnv):
    """Dig ``fill_kg`` of material out of the pile and lift it clear, mouth up.

    ## Description
    ``HexLoading-v0``'s site (pile, truck, digging forces, spill) and machine. The episode starts with
    the empty bucket open over the pile's cut entry, teeth down, the arm pointed at the pile; the
    agent must push the teeth in, drag them through the pile while the bucket fills, curl it and lift
    it out. It succeeds when the bucket holds ``fill_kg`` (default 1.5 t, 70 % of the heaped 2.1 t),
    its teeth are ``lift_m`` above the pile's surface below them and its mouth is within 0.6 rad of
    facing up (so it holds what it carries).

    ## Action and Observation Spaces
    As ``HexLoading-v0``'s: four spool fractions held 0.1 s; the 23 observations (joint angles, rates
    and loads, material in the bucket, the teeth relative to pile and truck, the mouth's tilt, ...).

    ## Rewards
    Per step, the sum of the terms below, each in ``info`` as ``reward_<term>``:

    | term | value |
    |------|-------|
    | load | ``load_weight`` × the change of the tonnes in the bucket |
    | lift | ``lift_weight`` × the change of tonnes in the bucket × min(teeth above the pile, ``lift_m``) / ``lift_m`` |
    | success | ``success_reward`` on success |
    | time | −``time_weight`` per step |
    | spill | −``spill_weight`` × tonnes spilled |
    | contact | −``contact_weight`` × kN·s of bucket/stick contact force on ground or truck above 50 kN |

    Why these: ``load`` and ``lift`` are potential-based shaping (an episode's sum is what the bucket
    holds, and how high, at its end), so they guide without rewarding a dig-and-drop loop; the success
    bonus dominates a full episode's sum (~+1.5 from ``load``, ~+1.5 from ``lift``, +5). The contact
    weight is a fifth of ``HexLoading-v0``'s: the pile itself is no contact, only ground and truck
    are, and a stronger penalty taught early policies to keep the bucket up and never dig.

    ## Episode End
    Terminates on success; truncates after ``time_limit`` s (20). ``info["is_success"]`` (SB3's success
    counter) says which.

    ## Arguments
    ``fill_kg`` (1500), ``lift_m`` (0.5), ``load_weight`` (1.0), ``lift_weight`` (1.0), ``success_reward``
    (5.0), ``time_weight`` (0.01), ``spill_weight`` (0.5), ``contact_weight`` (0.002), ``time_limit``
    (20.0); and ``HexLoading-v0``'s ``render_mode``, ``camera``, ``width``, ``height``, ``backend``,
    ``tables``, ``earthwork_periods``, ``model``.
    """

    env_id = DIG_ENV_ID

    def __init__(
        self,
        fill_kg: float = 1500.0,
        lift_m: float = 0.5,
        load_weight: float = 1.0,
        lift_weight: float = 1.0,
        success_reward: float = 5.0,
        time_weight: float = 0.01,
        spill_weight: float = 0.5,
        contact_weight: float = 0.002,
        time_limit: float = 20.0,
        **loading_kwargs: Any,
    ) -> None:
        for name in (
            "dig_start_share",
            "loaded_start_share",
            "delivery_weight",
            "fill_weight",
            "fuel_weight",
            "truck_capacity_kg",
            "reach_weight",
            "carry_weight",
        ):
            if name in loading_kwargs:
                raise TypeError(f"HexDig-v0 has no argument {name!r} (HexLoading-v0's; this task's reward is its own)")
        if not _is_number(fill_kg) or not 0.0 < fill_kg <= HEAPED_BUCKET_KG:
            raise ValueError(
                f"fill_kg must be > 0 and at most the heaped bucket's {HEAPED_BUCKET_KG:.0f} kg, got {fill_kg!r}"
            )
        if not _is_number(lift_m) or not (math.isfinite(lift_m) and lift_m > 0):
            raise ValueError(f"lift_m must be a finite number > 0, got {lift_m!r}")
        self.dig_weights = {
            "load": load_weight, "lift": lift_weight, "success": success_reward, "time": time_weight,
            "spill": spill_weight, "contact": contact_weight,
        }  # fmt: skip
        for name, weight in self.dig_weights.items():
            if not _is_number(weight) or not (math.isfinite(weight) and weight >= 0):
                raise ValueError(f"{name} weight must be a finite number >= 0, got {weight!r}")
        # of the loading task's reward terms only the contacts count (in kN s, read back from its contact term)
        super().__init__(time_limit=time_limit, delivery_weight=0.0, fuel_weight=0.0, spill_weight=0.0,
                         time_weight=0.0, contact_weight=1.0, **loading_kwargs)  # fmt: skip
        self.fill_kg, self.lift_m = float(fill_kg), float(lift_m)
        self._potentials = (0.0, 0.0)  # (tonnes in the bucket, lift potential) after the last step
        self._spilled_kg = 0.0

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """A new site and a start with the open bucket over the pile's cut entry (see the class docstring)."""
        obs, info = super().reset(seed=seed, options=options)
        self._potentials, self._spilled_kg = self._potential(obs), 0.0
        return obs, self._dig_info(dict.fromkeys(DIG_REWARD_TERMS, 0.0), info, False)

    def _draw_start(self, rng: np.random.Generator) -> tuple[Layout, np.ndarray, float]:
        """A site, joint angles with the teeth over its cut's entry, above the pile's top, pointing down, and an
        empty bucket."""
        layout = sample_layout(rng)
        return layout, dig_start_pose(rng, layout), 0.0

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Hold the spools for 0.1 s."""
        obs, _, _, truncated, info = super().step(action)
        load, lift = self._potential(obs)
        success = (info["bucket_kg"] >= self.fill_kg and obs[_ABOVE_PILE] >= self.lift_m
                   and obs[_TILT] <= CARRIED_TILT)  # fmt: skip
        w = self.dig_weights
        terms = {
            "load": w["load"] * (load - self._potentials[0]),
            "lift": w["lift"] * (lift - self._potentials[1]),
            "success": w["success"] if success else 0.0,
            "time": -w["time"],
            "spill": -w["spill"] * (info["spilled_kg"] - self._spilled_kg) / 1000.0,
            "contact": w["contact"] * info["reward_contact"],  # the loading task's contact term: -kN s
        }
        self._potentials, self._spilled_kg = (load, lift), info["spilled_kg"]
        return obs, float(sum(terms.values())), bool(success), bool(truncated and not success), \
            self._dig_info(terms, info, success)  # fmt: skip

    def _potential(self, obs: np.ndarray) -> tuple[float, float]:
        """(tonnes in the bucket, tonnes times the teeth's height above the pile as a fraction of ``lift_m``)."""
        tonnes = float(obs[_PAYLOAD])
        return tonnes, tonnes * min(max(float(obs[_ABOVE_PILE]), 0.0), self.lift_m) / self.lift_m

    def _dig_info(self, terms: dict[str, float], loading_info: dict[str, Any], success: bool) -> dict[str, Any]:
        """The loading task's stores but the truck's (pile, bucket, spilled kg, fuel, time), this task's reward
        terms, ``is_success``."""
        info = {
            key: value for key, value in loading_info.items() if not key.startswith("reward_") and key != "truck_kg"
        }
        info.update({f"reward_{term}": value for term, value in terms.items()})
        info["is_success"] = bool(success)
        return info

"""``HexDig-v0``: fill the bucket from the pile and lift it clear, starting with the open bucket over it.

The second rung of hexgym's tasks for learning, between reaching (``HexReach-v0``) and the whole cycle
(``HexLoading-v0``): a sibling of the loading task over the same site base (:class:`hexgym.envs.base.SiteEnv`:
site, pile, digging forces, machine, observation), with its own start, reward and end, so a digging policy
learnt here acts on the loading task's observations.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from hexgym.envs import DIG_ENV_ID
from hexgym.envs.base import SiteConfig, SiteEnv, SiteRules, is_number
from hexgym.envs.loading import OBSERVATION_NAMES, LoadingConfig, dig_start_pose
from hexgym.envs.task import REWARD_TERMS, SiteStart
from hexgym.envs.world import sample_layout
from hexgym.machine import parameters as p

HEAPED_BUCKET_KG = p.BUCKET_HEAPED_CAPACITY * p.MATERIAL_DENSITY
CARRIED_TILT = 0.6  # rad: a mouth this close to facing up holds its load (the material's repose angle: 0.59)
_PAYLOAD, _ABOVE_PILE, _TILT = (OBSERVATION_NAMES.index(n) for n in ("payload", "tip_above_pile", "bucket_tilt"))
DIG_REWARD_TERMS = ("load", "lift", "success", "time", "spill", "contact")
# of the loading task's reward terms only the contacts count (in kN s, read back from its contact term)
_SITE_WEIGHTS = dict.fromkeys(REWARD_TERMS, 0.0) | {"contact": 1.0}


@dataclass(frozen=True)
class DigConfig(SiteConfig):
    """``HexDig-v0``'s configuration: the site's (:class:`hexgym.envs.base.SiteConfig`, a 20 s episode), the
    success criteria and the reward terms' weights (see :class:`HexDigEnv`'s Arguments). Frozen; checked once
    when made."""

    time_limit: float = 20.0
    fill_kg: float = 1500.0
    lift_m: float = 0.5
    load_weight: float = 1.0
    lift_weight: float = 1.0
    success_reward: float = 5.0
    time_weight: float = 0.01
    spill_weight: float = 0.5
    contact_weight: float = 0.002

    def __post_init__(self) -> None:
        if not is_number(self.fill_kg) or not 0.0 < self.fill_kg <= HEAPED_BUCKET_KG:
            raise ValueError(
                f"fill_kg must be > 0 and at most the heaped bucket's {HEAPED_BUCKET_KG:.0f} kg, got {self.fill_kg!r}"
            )
        if not is_number(self.lift_m) or not (math.isfinite(self.lift_m) and self.lift_m > 0):
            raise ValueError(f"lift_m must be a finite number > 0, got {self.lift_m!r}")
        for term, weight in self.weights.items():
            if not is_number(weight) or not (math.isfinite(weight) and weight >= 0):
                raise ValueError(f"{term} weight must be a finite number >= 0, got {weight!r}")
        self._set("fill_kg", float(self.fill_kg))
        self._set("lift_m", float(self.lift_m))
        super().__post_init__()

    @property
    def weights(self) -> dict[str, float]:
        """The weights of the terms ``load``, ``lift``, ``success``, ``time``, ``spill``, ``contact``."""
        return {
            "load": self.load_weight, "lift": self.lift_weight, "success": self.success_reward,
            "time": self.time_weight, "spill": self.spill_weight, "contact": self.contact_weight,
        }  # fmt: skip

    def site_rules(self) -> SiteRules:
        """The loading task under the dig counts the contacts only (its truck is never filled)."""
        return SiteRules(self.time_limit, p.TRUCK_CAPACITY, _SITE_WEIGHTS)


_LOADING_ONLY = frozenset(f.name for f in dataclasses.fields(LoadingConfig)) - {
    f.name for f in dataclasses.fields(DigConfig)
}


class HexDigEnv(SiteEnv):
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
    Keyword arguments (``gymnasium.make("HexDig-v0", **kwargs)``) or a :class:`DigConfig` with overrides:
    ``fill_kg`` (1500), ``lift_m`` (0.5), ``load_weight`` (1.0), ``lift_weight`` (1.0), ``success_reward``
    (5.0), ``time_weight`` (0.01), ``spill_weight`` (0.5), ``contact_weight`` (0.002), ``time_limit``
    (20.0); and the site's (:class:`hexgym.envs.base.SiteConfig`): ``render_mode``, ``camera``, ``width``,
    ``height``, ``scene_path``, ``backend``, ``tables``, ``earthwork_periods``, ``model``. ``HexLoading-v0``'s
    own (its reward weights, truck capacity, start shares) are refused by name.

    ## Version History
    * v0: the dig from the open bucket over the pile's cut entry to a full bucket lifted clear.
    """

    env_id = DIG_ENV_ID
    config_type = DigConfig
    config: DigConfig

    def __init__(self, config: DigConfig | None = None, **overrides: Any) -> None:
        for name in overrides:
            if name in _LOADING_ONLY:
                raise TypeError(f"HexDig-v0 has no argument {name!r} (HexLoading-v0's; this task's reward is its own)")
        super().__init__(config, **overrides)
        self._potentials = (0.0, 0.0)  # (tonnes in the bucket, lift potential) after the last step
        self._spilled_kg = 0.0

    def draw_start(self, rng: np.random.Generator) -> SiteStart:
        """A site, joint angles with the teeth over its cut's entry, above the pile's top, pointing down, and an
        empty bucket."""
        layout = sample_layout(rng)
        return SiteStart(layout, dig_start_pose(rng, layout), 0.0)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        """A new site and a start with the open bucket over the pile's cut entry (see the class docstring)."""
        obs, info = super().reset(seed=seed, options=options)
        self._potentials, self._spilled_kg = self._potential(obs), 0.0
        return obs, self._dig_info(dict.fromkeys(DIG_REWARD_TERMS, 0.0), info, False)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Hold the spools for 0.1 s."""
        obs, _, _, truncated, info = super().step(action)
        c = self.config
        load, lift = self._potential(obs)
        success = (info["bucket_kg"] >= c.fill_kg and obs[_ABOVE_PILE] >= c.lift_m
                   and obs[_TILT] <= CARRIED_TILT)  # fmt: skip
        terms = {
            "load": c.load_weight * (load - self._potentials[0]),
            "lift": c.lift_weight * (lift - self._potentials[1]),
            "success": c.success_reward if success else 0.0,
            "time": -c.time_weight,
            "spill": -c.spill_weight * (info["spilled_kg"] - self._spilled_kg) / 1000.0,
            "contact": c.contact_weight * info["reward_contact"],  # the loading task's contact term: -kN s
        }
        self._potentials, self._spilled_kg = (load, lift), info["spilled_kg"]
        return obs, float(sum(terms.values())), bool(success), bool(truncated and not success), \
            self._dig_info(terms, info, success)  # fmt: skip

    def _potential(self, obs: np.ndarray) -> tuple[float, float]:
        """(tonnes in the bucket, tonnes times the teeth's height above the pile as a fraction of ``lift_m``)."""
        tonnes, lift_m = float(obs[_PAYLOAD]), self.config.lift_m
        return tonnes, tonnes * min(max(float(obs[_ABOVE_PILE]), 0.0), lift_m) / lift_m

    def _dig_info(self, terms: dict[str, float], loading_info: dict[str, Any], success: bool) -> dict[str, Any]:
        """The loading task's stores but the truck's (pile, bucket, spilled kg, fuel, time), this task's reward
        terms, ``is_success``."""
        info = {
            key: value for key, value in loading_info.items() if not key.startswith("reward_") and key != "truck_kg"
        }
        info.update({f"reward_{term}": value for term, value in terms.items()})
        info["is_success"] = bool(success)
        return info

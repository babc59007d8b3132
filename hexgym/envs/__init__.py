"""hexgym's tasks as Gymnasium environments: ``HexReach-v0`` (:class:`hexgym.envs.reach.HexReachEnv`: the teeth
to a target through the hydraulics), ``HexDig-v0`` (:class:`hexgym.envs.dig.HexDigEnv`: fill the bucket from the
pile and lift it) and the loading task ``HexLoading-v0`` (:class:`hexgym.envs.loading.HexLoadingEnv`;
batched, :class:`hexgym.envs.vector.HexLoadingVectorEnv`). The latter two are siblings over one site base
(:mod:`.base`: site, machine, rendering; a frozen config each), running the task written once over N sites
(:mod:`.task`, compiled by :mod:`.compiled`'s settings) on their machines (:mod:`.sites`: the physics protocol's
kinds), the site's world (:mod:`.world`: pile, truck, layout) and its earthwork (:mod:`.earthwork`: the pile,
digging, resistance, spill).

``import hexgym`` registers them; this package imports MuJoCo and the machine model only when an
environment is made.
"""

from __future__ import annotations

import gymnasium

ENV_ID = "HexLoading-v0"


REACH_ENV_ID = "HexReach-v0"
DIG_ENV_ID = "HexDig-v0"


def register_envs() -> None:
    """Register the environments with Gymnasium (idempotent)."""
    if REACH_ENV_ID not in gymnasium.registry:
        gymnasium.register(id=REACH_ENV_ID, entry_point="hexgym.envs.reach:HexReachEnv")
    if DIG_ENV_ID not in gymnasium.registry:
        gymnasium.register(id=DIG_ENV_ID, entry_point="hexgym.envs.dig:HexDigEnv")
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(
            id=ENV_ID,
            entry_point="hexgym.envs.loading:HexLoadingEnv",
            # gymnasium.make_vec(ENV_ID, num_envs=N): the batched environment (a MuJoCo batch on the native plugin)
            vector_entry_point="hexgym.envs.vector:make_vector_env",
        )

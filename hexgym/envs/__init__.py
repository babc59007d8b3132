"""Gymnasium environments: ``HexLoading-v0`` (:class:`hexgym.envs.loading.HexLoadingEnv`; batched,
:class:`hexgym.envs.vector.HexLoadingVectorEnv`).

``import hexgym`` registers them; this package imports MuJoCo and the machine model only when an
environment is made.
"""

from __future__ import annotations

import gymnasium

ENV_IDS = ("HexLoading-v0",)


def register_envs() -> None:
    """Register the environments with Gymnasium (idempotent)."""
    if "HexLoading-v0" not in gymnasium.registry:
        gymnasium.register(
            id="HexLoading-v0",
            entry_point="hexgym.envs.loading:HexLoadingEnv",
            # gymnasium.make_vec("HexLoading-v0", num_envs=N): the batched environment (needs the native plugin)
            vector_entry_point="hexgym.envs.vector:make_vector_env",
        )

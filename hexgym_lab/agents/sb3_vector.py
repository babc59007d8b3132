"""A Gymnasium vector environment as a Stable-Baselines3 ``VecEnv``: SB3 learns on the batched ``HexLoading-v0``.

``gymnasium.make_vec("HexLoading-v0", num_envs=N)`` steps N sites as one MuJoCo batch in C threads
(:class:`hexgym.envs.vector.HexLoadingVectorEnv`), several times faster per step than N single environments in
subprocesses. SB3 expects another episode convention: an ended episode's site starts its next episode in the
same step, its last observation in ``info["terminal_observation"]``. :class:`SB3VectorEnv` converts: the sites
that ended are reset at once (Gymnasium's ``reset_mask``) and their final observations kept in the infos, so
the vector environment's ``NEXT_STEP`` autoreset step never happens. The infos (Gymnasium: a dict of arrays with
``_key`` masks) become one dict per site, as SB3's own vector environments give them.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn


class SB3VectorEnv(VecEnv):
    """Stable-Baselines3's view of a Gymnasium vector environment that supports ``options={"reset_mask": m}``.

    Args:
        venv: the vector environment (e.g. ``gymnasium.make_vec("HexLoading-v0", num_envs=16)``).
    """

    def __init__(self, venv: Any) -> None:
        if not hasattr(venv, "single_observation_space"):
            raise TypeError(f"SB3VectorEnv wraps a Gymnasium vector environment, got {type(venv).__name__}")
        self.venv = venv
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self._actions: np.ndarray | None = None

    def reset(self) -> np.ndarray:
        """Reset every site (the seed from :meth:`seed`, if one was set since the last reset: site ``i`` gets
        ``seed + i``)."""
        seed = self._seeds[0] if self._seeds and self._seeds[0] is not None else None
        obs, info = self.venv.reset(seed=seed)
        self.reset_infos = site_infos(info, self.num_envs)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        """Hold the actions for the next :meth:`step_wait`."""
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        """Step every site; those whose episode ended start the next one at once (see the module docstring)."""
        if self._actions is None:
            raise RuntimeError("step_wait() without step_async()")
        obs, rewards, terminated, truncated, info = self.venv.step(self._actions)
        self._actions = None
        dones = np.logical_or(terminated, truncated)
        infos = site_infos(info, self.num_envs)
        if dones.any():
            first, start_info = self.venv.reset(options={"reset_mask": dones})
            starts = site_infos(start_info, self.num_envs)
            for i in np.flatnonzero(dones):
                infos[i]["terminal_observation"] = obs[i]
                infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
                self.reset_infos[i] = starts[i]  # where SB3's own vector environments keep a restart's info
            obs = np.where(dones[:, None], first, obs)
        return obs, np.asarray(rewards, np.float32), dones, infos

    def close(self) -> None:
        """Close the vector environment."""
        self.venv.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The vector environment's attribute, once per site asked for (its sites share it)."""
        return [getattr(self.venv, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set an attribute of the vector environment (shared by all its sites)."""
        setattr(self.venv, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        """Call a method of the vector environment once (its sites share it); the result for each site asked for."""
        result = getattr(self.venv, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        """No site is wrapped in a Gymnasium wrapper (the batch has none per site)."""
        return [False for _ in self._get_indices(indices)]

    def _get_indices(self, indices: VecEnvIndices) -> Iterable[int]:
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else indices


def site_infos(info: dict[str, Any], num_envs: int) -> list[dict[str, Any]]:
    """Gymnasium's vector info (arrays, each with a ``_key`` mask) as one dict per site (the masked-in entries)."""
    out: list[dict[str, Any]] = [{} for _ in range(num_envs)]
    for key, values in info.items():
        if key.startswith("_"):
            continue
        mask: Sequence[bool] = info.get(f"_{key}", np.ones(num_envs, bool))
        if isinstance(values, dict):
            nested = site_infos(values, num_envs)
            for i in np.flatnonzero(mask):
                out[i][key] = nested[i]
            continue
        for i in np.flatnonzero(mask):
            out[i][key] = values[i].item() if isinstance(values[i], np.generic) else values[i]
    return out

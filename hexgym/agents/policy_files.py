"""Policy files read without running code from them: the Stable-Baselines3 model zip and its normaliser, and an
RLlib checkpoint's weights.

**Observation normaliser.** A policy trained on normalised observations needs the statistics it was
trained with. Stable-Baselines3 pickles its ``VecNormalize`` wrapper for that, and unpickling a file
can run any code in it, so hexgym saves the statistics as JSON beside the model
(``<stem>_vecnormalize.json``, numbers only; :class:`ObsNormalizer`) and reads them with ``json``.
A policy whose normaliser is missing is refused (run raw, it would act on the wrong inputs); an
old pickled normaliser (``<stem>_vecnormalize.pkl``) is refused with the command that converts it,
``hexgym convert-normalizer``, which reads the pickle with an unpickler that only builds numpy
arrays and records the other objects' fields (:func:`convert_pickled_normalizer`): no class of the
file's choosing is instantiated and no function of its choosing is called.

**What a policy was trained on.** The normaliser file also records the task, the machine model and the
observation layout the policy was trained on (``trained_on``, :class:`TrainedOn`): ``hexgym train`` and
``hexgym clone`` write it, and :func:`hexgym.agents.policies.load_trained` refuses a policy used on another
task, another model or another observation layout in one line. A file without it (an older one, or one
written by hand) is checked by its observation and action shapes alone, without a message.

**Model zip.** ``PPO.load``/``SAC.load`` read the zip's ``data`` (JSON) and its ``*.pth`` tensors.
The tensors are read by ``torch.load(..., weights_only=True)`` (Stable-Baselines3 >= 2.3), which
builds only tensors and plain containers. But ``data`` holds some entries as base64 cloudpickles
(``policy_class``, the spaces, the schedules, the buffer class, ``policy_kwargs`` when it names a
class) and ``load`` unpickles them unless ``custom_objects`` provides a replacement. :func:`load_sb3_model`
provides one for every pickled entry, built from the readable fields Stable-Baselines3 writes
beside each pickle and an allow-list (the MlpPolicy of PPO or SAC, the environment's spaces, constant
or linear schedules, ``torch.nn`` activations), and refuses a file with any other pickled entry:
no pickle from the zip is ever loaded.

**RLlib checkpoint.** ``hexgym train --framework rllib`` writes RLlib checkpoint directories. Of one,
:func:`read_module_weights` reads the RL module's weights alone (numpy arrays through an allow-list unpickler,
or torch's ``weights_only`` loader); its pickled class and constructor arguments are never read.
"""

from __future__ import annotations

import base64
import io
import json
import math
import os
import pickle
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hexgym.files import atomic_path, check_input_file, check_output_file

NORMALIZER_FORMAT = "hexgym.vecnormalize"
NORMALIZER_VERSION = 1
MAX_NORMALIZER_BYTES = 16 * 2**20  # a normaliser of any real policy is a few kB
MAX_DATA_BYTES = 64 * 2**20  # the zip's "data" record (JSON, a few kB in practice)


class PolicyFileError(ValueError):
    """A policy or normaliser file that cannot be used; the message names the file and the problem."""


@dataclass(frozen=True)
class TrainedOn:
    """What a policy was trained on, as its normaliser file records it (the ``trained_on`` object).

    Attributes:
        env_id: the task's Gymnasium id, e.g. ``"HexLoading-v0"``.
        tables: the machine model: the learned model's table set (``"circuit"``, ``"paper"``), ``"model:<name>"``
            for a model directory fitted to a machine's logs (the directory's name), ``"reference"`` for the
            reference model; None: not recorded.
        obs_names: the environment's observation entries by name, in order (a wrapper's additions, such as the
            previous action, not included); None: not recorded (a task without named observations).
    """

    env_id: str
    tables: str | None = None
    obs_names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.env_id, str) or not self.env_id:
            raise ValueError(f"TrainedOn: env_id must be a non-empty string, got {self.env_id!r}")
        if self.tables is not None and (not isinstance(self.tables, str) or not self.tables):
            raise ValueError(f"TrainedOn: tables must be a non-empty string or None, got {self.tables!r}")
        if self.obs_names is not None:
            names = tuple(self.obs_names)
            if not names or not all(isinstance(n, str) and n for n in names):
                raise ValueError("TrainedOn: obs_names must be a non-empty list of non-empty strings")
            object.__setattr__(self, "obs_names", names)

    def to_json(self) -> dict[str, Any]:
        """The ``trained_on`` object of the file (fields not recorded left out)."""
        data: dict[str, Any] = {"env_id": self.env_id}
        if self.tables is not None:
            data["tables"] = self.tables
        if self.obs_names is not None:
            data["obs_names"] = list(self.obs_names)
        return data


# -- names --------------------------------------------------------------------------------------
def _normalizer_name(model_path: str | Path, suffix: str) -> Path:
    model_path = Path(model_path)
    match = re.fullmatch(r"(.*)_(\d+)_steps", model_path.stem)  # CheckpointCallback-style names
    if match:
        return model_path.with_name(f"{match[1]}_vecnormalize_{match[2]}_steps{suffix}")
    return model_path.with_name(f"{model_path.stem}_vecnormalize{suffix}")


def normalizer_path(model_path: str | Path) -> Path:
    """Where the observation normaliser of a saved model lies (``<stem>_vecnormalize.json``, or a checkpoint's)."""
    return _normalizer_name(model_path, ".json")


def pickled_normalizer_path(model_path: str | Path) -> Path:
    """Where an older hexgym (or rl-zoo3) put the pickled VecNormalize (``<stem>_vecnormalize.pkl``)."""
    return _normalizer_name(model_path, ".pkl")


# -- the normaliser -------------------------------------------------------------------------------
@dataclass(frozen=True)
class ObsNormalizer:
    """The statistics of a ``VecNormalize`` (Box observations), as numbers only.

    :meth:`normalize_obs` is ``VecNormalize.normalize_obs`` (the same arithmetic, so the same
    actions to the last bit); :meth:`vec_normalize` rebuilds the wrapper to go on training.
    ``norm_obs`` False: an identity (a policy trained without observation normalisation).
    """

    norm_obs: bool = False
    norm_reward: bool = False
    clip_obs: float = 10.0
    clip_reward: float = 10.0
    gamma: float = 0.99
    epsilon: float = 1e-8
    obs_mean: tuple[float, ...] = ()
    obs_var: tuple[float, ...] = ()
    obs_count: float = 1e-4
    obs_dtype: str = "float64"  # of the statistics (a clone's are float32): the arithmetic follows it
    ret_mean: float = 0.0
    ret_var: float = 1.0
    ret_count: float = 1e-4
    trained_on: TrainedOn | None = None  # what the policy was trained on (None: not recorded)

    def __post_init__(self) -> None:
        for key in ("clip_obs", "clip_reward", "gamma", "epsilon", "obs_count", "ret_mean", "ret_var", "ret_count"):
            value = getattr(self, key)
            if not isinstance(value, (int, float, np.floating, np.integer)) or isinstance(value, bool):
                raise TypeError(f"ObsNormalizer: {key} must be a number, got {value!r}")
            if not math.isfinite(value):
                raise ValueError(f"ObsNormalizer: {key} must be finite, got {value!r}")
        if self.trained_on is not None and not isinstance(self.trained_on, TrainedOn):
            raise TypeError(f"ObsNormalizer: trained_on must be a TrainedOn or None, got {self.trained_on!r}")
        if self.obs_dtype not in _DTYPES:
            raise ValueError(f"ObsNormalizer: obs_dtype must be one of {_DTYPES}, got {self.obs_dtype!r}")
        _check_normalizer("ObsNormalizer", self)
        arrays = (np.array(self.obs_mean, dtype=self.obs_dtype), np.array(self.obs_var, dtype=self.obs_dtype))
        object.__setattr__(self, "_arrays", arrays)

    @property
    def size(self) -> int | None:
        """Observation entries normalised (None for an identity)."""
        return len(self.obs_mean) if self.norm_obs else None

    def normalize_obs(self, obs: np.ndarray) -> np.ndarray:
        """The normalised observation (float32), as ``VecNormalize.normalize_obs`` computes it."""
        if not self.norm_obs:
            return np.array(obs, copy=True)
        mean, var = self._arrays
        return np.clip((obs - mean) / np.sqrt(var + self.epsilon), -self.clip_obs, self.clip_obs).astype(np.float32)

    @classmethod
    def from_vec_normalize(cls, venv: Any | None, trained_on: TrainedOn | None = None) -> ObsNormalizer:
        """The statistics of a ``VecNormalize`` (None: an identity), recording ``trained_on`` when given."""
        if venv is None:
            return cls(trained_on=trained_on)
        if isinstance(venv.obs_rms, dict):
            raise ValueError("dictionary observation spaces are not supported by hexgym's normaliser files")
        rms = venv.obs_rms
        return cls(
            norm_obs=bool(venv.norm_obs), norm_reward=bool(venv.norm_reward), clip_obs=float(venv.clip_obs),
            clip_reward=float(venv.clip_reward), gamma=float(venv.gamma), epsilon=float(venv.epsilon),
            obs_mean=tuple(float(x) for x in np.ravel(rms.mean)), obs_var=tuple(float(x) for x in np.ravel(rms.var)),
            obs_count=float(rms.count), obs_dtype=_dtype_name(rms.mean), ret_mean=float(np.ravel(venv.ret_rms.mean)[0]),
            ret_var=float(np.ravel(venv.ret_rms.var)[0]), ret_count=float(venv.ret_rms.count), trained_on=trained_on,
        )  # fmt: skip

    def vec_normalize(self, venv: Any, training: bool = True) -> Any:
        """A ``VecNormalize`` around ``venv`` holding these statistics (``venv`` itself for an identity)."""
        from stable_baselines3.common.vec_env import VecNormalize

        if not self.norm_obs and not self.norm_reward:
            return venv
        wrapper = VecNormalize(venv, training=training, norm_obs=self.norm_obs, norm_reward=self.norm_reward,
                               clip_obs=self.clip_obs, clip_reward=self.clip_reward, gamma=self.gamma,
                               epsilon=self.epsilon)  # fmt: skip
        if self.norm_obs:
            if wrapper.obs_rms.mean.shape != self._arrays[0].shape:
                raise ValueError(f"the normaliser has {len(self.obs_mean)} entries, the environment's "
                                 f"observations {wrapper.obs_rms.mean.shape}")  # fmt: skip
            wrapper.obs_rms.mean, wrapper.obs_rms.var = self._arrays[0].copy(), self._arrays[1].copy()
            wrapper.obs_rms.count = self.obs_count
        wrapper.ret_rms.mean, wrapper.ret_rms.var = np.float64(self.ret_mean), np.float64(self.ret_var)
        wrapper.ret_rms.count = self.ret_count
        return wrapper

    def to_json(self) -> dict[str, Any]:
        """The file's content: numbers, booleans, the format tag and what the policy was trained on."""
        data: dict[str, Any] = {"format": NORMALIZER_FORMAT, "version": NORMALIZER_VERSION}
        data |= {k: getattr(self, k) for k in ("norm_obs", "norm_reward", "clip_obs", "clip_reward", "gamma",
                                               "epsilon")}  # fmt: skip
        data["obs"] = {"mean": list(self.obs_mean), "var": list(self.obs_var), "count": self.obs_count,
                       "dtype": self.obs_dtype}  # fmt: skip
        data["ret"] = {"mean": self.ret_mean, "var": self.ret_var, "count": self.ret_count}
        if self.trained_on is not None:
            data["trained_on"] = self.trained_on.to_json()
        return data


def write_normalizer(normalizer: ObsNormalizer, path: str | Path) -> Path:
    """Write ``normalizer`` as JSON, atomically (NaN or infinity refused)."""
    text = json.dumps(normalizer.to_json(), indent=1, allow_nan=False)
    with atomic_path(path) as tmp:
        tmp.write_text(text + "\n")
    return Path(path)


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not a finite number")


_FIELDS = {"norm_obs": bool, "norm_reward": bool, "clip_obs": float, "clip_reward": float, "gamma": float,
           "epsilon": float}  # fmt: skip
_STATS = {"obs": ("mean", "var", "count", "dtype"), "ret": ("mean", "var", "count")}
_DTYPES = ("float32", "float64")


def _dtype_name(array: Any) -> str:
    """The statistics' dtype name, float32 or float64 (others are computed in float64)."""
    name = np.asarray(array).dtype.name
    return name if name in _DTYPES else "float64"


def read_normalizer(path: str | Path) -> ObsNormalizer:
    """Read and check a normaliser file written by :func:`write_normalizer` (no pickle involved).

    :class:`PolicyFileError` names the file and the problem: not UTF-8 JSON, another format or
    version, an unknown key, a value of the wrong type, a non-finite number, a negative variance
    or count, means and variances of different lengths.
    """
    path = check_input_file(path, "observation normaliser")
    if path.stat().st_size > MAX_NORMALIZER_BYTES:
        raise PolicyFileError(f"observation normaliser {path}: {path.stat().st_size} bytes is too large to be one")
    try:
        data = json.loads(path.read_bytes().decode("utf-8"), parse_constant=_reject_constant)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        if path.read_bytes()[:2] in (b"\x80\x02", b"\x80\x03", b"\x80\x04", b"\x80\x05"):
            raise PolicyFileError(f"observation normaliser {path} is a pickle, not JSON: {_CONVERT_HINT}") from None
        raise PolicyFileError(f"observation normaliser {path} is not a JSON file ({exc})") from None
    return _normalizer_from_json(path, data)


def _normalizer_from_json(path: Path, data: Any) -> ObsNormalizer:
    where = f"observation normaliser {path}"
    if not isinstance(data, dict):
        raise PolicyFileError(f"{where}: not a JSON object")
    if data.get("format") != NORMALIZER_FORMAT:
        raise PolicyFileError(f"{where}: format {data.get('format')!r}, expected {NORMALIZER_FORMAT!r}")
    if data.get("version") != NORMALIZER_VERSION or isinstance(data.get("version"), bool):
        raise PolicyFileError(f"{where}: version {data.get('version')!r}; this hexgym reads {NORMALIZER_VERSION}")
    unknown = set(data) - {"format", "version", "trained_on", *_FIELDS, *_STATS}
    if unknown:
        raise PolicyFileError(f"{where}: unknown key(s) {sorted(unknown)}")
    kwargs: dict[str, Any] = {}
    for key, kind in _FIELDS.items():
        if key in data:
            kwargs[key] = _typed(where, key, data[key], kind)
    for group, keys in _STATS.items():
        stats = data.get(group, {})
        if not isinstance(stats, dict) or set(stats) - set(keys):
            raise PolicyFileError(f"{where}: {group!r} must be an object with keys {list(keys)}")
        for key in keys:
            if key not in stats:
                continue
            value = stats[key]
            if group == "obs" and key == "dtype":
                if value not in _DTYPES:
                    raise PolicyFileError(f"{where}: 'obs.dtype' must be one of {_DTYPES}, got {value!r}")
                kwargs["obs_dtype"] = value
            elif group == "obs" and key in ("mean", "var"):
                if not isinstance(value, list):
                    raise PolicyFileError(f"{where}: '{group}.{key}' must be a list of numbers")
                kwargs[f"{group}_{key}"] = tuple(_typed(where, f"{group}.{key}[{i}]", v, float)
                                                 for i, v in enumerate(value))  # fmt: skip
            else:
                kwargs[f"{group}_{key}"] = _typed(where, f"{group}.{key}", value, float)
    if "trained_on" in data:
        kwargs["trained_on"] = _trained_on_from_json(where, data["trained_on"])
    try:
        return ObsNormalizer(**kwargs)  # checks its numbers (clip_obs > 0, ...)
    except (ValueError, TypeError) as exc:
        raise PolicyFileError(f"{where}: {str(exc).removeprefix('ObsNormalizer: ')}") from None


def _trained_on_from_json(where: str, data: Any) -> TrainedOn:
    """The ``trained_on`` object: ``env_id`` (a string), optional ``tables`` (a string), ``obs_names`` (strings)."""
    if not isinstance(data, dict) or set(data) - {"env_id", "tables", "obs_names"} or "env_id" not in data:
        raise PolicyFileError(f"{where}: 'trained_on' must be an object with 'env_id' and optionally 'tables' and "
                              "'obs_names'")  # fmt: skip
    for key in ("env_id", "tables"):
        if key in data and (not isinstance(data[key], str) or not data[key]):
            raise PolicyFileError(f"{where}: 'trained_on.{key}' must be a non-empty string, got {data[key]!r}")
    names = data.get("obs_names")
    if names is not None and (
        not isinstance(names, list) or not names or not all(isinstance(n, str) and n for n in names)
    ):
        raise PolicyFileError(f"{where}: 'trained_on.obs_names' must be a non-empty list of names")
    return TrainedOn(data["env_id"], data.get("tables"), tuple(names) if names is not None else None)


def _typed(where: str, key: str, value: Any, kind: type) -> Any:
    if kind is bool:
        if not isinstance(value, bool):
            raise PolicyFileError(f"{where}: {key!r} must be true or false, got {value!r}")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise PolicyFileError(f"{where}: {key!r} must be a finite number, got {value!r}")
    return float(value)


def _check_normalizer(where: str, n: ObsNormalizer) -> None:
    if n.norm_obs:
        if not n.obs_mean or len(n.obs_mean) != len(n.obs_var):
            raise PolicyFileError(f"{where}: 'obs.mean' and 'obs.var' must be lists of the same length >= 1, "
                                  f"got {len(n.obs_mean)} and {len(n.obs_var)}")  # fmt: skip
        if min(n.obs_var) < 0:
            raise PolicyFileError(f"{where}: a variance in 'obs.var' is negative ({min(n.obs_var)})")
    for key in ("clip_obs", "clip_reward", "epsilon"):
        if getattr(n, key) <= 0:
            raise PolicyFileError(f"{where}: {key!r} must be > 0, got {getattr(n, key)}")
    if not 0 <= n.gamma <= 1:
        raise PolicyFileError(f"{where}: 'gamma' must be from 0 to 1, got {n.gamma}")
    if n.obs_count <= 0 or n.ret_count <= 0 or n.ret_var < 0:
        raise PolicyFileError(f"{where}: counts must be > 0 and variances >= 0")


_CONVERT_HINT = "convert it once with `hexgym convert-normalizer FILE` (it reads only the statistics)"


def load_normalizer(model_path: str | Path) -> ObsNormalizer:
    """The normaliser beside ``model_path``; :class:`PolicyFileError` when it is missing or only pickled."""
    path = normalizer_path(model_path)
    if path.exists():
        return read_normalizer(path)
    old = pickled_normalizer_path(model_path)
    if old.exists():
        raise PolicyFileError(
            f"the policy's observation normaliser {old} is a pickle, which hexgym no longer reads (a pickle "
            f"can run code); {_CONVERT_HINT.replace('FILE', str(old))}, which writes {path.name}"
        )
    raise PolicyFileError(
        f"policy {model_path} has no observation normaliser {path}: without the statistics it was trained with "
        f"it would act on raw observations. Put the file beside the model (for a model trained without "
        f'normalisation: {{"format": "{NORMALIZER_FORMAT}", "version": {NORMALIZER_VERSION}, "norm_obs": false}})'
    )


# -- converting an old pickled VecNormalize, without running it -----------------------------------
class _Record:
    """Stands in for any object of the pickle: keeps its constructor arguments and state, runs nothing."""

    def __new__(cls, *args: Any, **kwargs: Any) -> _Record:  # NEWOBJ calls only __new__
        record = super().__new__(cls)
        record.args = args
        return record

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        pass

    def __setstate__(self, state: Any) -> None:
        self.state = state


def _record(*args: Any) -> _Record:
    return _Record(*args)


# What a pickled VecNormalize refers to: its class, RunningMeanStd, gymnasium's Box with numpy's
# random generator, numpy arrays. Only numpy's array reconstruction runs; the rest are recorded.
_RECORDED = {
    ("stable_baselines3.common.vec_env.vec_normalize", "VecNormalize"),
    ("stable_baselines3.common.running_mean_std", "RunningMeanStd"),
    ("gymnasium.spaces.box", "Box"),
    ("numpy.random._pickle", "__generator_ctor"),
    ("numpy.random._pickle", "__bit_generator_ctor"),
    ("numpy.random._pickle", "__randomstate_ctor"),
    ("numpy.random._pcg64", "PCG64"),
    ("numpy.random._mt19937", "MT19937"),
    ("numpy.random.bit_generator", "SeedSequence"),
    ("numpy.random.bit_generator", "__pyx_unpickle_SeedSequence"),
}
_NUMPY = {
    ("numpy", "dtype"), ("numpy", "ndarray"),
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
}  # fmt: skip


class _StatisticsUnpickler(pickle.Unpickler):
    recorded = _RECORDED

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in _NUMPY:
            return super().find_class(module, name)
        if (module, name) in self.recorded:
            return _Record if name[0].isupper() else _record
        raise pickle.UnpicklingError(f"it refers to {module}.{name}, which a VecNormalize's statistics do not need")


def _state(obj: Any, what: str) -> dict[str, Any]:
    if not isinstance(obj, _Record) or not isinstance(getattr(obj, "state", None), dict):
        raise ValueError(f"{what} is not a pickled object with a state")
    return obj.state


def convert_pickled_normalizer(pkl: str | Path, out: str | Path | None = None) -> Path:
    """Write the statistics of a pickled ``VecNormalize`` as a JSON normaliser (default: beside it, ``.json``).

    The pickle is read by an unpickler that builds numpy arrays and records everything else
    (nothing of the file's choosing runs); anything beyond a VecNormalize's parts is refused.
    """
    pkl = check_input_file(pkl, "pickled normaliser")
    out = check_output_file(out if out is not None else pkl.with_suffix(".json"), "normaliser", inputs=(pkl,))
    try:
        with pkl.open("rb") as f:
            state = _state(_StatisticsUnpickler(f).load(), "the file")
        rms = state["obs_rms"]
        if isinstance(rms, dict):
            raise ValueError("dictionary observation spaces are not supported")
        obs, ret = _state(rms, "obs_rms"), _state(state["ret_rms"], "ret_rms")
        normalizer = ObsNormalizer(
            norm_obs=bool(state["norm_obs"]), norm_reward=bool(state["norm_reward"]),
            clip_obs=float(state["clip_obs"]), clip_reward=float(state["clip_reward"]), gamma=float(state["gamma"]),
            epsilon=float(state["epsilon"]), obs_mean=tuple(float(x) for x in np.ravel(obs["mean"])),
            obs_var=tuple(float(x) for x in np.ravel(obs["var"])), obs_count=float(obs["count"]),
            obs_dtype=_dtype_name(obs["mean"]),
            ret_mean=float(np.ravel(ret["mean"])[0]), ret_var=float(np.ravel(ret["var"])[0]),
            ret_count=float(ret["count"]),
        )  # fmt: skip
    except Exception as exc:  # anything in a file that is not what it should be
        raise PolicyFileError(f"{pkl} is not a pickled VecNormalize hexgym can convert: {exc}") from None
    _check_normalizer(f"pickled normaliser {pkl}", normalizer)
    return write_normalizer(normalizer, out)


# -- the model zip --------------------------------------------------------------------------------
_ACTIVATIONS = ("ReLU", "Tanh", "ELU", "LeakyReLU", "GELU", "SiLU", "Sigmoid", "Softplus", "Mish", "Identity")


def read_model_data(path: str | Path) -> dict[str, Any]:
    """The ``data`` record (JSON) of a Stable-Baselines3 zip, without deserialising anything in it."""
    path = check_input_file(path, "policy file")
    try:
        with zipfile.ZipFile(path) as archive:
            info = archive.getinfo("data")
            if info.file_size > MAX_DATA_BYTES:
                raise ValueError(f"its data record has {info.file_size} bytes")
            data = json.loads(archive.read("data").decode("utf-8"))
            names = set(archive.namelist())
    except (zipfile.BadZipFile, KeyError, ValueError, UnicodeDecodeError, EOFError, OSError) as exc:
        raise PolicyFileError(f"{path} is not a Stable-Baselines3 model zip ({exc})") from None
    except RecursionError:
        raise PolicyFileError(f"{path} is not a Stable-Baselines3 model zip (its data record is nested too "
                              "deeply to be one)") from None  # fmt: skip
    if not isinstance(data, dict) or "policy.pth" not in names:
        raise PolicyFileError(f"{path} is not a Stable-Baselines3 model zip (no policy data or weights)")
    return data


# Rollout state a saved model carries (the last observations, episode statistics): not needed to act,
# and without them learn() starts from a reset, as it does anyway when a model is loaded onto an env.
_TRAINING_STATE = ("_last_obs", "_last_original_obs", "_last_episode_starts", "ep_info_buffer", "ep_success_buffer")


def _serialized(item: Any) -> bool:
    return isinstance(item, dict) and ":serialized:" in item


def algorithm_of(path: str | Path, data: dict[str, Any] | None = None) -> type:
    """The Stable-Baselines3 class (PPO or SAC, MlpPolicy) that saved ``path``, read from its readable fields."""
    from stable_baselines3 import PPO, SAC

    data = read_model_data(path) if data is None else data
    item = data.get("policy_class")
    text = json.dumps({k: v for k, v in item.items() if k != ":serialized:"}) if _serialized(item) else ""
    if "stable_baselines3.sac.policies" in text and "SACPolicy" in text:
        return SAC
    if "stable_baselines3.common.policies" in text and "ActorCriticPolicy" in text:
        return PPO
    raise PolicyFileError(f"{path}: neither a PPO nor a SAC MlpPolicy model")


def _shape(path: Path, key: str, item: Any) -> tuple[int, ...]:
    shape = item.get("_shape") if isinstance(item, dict) else None
    if not isinstance(shape, list) or not all(isinstance(n, int) and not isinstance(n, bool) for n in shape):
        raise PolicyFileError(f"{path}: the {key} has no readable shape")
    return tuple(shape)


def _schedule(path: Path, key: str, item: dict[str, Any]) -> Any:
    """A constant or linear schedule from its readable ``value_schedule`` field."""
    from stable_baselines3.common.utils import FloatSchedule, LinearSchedule

    text = str(item.get("value_schedule", ""))
    number = r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)"
    if m := re.fullmatch(rf"ConstantSchedule\(val={number}\)", text):
        return FloatSchedule(float(m[1]))
    if m := re.fullmatch(rf"LinearSchedule\(start={number}, end={number}, end_fraction={number}\)", text):
        return FloatSchedule(LinearSchedule(float(m[1]), float(m[2]), float(m[3])))
    raise PolicyFileError(f"{path}: the {key} is a pickled schedule hexgym cannot read safely ({text or 'unnamed'})")


class _TrainFreqUnpickler(_StatisticsUnpickler):
    recorded = {("stable_baselines3.common.type_aliases", "TrainFreq"),
                ("stable_baselines3.common.type_aliases", "TrainFrequencyUnit")}  # fmt: skip


def _train_freq(path: Path, item: dict[str, Any]) -> Any:
    """SAC's ``TrainFreq(frequency, unit)``, read from its pickle by recording it (nothing runs)."""
    from stable_baselines3.common.type_aliases import TrainFreq, TrainFrequencyUnit

    try:
        record = _TrainFreqUnpickler(io.BytesIO(base64.b64decode(item[":serialized:"], validate=True))).load()
        frequency, unit = record.args
        unit = TrainFrequencyUnit(unit.args[0])
        if isinstance(frequency, bool) or not isinstance(frequency, int) or frequency < 1:
            raise ValueError(f"frequency {frequency!r}")
    except Exception as exc:  # anything but a TrainFreq of a whole number and a unit
        raise PolicyFileError(f"{path}: its train_freq is not one hexgym can read safely ({exc})") from None
    return TrainFreq(frequency, unit)


def _class_from(path: Path, key: str, text: str) -> Any:
    import torch

    m = re.fullmatch(r"<class '([\w.]+)'>", text)
    name = m[1] if m else ""
    if name.startswith("torch.nn.modules.") and name.rsplit(".", 1)[1] in _ACTIVATIONS:
        return getattr(torch.nn, name.rsplit(".", 1)[1])
    if name in ("torch.optim.adam.Adam", "torch.optim.rmsprop.RMSprop", "torch.optim.sgd.SGD"):
        return getattr(torch.optim, name.rsplit(".", 1)[1])
    if name == "stable_baselines3.common.torch_layers.FlattenExtractor":
        from stable_baselines3.common.torch_layers import FlattenExtractor

        return FlattenExtractor
    raise PolicyFileError(f"{path}: its policy_kwargs name {text!r} for {key!r}, which hexgym does not load")


def _policy_kwargs(path: Path, item: dict[str, Any]) -> dict[str, Any]:
    kwargs = {}
    for key, value in item.items():
        if key.startswith(":"):
            continue
        kwargs[key] = _class_from(path, key, value) if isinstance(value, str) and value.startswith("<") else value
    return kwargs


def safe_custom_objects(
    path: str | Path, data: dict[str, Any], observation_space: Any, action_space: Any
) -> dict[str, Any]:
    """A replacement for every pickled entry of a model zip's ``data``, or :class:`PolicyFileError`.

    ``observation_space``/``action_space``: the environment's; the zip's must have their shapes.
    """
    path = Path(path)
    algo = algorithm_of(path, data)
    custom: dict[str, Any] = {}
    for key, item in data.items():
        if not _serialized(item):
            continue
        if key == "policy_class":
            custom[key] = algo.policy_aliases["MlpPolicy"]
        elif key in ("observation_space", "action_space"):
            space = observation_space if key == "observation_space" else action_space
            saved = _shape(path, key, item)
            if saved != space.shape:
                what = "observations" if key == "observation_space" else "actions"
                raise PolicyFileError(f"{path}: the policy takes {what} of shape {saved}, the environment's "
                                      f"have shape {space.shape}")  # fmt: skip
            custom[key] = space
        elif key in ("rollout_buffer_class", "replay_buffer_class"):
            custom[key] = None  # the algorithm picks the buffer for the space itself
        elif key in _TRAINING_STATE:
            custom[key] = None  # learn() resets the environment and starts these afresh
        elif key in ("lr_schedule", "learning_rate", "clip_range", "clip_range_vf"):
            custom[key] = _schedule(path, key, item)
        elif key == "policy_kwargs":
            custom[key] = _policy_kwargs(path, item)
        elif key == "train_freq":
            custom[key] = _train_freq(path, item)
        else:
            raise PolicyFileError(f"{path}: its {key!r} is pickled; hexgym does not unpickle policy files")
    return custom


def load_sb3_model(path: str | Path, observation_space: Any, action_space: Any, **kwargs: Any) -> Any:
    """``PPO.load``/``SAC.load`` of ``path`` with every pickled entry replaced (:func:`safe_custom_objects`).

    ``kwargs`` go to ``load`` (``env``, ``seed``, ...). Errors reading the weights (a damaged zip,
    tensors that do not fit the network) are :class:`PolicyFileError` naming the file.
    """
    path = check_input_file(path, "policy file")
    data = read_model_data(path)
    algo = algorithm_of(path, data)
    custom = safe_custom_objects(path, data, observation_space, action_space)
    try:
        return algo.load(path, device="cpu", custom_objects=custom, **kwargs)
    except PolicyFileError:
        raise
    except Exception as exc:  # a zip whose tensors or settings do not load
        message = " ".join(str(exc).split())[:300]
        raise PolicyFileError(f"{path}: the model does not load ({type(exc).__name__}: {message})") from None


def pickles_in(path: str | Path) -> list[str]:
    """The ``data`` entries of a model zip that are pickled (for reports and tests)."""
    return [k for k, v in read_model_data(path).items() if _serialized(v)]


# -- RLlib checkpoints ------------------------------------------------------------------------------------
RLLIB_CHECKPOINT = "checkpoint"  # a run directory's newest checkpoint
RLLIB_MODULE_PATH = ("learner_group", "learner", "rl_module", "default_policy")  # RLlib's component names


def rllib_module_path(path: str | Path) -> Path:
    """The RL module directory inside an RLlib checkpoint (or a run directory holding ``checkpoint/``)."""
    path = Path(path)
    if (path / RLLIB_CHECKPOINT).is_dir() and not (path / RLLIB_MODULE_PATH[0]).exists():
        path = path / RLLIB_CHECKPOINT
    module = path.joinpath(*RLLIB_MODULE_PATH)
    if not module.is_dir():
        raise FileNotFoundError(
            f"{path} is not an RLlib checkpoint of `hexgym train --framework rllib` (no {'/'.join(RLLIB_MODULE_PATH)})"
        )
    return module


# What an RL module's state pickle (``module_state.pkl``: a dict of numpy arrays) refers to: a dict
# class and numpy's array construction from bytes. Any other reference refuses the file unread.
_WEIGHT_GLOBALS = {
    ("collections", "OrderedDict"),
    ("numpy", "dtype"), ("numpy", "ndarray"),
    ("numpy._core.numeric", "_frombuffer"), ("numpy.core.numeric", "_frombuffer"),
    ("numpy._core.multiarray", "_reconstruct"), ("numpy.core.multiarray", "_reconstruct"),
}  # fmt: skip
MAX_STATE_BYTES = 1 << 30  # an RL module's weights (hexgym's: tens of kB)


class _WeightsUnpickler(pickle.Unpickler):
    def find_class(self, module: str, name: str) -> Any:
        if (module, name) in _WEIGHT_GLOBALS:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"it refers to {module}.{name}; a module's weights are numpy arrays only")

    def persistent_load(self, pid: Any) -> Any:
        raise pickle.UnpicklingError("it refers to an outside object")


def read_module_weights(module_dir: str | Path) -> dict[str, np.ndarray]:
    """The weights of an RL module directory (``module_state.pkl``, or torch's ``module_state.pt``), read
    without running anything from the checkpoint: numpy arrays only (``torch.load(weights_only=True)``)."""
    module_dir = Path(module_dir)
    found = [
        module_dir / name for name in ("module_state.pkl", "module_state.pt") if os.path.lexists(module_dir / name)
    ]
    if not found:
        raise PolicyFileError(f"RLlib checkpoint {module_dir}: no module_state.pkl (the RL module's weights)")
    path = check_input_file(found[0], "RLlib module state")
    if path.stat().st_size > MAX_STATE_BYTES:
        raise PolicyFileError(f"RLlib module state {path}: {path.stat().st_size} bytes, more than {MAX_STATE_BYTES}")
    try:
        if path.suffix == ".pt":
            import torch

            state = torch.load(path, map_location="cpu", weights_only=True)
            state = {k: v.numpy() if hasattr(v, "numpy") else v for k, v in state.items()}
        else:
            with path.open("rb") as f:
                state = _WeightsUnpickler(f).load()
    except Exception as exc:  # noqa: BLE001 - a damaged or crafted file: what it is, in one line
        text = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise PolicyFileError(f"RLlib module state {path} is not an RL module's weights: {text}") from None
    if not isinstance(state, dict) or not all(isinstance(k, str) for k in state):
        raise PolicyFileError(f"RLlib module state {path} is not a mapping of names to arrays")
    for key, value in state.items():
        if not isinstance(value, np.ndarray) or value.dtype.kind != "f" or not np.all(np.isfinite(value)):
            raise PolicyFileError(f"RLlib module state {path}: {key} is not an array of finite numbers")
    return state

"""rl-zoo3 hyperparameter files, read without running them: :func:`load_hyperparams` (the packaged ones in
``hexgym_lab/hyperparams/``, package data that a wheel carries, or a user's), their keyword strings parsed as
literals (:func:`parse_kwargs`), and the wrappers a file's ``env_wrapper`` may name (:data:`WRAPPERS`: registered,
never imported by name)."""

from __future__ import annotations

import ast
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hexgym.envs import ENV_ID
from hexgym.files import check_input_file
from hexgym.wrappers import PreviousActionWrapper

HYPERPARAMS_DIR = Path(__file__).resolve().parents[1] / "hyperparams"  # the packaged <algo>.yml files
ALGOS = ("ppo", "sac")
# rl-zoo3 keys that are not arguments of the algorithm's constructor
_ZOO_KEYS = ("n_envs", "n_timesteps", "policy", "normalize", "env_kwargs", "policy_kwargs", "env_wrapper")


_ACTIVATIONS = ("ReLU", "Tanh", "ELU", "LeakyReLU", "GELU", "SiLU", "Sigmoid", "Softplus", "Mish", "Identity")


def parse_kwargs(text: str | dict | bool) -> dict | bool:
    """An rl-zoo3 keyword string such as ``"dict(norm_obs=True, net_arch=[64, 64])"`` -> a dict.

    rl-zoo3 ``eval``s these strings; hexgym reads them without running them: ``dict(...)`` calls,
    literals (numbers, strings, True/False/None, lists, tuples, {...}) and ``nn.<activation>``
    (``torch.nn``'s ReLU, Tanh, ...) are understood, anything else is refused.
    """
    if not isinstance(text, str):
        return text
    try:
        return _literal(ast.parse(text.strip(), mode="eval").body)
    except (SyntaxError, ValueError, RecursionError) as exc:
        raise ValueError(f"cannot read the hyperparameter {text!r}: {exc}") from None


def _literal(node: ast.AST) -> Any:
    """The value of an rl-zoo3 keyword expression (see :func:`parse_kwargs`)."""
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float, str, bool, type(None))):
        return node.value
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        value = _literal(node.operand)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return -value if isinstance(node.op, ast.USub) else value
    if isinstance(node, (ast.List, ast.Tuple)):
        items = [_literal(e) for e in node.elts]
        return items if isinstance(node, ast.List) else tuple(items)
    if isinstance(node, ast.Dict) and all(k is not None for k in node.keys):
        return {_literal(k): _literal(v) for k, v in zip(node.keys, node.values, strict=True)}
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "dict" and not node.args:
        if all(k.arg is not None for k in node.keywords):
            return {k.arg: _literal(k.value) for k in node.keywords}
    if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "nn":
        if node.attr in _ACTIVATIONS:
            import torch

            return getattr(torch.nn, node.attr)
        raise ValueError(f"nn.{node.attr} is not an activation hexgym knows ({', '.join(_ACTIVATIONS)})")
    raise ValueError(f"{ast.unparse(node)!r} is not allowed: only dict(...), literals and nn.<activation>")


def load_hyperparams(algo: str, env_id: str = ENV_ID, path: str | Path | None = None) -> dict[str, Any]:
    """The rl-zoo3 hyperparameters of ``algo`` for ``env_id`` (``policy_kwargs``/``normalize`` parsed)."""
    import yaml

    if algo not in ALGOS:
        raise ValueError(f"algo must be one of {ALGOS}, got {algo!r}")
    path = Path(path) if path is not None else HYPERPARAMS_DIR / f"{algo}.yml"
    if not path.exists():
        raise FileNotFoundError(f"no hyperparameter file {path} (give one with --hyperparams)")
    check_input_file(path, "hyperparameter file")
    try:
        table = yaml.safe_load(path.read_bytes().decode("utf-8")) or {}
    except (yaml.YAMLError, UnicodeDecodeError, RecursionError) as exc:
        raise ValueError(f"{path} is not a readable YAML file: {' '.join(str(exc).split())}") from None
    if not isinstance(table, dict):
        raise ValueError(f"{path} must map env ids to hyperparameters, not hold a {type(table).__name__}")
    if _nodes(table) > MAX_YAML_NODES:
        raise ValueError(f"{path} expands to more than {MAX_YAML_NODES} values (aliases within aliases?)")
    if env_id not in table:
        raise ValueError(f"{path} has no entry for {env_id!r} (it has {sorted(map(str, table))})")
    if not isinstance(table[env_id], dict):
        raise ValueError(f"{path}: the entry for {env_id!r} must be a mapping of hyperparameters")
    hp = dict(table[env_id])
    try:
        wrapper_named(hp.get("env_wrapper"))  # a registered name, or refused before any work
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    hp["policy_kwargs"] = parse_kwargs(hp.get("policy_kwargs", {}))
    normalize = parse_kwargs(hp.get("normalize", False))
    hp["normalize"] = {"norm_obs": True, "norm_reward": False} if normalize is True else (normalize or {})
    return hp


MAX_YAML_NODES = 100_000  # values in a hyperparameter file, aliases expanded (a real one has ~20 per env)


def _nodes(value: Any, limit: int = MAX_YAML_NODES) -> int:
    """Values in a YAML document counted through its aliases (stops counting past ``limit``)."""
    count, stack = 0, [value]
    while stack and count <= limit:
        item = stack.pop()
        count += 1
        if isinstance(item, dict):
            stack.extend(item.keys())
            stack.extend(item.values())
        elif isinstance(item, (list, tuple)):
            stack.extend(item)
    return count


def algo_kwargs(hp: dict[str, Any]) -> dict[str, Any]:
    """The constructor arguments of the algorithm (rl-zoo3's own keys removed)."""
    kwargs = {k: v for k, v in hp.items() if k not in _ZOO_KEYS}
    return kwargs | {"policy_kwargs": hp.get("policy_kwargs", {})}


WRAPPERS: dict[str, Callable[[Any], Any]] = {"hexgym.wrappers.PreviousActionWrapper": PreviousActionWrapper}
"""The wrappers a hyperparameter file's ``env_wrapper`` may name (by this name or its last part): a file names
a registered wrapper, never a module to import, so a hyperparameter file runs no code of its own choosing."""


def register_wrapper(name: str, wrapper: Callable[[Any], Any]) -> None:
    """Let ``env_wrapper: <name>`` apply ``wrapper`` (a callable taking and returning an env) in this process."""
    if not isinstance(name, str) or not name or not callable(wrapper):
        raise TypeError(f"register_wrapper needs a name and a callable, got {name!r} and {wrapper!r}")
    WRAPPERS[name] = wrapper


def wrapper_named(path: Any) -> Any:
    """The registered wrapper (:data:`WRAPPERS`) named by rl-zoo3's ``env_wrapper``, or None; nothing is imported."""
    if path is None or path == "":
        return None
    if not isinstance(path, str):
        raise ValueError(f"env_wrapper must be the name of a registered wrapper, got {path!r}")
    short = {name.rpartition(".")[2]: wrapper for name, wrapper in WRAPPERS.items()}
    found = WRAPPERS.get(path) or short.get(path)
    if found is None:
        raise ValueError(
            f"env_wrapper {path!r} is not a registered wrapper ({', '.join(sorted(WRAPPERS))}); a hyperparameter "
            "file names registered wrappers only, it never imports a module (from Python: "
            "hexgym_lab.agents.hyperparams.register_wrapper)"
        )
    return found

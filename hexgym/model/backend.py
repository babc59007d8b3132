"""Choosing the learned model's backend: the one place that decides between Python and native.

``"native"`` is the ``hexgym.mbl`` plugin (:mod:`hexgym.model.native_backend`), ``"python"`` the
readable Python step loop (:mod:`hexgym.model.python_backend`), and ``"auto"`` native when the
plugin library is built and loads, else Python (saying why once per process). Setting the
environment variable ``HEXGYM_BACKEND=python`` makes ``"auto"`` pick Python even where the plugin is
built (CI runs the model and environment tests once more this way).
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

from hexgym.mbl.schema import DEFAULT_TABLE_SET
from hexgym.model.base import LearnedModelBase

if TYPE_CHECKING:  # the CLI's parser imports this module: MuJoCo loads only with a model
    import mujoco

    from hexgym.hydraulics.overrides import HydraulicsOverrides
    from hexgym.model.python_backend import LearnedModel

BACKENDS = ("auto", "python", "native")
BACKEND_VARIABLE = "HEXGYM_BACKEND"
_fallback_said = False


def check_backend(backend: str) -> None:
    """Raise ValueError naming ``backend`` unless it is one of :data:`BACKENDS`."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")


def resolve_backend(backend: str = "auto") -> str:
    """``backend`` with "auto" resolved: "python" when ``HEXGYM_BACKEND=python`` is set or the plugin
    cannot be loaded (saying why, once per process), else "native"."""
    check_backend(backend)
    if backend != "auto":
        return backend
    forced = os.environ.get(BACKEND_VARIABLE, "")
    if forced not in ("", "auto", "python", "native"):
        raise ValueError(f"environment variable {BACKEND_VARIABLE}={forced!r}: use python, native or auto")
    if forced in ("python", "native"):
        return forced
    from hexgym.model.plugin import load_plugin

    global _fallback_said
    reason = load_plugin()
    if reason and not _fallback_said:
        _fallback_said = True
        warnings.warn(f"hexgym: {reason}; the learned model runs in Python", RuntimeWarning, stacklevel=2)
    return "python" if reason else "native"


def backend_for(table_set: str, backend: str = "auto") -> str:
    """The backend that runs ``table_set``: :func:`resolve_backend`, except that a set the plugin does not run
    (one not in :data:`hexgym.mbl.schema.NATIVE_TABLE_SETS`) runs in Python, and "native" for it is refused
    naming both. ValueError naming the sets for a name that is none of them."""
    from hexgym.mbl.schema import NATIVE_TABLE_SETS, TABLE_SETS

    check_backend(backend)
    if table_set not in TABLE_SETS:
        raise ValueError(f"table set must be one of {tuple(TABLE_SETS)}, got {table_set!r}")
    if table_set in NATIVE_TABLE_SETS:
        return resolve_backend(backend)
    if backend == "native":
        raise ValueError(f"backend 'native' does not run the {table_set} tables: use backend 'python' or 'auto'")
    return "python"


def python_learned_model(
    table_set: str = DEFAULT_TABLE_SET,
    tables_dir: str | Path | None = None,
    model: mujoco.MjModel | None = None,
    control_period: float | None = None,
    hydraulics: HydraulicsOverrides | None = None,
) -> LearnedModel:
    """The Python learned model of ``table_set`` on ``model`` (default: the lean machine): the circuit model
    (:class:`hexgym.model.circuit_model.CircuitModel`) for "circuit", the table model
    (:class:`hexgym.model.python_backend.LearnedModel`) for "paper". ``hydraulics``: the circuit model's pumps
    (default: a fitted model's, :func:`hexgym.mbl.table.model_hydraulics`, else the data sheet's); the paper's
    tables hold theirs in their data (ValueError)."""
    from hexgym.mbl.schema import CIRCUIT_TABLE_SETS
    from hexgym.mbl.table import load_tables, model_hydraulics
    from hexgym.model.python_backend import LearnedModel

    tables = load_tables(tables_dir, table_set)
    if table_set in CIRCUIT_TABLE_SETS:
        from hexgym.model.circuit_model import CircuitModel

        if hydraulics is None:
            hydraulics = model_hydraulics(tables_dir)
        return CircuitModel(tables, model=model, control_period=control_period, table_set=table_set,
                            hydraulics=hydraulics)  # fmt: skip
    if hydraulics is not None:
        raise ValueError(f"the {table_set!r} tables hold their pumps in their data: hydraulics cannot be overridden")
    return LearnedModel(tables, model=model, control_period=control_period)


def make_learned_model(
    backend: str = "auto",
    tables_dir: str | Path | None = None,
    control_period: float | None = None,
    table_set: str = DEFAULT_TABLE_SET,
) -> LearnedModelBase:
    """The learned model on ``backend`` ("native", "python" or "auto"), on the lean machine.

    ``table_set``: "circuit" or "paper" (:mod:`hexgym.mbl.schema`; the circuit model,
    :mod:`hexgym.model.circuit_model`, for the circuit sets; all run on either backend);
    ``tables_dir``: other tables of that set than the packaged ones (both backends read the same files).
    """
    if backend_for(table_set, backend) == "native":
        from hexgym.model.native_backend import NativeLearnedModel

        return NativeLearnedModel(tables_dir=tables_dir, control_period=control_period, table_set=table_set)
    return python_learned_model(table_set, tables_dir, control_period=control_period)

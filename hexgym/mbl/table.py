"""MBL tables: a fitted LWR evaluated once on a grid, then looked up by multilinear interpolation.

The paper runs its learned model fast by "a locally-weighted regression scheme in conjunction with
a table-lookup": the LWR (:mod:`hexgym_lab.mbl.lwr`) is too slow to call every simulation step (a
neighbour search and a small solve per query), so each table stores the LWR's predictions at the
nodes of a rectangular grid over its inputs and interpolates between them.

Grid. One 1-D axis per input. :func:`suggest_axes` makes uniform axes over the data's range:
spool axes at the sampling step (1 mm, so nodes sit on the sampled levels), other axes with
``nodes_per_bandwidth`` nodes per kernel width ``h * scale`` (the LWR output is a Gaussian
smoothing of the data, so it has no detail finer than the kernel; linear interpolation at spacing
``h s`` loses little; :func:`build_table` measures how much). Uniform axes also make the cell
index a subtraction and a multiply instead of a search. Measured on the synthetic flow-sharing
set (6000 points, 4 inputs, selected parameters, 23 x 23 x 22 x 12 nodes): table vs direct LWR
differs by 0.6 % of the output range RMS at random points, against 3.4 % for LWR vs the true
function, and the table's error vs the true function is the same 3.4 %; doubling the nodes on
the load axes gains 0.06 %, halving the spool step 0.25 %.

Speed (same set, 2-core machine): one query 8-17 µs through the pure-Python path (4-5 inputs),
60 µs through the numpy path, 200-320 µs through RegularGridInterpolator, 350-500 µs direct LWR;
batched, 1.4-2 µs per query vs 19-67 µs direct.

Lookup. ``table(x)`` interpolates multilinearly (the 2^d corners of the cell). Queries outside the
grid are clamped to its boundary, so the output is the boundary value (a spool past ±11 mm reads
as ±11 mm): the simulator never sees an extrapolated velocity. ``table.lookup(Xq,
return_confidence=True)`` also returns the interpolated node confidence (effective sample size of
the LWR fit at the nodes), set to 0 for queries outside the grid; values below ~2 mean the query
is away from the training data. A NaN query raises ValueError. A single 1-D query takes a
pure-Python path (faster than numpy's per-call overhead for one point; the tests prove it equal
to ``scipy.interpolate.RegularGridInterpolator``); batches take a vectorised numpy path.

File. One ``.npz`` per table (``np.savez_compressed``, no pickle): the arrays ``values``,
``confidence``, ``axis_0`` ... and ``meta``, a one-element string array holding JSON with the
format version, names, LWR parameters, metrics, the training data's sha256 and the sha256 of the
table's own content. Writes are atomic (temporary file in the same directory + ``os.replace``);
:func:`load_table` checks the version, the shapes and the content hash and names the file in
every error.
"""

# Matrix names (X, Xq) follow the statistics notation, hence N803/N806 off.
# ruff: noqa: N803, N806

from __future__ import annotations

import array
import bisect
import hashlib
import json
import os
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from hexgym.files import atomic_path
from hexgym.mbl.lwr_params import LWRParams, as_queries, check_finite
from hexgym.mbl.schema import DEFAULT_TABLE_SET, TABLE_SETS, check_table_schema

FORMAT_VERSION = 1
_UNIFORM_RTOL = 1e-9  # an axis whose steps agree to this is treated as uniform


class TableFileError(ValueError):
    """A table file that cannot be used: corrupt, wrong version, wrong shapes or altered content."""


def dataset_hash(X: np.ndarray, y: np.ndarray) -> str:
    """sha256 of the training arrays (float64, C order, with their shapes)."""
    h = hashlib.sha256()
    for a in (np.ascontiguousarray(X, dtype=np.float64), np.ascontiguousarray(y, dtype=np.float64)):
        h.update(repr(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


@dataclass(frozen=True, eq=False)
class MBLTable:
    """A memory-based-learning table: LWR predictions on a grid, interpolated multilinearly.

    Attributes:
        name: the table's name (e.g. ``"boom"``).
        inputs: input names, one per axis, in query column order.
        output: the output's name (e.g. ``"boom_cylinder_velocity"``).
        axes: one strictly increasing 1-D array of node coordinates per input.
        values: LWR predictions at the nodes, shape ``tuple(len(a) for a in axes)``.
        confidence: LWR effective sample size at the nodes, same shape.
        params: the LWR parameters the values were computed with.
        metrics: ``loo_rmse_rel``, ``holdout_rmse_rel`` (RMSE / output range in the data),
            ``n_points`` and whatever else the builder measured.
        data_hash: sha256 of the training data (:func:`dataset_hash`).
    """

    name: str
    inputs: tuple[str, ...]
    output: str
    axes: tuple[np.ndarray, ...] = field(repr=False)
    values: np.ndarray = field(repr=False)
    confidence: np.ndarray = field(repr=False)
    params: LWRParams
    metrics: dict[str, float] = field(default_factory=dict)
    data_hash: str = ""
    _fast: dict[str, Any] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        axes = tuple(np.array(a, dtype=np.float64) for a in self.axes)
        values = np.array(self.values, dtype=np.float64)
        confidence = np.array(self.confidence, dtype=np.float64)
        object.__setattr__(self, "inputs", tuple(str(s) for s in self.inputs))
        object.__setattr__(self, "axes", axes)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "confidence", confidence)
        self._validate()
        for a in (*axes, values, confidence):
            a.flags.writeable = False  # the fast path keeps its own copy: keep them in step
        self._prepare_lookup()

    def _validate(self) -> None:
        d = len(self.inputs)
        if len(self.axes) != d or self.params.n_inputs != d:
            raise ValueError(
                f"table {self.name!r}: {d} inputs, {len(self.axes)} axes, {self.params.n_inputs} input_scales"
            )
        for j, a in enumerate(self.axes):
            if a.ndim != 1 or len(a) < 2 or not np.all(np.diff(a) > 0):
                raise ValueError(
                    f"table {self.name!r}: axis {j} ({self.inputs[j]}) must be 1-D, increasing, >= 2 nodes"
                )
            check_finite(f"table {self.name!r} axis {j}", a)
        shape = tuple(len(a) for a in self.axes)
        for what, arr in (("values", self.values), ("confidence", self.confidence)):
            if arr.shape != shape:
                raise ValueError(f"table {self.name!r}: {what} has shape {arr.shape}, the axes make {shape}")
            check_finite(f"table {self.name!r} {what} (flattened)", arr.reshape(-1))

    def _prepare_lookup(self) -> None:
        """Per-axis origin, inverse step, strides and corner offsets for both lookup paths."""
        d = len(self.axes)
        n = np.array([len(a) for a in self.axes])
        strides = np.ones(d, dtype=np.int64)
        for j in range(d - 2, -1, -1):
            strides[j] = strides[j + 1] * n[j + 1]
        bits = (np.arange(2**d)[:, None] >> np.arange(d - 1, -1, -1)[None, :]) & 1  # last axis = lowest bit
        steps = [np.diff(a) for a in self.axes]
        uniform = [bool(np.allclose(s, s[0], rtol=_UNIFORM_RTOL, atol=0.0)) for s in steps]
        self._fast.update(
            d=d,
            n=n,
            lo=np.array([a[0] for a in self.axes]),
            hi=np.array([a[-1] for a in self.axes]),
            inv_step=np.array([(len(a) - 1) / (a[-1] - a[0]) for a in self.axes]),
            uniform=np.array(uniform),
            strides=strides,
            bits=bits.astype(bool),
            offsets=(bits * strides).sum(axis=1),
            flat=self.values.reshape(-1),
            flat_conf=self.confidence.reshape(-1),
            # plain-Python copies for the single-query path (indexing them is ~3x faster than numpy)
            py=[
                (float(a[0]), float(a[-1]), (len(a) - 1) / float(a[-1] - a[0]), len(a) - 2, u, a.tolist(), int(s))
                for a, u, s in zip(self.axes, uniform, strides, strict=True)
            ],
            py_offsets=((bits * strides).sum(axis=1)).tolist(),
            py_flat=array.array("d", self.values.reshape(-1).tobytes()),
        )

    # ------------------------------------------------------------------ lookup

    @property
    def shape(self) -> tuple[int, ...]:
        """The grid's shape (nodes per axis)."""
        return self.values.shape

    def __call__(self, Xq: Any) -> float | np.ndarray:
        """Interpolated output: a float for one 1-D query of length d, else an array (q,)."""
        if isinstance(Xq, (list, tuple)) and len(Xq) == self._fast["d"] and np.ndim(Xq[0]) == 0:
            return self._lookup_one(Xq)
        Xq = np.asarray(Xq, dtype=np.float64)
        if Xq.ndim == 1:
            return self._lookup_one(Xq.tolist()) if Xq.shape[0] == self._fast["d"] else self.lookup(Xq)
        return self.lookup(Xq)

    def _lookup_one(self, x: list[float] | tuple[float, ...]) -> float:
        """One query, pure Python: clamp, locate the cell, reduce the 2^d corners axis by axis."""
        base, frac = 0, []
        for j, (lo, hi, inv, imax, uniform, nodes, stride) in enumerate(self._fast["py"]):
            v = float(x[j])
            if v - v != 0.0:  # NaN or inf (as the batched path, which refuses both)
                kind = "NaN" if v != v else "inf"
                raise ValueError(f"table {self.name!r}: query contains {kind} at column {j} ({self.inputs[j]})")
            v = lo if v < lo else hi if v > hi else v
            if uniform:
                pos = (v - lo) * inv
                i = int(pos)
                i = imax if i > imax else i
                t = pos - i
            else:
                i = min(imax, bisect.bisect_right(nodes, v) - 1)
                t = (v - nodes[i]) / (nodes[i + 1] - nodes[i])
            base += i * stride
            frac.append(t)
        flat = self._fast["py_flat"]
        vals = [flat[base + o] for o in self._fast["py_offsets"]]
        for t in reversed(frac):  # the last axis is the lowest bit: neighbours pair up as (even, odd)
            vals = [a + t * (b - a) for a, b in zip(vals[0::2], vals[1::2], strict=True)]
        return vals[0]

    def lookup(self, Xq: Any, return_confidence: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Vectorised lookup of queries (q, d) (or one 1-D query); queries are clamped to the grid.

        With ``return_confidence`` also the interpolated node confidence, 0 where a query was clamped.
        """
        f = self._fast
        Xq = as_queries(f"query to table {self.name!r}", Xq, f["d"])
        xc = np.clip(Xq, f["lo"], f["hi"])
        idx = np.empty(Xq.shape, dtype=np.int64)
        t = np.empty(Xq.shape)
        for j, a in enumerate(self.axes):
            if f["uniform"][j]:
                pos = (xc[:, j] - f["lo"][j]) * f["inv_step"][j]
                idx[:, j] = np.minimum(pos.astype(np.int64), f["n"][j] - 2)
                t[:, j] = pos - idx[:, j]
            else:
                i = np.clip(np.searchsorted(a, xc[:, j], side="right") - 1, 0, f["n"][j] - 2)
                idx[:, j] = i
                t[:, j] = (xc[:, j] - a[i]) / (a[i + 1] - a[i])
        corner = idx @ f["strides"]
        flat_idx = corner[:, None] + f["offsets"][None, :]
        w = np.where(f["bits"][None, :, :], t[:, None, :], 1.0 - t[:, None, :]).prod(axis=2)  # (q, 2^d)
        out = np.einsum("qc,qc->q", w, f["flat"][flat_idx])
        if not return_confidence:
            return out
        conf = np.einsum("qc,qc->q", w, f["flat_conf"][flat_idx])
        inside = np.all((Xq >= f["lo"]) & (Xq <= f["hi"]), axis=1)
        return out, np.where(inside, conf, 0.0)

    # ------------------------------------------------------------------ file

    def metadata(self) -> dict[str, Any]:
        """The JSON metadata stored with the arrays (without the content hash)."""
        return {
            "format_version": FORMAT_VERSION,
            "name": self.name,
            "inputs": list(self.inputs),
            "output": self.output,
            "shape": list(self.shape),
            "params": self.params.to_dict(),
            "metrics": self.metrics,
            "data_hash": self.data_hash,
        }

    def content_hash(self) -> str:
        """sha256 of the metadata (canonical JSON) and every array's dtype, shape and bytes."""
        return content_sha256(self.metadata(), self._arrays())

    def _arrays(self) -> dict[str, np.ndarray]:
        arrays = {"values": self.values, "confidence": self.confidence}
        arrays.update({f"axis_{j}": a for j, a in enumerate(self.axes)})
        return arrays

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the table to ``path`` (.npz) atomically; returns the path."""
        path = Path(path)
        meta = self.metadata()
        meta["content_sha256"] = self.content_hash()
        payload = {"meta": np.array([json.dumps(meta, sort_keys=True)]), **self._arrays()}
        with atomic_path(path) as tmp, tmp.open("wb") as fh:  # a file object: numpy appends no ".npz"
            np.savez_compressed(fh, allow_pickle=False, **payload)
        return path


# The metadata the content hash covers (MBLTable.metadata), and all the keys a file's metadata has.
HASHED_META_KEYS = ("data_hash", "format_version", "inputs", "metrics", "name", "output", "params", "shape")
_META_KEYS = (*HASHED_META_KEYS, "content_sha256")


def content_sha256(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> str:
    """The content hash of a table: sha256 of the metadata's :data:`HASHED_META_KEYS` as canonical JSON
    (``json.dumps(..., sort_keys=True)``), then for each array in order (``values``, ``confidence``,
    ``axis_0`` ...) ``"<name>|<dtype>|<shape tuple>"`` and its bytes in C order. The native plugin
    (``native/mbl_table.cc``) computes the same from the file."""
    h = hashlib.sha256(json.dumps({k: meta[k] for k in HASHED_META_KEYS}, sort_keys=True).encode())
    for name, arr in arrays.items():
        h.update(f"{name}|{arr.dtype.str}|{arr.shape}".encode())
        h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()


def load_table(path: str | os.PathLike[str]) -> MBLTable:
    """Read a table written by :meth:`MBLTable.save`, checking it as the native plugin does.

    The rules, in order (``native/mbl_table.cc`` applies the same, so both backends refuse the
    same files): a zip of ``.npy`` arrays (no pickles) whose ``meta`` is one JSON object; format
    version; every metadata key; every array present with the shape the metadata gives, dtype
    float64 (``<f8``) and C order, no other dtype in the file; the content hash
    (:func:`content_sha256`); finite values; axes of >= 2 strictly increasing nodes; valid LWR
    parameters. Raises FileNotFoundError for a missing file and :class:`TableFileError` (naming the
    file and the problem) for anything else wrong with it.
    """
    path = Path(path)
    if not os.path.lexists(path):
        raise FileNotFoundError(f"MBL table file {path} does not exist")
    if not path.is_file():
        raise TableFileError(f"MBL table file {path} is not a regular file")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except Exception as exc:  # zip, pickle-refusal and I/O errors all mean: not a usable table file
        raise TableFileError(f"MBL table file {path} is corrupt or not a table file: {exc}") from exc
    meta_array = arrays.pop("meta", None)
    if meta_array is None:
        raise TableFileError(f"MBL table file {path}: array 'meta' is missing")
    if meta_array.shape != (1,) or meta_array.dtype.kind != "U":
        raise TableFileError(f"MBL table file {path}: 'meta' is not one JSON string")
    try:
        meta = json.loads(str(meta_array[0]))
    except ValueError as exc:
        raise TableFileError(f"MBL table file {path}: metadata is not valid JSON: {exc}") from exc
    _check_meta(path, meta, arrays)
    d = len(meta["inputs"])
    hashed = {"values": arrays["values"], "confidence": arrays["confidence"]}
    hashed.update({f"axis_{j}": arrays[f"axis_{j}"] for j in range(d)})
    if content_sha256(meta, hashed) != meta["content_sha256"]:
        raise TableFileError(f"MBL table file {path}: content hash mismatch (the file was altered or is corrupt)")
    for name, arr in hashed.items():
        if not np.all(np.isfinite(arr)):
            raise TableFileError(f"MBL table file {path}: array {name!r} holds non-finite numbers")
    for j in range(d):
        axis = arrays[f"axis_{j}"]
        if len(axis) < 2:
            raise TableFileError(f"MBL table file {path}: axis {j} has fewer than 2 nodes")
        if not np.all(np.diff(axis) > 0):
            raise TableFileError(f"MBL table file {path}: axis {j} is not strictly increasing")
    try:
        return MBLTable(
            name=meta["name"],
            inputs=tuple(meta["inputs"]),
            output=meta["output"],
            axes=tuple(arrays[f"axis_{j}"] for j in range(d)),
            values=arrays["values"],
            confidence=arrays["confidence"],
            params=LWRParams.from_dict(meta["params"]),
            metrics=meta["metrics"],
            data_hash=meta["data_hash"],
        )
    except (ValueError, TypeError, KeyError) as exc:
        raise TableFileError(f"MBL table file {path} holds an invalid table: {exc}") from exc


def _check_meta(path: Path, meta: Any, arrays: dict[str, np.ndarray]) -> None:
    """Version, keys and the arrays' shapes, dtypes and order against the metadata."""
    if not isinstance(meta, dict):
        raise TableFileError(f"MBL table file {path}: metadata is not a JSON object")
    version = meta.get("format_version")
    if isinstance(version, bool) or version != FORMAT_VERSION:
        raise TableFileError(
            f"MBL table file {path} has format version {version!r}; this hexgym reads version {FORMAT_VERSION}"
            " (rebuild the table)"
        )
    missing = [k for k in _META_KEYS if k not in meta]
    if missing:
        raise TableFileError(f"MBL table file {path}: metadata lacks {missing}")
    inputs, shape = meta["inputs"], meta["shape"]
    if not isinstance(inputs, list) or not all(isinstance(s, str) for s in inputs):
        raise TableFileError(f"MBL table file {path}: 'inputs' is not a list of names")
    if not isinstance(shape, list) or not all(isinstance(n, int) and not isinstance(n, bool) for n in shape):
        raise TableFileError(f"MBL table file {path}: 'shape' is not a list of whole numbers")
    if not isinstance(meta["content_sha256"], str):
        raise TableFileError(f"MBL table file {path}: metadata lacks 'content_sha256'")
    shape = tuple(shape)
    d = len(inputs)
    if len(shape) != d:
        raise TableFileError(f"MBL table file {path}: {d} inputs but a {len(shape)}-D shape {shape}")
    expected = {"values": shape, "confidence": shape, **{f"axis_{j}": (shape[j],) for j in range(d)}}
    for name, want in expected.items():
        if name not in arrays:
            raise TableFileError(f"MBL table file {path}: array {name!r} is missing")
        if arrays[name].shape != want:
            raise TableFileError(
                f"MBL table file {path}: array {name!r} has shape {arrays[name].shape}, expected {want}"
            )
    for name, arr in arrays.items():
        if arr.dtype.str != "<f8":
            raise TableFileError(f"MBL table file {path}: {name}.npy has dtype {arr.dtype.str}, expected <f8")
        if not arr.flags.c_contiguous:
            raise TableFileError(f"MBL table file {path}: {name}.npy is not in C order")


def resolve_tables(tables: str | os.PathLike[str], option: str = "tables") -> tuple[str, Path | None]:
    """(table set, directory) of a ``tables`` value: a set's name (the packaged tables: directory None), or a fitted
    model's directory (with ``provenance.json``, which names its set); ValueError in one line for anything else."""
    if isinstance(tables, str) and tables in TABLE_SETS:
        return tables, None
    if isinstance(tables, (str, os.PathLike)) and Path(tables).is_dir():
        held = model_table_set(tables)
        if held is not None:
            return held, Path(tables)
    raise ValueError(f"{option} must be one of {tuple(TABLE_SETS)}, got {tables!r} (or a fitted model's directory, "
                     f"one with {MODEL_PROVENANCE}, from `hexgym fit --logs`)")  # fmt: skip


# what of a unit's hydraulics the learned model applies (the rest is the data sheet's)
MODEL_HYDRAULICS = ("pump.max_flow_m3s", "relief.main_pa", "relief.swing_pa", "relief.line_pa")


def model_hydraulics(directory: str | os.PathLike[str] | None):
    """A fitted model's unit hydraulics (its ``provenance.json``'s ``hydraulics``, in the hydraulics file's format,
    :mod:`hexgym.hydraulics.overrides`): HydraulicsOverrides, or None for packaged tables or a model without any.
    Only :data:`MODEL_HYDRAULICS` may be set (the learned valve is the unit's own); ValueError naming the key."""
    from hexgym.hydraulics.overrides import parse_hydraulics

    path = Path(directory) / MODEL_PROVENANCE if directory is not None else None
    if path is None or not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8")).get("hydraulics")
    except (ValueError, OSError, AttributeError) as exc:
        raise TableFileError(f"{path}: not a model's provenance (a JSON object): {exc}") from None
    if not data:
        return None
    overrides = parse_hydraulics(data, f"{path} hydraulics")
    given = {f"{section}.{key}" for section, body in data.items() for key in (body or {})}
    other = sorted(given - set(MODEL_HYDRAULICS))
    if other:
        raise TableFileError(f"{path}: hydraulics.{other[0]}: the learned model applies only {MODEL_HYDRAULICS}")
    return overrides


def check_model_table_set(directory: str | os.PathLike[str], table_set: str) -> None:
    """TableFileError where ``directory`` is a fitted model of another table set than ``table_set``."""
    held = model_table_set(directory)
    if held is not None and held != table_set:
        raise TableFileError(f"{directory}: a model of the {held} table set ({MODEL_PROVENANCE}); the {table_set} "
                             "tables are needed here")  # fmt: skip


def packaged_tables_dir(table_set: str = DEFAULT_TABLE_SET) -> Path:
    """Where the fitted tables of ``table_set`` ship inside the package (``hexgym/mbl_tables/<set>``)."""
    if table_set not in TABLE_SETS:
        raise ValueError(f"table set must be one of {tuple(TABLE_SETS)}, got {table_set!r}")
    return Path(str(resources.files("hexgym") / "mbl_tables" / table_set))


def require_packaged(table_set: str) -> Path:
    """The packaged tables' directory of ``table_set``; FileNotFoundError saying how to make them if the
    package has none (an install without its tables)."""
    directory = packaged_tables_dir(table_set)
    if not directory.is_dir():
        raise FileNotFoundError(
            f"the {table_set} tables are not shipped: make them with `hexgym collect --tables {table_set} --out DATA`"
            f" then `hexgym fit --tables {table_set} --data DATA` (which writes tables/{table_set}/), and pass that"
            " directory (or fit with --out naming the package's mbl_tables/ to ship them)"
        )
    return directory


def table_path(name: str, directory: str | Path | None = None, table_set: str = DEFAULT_TABLE_SET) -> Path:
    """The file of table ``name`` (in ``directory``, default the packaged tables of ``table_set``)."""
    return Path(directory or packaged_tables_dir(table_set)) / f"{name}.npz"


MODEL_PROVENANCE = "provenance.json"  # a fitted model's directory (``hexgym fit --logs``) holds this beside its tables


def model_table_set(directory: str | os.PathLike[str]) -> str | None:
    """The table set a fitted model's directory holds (its ``provenance.json``), or None for a directory without
    one; TableFileError naming the file where it cannot be read or names no known set."""
    path = Path(directory) / MODEL_PROVENANCE
    if not path.is_file():
        return None
    try:
        table_set = json.loads(path.read_text(encoding="utf-8")).get("table_set")
    except (ValueError, OSError, AttributeError) as exc:
        raise TableFileError(f"{path}: not a model's provenance (a JSON object with 'table_set'): {exc}") from None
    if table_set not in TABLE_SETS:
        raise TableFileError(f"{path}: table_set {table_set!r} is none of {tuple(TABLE_SETS)}")
    return table_set


def load_tables(directory: str | Path | None = None, table_set: str = DEFAULT_TABLE_SET) -> dict[str, MBLTable]:
    """The tables of ``table_set`` (from ``directory``, default the packaged ones), each checked by
    :func:`load_table` and against :mod:`hexgym.mbl.schema`: a file whose inputs or output differ fails
    naming the file and what differs (e.g. a table fitted to another schema's inputs). A fitted model's directory
    (with ``provenance.json``) of another set is refused naming both."""
    if table_set not in TABLE_SETS:
        raise ValueError(f"table set must be one of {tuple(TABLE_SETS)}, got {table_set!r}")
    if directory is None:
        require_packaged(table_set)
    else:
        check_model_table_set(directory, table_set)
    tables = {}
    for name in TABLE_SETS[table_set]:
        path = table_path(name, directory, table_set)
        table = load_table(path)
        if table.name != name:  # as the native plugin checks
            raise TableFileError(f"MBL table file {path} holds table {table.name!r}, expected {name!r}")
        try:
            check_table_schema(str(path), name, table.inputs, table.output, table_set)
        except ValueError as exc:  # named as every other problem of a table file
            raise TableFileError(f"MBL table file {exc}") from None
        tables[name] = table
    return tables

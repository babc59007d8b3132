"""Checks of a collected data set file (``<table>.npz``, written by :mod:`hexgym_lab.mbl.collect`) before fitting.

A data set holds ``X`` (n, d) float, ``y`` (n,) float, ``inputs`` (d,) names, ``output`` (a name)
and ``episode`` (n,) integers, among others (see :func:`hexgym_lab.mbl.collect.collect`). A file that
is missing, not an ``.npz`` archive (or one holding pickles), lacks one of these arrays, has them in
the wrong shape or type, or holds a non-finite number is refused with a ValueError naming the file
(FileNotFoundError for a missing one) before minutes of fitting start. Whether the inputs and output
are the table's is checked where the data are loaded (:func:`hexgym_lab.mbl.fit.load_table_data`).
"""

# ruff: noqa: N806 - X follows the statistics notation

from __future__ import annotations

from pathlib import Path

import numpy as np

from hexgym.files import check_input_file

MIN_EPISODES = 2  # a fit selects on some episodes and measures on others


def check_dataset_file(path: str | Path) -> int:
    """The number of samples in the data set at ``path``, or a ValueError naming the file and the problem."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"data set {path} does not exist (run `hexgym collect`)")
    check_input_file(path, "data set")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in ("X", "y", "inputs", "output", "episode") if k in data.files}
    except Exception as exc:  # zip, pickle-refusal and I/O errors: not a usable data set
        raise ValueError(f"data set {path} is corrupt or not an .npz data set ({exc})") from None
    missing = [k for k in ("X", "y", "inputs", "output", "episode") if k not in arrays]
    if missing:
        raise ValueError(f"data set {path} lacks the array(s) {missing}")
    X, y, inputs, output, episode = (arrays[k] for k in ("X", "y", "inputs", "output", "episode"))
    if X.ndim != 2 or X.dtype.kind != "f" or X.shape[0] < 1:
        raise ValueError(f"data set {path}: 'X' must be a float array of n >= 1 rows by d inputs, got "
                         f"{X.dtype} {X.shape}")  # fmt: skip
    n, d = X.shape
    if y.shape != (n,) or y.dtype.kind != "f":
        raise ValueError(f"data set {path}: 'y' must be {n} floats, one per row of X, got {y.dtype} {y.shape}")
    if episode.shape != (n,) or episode.dtype.kind not in "iu":
        raise ValueError(f"data set {path}: 'episode' must be {n} integers, got {episode.dtype} {episode.shape}")
    if inputs.shape != (d,) or inputs.dtype.kind != "U" or output.shape != () or output.dtype.kind != "U":
        raise ValueError(f"data set {path}: 'inputs' must name the {d} columns of X and 'output' the output")
    if len(np.unique(episode)) < MIN_EPISODES:
        raise ValueError(f"data set {path}: {len(np.unique(episode))} episode(s); fitting holds out whole episodes "
                         f"and needs at least {MIN_EPISODES} (collect more samples)")  # fmt: skip
    for name, values in (("X", X), ("y", y)):
        bad = np.argwhere(~np.isfinite(values))
        if bad.size:
            raise ValueError(f"data set {path}: {name!r} holds a non-finite number at row {bad[0][0]}"
                             f" ({len(bad)} in all)")  # fmt: skip
    return n


def npz_kind(path: str | Path) -> str | None:
    """What the ``.npz`` at ``path`` holds, from its member names alone: "data set" (``X``), "table"
    (``meta`` and ``values``), None for anything else or no file."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
    except (OSError, zipfile.BadZipFile, ValueError):
        return None
    if "X.npy" in names:
        return "data set"
    if {"meta.npy", "values.npy"} <= names:
        return "table"
    return None


def refuse_other_npz(directory: str | Path, names: list[str] | tuple[str, ...], writes: str) -> None:
    """ValueError when ``directory/<name>.npz`` holds something other than ``writes`` ("data set" or "table"):
    collected data sets and fitted tables share their file names, and one must not replace the other."""
    for name in names:
        path = Path(directory) / f"{name}.npz"
        kind = npz_kind(path) if path.is_file() else None
        if kind is not None and kind != writes:
            raise ValueError(f"{path} is a {'fitted table' if kind == 'table' else 'collected data set'}; this "
                             f"command writes {writes}s and would replace it (give another --out)")  # fmt: skip

"""File output and input checks: atomic writes, and paths refused up front, before any work.

Atomic output: a reader sees the old file or the complete new one, never half of one, and a failed
write (full disk, an exception) leaves the old file as it was. :func:`check_output_file` and
:func:`check_output_dir` refuse, before a command starts its work, an output that could not be
written: a directory where a file goes (or a file where a directory goes), a path under a file, a
read-only file or directory, an output that is also one of the command's inputs.
:func:`check_input_file` refuses an input that is missing, a directory or unreadable. A path is
read-only when this user may not write it or when it has no write permission bits at all (so a file
marked read-only is respected even by root); unreadable likewise.
"""

from __future__ import annotations

import json
import os
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a unique temporary path beside ``path`` (same suffix); on success it replaces ``path``.

    The one way hexgym writes output files: on an exception the temporary file is removed and
    ``path`` is untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}")
    os.close(fd)
    os.chmod(name, 0o644)  # mkstemp makes it owner-only; these are ordinary (often packaged) files
    tmp = Path(name)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_json(path: str | Path, data: object) -> Path:
    """Write ``data`` as indented JSON, atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2))
    return Path(path)


def save_figure(fig: object, path: str | Path, dpi: int = 90) -> Path:
    """Save a matplotlib figure atomically and close it."""
    import matplotlib.pyplot as plt

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi)
    plt.close(fig)
    return Path(path)


class PathError(ValueError):
    """An input or output path that cannot be used; the message names the path and the problem."""


def _nearest_existing(path: Path) -> Path:
    """``path`` or its nearest ancestor that exists (as a link, a file or a directory)."""
    while not os.path.lexists(path) and path != path.parent:
        path = path.parent
    return path


def _may_write(path: Path) -> bool:
    return os.access(path, os.W_OK) and bool(path.stat().st_mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))


def _may_read(path: Path) -> bool:
    return os.access(path, os.R_OK) and bool(path.stat().st_mode & (stat.S_IRUSR | stat.S_IRGRP | stat.S_IROTH))


def _check_parents(path: Path, what: str) -> None:
    """The folder that will hold ``path`` exists or can be made, and may be written."""
    existing = _nearest_existing(path.parent)
    if not existing.is_dir():
        raise PathError(f"{what} {path}: {existing} is a file, not a directory")
    if not (_may_write(existing) and os.access(existing, os.X_OK)):
        raise PathError(f"{what} {path}: cannot write in {existing} (read-only)")


def _same(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))
    except OSError:
        return False


def check_output_file(
    path: str | os.PathLike[str],
    what: str = "output",
    inputs: tuple[str | os.PathLike[str] | None, ...] = (),
    source_what: str = "an input or another output",
) -> Path:
    """``path`` as a Path, or :class:`PathError` if a file cannot be written there (see the module).

    ``inputs``: the command's other files (its inputs and its other outputs), which ``path`` must not be.
    """
    path = Path(path)
    if str(path) == "" or path.name in ("", ".", ".."):
        raise PathError(f"{what} {str(path)!r}: not a file name")
    if path.is_dir():
        raise PathError(f"{what} {path} is a directory; give a file name")
    if os.path.lexists(path) and not path.is_file():
        raise PathError(f"{what} {path} exists and is not a regular file")
    for source in inputs:
        if source is not None and _same(path, Path(source)):
            raise PathError(f"{what} {path} is also {source_what} of this command; one would destroy the other")
    _check_parents(path, what)
    if path.is_file() and not _may_write(path):
        raise PathError(f"{what} {path} is read-only; hexgym does not replace it")
    return path


def check_output_dir(
    path: str | os.PathLike[str], what: str = "output directory", inputs: tuple[str | os.PathLike[str] | None, ...] = ()
) -> Path:
    """``path`` as a Path, or :class:`PathError` if files cannot be written in it (see the module).

    ``inputs``: the command's input files and directories, which ``path`` must be none of.
    """
    path = Path(path)
    if str(path) == "":
        raise PathError(f"{what}: empty path")
    for source in inputs:
        if source is not None and _same(path, Path(source)):
            raise PathError(f"{what} {path} is also an input of this command; its files would replace the input's")
    if os.path.lexists(path) and not path.is_dir():
        raise PathError(f"{what} {path} is a file, not a directory")
    if path.is_dir():
        if not (_may_write(path) and os.access(path, os.X_OK)):
            raise PathError(f"{what} {path} is read-only")
        return path
    _check_parents(path / "x", what)
    return path


def check_input_file(path: str | os.PathLike[str], what: str = "input file") -> Path:
    """``path`` as a Path: an existing, readable regular file (FileNotFoundError or :class:`PathError`)."""
    path = Path(path)
    if not os.path.lexists(path):
        raise FileNotFoundError(f"{what} {path} does not exist")
    if path.is_dir():
        raise PathError(f"{what} {path} is a directory, not a file")
    if not path.is_file():
        raise PathError(f"{what} {path} is not a regular file (a broken link, a device or a pipe)")
    if not _may_read(path):
        raise PathError(f"{what} {path} is not readable (permission denied)")
    return path


def check_input_dir(path: str | os.PathLike[str], what: str = "input directory") -> Path:
    """``path`` as a Path: an existing, readable directory (FileNotFoundError or :class:`PathError`)."""
    path = Path(path)
    if not os.path.lexists(path):
        raise FileNotFoundError(f"{what} {path} does not exist")
    if not path.is_dir():
        raise PathError(f"{what} {path} is a file, not a directory")
    if not (_may_read(path) and os.access(path, os.X_OK)):
        raise PathError(f"{what} {path} is not readable (permission denied)")
    return path

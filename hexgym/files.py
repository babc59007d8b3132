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

import contextlib
import errno
import json
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a unique temporary path beside ``path`` (same suffix); on success it replaces ``path``.

    The one way hexgym writes output files: on an exception the temporary file is removed and
    ``path`` is untouched. An OSError of the write (a full disk) names ``path``, not the temporary.
    """
    with atomic_paths(path) as (tmp,):
        yield tmp


@contextmanager
def atomic_paths(*paths: str | Path) -> Iterator[list[Path]]:
    """:func:`atomic_path` for files that are one output (a video and its snapshot, a model and its normaliser).

    Yields a temporary path beside each; only once the block has written them all are they renamed over the
    ``paths``, one after the other. A failure or Ctrl-C in the block leaves every old file as it was. The renames
    write no data (a full disk does not stop them); should one still fail, after others succeeded, the OSError
    says which files are new and which old.
    """
    paths = tuple(Path(p) for p in paths)
    temporaries: list[Path] = []
    try:
        for path in paths:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}")
            os.close(fd)
            temporaries.append(Path(name))
            os.chmod(name, _mode_for(path))  # mkstemp makes it owner-only
        try:
            yield list(temporaries)
        except OSError as exc:
            _name_output(exc, dict(zip(temporaries, paths, strict=True)))
            raise
        for i, (tmp, path) in enumerate(zip(temporaries, paths, strict=True)):
            try:
                os.replace(tmp, path)
            except OSError as exc:
                if i == 0:
                    _name_output(exc, {tmp: path})
                    raise
                new = ", ".join(str(p) for p in paths[:i])
                raise OSError(exc.errno, f"{exc.strerror}; {new} already replaced, the rest not: a mixed set",
                              str(path)) from exc  # fmt: skip
    finally:
        for tmp in temporaries:
            tmp.unlink(missing_ok=True)


_SPACE_ERRORS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)  # a full disk, a quota, a file size limit


def _name_output(exc: OSError, outputs: dict[Path, Path]) -> None:
    """Make an OSError of a write into a temporary (or staging) path name the output it stands for: a write that
    fails on a full disk names no file (``exc.filename`` None), or the temporary one."""
    if exc.filename is None:
        if exc.errno in _SPACE_ERRORS and len(outputs) == 1:
            exc.filename = str(next(iter(outputs.values())))
        return
    written = str(exc.filename)
    for tmp, path in outputs.items():
        if written == str(tmp) or written.startswith(f"{tmp}{os.sep}"):
            exc.filename = str(path) + written[len(str(tmp)) :]
            return


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _mode_for(path: Path, directory: bool = False) -> int:
    """The permission bits a replacement of ``path`` gets: those of the file it replaces (a private file
    stays private), else what a new file gets under this process's umask."""
    try:
        return stat.S_IMODE(path.stat().st_mode)
    except OSError:
        return (0o777 if directory else 0o666) & ~_umask()


@contextmanager
def staged_dir(path: str | Path, keep: bool = True) -> Iterator[Path]:
    """Yield a temporary directory beside ``path``; on success it replaces ``path`` as a whole.

    For outputs made of several files (a table set, data sets, a validation report): a reader, or a run
    interrupted or failed half way, sees the old set or the complete new one, never a mix. ``keep``: the
    staging directory starts with ``path``'s files (hard links where possible, so a large folder costs
    nothing; hexgym replaces files, it never writes into one), so files the command does not write
    survive. On an exception (Ctrl-C included) the staging directory is removed and ``path`` is as it was.
    The swap is one atomic exchange on Linux (``renameat2``), else two renames.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        try:
            if keep and path.is_dir():
                shutil.copytree(path, tmp, symlinks=True, dirs_exist_ok=True, copy_function=_link_or_copy)
            os.chmod(tmp, _mode_for(path, directory=True))
            yield tmp
        except OSError as exc:  # named after the output, not the staging folder
            _name_output(exc, {tmp: path})
            raise
        _swap_in(tmp, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _link_or_copy(source: str, target: str) -> None:
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)


def _swap_in(new: Path, path: Path) -> None:
    """Put directory ``new`` at ``path``; the old ``path`` (if any) ends up at ``new`` (for removal)."""
    if not os.path.lexists(path):
        os.rename(new, path)
        new.mkdir()
        return
    if _exchange(new, path):
        return
    old = new.with_name(new.name + ".old")
    os.rename(path, old)
    try:
        os.rename(new, path)
    except BaseException:
        os.rename(old, path)
        raise
    os.rename(old, new)


def _exchange(a: Path, b: Path) -> bool:
    """Swap ``a`` and ``b`` atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False where unavailable."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    return False


class RunDirectoryInUseError(RuntimeError):
    """A run directory another process is writing (its lock file is held)."""


@contextmanager
def run_lock(directory: str | Path, what: str = "run directory") -> Iterator[Path]:
    """Hold ``directory/.lock`` (an exclusive ``flock``) while a run writes ``directory``; a second run
    into the same directory is refused with :class:`RunDirectoryInUseError`, not interleaved with the first. The
    lock goes with the process: a killed run leaves nothing to clean up."""
    import fcntl

    directory = Path(directory)
    made = [d for d in (directory, *directory.parents) if not os.path.lexists(d)]  # folders this lock makes
    directory.mkdir(parents=True, exist_ok=True)
    lock = directory / ".lock"
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise RunDirectoryInUseError(
                f"{what} {directory} is in use by another run (process holding {lock}); wait for it or give "
                "another directory"
            ) from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield directory
    finally:
        if made and os.listdir(directory) == [".lock"]:  # a run that wrote nothing leaves no folder behind
            lock.unlink(missing_ok=True)
            with contextlib.suppress(OSError):
                for folder in made:
                    folder.rmdir()
        os.close(fd)


def write_json(path: str | Path, data: object) -> Path:
    """Write ``data`` as indented JSON, atomically (numpy's scalars as the numbers they hold). The text is made
    before the file is touched: data that cannot be written leaves no file."""
    text = json.dumps(data, indent=2, default=_json_scalar)
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def _json_scalar(value: object) -> object:
    """A numpy scalar as its Python number (``json.dumps``'s ``default``); anything else is refused as json does."""
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"Object of type {type(value).__name__} is not JSON serializable")


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

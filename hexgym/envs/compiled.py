"""How the environments' kernels are compiled (:data:`jit`), and the maintenance step that drops stale caches.

Every compiled function of the loading task (:mod:`.earthwork`, :mod:`.task`, :mod:`.sites`, :mod:`.vector`) is
``numba.njit(cache=True, nogil=True)``: compiled on the first call of a fresh install and loaded from
``__pycache__`` later; no fastmath, so one site and N sites give the same floats.

numba checks a cached function against its own file only (time stamp and size), not against the functions it
calls or the module constants it froze at compile time: after an edit of :mod:`.earthwork` or
:mod:`hexgym.machine.parameters`, the cached functions of :mod:`.task` would run the old arithmetic. An
installed package is never edited (an upgrade writes every file anew, so each cache misses), so only a
source checkout needs :func:`drop_stale_caches`: the test suite runs it at its start (``tests/conftest.py``),
and ``python -m hexgym.envs.compiled`` runs it by hand. Importing hexgym never runs it.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numba

jit = numba.njit(cache=True, nogil=True)  # every compiled function of the task: cached on disk, no fastmath

PACKAGE = Path(__file__).resolve().parents[1]  # hexgym/
STAMP = Path("envs", "__pycache__", "numba-sources.sha256")  # under the package: what the caches were made from


def drop_stale_caches(package: Path = PACKAGE) -> bool:
    """Delete numba's cached functions under ``package`` when any of its sources changed since they were stamped;
    returns whether it did.

    The package's sources (names, sizes, modification times) are stamped beside the caches; recompiling all takes
    ~6 s. A package whose caches cannot be written (a read-only install) is left alone: numba caches its functions
    elsewhere then, and a new install changes every file's time stamp.
    """
    sources = sorted(path for path in package.rglob("*.py") if "__pycache__" not in path.parts)
    text = "\n".join(f"{path.relative_to(package)} {path.stat().st_size} {path.stat().st_mtime_ns}" for path in sources)
    stamp = package / STAMP
    digest = hashlib.sha256(text.encode()).hexdigest()
    try:
        if stamp.is_file() and stamp.read_text() == digest:
            return False
        for cached in (*package.rglob("*.nbi"), *package.rglob("*.nbc")):
            cached.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        partial = stamp.with_name(f"{stamp.name}.{digest[:8]}.tmp")
        partial.write_text(digest)
        partial.replace(stamp)
    except OSError:
        return False
    return True


if __name__ == "__main__":
    print("dropped stale compiled functions" if drop_stale_caches() else "compiled functions are current")

"""Test set-up: offscreen rendering through EGL must be chosen before mujoco is imported; the test process
ends without Python's finalisation.

One pytest process starts and stops several local Rays (collection, validation, evaluation, RLlib), EGL
contexts and MuJoCo thread pools. Ray's core worker can leave threads behind that crash the interpreter's
teardown after a session was shut down and another started in the same process (ray-project/ray#31145):
a segmentation fault after every test passed. That teardown is no part of what is tested; each command's
own exit is, by the tests that run it in a subprocess and check its status.
"""

import os
import sys

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

from hexgym.envs.compiled import drop_stale_caches  # noqa: E402  (after MUJOCO_GL: importing hexgym imports mujoco)

# A checkout's sources change between runs; numba's caches check only their own file (hexgym.envs.compiled)
drop_stale_caches()

_EXIT_STATUS = pytest.StashKey[int]()


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    session.config.stash[_EXIT_STATUS] = int(exitstatus)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config: pytest.Config) -> None:
    """After every report is written: leave with the session's status, skipping the interpreter's teardown."""
    if _EXIT_STATUS not in config.stash:  # a run that never reached its session's end: exit as pytest would
        return
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(config.stash[_EXIT_STATUS])

"""The loading task written once over N sites (hexgym.envs.task): compiled, cached, and one site's step leaves the
others alone."""

import numba
import numpy as np
from numba.core.caching import NullCache

from hexgym.envs import earthwork, task
from hexgym.envs.loading import sample_start
from hexgym.envs.sites import MachineSites, make_machine


def _dispatchers(module):
    return {name: obj for name, obj in vars(module).items() if isinstance(obj, numba.core.registry.CPUDispatcher)}


def test_compiled_functions_are_cached_on_disk_and_documented():
    found = _dispatchers(task) | _dispatchers(earthwork)
    assert {"plan", "begin_dig", "follow_resistance", "end_clear", "account", "finish", "observe", "dig"} <= set(found)
    for name, function in found.items():
        assert not isinstance(function._cache, NullCache), f"{name} is compiled without cache=True"
        assert not function.targetoptions.get("fastmath"), f"{name}: fastmath would make results depend on N"
        assert function.__doc__, f"{name} has no docstring"


def test_stepping_some_sites_leaves_the_others_untouched():
    machines = [make_machine("python", tool_contact_slots=task.CONTACT_SLOTS) for _ in range(3)]
    sites = MachineSites(machines)
    weights = dict.fromkeys(task.REWARD_TERMS, 1.0)
    t = task.LoadingTask(3, sites, 180.0, 13000.0, weights)
    rng = np.random.default_rng(0)
    t.start(np.arange(3), [task.SiteStart(*sample_start(rng)) for _ in range(3)])
    qpos, obs = sites.qpos.copy(), t.observe(np.arange(3))
    for _ in range(3):
        t.step(np.array([0, 2]), np.full((2, 4), 0.011))  # every spool fully open: the sites stepped move
    moved = [not np.array_equal(sites.qpos[i], qpos[i]) for i in range(3)]
    assert moved == [True, False, True]
    assert np.array_equal(sites.qpos[0], machines[0].physics.data.qpos)  # the gathered copy is current
    assert t.steps.tolist() == [3, 0, 3] and np.isclose(t.elapsed[0], 0.3)
    assert np.array_equal(t.observe(np.array([1]))[0], obs[1])


def test_compiled_stages_take_named_state_not_dozens_of_arrays():
    """The stages take the task's state by name (records, named tuples): a handful of arguments each."""
    import inspect

    for name, function in _dispatchers(task).items():
        count = len(inspect.signature(function.py_func).parameters)
        assert count <= 8, f"{name} takes {count} arguments"
    assert {"stores", "payload_kg", "tip_velocity", "cutting", "revision"} <= set(task.SITE.names)


def test_importing_hexgym_changes_no_file(tmp_path):
    """Importing hexgym and its environments writes and deletes nothing (numba's caches are swept only by the
    maintenance step, hexgym.envs.compiled.drop_stale_caches): checked with the sources' stamp made stale."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from hexgym.envs import compiled

    def files() -> dict[str, tuple[int, int]]:
        paths = (path for path in compiled.PACKAGE.rglob("*") if path.is_file() and path.suffix != ".pyc")
        return {str(path): (path.stat().st_size, path.stat().st_mtime_ns) for path in paths}

    earthwork.table_at(np.array([0.0, 1.0]), 0.0, 1.0, 0.5)  # a compiled function, cached on disk
    stamp = compiled.PACKAGE / compiled.STAMP
    kept = stamp.read_text() if stamp.is_file() else None
    stamp.parent.mkdir(exist_ok=True)
    stamp.write_text("stale")
    try:
        before = files()
        assert any(name.endswith(".nbi") for name in before)  # what a sweep would delete
        modules = "hexgym, hexgym.envs.loading, hexgym.envs.dig, hexgym.envs.reach, hexgym.envs.vector"
        env = {**os.environ, "PYTHONPATH": str(compiled.PACKAGE.parent)}
        subprocess.run([sys.executable, "-c", f"import {modules}"], check=True, env=env, cwd=tmp_path)
        assert files() == before and stamp.read_text() == "stale"
        assert not any(Path(tmp_path).iterdir())  # nor where it ran
    finally:
        if kept is None:
            stamp.unlink()
        else:
            stamp.write_text(kept)


def _protocol_members() -> set[str]:
    members = set(task.SitePhysics.__annotations__)
    return members | {name for name, value in vars(task.SitePhysics).items() if callable(value) and name[0] != "_"}


def test_both_kinds_of_site_implement_the_physics_protocol():
    """The single environment's sites and the batch both carry the start and the action (start, hold): the
    environments reach into no other object's private method."""
    import pytest

    from hexgym.envs.sites import BatchSites, native_world_model
    from hexgym.model.plugin import load_plugin

    assert {"start", "hold", "step", "control_period"} <= _protocol_members()
    kinds = [MachineSites([make_machine("python", tool_contact_slots=task.CONTACT_SLOTS)])]
    if not load_plugin():
        kinds.append(BatchSites(native_world_model(tool_contact_slots=task.CONTACT_SLOTS), 2, 1))
    for sites in kinds:
        missing = {name for name in _protocol_members() if not hasattr(sites, name)}
        assert not missing, f"{type(sites).__name__} lacks {sorted(missing)}"
    if len(kinds) == 1:
        pytest.skip("the native plugin is not built: the batch was not checked")

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

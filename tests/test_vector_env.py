"""The batched HexLoading-v0 (gymnasium.make_vec): the same results as single environments, its API, its errors."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

import hexgym  # noqa: F401 - registers HexLoading-v0
from hexgym.agents.scripted import ScriptedLoader
from hexgym.envs.loading import HexLoadingEnv
from hexgym.envs.vector import HexLoadingVectorEnv
from hexgym.hydraulics import fuel
from hexgym.interpolation import UniformTable
from hexgym.machine import parameters as p
from hexgym.machine.physics import payload_inertia
from hexgym_lab.bench import vector_steps_per_second

# the default backend ("auto": native when built, unless HEXGYM_BACKEND=python) and the Python one
BACKENDS = ["auto", "python"]


def _assert_same(tag, batched, single):
    """Equal exactly: values, shapes and dtypes (dicts key by key, as SyncVectorEnv builds them)."""
    if isinstance(single, tuple):
        for k, (b, s) in enumerate(zip(batched, single, strict=True)):
            _assert_same(f"{tag}[{k}]", b, s)
        return
    if isinstance(single, dict):
        assert batched.keys() == single.keys(), (tag, sorted(set(batched) ^ set(single)))
        for key in single:
            _assert_same(f"{tag}[{key!r}]", batched[key], single[key])
        return
    batched, single = np.asarray(batched), np.asarray(single)
    assert batched.shape == single.shape and batched.dtype == single.dtype, (tag, batched.dtype, single.dtype)
    differ = np.flatnonzero((batched != single).reshape(len(single), -1).any(axis=1))
    assert not len(differ), f"{tag}: environments {differ.tolist()} differ"


def _compare_with_single_envs(num_envs, steps, time_limit, seed=7, backend="auto", **weights):
    """Step make_vec(num_envs) and a SyncVectorEnv of HexLoadingEnv with the same seeds and actions: the scripted
    loader's on even sites (it digs and, given time, dumps), random ones on odd sites, one site driven into the
    ground (hard contacts). Returns the largest bucket, truck, spilled and contact figures seen, and the resets."""
    vec = gym.make_vec("HexLoading-v0", num_envs=num_envs, time_limit=time_limit, backend=backend, **weights)
    sync = gym.vector.SyncVectorEnv(
        [lambda: HexLoadingEnv(backend=backend, time_limit=time_limit, **weights)] * num_envs
    )
    assert isinstance(vec.unwrapped, HexLoadingVectorEnv)
    _assert_same("reset", vec.reset(seed=seed), sync.reset(seed=seed))
    loaders = [ScriptedLoader() if i % 2 == 0 else None for i in range(num_envs)]
    rng = np.random.default_rng(seed)
    seen = {"bucket_kg": 0.0, "truck_kg": 0.0, "spilled_kg": 0.0, "contact_impulse_ns": 0.0, "resets": 0}
    for t in range(steps):
        actions = rng.uniform(-1, 1, (num_envs, 4)).astype(np.float32)
        if t % 40 < 15:
            actions[num_envs - 1] = [0.0, -1.0, 1.0, 0.0]  # boom down, stick in: into the ground
        for i, loader in enumerate(loaders):
            if loader is not None:
                actions[i] = loader.act(sync.envs[i])
        batched, single = vec.step(actions), sync.step(actions)
        for name, b, s in zip(("obs", "reward", "terminated", "truncated", "info"), batched, single, strict=True):
            _assert_same(f"step {t} {name}", b, s)
        info = single[4]
        for key in ("bucket_kg", "truck_kg", "spilled_kg", "contact_impulse_ns"):
            if key in info:
                seen[key] = max(seen[key], float(info[key].max()))
        for i in np.flatnonzero(single[2] | single[3]):
            seen["resets"] += 1
            if loaders[i] is not None:
                loaders[i] = ScriptedLoader()
    vec.close()
    sync.close()
    return seen


@pytest.mark.parametrize("backend", BACKENDS)
def test_results_equal_single_envs_through_digging_contacts_and_autoreset(backend):
    # exactly equal, not approximately: a site steps as the single environment's machine does (the batch's
    # MjData as mj_step), and the task's compiled functions are the same for one site and for N
    seen = _compare_with_single_envs(num_envs=4, steps=160, time_limit=7.0, backend=backend)
    assert seen["bucket_kg"] > 50  # the scripted sites dug (only digging fills the bucket)
    assert seen["contact_impulse_ns"] > 0  # the site driven down hit the ground
    assert seen["resets"] >= 4  # every site's episode ended (t = 7 s) and restarted on the next step


def test_shaping_terms_and_dig_starts_equal_single_envs():
    shaping = {
        "reach_weight": 0.05,
        "load_weight": 0.3,
        "lift_weight": 0.2,
        "carry_weight": 0.3,
        "dig_start_share": 0.5,
    }
    seen = _compare_with_single_envs(num_envs=3, steps=130, time_limit=12.0, **shaping)
    assert seen["bucket_kg"] > 50 and seen["resets"] >= 3


def test_loaded_starts_equal_single_envs():
    shares = {"dig_start_share": 0.3, "loaded_start_share": 0.5, "carry_weight": 0.3}
    seen = _compare_with_single_envs(num_envs=3, steps=60, time_limit=2.0, **shares)
    assert seen["bucket_kg"] >= 1000.0 and seen["resets"] >= 6


@pytest.mark.slow
def test_results_equal_single_envs_through_loading_the_truck():
    seen = _compare_with_single_envs(num_envs=3, steps=450, time_limit=40.0)
    assert seen["truck_kg"] > 500 and seen["spilled_kg"] > 0  # the scripted site dumped into the bed


def test_make_vec_api_spaces_seeding_and_info_masks():
    vec = gym.make_vec("HexLoading-v0", num_envs=3, time_limit=0.2)
    single = HexLoadingEnv(time_limit=0.2)
    assert vec.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert vec.action_space.shape == (3, 4) and vec.observation_space.shape == (3, 23)
    assert vec.single_observation_space == single.observation_space
    assert vec.observation_space == batch_space(single.observation_space, 3)
    assert vec.action_space == batch_space(single.action_space, 3)
    obs, info = vec.reset(seed=[5, 9, 11])
    assert vec.observation_space.contains(obs)
    assert np.array_equal(obs[1], single.reset(seed=9)[0])
    assert info["_pile_kg"].all() and "fuel_l_step" not in info
    for _ in range(2):  # 0.2 s: the second step truncates every site
        obs, reward, terminated, truncated, info = vec.step(np.zeros((3, 4), np.float32))
    assert truncated.all() and not terminated.any() and info["_fuel_l_step"].all()
    obs, reward, terminated, truncated, info = vec.step(np.zeros((3, 4), np.float32))  # the autoreset step
    assert not (truncated.any() or reward.any()) and "fuel_l_step" not in info and (info["time_s"] == 0).all()
    assert np.array_equal(obs[1], single.reset()[0])  # site 1 goes on with its own generator, as after seed 9
    vec.close()


def test_bad_actions_name_the_environment():
    vec = gym.make_vec("HexLoading-v0", num_envs=3)
    with pytest.raises(RuntimeError, match="reset"):
        vec.step(np.zeros((3, 4)))
    vec.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(3, 4\)"):
        vec.step(np.zeros(4))
    actions = np.zeros((3, 4))
    actions[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"environment 2 .*entries \[1\]"):
        vec.step(actions)
    vec.close()


@pytest.mark.parametrize("backend", BACKENDS)
def test_actions_of_any_layout_and_type_hold_the_same_spools(backend):
    # float64 rows, a float32 column-major copy and a list give the same results (float32 widens exactly)
    rows = np.random.default_rng(3).uniform(-1.5, 1.5, (4, 2, 4)).astype(np.float32)
    given = [lambda a: a.astype(np.float64), lambda a: np.asfortranarray(a), lambda a: a.tolist()]
    results = []
    for form in given:
        vec = gym.make_vec("HexLoading-v0", num_envs=2, backend=backend)
        vec.reset(seed=4)
        results.append([vec.step(form(a)) for a in rows])
        vec.close()
    for other in results[1:]:
        _assert_same("steps", tuple(other), tuple(results[0]))


def test_without_the_plugin_it_says_to_use_sync(monkeypatch):
    import hexgym.model.plugin
    from hexgym.model.plugin import NativePluginError

    monkeypatch.setattr(hexgym.model.plugin, "load_plugin", lambda: "the native plugin was not built")
    with pytest.raises(NativePluginError, match="vectorization_mode='sync'"):
        HexLoadingVectorEnv(2, backend="native")


@pytest.mark.parametrize("kwargs", [{"backend": "cuda"}, {"render_mode": "rgb_array"}, {"num_envs": 0}])
def test_unsupported_arguments_are_refused(kwargs):
    with pytest.raises(ValueError):
        HexLoadingVectorEnv(**({"num_envs": 2} | kwargs))


def test_compiled_tables_fuel_and_payload_match_the_scalar_ones():
    from hexgym.envs.earthwork import table_at
    from hexgym.envs.task import _brake_power

    table = UniformTable(-1.0, 2.0, np.random.default_rng(0).normal(size=50))
    x = np.linspace(-1.5, 2.5, 997)
    values = np.array(table.values)
    assert [table_at(values, table.start, table.step, v) for v in x] == [table(v) for v in x]
    rates = fuel._fuel_rate_table()
    for power in np.linspace(0.0, 400e3, 301):
        brake = min(_brake_power(power), p.ENGINE_POWER)
        assert table_at(np.array(rates.values), rates.start, rates.step, brake) * 0.075 / 3600.0 == fuel.fuel_litres(
            power, 0.075
        )
    from hexgym.machine.physics import ExcavatorPhysics

    physics = ExcavatorPhysics()
    masses = np.array([0.0, 0.5, 20.0, 1234.5, p.BUCKET_HEAPED_CAPACITY * p.MATERIAL_DENSITY])
    inertias = payload_inertia(masses)
    for mass, inertia in zip(masses, inertias, strict=True):
        physics.set_payload(mass)
        assert physics.model.body("payload").inertia.tolist() == inertia.tolist()


def test_benchmark_function_reports_env_steps_per_second():
    assert vector_steps_per_second(num_envs=2, vector_steps=3, seed=0)[0] > 0


def test_reset_mask_resets_some_sites_as_sync_does():
    vec = gym.make_vec("HexLoading-v0", num_envs=3)
    sync = gym.vector.SyncVectorEnv([lambda: HexLoadingEnv()] * 3)
    _assert_same("reset", vec.reset(seed=1), sync.reset(seed=1))
    actions = np.random.default_rng(0).uniform(-1, 1, (5, 3, 4)).astype(np.float32)
    for a in actions:
        _assert_same("step", vec.step(a), sync.step(a))
    mask = np.array([False, True, False])
    _assert_same("masked reset", vec.reset(seed=20, options={"reset_mask": mask.copy()}),
                 sync.reset(seed=20, options={"reset_mask": mask.copy()}))  # fmt: skip
    for a in actions:
        _assert_same("step after", vec.step(a), sync.step(a))
    with pytest.raises(ValueError, match="reset_mask"):
        vec.reset(options={"reset_mask": np.zeros(3, bool)})
    vec.close()
    sync.close()

"""HexLoading-v0: the Gymnasium contract, rewards, conservation, rendering, vectorisation."""

import pickle
import warnings

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import hexgym  # noqa: F401 - registers HexLoading-v0
from hexgym.agents.scripted import ScriptedLoader
from hexgym.envs.loading import OBSERVATION_NAMES, REWARD_TERMS, HexLoadingEnv
from hexgym.machine import parameters as p


@pytest.fixture(scope="module")
def env():
    e = gym.make("HexLoading-v0")
    yield e
    e.close()


def _rollout(env, actions, seed):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for a in actions:
        obs, reward, *_ = env.step(a)
        out.append(np.append(obs, reward))
    return out


def test_passes_gymnasium_and_sb3_checkers_without_warnings():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = gym.make("HexLoading-v0", width=96, height=64)
        check_env(env.unwrapped)
        sb3_check_env(env.unwrapped, warn=True)
        env.close()


def test_spaces_and_metadata(env):
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (4,), np.float32)
    assert env.observation_space.shape == (len(OBSERVATION_NAMES),) == (23,)
    assert env.metadata["render_fps"] == 10
    assert {"rgb_array", "depth_array"} <= set(env.metadata["render_modes"])


def test_reward_terms_sum_exactly_and_are_named(env):
    env.reset(seed=3)
    rng = np.random.default_rng(0)
    for _ in range(30):
        _, reward, _, _, info = env.step(rng.uniform(-1, 1, 4).astype(np.float32))
        assert reward == sum(info[f"reward_{k}"] for k in REWARD_TERMS)
        assert info["reward_time"] == pytest.approx(-0.02 * 0.1)
        assert info["reward_fuel"] < 0  # the engine idles at least


def test_shaping_terms_are_potential_differences_and_off_by_default():
    """Each shaping term is its weight times the change of :func:`potentials`: over the scripted loader's dig
    and lift they sum to the end potentials less the start ones; with the default weights they are 0."""
    from hexgym.agents.scripted import ScriptedLoader
    from hexgym.envs import task

    weights = {"reach": 0.05, "load": 0.3, "lift": 0.2, "carry": 0.3}
    env = HexLoadingEnv(**{f"{term}_weight": w for term, w in weights.items()})
    env.reset(seed=2)

    def now():
        out = env.task.potentials_of(np.zeros(1, np.intp))
        return dict(zip(task.SHAPING_TERMS, out[0], strict=True))

    start, sums, loader = now(), dict.fromkeys(weights, 0.0), ScriptedLoader()
    assert start["reach"] < -2.0 and start["load"] == start["lift"] == start["carry"] == 0.0  # empty, far
    for _ in range(120):
        _, reward, _, _, info = env.step(loader.act(env))
        assert reward == sum(info[f"reward_{k}"] for k in REWARD_TERMS)
        for term in weights:
            sums[term] += info[f"reward_{term}"]
    end = now()
    assert info["bucket_kg"] > 1000 and end["lift"] > 0.5 and end["carry"] > 0.0  # loaded, lifted, on its way
    for term, w in weights.items():
        assert sums[term] == pytest.approx(w * (end[term] - start[term]), abs=1e-9)
    plain = HexLoadingEnv()
    plain.reset(seed=2)
    info = plain.step(np.zeros(4, np.float32))[4]
    assert all(info[f"reward_{term}"] == 0.0 for term in task.SHAPING_TERMS)


def test_reward_weights_are_constructor_arguments():
    env = HexLoadingEnv(time_weight=1.0, fuel_weight=0.0)
    env.reset(seed=0)
    _, reward, _, _, info = env.step(np.zeros(4, np.float32))
    assert info["reward_time"] == pytest.approx(-0.1) and info["reward_fuel"] == 0.0
    assert reward == pytest.approx(-0.1)


def test_deterministic_under_a_seed_and_resets_are_randomised():
    actions = np.random.default_rng(1).uniform(-1, 1, (40, 4)).astype(np.float32)
    a, b = gym.make("HexLoading-v0"), gym.make("HexLoading-v0")
    for x, y in zip(_rollout(a, actions, 7), _rollout(b, actions, 7), strict=True):
        assert np.array_equal(x, y)
    layouts = set()
    for seed in range(4):
        a.reset(seed=seed)
        layouts.add(round(a.unwrapped.layout.truck_direction, 6))
    assert len(layouts) == 4


def test_pickled_env_continues_identically():
    env = HexLoadingEnv()
    env.reset(seed=5)
    rng = np.random.default_rng(2)
    for _ in range(10):
        env.step(rng.uniform(-1, 1, 4).astype(np.float32))
    clone = pickle.loads(pickle.dumps(env))
    actions = rng.uniform(-1, 1, (10, 4)).astype(np.float32)
    for act in actions:
        o1, r1, *_ = env.step(act)
        o2, r2, *_ = clone.step(act)
        assert np.array_equal(o1, o2) and r1 == r2


def test_bad_actions_raise_clear_errors_and_large_ones_are_clipped(env):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([0.0, np.nan, 0.0, 0.0], np.float32))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3, np.float32))
    a, b = HexLoadingEnv(), HexLoadingEnv()
    a.reset(seed=1)
    b.reset(seed=1)
    oa, *_ = a.step(np.array([5.0, -3.0, 1.0, 0.0]))
    ob, *_ = b.step(np.array([1.0, -1.0, 1.0, 0.0]))
    assert np.array_equal(oa, ob)


def test_step_before_reset_is_refused():
    with pytest.raises(RuntimeError, match="reset"):
        HexLoadingEnv().step(np.zeros(4))


def test_observations_do_not_alias_the_simulation():
    env = HexLoadingEnv()
    obs, _ = env.reset(seed=0)
    kept = obs.copy()
    env.step(np.ones(4, np.float32))
    assert np.array_equal(obs, kept)


def test_material_is_conserved_every_step_while_loading():
    env = HexLoadingEnv()
    env.reset(seed=0)
    controller = ScriptedLoader()
    total = env.unwrapped.earth.total_kg()
    for _ in range(400):  # 40 s: digs, carries, dumps
        _, _, _, _, info = env.step(controller.act(env))
        stores = info["pile_kg"] + info["bucket_kg"] + info["truck_kg"] + info["spilled_kg"]
        assert abs(stores - total) < 1e-6
    assert info["truck_kg"] > 0
    # the payload rides in the bucket body: its mass is the bucket's contents
    assert env.physics.payload_kg == pytest.approx(info["bucket_kg"], abs=25.0)


def test_digging_lowers_the_rendered_pile():
    env = HexLoadingEnv()
    env.reset(seed=0)
    controller = ScriptedLoader()
    before = env.earth.pile.heights.copy()
    while controller.phase != "curl":
        env.step(controller.act(env))
    assert env.earth.pile.heights.min() >= 0 and (before - env.earth.pile.heights).max() > 0.2
    start = env.world.model.hfield_adr[env.world.pile_hfield]  # the pile's (the bed's load has one too)
    hfield = env.world.model.hfield_data[start : start + before.size].reshape(before.shape)
    env.world.show_pile(env.earth.pile.heights)
    # the hfield (what is drawn) is the heightmap: a ray down onto it hits the surface
    m, d = env.physics.model, env.physics.data
    i, j = np.unravel_index(np.argmax(before - env.earth.pile.heights), before.shape)
    x = env.earth.pile.origin[0] + j * env.earth.pile.spacing
    y = env.earth.pile.origin[1] + i * env.earth.pile.spacing
    geomid = np.zeros(1, np.int32)
    group = np.array([0, 1, 0, 0, 0, 0], np.uint8)
    distance = mujoco.mj_ray(m, d, np.array([x, y, 10.0]), np.array([0, 0, -1.0]), group, 1, -1, geomid)
    assert geomid[0] == env.world.pile_geom
    assert 10.0 - distance == pytest.approx(env.earth.pile.heights[i, j], abs=0.01)
    assert hfield.max() <= 1.0


def test_hard_contacts_with_the_ground_are_penalised():
    env = HexLoadingEnv()
    env.reset(seed=1)
    contact = 0.0
    for _ in range(40):  # boom down, stick in: the bucket is driven into the ground
        _, _, _, _, info = env.step(np.array([0.0, -1.0, 1.0, 0.0], np.float32))
        contact += info["reward_contact"]
    assert contact < 0


def test_truncation_and_termination():
    env = HexLoadingEnv(time_limit=1.0)
    env.reset(seed=0)
    flags = [env.step(np.zeros(4, np.float32))[3] for _ in range(10)]
    assert flags == [False] * 9 + [True]
    env = HexLoadingEnv(truck_capacity_kg=500.0)
    env.reset(seed=0)
    controller = ScriptedLoader()
    for _ in range(600):
        _, _, terminated, truncated, info = env.step(controller.act(env))
        if terminated:
            break
    assert terminated and not truncated and info["truck_kg"] >= 500.0


@pytest.mark.parametrize("mode", ["rgb_array", "depth_array"])
@pytest.mark.parametrize("camera", ["chase", "cab"])
def test_renders_offscreen(mode, camera):
    env = gym.make("HexLoading-v0", render_mode=mode, camera=camera, width=160, height=96)
    env.reset(seed=0)
    frame = env.render()
    env.close()
    if mode == "rgb_array":
        assert frame.shape == (96, 160, 3) and frame.dtype == np.uint8 and frame.std() > 5
    else:
        assert frame.shape == (96, 160) and frame.dtype == np.float32 and np.all(frame > 0)
        assert 1.0 < frame[-1].mean() < 50.0  # metres to the ground in the bottom row (the sky is at the far plane)
    with pytest.raises(ValueError, match="render_mode"):
        HexLoadingEnv(render_mode="bogus")


def test_the_pile_is_drawn_where_the_episode_put_it():
    env = HexLoadingEnv(render_mode="rgb_array", width=64, height=48)
    for seed in (0, 1):
        env.reset(seed=seed)
        env.render()
        model = env._view[0]
        np.testing.assert_allclose(model.geom_pos[model.geom("pile").id, :2], env.layout.pile_centre)
    env.close()


def test_pickle_after_rendering_drops_the_renderer():
    env = HexLoadingEnv(render_mode="rgb_array", width=64, height=48)
    env.reset(seed=0)
    first = env.render()
    clone = pickle.loads(pickle.dumps(env))
    assert np.array_equal(clone.render(), first)
    env.close()
    clone.close()


def test_make_vec_and_subproc_vec_env():
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    vec = gym.make_vec("HexLoading-v0", num_envs=2, vectorization_mode="sync")
    obs, _ = vec.reset(seed=0)
    obs, reward, *_ = vec.step(np.zeros((2, 4), np.float32))
    assert obs.shape == (2, 23) and reward.shape == (2,)
    vec.close()
    # the workers are fresh processes: "hexgym:" makes gymnasium import hexgym (which registers the id)
    sub = make_vec_env("hexgym:HexLoading-v0", n_envs=2, seed=0, vec_env_cls=SubprocVecEnv)
    sub.reset()
    obs, reward, done, _ = sub.step(np.zeros((2, 4), np.float32))
    assert obs.shape == (2, 23) and not done.any()
    sub.close()


@pytest.mark.slow
def test_random_steps_produce_no_nan_and_no_mujoco_warning():
    env = HexLoadingEnv()
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(100_000):
        obs, _, terminated, truncated, _ = env.step(rng.uniform(-1.2, 1.2, 4))
        assert np.all(np.isfinite(obs))
        if terminated or truncated:
            assert _mujoco_warnings(env) == 0, "MuJoCo raised a warning"
            env.reset()
    assert _mujoco_warnings(env) == 0


def _mujoco_warnings(env):
    return sum(w.number for w in env.physics.data.warning)


def test_spool_scaling():
    assert p.SPOOL_STROKE == pytest.approx(0.011)


def test_sampled_moment_arms_match_the_linkage():
    from hexgym.machine import kinematics
    from hexgym.machine.kinematics import tabulated_moment_arms

    rng = np.random.default_rng(4)
    for _ in range(50):
        q = np.array([0.0] + [rng.uniform(*kinematics.joint_range(n)) for n in kinematics.FRONT_CYLINDERS])
        exact = [kinematics.moment_arm(n, q[i + 1]) for i, n in enumerate(kinematics.FRONT_CYLINDERS)]
        assert np.allclose(tabulated_moment_arms(q), exact, atol=5e-6)


def test_tabulated_fuel_rate_matches_the_bsfc_map():
    from hexgym.hydraulics.circuit import fuel_rate
    from hexgym.hydraulics.fuel import brake_power, fuel_litres

    for power in np.linspace(0.0, 1.5 * p.ENGINE_POWER, 997):
        exact = fuel_rate(brake_power(power)) * 0.1 / 3600.0
        assert fuel_litres(power, 0.1) == pytest.approx(exact, rel=1e-5)


def test_clear_periods_follow_the_teeth_height_above_the_pile():
    env = HexLoadingEnv()
    env.reset(seed=0)
    pile, periods = env.earth.pile, env._periods
    site = env.physics.data.site_xpos[env._tip_site]
    x, y = env.layout.pile_centre
    surface = pile.height_at_point(x, y)
    site[:] = [x, y, surface - 0.2]  # (the tip site is only read; the next mj_step1 rewrites it)
    assert env._clear_periods() == 0
    site[:] = [x, y, pile.top + 0.61]
    assert env._clear_periods() == periods
    site[:] = [x, y, surface + 0.2]  # within two periods' travel (0.15 m each) of the top
    assert 0 < env._clear_periods() < periods


def test_clear_periods_shortcut_agrees_with_the_period_by_period_definition():
    """The whole-step check taken first changes no answer: m periods are clear when no grid point within half a
    bucket width plus m periods' travel stands higher than the teeth less that travel."""
    env = HexLoadingEnv()
    env.reset(seed=0)
    pile, periods = env.earth.pile, env._periods
    site = env.physics.data.site_xpos[env._tip_site]
    per_period = 0.6 / periods  # loading._PILE_MARGIN spread over the step
    x0, y0 = env.layout.pile_centre
    seen = set()
    for x, y, z in np.random.default_rng(0).uniform([x0 - 5, y0 - 5, -0.5], [x0 + 5, y0 + 5, pile.top + 1.0], (400, 3)):
        site[:] = [x, y, z]
        expected = 0
        while expected < periods:
            travel = (expected + 1) * per_period
            if pile.clearance(site, p.BUCKET_WIDTH / 2 + travel) < travel:
                break
            expected += 1
        assert env._clear_periods() == expected, (x, y, z)
        seen.add(expected)
    assert {0, periods} <= seen and len(seen) > 2  # the sweep met clear, blocked and partly clear teeth


def test_hard_contact_force_sums_only_tool_contacts_as_numpy_would():
    env = HexLoadingEnv()
    env.reset(seed=1)
    d, world = env.physics.data, env.world
    rng = np.random.default_rng(0)
    others = pressed = 0
    for k in range(3000):  # first boom down and stick in (the bucket into the ground), then random spools
        env.step(np.array([0.0, -1.0, 1.0, 0.0]) if k < 40 else rng.uniform(-1, 1, 4))
        g1, g2 = d.contact.geom1, d.contact.geom2
        tool = (world.tool_geoms[g1] & world.obstacle_geoms[g2]) | (world.tool_geoms[g2] & world.obstacle_geoms[g1])
        depth = -np.minimum(d.contact.dist[tool], 0.0).sum()
        force = p.CONTACT_STIFFNESS * depth - p.HARD_CONTACT_FORCE
        expected = min(max(force, 0.0), p.HARD_CONTACT_FORCE_CAP - p.HARD_CONTACT_FORCE) if tool.any() else 0.0
        assert env._hard_contact_force() == expected
        others += bool((~tool).any())  # the boom against the truck: not the bucket's or stick's, does not count
        pressed += expected > 0
        if others and pressed:
            break
    assert others and pressed


@pytest.mark.parametrize("periods", [0, 1.5, True])
def test_bad_earthwork_periods_are_refused(periods):
    with pytest.raises(ValueError, match="earthwork_periods"):
        HexLoadingEnv(earthwork_periods=periods)


def test_digging_once_per_step_fills_and_curls_like_digging_every_period():
    from hexgym.agents.scripted import DEFAULT_SETTINGS, ScriptedLoader

    phases = {}
    for periods in (1, 4):
        env = HexLoadingEnv(earthwork_periods=periods)
        env.reset(seed=2)
        controller = ScriptedLoader()
        while controller.phase != "to_truck" and env.elapsed < 30.0:
            _, _, _, _, info = env.step(controller.act(env))
            if controller.phase == "drag":
                dragged_kg = info["bucket_kg"]
        full_kg = DEFAULT_SETTINGS.full_fraction * p.BUCKET_HEAPED_CAPACITY * p.MATERIAL_DENSITY
        assert dragged_kg >= full_kg  # dragged it full
        phases[periods] = dict((phase, t) for t, phase in controller.log)
    # the drag fills in about the same time (measured 8.8 s and 8.9 s to the curl), and the curl, which
    # the pile's resistance stalls, lasts as long (4.0 s both; 2.0 s with the force held over whole steps)
    assert phases[4]["curl"] == pytest.approx(phases[1]["curl"], abs=0.5)
    curl = {k: v["to_truck"] - v["curl"] for k, v in phases.items()}
    assert curl[4] == pytest.approx(curl[1], abs=0.3)


def test_fullest_cut_line_moves_off_a_trench():
    from hexgym.envs.loading import heap_for, sample_start
    from hexgym.envs.world import CUT_SWING_RANGE, entry_radius, fullest_cut_direction, inner_radius

    layout, _ = sample_start(np.random.default_rng(5))
    pile = heap_for(layout)
    assert fullest_cut_direction(pile.height_at, layout) == pytest.approx(layout.pile_direction)  # a round heap
    # dig a trench along the centre line: the fullest line is now beside it, within the range
    c, s = np.cos(layout.pile_direction), np.sin(layout.pile_direction)
    for r in np.arange(inner_radius(layout), entry_radius(layout), 0.2):
        pile.take((r * c, r * s), (-s, c), p.BUCKET_WIDTH, 0.0, 10.0)
    offset = fullest_cut_direction(pile.height_at, layout) - layout.pile_direction
    assert 0.1 < abs(offset) <= CUT_SWING_RANGE + 1e-9


def test_observation_points_to_the_fullest_cut_and_follows_the_pile(env):
    u = env.unwrapped
    obs, _ = env.reset(seed=7)
    swing = u.physics.joint_positions()[0]
    direction = u.fullest_cut_direction()
    assert obs[OBSERVATION_NAMES.index("swing_to_cut")] == pytest.approx(swing - direction, abs=1e-6)
    c, s, centre = np.cos(direction), np.sin(direction), np.hypot(*u.layout.pile_centre)
    for r in np.arange(centre - 2.0, centre + 1.0, 0.2):
        u.earth.pile.take((r * c, r * s), (-s, c), p.BUCKET_WIDTH, 0.0, 10.0)  # take the line it points to
    assert u.fullest_cut_direction() != pytest.approx(direction)  # the cached value followed the pile's change


def test_a_config_with_overrides_makes_the_same_environment():
    """Keyword arguments, a frozen config and a config with overrides are one way to say the same thing; a bad or
    unknown one is refused in one line naming it."""
    import dataclasses

    from hexgym.envs.loading import LoadingConfig

    by_name = HexLoadingEnv(time_limit=30.0, fuel_weight=1.0)
    by_config = HexLoadingEnv(LoadingConfig(time_limit=30.0), fuel_weight=1.0)
    assert by_name.config == by_config.config and by_config.config.time_limit == 30.0
    np.testing.assert_array_equal(by_name.reset(seed=4)[0], by_config.reset(seed=4)[0])
    action = np.array([0.3, -0.2, 0.5, 0.1], np.float32)
    (obs_a, *rest_a), (obs_b, *rest_b) = by_name.step(action), by_config.step(action)
    np.testing.assert_array_equal(obs_a, obs_b)
    assert rest_a == rest_b
    with pytest.raises(dataclasses.FrozenInstanceError):
        by_name.config.time_limit = 5.0
    with pytest.raises(TypeError, match="HexLoading-v0 got an unexpected keyword argument 'tim_limit'"):
        HexLoadingEnv(tim_limit=30.0)
    with pytest.raises(ValueError, match="^time_limit must be a finite number > 0 s, got -1.0$"):
        LoadingConfig(time_limit=-1.0)

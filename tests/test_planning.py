"""Batched rollouts on the loading site, collision prediction, the collision shield and ``hexgym shield``."""

import json
import pickle

import gymnasium as gym
import numpy as np
import pytest

import hexgym  # noqa: F401  (registers HexLoading-v0)
from hexgym.machine import parameters as p
from hexgym.model import plugin

pytestmark = pytest.mark.skipif(plugin.plugin_library() is None, reason="native plugin not built")

BOOM_DOWN = np.array([0.0, -p.SPOOL_STROKE, 0.0, 0.0])


@pytest.fixture(scope="module")
def model():
    from hexgym.planning import RolloutModel

    m = RolloutModel()
    yield m
    m.close()


@pytest.fixture(scope="module")
def paper_model():
    """A fast model that is not the circuit model: the paper's tables (what the check's corrections are for)."""
    from hexgym.planning import RolloutModel

    m = RolloutModel(table_set="paper")
    yield m
    m.close()


@pytest.fixture()
def env():
    e = gym.make("HexLoading-v0", backend="native")
    e.reset(seed=0)
    yield e
    e.close()


def test_prediction_is_the_environments_motion_and_finds_its_contact(env, model):
    from hexgym.planning import PAIRS, MachineState, predict

    state = MachineState.from_env(env)
    prediction = predict(state, BOOM_DOWN, 1.0, model)
    assert prediction.times_s.shape == (40,) and prediction.tip.shape == (40, 3) and prediction.q.shape == (40, 4)
    env.step(np.array([0.0, -1.0, 0.0, 0.0], np.float32))
    tip = env.unwrapped.physics.data.site_xpos[env.unwrapped._tip_site]
    np.testing.assert_allclose(prediction.tip[3], tip, atol=1e-9)  # after 0.1 s, as the environment
    contact = prediction.first_contact
    assert contact is not None and contact.bodies in PAIRS
    assert 0.0 < contact.time_s < 1.0 and contact.depth_m > 0.0 and np.isfinite(contact.point).all()
    assert (
        prediction.min_clearance_m < 0.0 and prediction.clearance_m[:, 1].min() < 0.0
    )  # the bucket too, in the ground
    first = next(
        k for k in range(1, 11) if env.step(np.array([0.0, -1.0, 0.0, 0.0], np.float32))[4]["contact_impulse_ns"]
    )
    assert abs((first + 1) * 0.1 - contact.time_s) <= 0.1  # the environment's first hard contact, then
    # standing still: no contact, the clearance of the start
    still = predict(state, np.zeros(4), 0.5, model)
    assert still.first_contact is None and still.min_clearance_m > 0.3


def test_a_state_from_angles_and_rates_rolls_out_as_the_environments(env, model):
    from hexgym.planning import MachineState

    full = MachineState.from_env(env)
    bare = MachineState(full.q, full.qd, full.payload_kg, full.layout)
    spools = np.random.default_rng(0).uniform(-p.SPOOL_STROKE, p.SPOOL_STROKE, (8, 20, 4))
    a, b = model.rollout(full, spools, 1.0), model.rollout(bare, spools, 1.0)
    assert a.tip.shape == (8, 40, 3) and a.clearance_m.shape == (8, 40, 4) and a.min_clearance_m.shape == (8,)
    np.testing.assert_allclose(a.tip, b.tip, atol=1e-9)
    assert np.all(a.min_clearance_m <= a.bucket_clearance_m) and np.all(a.min_clearance_m <= a.stick_clearance_m)
    assert np.all(a.clearance_m <= model.detection_m)


def test_bad_input_is_named(env, model):
    from hexgym.planning import MachineState, predict

    state = MachineState.from_env(env)
    for horizon in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="horizon_s must be finite and > 0"):
            predict(state, BOOM_DOWN, horizon, model)
    with pytest.raises(ValueError, match="too long for memory"):
        predict(state, BOOM_DOWN, 1e9, model)
    with pytest.raises(ValueError, match=r"state outside the joint ranges: boom angle"):
        MachineState(np.array([0.0, 3.0, 0.8, 0.7]), np.zeros(4), 0.0, state.layout)
    with pytest.raises(ValueError, match="payload_kg"):
        MachineState(state.q, state.qd, -1.0, state.layout)
    with pytest.raises(ValueError, match=r"spools must be within"):
        predict(state, BOOM_DOWN * 2, 1.0, model)
    with pytest.raises(ValueError, match=r"spools must have shape"):
        predict(state, np.zeros(3), 1.0, model)


def _contacts(env, actions):
    contacts, touching, interventions = 0, False, 0
    for action in actions:
        _, _, terminated, truncated, info = env.step(action)
        hard = info["contact_impulse_ns"] > 0
        contacts += hard and not touching
        touching = hard
        interventions += info.get("shield_intervened", False)
    return contacts, interventions


def test_the_shield_prevents_a_random_policys_hard_contacts():
    from hexgym.wrappers import CollisionShield

    actions = np.random.default_rng(1).uniform(-1, 1, (150, 4)).astype(np.float32)
    bare = gym.make("HexLoading-v0", backend="native")
    bare.reset(seed=1)
    without, _ = _contacts(bare, actions)
    shielded = CollisionShield(gym.make("HexLoading-v0", backend="native"))
    shielded.reset(seed=1)
    with_, interventions = _contacts(shielded, actions)
    assert without >= 5 and with_ <= 0.1 * without and interventions > 0
    _, _, _, _, info = shielded.step(actions[0])
    assert {"shield_intervened", "shield_action", "shield_min_clearance_m", "shield_ms"} <= set(info)
    clone = pickle.loads(pickle.dumps(shielded))  # the rollout model is rebuilt, not pickled
    assert clone._model is None
    shielded.close()


def test_the_shield_refuses_a_bad_horizon():
    from hexgym.wrappers import CollisionShield

    for horizon in (0.0, -1.0, 1e6):
        with pytest.raises(ValueError, match="horizon_s"):
            CollisionShield(gym.make("HexLoading-v0", backend="native"), horizon_s=horizon)


def test_the_shield_works_with_make_vec_and_sb3():
    from stable_baselines3.common.vec_env import DummyVecEnv

    from hexgym.wrappers import CollisionShield

    vec = gym.make_vec("HexLoading-v0", num_envs=2, vectorization_mode="sync", wrappers=[CollisionShield])
    vec.reset(seed=0)
    _, _, _, _, infos = vec.step(np.zeros((2, 4), np.float32))
    assert "shield_intervened" in infos
    vec.close()
    sb3 = DummyVecEnv([lambda: CollisionShield(gym.make("HexLoading-v0"))])
    sb3.seed(0)
    sb3.reset()
    _, _, _, infos = sb3.step(np.zeros((1, 4), np.float32))
    assert "shield_intervened" in infos[0]
    sb3.close()


def test_shield_command_writes_the_figures(tmp_path, capsys):
    from hexgym_lab.cli import main

    out, plot = tmp_path / "shield.json", tmp_path / "shield.png"
    argv = ["shield", "--policy", "random", "--episodes", "2", "--seconds", "5", "--json", str(out)]
    argv += ["--plot", str(plot)]
    assert main(argv) == 0
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and plot.stat().st_size > 10_000
    result = json.loads(out.read_text())
    for key in ("contacts_per_hour_without", "contacts_per_hour_with", "interventions_per_hour",
                "tonnes_per_hour_without", "tonnes_per_hour_with", "shield_ms_per_step"):  # fmt: skip
        assert isinstance(result[key], float), key
    assert main(["shield", "--horizon", "0", "--episodes", "1"]) == 2
    assert "--horizon must be > 0" in capsys.readouterr().err


@pytest.mark.slow
def test_shield_targets_on_random_episodes():
    from hexgym_lab.shield import compare

    result = compare("random", episodes=3, seed=0, seconds=60.0)
    assert result["contact_reduction"] >= 0.9
    assert result["shield_ms_per_step"] <= 2.0 * 2  # the target is 2 ms; shared CI cores are slower


def test_truck_clearance_is_predicted_where_the_layout_puts_the_truck(env, model):
    from hexgym.planning import MachineState

    layout = env.unwrapped.layout
    for boom in np.linspace(0.2, 1.0, 9):
        q = np.array([layout.truck_direction, boom, 0.4, 0.8])
        clearance = model.at_angles(q, layout).clearance
        if clearance[0, 0] < model.detection_m:
            break
    else:
        pytest.skip("no pose near the truck found")
    batch = model.rollout(MachineState(q, np.zeros(4), 0.0, layout), np.zeros(4), 0.2)
    along = model.at_angles(batch.q[0], layout).clearance
    np.testing.assert_allclose(batch.clearance_m[0], along, atol=1e-6)
    assert batch.clearance_m[0, :, 0].min() < model.detection_m  # the truck is where the layout says


def test_clearance_sensors_read_the_geom_pairs_distances(model):
    """The clearance sensors (which measure only pairs whose bounding volumes are within the cutoff) read what
    MuJoCo's distance between the geoms gives, near and far, over moves about the site."""
    from hexgym_lab.plan import start_states

    rng = np.random.default_rng(7)
    near, far = np.zeros(4, bool), np.zeros(4, bool)
    for task in ("dump", "return"):
        state, _ = start_states(3)[task]
        knots = np.clip(rng.normal(0.0, 0.7, (12, 10, 4)), -1.0, 1.0) * p.SPOOL_STROKE
        batch = model.rollout(state, np.repeat(knots, 20, axis=1), 5.0)
        for i in range(len(knots)):
            exact = model.at_angles(batch.q[i], state.layout).clearance
            np.testing.assert_allclose(batch.clearance_m[i], exact, atol=1e-12)
        near |= (batch.clearance_m < model.detection_m).any(axis=(0, 1))
        far |= (batch.clearance_m == model.detection_m).any(axis=(0, 1))
    assert near.all() and far.all()  # every pair both within the cutoff and beyond it


def test_rollouts_without_contacts_are_the_same_until_a_contact_then_pass_through(env, model):
    """``contacts=False`` leaves the collision pass out: the same motion in the air, deeper into the ground; the
    bucket's clearances (to its mesh's convex hull) are the collision mesh's distances."""
    import mujoco

    from hexgym.planning import MachineState, RolloutModel

    state = MachineState.from_env(env)
    free = RolloutModel(contacts=False)
    try:
        up = np.array([0.3, 0.5, 0.0, 0.0]) * p.SPOOL_STROKE  # swing and boom up: in the air
        a, b = model.rollout(state, up, 1.0), free.rollout(state, up, 1.0)
        assert a.min_clearance_m[0] > 0.1
        np.testing.assert_allclose(b.q, a.q, atol=1e-12)
        np.testing.assert_allclose(b.clearance_m, a.clearance_m, atol=1e-12)
        down_with, down_without = model.rollout(state, BOOM_DOWN, 2.0), free.rollout(state, BOOM_DOWN, 2.0)
        assert down_with.bucket_clearance_m[0] < 0  # the ground stops it ...
        assert down_without.bucket_clearance_m[0] < down_with.bucket_clearance_m[0] - 0.05  # ... or not
    finally:
        free.close()
    m, d = model.model, model.physics.data
    mesh, hull = m.geom("bucket_collision").id, m.geom("planning_bucket_hull").id
    fromto = np.empty(6)
    for x in a.states[0, ::8]:
        mujoco.mj_setState(m, d, x, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        mujoco.mj_kinematics(m, d)
        for other in ("ground", "truck_left_wall", "truck_floor"):
            g = m.geom(other).id
            exact = mujoco.mj_geomDistance(m, d, mesh, g, 1.0, fromto)
            assert mujoco.mj_geomDistance(m, d, hull, g, 1.0, fromto) == pytest.approx(exact, abs=1e-6)


def test_the_planner_simulates_no_further_than_the_best_moves_cost(env, model):
    """Once a move reaches the goal, no batch runs past the best cost so far (a move's cost is at least its time and
    w_fuel x its idle fuel), never short of the plan's time; loaded or not, a move keeps the one margin."""
    from hexgym.planning import MachineState
    from hexgym.planning.goals import MARGIN_M, margin_for, tip_goal
    from hexgym.planning.planner import plan_motion

    state = MachineState.from_env(env)
    assert margin_for(state) == MARGIN_M
    assert margin_for(MachineState(state.q, state.qd, 2000.0, state.layout)) == MARGIN_M  # loaded too
    goal = tip_goal(env.unwrapped.physics.tip_position() + np.array([0.0, 0.0, 0.6]), state.layout)
    horizons: list[float] = []
    rollout = model.rollout

    def recorded(start, spools, horizon_s):
        horizons.append(horizon_s)
        return rollout(start, spools, horizon_s)

    model.rollout = recorded
    try:
        for w_fuel in (1.0, 100.0):
            horizons.clear()
            plan = plan_motion(state, goal, model, w_fuel=w_fuel, budget=200, population=50, horizon_s=4.0,
                               margin_m=0.0)  # fmt: skip
            assert plan.reached and horizons[0] == pytest.approx(4.0)
            assert min(horizons[1:-1]) < 4.0 and min(horizons) >= plan.time_s - 1e-9
    finally:
        del model.rollout


def test_the_planner_refuses_bad_input(env, model):
    from hexgym.planning import MachineState
    from hexgym.planning.goals import Goal, dump_goal, tip_goal
    from hexgym.planning.planner import plan_motion

    layout = env.unwrapped.layout
    state = MachineState(env.unwrapped.physics.joint_positions(), np.zeros(4), 2000.0, layout)
    goal = dump_goal(layout)
    with pytest.raises(ValueError, match="budget must be an integer >= 1"):
        plan_motion(state, goal, model, budget=0)
    with pytest.raises(ValueError, match="horizon_s must be > 0"):
        plan_motion(state, goal, model, horizon_s=0.0)
    with pytest.raises(ValueError, match="out of the machine's reach"):
        tip_goal(np.array([40.0, 0.0, 1.0]), layout)
    with pytest.raises(ValueError, match="goal task must be one of"):
        Goal("dig", np.zeros(3), layout)


def test_a_small_plan_reaches_over_the_truck_or_says_why(env, model):
    from hexgym.planning import MachineState
    from hexgym.planning.goals import dump_goal
    from hexgym.planning.planner import plan_motion

    layout = env.unwrapped.layout
    state = MachineState(env.unwrapped.physics.joint_positions(), np.zeros(4), 2000.0, layout)
    plan = plan_motion(state, dump_goal(layout), model, budget=300, population=50, horizon_s=6.0)
    assert plan.rollouts == 301 and plan.spools_m.shape[1] == 4 and len(plan.tip) == len(plan.spools_m)
    assert np.abs(plan.spools_m).max() <= p.SPOOL_STROKE
    if plan.collision_free and plan.reached:
        assert plan.goal_error_m == 0.0 and "reaches the goal" in plan.message
    elif not plan.collision_free:
        assert "no collision-free motion" in plan.message


def test_a_plan_from_inside_the_ground_is_not_reported_safe(env, model):
    from hexgym.planning import MachineState
    from hexgym.planning.goals import dump_goal
    from hexgym.planning.planner import plan_motion

    layout = env.unwrapped.layout
    for boom in np.linspace(0.6, -0.4, 11):
        q = np.array([0.0, boom, 0.5, 0.8])
        clearance = model.at_angles(q, layout).clearance
        if clearance[0, 1] < -0.2:
            break
    else:
        pytest.skip("no pose in the ground found")
    plan = plan_motion(MachineState(q, np.zeros(4), 0.0, layout), dump_goal(layout), model, budget=40, horizon_s=2.0)
    assert not plan.collision_free and plan.min_clearance_m < 0
    assert plan.message.startswith("no collision-free motion found")


def test_the_check_replays_a_plan_on_the_circuit_model_and_finds_its_contact(env, model):
    from hexgym.planning import MachineState
    from hexgym.planning.check import PlanCheck
    from hexgym.planning.goals import dump_goal

    layout = env.unwrapped.layout
    state = MachineState(env.unwrapped.physics.joint_positions(), np.zeros(4), 0.0, layout)
    check = PlanCheck(model)
    held = check(np.zeros((40, 4)), state, dump_goal(layout))
    clearance = model.at_angles(state.q[None], layout).clearance
    assert held.collision_free and held.min_clearance_m == pytest.approx(clearance.min(), abs=0.02)
    down = check(np.tile(BOOM_DOWN, (80, 1)), state, dump_goal(layout))  # 2 s boom down: into the ground
    assert not down.collision_free and down.time_s is None and down.goal_error_m > 0.0
    assert down.message.startswith("no collision-free motion found") and "from the goal" in held.message


def test_the_check_predicts_the_references_fuel(env, model):
    """The check's fuel (the circuit's pump pressures and flows) is the reference's for the same spools, within 3 %;
    held spools burn the engine's idle rate."""
    from hexgym.hydraulics.reference import ReferenceModel
    from hexgym.planning import MachineState
    from hexgym.planning.check import PlanCheck, replay_plan
    from hexgym.planning.goals import dump_goal

    layout = env.unwrapped.layout
    state = MachineState(env.unwrapped.physics.joint_positions(), np.zeros(4), 0.0, layout)
    check, goal = PlanCheck(model), dump_goal(layout)
    move = np.tile(np.array([0.8, 0.6, -0.4, 0.3]) * p.SPOOL_STROKE, (80, 1))  # 2 s: swing, boom up, stick out
    moved = check(move, state, goal).fuel_l
    reference = replay_plan(ReferenceModel(), move, state, goal, model).fuel_l
    held = check(np.zeros((80, 4)), state, goal).fuel_l
    assert moved == pytest.approx(reference, rel=0.03)
    assert 0.0 < held < moved / 2


def test_circuit_rollouts_are_the_checks_replays_with_its_fuel(env, model, paper_model):
    """The native circuit model's rollouts follow the check's replay of the same spools on the circuit model in Python,
    with the teeth and clearances of the site's geometry, and carry the engine's fuel rate from the circuit's pump
    pressures and flows (as the replay reports it, one state at a time); a table model's rollouts carry none."""
    from hexgym.hydraulics.circuit import STATE_SIZE, HydraulicCircuit, engine_fuel_rates, fuel_rate, regulated_flows
    from hexgym.planning import MachineState
    from hexgym.planning.check import PlanCheck, replay_plan
    from hexgym.planning.goals import dump_goal
    from hexgym.planning.planner import move_fuel_l

    states = np.random.default_rng(2).uniform(0.0, 3.0e7, (20, STATE_SIZE))
    states[:, -2:] = np.random.default_rng(3).uniform(-0.2, 1.2, (20, 2))
    states[0, :2] = 0.0
    one_by_one = [fuel_rate(HydraulicCircuit().pump_power(s)[2]) for s in states]
    np.testing.assert_allclose(engine_fuel_rates(states), one_by_one, rtol=1e-12)
    flows = [HydraulicCircuit.pump_flows(s[:2], s[-2:], 0.004, 1.2e5)[0] for s in states]  # the law, two ways
    np.testing.assert_array_equal(regulated_flows(states[:, :2], states[:, -2:], 0.004, 1.2e5), flows)

    layout = env.unwrapped.layout
    state = MachineState(env.unwrapped.physics.joint_positions(), np.zeros(4), 1500.0, layout)
    check = PlanCheck(model)
    spools = np.repeat(np.random.default_rng(3).uniform(-1.0, 1.0, (2, 10, 4)) * p.SPOOL_STROKE, 4, axis=1)
    batch = model.rollout(state, spools, 1.0)
    run = replay_plan(check.machine, spools[1], state, dump_goal(layout), model)
    assert batch.q.shape == (2, 40, 4) and batch.fuel_l_per_h.shape == (2, 40)
    np.testing.assert_allclose(batch.tip[1, 1::2], run.tips[1:21], atol=0.01)
    np.testing.assert_allclose(batch.clearance_m[1, 1::2], run.clearance[1:21], atol=0.01)
    litres = move_fuel_l(model, batch, 1, 39)
    assert litres == pytest.approx(batch.fuel_l_per_h[1].sum() * model.control_period / 3600.0)
    assert litres == pytest.approx(run.fuel_l, rel=0.03)  # the same rate, sampled every period / every second one
    assert paper_model.rollout(state, spools, 1.0).fuel_l_per_h is None


def test_the_tilt_at_angles_is_the_rollouts_tilt(env, model):
    from hexgym.planning import MachineState

    state = MachineState(env.unwrapped.physics.joint_positions(), np.zeros(4), 0.0, env.unwrapped.layout)
    batch = model.rollout(state, np.tile(np.array([0.5, 0.5, -0.5, 1.0]) * p.SPOOL_STROKE, (20, 1)), 0.5)
    np.testing.assert_allclose(model.at_angles(batch.q[0], state.layout).tilt, batch.tilt[0], atol=1e-12)  # all
    assert model.at_angles(batch.q[0, 3], state.layout).tilt == pytest.approx(batch.tilt[0, 3:4], abs=1e-12)  # one pose


def test_a_correction_trims_a_plan_to_its_point_on_the_accurate_model(env, paper_model):
    """Spools that bring a fast model's teeth (the paper tables') to rest at a point leave the circuit model's
    elsewhere; the correction's trimmed spools bring them there. Spools already there are returned as they are."""
    model = paper_model
    from hexgym.planning import MachineState
    from hexgym.planning.check import SETTLE_S, PlanCheck, replay_plan
    from hexgym.planning.goals import tip_goal

    layout = env.unwrapped.layout
    state = MachineState(env.unwrapped.physics.joint_positions(), np.zeros(4), 0.0, layout)
    move = np.tile(np.array([0.6, 0.5, -0.4, 0.3]) * p.SPOOL_STROKE, (80, 1))  # 2 s: swing, boom up, stick out
    settle = np.zeros((round(SETTLE_S / model.control_period), 4))
    fast_end = model.rollout(state, np.vstack([move, settle]), 2.0 + SETTLE_S).tip[0, -1]
    goal = tip_goal(fast_end, layout)
    check = PlanCheck(model)
    before = check(move, state, goal)
    spools, after, replays = check.correct(move, state, goal)
    assert spools.shape == move.shape and np.abs(spools).max() <= p.SPOOL_STROKE
    assert after.collision_free and after.goal_error_m < min(0.1, before.goal_error_m / 1.5)  # 0.12 -> 0.07 m
    assert check(spools, state, goal) == after and 1 <= replays <= 7
    rest = replay_plan(check.machine, move, state, goal, model).tips[-1]
    same, result, replays = check.correct(move, state, tip_goal(rest, layout))
    assert same is move and replays == 1 and result.goal_error_m < 1e-9


def test_a_checked_plan_keeps_the_clearance_the_check_found_missing(env, model):
    """Two rounds, each plan checked; the second keeps the clearance the check found the first overstated."""
    from hexgym.planning import MachineState
    from hexgym.planning.check import CheckResult
    from hexgym.planning.goals import dump_goal
    from hexgym.planning.planner import MEND_DELAYS_S, plan_checked

    layout = env.unwrapped.layout
    state = MachineState(env.unwrapped.physics.joint_positions(), np.zeros(4), 2000.0, layout)
    checked = []

    def check(spools_m, start, goal):  # a machine 0.4 m closer to the truck than the fast model says
        clearance = model.at_angles(np.atleast_2d(start.q), layout).clearance
        result = CheckResult(float(clearance.min()) - 0.4 * len(checked), 1.0, None)
        checked.append(result)
        return result

    plan, result = plan_checked(state, dump_goal(layout), model, check, budget=60, population=30, horizon_s=3.0)
    assert plan.rollouts == 62  # each round simulates its final plan once more
    # never at the goal: the swing delayed by each of MEND_DELAYS_S is checked too, each worse
    assert len(checked) == 2 + len(MEND_DELAYS_S)
    assert result is checked[0]  # the second round's plan, checked worse, is not the one returned
    with pytest.raises(ValueError, match="budget must be an integer >= 2"):
        plan_checked(state, dump_goal(layout), model, check, budget=1)


def test_a_plan_that_touches_on_the_accurate_model_is_mended_by_a_later_swing(env, model):
    """A checked plan in contact, or closer than the check's margin, is tried with its swing started later; the first
    delay that the check finds clear by its margin and at the goal is returned, its other spools as planned."""
    from hexgym.planning import MachineState
    from hexgym.planning.check import CHECK_MARGIN_M, CheckResult
    from hexgym.planning.goals import dump_goal
    from hexgym.planning.planner import MEND_DELAYS_S, plan_checked

    layout = env.unwrapped.layout
    state = MachineState(env.unwrapped.physics.joint_positions(), np.zeros(4), 2000.0, layout)
    near, late = (round(delay / model.control_period) for delay in MEND_DELAYS_S[:2])
    close = CheckResult(CHECK_MARGIN_M / 2, 0.0, 4.0)
    assert close.collision_free and not close.clear and "0.05 m clear" in close.message

    def check(spools_m, start, goal):  # a machine whose bucket meets the truck unless the swing waits `late` periods
        waits = int(np.argmax(spools_m[:, 0] != 0.0))
        return CheckResult(0.1, 0.0, 4.0) if waits >= late else close if waits >= near else CheckResult(-0.2, 0.0, 4.0)

    plan, result = plan_checked(state, dump_goal(layout), model, check, budget=60, population=30, horizon_s=3.0,
                                initial=np.tile([1.0, 1.0, 0.0, 0.0], (6, 1)))  # fmt: skip
    assert result.collision_free and result.time_s == 4.0
    assert not plan.spools_m[:late, 0].any() and plan.spools_m[late, 0] != 0.0
    assert plan.spools_m[0, 1] != 0.0  # the boom lifts from the start, ahead of the swing


def test_a_fitted_swing_comes_to_rest_at_its_target_on_the_circuit_model(env, model):
    """The rollouts' quickest swing (full, then closed: the crossover reliefs brake it) stops at the target there;
    the swing fitted on the circuit model's replays (full, then closed, switched no earlier) stops at it there."""
    from hexgym.planning import MachineState
    from hexgym.planning.check import PlanCheck, replay_plan
    from hexgym.planning.goals import dump_goal
    from hexgym.planning.planner import swing_bang_bang

    layout = env.unwrapped.layout
    state = MachineState(env.unwrapped.physics.joint_positions(), np.zeros(4), 0.0, layout)
    target = state.q[0] - 1.2
    swing, switch, stop, rollouts = swing_bang_bang(model, state, target, 5.0)
    assert rollouts == len(swing) * 2 // 3 - 1 and swing[0] == -p.SPOOL_STROKE and not swing[switch:].any()
    assert switch < stop < len(swing)  # braked by the crossover reliefs, it has stopped within the horizon
    fast = model.rollout(state, np.column_stack([swing, np.zeros((len(swing), 3))]), 5.0)
    assert abs(fast.q[0, -1, 0] - target) < 0.03
    check = PlanCheck(model)
    spools = check.fit_swing(np.zeros((len(swing), 4)), state, target, switch)
    fitted = np.flatnonzero(spools[:, 0])
    assert (spools[fitted, 0] == -p.SPOOL_STROKE).all() and fitted[-1] + 1 == len(fitted) >= switch
    assert not spools[:, 1:].any()
    run = replay_plan(check.machine, spools, state, dump_goal(layout), model)
    assert abs(run.rows["q_swing_rad"][-1] - target) < 0.03 and abs(run.rows["qd_swing_radps"][-1]) < 0.02


def test_a_plan_with_a_fitted_swing_runs_the_fitted_spools(env, model):
    """``fit_swing``: the search holds the swing at the fast model's quickest; each round's plan gets the fitted
    swing before its check; the returned plan's spools are the fitted ones, its rollouts count the swing's batch."""
    from hexgym.planning import MachineState
    from hexgym.planning.check import CheckResult
    from hexgym.planning.goals import return_goal
    from hexgym.planning.planner import MEND_DELAYS_S, plan_checked
    from hexgym.planning.rollouts import bang_bang

    layout = env.unwrapped.layout
    state = MachineState(env.unwrapped.physics.joint_positions(), np.zeros(4), 0.0, layout)
    goal = return_goal(layout, state.q[0] + 1.0)
    fitted, seen = [], []

    def fit_swing(spools_m, start, target, switch):
        out = np.array(spools_m)
        out[:, 0] = 0.5e-3  # a mark
        fitted.append((target, switch, spools_m[:, 0].copy()))
        return out

    def check(spools_m, start, goal):
        seen.append(spools_m)
        return CheckResult(1.0, 1.0, None)

    plan, _ = plan_checked(state, goal, model, check, budget=40, population=20, horizon_s=2.0, fit_swing=fit_swing)
    # the two rounds' plans are checked with the fitted swing; never at the goal, each is then tried delayed
    assert len(fitted) == 2 and all(np.array_equal(s[:, 0], np.full(len(s), 0.5e-3)) for s in seen[:2])
    assert len(seen) == 2 + len(MEND_DELAYS_S)
    assert abs(fitted[0][0] - (state.q[0] + 1.0)) < 0.3  # the goal's bearing
    searched, switch = fitted[0][2], fitted[0][1]  # full towards the goal to the switch, then counter, then closed
    stop = len(searched) - np.count_nonzero(np.cumprod(searched[::-1] == 0.0))
    assert np.array_equal(searched, bang_bang(1.0, switch, stop, len(searched))) and 0 < switch == stop
    assert np.array_equal(plan.spools_m[:, 0], np.full(len(plan.spools_m), 0.5e-3))
    assert plan.rollouts == 42 + 2 * 80 // 3 - 1


def test_plan_command_names_bad_input(capsys):
    from hexgym_lab.cli import main

    assert main(["plan", "--task", "dump", "--budget", "0"]) == 2
    assert "--budget must be >= 2" in capsys.readouterr().err  # two rounds, each checked
    assert main(["plan", "--task", "dump", "--seeds", "5-2"]) == 2
    assert "--seeds must be A-B" in capsys.readouterr().err
    assert main(["plan", "--task", "dump", "--video", "plan.avi"]) == 2
    assert "--video must be an .mp4 file" in capsys.readouterr().err
    from hexgym_lab.plan import run_plan

    with pytest.raises(ValueError, match="--swing must be one of"):
        run_plan("return", [0], swing="fast")
    with pytest.raises(ValueError, match="--workers must be >= 1"):
        run_plan("return", [0], workers=0)
    with pytest.raises(ValueError, match="--population must be >= 2"):
        run_plan("return", [0], population=1)
    assert main(["plan", "--task", "dump", "--workers", "0"]) == 2
    assert "--workers must be" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["plan", "--task", "dump", "--swing", "exact"])
    assert "invalid choice: 'exact'" in capsys.readouterr().err


@pytest.mark.slow
def test_plan_command_writes_the_figures(tmp_path):
    from hexgym_lab.cli import main

    out = tmp_path / "plan.json"
    png = tmp_path / "plan.png"
    assert main(["plan", "--task", "dump", "--seed", "0", "--json", str(out), "--plot", str(png)]) == 0
    assert png.stat().st_size > 0
    result = json.loads(out.read_text())
    for key in ("plan_wall_s", "rollouts", "predicted_time_s", "predicted_fuel_l", "reference_time_s",
                "reference_fuel_l", "reference_goal_error_m", "reference_min_clearance_m", "scripted_time_s",
                "scripted_fuel_l", "scripted_reference_time_s", "scripted_reference_fuel_l"):  # fmt: skip
        assert key in result, key
    assert result["target_margin_m"] == 0.8  # loaded: the default margin is the loaded one
    assert result["predicted_margin_kept"] == (result["predicted_min_clearance_m"] >= 0.8)
    assert result["scripted_reference_time_s"] > 0 and result["scripted_reference_fuel_l"] > 0


def test_a_plan_predicts_the_references_time_and_fuel():
    """The candidates are the circuit model's, natively: the plan's predicted fuel is the reference's within a few
    per cent, with the one margin; the goal figure holds under spool noise; a plan at the goal says so."""
    from hexgym.planning.goals import MARGIN_M
    from hexgym_lab.plan import plan_task

    result = plan_task("dump", 0, budget=120, nthread=1)
    assert result["target_margin_m"] == MARGIN_M and result["rollouts"] >= 120
    assert result["predicted_fuel_l"] == pytest.approx(result["reference_fuel_l"], rel=0.05)
    assert result["predicted_reached"] and result["reference_time_s"] is not None
    assert result["noise_goal_error_m"] <= 0.3 and result["swing_limit_s"] > 0
    assert "at the goal" in result["plan_message"]


def test_plan_summary_counts_the_targets_on_each_machine():
    """Faster / less fuel counted against the scripted loader on the learned model and, for the reference replay,
    against the scripted loader on the reference; a move that never reached the goal counts as neither."""
    from hexgym_lab.plan import summarise

    def seed(learned_t, ref_t, ref_fuel, scripted_ref_t):
        return {"seed": 0, "plan_wall_s": 1.5, "rollouts": 2001, "learned_time_s": learned_t, "learned_fuel_l": 0.8,
                "scripted_time_s": 4.0, "scripted_fuel_l": 1.0, "predicted_time_s": 3.0, "predicted_fuel_l": 0.8,
                "predicted_reached": True, "reference_time_s": ref_t, "reference_fuel_l": ref_fuel,
                "scripted_reference_time_s": scripted_ref_t, "scripted_reference_fuel_l": 1.0,
                "reference_goal_error_m": 0.1, "reference_min_clearance_m": 0.2, "checked_time_s": ref_t,
                "checked_fuel_l": 1.1 * ref_fuel, "noise_goal_error_m": 0.1, "swing_limit_s": 2.0}  # fmt: skip

    out = summarise([seed(3.0, 4.0, 0.9, 5.0), seed(None, None, 0.8, 5.0), seed(4.0, 5.0, 0.8, 5.0)])
    targets = out["targets"]
    assert targets["faster_15pct_no_more_fuel"] == 1 and targets["less_fuel_15pct_no_more_time"] == 2
    assert targets["reference_faster_15pct_no_more_fuel"] == 1  # 4.0 / 5.0 s with 0.9 of the fuel
    assert targets["reference_less_fuel_15pct_no_more_time"] == 1  # 5.0 / 5.0 s with 0.8 of the fuel
    assert out["median_reference_time_vs_scripted_reference"] == pytest.approx(0.9)
    assert out["median_checked_fuel_error"] == pytest.approx(0.1)
    assert out["median_swing_switch_later_s"] is None  # no fitted swing
    fitted = seed(3.0, 4.0, 0.9, 5.0) | {"swing_switch_s": {"fast_model": 1.5, "plan": 1.8}}
    assert summarise([fitted, seed(3.0, 4.0, 0.9, 5.0)])["median_swing_switch_later_s"] == pytest.approx(0.3)


def test_swing_switches_are_where_the_full_spool_towards_the_turn_ends():
    """The plan's switch is the end of its full spool towards the turn, not of a counter-spool after it."""
    from types import SimpleNamespace

    from hexgym.planning.rollouts import bang_bang
    from hexgym_lab.plan import _swing_switches

    spools = np.zeros((100, 4))
    spools[:, 0] = bang_bang(-1.0, 40, 70, 100)  # the fast model's own turn: full, full counter-spool, closed
    assert _swing_switches(SimpleNamespace(spools_m=spools, fast_swing_switch=40), 0.025) == pytest.approx(
        {"fast_model": 1.0, "plan": 1.0}
    )
    spools[:, 0] = bang_bang(-1.0, 52, 52, 100)  # fitted: full, then closed
    assert _swing_switches(SimpleNamespace(spools_m=spools, fast_swing_switch=40), 0.025)["plan"] == pytest.approx(1.3)
    assert _swing_switches(SimpleNamespace(spools_m=spools, fast_swing_switch=None), 0.025) is None


def test_plot_plan_writes_a_png(tmp_path):
    from hexgym_lab.plan import plot_plan

    path = np.column_stack([np.linspace(5, 0, 20), np.linspace(0, 6, 20), np.linspace(1, 3, 20)])
    result = {
        "task": "dump", "seed": 0, "learned_time_s": 3.5, "learned_fuel_l": 0.025, "reference_fuel_l": 0.024,
        "reference_goal_error_m": 0.1, "scripted_time_s": 4.9, "scripted_fuel_l": 0.032,
        "planned_spools_mm": np.full((140, 4), 5.0).tolist(), "scripted_spools_mm": np.full((49, 4), -5.0).tolist(),
        "paths": {"planned_tip": path.tolist(), "reference_tip": path.tolist(), "scripted_tip": path.tolist()},
    }  # fmt: skip
    out = plot_plan(result, tmp_path / "plan.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_plan_video_films_the_plan_then_the_scripted_move(tmp_path):
    """Each step of the plan (a row per 25 ms control period, a frame per 0.1 s step) and of the scripted move."""
    import imageio.v3 as iio

    from hexgym_lab.plan import plan_video

    result = {"task": "dump", "seed": 0, "planned_spools_mm": np.full((12, 4), 3.0).tolist(),
              "scripted_spools_mm": np.full((5, 4), -3.0).tolist()}  # fmt: skip
    out = plan_video(result, tmp_path / "plan.mp4", width=160, height=96)
    frames = iio.imread(out)
    assert frames.shape == (3 + 5, 96, 160, 3) and frames.std() > 5


def test_release_at_stops_closes_only_spools_that_push_a_cylinder_into_its_stop():
    from hexgym.planning.check import ROW_S, PlanReplay, release_at_stops

    period, n = 0.025, 40  # 1 s of spools; rows every ROW_S
    columns = [(f"{c}_extension_m", float) for c in ("boom", "stick", "bucket")]
    rows = np.zeros(round(n * period / ROW_S) + 1, dtype=columns)
    stroke = p.CYLINDERS["bucket"].stroke
    rows["bucket_extension_m"] = np.linspace(stroke - 0.1, stroke + 0.02, len(rows)).clip(max=stroke)
    rows["boom_extension_m"] = 0.5
    rows["stick_extension_m"] = 0.0  # fully retracted throughout
    run = PlanReplay(rows, None, None, None, None, None, len(rows) - 1)
    spools = np.zeros((n, 4))
    spools[:, 1] = 0.009  # boom mid-stroke: kept
    spools[:, 3] = 0.009  # bucket curling: closed from where it reaches its stop
    spools[:, 2] = 0.005  # stick pushed out of its retracted end: kept
    released = release_at_stops(spools, run, period)
    at_stop = rows["bucket_extension_m"][(np.arange(n) * period / ROW_S + 1e-9).astype(int)] >= stroke - 0.005
    assert at_stop.any() and not at_stop.all()
    np.testing.assert_array_equal(released[:, 3], np.where(at_stop, 0.0, 0.009))
    np.testing.assert_array_equal(released[:, :3], spools[:, :3])
    spools[:, 2] = -0.005  # now pulled into its retracted end: closed throughout
    assert not release_at_stops(spools, run, period)[:, 2].any()
    spools[:, 2] = spools[:, 3] = 0.0
    assert release_at_stops(spools, run, period) is spools  # nothing to release: the plan itself


def test_a_replay_reaches_the_goal_only_where_it_stays_there():
    """A move that passes through the goal and comes to rest beyond it has not reached it; one that stays has, from
    the row it stays from."""
    from hexgym.planning.check import PlanReplay

    rows = np.zeros(6, dtype=[("t", float)])
    rows["t"] = np.arange(6) * 0.05

    def time_s(at: list[int]) -> float | None:
        return PlanReplay(rows, None, None, None, None, np.array(at, bool), 5).time_s

    assert time_s([0, 1, 1, 0, 0, 0]) is None  # through and beyond
    assert time_s([0, 1, 0, 0, 1, 1]) == pytest.approx(0.2)  # through, back, and there to the end
    assert time_s([1, 1, 1, 1, 1, 1]) == 0.0 and time_s([0] * 6) is None


def test_plans_keep_off_the_valves_toe():
    """Spools within the dead band or less than TOE_MARGIN_M past it are closed; the others are kept."""
    from hexgym.planning.rollouts import TOE_MARGIN_M, off_the_toe

    edge = p.SPOOL_DEAD_BAND + TOE_MARGIN_M
    spools = np.array([[1.523e-3, -1.6e-3, edge + 1e-6, -p.SPOOL_STROKE], [0.0, 1e-3, -edge - 1e-6, 5e-3]])
    out = off_the_toe(spools)
    np.testing.assert_array_equal(out, [[0.0, 0.0, edge + 1e-6, -p.SPOOL_STROKE], [0.0, 0.0, -edge - 1e-6, 5e-3]])
    assert spools[0, 0] == 1.523e-3  # a copy


def test_a_plans_goal_figure_is_checked_under_spool_noise(env, model):
    """``noise_spread``: the goal errors where the noisy executions come to rest, one per copy; without noise every
    copy is the plan's own execution."""
    from hexgym.planning import MachineState
    from hexgym.planning.goals import tip_goal
    from hexgym.planning.planner import noise_spread, plan_motion

    state = MachineState.from_env(env)
    goal = tip_goal(env.unwrapped.physics.tip_position() + np.array([0.0, 0.0, 0.6]), state.layout)
    plan = plan_motion(state, goal, model, budget=40, population=20, horizon_s=3.0, margin_m=0.0)
    quiet = noise_spread(plan, state, goal, model, sigma_m=0.0, copies=3)
    noisy = noise_spread(plan, state, goal, model, copies=4)
    assert quiet.shape == (3,) and np.ptp(quiet) == 0.0
    assert noisy.shape == (4,) and np.isfinite(noisy).all() and not np.array_equal(noisy, np.full(4, quiet[0]))


def test_the_planner_counts_what_the_tilt_would_spill():
    """The spill the planner charges is the environment's law: the payload beyond what the bucket retains at the
    most tilt so far (``retained_volumes`` is ``retained_volume`` elementwise)."""
    from types import SimpleNamespace

    from hexgym.envs.earthwork import retained_volume, retained_volumes
    from hexgym.planning.planner import evaluate

    tilts = np.linspace(-0.2, 3.0, 97)
    np.testing.assert_allclose(retained_volumes(tilts), [retained_volume(t) for t in tilts], rtol=1e-12)

    class Near:  # a goal every period reaches, at no error
        task = "tip"

        def reached(self, batch):
            return np.ones(batch.tilt.shape, bool)

        def error_m(self, mouth, tip):
            return np.zeros(mouth.shape[:-1])

    tilt = np.array([[0.0, 0.0], [0.0, 0.5]])
    batch = SimpleNamespace(tilt=tilt, times_s=np.array([0.025, 0.05]), clearance_m=np.ones((2, 2, 4)),
                            mouth=np.zeros((2, 2, 3)), tip=np.zeros((2, 2, 3)))  # fmt: skip
    heaped = retained_volume(0.0) * p.MATERIAL_DENSITY
    spill = evaluate(batch, Near(), heaped, margin_m=0.0)["spill"]
    assert spill[0] == 0.0 and spill[1] == 0.0  # both end at the first period: no tilt yet
    batch.tilt = np.array([[0.5, 0.5], [0.0, 0.0]])
    spill = evaluate(batch, Near(), heaped, margin_m=0.0)["spill"]
    assert spill[0] == pytest.approx(heaped - retained_volume(0.5) * p.MATERIAL_DENSITY) and spill[1] == 0.0


def test_a_prediction_from_a_reference_environment_starts_from_its_circuit_state():
    """From ``HexLoading-v0(model="reference")`` the state carries the reference's circuit state (pressures, pump
    displacements), and the circuit model's rollouts start from it: the swing turning at full spool is predicted
    where the reference takes it (without it the rollout starts its circuit at rest and lags by a tenth of a rad)."""
    import dataclasses

    from hexgym.planning import MachineState, RolloutModel

    env = gym.make("HexLoading-v0", model="reference")
    env.reset(seed=0)
    action = np.array([0.5, 0.8, 0.3, 0.2], np.float32)
    for _ in range(30):
        env.step(action)
    state = MachineState.from_env(env)
    assert state.hydraulic_state is not None and state.hydraulic_state.shape == (14,) and state.qd[0] > 0.3
    model = RolloutModel(contacts=False)
    try:
        spools = np.tile(action * p.SPOOL_STROKE, (40, 1))
        carried = model.rollout(state, spools, 1.0).q[0, 3::4]
        at_rest = model.rollout(dataclasses.replace(state, hydraulic_state=None), spools, 1.0).q[0, 3::4]
    finally:
        model.close()
    moved = []
    for _ in range(10):
        env.step(action)
        moved.append(env.unwrapped.physics.joint_positions().copy())
    env.close()
    assert np.abs(carried - np.array(moved)).max() < 0.02
    assert np.abs(at_rest[:, 0] - np.array(moved)[:, 0]).max() > 0.05
    with pytest.raises(ValueError, match="hydraulic state must be 14 finite numbers"):
        model.machine.set_hydraulic_state(np.full(14, np.nan), np.zeros(4))

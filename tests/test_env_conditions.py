"""HexLoading-v0's robustness options: shifted site ranges, a heavier material, a weaker engine."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import hexgym  # noqa: F401  (registers the environments)
from hexgym.envs.loading import _FRONT_GUESS, LoadingConfig
from hexgym.envs.world import entry_radius, sample_layout
from hexgym.hydraulics.circuit import HydraulicCircuit
from hexgym.hydraulics.overrides import OverriddenCircuit, engine_power_limit_w, with_engine_power
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.model.circuit_kernel import pump_power_limit

_CAB_LENGTH, _WALL = 1.8, 0.08


def _toe_clearance(layout) -> float:
    """How far (m) the truck's footprint (bed and cab) is from the pile's toe; negative: it reaches over it."""
    toe = layout.pile_top_radius + layout.pile_height / math.tan(p.MATERIAL_REPOSE_ANGLE)
    yaw = layout.truck_yaw
    d = np.subtract(layout.pile_centre, layout.truck_centre)
    x, y = d[0] * math.cos(yaw) + d[1] * math.sin(yaw), -d[0] * math.sin(yaw) + d[1] * math.cos(yaw)
    half_l, half_w = p.TRUCK_BED_LENGTH / 2 + _WALL, p.TRUCK_BED_WIDTH / 2 + _WALL
    dx = max(-half_l - x, 0.0, x - half_l - _CAB_LENGTH)
    dy = max(-half_w - y, 0.0, y - half_w)
    return math.hypot(dx, dy) - toe


def _inside(value: float, bounds) -> bool:
    return bounds[0] <= value <= bounds[1]


def test_shifted_layouts_lie_outside_the_training_ranges_within_reach_and_clear_of_the_truck():
    rng = np.random.default_rng(0)
    training = [sample_layout(rng) for _ in range(2000)]
    shifted = [sample_layout(rng, "shifted") for _ in range(2000)]
    worst = min(_toe_clearance(layout) for layout in training)
    for layout in shifted:
        pile_distance, truck_distance = math.hypot(*layout.pile_centre), layout.truck_distance
        pile_angle, truck_angle = layout.pile_direction, abs(layout.truck_direction)
        assert not _inside(pile_distance, p.PILE_DISTANCE_RANGE)
        assert not _inside(pile_angle, p.PILE_SWING_RANGE)
        assert not _inside(truck_distance, p.TRUCK_DISTANCE_RANGE)
        assert not _inside(truck_angle, p.TRUCK_SWING_RANGE)
        assert np.sign(pile_angle) != np.sign(layout.truck_direction)  # the pile turned away from the truck
        assert _toe_clearance(layout) >= worst  # the truck no nearer the pile than in training
    # within reach: a cut's entry above the highest pile, teeth down (the farthest shifted pile)
    far = max(shifted, key=entry_radius)
    misses = [kinematics.front_angles_for(entry_radius(far), p.PILE_HEIGHT_RANGE[1] + 0.3, b, _FRONT_GUESS)[1]
              for b in np.linspace(-3.0, 0.0, 13)]  # fmt: skip
    assert min(misses) < 0.05


def test_shifted_starts_are_collision_free_and_seeded():
    env = gym.make("HexLoading-v0", site_ranges="shifted").unwrapped
    layouts = []
    for seed in range(6):
        obs, info = env.reset(seed=seed)
        assert env._hard_contact_force() == 0.0 and np.isfinite(obs).all()
        layouts.append(env.layout)
    env.reset(seed=3)
    assert env.layout == layouts[3]
    nominal = gym.make("HexLoading-v0").unwrapped
    nominal.reset(seed=3)
    assert nominal.layout != layouts[3]


def test_a_heavier_material_fills_the_bucket_with_more_and_digs_harder():
    from hexgym.envs import earthwork as ew

    heavy = 1.25 * p.MATERIAL_DENSITY
    assert ew.digging_resistance(0.3, 0.5, 0.0, heavy) == pytest.approx(1.25 * ew.digging_resistance(0.3, 0.5, 0.0))
    assert ew.side_plate_force(0.3, heavy) == pytest.approx(1.25 * ew.side_plate_force(0.3))
    full = ew.retained_volume(0.0) * heavy  # a heaped bucket of it holds 25 % more kilograms: nothing spills
    assert ew.spill_out(full, 0.0, 0.1, heavy) == 0.0 and ew.spill_out(full, 0.0, 0.1) > 0.0
    config = LoadingConfig(material_density_scale=1.25)
    assert config.material_density == pytest.approx(heavy)
    env = gym.make("HexLoading-v0", material_density_scale=1.25).unwrapped
    env.reset(seed=0)
    assert env.earth.density == pytest.approx(heavy)
    env.physics.set_payload(full)  # a heaped bucket of the heavier material masses the machine


def test_a_weaker_engine_lowers_the_pump_power_limit_on_every_model():
    assert engine_power_limit_w(1.0) == pytest.approx(p.PUMP_POWER_LIMIT)
    assert with_engine_power(None, 1.0) is None
    weaker = with_engine_power(None, 0.9)
    assert weaker.power_limit_w == pytest.approx((0.9 * p.ENGINE_POWER - p.ACCESSORY_POWER) * p.PUMP_OVERALL_EFFICIENCY)
    assert pump_power_limit(OverriddenCircuit(weaker)) == weaker.power_limit_w
    assert pump_power_limit(HydraulicCircuit()) == p.PUMP_POWER_LIMIT
    assert LoadingConfig(engine_power_scale=0.9).engine_power_w == pytest.approx(0.9 * p.ENGINE_POWER)


def _front_motion(backend: str, **options) -> np.ndarray:
    env = gym.make("HexLoading-v0", backend=backend, **options).unwrapped
    env.reset(seed=3)
    angles = []
    for k in range(16):  # every spool open: the pumps at their power limit
        env.step(np.array([1.0, 1.0, -1.0, -1.0]) if k < 8 else np.array([-1.0, -0.5, 1.0, 1.0]))
        angles.append(env.physics.data.qpos[:4].copy())
    return np.array(angles)


def test_a_weaker_engine_slows_the_machine_alike_on_the_native_and_python_backends():
    from hexgym.model.plugin import load_plugin

    if load_plugin():
        pytest.skip("the native plugin is not built")
    weak_native = _front_motion("native", engine_power_scale=0.9)
    weak_python = _front_motion("python", engine_power_scale=0.9)
    np.testing.assert_allclose(weak_native, weak_python, atol=1e-9)
    nominal = _front_motion("native")
    assert np.abs(nominal - weak_native).max() > 1e-3  # the limit binds


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"site_ranges": "wide"}, r"site_ranges must be one of \('training', 'shifted'\), got 'wide'"),
        ({"material_density_scale": 3.0}, r"material_density_scale must be a finite number from 0.5 to 1.5, got 3.0"),
        ({"engine_power_scale": 1.2}, r"engine_power_scale must be a finite number from 0.5 to 1, got 1.2"),
        ({"engine_power_scale": "weak"}, r"engine_power_scale must be a finite number from 0.5 to 1, got 'weak'"),
        ({"engine_power_scale": 0.9, "tables": "paper"}, r"engine_power_scale=0.9 does not apply to tables='paper'"),
    ],
)
def test_bad_robustness_options_are_refused_in_one_line(options, message):
    with pytest.raises(ValueError, match=message) as caught:
        gym.make("HexLoading-v0", **options)
    assert "\n" not in str(caught.value)


def test_evaluate_refuses_a_bad_robustness_flag_naming_it(capsys):
    from hexgym_lab.cli import main

    assert main(["evaluate", "--policy", "scripted", "--episodes", "1", "--material-density-scale", "2"]) != 0
    err = capsys.readouterr().err.strip()
    assert "--material-density-scale 2.0" in err and "0.5 to 1.5" in err and "\n" not in err

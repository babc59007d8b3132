"""hexgym.machine.kinematics against finite differences and against MuJoCo's own sites and Jacobians."""

import mujoco
import numpy as np
import pytest

from hexgym.machine import kinematics
from hexgym.machine.physics import ExcavatorPhysics

PIN_PAIRS = {
    "boom": ("boom_cylinder_base_pin", "boom_cylinder_rod_pin"),
    "stick": ("stick_cylinder_base_pin", "stick_cylinder_rod_pin"),
    "bucket": ("bucket_cylinder_base_pin", "bucket_cylinder_rod_pin"),
}


def _random_poses(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lo = [-np.pi] + [kinematics.joint_range(j)[0] for j in kinematics.FRONT_CYLINDERS]
    hi = [np.pi] + [kinematics.joint_range(j)[1] for j in kinematics.FRONT_CYLINDERS]
    return rng.uniform(lo, hi, size=(n, 4))


@pytest.fixture(scope="module")
def physics() -> ExcavatorPhysics:
    return ExcavatorPhysics()


@pytest.mark.parametrize("name", kinematics.FRONT_CYLINDERS)
def test_moment_arm_is_the_derivative_of_length(name):
    h = 1e-6
    for angle in np.linspace(*kinematics.joint_range(name), 25):
        fd = (kinematics.cylinder_length(name, angle + h) - kinematics.cylinder_length(name, angle - h)) / (2 * h)
        assert kinematics.moment_arm(name, angle) == pytest.approx(fd, rel=1e-6, abs=1e-8)
        assert kinematics.moment_arm(name, angle) > 0.05  # a positive spool moves the joint positively


@pytest.mark.parametrize("name", kinematics.FRONT_CYLINDERS)
def test_joint_angle_inverts_cylinder_length(name):
    for angle in np.linspace(*kinematics.joint_range(name), 11):
        assert kinematics.joint_angle(name, kinematics.cylinder_length(name, angle)) == pytest.approx(angle, abs=1e-9)
    with pytest.raises(ValueError, match=name):
        kinematics.joint_angle(name, 50.0)


def test_mujoco_pin_distances_are_the_cylinder_lengths(physics):
    data = physics.data
    for q in _random_poses(40):
        physics.set_joint_state(q)
        for k, (name, (base, rod)) in enumerate(PIN_PAIRS.items(), start=1):
            length = np.linalg.norm(data.site(base).xpos - data.site(rod).xpos)
            assert length == pytest.approx(kinematics.cylinder_length(name, q[k]), abs=1e-9)


def test_closed_chains_assemble_exactly(physics):
    """Positions and velocities of the passive joints satisfy every connect constraint."""
    data = physics.data
    rng = np.random.default_rng(1)
    for q in _random_poses(40, seed=2):
        physics.set_joint_state(q, rng.normal(size=4))
        equality = data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
        assert np.abs(data.efc_pos[equality]).max() < 1e-9
        assert np.abs(data.efc_vel[equality]).max() < 1e-6


def test_moment_arms_against_mujoco_sites(physics):
    """dC/dq from MuJoCo's pin sites (central differences of assembled poses) = the module's."""
    data, h = physics.data, 1e-6
    for q in _random_poses(15, seed=3):
        for k, (name, (base, rod)) in enumerate(PIN_PAIRS.items(), start=1):
            lengths = []
            for sign in (1, -1):
                dq = np.zeros(4)
                dq[k] = sign * h
                physics.set_joint_state(q + dq)
                lengths.append(np.linalg.norm(data.site(base).xpos - data.site(rod).xpos))
            assert (lengths[0] - lengths[1]) / (2 * h) == pytest.approx(kinematics.moment_arm(name, q[k]), rel=1e-5)


def test_tip_position_and_jacobian_match_mujoco(physics):
    model, data = physics.model, physics.data
    tip = model.site("tip").id
    jacp = np.zeros((3, model.nv))
    for q in _random_poses(40, seed=4):
        physics.set_joint_state(q)
        np.testing.assert_allclose(kinematics.tip_position(q), data.site_xpos[tip], atol=1e-9)
        mujoco.mj_jacSite(model, data, jacp, None, tip)
        dofs = [model.joint(n).dofadr[0] for n in kinematics.JOINTS]
        np.testing.assert_allclose(kinematics.tip_jacobian(q), jacp[:, dofs], atol=1e-9)


def test_tip_jacobian_is_the_derivative_of_tip_position():
    h = 1e-6
    for q in _random_poses(10, seed=5):
        fd = np.column_stack(
            [(kinematics.tip_position(q + h * e) - kinematics.tip_position(q - h * e)) / (2 * h) for e in np.eye(4)]
        )
        np.testing.assert_allclose(kinematics.tip_jacobian(q), fd, atol=1e-6)

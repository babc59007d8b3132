"""The MJCF model: generated from the parameters, compiles cleanly, masses, ranges, stability."""

from pathlib import Path

import mujoco
import numpy as np
import pytest

from hexgym.machine import kinematics, mjcf
from hexgym.machine import parameters as p
from hexgym.machine.assets import AssetError, asset_path, assets_dir, load_model
from hexgym.machine.physics import (
    ExcavatorPhysics,
    contiguous_index,
    force_actuated_model,
    skip_collisions_if_none_possible,
)


def _warnings(data: mujoco.MjData) -> dict[str, int]:
    return {mujoco.mjtWarning(i).name: int(w.number) for i, w in enumerate(data.warning) if w.number}


@pytest.mark.parametrize(("name", "lean"), [("cat325.xml", False), ("cat325_lean.xml", True)])
def test_committed_xml_matches_generator(name, lean):
    committed = asset_path(name).read_text()
    meshes = str(assets_dir() / "meshes")
    generated = mjcf.model_xml(mjcf.home_keyframe(mjcf.model_xml(lean=lean), meshes), lean=lean)
    assert committed == generated, f"assets/{name} is stale: run `hexgym build-assets`"


@pytest.mark.parametrize(("scene", "machine_file"), [("scene_lean.xml", "cat325_lean.xml")])
def test_generated_scenes_are_the_scene_around_their_machine(scene, machine_file):
    generated = mjcf.scene_xml_around(asset_path("scene.xml").read_text(), machine_file)
    assert asset_path(scene).read_text() == generated, "stale: run `hexgym build-assets`"
    model = load_model(scene=True, lean=True)
    assert model.nv == 4 and model.geom("ground").id >= 0 and model.camera("chase").id >= 0


def test_lean_model_has_the_full_models_mass_and_loads():
    """The lean model lumps cylinders and four-bar into point masses: same mass, loads within 2 % of relief."""
    from hexgym.model.python_backend import LearnedModel

    full, lean = LearnedModel(model=load_model()), LearnedModel(model=load_model(lean=True))
    assert lean.physics.model.nv == 4 and lean.physics.model.neq == 0
    assert full.physics.model.body_subtreemass[1] == pytest.approx(lean.physics.model.body_subtreemass[1], rel=1e-9)
    relief = np.array([p.LINE_RELIEF[c] * p.CYLINDERS[c].head_area for c in kinematics.FRONT_CYLINDERS])
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = np.array([0.0, *(rng.uniform(*kinematics.joint_range(j)) for j in kinematics.JOINTS[1:])])
        full.reset(q, payload_kg=1000.0)
        lean.reset(q, payload_kg=1000.0)
        assert np.all(np.abs(lean.cylinder_loads() - full.cylinder_loads()) < 0.02 * relief)
        assert lean.physics.swing_inertia() == pytest.approx(full.physics.swing_inertia(), rel=0.03)


@pytest.mark.parametrize(("scene", "lean"), [(False, False), (True, False), (False, True), (True, True)])
def test_compiles_without_warnings(scene, lean, capfd):
    model = load_model(scene=scene, lean=lean)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    mujoco.mj_forward(model, data)
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    assert _warnings(data) == {}
    assert model.nu == 4 and [model.actuator(i).name for i in range(4)] == list(kinematics.JOINTS)


def test_operating_mass_and_parts():
    model = load_model()
    assert model.body_subtreemass[model.body("undercarriage").id] == pytest.approx(27000, rel=0.02)
    assert model.body("boom").mass[0] == p.BOOM_MASS
    assert model.body("stick").mass[0] == p.STICK_MASS
    upper = model.body("upper").id
    assert model.body_mass[upper] == p.UPPER_MASS
    assert model.body_inertia[upper][2] == pytest.approx(p.UPPER_YAW_INERTIA)
    bucket_and_linkage = sum(
        model.body(n).mass[0]
        for n in ("bucket", "guide_link", "power_link", "bucket_cylinder_barrel", "bucket_cylinder_rod")
    )
    assert bucket_and_linkage == pytest.approx(1100 + 230, abs=150)  # bucket + linkage ~1.1 t, + its cylinder


def test_joint_ranges_are_the_cylinder_strokes():
    model = load_model()
    for name in kinematics.FRONT_CYLINDERS:
        lo, hi = model.joint(name).range
        cyl = p.CYLINDERS[name]
        assert kinematics.cylinder_length(name, lo) == pytest.approx(cyl.retracted_length, abs=1e-6)
        assert kinematics.cylinder_length(name, hi) == pytest.approx(cyl.extended_length, abs=1e-6)
        slide = model.joint(f"{name}_cylinder")
        assert tuple(slide.range) == pytest.approx((0.0, cyl.stroke))
    # plausible 25 t envelope: boom about -50..+52 deg, stick and bucket wide
    assert np.degrees(model.joint("boom").range) == pytest.approx([-50, 52], abs=3)
    assert np.ptp(np.degrees(model.joint("stick").range)) > 110
    assert np.ptp(np.degrees(model.joint("bucket").range)) > 160
    assert not model.jnt_limited[model.joint("swing").id]


def test_sites_named_after_pins():
    model = load_model()
    names = {model.site(i).name for i in range(model.nsite)}
    for pin in (
        "tip",
        "boom_foot_pin",
        "boom_cylinder_base_pin",
        "boom_cylinder_rod_pin",
        "stick_cylinder_base_pin",
        "stick_cylinder_rod_pin",
        "stick_pin",
        "bucket_cylinder_base_pin",
        "bucket_cylinder_rod_pin",
        "guide_link_pivot_pin",
        "bucket_link_pin",
        "bucket_pin",
    ):
        assert pin in names


def test_home_keyframe_is_assembled_and_holds():
    physics = ExcavatorPhysics()
    data = physics.data
    assert np.abs(data.efc_pos[data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY]).max() < 1e-9
    np.testing.assert_allclose(physics.joint_positions(), mjcf.HOME, atol=1e-12)
    physics.set_payload(2000.0)
    physics.step(2500)  # 5 s with closed spools (zero rate commands) and a full bucket
    np.testing.assert_allclose(physics.joint_positions(), mjcf.HOME, atol=6e-3)
    assert np.abs(physics.joint_velocities()).max() < 1e-4


def test_ten_seconds_of_random_commands_are_clean():
    physics = ExcavatorPhysics(scene=True)
    rng = np.random.default_rng(0)
    lo, hi = physics.model.actuator_ctrlrange.T
    for i in range(int(10.0 / physics.timestep)):
        if i % 100 == 0:
            physics.data.ctrl[:] = rng.uniform(lo, hi)
        physics.step()
    data = physics.data
    assert _warnings(data) == {}
    assert np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))
    equality = data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
    assert np.abs(data.efc_pos[equality]).max() < 2e-3  # the cylinders stay on their pins (m)
    q = physics.joint_positions()
    for k, name in enumerate(kinematics.FRONT_CYLINDERS, start=1):
        lo_q, hi_q = physics.model.joint(name).range
        assert lo_q - 0.02 <= q[k] <= hi_q + 0.02


def test_force_actuated_model_takes_torques():
    physics = ExcavatorPhysics(force_actuated_model())
    assert physics.model.na == 0
    physics.set_actuator_forces(np.zeros(3), 0.0)
    physics.step(200)
    assert physics.joint_velocities()[1] < -0.01  # no cylinder force: the boom falls


@pytest.mark.parametrize("text", [None, "<mujoco><worldbody><geom type='mesh' mesh='nope'/></worldbody></mujoco>"])
def test_missing_or_corrupt_asset_names_the_file(tmp_path: Path, text):
    path = tmp_path / "broken.xml"
    if text is not None:
        path.write_text(text)
    with pytest.raises(AssetError, match="broken.xml"):
        load_model(path)
    with pytest.raises(AssetError, match="no_such_file.xml"):
        asset_path("no_such_file.xml")


def test_payload_and_tip_force_change_the_loads():
    physics = ExcavatorPhysics()
    inertia0 = physics.swing_inertia()
    physics.set_payload(2000.0)
    assert physics.swing_inertia() > inertia0 + 2000 * 2.0**2
    with pytest.raises(ValueError, match="payload"):
        physics.set_payload(float("nan"))
    with pytest.raises(ValueError, match="tip force"):
        physics.apply_tip_force(np.array([1.0, np.nan, 0.0]))


def test_setting_the_payload_mid_motion_keeps_the_state():
    physics = ExcavatorPhysics(load_model(lean=True))
    physics.set_joint_state(np.array([0.4, 0.2, 0.6, 0.3]), np.array([0.1, -0.05, 0.2, 0.0]))
    physics.data.time = 3.0
    q, qd = physics.joint_positions(), physics.joint_velocities()
    physics.set_payload(1500.0)
    np.testing.assert_array_equal(physics.joint_positions(), q)
    np.testing.assert_array_equal(physics.joint_velocities(), qd)
    assert physics.data.time == 3.0 and physics.model.body("payload").mass[0] == 1500.0


def test_collision_pass_is_skipped_only_where_nothing_can_touch():
    contact_off = int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    machine = ExcavatorPhysics(load_model(lean=True))  # machine geoms collide only with world geoms
    assert machine.model.opt.disableflags & contact_off
    scene = ExcavatorPhysics(scene=True)  # the ground can touch the bucket
    assert not scene.model.opt.disableflags & contact_off
    lean = load_model(lean=True)
    lean.geom_conaffinity[lean.geom("bucket_collision").id] = 2  # now the bucket could hit the boom
    assert not skip_collisions_if_none_possible(lean) and not lean.opt.disableflags & contact_off


def test_contiguous_index_is_a_slice_only_for_consecutive_ids():
    values = np.arange(10.0) * 1.5
    assert contiguous_index(np.array([3, 4, 5])) == slice(3, 6)
    for ids in ([3, 4, 5], [0], [2, 1, 0], [1, 3, 4], [4, 4]):
        index = contiguous_index(np.array(ids))
        assert isinstance(index, slice) == (ids in ([3, 4, 5], [0]))
        assert np.array_equal(values[index], values[ids])

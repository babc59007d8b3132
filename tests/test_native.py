"""The native learned model (hexgym.mbl MuJoCo plugin): built, loaded, equal to the Python path, exact state."""

import json
import shutil
import sysconfig
from pathlib import Path

import mujoco
import numpy as np
import pytest

import hexgym  # noqa: F401  (loads the plugin)
from hexgym import native
from hexgym.fit import packaged_tables_dir
from hexgym.learned import LearnedModel
from hexgym.mjcf_native import MBL_MODEL_FILE, mbl_model_xml
from hexgym.replay import replay
from hexgym.resources import asset_path
from hexgym.validate import scenarios

_COMPILER = shutil.which(sysconfig.get_config_var("CXX").split()[0] if sysconfig.get_config_var("CXX") else "c++")
needs_plugin = pytest.mark.skipif(not native.native_available(), reason=f"native plugin: {native.load_plugin()}")


def _tip(rows: np.ndarray) -> np.ndarray:
    return np.column_stack([rows["tip_x"], rows["tip_y"], rows["tip_z"]])


def test_plugin_is_built_wherever_a_compiler_is():
    """A machine with a C++ compiler and zlib's header must have built the plugin (pip install builds it)."""
    if _COMPILER is None or not Path("/usr/include/zlib.h").exists():
        pytest.skip("no C++ compiler or zlib.h here: the Python path is the learned model")
    assert native.load_plugin() == ""
    assert native.plugin_library() is not None


@needs_plugin
def test_library_matches_the_running_mujoco():
    import ctypes

    lib = ctypes.CDLL(str(native.plugin_library()))
    assert lib.hexgym_mbl_built_mujoco_version() == mujoco.mj_version()


def test_committed_mbl_model_matches_generator():
    assert asset_path(MBL_MODEL_FILE).read_text() == mbl_model_xml(), "stale: run `hexgym build-assets`"


@needs_plugin
def test_mbl_model_compiles_and_a_boom_spool_lifts_the_boom():
    """What the viewer shows: cat325_mbl.xml, ctrl = spools in mm."""
    m = mujoco.MjModel.from_xml_path(str(asset_path(MBL_MODEL_FILE)))
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    q0 = d.qpos.copy()
    d.ctrl[m.actuator("boom").id] = 8.0
    for _ in range(40):  # 1 s
        mujoco.mj_step(m, d)
    dq = d.qpos - q0
    assert dq[m.joint("boom").qposadr[0]] > 0.05
    assert np.abs(np.delete(dq, m.joint("boom").qposadr[0])).max() < 1e-6
    d.ctrl[:] = 0.0  # spools closed: the boom holds
    q1 = d.qpos.copy()
    for _ in range(40):
        mujoco.mj_step(m, d)
    assert np.abs(d.qpos - q1).max() < 1e-5


@needs_plugin
@pytest.mark.parametrize("test", ["test1", "test2", "test3"])
def test_native_and_python_give_the_same_trajectory(test):
    """One source of truth: the same tables, loads and logic (validate's command logs, up to 50 s)."""
    log, pose = scenarios()[test]
    python = replay(LearnedModel(), log, start=pose)
    native_rows = replay(native.NativeLearnedModel(), log, start=pose)
    err = np.linalg.norm(_tip(python) - _tip(native_rows), axis=1)
    print(f"{test}: {log.duration:g} s, max tip difference {err.max():.3e} m")
    assert err.max() < 1e-3
    assert np.ptp(_tip(python), axis=0).max() > 1.0  # the machine did move


@needs_plugin
def test_native_holds_targets_over_a_longer_control_period():
    log, pose = scenarios()["test1"]
    python = replay(LearnedModel(control_period=0.05), log, start=pose, dt_out=0.1)
    native_rows = replay(native.NativeLearnedModel(control_period=0.05), log, start=pose, dt_out=0.1)
    assert np.linalg.norm(_tip(python) - _tip(native_rows), axis=1).max() < 1e-3


def _run_steps(model: native.NativeLearnedModel, log, k0: int, k1: int) -> np.ndarray:
    """``mj_step`` k0..k1 with the log's spools as ctrl (mm); qpos after each."""
    m, d, qs = model.physics.model, model.physics.data, []
    for k in range(k0, k1):
        d.ctrl[:] = log.spools_at((k + 1e-9) * m.opt.timestep)
        mujoco.mj_step(m, d)
        qs.append(d.qpos.copy())
    return np.array(qs)


@needs_plugin
def test_state_round_trip_reproduces_the_trajectory_exactly():
    """mj_getState/mj_setState capture the plugin's state: the swing's rate target (act), the
    targets held within a control period and the step's place in it (plugin state)."""
    log, pose = scenarios()["test3"]
    model = native.NativeLearnedModel(control_period=0.05)  # two steps per table query
    m, d = model.physics.model, model.physics.data
    model.reset(pose)
    k_save = 301  # mid-period, swinging and lifting (7 mm swing, 9 mm boom)
    _run_steps(model, log, 0, k_save)
    kind = mujoco.mjtState.mjSTATE_INTEGRATION
    saved = np.empty(mujoco.mj_stateSize(m, kind))
    mujoco.mj_getState(m, d, saved, kind)
    assert abs(d.act[0]) > 0.1 and d.plugin_state[5] == 1.0  # swinging, one step into a period
    first = _run_steps(model, log, k_save, k_save + 400)
    mujoco.mj_setState(m, d, saved, kind)
    again = _run_steps(model, log, k_save, k_save + 400)
    np.testing.assert_array_equal(first, again)
    # the state is what makes it exact: without the activation or the plugin state the run differs
    for field in ("act", "plugin_state"):
        mujoco.mj_setState(m, d, saved, kind)
        getattr(d, field)[:] = 0.0
        assert np.abs(_run_steps(model, log, k_save, k_save + 400) - first).max() > 1e-6, field


def _copy_tables(tmp_path: Path) -> Path:
    directory = tmp_path / "tables"
    shutil.copytree(packaged_tables_dir(), directory)
    return directory


def _rewrite_meta(path: Path, **changes: object) -> None:
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta"][0]))
    meta.update(changes)
    arrays["meta"] = np.array([json.dumps(meta, sort_keys=True)])
    with path.open("wb") as fh:
        np.savez_compressed(fh, **arrays)


@needs_plugin
def test_other_tables_directory_is_used(tmp_path):
    directory = _copy_tables(tmp_path)
    model = native.NativeLearnedModel(tables_dir=directory)
    assert native.plugin_config_values(model.physics.model)["tables"] == str(directory.resolve())
    model.reset()
    model.step(np.array([0.0, 0.008, 0.0, 0.0]), n=10)
    assert model.physics.joint_velocities()[1] > 0.05


@needs_plugin
@pytest.mark.parametrize(
    ("damage", "message"),
    [
        ("version", "has format version 2; this plugin reads version 1"),
        ("truncate", "is corrupt or not a table file"),
        ("inputs", "has inputs [stick_spool_m, swing_spool_m"),
        ("missing", "does not exist"),
    ],
)
def test_bad_table_file_fails_model_loading_naming_file_and_problem(tmp_path, damage, message):
    directory = _copy_tables(tmp_path)
    path = directory / "swing.npz"
    if damage == "version":
        _rewrite_meta(path, format_version=2)
    elif damage == "truncate":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif damage == "inputs":
        _rewrite_meta(
            path, inputs=["stick_spool_m", "swing_spool_m", "stick_force_n", "swing_inertia_kgm2", "swing_rate_radps"]
        )
    else:
        path.unlink()
    with pytest.raises(ValueError) as info:
        native.load_mbl_model(directory)
    assert str(path) in str(info.value) and message in str(info.value)


@needs_plugin
def test_bad_spools_are_refused_before_the_plugin_sees_them():
    model = native.NativeLearnedModel()
    model.reset()
    with pytest.raises(ValueError, match="not a finite number"):
        model.step(np.array([0.0, np.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match="shape"):
        model.step(np.zeros(3))


def test_make_learned_model_backends():
    assert isinstance(native.make_learned_model("python"), LearnedModel)
    with pytest.raises(ValueError, match="backend must be one of"):
        native.make_learned_model("fortran")
    auto = native.make_learned_model("auto")
    expected = native.NativeLearnedModel if native.native_available() else LearnedModel
    assert isinstance(auto, expected)


@needs_plugin
def test_both_backends_stall_at_the_ground_alike_without_kicks():
    """Driving the bucket into the ground: it stops within a step, no joint is flung, both backends agree."""
    from hexgym.envs.world import build_world_model

    models = {
        "python": LearnedModel(model=build_world_model(asset_path("scene_lean.xml"))),
        "native": native.NativeLearnedModel(model=build_world_model(None, machine_file=MBL_MODEL_FILE)),
    }
    rows = {}
    for name, model in models.items():
        model.reset(np.array([0.0, 0.2, 0.9, 0.3]))
        tips = []
        for k in range(160):  # 4 s: boom and stick down into the ground, then swinging along it
            model.step(np.array([0.006 if k > 80 else 0.0, -0.011, 0.011, 0.0]))
            d = model.physics.data
            depth = -min((c.dist for c in d.contact[: d.ncon]), default=0.0)
            assert depth < 0.12 and np.all(np.abs(model.physics.joint_velocities()) <= 2.0 + 1e-9)
            tips.append(model.physics.tip_position())
        rows[name] = np.array(tips)
    assert rows["python"][:, 2].min() > -0.3  # the teeth stay near the surface, not through it
    np.testing.assert_allclose(rows["python"], rows["native"], atol=1e-6)

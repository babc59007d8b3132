"""The native learned model (hexgym.mbl MuJoCo plugin): built, loaded, equal to the Python path, exact state."""

import json
import shutil
import sysconfig
from pathlib import Path

import mujoco
import numpy as np
import pytest

import hexgym  # noqa: F401  (loads the plugin)
from hexgym.machine import kinematics
from hexgym.machine.assets import asset_path, assets_dir, load_model
from hexgym.mbl.schema import CIRCUIT_TABLE_SETS, NATIVE_TABLE_SETS
from hexgym.mbl.table import packaged_tables_dir
from hexgym.model import backend, native_backend, plugin
from hexgym.model.plugin_mjcf import MBL_FULL_MODEL_FILE, MBL_MODEL_FILE, mbl_model_xml
from hexgym.model.python_backend import LearnedModel
from hexgym.model.replay import replay
from hexgym_lab.validate import scenarios

_COMPILER = shutil.which(sysconfig.get_config_var("CXX").split()[0] if sysconfig.get_config_var("CXX") else "c++")
needs_plugin = pytest.mark.skipif(not plugin.native_available(), reason=f"native plugin: {plugin.load_plugin()}")


def _tip(rows: np.ndarray) -> np.ndarray:
    return np.column_stack([rows["tip_x_m"], rows["tip_y_m"], rows["tip_z_m"]])


def test_plugin_is_built_wherever_a_compiler_is():
    """A machine with a C++ compiler and zlib's header must have built the plugin (pip install builds it)."""
    if _COMPILER is None or not Path("/usr/include/zlib.h").exists():
        pytest.skip("no C++ compiler or zlib.h here: the Python path is the learned model")
    assert plugin.load_plugin() == ""
    assert plugin.plugin_library() is not None


@needs_plugin
def test_library_matches_the_running_mujoco():
    import ctypes

    lib = ctypes.CDLL(str(plugin.plugin_library()))
    assert lib.hexgym_mbl_built_mujoco_version() == mujoco.mj_version()


@pytest.mark.parametrize(("name", "full"), [(MBL_MODEL_FILE, False), (MBL_FULL_MODEL_FILE, True)])
def test_committed_mbl_model_matches_generator(name, full):
    assert asset_path(name).read_text() == mbl_model_xml(full=full), "stale: run `hexgym build-assets`"


@needs_plugin
def test_mbl_model_compiles_and_a_boom_spool_lifts_the_boom():
    """What the viewer shows: cat325_mbl.xml (the circuit model), ctrl = spools in mm. The other joints give only
    what their closed chambers' oil springs let the boom's acceleration move them (as the reference does); with
    the spools closed the boom rings down on its oil and then holds."""
    m = mujoco.MjModel.from_xml_path(str(asset_path(MBL_MODEL_FILE)))
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    q0 = d.qpos.copy()
    d.ctrl[m.actuator("boom").id] = 8.0
    for _ in range(40):  # 1 s
        mujoco.mj_step(m, d)
    dq = d.qpos - q0
    assert dq[m.joint("boom").qposadr[0]] > 0.05
    assert np.abs(np.delete(dq, m.joint("boom").qposadr[0])).max() < 2e-3
    d.ctrl[:] = 0.0  # spools closed: the boom rings down on its oil (both pumps raised it fast), then holds
    for _ in range(120):
        mujoco.mj_step(m, d)
    q1 = d.qpos.copy()
    for _ in range(40):
        mujoco.mj_step(m, d)
    assert np.abs(d.qpos - q1).max() < 2e-3


_JOINT_FOR_SPOOL = {"swing": 0, "boom": 1, "stick": 2, "bucket": 3}


@needs_plugin
@pytest.mark.parametrize("joint", list(_JOINT_FOR_SPOOL))
def test_full_machine_with_plugin_moves_each_joint_its_way(joint):
    """What the viewer shows on the full machine (cat325_mbl_full.xml): from the keyframe, ctrl = spools
    in mm; each spool moves its joint the way the lean machine does and no other, a closed spool holds."""
    moves = {}
    for name in (MBL_FULL_MODEL_FILE, MBL_MODEL_FILE):
        m = mujoco.MjModel.from_xml_path(str(asset_path(name)))
        d = mujoco.MjData(m)
        mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
        main = [m.joint(j).qposadr[0] for j in _JOINT_FOR_SPOOL]
        q0 = d.qpos[main].copy()
        d.ctrl[m.actuator(joint).id] = 8.0
        while d.time < 1.0:
            mujoco.mj_step(m, d)
        moves[name] = d.qpos[main] - q0
        k = _JOINT_FOR_SPOOL[joint]
        if joint == "swing":  # + turns counter-clockwise seen from above
            assert moves[name][0] > 0.1, name
        else:  # + extends the joint's cylinder
            assert (
                kinematics.cylinder_length(joint, d.qpos[main][k]) > kinematics.cylinder_length(joint, q0[k]) + 0.05
            ), name
        d.ctrl[:] = 0.0  # spools closed: the machine holds (the swing once its brakes stopped it, the boom rung down)
        while d.time < 4.0:
            mujoco.mj_step(m, d)
        q1 = d.qpos[main].copy()
        while d.time < 5.0:
            mujoco.mj_step(m, d)
        assert np.abs(d.qpos[main] - q1).max() < 1e-3, name
    full, lean = moves[MBL_FULL_MODEL_FILE], moves[MBL_MODEL_FILE]
    k = _JOINT_FOR_SPOOL[joint]
    assert full[k] == pytest.approx(lean[k], rel=0.15)
    # the others only give on their closed chambers' oil (the bucket 0.013 rad under the stick's 0.36 rad)
    assert np.abs(np.delete(full, k)).max() < 0.02


@needs_plugin
def test_full_machine_plugin_equals_the_python_learned_model_on_it():
    """The plugin's loads on the closed chains (equality forces included, joint limits not) are the
    Python path's: the same trajectory on the full machine (at 50 ms, a whole number of its 2 ms steps)."""
    log, pose = scenarios()["test1"]
    python = replay(
        LearnedModel(model=load_model(), control_period=0.05, table_set="paper"), log, start=pose, duration=4.0
    )
    full_model = native_backend.load_mbl_model(full=True, control_period=0.05, table_set="paper")
    full = native_backend.NativeLearnedModel(model=full_model)
    native_rows = replay(full, log, start=pose, duration=4.0)
    assert full.physics.model.neq == 4  # the closed chains are there
    np.testing.assert_allclose(_tip(native_rows), _tip(python), atol=1e-9)
    np.testing.assert_allclose(native_rows["boom_force_n"], python["boom_force_n"], rtol=1e-9, atol=1e-3)


@needs_plugin
def test_full_machine_follows_the_lean_machine():
    """validate's Test 1 (8 s) on cat325_mbl_full.xml (2 ms steps, queries 12.5 steps apart) and on
    the lean cat325_mbl.xml: the tips differ by what the lumped masses and the full model's servo lag make."""
    log, pose = scenarios()["test1"]
    lean = replay(native_backend.NativeLearnedModel(), log, start=pose)
    full_model = native_backend.NativeLearnedModel(model=native_backend.load_mbl_model(full=True))
    full = replay(full_model, log, start=pose)
    assert full_model.control_period == 0.025 and full_model.physics.timestep == 0.002
    err = np.linalg.norm(_tip(full) - _tip(lean), axis=1)
    print(f"full vs lean machine, Test 1: max tip difference {err.max():.3f} m, rms {np.sqrt(np.mean(err**2)):.3f} m")
    assert full["t"][-1] == pytest.approx(8.0)
    assert err.max() < 0.25 and np.sqrt(np.mean(err**2)) < 0.07
    assert np.ptp(_tip(lean), axis=0).max() > 4.0


@needs_plugin
@pytest.mark.parametrize("test", ["test1", "test2", "test3"])
@pytest.mark.parametrize("table_set", NATIVE_TABLE_SETS)
def test_native_and_python_give_the_same_trajectory(test, table_set):
    """One source of truth: the same tables, loads and logic (validate's command logs, up to 50 s); for the
    circuit model the same kernel in the plugin and behind the Python model (1 mm: the target)."""
    log, pose = scenarios()[test]
    python = replay(backend.python_learned_model(table_set), log, start=pose)
    native_rows = replay(native_backend.NativeLearnedModel(table_set=table_set), log, start=pose)
    err = np.linalg.norm(_tip(python) - _tip(native_rows), axis=1)
    print(f"{test}: {log.duration:g} s, max tip difference {err.max():.3e} m")
    assert err.max() < 1e-3
    assert np.ptp(_tip(python), axis=0).max() > 1.0  # the machine did move


@needs_plugin
def test_native_holds_targets_over_a_longer_control_period():
    log, pose = scenarios()["test1"]
    python = replay(LearnedModel(control_period=0.05, table_set="paper"), log, start=pose, dt_out=0.1)
    native = native_backend.NativeLearnedModel(control_period=0.05, table_set="paper")
    native_rows = replay(native, log, start=pose, dt_out=0.1)
    assert np.linalg.norm(_tip(python) - _tip(native_rows), axis=1).max() < 1e-3


def _run_steps(model: native_backend.NativeLearnedModel, log, k0: int, k1: int) -> np.ndarray:
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
    model = native_backend.NativeLearnedModel(control_period=0.05, table_set="paper")  # two steps per query
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


@needs_plugin
@pytest.mark.parametrize("table_set", CIRCUIT_TABLE_SETS)
def test_circuit_state_round_trip_is_exact_to_the_bit(table_set):
    """The circuit model's pressures, pump displacements and joint rates are plugin state: save mid-episode, run
    on, restore, run again: identical to the bit; without the circuit's state the run differs."""
    log, pose = scenarios()["test3"]
    model = native_backend.NativeLearnedModel(table_set=table_set)
    assert model.table_set == table_set
    m, d = model.physics.model, model.physics.data
    model.reset(pose)
    k_save = 301
    _run_steps(model, log, 0, k_save)
    kind = mujoco.mjtState.mjSTATE_FULLPHYSICS
    saved = np.empty(mujoco.mj_stateSize(m, kind))
    mujoco.mj_getState(m, d, saved, kind)
    assert model.hydraulic_state[0] > 5e6  # a pump working
    first = _run_steps(model, log, k_save, k_save + 400)
    hydraulics = model.hydraulic_state
    mujoco.mj_setState(m, d, saved, kind)
    again = _run_steps(model, log, k_save, k_save + 400)
    np.testing.assert_array_equal(first, again)
    np.testing.assert_array_equal(hydraulics, model.hydraulic_state)
    copy = mujoco.MjData(m)  # a copy of the data (a planner's rollout start) runs on the same way
    mujoco.mj_setState(m, d, saved, kind)
    mujoco.mj_copyData(copy, m, d)
    mujoco.mj_step(m, d)
    mujoco.mj_step(m, copy)
    np.testing.assert_array_equal(d.qpos, copy.qpos)
    mujoco.mj_setState(m, d, saved, kind)
    slots = slice(model._state.start + plugin.STATE["hydraulics"], model._state.start + plugin.STATE["rates"] + 4)
    d.plugin_state[slots] = 0.0
    assert np.abs(_run_steps(model, log, k_save, k_save + 400) - first).max() > 1e-6


@needs_plugin
def test_a_diverging_circuit_state_is_refused_naming_it():
    model = native_backend.NativeLearnedModel()
    model.reset("home")
    model.step(np.array([0.0, 0.008, 0.0, 0.0]), n=4)
    d = model.physics.data
    d.plugin_state[model._state.start + plugin.STATE["hydraulics"] + 4] = np.nan  # the boom's head pressure
    q = d.qpos.copy()
    with pytest.raises(ValueError, match="hydraulic state must be 14 finite numbers"):
        model.step(np.array([0.0, 0.008, 0.0, 0.0]))
    assert np.all(np.isfinite(d.qpos)) and np.abs(d.qpos - q).max() < 0.01  # held still, no NaN in MuJoCo


@needs_plugin
def test_circuit_tables_that_cannot_be_used_fail_loading_naming_the_file(tmp_path):
    """A plugin MJCF naming circuit tables that are missing, of another set, or whose hash does not match."""
    directory = tmp_path / "tables"
    shutil.copytree(packaged_tables_dir("circuit"), directory)
    meshes = assets_dir() / "meshes"
    xml = tmp_path / "cat325_mbl.xml"
    xml.write_text(mbl_model_xml(directory).replace('meshdir="meshes"', f'meshdir="{meshes}"', 1))
    mujoco.MjModel.from_xml_path(str(xml))  # loads as it is
    path = directory / "boom_pa.npz"
    _rewrite_meta(path, params={"bandwidth": 0.5, "input_scales": [1.0]})  # the content hash no longer matches
    with pytest.raises(ValueError, match=f"MBL table file {path}"):
        mujoco.MjModel.from_xml_path(str(xml))
    path.unlink()
    with pytest.raises(ValueError, match=f"MBL table file {path} does not exist"):
        mujoco.MjModel.from_xml_path(str(xml))
    paper = tmp_path / "paper"
    shutil.copytree(packaged_tables_dir("paper"), paper)
    with pytest.raises(ValueError, match="swing_bypass.npz does not exist"):
        native_backend.load_mbl_model(paper)  # the paper's tables where the circuit's are named


def _copy_tables(tmp_path: Path) -> Path:
    directory = tmp_path / "tables"
    shutil.copytree(packaged_tables_dir("paper"), directory)
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
    model = native_backend.NativeLearnedModel(tables_dir=directory, table_set="paper")
    assert plugin.plugin_config_values(model.physics.model)["tables"] == str(directory.resolve())
    model.reset()
    model.step(np.array([0.0, 0.008, 0.0, 0.0]), n=10)
    assert model.physics.joint_velocities()[1] > 0.05


def _rewrite_values(path: Path, values: np.ndarray) -> None:
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["values"] = values(arrays["values"])
    with path.open("wb") as fh:
        np.savez_compressed(fh, **arrays)


def _flip_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF  # inside the compressed values
    path.write_bytes(bytes(data))


_DAMAGE = {
    "version": (lambda p: _rewrite_meta(p, format_version=2), "has format version 2; this plugin reads version 1"),
    "name": (lambda p: _rewrite_meta(p, name="stick"), "holds table 'stick', expected 'swing'"),
    "shape": (
        lambda p: _rewrite_values(p, lambda v: v[..., :-1].copy()),
        "'values' has shape (23, 23, 2, 8, 29) dtype <f8; its axes need shape (23, 23, 2, 8, 30)",  # the swing table
    ),
    "dtype": (lambda p: _rewrite_values(p, lambda v: v.astype(np.float32)), "values.npy has dtype <f4, expected <f8"),
    "truncated": (lambda p: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2]), "is corrupt or not a table file"),
    "corrupt": (_flip_byte, "is corrupt or not a table file: zip member values.npy fails its CRC check"),
    "not a zip": (lambda p: p.write_text("swing table\n"), "is corrupt or not a table file: not a zip archive"),
    "inputs": (
        lambda p: _rewrite_meta(
            p, inputs=["stick_spool_m", "swing_spool_m", "stick_force_n", "swing_inertia_kgm2", "swing_rate_radps"]
        ),
        "has inputs [stick_spool_m, swing_spool_m",
    ),
    "output": (
        lambda p: _rewrite_meta(p, output="swing_torque_nm"),
        "has output 'swing_torque_nm'; the plugin expects 'swing_acceleration_radps2'",
    ),
    "missing": (Path.unlink, "does not exist"),
}


@needs_plugin
@pytest.mark.parametrize("damage", list(_DAMAGE))
def test_bad_table_file_fails_model_loading_naming_file_and_problem(tmp_path, damage):
    """MuJoCo's own loading (``MjModel.from_xml_path``, as the viewer loads a model) fails with the
    plugin's message: the file and what does not match."""
    directory = _copy_tables(tmp_path)
    path = directory / "swing.npz"
    spoil, message = _DAMAGE[damage]
    spoil(path)
    xml = tmp_path / "cat325_mbl.xml"
    meshes = assets_dir() / "meshes"
    text = mbl_model_xml(directory, table_set="paper")
    xml.write_text(text.replace('meshdir="meshes"', f'meshdir="{meshes}"', 1))
    with pytest.raises(ValueError) as info:
        mujoco.MjModel.from_xml_path(str(xml))
    assert f"MBL table file {path}" in str(info.value) and message in str(info.value), str(info.value)
    with pytest.raises(ValueError, match="MBL table file"):
        native_backend.load_mbl_model(directory, table_set="paper")  # the Python face says the same


@needs_plugin
def test_randomly_damaged_table_files_fail_cleanly(tmp_path):
    """Bytes flipped anywhere in a table file (headers, directory, compressed data): the model loads
    (damage the zip format does not see, e.g. in a name's padding) or fails with the file's name; never
    a crash of the process."""
    directory = _copy_tables(tmp_path)
    path = directory / "stick.npz"
    original = path.read_bytes()
    rng = np.random.default_rng(0)
    failed = 0
    for _ in range(25):
        data = bytearray(original)
        for i in rng.integers(0, len(data), size=rng.integers(1, 4)):
            data[i] ^= int(rng.integers(1, 256))
        path.write_bytes(bytes(data))
        try:
            native_backend.load_mbl_model(directory, table_set="paper")
        except ValueError as exc:
            assert f"MBL table file {path}" in str(exc), str(exc)
            failed += 1
    assert failed >= 20


@needs_plugin
def test_version_check_names_both_mujoco_versions():
    """The check the library makes before registering (native/mbl_plugin.cc VersionError), called with
    a pair of versions: that it refuses a MuJoCo it was not built against. (The refusal itself, the
    library loaded into another MuJoCo, is not exercised: only one MuJoCo is installed here.)"""
    import ctypes

    lib = ctypes.CDLL(str(plugin.plugin_library()))
    buffer = ctypes.create_string_buffer(512)
    lib.hexgym_mbl_version_error.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_char_p, ctypes.c_int]
    assert lib.hexgym_mbl_version_error(3003007, 4000000, buffer, len(buffer)) > 0
    message = buffer.value.decode()
    assert "built against MuJoCo 3003007 but is loaded into MuJoCo 4000000" in message and "rebuild" in message
    running = mujoco.mj_version()
    assert lib.hexgym_mbl_version_error(running, running, buffer, len(buffer)) == 0 and buffer.value == b""
    assert plugin.load_plugin() == ""  # this build agrees with this MuJoCo: nothing refused


@needs_plugin
def test_bad_spools_are_refused_before_the_plugin_sees_them():
    model = native_backend.NativeLearnedModel()
    model.reset()
    with pytest.raises(ValueError, match="not a finite number"):
        model.step(np.array([0.0, np.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match="shape"):
        model.step(np.zeros(3))


def test_make_learned_model_backends():
    assert isinstance(backend.make_learned_model("python"), LearnedModel)
    with pytest.raises(ValueError, match="backend must be one of"):
        backend.make_learned_model("fortran")
    auto = backend.make_learned_model("auto")
    expected = native_backend.NativeLearnedModel if plugin.native_available() else LearnedModel
    assert isinstance(auto, expected)


@needs_plugin
@pytest.mark.parametrize("table_set", NATIVE_TABLE_SETS)
def test_both_backends_stall_at_the_ground_alike_without_kicks(table_set):
    """Driving the bucket into the ground: it stops within a step, no joint is flung, both backends agree."""
    from hexgym.envs.world import build_world_model

    machine = mbl_model_xml(table_set=table_set)
    models = {
        "python": backend.python_learned_model(table_set, model=build_world_model(asset_path("scene_lean.xml"))),
        "native": native_backend.NativeLearnedModel(model=build_world_model(None, machine_xml=machine)),
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


def test_without_the_library_the_circuit_model_runs_its_definition_and_says_so_once(monkeypatch):
    """A build without a compiler: the circuit model falls back to the numpy definition (the same trajectory),
    warning once per process."""
    from hexgym.model import circuit_kernel, circuit_model

    monkeypatch.setattr(circuit_kernel, "native_reason", lambda: "the native plugin was not built")
    monkeypatch.setattr(circuit_model, "_fallback_said", False)
    with pytest.warns(RuntimeWarning, match="not built; the circuit model runs its numpy definition"):
        fallback = circuit_model.CircuitModel()
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        circuit_model.CircuitModel()  # said once
    assert fallback._kernel is None
    log, pose = scenarios()["test1"]
    rows = replay(fallback, log, start=pose, duration=2.0)
    monkeypatch.undo()
    if plugin.native_available():
        native_rows = replay(circuit_model.CircuitModel(), log, start=pose, duration=2.0)
        assert np.abs(_tip(rows) - _tip(native_rows)).max() < 1e-9

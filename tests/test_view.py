"""``hexgym view``: the site's scene with the plugin-driven machine, the key map, and the window under Xvfb (slow)."""

import os
import shutil
import subprocess
import sys
import time

import mujoco
import numpy as np
import pytest

from hexgym.envs.world import bucket_level
from hexgym.machine import kinematics
from hexgym.model.plugin import native_available
from hexgym_lab import view
from hexgym_lab.cli import main

needs_plugin = pytest.mark.skipif(not native_available(), reason="the native hexgym.mbl plugin is not built")
SWING, BOOM, STICK, BUCKET = range(4)


@needs_plugin
def test_scene_is_the_loading_site_around_the_plugin_driven_full_machine():
    site = view.ViewSite(payload_kg=1500.0, seed=3)
    m, d = site.model, site.data
    for geom in ("ground", "pile", "truck_floor", "truck_cab", "truck_load", "bucket_load_1"):
        assert m.geom(geom).id >= 0
    for body in ("truck", "undercarriage", "upper", "boom", "stick", "bucket", "boom_cylinder_rod", "guide_link"):
        assert m.body(body).id >= 0
    assert m.nlight >= 1 and m.nplugin == 1
    assert all(m.actuator_plugin[i] == 0 for i in site.spools)
    np.testing.assert_array_equal(m.actuator_ctrlrange[site.spools], [[-11.0, 11.0]] * 4)
    # placed as the environment places its site: the truck where the layout says, the pile drawn, the load sized
    np.testing.assert_allclose(d.mocap_pos[m.body("truck").mocapid[0], :2], site.layout.truck_centre)
    assert m.hfield_data.max() > 0.5
    assert m.geom_rgba[m.geom(f"bucket_load_{bucket_level(1500.0)}").id, 3] == 1.0  # the load drawn
    q = d.qpos[[m.jnt_qposadr[m.joint(n).id] for n in kinematics.JOINTS]]
    np.testing.assert_allclose(q, [0.0, 0.35, 0.85, 0.75], atol=2e-3)  # the keyframe "home"
    # ctrl is the spool in mm: boom up at full stroke raises the boom through the plugin
    tip_z = d.site_xpos[m.site("tip").id, 2]
    d.ctrl[site.spools] = [0.0, 11.0, 0.0, 0.0]
    for _ in range(250):  # 0.5 s
        mujoco.mj_step(m, d)
    mujoco.mj_forward(m, d)
    assert d.site_xpos[m.site("tip").id, 2] > tip_z + 0.2
    assert np.all(np.isfinite(d.qpos))


@needs_plugin
def test_start_pose_and_site_follow_the_options():
    site = view.ViewSite(start=view.parse_start("0.5,0.2,1.0,0.5"), seed=1)
    q = site.data.qpos[[site.model.jnt_qposadr[site.model.joint(n).id] for n in kinematics.JOINTS]]
    np.testing.assert_allclose(q, [0.5, 0.2, 1.0, 0.5], atol=2e-3)
    other = view.ViewSite(start="site", seed=2)
    assert other.layout != site.layout
    with pytest.raises(ValueError, match="no keyframe 'nope'"):
        view.ViewSite(start="nope")


@needs_plugin
def test_restart_puts_back_what_the_viewers_reset_takes_away():
    site = view.ViewSite(payload_kg=1000.0, seed=4)
    m, d = site.model, site.data
    truck = m.body("truck").mocapid[0]
    placed = d.mocap_pos[truck].copy()
    d.ctrl[site.spools] = 11.0
    for _ in range(100):
        mujoco.mj_step(m, d)
    mujoco.mj_resetData(m, d)  # what the viewer's Reset button does: qpos0, the truck at its default place
    assert not np.allclose(d.mocap_pos[truck], placed)
    site.restart()
    np.testing.assert_allclose(d.mocap_pos[truck], placed)
    q = d.qpos[[m.jnt_qposadr[m.joint(n).id] for n in kinematics.JOINTS]]
    np.testing.assert_allclose(q, [0.0, 0.35, 0.85, 0.75], atol=2e-3)
    assert d.time == 0.0 and np.all(d.ctrl[site.spools] == 0.0)


@needs_plugin
@pytest.mark.parametrize("aspect", [0.6, 1.6, 2.4])
def test_free_camera_frames_the_site_for_the_windows_shape(aspect):
    from hexgym.envs.world import site_points

    site = view.ViewSite(seed=4)
    camera = mujoco.MjvCamera()
    site.aim(camera, aspect)
    el, az = np.radians(camera.elevation), np.radians(camera.azimuth)
    forward = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    points = site_points(site.layout) - (camera.lookat - camera.distance * forward)
    depth = points @ forward
    half = np.tan(np.radians(site.model.vis.global_.fovy) / 2.0)
    x, y = points @ right / (depth * half * aspect), points @ up / (depth * half)
    assert np.all(depth > 0) and np.all(np.abs(x) <= 1.0) and np.all(np.abs(y) <= 1.0)  # all in view
    assert max(np.ptp(x), np.ptp(y)) > 1.5  # and filling it along one side


def test_keys_move_the_spools_as_documented():
    spools = np.zeros(4)
    documented = {  # key name -> spool, direction
        "Left": (SWING, +1), "Right": (SWING, -1), "Up": (BOOM, +1), "Down": (BOOM, -1),
        "Home": (STICK, +1), "End": (STICK, -1), "Insert": (BUCKET, +1), "Delete": (BUCKET, -1),
    }  # fmt: skip
    glfw_codes = {"Left": 263, "Right": 262, "Up": 265, "Down": 264, "Home": 268, "End": 269, "Insert": 260,
                  "Delete": 261}  # fmt: skip
    for name, (spool, sign) in documented.items():
        before = spools.copy()
        assert view.apply_key(spools, glfw_codes[name])
        expected = before.copy()
        expected[spool] += sign * view.SPOOL_STEP_MM
        np.testing.assert_allclose(spools, expected)
        assert name in view.key_help()
    for _ in range(10):  # held at the end of the stroke
        view.apply_key(spools, glfw_codes["Left"])
        view.apply_key(spools, glfw_codes["Down"])
    assert spools[SWING] == 11.0 and spools[BOOM] == -11.0
    assert not view.apply_key(spools, ord("W"))  # not ours: left to the viewer
    assert spools[SWING] == 11.0
    assert view.apply_key(spools, 32)  # Space centres all
    np.testing.assert_array_equal(spools, 0.0)
    # none of the keys is a viewer shortcut (letters toggle visualisation flags, digits geom groups)
    for code in [*view.KEY_MAP, view.CENTRE_KEY]:
        assert not (code < 128 and chr(code).isalnum())


def test_without_the_plugin_view_says_so_in_one_line(monkeypatch, capsys):
    monkeypatch.setattr("hexgym.model.plugin.load_plugin", lambda: "the native plugin was not built (no _mbl_plugin)")
    assert main(["view", "--frames", "1"]) != 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("hexgym view: error:") and "not built" in err


@needs_plugin
def test_without_a_display_view_says_so(monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["view", "--frames", "1"]) != 0
    assert "no display" in capsys.readouterr().err


def test_bad_start_is_reported():
    with pytest.raises(ValueError, match="four angles"):
        view.parse_start("0.1,0.2")
    assert view.parse_start("home") == "home"


@pytest.fixture(scope="module")
def xvfb_env():
    """A private Xvfb display (picked by Xvfb itself) and the environment to run the viewer on it."""
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb not on PATH (apt-get install -y xvfb)")
    if not native_available():
        pytest.skip("the native hexgym.mbl plugin is not built")
    read, write = os.pipe()
    server = subprocess.Popen(
        ["Xvfb", "-displayfd", str(write), "-screen", "0", "1920x1080x24", "-nolisten", "tcp"],
        pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    os.close(write)
    with os.fdopen(read) as pipe:
        display = pipe.readline().strip()
    if not display:
        server.kill()
        pytest.skip("Xvfb did not start")
    env = {**os.environ, "DISPLAY": f":{display}", "MUJOCO_GL": "glfw"}
    yield env
    server.terminate()
    server.wait(timeout=10)


def _run_view(env: dict, *args: str) -> subprocess.Popen:
    command = [sys.executable, "-m", "hexgym_lab.cli", "view", *args]
    return subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.slow  # ~10 s: the viewer's window on Xvfb, its pixels read back
def test_viewer_window_shows_the_lit_site(xvfb_env, tmp_path):
    import imageio.v3 as iio

    shot = tmp_path / "view.png"
    proc = _run_view(xvfb_env, "--frames", "30", "--screenshot", str(shot), "--payload-kg", "1500")
    out, err = proc.communicate(timeout=180)
    assert proc.returncode == 0, err
    assert "Insert" in out and f"wrote {shot}" in err  # the key help on stdout, where the picture went on stderr
    image = iio.imread(shot).astype(float)
    assert image.shape[0] > 400 and image.shape[1] > 600
    assert image.std() > 20.0  # not blank
    assert (image.max(axis=2) < 16).mean() < 0.5  # not mostly black
    # the scene is drawn and lit: warm pixels (ground, sand, machine, truck) fill a good part of the window
    warm = (image[..., 0] > image[..., 2] + 30) & (image[..., 0] > 100)
    assert warm.mean() > 0.1


@pytest.mark.slow  # ~10 s
def test_viewer_keys_drive_the_spools(xvfb_env):
    if shutil.which("xdotool") is None:
        pytest.skip("xdotool not on PATH (apt-get install -y xdotool)")
    proc = _run_view(xvfb_env, "--seconds", "6")
    window = ""
    for _ in range(100):  # the window appears once the site is built
        found = subprocess.run(["xdotool", "search", "--name", view.WINDOW_TITLE], env=xvfb_env,
                               capture_output=True, text=True)  # fmt: skip
        window = found.stdout.split()[0] if found.stdout.split() else ""
        if window or proc.poll() is not None:
            break
        time.sleep(0.2)
    assert window, proc.communicate()[1]
    keys = ["Left", "Left", "Up", "Insert", "Delete", "Delete", "Home", "space", "Right", "End", "BackSpace"]
    subprocess.run(["xdotool", "key", "--window", window, "--delay", "50", *keys], env=xvfb_env, check=True)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert "spools (mm): swing  -2.75  boom  +0.00  stick  -2.75  bucket  +0.00" in out  # after Space, Right, End
    assert "reset: the machine is back at its start" in out  # BackSpace: the viewer's Reset
    assert "spools +0.00, +0.00, +0.00, +0.00 mm" in out

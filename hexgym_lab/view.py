"""``hexgym view``: MuJoCo's interactive viewer on the loading site, the machine driven by its spools.

The scene is HexLoading-v0's (:func:`hexgym.envs.world.build_world_model`: ground, sun, pile, dump
truck) around the full machine with its cylinders and bucket linkage (``cat325_mbl_full.xml``),
whose four actuators are the native ``hexgym.mbl`` plugin's: ctrl is the spool position in mm
(±11 mm, + extends the cylinder / swings counter-clockwise), turned into joint motion by the MBL
tables inside ``mj_step``. Move the spools on the viewer's *Control* sliders or with the keys of
:data:`KEY_MAP`, like an operator's two joysticks: each press moves one spool by
:data:`SPOOL_STEP_MM`; the spool stays there (the machine keeps moving) until it is moved back or
all are centred.

Letters and the digits 0-5 are the viewer's own shortcuts (visualisation flags, geom groups), so
the keys here are the arrows, the editing block (Insert/Delete, Home/End) and Space, which the
passive viewer leaves alone.

``--screenshot PNG --frames N`` saves what the viewer's window shows after N frames and exits: the
window's pixels are read from the X server (Xlib ``XGetImage``), so it needs an X display (a real
one or Xvfb).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import queue
import sys
import threading
import time
from pathlib import Path

import mujoco
import numpy as np

from hexgym.machine import kinematics

MACHINE_FILE = "cat325_mbl_full.xml"  # the full machine driven by the hexgym.mbl plugin
SPOOL_RANGE_MM = 11.0
SPOOL_STEP_MM = 2.75  # a quarter stroke per press: the first press is past the 1.5 mm dead band
FRAME_PERIOD = 1.0 / 60.0  # s of simulated (and, when it keeps up, wall) time per drawn frame
WINDOW_TITLE = "MuJoCo : "  # the viewer's window is titled this and the model's name

# GLFW key code (MuJoCo's mjKEY_* are the same) -> (key name, spool index in kinematics.JOINTS order, direction, what)
_KEYS: dict[int, tuple[str, int, int, str]] = {
    263: ("Left", 0, +1, "swing left (counter-clockwise)"),
    262: ("Right", 0, -1, "swing right (clockwise)"),
    265: ("Up", 1, +1, "boom up"),
    264: ("Down", 1, -1, "boom down"),
    268: ("Home", 2, +1, "stick in (crowd)"),
    269: ("End", 2, -1, "stick out"),
    260: ("Insert", 3, +1, "bucket curl (close)"),
    261: ("Delete", 3, -1, "bucket dump (open)"),
}
CENTRE_KEY = 32  # Space: all spools to neutral (hands off the joysticks)
KEY_MAP = {code: (spool, sign) for code, (_, spool, sign, _) in _KEYS.items()}


def key_help() -> str:
    """The key map as printed on start and in ``hexgym view --help``."""
    lines = [f"  {name:<9} {what}" for name, _, _, what in _KEYS.values()]
    lines.append(f"  {'Space':<9} centre all spools (stop)")
    lines.append(f"  {'Backspace':<9} the viewer's Reset: the machine back at its start (so does Load key)")
    return (
        f"keys (each press moves a spool {SPOOL_STEP_MM:g} mm, up to ±{SPOOL_RANGE_MM:g} mm; "
        "or the Control sliders, Shift+Tab shows them):\n" + "\n".join(lines)
    )


def apply_key(spools_mm: np.ndarray, keycode: int, step_mm: float = SPOOL_STEP_MM) -> bool:
    """Move the spools (mm, swing, boom, stick, bucket; changed in place) as key ``keycode`` says.

    Returns whether the key is one of the map's (others are left to the viewer).
    """
    if keycode == CENTRE_KEY:
        spools_mm[:] = 0.0
        return True
    if keycode not in KEY_MAP:
        return False
    spool, sign = KEY_MAP[keycode]
    spools_mm[spool] = np.clip(spools_mm[spool] + sign * step_mm, -SPOOL_RANGE_MM, SPOOL_RANGE_MM)
    return True


def parse_start(start: str) -> str | np.ndarray:
    """``--start``: a keyframe name, or four joint angles in rad ("swing,boom,stick,bucket") within the joints'
    ranges."""
    if "," not in start:
        return start
    try:
        q = np.array([float(v) for v in start.split(",")])
    except ValueError:
        q = np.array([])
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise ValueError(
            f"--start must be a keyframe name or four angles 'swing,boom,stick,bucket' (rad), got {start!r}"
        )
    return kinematics.check_joint_angles(q, f"--start {start}")


class ViewSite:
    """The loading site with the plugin-driven full machine, started at rest (what the viewer shows).

    Args:
        start: a keyframe of the machine (``"home"``), ``"site"`` (the environment's start pose for
            ``seed``: the arm between pile and truck), or four joint angles (rad).
        payload_kg: material in the bucket (its mass loads the linkage; drawn as a heap).
        seed: the site's layout (pile and truck placement), drawn as HexLoading-v0 draws it.
    """

    def __init__(self, start: str | np.ndarray = "home", payload_kg: float = 0.0, seed: int = 0) -> None:
        from hexgym.envs.loading import heap_for, sample_start
        from hexgym.envs.world import World, build_world_model
        from hexgym.model.native_backend import NativeLearnedModel
        from hexgym.model.plugin import NativePluginError, load_plugin

        reason = load_plugin()
        if reason:
            raise NativePluginError(f"the viewer's machine runs on the native plugin: {reason}")
        if not 0.0 <= payload_kg < 1e5:
            raise ValueError(f"payload must be in [0, 100000) kg, got {payload_kg}")
        self.layout, site_q = sample_start(np.random.default_rng(seed))
        self.start = site_q if isinstance(start, str) and start == "site" else start
        self.payload_kg = payload_kg
        self.machine = NativeLearnedModel(model=build_world_model(machine_file=MACHINE_FILE))
        self.model, self.data = self.machine.physics.model, self.machine.physics.data
        keyframes = [self.model.key(i).name for i in range(self.model.nkey)]
        if isinstance(self.start, str) and self.start not in keyframes:
            raise ValueError(f"--start: no keyframe {start!r}; use one of {keyframes}, 'site' or four angles (rad)")
        self.spools = np.array([self.model.actuator(n).id for n in kinematics.JOINTS])
        self._world = World(self.model)
        self._world.show_pile(heap_for(self.layout).heights)
        self._world.show_loads(truck_kg=0.0, bucket_kg=payload_kg)
        self.restart()

    def restart(self) -> None:
        """Put the machine at its start, at rest, spools neutral, and the truck in its place (time 0)."""
        self.machine.reset(self.start, payload_kg=self.payload_kg)
        self._world.place(self.data, self.layout)
        mujoco.mj_forward(self.model, self.data)

    def aim(self, camera: mujoco.MjvCamera, aspect: float = 1.6) -> None:
        """Point the viewer's free camera at the machine, the pile and the truck so that they fill a view of
        ``aspect`` (width / height) at the model's field of view: the film's framing
        (:func:`hexgym.envs.world.site_camera`), as the free camera's look-at point, distance and angles."""
        from hexgym.envs.world import site_camera, site_points

        position, quat = site_camera(self.layout, aspect, float(self.model.vis.global_.fovy))
        rotation = np.empty(9)
        mujoco.mju_quat2Mat(rotation, quat)
        forward = -rotation.reshape(3, 3)[:, 2]  # the camera looks along its -z
        distance = float(np.mean((site_points(self.layout) - position) @ forward))  # to the points' middle depth
        camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        camera.lookat[:] = position + distance * forward
        camera.distance = distance
        camera.azimuth = float(np.degrees(np.arctan2(forward[1], forward[0])))
        camera.elevation = float(np.degrees(np.arcsin(np.clip(forward[2], -1.0, 1.0))))


def _fit_to_window(site: ViewSite, viewer, aimed: tuple | None) -> tuple | None:
    """Frame the site for the viewer's scene area (the window less its panels) when that first shows or changes
    size, unless the user has moved the camera since the last framing; returns the new (size, camera) or ``aimed``."""
    viewport = viewer.viewport
    if viewport is None or viewport.width < 2 or viewport.height < 2:
        return aimed
    size = (viewport.width, viewport.height)
    cam = viewer.cam
    now = (tuple(cam.lookat), cam.distance, cam.azimuth, cam.elevation)
    if aimed is not None and (aimed[0] == size or aimed[1] != now):
        return aimed
    site.aim(cam, size[0] / size[1])
    return size, (tuple(cam.lookat), cam.distance, cam.azimuth, cam.elevation)


def capture_window(path: str | Path, title: str = WINDOW_TITLE) -> Path:
    """Save the pixels of the X window whose title starts with ``title`` as a PNG (RGB)."""
    from hexgym.machine.render import write_png

    return write_png(x_window_pixels(title), path)


def x_window_pixels(title: str = WINDOW_TITLE) -> np.ndarray:
    """The window's pixels (H x W x 3 uint8) read from the X server of ``$DISPLAY``."""
    name = ctypes.util.find_library("X11")
    if name is None:
        raise RuntimeError("cannot capture the window: libX11 not found")
    x = ctypes.CDLL(name)
    x.XOpenDisplay.restype = ctypes.c_void_p
    x.XOpenDisplay.argtypes = [ctypes.c_char_p]
    x.XDefaultRootWindow.restype = ctypes.c_ulong
    x.XDefaultRootWindow.argtypes = [ctypes.c_void_p]
    x.XQueryTree.argtypes = [ctypes.c_void_p, ctypes.c_ulong] + [ctypes.c_void_p] * 3 + [ctypes.c_void_p]
    x.XFetchName.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.POINTER(ctypes.c_void_p)]
    x.XGetGeometry.argtypes = [ctypes.c_void_p, ctypes.c_ulong] + [ctypes.c_void_p] * 7
    x.XGetImage.restype = ctypes.POINTER(_XImage)
    x.XGetImage.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int, ctypes.c_int, ctypes.c_uint,
                            ctypes.c_uint, ctypes.c_ulong, ctypes.c_int]  # fmt: skip
    x.XFree.argtypes = [ctypes.c_void_p]
    x.XCloseDisplay.argtypes = [ctypes.c_void_p]
    display = x.XOpenDisplay(None)
    if not display:
        raise RuntimeError("cannot capture the window: no X display ($DISPLAY)")
    try:
        window = _find_window(x, display, x.XDefaultRootWindow(display), title.encode())
        if window is None:
            raise RuntimeError(f"cannot capture the window: no window titled {title!r}")
        root, px, py = ctypes.c_ulong(), ctypes.c_int(), ctypes.c_int()
        width, height, border, depth = ctypes.c_uint(), ctypes.c_uint(), ctypes.c_uint(), ctypes.c_uint()
        x.XGetGeometry(display, window, *(ctypes.byref(v) for v in (root, px, py, width, height, border, depth)))
        all_planes, z_pixmap = 0xFFFFFFFF, 2
        image = x.XGetImage(display, window, 0, 0, width.value, height.value, all_planes, z_pixmap)
        if not image:
            raise RuntimeError("cannot capture the window: XGetImage failed")
        try:
            im = image.contents
            if im.bits_per_pixel != 32:
                raise RuntimeError(f"cannot capture the window: {im.bits_per_pixel} bits per pixel")
            raw = ctypes.string_at(im.data, im.bytes_per_line * im.height)
            rows = np.frombuffer(raw, np.uint8).reshape(im.height, im.bytes_per_line)
            bgrx = rows[:, : 4 * im.width].reshape(im.height, im.width, 4)
            lsb_first = im.byte_order == 0  # TrueColor 0xXXRRGGBB: B, G, R, X in memory, else X, R, G, B
            return (bgrx[..., 2::-1] if lsb_first else bgrx[..., 1:]).copy()
        finally:
            x.XFree(image.contents.data)
            x.XFree(image)
    finally:
        x.XCloseDisplay(display)


class _XImage(ctypes.Structure):
    """The head of Xlib's ``XImage`` (the fields read here, in Xlib's order)."""

    _fields_ = [
        ("width", ctypes.c_int),
        ("height", ctypes.c_int),
        ("xoffset", ctypes.c_int),
        ("format", ctypes.c_int),
        ("data", ctypes.c_void_p),
        ("byte_order", ctypes.c_int),
        ("bitmap_unit", ctypes.c_int),
        ("bitmap_bit_order", ctypes.c_int),
        ("bitmap_pad", ctypes.c_int),
        ("depth", ctypes.c_int),
        ("bytes_per_line", ctypes.c_int),
        ("bits_per_pixel", ctypes.c_int),
    ]


def _find_window(x: ctypes.CDLL, display: int, window: int, title: bytes) -> int | None:
    """Depth-first search of the window tree for a window whose WM_NAME starts with ``title``."""
    name = ctypes.c_void_p()
    if x.XFetchName(display, window, ctypes.byref(name)) and name.value:
        found = ctypes.string_at(name.value).startswith(title)
        x.XFree(name.value)
        if found:
            return window
    root, parent, children, count = (
        ctypes.c_ulong(),
        ctypes.c_ulong(),
        ctypes.POINTER(ctypes.c_ulong)(),
        ctypes.c_uint(),
    )
    if not x.XQueryTree(display, window, ctypes.byref(root), ctypes.byref(parent), ctypes.byref(children),
                        ctypes.byref(count)):  # fmt: skip
        return None
    try:
        for i in range(count.value):
            found = _find_window(x, display, children[i], title)
            if found is not None:
                return found
    finally:
        if children:
            x.XFree(children)
    return None


def spool_line(spools_mm: np.ndarray) -> str:
    """The spools as printed after each key press."""
    return "spools (mm): " + "  ".join(f"{n} {v:+6.2f}" for n, v in zip(kinematics.JOINTS, spools_mm, strict=True))


def run_viewer(
    site: ViewSite,
    seconds: float | None = None,
    frames: int | None = None,
    screenshot: str | Path | None = None,
    camera: str = "free",
    panels: bool = False,
) -> dict[str, float | int | list[float]]:
    """Open the passive viewer on ``site`` and simulate in real time until its window is closed.

    ``seconds``: stop after this much simulated time; ``frames``: after this many drawn frames
    (with ``screenshot``: save the window's pixels there first; 60 frames if neither limit is given).
    ``panels``: open with the viewer's side panels (Tab and Shift+Tab show and hide them either way); without, the
    site fills the window. The free camera frames machine, pile and truck for the window's scene area whenever that
    changes size, until the camera is moved. Returns the simulated time, the frames drawn and the spools (mm) at the
    end.
    """
    if screenshot is not None and frames is None and seconds is None:
        frames = 60
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise RuntimeError("no display to open the viewer on (set DISPLAY, or run under xvfb-run)")
    import mujoco.viewer

    model, data = site.model, site.data
    steps_per_frame = max(1, round(FRAME_PERIOD / model.opt.timestep))
    presses: queue.SimpleQueue[int] = queue.SimpleQueue()  # the viewer's thread calls back; we step here
    before = set(threading.enumerate())
    viewer = mujoco.viewer.launch_passive(
        model, data, key_callback=presses.put, show_left_ui=panels, show_right_ui=panels
    )
    ui_threads = [t for t in threading.enumerate() if t not in before]
    drawn = 0
    try:
        with viewer.lock():
            if camera == "free":
                site.aim(viewer.cam)
            else:
                viewer.cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
                viewer.cam.fixedcamid = model.camera(camera).id
        aimed = None  # (viewport size, camera) of the last framing: the free camera fits the window until moved
        start = time.perf_counter()
        while viewer.is_running():
            with viewer.lock():
                if camera == "free":
                    aimed = _fit_to_window(site, viewer, aimed)
                spools = data.ctrl[site.spools]  # as the sliders left them
                pressed = False
                while not presses.empty():
                    pressed |= apply_key(spools, presses.get())
                data.ctrl[site.spools] = spools
                for _ in range(steps_per_frame):
                    mujoco.mj_step(model, data)
            before = data.time
            viewer.sync()  # (no set_texts overlay: in MuJoCo 4.0.0 it deadlocks with a key press)
            if data.time < before:  # the viewer's Reset or Load key: qpos0 or a keyframe, no truck, no assembly
                with viewer.lock():
                    site.restart()
                print("reset: the machine is back at its start", flush=True)
            if pressed:
                print(spool_line(spools), flush=True)
            drawn += 1
            if (frames is not None and drawn >= frames) or (seconds is not None and data.time >= seconds):
                break
            time.sleep(max(0.0, start + drawn * steps_per_frame * model.opt.timestep - time.perf_counter()))
        if screenshot is not None and viewer.is_running():
            time.sleep(0.5)  # the viewer's thread draws the last sync
            capture_window(screenshot)
    finally:
        viewer.close()
        for thread in ui_threads:  # let it release its window before Python exits (else it may crash)
            thread.join(timeout=5.0)
    return {"sim_seconds": float(data.time), "frames": drawn, "spools_mm": data.ctrl[site.spools].tolist()}

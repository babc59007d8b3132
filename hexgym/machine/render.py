"""Offscreen rendering of a simulation to frames, PNG snapshots and MP4 videos.

Set ``MUJOCO_GL=egl`` (CPU machines here render through Mesa's EGL) before ``mujoco`` is first
imported; the command line does this itself when nothing else was chosen.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import mujoco
import numpy as np

from hexgym.files import atomic_path, atomic_paths
from hexgym.machine.names import CHASE_CAMERA


class ModelMirror:
    """Shows a simulation of the lean machine with the full one: cylinders, rods and bucket links drawn.

    The lean model (``assets/cat325_lean.xml``) has no cylinder or four-bar bodies; for pictures,
    :meth:`sync` poses the full model (``target``, the same world around the full machine) at the
    lean simulation's main joint angles with the closed chains assembled (:func:`assembled_state`),
    and copies what the world shows: mocap bodies, heightfields, the sizes and colours of the geoms
    both models name alike (e.g. a load drawn in the bucket or the truck) and the places of those
    fixed to the world (the pile, moved to each episode's site), and the poses of the cameras both name alike
    (one aimed at each episode's site). Returns from :meth:`sync` which heightfields changed, so a renderer can
    re-upload them.
    """

    def __init__(self, source: mujoco.MjModel, target: mujoco.MjModel) -> None:
        from hexgym.machine import kinematics

        self.target = target
        self._source_q = np.array([source.jnt_qposadr[source.joint(n).id] for n in kinematics.JOINTS])
        if source.nmocap != target.nmocap:
            raise ValueError(f"models differ in mocap bodies: {source.nmocap} vs {target.nmocap}")
        self._geoms = [
            (i, target.geom(source.geom(i).name).id)
            for i in range(source.ngeom)
            if source.geom(i).name and mujoco.mj_name2id(target, mujoco.mjtObj.mjOBJ_GEOM, source.geom(i).name) >= 0
        ]
        self._placed = [(i, j) for i, j in self._geoms if source.geom_bodyid[i] == 0]  # world geoms: the site's
        self._hfields = [
            (source.hfield(i).name, i, target.hfield(source.hfield(i).name).id) for i in range(source.nhfield)
        ]
        self._cameras = [
            (i, j) for i in range(source.ncam) if (j := mujoco.mj_name2id(target, mujoco.mjtObj.mjOBJ_CAMERA,
                                                                          source.camera(i).name)) >= 0
        ]  # fmt: skip
        self._source = source

    def sync(self, source_data: mujoco.MjData, target_data: mujoco.MjData) -> list[int]:
        """Pose ``target_data`` like ``source_data``; the target heightfield ids whose data changed."""
        from hexgym.machine.physics import assembled_state

        src, tgt = self._source, self.target
        qpos, _ = assembled_state(tgt, source_data.qpos[self._source_q])
        target_data.qpos[:] = qpos
        target_data.mocap_pos[:], target_data.mocap_quat[:] = source_data.mocap_pos, source_data.mocap_quat
        target_data.time = source_data.time
        for i, j in self._geoms:
            tgt.geom_size[j], tgt.geom_rgba[j] = src.geom_size[i], src.geom_rgba[i]
        for i, j in self._placed:
            tgt.geom_pos[j], tgt.geom_quat[j] = src.geom_pos[i], src.geom_quat[i]
        for i, j in self._cameras:
            tgt.cam_mode[j], tgt.cam_pos[j], tgt.cam_quat[j] = src.cam_mode[i], src.cam_pos[i], src.cam_quat[i]
        changed = []
        for _, i, j in self._hfields:
            a, n = src.hfield_adr[i], src.hfield_nrow[i] * src.hfield_ncol[i]
            b = tgt.hfield_adr[j]
            if not np.array_equal(tgt.hfield_data[b : b + n], src.hfield_data[a : a + n]):
                tgt.hfield_data[b : b + n] = src.hfield_data[a : a + n]
                changed.append(j)
        mujoco.mj_forward(tgt, target_data)
        return changed


class FrameRenderer:
    """Renders RGB frames of ``(model, data)`` from a named camera of the scene."""

    def __init__(self, model: mujoco.MjModel, width: int = 960, height: int = 540, camera: str = CHASE_CAMERA) -> None:
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0:
            raise ValueError(f"no camera named {camera!r} in the model (have: {_camera_names(model)})")
        self.camera = camera
        self._renderer = mujoco.Renderer(model, height=height, width=width)

    def render(self, data: mujoco.MjData) -> np.ndarray:
        """One RGB frame (height x width x 3, uint8) of the current state."""
        self._renderer.update_scene(data, camera=self.camera)
        return self._renderer.render().copy()

    def close(self) -> None:
        """Release the OpenGL context."""
        self._renderer.close()


def _camera_names(model: mujoco.MjModel) -> list[str]:
    return [model.camera(i).name for i in range(model.ncam)]


MAX_FRAME_BYTES = 4 * 2**30  # frames a video may hold in memory before it is encoded


def check_frame_memory(frames: int, width: int, height: int, what: str = "the video") -> None:
    """ValueError when ``frames`` RGB frames of ``width`` x ``height`` would exceed :data:`MAX_FRAME_BYTES`."""
    size = frames * width * height * 3
    if size > MAX_FRAME_BYTES:
        raise ValueError(
            f"{what} would hold {frames} frames of {width} x {height} pixels ({size / 2**30:.1f} GiB) in memory; "
            f"the limit is {MAX_FRAME_BYTES / 2**30:.0f} GiB: shorten it, record fewer episodes or smaller frames"
        )


def write_png(frame: np.ndarray, path: str | Path) -> Path:
    """Write one frame as a PNG, atomically (a reader never sees a half-written file)."""
    _check_frame(frame, path)
    with atomic_path(path) as tmp:
        _encode_png(frame, tmp, path)
    return Path(path)


def write_mp4(
    frames: Iterable[np.ndarray], path: str | Path, fps: float, snapshot: tuple[np.ndarray, str | Path] | None = None
) -> Path:
    """Encode frames (H.264, yuv420p so every player opens it) to an MP4, atomically.

    ``snapshot``: (a frame, a PNG path) written with the video as one output: both are encoded to temporary files
    and replace the old pair only once both are complete (:func:`hexgym.files.atomic_paths`), so a failed or
    interrupted run never leaves a new video beside an old picture.

    No frames, an empty frame or a rate outside :data:`MIN_FPS`-:data:`MAX_FPS` raise ValueError, an encoder
    that wrote nothing raises RuntimeError and one that could not write the whole file (a full disk) OSError:
    in each case ``path`` (and the snapshot's) keeps what it held.
    """
    frames = list(frames)
    if not frames:
        raise ValueError(f"no frames to write to {path}")
    if not (np.isfinite(fps) and MIN_FPS <= fps <= MAX_FPS):
        raise ValueError(f"the frame rate must be from {MIN_FPS:g} to {MAX_FPS:g} frames/s, got {fps}")
    for frame in frames:
        _check_frame(frame, path)
    outputs = [path]
    if snapshot is not None:
        _check_frame(snapshot[0], snapshot[1])
        outputs.append(snapshot[1])
    with atomic_paths(*outputs) as temporaries:
        _encode_mp4(frames, temporaries[0], fps, path)
        if snapshot is not None:
            _encode_png(snapshot[0], temporaries[1], snapshot[1])
    return Path(path)


def _encode_png(frame: np.ndarray, tmp: Path, path: str | Path) -> None:
    """``frame`` as a PNG in ``tmp``; an OSError (a full disk) names ``path``, the output."""
    import imageio.v3 as iio

    try:
        iio.imwrite(tmp, frame)
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None


def _encode_mp4(frames: list[np.ndarray], tmp: Path, fps: float, path: str | Path) -> None:
    """``frames`` as an MP4 in ``tmp``, checked whole (:func:`_check_mp4`); errors name ``path``, the output."""
    import imageio.v2 as imageio

    try:
        with imageio.get_writer(
            tmp, fps=fps, codec="libx264", quality=7, pixelformat="yuv420p", macro_block_size=8
        ) as w:
            for frame in frames:
                w.append_data(frame)
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
    if tmp.stat().st_size == 0:
        raise RuntimeError(f"the video encoder wrote nothing for {path}")
    _check_mp4(tmp, path)


MIN_FPS, MAX_FPS = 0.1, 1000.0  # playback rates an MP4 is written at (outside: players show no video)


def _check_mp4(tmp: Path, path: str | Path) -> None:
    """OSError unless ``tmp`` is a whole MP4: top-level boxes that fill the file exactly, ``mdat`` and ``moov``
    among them. The encoder runs in its own process and a write it could not finish (a full disk) is not
    reported to Python: the file is then cut short, and must not replace ``path``."""
    import errno

    size, offset, kinds = tmp.stat().st_size, 0, set()
    with tmp.open("rb") as f:
        while offset < size:
            f.seek(offset)
            header = f.read(16)
            if len(header) < 8:
                break
            length, kind = int.from_bytes(header[:4], "big"), header[4:8]
            if length == 1 and len(header) == 16:
                length = int.from_bytes(header[8:16], "big")
            elif length == 0:
                length = size - offset
            if length < 8:
                break
            kinds.add(kind)
            offset += length
    if offset != size or not {b"mdat", b"moov"} <= kinds:
        raise OSError(errno.EIO, "the video encoder could not write it whole (a full disk?); the old file is kept",
                      str(path))  # fmt: skip


def _check_frame(frame: np.ndarray, path: str | Path) -> None:
    """ValueError unless ``frame`` is a non-empty image (H x W or H x W x 3/4)."""
    shape = np.shape(frame)
    if len(shape) not in (2, 3) or min(shape[:2]) < 1 or (len(shape) == 3 and shape[2] not in (1, 3, 4)):
        raise ValueError(f"cannot write an image of shape {shape} to {path}")

"""Offscreen rendering of a simulation to frames, PNG snapshots and MP4 videos.

Set ``MUJOCO_GL=egl`` (CPU machines here render through Mesa's EGL) before ``mujoco`` is first
imported; the command line does this itself when nothing else was chosen.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import mujoco
import numpy as np

from hexgym.files import atomic_path

CAMERAS = ("chase", "cab")


class FrameRenderer:
    """Renders RGB frames of ``(model, data)`` from a named camera of the scene."""

    def __init__(self, model: mujoco.MjModel, width: int = 960, height: int = 540, camera: str = "chase") -> None:
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


def write_png(frame: np.ndarray, path: str | Path) -> Path:
    """Write one frame as a PNG, atomically (a reader never sees a half-written file)."""
    import imageio.v3 as iio

    with atomic_path(path) as tmp:
        iio.imwrite(tmp, frame)
    return Path(path)


def write_mp4(frames: Iterable[np.ndarray], path: str | Path, fps: float) -> Path:
    """Encode frames (H.264, yuv420p so every player opens it) to an MP4, atomically."""
    import imageio.v2 as imageio

    with (
        atomic_path(path) as tmp,
        imageio.get_writer(tmp, fps=fps, codec="libx264", quality=7, pixelformat="yuv420p", macro_block_size=8) as w,
    ):
        for frame in frames:
            w.append_data(frame)
    return Path(path)

"""Where the packaged model files live, and loading them with errors that name the file.

The repository's top-level ``assets/`` directory is installed as the package ``hexgym.assets``
(see ``pyproject.toml``), so the same lookup works from a checkout, an editable install and a
normal ``pip install .``.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import mujoco

MODEL_FILE = "cat325.xml"
LEAN_MODEL_FILE = "cat325_lean.xml"  # the learned model's fast variant (hexgym/machine/mjcf.py: lean)
LEAN_SCENE_FILE = "scene_lean.xml"  # scene.xml around the lean machine (generated)
SCENE_FILE = "scene.xml"


class AssetError(RuntimeError):
    """A model file is missing or cannot be compiled."""


def assets_dir() -> Path:
    """The directory holding ``cat325.xml``, ``scene.xml`` and ``meshes/``."""
    return Path(str(resources.files("hexgym.assets")))


def asset_path(name: str) -> Path:
    """Path of a packaged asset file; raises :class:`AssetError` naming it if it is missing."""
    path = assets_dir() / name
    if not path.is_file():
        raise AssetError(f"hexgym asset not found: {path}")
    return path


def load_model(path: str | Path | None = None, scene: bool = False, lean: bool = False) -> mujoco.MjModel:
    """Compile an MJCF file (default: the packaged machine, or with ``scene`` the world around it).

    ``lean``: the packaged lean machine (no cylinder bodies, larger step) that the learned model runs on.

    Any failure (missing file, missing mesh, malformed XML) raises :class:`AssetError` with the
    file's path and MuJoCo's message.
    """
    if path is None:
        names = {(False, False): MODEL_FILE, (True, False): SCENE_FILE, (False, True): LEAN_MODEL_FILE}
        path = asset_path(names.get((scene, lean), LEAN_SCENE_FILE))
    path = Path(path)
    if not path.is_file():
        raise AssetError(f"model file not found: {path}")
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        raise AssetError(f"cannot load model {path}: {exc}") from exc

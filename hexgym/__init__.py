"""hexgym: a fast, faithful simulator of a 25-ton hydraulic excavator (Cat 325 class) on MuJoCo.

Modules: :mod:`hexgym.machine.parameters` (every physical number), :mod:`hexgym.machine.kinematics` (kinematics),
:mod:`hexgym.machine.physics` (the MuJoCo simulation), :mod:`hexgym.machine.mjcf` and :mod:`hexgym.tools.meshes`
(generate ``assets/``), :mod:`hexgym.machine.render` (offscreen video), :mod:`hexgym.tools.cli` (``hexgym``).
"""

import os as _os

# Offscreen rendering needs its GL backend chosen before mujoco is first imported (below): without
# a display, Mesa's EGL (works on CPU-only machines); with one, MuJoCo's default (GLFW windows).
if "MUJOCO_GL" not in _os.environ and not _os.environ.get("DISPLAY"):
    _os.environ["MUJOCO_GL"] = "egl"

from hexgym.envs import register_envs as _register_envs  # noqa: E402

__version__ = "0.1.0"

_register_envs()  # `import hexgym` makes gymnasium.make("HexLoading-v0") work

from hexgym.model.native_backend import load_plugin as _load_plugin  # noqa: E402

_load_plugin()  # registers the native hexgym.mbl plugin with MuJoCo when the build compiled it

"""hexgym: a fast, faithful simulator of a 25-ton hydraulic excavator (Cat 325 class) on MuJoCo.

The runtime library: what a program imports to simulate, plan and act. The subpackages follow the data
flow, each importing only those before it: :mod:`hexgym.machine` (parameters, kinematics, the bucket, the
MuJoCo linkage, assets) -> :mod:`hexgym.hydraulics` (the analytical circuit, fuel, the reference model) ->
:mod:`hexgym.mbl` (the table schema and the fitted tables' lookup) -> :mod:`hexgym.model` (the learned model
on the Python or native backend, command logs, replay) -> :mod:`hexgym.envs` (``HexLoading-v0`` and its
siblings) -> :mod:`hexgym.planning` (optimal motions, collision prediction) -> :mod:`hexgym.wrappers` (the
collision shield) -> :mod:`hexgym.agents` (the scripted loader, the shipped policy and loading policies).

The lab beside it, :mod:`hexgym_lab` (collection, fitting, training, evaluation, benchmarks, validation,
asset builders and the ``hexgym`` command line), imports hexgym; hexgym never imports the lab.

``import hexgym`` registers the environments and nothing more: the native plugin library is loaded
when a native model is first built.
"""

import os as _os

# Offscreen rendering needs its GL backend chosen before mujoco is first imported: without a
# display, Mesa's EGL (works on CPU-only machines); with one, MuJoCo's default (GLFW windows).
if "MUJOCO_GL" not in _os.environ and not _os.environ.get("DISPLAY"):
    _os.environ["MUJOCO_GL"] = "egl"

from hexgym.envs import ENV_ID, register_envs  # noqa: E402

__version__ = "0.1.0"
__all__ = ["ENV_ID", "register_envs"]

register_envs()  # `import hexgym` makes gymnasium.make("HexLoading-v0") work

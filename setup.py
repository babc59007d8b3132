"""Build hook for the native learned-model plugin (``native/*.cc`` -> ``hexgym/_mbl_plugin*.so``).

Everything else about the package is in pyproject.toml. The plugin is a MuJoCo engine plugin
library (not a Python module), compiled against the headers and ``libmujoco`` of the ``mujoco``
package in the build environment (pinned in ``build-system.requires`` to the runtime version).
It is optional: without a C++ compiler, zlib or MuJoCo's headers the build says why and the
package installs without it (hexgym then runs the learned model in Python).
"""

from __future__ import annotations

import glob
import os
import sys

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

PLUGIN = "hexgym._mbl_plugin"
SOURCES = sorted(glob.glob(os.path.join("native", "*.cc")))


class BuildMujocoPlugin(build_ext):
    """build_ext that finds MuJoCo's include dir and libmujoco through the ``mujoco`` package."""

    def build_extension(self, ext: Extension) -> None:
        """Compile the plugin, or explain why not and go on without it."""
        try:
            import mujoco
        except ImportError as exc:
            print(
                f"hexgym: not building the native plugin ({exc}); the learned model will run in Python", file=sys.stderr
            )
            return
        mujoco_dir = os.path.dirname(mujoco.__file__)
        libraries = sorted(glob.glob(os.path.join(mujoco_dir, "libmujoco.so.*")))
        if not libraries or not os.path.isdir(os.path.join(mujoco_dir, "include", "mujoco")):
            print(
                f"hexgym: {mujoco_dir} has no MuJoCo headers or libmujoco.so; not building the native plugin",
                file=sys.stderr,
            )
            return
        ext.include_dirs.append(os.path.join(mujoco_dir, "include"))
        ext.extra_link_args += [
            libraries[0],
            "-lz",
            # found through the mujoco package beside hexgym (an installed wheel); Python has
            # always loaded libmujoco by its soname before the plugin, which covers editable installs
            "-Wl,-rpath,$ORIGIN/../mujoco",
        ]
        super().build_extension(ext)

    def get_export_symbols(self, ext: Extension) -> list[str]:
        """A plugin library has no PyInit_ function to export."""
        return []


setup(
    ext_modules=[
        Extension(
            PLUGIN,
            sources=SOURCES,
            language="c++",
            extra_compile_args=["-std=c++17", "-O2", "-fvisibility=hidden", "-ffp-contract=off"],
            optional=True,  # a failed compile is a warning: the package still installs
        )
    ],
    cmdclass={"build_ext": BuildMujocoPlugin},
)

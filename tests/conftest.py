"""Test set-up: offscreen rendering through EGL must be chosen before mujoco is imported."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

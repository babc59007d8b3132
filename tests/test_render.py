"""Drawing the lean simulation with the full machine (hexgym.machine.render.ModelMirror)."""

import mujoco
import numpy as np

from hexgym.machine.assets import load_model
from hexgym.machine.render import ModelMirror


def test_mirror_poses_the_full_machine_like_the_lean_one():
    lean, full = load_model(scene=True, lean=True), load_model(scene=True)
    src, tgt = mujoco.MjData(lean), mujoco.MjData(full)
    q = np.array([0.7, 0.3, 0.9, -0.4])
    for j, name in enumerate(("swing", "boom", "stick", "bucket")):
        src.qpos[lean.joint(name).qposadr[0]] = q[j]
    mujoco.mj_forward(lean, src)
    mirror = ModelMirror(lean, full)
    assert mirror.sync(src, tgt) == []  # no heightfields in the plain scene
    np.testing.assert_allclose(tgt.site_xpos[full.site("tip").id], src.site_xpos[lean.site("tip").id], atol=1e-9)
    # the full model's closed chains are assembled: its pin pairs meet
    rod_end, rod_pin = full.site("bucket_cylinder_rod_end").id, full.site("bucket_cylinder_rod_pin").id
    assert np.linalg.norm(tgt.site_xpos[rod_end] - tgt.site_xpos[rod_pin]) < 1e-6

"""Offscreen rendering under MUJOCO_GL=egl and the demo's outputs."""

import imageio.v2 as imageio
import imageio.v3 as iio
import numpy as np

from hexgym.machine.physics import ExcavatorPhysics
from hexgym.machine.render import FrameRenderer
from hexgym_lab.agents.demo import run_demo


def test_renders_a_non_blank_frame_from_both_cameras():
    physics = ExcavatorPhysics(scene=True)
    for camera in ("chase", "cab"):
        renderer = FrameRenderer(physics.model, width=320, height=240, camera=camera)
        frame = renderer.render(physics.data)
        renderer.close()
        assert frame.shape == (240, 320, 3)
        assert frame.std() > 10  # not a uniform (blank or black) image
        # the machine's yellow is in the chase view
        if camera == "chase":
            yellow = (frame[..., 0] > 150) & (frame[..., 1] > 100) & (frame[..., 2] < 80)
            assert yellow.mean() > 0.01


def test_demo_writes_video_and_snapshot(tmp_path):
    paths = run_demo(tmp_path, fps=10, width=320, height=192, duration=1.0)
    with imageio.get_reader(paths["video"], format="ffmpeg") as reader:
        frames = [frame for frame in reader]
    assert len(frames) == 10 and frames[0].shape == (192, 320, 3)
    assert np.abs(frames[-1].astype(int) - frames[0].astype(int)).mean() > 0.5  # the machine moved
    snapshot = iio.imread(paths["snapshot"])
    assert snapshot.shape == (192, 320, 3) and snapshot.std() > 10
    assert not list(tmp_path.glob(".*tmp*"))  # atomic writes leave no temporaries


def test_demo_reports_the_scripted_run(tmp_path):
    result = run_demo(tmp_path, width=64, height=48, duration=0.5)
    assert result["metrics"]["sim_seconds"] == 0.5 and result["metrics"]["delivered_t"] == 0.0

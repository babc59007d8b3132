"""What the films show: the delivered material in the bed, the load in the bucket, the camera's framing, the caption."""

import math

import imageio.v3 as iio
import mujoco
import numpy as np
import pytest
import trimesh

from hexgym.envs.loading import HexLoadingEnv
from hexgym.envs.world import (
    LOAD_LEVELS,
    _bed_grid,
    bed_heights,
    bucket_level,
    sample_layout,
    site_camera,
    site_points,
)
from hexgym.machine import parameters as p
from hexgym.machine.bucket import BUCKET, fill_mesh
from hexgym_lab.agents.film import caption, overlay_text

WIDTH, HEIGHT = 320, 192


def _pixels(rel: np.ndarray, fovy_deg: float) -> np.ndarray:
    """Pixel (column, row) in a WIDTH x HEIGHT frame of points ``rel`` (n, 3) in a camera's frame (x right, y up,
    looking along -z); nan behind the camera."""
    focal = HEIGHT / 2 / math.tan(math.radians(fovy_deg) / 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        ahead = -rel[:, 2]
        pixels = np.column_stack([WIDTH / 2 + focal * rel[:, 0] / ahead, HEIGHT / 2 - focal * rel[:, 1] / ahead])
    pixels[ahead <= 0] = np.nan
    return pixels


def _project(model: mujoco.MjModel, data: mujoco.MjData, camera: str, points: np.ndarray) -> np.ndarray:
    """Pixel (column, row) of world ``points`` (n, 3) in a WIDTH x HEIGHT frame of ``camera``."""
    cam = model.camera(camera).id
    return _pixels((points - data.cam_xpos[cam]) @ data.cam_xmat[cam].reshape(3, 3), model.cam_fovy[cam])


@pytest.fixture(scope="module")
def site():
    env = HexLoadingEnv(render_mode="rgb_array", width=WIDTH, height=HEIGHT)
    env.reset(seed=0)
    yield env
    env.close()


def _frame(env: HexLoadingEnv, truck_kg: float, bucket_kg: float) -> np.ndarray:
    env.task.stores[0, 1], env.earth.bucket_kg = truck_kg, bucket_kg  # the truck's store: the task's record
    return env.render().astype(int)


def _bed_box(env: HexLoadingEnv) -> tuple[slice, slice]:
    """The frame's rows and columns that the bed's inside (floor to rim) covers."""
    model, data, _ = env._render_view()
    truck = data.xpos[model.body("truck").id]
    rotation = data.xmat[model.body("truck").id].reshape(3, 3)
    corners = np.array([(x, y, z) for x in (-2.5, 2.5) for y in (-1.15, 1.15) for z in (1.55, 2.6)])
    pixels = _project(model, data, "chase", truck + corners @ rotation.T)
    lo, hi = np.floor(pixels.min(axis=0)).astype(int), np.ceil(pixels.max(axis=0)).astype(int)
    return slice(max(lo[1], 0), min(hi[1], HEIGHT)), slice(max(lo[0], 0), min(hi[0], WIDTH))


def test_delivered_tonnes_fill_the_bed_in_the_picture(site):
    empty = _frame(site, 0.0, 0.0)
    rows, cols = _bed_box(site)
    assert (rows.stop - rows.start) * (cols.stop - cols.start) > 400  # the bed is in the frame
    changed = np.abs(_frame(site, 4000.0, 0.0) - empty).sum(axis=2) > 30
    inside = np.zeros_like(changed)
    inside[rows, cols] = True
    assert changed[inside].mean() > 0.1  # the bed's pixels show the material
    assert changed[~inside].mean() < 1e-3  # and nothing else (but a stray pixel of the sun's shadow map)
    fuller = np.abs(_frame(site, 10000.0, 0.0) - empty).sum(axis=2) > 30
    assert fuller[inside].sum() > changed[inside].sum()  # more tonnes, more of the bed covered
    sand = _frame(site, 10000.0, 0.0)[rows, cols]
    assert ((sand[..., 0] > sand[..., 2] + 40) & (sand[..., 1] > sand[..., 2] + 20)).mean() > 0.2  # sand, not paint


def test_the_bucket_load_is_drawn_and_grows(site):
    empty = _frame(site, 0.0, 0.0)
    half = np.abs(_frame(site, 0.0, 900.0) - empty).sum(axis=2) > 30
    full = np.abs(_frame(site, 0.0, 2100.0) - empty).sum(axis=2) > 30
    assert half.any() and full.sum() > half.sum()  # the heap shows above the mouth as the bucket fills
    model = site._render_view()[0]
    shown = [model.geom(f"bucket_load_{k}").id for k in range(1, LOAD_LEVELS + 1) if model.geom_rgba[
        model.geom(f"bucket_load_{k}").id, 3] > 0]  # fmt: skip
    assert shown == [model.geom(f"bucket_load_{bucket_level(2100.0)}").id]  # one level at a time


def test_bed_heights_hold_the_delivered_volume():
    *_, weights = _bed_grid()
    for volume in (0.3, 2.0, 6.0):
        heights = bed_heights(volume)
        assert (heights * weights).sum() == pytest.approx(volume, rel=1e-3)
        assert heights.max() <= p.TRUCK_BED_WALL_HEIGHT + 0.6 + 1e-9
    assert not bed_heights(0.0).any()
    assert (bed_heights(3.0) >= bed_heights(1.0)).all()


@pytest.mark.parametrize("level", [1, LOAD_LEVELS // 2, LOAD_LEVELS])
def test_bucket_fill_mesh_holds_its_volume(level):
    volume = level / LOAD_LEVELS * BUCKET.heaped_capacity
    vertices, faces = fill_mesh(volume)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    assert mesh.volume == pytest.approx(volume, rel=0.02)  # outward winding: positive, the volume it stands for
    assert np.abs(vertices[:, 1]).max() <= p.BUCKET_WIDTH / 2  # inside the side plates
    assert bucket_level(0.0) == 0 and bucket_level(volume * p.MATERIAL_DENSITY) == level


@pytest.mark.parametrize("seed", range(6))
def test_site_camera_holds_machine_pile_and_truck(seed):
    layout = sample_layout(np.random.default_rng(seed))
    position, quat = site_camera(layout, WIDTH / HEIGHT, 55.0)
    xmat = np.empty(9)
    mujoco.mju_quat2Mat(xmat, quat)
    column, row = _pixels((site_points(layout) - position) @ xmat.reshape(3, 3), 55.0).T
    assert (column >= 0).all() and (column <= WIDTH).all() and (row >= 0).all() and (row <= HEIGHT).all()
    assert np.ptp(column) > 0.8 * WIDTH or np.ptp(row) > 0.8 * HEIGHT  # and fill the frame


def _captioned(frame: np.ndarray) -> bool:
    """Whether ``frame`` carries the caption: a dark strip across its top with white text in it."""
    strip = frame[: max(9, round(frame.shape[0] / 32)), :]
    white = (strip.min(axis=2) > 170).mean()
    return bool(np.median(strip) < 70 and white > 0.01)


def test_caption_columns_and_strip():
    info = {"time_s": 12.34, "bucket_kg": 1950.0, "truck_kg": 1739.7, "fuel_l": 0.412}
    columns = [shown for shown, _ in caption(info, "dig", label="ep 1")]
    assert columns == ["ep 1", "t 12.3 s", "phase dig", "bucket 1.95 t", "delivered 1.74 t", "fuel 0.41 L"]
    frame = np.full((HEIGHT, WIDTH, 3), 150, np.uint8)
    marked = overlay_text(frame, caption(info, "dig"))
    assert _captioned(marked) and not _captioned(frame)
    assert np.array_equal(marked[HEIGHT // 4 :], frame[HEIGHT // 4 :])  # only the strip changes


def test_demo_video_and_plan_film_carry_the_caption(tmp_path, monkeypatch):
    from hexgym_lab.agents.demo import run_demo
    from hexgym_lab.agents.video import record_video
    from hexgym_lab.plan import plan_video

    demo = run_demo(tmp_path, width=WIDTH, height=HEIGHT, duration=0.3)["video"]
    video = record_video("scripted", tmp_path / "v.mp4", seconds=0.3, width=WIDTH, height=HEIGHT)["video"]
    result = {"task": "dump", "seed": 0, "planned_spools_mm": np.full((4, 4), 3.0).tolist(),
              "scripted_spools_mm": np.full((2, 4), -3.0).tolist()}  # fmt: skip
    plan = plan_video(result, tmp_path / "plan.mp4", width=WIDTH, height=HEIGHT)
    for path in (demo, video, plan):
        frames = iio.imread(path)
        assert all(_captioned(frame) for frame in frames), path

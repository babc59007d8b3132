"""The loading task's earthwork (compiled with numba): the pile, digging, the bucket's contents, conservation."""

import numpy as np
import pytest

from hexgym.envs.earthwork import (
    Earthwork,
    Pile,
    digging_resistance,
    earthmoving_factors,
    mouth_normal,
    resistance,
    retained_volume,
    side_plate_force,
)
from hexgym.machine import parameters as p
from hexgym.machine.bucket import BUCKET, bucket_profile, struck_volume

SPACING = 0.1
N = 81


def heap(height=1.5, top=1.2):
    return Pile.heap((7.0, 0.5), height, top, N, SPACING)


def test_the_bucket_geometry_is_its_profile_to_the_millimetre():
    profile = bucket_profile()
    assert BUCKET.struck_capacity == pytest.approx(struck_volume(profile), abs=5e-4)
    assert np.allclose(BUCKET.lip, profile.lip, atol=5e-4)
    assert np.allclose(BUCKET.edge, profile.edge, atol=5e-4)
    assert np.allclose(BUCKET.teeth_direction, -profile.floor, atol=5e-4)
    assert BUCKET.heaped_capacity == pytest.approx(p.BUCKET_HEAPED_CAPACITY, abs=5e-4)  # the profile's design goal
    # the mouth faces away from the bucket pin (the inside is on the pin's side)
    mid = (np.array(BUCKET.lip) + np.array(BUCKET.edge)) / 2
    assert mouth_normal() @ (np.zeros(2) - mid) < 0


def test_earthmoving_factors_behave_as_mckyes():
    rakes = np.radians([20.0, 45.0, 60.0, 90.0])
    n_gamma, n_q = earthmoving_factors(rakes)
    assert np.all(n_gamma > 0) and np.allclose(n_q, 2 * n_gamma)
    assert n_gamma[1] < n_gamma[3]  # a vertical blade resists more than a 45 deg one
    # no friction at all: the Rankine passive wedge of a vertical wall, N_gamma = Kp / 2 = 0.5
    assert earthmoving_factors(np.pi / 2, friction=0.0, tool_friction=0.0)[0][0] == pytest.approx(0.5, rel=1e-3)
    # Coulomb passive pressure of a smooth vertical wall: Kp = tan^2(45 + phi/2)
    phi = np.radians(30.0)
    kp = np.tan(np.pi / 4 + phi / 2) ** 2
    assert earthmoving_factors(np.pi / 2, friction=phi, tool_friction=0.0)[0][0] == pytest.approx(kp / 2, rel=5e-3)


def test_resistance_grows_with_depth_and_surcharge():
    rake = np.radians(45.0)
    shallow, deep = digging_resistance(0.2, rake, 0.0), digging_resistance(0.4, rake, 0.0)
    assert deep == pytest.approx(4 * shallow)  # gamma d^2 term
    assert digging_resistance(0.4, rake, 10e3) > deep
    assert digging_resistance(0.0, rake, 10e3) == 0.0


def test_pushed_sideways_the_side_plate_resists():
    """Across the arm's plane the side plate meets the pile's passive pressure (Coulomb, d^2 growth); in the
    plane the edge cuts as before, with no sideways part."""
    assert side_plate_force(0.6) == pytest.approx(4 * side_plate_force(0.3)) and side_plate_force(0.0) == 0.0
    phi, delta = p.MATERIAL_FRICTION_ANGLE, p.MATERIAL_TOOL_FRICTION_ANGLE
    kp = np.cos(phi) ** 2 / (np.cos(delta) * (1 - np.sqrt(np.sin(phi + delta) * np.sin(phi) / np.cos(delta))) ** 2)
    assert 9.0 < kp < 10.5  # Coulomb's passive coefficient for 35 and 23 degrees (Rankine's 3.7 without wall friction)
    length = np.hypot(*np.subtract(BUCKET.edge, BUCKET.lip))
    assert side_plate_force(0.5) == pytest.approx(0.5 * kp * p.MATERIAL_DENSITY * p.GRAVITY * 0.25 * length)
    edge, teeth = (0.0, 1.0, 0.0), (-0.7071, 0.0, -0.7071)  # the edge along y, the teeth down towards the machine
    sideways = np.array(resistance(0.5, 0.0, *edge, *teeth, 0.0, 0.4, 0.0))  # moving along the edge at 0.4 m/s
    np.testing.assert_allclose(sideways, [0.0, -side_plate_force(0.5), 0.0], atol=1e-6)
    slow = np.array(resistance(0.5, 0.0, *edge, *teeth, 0.0, -0.01, 0.0))  # in proportion below 5 cm/s
    np.testing.assert_allclose(slow, [0.0, 0.2 * side_plate_force(0.5), 0.0], atol=1e-6)
    cutting = np.array(resistance(0.5, 0.0, *edge, *teeth, -0.4, 0.0, 0.0))  # in the arm's plane: no side part
    assert cutting[1] == 0.0 and cutting[0] > 0.0


def test_heap_volume_and_surface():
    pile = heap(height=1.5, top=1.2)
    r_top, h = 1.2, 1.5
    r_base = r_top + h / np.tan(p.MATERIAL_REPOSE_ANGLE)
    frustum = np.pi * h / 3 * (r_base**2 + r_base * r_top + r_top**2)
    assert pile.volume() == pytest.approx(frustum, rel=0.02)
    assert pile.height_at(np.array([7.0, 0.5])) == pytest.approx(1.5)
    assert pile.height_at(np.array([30.0, 0.0])) == 0.0  # off the grid
    # bilinear between grid points: the mean of the corners in the middle of a cell
    i, j = 20, 30
    x, y = pile.origin[0] + (j + 0.5) * SPACING, pile.origin[1] + (i + 0.5) * SPACING
    corners = pile.heights[i : i + 2, j : j + 2].mean()
    assert pile.height_at(np.array([x, y])) == pytest.approx(corners)


def test_bad_heightmaps_are_refused():
    with pytest.raises(ValueError, match="square"):
        Pile(np.zeros((3, 4)), (0, 0), 0.1)
    with pytest.raises(ValueError, match=">= 0"):
        Pile(-np.ones((3, 3)), (0, 0), 0.1)


def test_take_removes_what_it_returns_and_no_more_than_asked():
    pile = heap()
    before = pile.volume()
    taken = pile.take(np.array([7.0, 0.5]), np.array([0.0, 1.0]), 1.5, 1.0, 0.05)
    assert taken == pytest.approx(0.05, rel=1e-9)
    assert pile.volume() == pytest.approx(before - taken, abs=1e-9)
    # asking for more than lies above the floor takes only that
    pile2 = heap()
    above = pile2.take(np.array([7.0, 0.5]), np.array([0.0, 1.0]), 1.5, 1.4, 100.0)
    assert 0 < above < 1.0
    assert pile2.take(np.array([7.0, 0.5]), np.array([0.0, 1.0]), 1.5, 2.0, 1.0) == 0.0  # floor above the top


def test_relax_conserves_and_limits_slopes():
    h = np.zeros((21, 21))
    h[10, 10] = 3.0  # a spike
    pile = Pile(h, (0.0, 0.0), SPACING)
    before = pile.volume()
    pile.relax(iterations=400)
    assert pile.volume() == pytest.approx(before, abs=1e-12)
    assert np.all(pile.heights >= 0)
    slope = np.abs(np.diff(pile.heights, axis=0)).max() / SPACING
    assert slope < np.tan(p.MATERIAL_REPOSE_ANGLE) * 1.05


def test_dig_fills_along_the_teeth_and_resists_the_motion():
    earth = Earthwork(heap())
    edge, lateral, teeth = np.array([7.0, 0.5, 1.2]), np.array([0.0, 1.0, 0.0]), np.array([-1.0, 0.0, 0.0])
    forward = earth.dig(edge, lateral, teeth, np.array([-0.5, 0.0, 0.0]), 0.01)
    assert forward.depth == pytest.approx(0.3)
    assert forward.taken_kg == pytest.approx(p.BUCKET_WIDTH * 0.3 * 0.5 * 0.01 * p.MATERIAL_DENSITY, rel=1e-6)
    assert forward.force[0] > 0 and forward.force[1] == 0  # against the motion, in the arm's plane
    backwards = earth.dig(edge, lateral, teeth, np.array([0.5, 0.0, 0.0]), 0.01)
    assert backwards.taken_kg == 0.0 and backwards.force[0] < 0
    above = earth.dig(np.array([7.0, 0.5, 2.0]), lateral, teeth, np.array([-0.5, 0.0, 0.0]), 0.01)
    assert above.depth == 0.0 and above.taken_kg == 0.0 and not above.force.any()


def test_bucket_fills_to_its_heap_and_spills_when_tilted():
    earth = Earthwork(heap())
    edge, lateral, teeth = np.array([7.0, 0.5, 0.8]), np.array([0.0, 1.0, 0.0]), np.array([-1.0, 0.0, 0.0])
    for _ in range(2000):
        earth.dig(edge, lateral, teeth, np.array([-1.0, 0.0, 0.0]), 0.01)
    heaped_kg = p.BUCKET_HEAPED_CAPACITY * p.MATERIAL_DENSITY
    assert earth.bucket_kg == pytest.approx(heaped_kg, rel=1e-9)
    assert earth.spill(0.0, into_truck=False, dt=1.0).to_ground_kg < 1e-9  # mouth up: it holds its heap
    for _ in range(100):
        earth.spill(p.MATERIAL_REPOSE_ANGLE, into_truck=False, dt=0.1)
    assert earth.bucket_kg == pytest.approx(BUCKET.struck_capacity * p.MATERIAL_DENSITY, rel=1e-3)
    for _ in range(100):
        earth.spill(np.radians(150.0), into_truck=True, dt=0.1)
    assert earth.bucket_kg == 0.0
    assert earth.truck_kg == pytest.approx(BUCKET.struck_capacity * p.MATERIAL_DENSITY, rel=1e-3)


def test_retained_volume_falls_with_tilt():
    tilts = np.radians(np.linspace(0, 180, 37))
    kept = np.array([retained_volume(t) for t in tilts])
    assert kept[0] == p.BUCKET_HEAPED_CAPACITY and kept[-1] == 0.0
    assert np.all(np.diff(kept) <= 0)


def test_material_is_conserved_through_random_digging_and_spilling():
    rng = np.random.default_rng(0)
    earth = Earthwork(heap())
    total = earth.total_kg()
    lateral = np.array([0.0, 1.0, 0.0])
    for _ in range(3000):
        edge = np.array([rng.uniform(5, 9), rng.uniform(-1, 2), rng.uniform(0, 1.6)])
        teeth = rng.normal(size=3)
        earth.dig(edge, lateral, teeth / np.linalg.norm(teeth), rng.normal(size=3), 0.01)
        earth.spill(rng.uniform(0, np.pi), bool(rng.integers(2)), 0.01)
        assert abs(earth.total_kg() - total) < 1e-6
    assert earth.truck_kg > 0 and earth.spilled_kg > 0 and earth.pile_kg < total


def test_point_height_matches_the_vectorised_one():
    pile = heap()
    rng = np.random.default_rng(3)
    points = rng.uniform([2.0, -4.0], [12.0, 5.0], (200, 2))
    expected = pile.height_at(points)
    assert np.allclose([pile.height_at_point(x, y) for x, y in points], expected, atol=1e-12)


def test_uniform_table_interpolates_like_numpy():
    from hexgym.interpolation import UniformTable

    x = np.linspace(-1.0, 2.0, 31)
    values = np.sin(3 * x)
    table = UniformTable(-1.0, 2.0, values)
    for point in np.random.default_rng(5).uniform(-1.5, 2.5, 300):
        assert table(point) == pytest.approx(np.interp(point, x, values), abs=1e-12)
    with pytest.raises(ValueError, match="increasing"):
        UniformTable(1.0, 1.0, values)


def test_clearance_and_cached_volume_follow_the_digging():
    pile = heap(height=1.5, top=1.2)
    assert pile.clearance(np.array([7.0, 0.5, 2.0]), 0.5) == pytest.approx(0.5)
    assert pile.clearance(np.array([7.0, 0.5, 1.0]), 0.5) == pytest.approx(-0.5)
    assert pile.clearance(np.array([30.0, 0.0, 0.0]), 0.5) == np.inf  # off the grid: no material near
    before = pile.volume()
    taken = pile.take(np.array([7.0, 0.5]), np.array([0.0, 1.0]), 1.5, 1.0, 0.05)
    assert pile.volume() == pytest.approx(before - taken, abs=1e-12)
    assert pile.volume() == pytest.approx(float(pile.heights.sum()) * pile.cell_area, abs=1e-12)


def test_cached_compiled_functions_are_dropped_when_a_source_changes(tmp_path):
    """numba checks a cached function against its own file only; any change to the package's sources drops them."""
    import os

    from hexgym.envs.compiled import drop_stale_caches

    (tmp_path / "envs" / "__pycache__").mkdir(parents=True)
    (tmp_path / "envs" / "task.py").write_text("x = 1\n")
    parameters = tmp_path / "parameters.py"
    parameters.write_text("DENSITY = 1650.0\n")
    cached = [tmp_path / "envs" / "__pycache__" / name for name in ("task.f-1.py311.nbi", "task.f-1.py311.1.nbc")]
    for path in cached:
        path.write_bytes(b"old")
    assert drop_stale_caches(tmp_path) and not any(p.exists() for p in cached)  # never stamped
    for path in cached:
        path.write_bytes(b"new")
    assert not drop_stale_caches(tmp_path) and all(p.exists() for p in cached)  # nothing changed
    parameters.write_text("DENSITY = 1800.0\n")  # a constant the compiled code froze
    os.utime(parameters, ns=(1, 1))
    assert drop_stale_caches(tmp_path) and not any(p.exists() for p in cached)

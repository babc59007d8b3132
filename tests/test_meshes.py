"""The generated visual meshes: complete, well-formed, in their body frames, reproducible."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from hexgym.machine import parameters as p
from hexgym.machine.bucket import BUCKET
from hexgym_lab import meshes

TOL = 0.02  # m


@pytest.fixture(scope="module")
def built() -> dict[str, trimesh.Trimesh]:
    return meshes.build_meshes()


def _contains(mesh: trimesh.Trimesh, *planar: tuple[float, float]) -> bool:
    """Whether the mesh's bounding box holds the planar (x, z) points at y = 0."""
    lo, hi = mesh.bounds
    pts = np.array([(x, 0.0, z) for x, z in planar])
    return bool(np.all(pts >= lo - TOL) and np.all(pts <= hi + TOL))


def test_every_mesh_is_built(built: dict[str, trimesh.Trimesh]) -> None:
    assert tuple(built) == meshes.MESH_NAMES


@pytest.mark.parametrize("name", meshes.MESH_NAMES)
def test_mesh_is_well_formed(built: dict[str, trimesh.Trimesh], name: str) -> None:
    mesh = built[name]
    assert len(mesh.faces) > 50
    assert len(mesh.faces) < 8000  # small files
    assert np.isfinite(mesh.vertices).all()
    assert mesh.is_watertight  # a union of closed pieces
    assert mesh.is_winding_consistent
    assert mesh.volume > 0.0  # normals point outward
    assert (mesh.area_faces > 1e-10).all()  # no degenerate triangles


def test_undercarriage_in_world_frame(built: dict[str, trimesh.Trimesh]) -> None:
    lo, hi = built["undercarriage"].bounds
    assert lo[2] == pytest.approx(0.0, abs=1e-6)  # on the ground
    assert hi[2] == pytest.approx(p.SWING_BEARING_HEIGHT, abs=1e-6)  # top of the swing bearing
    assert hi[0] - lo[0] == pytest.approx(p.TRACK_LENGTH, abs=TOL)
    assert hi[1] - lo[1] == pytest.approx(p.TRACK_GAUGE + p.TRACK_SHOE_WIDTH, abs=TOL)


def test_upper_parts_in_upper_frame(built: dict[str, trimesh.Trimesh]) -> None:
    cab_lo, cab_hi = built["cab"].bounds
    assert cab_hi[2] == pytest.approx(p.CAB_ROOF_HEIGHT - p.SWING_BEARING_HEIGHT, abs=1e-6)
    assert cab_lo[1] > meshes.BOOM_WIDTH / 2.0  # on the left, clear of the boom
    assert cab_hi[0] - cab_lo[0] == pytest.approx(p.CAB_SIZE[0], abs=0.1)
    assert cab_hi[1] - cab_lo[1] == pytest.approx(p.CAB_SIZE[1], abs=0.1)
    assert cab_lo[0] + cab_hi[0] > 0.0  # front left: mostly ahead of the swing axis
    cw = built["counterweight"]
    assert cw.bounds[0][0] == pytest.approx(-p.TAIL_SWING_RADIUS, abs=1e-6)
    assert np.hypot(cw.vertices[:, 0], cw.vertices[:, 1]).max() <= p.TAIL_SWING_RADIUS + 1e-6
    assert built["engine_housing"].bounds[1][1] > 0.0 > built["engine_housing"].bounds[0][1]
    assert _contains(built["upper_deck"], p.BOOM_FOOT, p.BOOM_CYLINDER_BASE)
    assert built["upper_deck"].bounds[0][2] < 0.0 + TOL  # sits on the bearing


def test_links_in_their_frames(built: dict[str, trimesh.Trimesh]) -> None:
    ends = [(0.0, 0.0), (p.BOOM_LENGTH, 0.0)]
    assert _contains(built["boom"], *ends, p.BOOM_KNEE, p.BOOM_CYLINDER_ROD_PIN, p.STICK_CYLINDER_BASE)
    assert _contains(
        built["stick"],
        (0.0, 0.0),
        (p.STICK_LENGTH, 0.0),
        p.STICK_CYLINDER_ROD_PIN,
        p.BUCKET_CYLINDER_BASE,
        p.GUIDE_LINK_PIVOT,
    )
    assert _contains(built["guide_link"], (0.0, 0.0), (p.GUIDE_LINK_LENGTH, 0.0))
    assert _contains(built["power_link"], (0.0, 0.0), (p.POWER_LINK_LENGTH, 0.0))
    for name in ("boom", "stick", "bucket", "guide_link", "power_link"):
        lo, hi = built[name].bounds
        assert lo[1] == pytest.approx(-hi[1])  # symmetric about the arm plane y = 0


def test_bucket_geometry(built: dict[str, trimesh.Trimesh]) -> None:
    bucket = built["bucket"]
    assert _contains(bucket, (0.0, 0.0), p.BUCKET_LINK_PIN, p.BUCKET_TIP)
    lo, hi = bucket.bounds
    assert hi[1] - lo[1] == pytest.approx(p.BUCKET_WIDTH, abs=0.1)
    # the teeth end on the tip line: vertices lie at BUCKET_TIP's (x, z), none beyond it
    tip = np.array(p.BUCKET_TIP)
    xz = bucket.vertices[:, [0, 2]]
    assert np.hypot(*(xz - tip).T).min() < 0.05
    assert (xz @ tip / np.hypot(*tip)).max() <= np.hypot(*tip) + TOL


def test_bucket_capacity() -> None:
    assert 0.9 <= BUCKET.struck_capacity <= 1.3
    assert BUCKET.heaped_capacity == pytest.approx(p.BUCKET_HEAPED_CAPACITY, rel=0.02)


def test_write_meshes_is_deterministic(tmp_path) -> None:
    first = meshes.write_meshes(tmp_path / "a")
    second = meshes.write_meshes(tmp_path / "b")
    assert [f.name for f in first] == [f"{n}.stl" for n in meshes.MESH_NAMES]
    assert sorted(f.name for f in (tmp_path / "a").iterdir()) == sorted(f.name for f in first)  # no temp left
    for a, b in zip(first, second, strict=True):
        assert a.read_bytes() == b.read_bytes()
    again = meshes.write_meshes(tmp_path / "a")  # overwriting in place
    assert [f.read_bytes() for f in again] == [f.read_bytes() for f in second]
    loaded = trimesh.load_mesh(first[0])
    assert len(loaded.faces) == len(meshes.build_meshes()[meshes.MESH_NAMES[0]].faces)
    assert sum(f.stat().st_size for f in first) < 2_000_000

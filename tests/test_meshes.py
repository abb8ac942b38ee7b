"""Mesh loading: any triangle mesh loads, merged into polygons only where the merge is exact."""

from __future__ import annotations

import importlib.metadata

import numpy as np
import pytest
import trimesh

from cellsight.geometry.meshes import drop_degenerate, load_mesh_solid
from cellsight.geometry.polyhedron import Polyhedron


def _robots_root():
    """example-robot-data's robots folder (URDFs and meshes), installed as a cmeel prefix."""
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        return None
    root = dist.locate_file("cmeel.prefix/share/example-robot-data/robots")
    return root if root.is_dir() else None


ROOT = _robots_root()
COLLISION_GLOBS = [f"ur_description/meshes/{ur}/collision/*.stl" for ur in ("ur3", "ur5", "ur10")]
COLLISION_GLOBS.append("panda_description/meshes/collision/*.stl")
COLLISION = [] if ROOT is None else sorted(p for g in COLLISION_GLOBS for p in ROOT.glob(g))
needs_robots = pytest.mark.skipif(ROOT is None, reason="example-robot-data is not installed")


def _write(tmp_path, name: str, vertices, triangles) -> str:
    path = tmp_path / name
    trimesh.Trimesh(np.asarray(vertices, float), np.asarray(triangles), process=False).export(path)
    return path


def _check_against_trimesh(solid: Polyhedron, path) -> None:
    """Faces valid (rebuilt by Polyhedron), no more faces than triangles, a watertight input
    closed with trimesh's volume."""
    mesh = trimesh.load(path, force="mesh")
    rebuilt = Polyhedron("again", solid.vertices, solid.faces, solid.closed)
    assert len(rebuilt.faces) <= len(mesh.faces)
    assert solid.closed == (mesh.is_watertight and mesh.is_winding_consistent)
    if solid.closed:
        assert solid.volume() == pytest.approx(abs(mesh.volume), rel=1e-6)


@needs_robots
def test_every_robot_collision_mesh_is_found() -> None:
    assert len(COLLISION) == 31  # UR3, UR5, UR10: 7 each; Panda: 10


@needs_robots
@pytest.mark.parametrize("path", COLLISION, ids=lambda p: f"{p.parts[-3]}-{p.stem}")
def test_robot_collision_mesh_loads(path) -> None:
    solid = load_mesh_solid(path)
    _check_against_trimesh(solid, path)
    if "ur5" in path.parts or "panda_description" in path.parts:
        assert solid.closed  # every UR5 and Panda collision mesh is watertight


@needs_robots
def test_a_whole_ur5_loads_as_closed_solids() -> None:
    solids = [load_mesh_solid(p) for p in COLLISION if "ur5" in p.parts]
    assert len(solids) == 7 and all(s.closed for s in solids)


def test_a_cube_of_twelve_triangles_becomes_six_quads(tmp_path) -> None:
    path = tmp_path / "cube.stl"
    trimesh.creation.box((0.1, 0.1, 0.1)).export(path)
    solid = load_mesh_solid(path, scale=2.0)
    assert sorted(len(f) for f in solid.faces) == [4] * 6
    assert solid.closed and solid.volume() == pytest.approx(0.008)


def _tunnel_box() -> tuple[np.ndarray, list[tuple[int, int, int]]]:
    """A 3 x 1 x 3 box with a 1 x 1 square tunnel along y: two square faces with a square
    hole, 32 triangles, volume 8."""
    square = [(0, 0), (3, 0), (3, 3), (0, 3)]
    hole = [(1, 1), (2, 1), (2, 2), (1, 2)]
    ring = square + hole  # 0..3 outer, 4..7 inner, at y = 0; +8 at y = 1
    v = np.array([(x, y, z) for y in (0.0, 1.0) for x, z in ring])
    quads = []
    for k in range(4):
        n = (k + 1) % 4
        quads += [(k, n, 4 + n, 4 + k), (8 + k, 12 + k, 12 + n, 8 + n)]  # the two holed caps
        quads += [(k, 8 + k, 8 + n, n), (4 + k, 4 + n, 12 + n, 12 + k)]  # outside, tunnel
    tris = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    return v, tris


def test_a_face_with_a_hole_is_kept_as_triangles_and_stays_closed(tmp_path) -> None:
    v, tris = _tunnel_box()
    mesh = trimesh.Trimesh(v, tris, process=False)
    trimesh.repair.fix_normals(mesh)
    assert mesh.is_watertight and mesh.volume == pytest.approx(8.0)
    mesh.export(tmp_path / "tunnel.stl")
    solid = load_mesh_solid(tmp_path / "tunnel.stl")
    assert solid.closed and solid.volume() == pytest.approx(8.0, rel=1e-9)
    assert sorted(len(f) for f in solid.faces) == [3] * 16 + [4] * 8  # caps stay triangles
    _check_against_trimesh(solid, tmp_path / "tunnel.stl")


def test_a_flat_triangle_is_removed_without_opening_the_mesh(tmp_path) -> None:
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    v, tris = np.asarray(box.vertices), [tuple(map(int, t)) for t in box.faces]
    # two triangles sharing an edge p-q; split one at the diagonal's midpoint m and close
    # the gap with the zero-area triangle (p, q, m)
    t1 = next(t for t in tris if any(u != t and set(u) & set(t) == set(t[:2]) for u in tris))
    p, q, r = t1
    v = np.vstack([v, (v[p] + v[q]) / 2])
    m = len(v) - 1
    tris.remove(t1)
    tris += [(p, m, r), (m, q, r), (p, q, m)]
    path = _write(tmp_path, "sliver.obj", v, tris)
    solid = load_mesh_solid(path)
    assert solid.closed and solid.volume() == pytest.approx(1.0)
    assert len(solid.faces) == 6  # m stays on the boundary of the faces beside p-q if a cube edge


def test_drop_degenerate_splits_the_neighbour_across_the_long_edge() -> None:
    v = np.array([(0, 0, 0), (1, 0, 0), (2, 0, 0), (1, 1, 0)], float)
    tris, dropped = drop_degenerate(v, np.array([(0, 1, 2), (2, 3, 0)]))  # (0,1,2) is flat
    assert dropped == 0
    assert sorted(map(sorted, tris.tolist())) == [[0, 1, 3], [1, 2, 3]]


def test_an_open_mesh_gives_an_open_solid(tmp_path) -> None:
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    path = _write(tmp_path, "open.stl", box.vertices, box.faces[:-2])  # one side missing
    solid = load_mesh_solid(path)
    assert not solid.closed and len(solid.faces) == 5

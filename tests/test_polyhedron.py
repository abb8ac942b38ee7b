"""Polyhedron validation and mesh loading."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from cellsight.errors import GeometryError
from cellsight.geometry.meshes import load_mesh_solid
from cellsight.geometry.polyhedron import Polyhedron, box, prism

U_SECTION = [(-0.05, -0.03), (0.05, -0.03), (0.05, 0.03), (0.02, 0.03),
             (0.02, 0.01), (-0.02, 0.01), (-0.02, 0.03), (-0.05, 0.03)]


def _outward(solid: Polyhedron) -> bool:
    """Independent outward check: each face normal points away from an interior point found
    by a ray-parity test with trimesh."""
    mesh = trimesh.Trimesh(solid.vertices, solid.triangles(), process=False)
    return bool(mesh.is_winding_consistent and mesh.volume > 0)


def test_box_and_prism_are_closed_and_outward() -> None:
    b = box("b", (0.2, 0.3, 0.4), (1, 2, 3))
    assert b.volume() == pytest.approx(0.024)
    p = prism("p", U_SECTION, 0.03)
    assert len(p.faces) == 10 and len(p.feature_points) == 16
    assert p.feature_names[0] == "f1" and p.feature_names[-1] == "f16"
    assert p.volume() == pytest.approx((0.1 * 0.06 - 0.04 * 0.02) * 0.03)
    assert _outward(b) and _outward(p)
    reversed_section = prism("r", U_SECTION[::-1], 0.03)
    assert reversed_section.volume() > 0


def test_non_planar_face_names_solid_and_face() -> None:
    b = box("bx", (1, 1, 1))
    v = b.vertices.copy()
    v[6, 2] += 0.01  # lifts one corner of the top face (face 1)
    with pytest.raises(GeometryError, match=r"solid 'bx' face 1: non-planar"):
        Polyhedron("bx", v, b.faces)


def test_degenerate_face_names_solid_and_face() -> None:
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0.0]])
    with pytest.raises(GeometryError, match=r"solid 'flat' face 0: degenerate"):
        Polyhedron("flat", v, ((0, 1, 2),), closed=False)
    with pytest.raises(GeometryError, match=r"solid 'few' face 0: a polygon needs at least 3"):
        Polyhedron("few", v, ((0, 1),), closed=False)
    with pytest.raises(GeometryError, match=r"solid 'rep' face 0: repeats a vertex"):
        Polyhedron("rep", v, ((0, 1, 1, 3),), closed=False)


def test_self_intersecting_face_is_rejected() -> None:
    bowtie = np.array([[0, 0, 0], [4, 0, 0], [4, 2, 0], [1, -1, 0], [0, 2, 0.0]])
    with pytest.raises(GeometryError, match=r"solid 'bow' face 0: edges .* intersect"):
        Polyhedron("bow", bowtie, ((0, 1, 2, 3, 4),), closed=False)


def test_wrongly_oriented_solids_are_rejected() -> None:
    b = box("inv", (1, 1, 1))
    inverted = tuple(tuple(reversed(f)) for f in b.faces)
    with pytest.raises(GeometryError, match=r"solid 'inv' face 0: faces are oriented inward"):
        Polyhedron("inv", b.vertices, inverted)
    one_flipped = (tuple(reversed(b.faces[0])),) + b.faces[1:]
    with pytest.raises(GeometryError, match=r"solid 'mix' face \d: edge .* same direction"):
        Polyhedron("mix", b.vertices, one_flipped)
    with pytest.raises(GeometryError, match=r"solid 'open' face \d: edge .* no opposite face"):
        Polyhedron("open", b.vertices, b.faces[1:])


def test_stl_box_is_rebuilt_with_six_outward_quads(tmp_path) -> None:
    trimesh.creation.box((0.2, 0.4, 0.6)).export(tmp_path / "box.stl")
    solid = load_mesh_solid(tmp_path / "box.stl")
    assert len(solid.faces) == 6 and all(len(f) == 4 for f in solid.faces)
    assert len(solid.vertices) == 8
    assert solid.volume() == pytest.approx(0.048)
    assert _outward(solid)


def test_non_convex_obj_is_rebuilt_with_its_octagons(tmp_path) -> None:
    p = prism("u", U_SECTION, 0.03)
    mesh = trimesh.Trimesh(p.vertices, p.triangles(), process=False)
    mesh.invert()  # an exporter that winds inward: the loader must fix the orientation
    mesh.export(tmp_path / "u.obj")
    solid = load_mesh_solid(tmp_path / "u.obj")
    assert sorted(len(f) for f in solid.faces) == [4] * 8 + [8, 8]
    assert solid.volume() == pytest.approx(p.volume())
    assert _outward(solid)
    # every rebuilt face lies on one of the original planes with the same outward normal
    for normal in solid.normals:
        assert np.isclose(p.normals @ normal, 1.0).any()


def test_missing_mesh_file(tmp_path) -> None:
    with pytest.raises(GeometryError, match="does not exist"):
        load_mesh_solid(tmp_path / "nope.stl")


def test_rigid_move_keeps_the_normals_a_fresh_solid_computes() -> None:
    """A rigidly moved solid skips validation: its normals must be what validation gives."""
    from scipy.spatial.transform import Rotation

    solid = prism("u", [[0, 0], [3, 0], [3, 2], [2, 2], [2, 1], [1, 1], [1, 2], [0, 2]], 0.5)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.3, -1.1, 2.0]).as_matrix()
    T[:3, 3] = [0.4, -2.0, 7.0]
    moved = solid.transformed(T, "moved")
    fresh = Polyhedron("fresh", moved.vertices, moved.faces, moved.closed)
    np.testing.assert_allclose(moved.normals, fresh.normals, atol=1e-12)
    assert moved.name == "moved" and moved.renamed("again").faces == solid.faces


def test_non_rigid_move_is_validated_again() -> None:
    """Flattening a box by a zero scale makes its faces degenerate: refused."""
    flatten = np.diag([1.0, 1.0, 0.0, 1.0])
    with pytest.raises(GeometryError, match="solid 'b'"):
        box("b", (1.0, 1.0, 1.0)).transformed(flatten)


def test_a_mesh_file_loads_once_per_process(tmp_path) -> None:
    """The second load of the same file is the first's solid under the new name; a changed
    file is read again."""
    path = tmp_path / "cube.stl"
    trimesh.creation.box((1.0, 1.0, 1.0)).export(path)
    first, second = load_mesh_solid(path, "a"), load_mesh_solid(path, "b")
    assert (first.name, second.name) == ("a", "b") and second.vertices is first.vertices
    trimesh.creation.box((2.0, 1.0, 1.0)).export(path)
    third = load_mesh_solid(path, "c")
    assert np.ptp(third.vertices[:, 0]) == pytest.approx(2.0)

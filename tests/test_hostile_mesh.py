"""Hostile and large mesh files (issue 23): COLLADA units, vertices no face uses, the merge of
large meshes at numpy speed, and the on-disk cache of prepared meshes."""

from __future__ import annotations

import copy
import re

import numpy as np
import pytest
import trimesh
import yaml

from cellsight import load_cell
from cellsight.cli import main
from cellsight.errors import CellFileError, GeometryError
from cellsight.geometry import mesh_cache, mesh_merge, meshes
from cellsight.geometry.polygon import check_polygon
from cellsight.geometry.polyhedron import Polyhedron
from cellsight.model.loader import builtin_cell_path

CORNERS = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
CUBE = [(0, 2, 1), (0, 3, 2), (4, 5, 6), (4, 6, 7), (0, 1, 5), (0, 5, 4), (3, 7, 6), (3, 6, 2),
        (0, 4, 7), (0, 7, 3), (1, 2, 6), (1, 6, 5)]  # outward

DAE = """<?xml version="1.0" encoding="utf-8"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset>{unit}<up_axis>Z_UP</up_axis></asset>
  <library_geometries>
    <geometry id="cube"><mesh>
      <source id="pos">
        <float_array id="pos-array" count="{count}">{positions}</float_array>
        <technique_common><accessor source="#pos-array" count="{points}" stride="3">
          <param name="X" type="float"/><param name="Y" type="float"/>
          <param name="Z" type="float"/>
        </accessor></technique_common>
      </source>
      <vertices id="vtx"><input semantic="POSITION" source="#pos"/></vertices>
      <triangles count="12"><input semantic="VERTEX" source="#vtx" offset="0"/>
        <p>{triangles}</p></triangles>
    </mesh></geometry>
  </library_geometries>
  <library_visual_scenes><visual_scene id="scene">
    <node id="cube-node"><instance_geometry url="#cube"/></node>
  </visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#scene"/></scene>
</COLLADA>
"""


def _cube_dae(tmp_path, name: str, size: float, unit: str = "", extra=()) -> str:
    """A cube of side ``size`` (file units) from corner 0, with ``extra`` unused points."""
    points = [tuple(size * c for c in p) for p in CORNERS] + list(extra)
    path = tmp_path / name
    path.write_text(DAE.format(unit=unit, count=3 * len(points), points=len(points),
                               positions=" ".join(f"{x:g}" for p in points for x in p),
                               triangles=" ".join(str(i) for t in CUBE for i in t)))
    return path


def _cube_obj(tmp_path, name: str, size: float = 1.0, extra=()) -> str:
    points = [tuple(size * c for c in p) for p in CORNERS] + list(extra)
    path = tmp_path / name
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in points)
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in CUBE))
    return path


@pytest.fixture(autouse=True)
def _fresh(tmp_path, monkeypatch):
    """Every test with its own disk cache and an empty per-process cache."""
    monkeypatch.setenv("CELLSIGHT_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(meshes, "_LOADED", {})


def _extent(solid: Polyhedron) -> np.ndarray:
    return np.ptp(solid.vertices, axis=0)


# --- COLLADA units ---------------------------------------------------------------------------


@pytest.mark.parametrize(("unit", "size", "metres"), [
    ('<unit name="millimeter" meter="0.001"/>', 100, 0.1),
    ('<unit name="inch" meter="0.0254"/>', 4, 0.1016),
    ("", 0.25, 0.25),  # no <unit>: COLLADA's default, 1 m
    ('<unit name="metre"/>', 0.25, 0.25),  # no meter attribute: 1 m as well
], ids=["mm", "inch", "no-unit", "no-meter"])
def test_collada_units_are_honoured(tmp_path, unit, size, metres) -> None:
    solid = meshes.load_mesh_solid(_cube_dae(tmp_path, "cube.dae", size, unit))
    assert _extent(solid) == pytest.approx([metres] * 3, rel=1e-12)
    assert solid.closed and len(solid.faces) == 6
    assert solid.volume() == pytest.approx(metres**3, rel=1e-9)


def test_scale_multiplies_the_collada_unit(tmp_path) -> None:
    path = _cube_dae(tmp_path, "cube.dae", 100, '<unit meter="0.001"/>')
    assert _extent(meshes.load_mesh_solid(path, scale=2.0)) == pytest.approx([0.2] * 3)


@pytest.mark.parametrize("meter", ["0", "-0.001", "nan", "inf", "one"])
def test_a_bad_collada_unit_is_refused_naming_file_and_value(tmp_path, meter) -> None:
    path = _cube_dae(tmp_path, "bad.dae", 1, f'<unit meter="{meter}"/>')
    expected = (rf"mesh file {re.escape(str(path))}: <unit meter='{meter}'>: "
                r"expected a positive number of metres per unit")
    with pytest.raises(GeometryError, match=expected):
        meshes.load_mesh_solid(path)


def _cell_with_mesh(tmp_path, mesh_name: str) -> str:
    data = yaml.safe_load(builtin_cell_path().read_text())
    data = copy.deepcopy(data)
    data["static"].append({"name": "crate", "solids": [{"mesh": {"file": mesh_name}}]})
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_a_cell_file_gets_the_dae_in_metres(tmp_path) -> None:
    _cube_dae(tmp_path, "crate.dae", 300, '<unit name="millimeter" meter="0.001"/>')
    cell = load_cell(_cell_with_mesh(tmp_path, "crate.dae"))
    crate = cell.objects[cell.object_index("crate")].solid
    assert _extent(crate) == pytest.approx([0.3] * 3)


def test_a_bad_unit_is_one_line_and_exit_2(tmp_path, capsys) -> None:
    _cube_dae(tmp_path, "crate.dae", 1, '<unit meter="-1"/>')
    cell = _cell_with_mesh(tmp_path, "crate.dae")
    with pytest.raises(CellFileError, match=r"field 'static\[\d+\]\.solids\[0\]'.*crate\.dae: "
                                            r"<unit meter='-1'>"):
        load_cell(cell)
    assert main(["visibility", "--cell", cell]) == 2
    err = capsys.readouterr().err
    assert err.startswith("cellsight: error: ") and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1 and "<unit meter='-1'>" in err


# --- vertices no face uses -------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["obj", "dae"])
def test_vertices_no_face_uses_are_no_feature_points(tmp_path, kind) -> None:
    extra = [(5.0, 5.0, 5.0), (0.5, 0.5, 0.5), (1.0, 1.0, 1.0)]  # far, inside, a duplicate
    make = _cube_obj if kind == "obj" else _cube_dae
    solid = meshes.load_mesh_solid(make(tmp_path, f"cube.{kind}", 1.0, extra=extra))
    corners = np.array(CORNERS, dtype=float)
    assert len(solid.feature_points) == 8
    assert sorted(map(tuple, solid.feature_points)) == sorted(map(tuple, corners))
    used = sorted({i for face in solid.faces for i in face})
    assert used == list(solid.feature_vertices) == list(range(len(solid.vertices)))


def test_an_stl_has_exactly_its_face_vertices_as_features(tmp_path) -> None:
    mesh = trimesh.creation.icosphere(subdivisions=2)
    path = tmp_path / "ball.stl"
    mesh.export(path)  # STL repeats each vertex per triangle: merged back
    solid = meshes.load_mesh_solid(path)
    assert len(solid.feature_points) == len(mesh.vertices)
    assert np.allclose(np.sort(solid.feature_points, axis=0), np.sort(mesh.vertices, axis=0),
                       atol=1e-6)  # STL stores float32


# --- the merge at numpy speed: same answers as the per-polygon checks ------------------------


def _random_polygons(rng, k: int, count: int) -> list[np.ndarray]:
    """Polygons of ``k`` vertices in random planes: simple stars, shuffled (mostly
    self-intersecting), some with a repeated vertex, collinear or out of plane."""
    out = []
    for n in range(count):
        angles = np.sort(rng.uniform(0, 2 * np.pi, k))
        xy = np.column_stack([np.cos(angles), np.sin(angles)]) * rng.uniform(0.2, 1.0, (k, 1))
        if n % 3 == 1:
            xy = xy[rng.permutation(k)]
        if n % 11 == 2:
            xy[1] = xy[0]
        if n % 13 == 3:
            xy[:, 1] = xy[:, 0] * 0.5
        frame = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        p = np.column_stack([xy, np.zeros(k)]) @ frame.T * rng.uniform(1e-3, 3.0)
        if n % 7 == 4:
            p[0] += frame[:, 2] * 1e-5
        out.append(p + rng.normal(size=3))
    return out


@pytest.mark.parametrize("k", [3, 4, 5, 6, 9, 17])
def test_vectorised_polygon_check_agrees_with_check_polygon(k) -> None:
    polygons = _random_polygons(np.random.default_rng(k), k, 300)
    expected = []
    for p in polygons:
        try:
            check_polygon(p, "p")
            expected.append(True)
        except GeometryError:
            expected.append(False)
    got = mesh_merge.valid_polygons(np.array(polygons))
    assert got.tolist() == expected
    assert 0 < sum(expected) < len(expected)


def _grid_box(k: int) -> trimesh.Trimesh:
    """A unit box whose faces are k x k grids of squares (12 k^2 triangles)."""
    lin = np.linspace(0.0, 1.0, k + 1)
    parts = []
    for axis in range(3):
        for side in (0.0, 1.0):
            a, b = np.meshgrid(lin, lin, indexing="ij")
            pts = np.zeros(((k + 1) ** 2, 3))
            others = [i for i in range(3) if i != axis]
            pts[:, others[0]], pts[:, others[1]], pts[:, axis] = a.ravel(), b.ravel(), side
            i, j = (x.ravel() for x in np.meshgrid(np.arange(k), np.arange(k), indexing="ij"))
            q = [i * (k + 1) + j, (i + 1) * (k + 1) + j, (i + 1) * (k + 1) + j + 1,
                 i * (k + 1) + j + 1]
            tris = np.concatenate([np.stack([q[0], q[1], q[2]], 1),
                                   np.stack([q[0], q[2], q[3]], 1)])
            parts.append(trimesh.Trimesh(pts, tris, process=False))
    mesh = trimesh.util.concatenate(parts)
    mesh.merge_vertices()
    trimesh.repair.fix_normals(mesh)
    return mesh


def test_a_finely_triangulated_box_merges_into_six_faces(tmp_path) -> None:
    path = tmp_path / "grid.stl"
    _grid_box(12).export(path)
    solid = meshes.load_mesh_solid(path)
    assert solid.closed and len(solid.faces) == 6
    assert sorted(map(len, solid.faces)) == [48] * 6  # boundary vertices kept
    assert solid.volume() == pytest.approx(1.0)


def test_a_loop_longer_than_the_cap_keeps_its_triangles(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(mesh_merge, "MERGE_MAX_VERTICES", 47)
    path = tmp_path / "grid.stl"
    _grid_box(12).export(path)
    solid = meshes.load_mesh_solid(path)
    assert solid.closed and len(solid.faces) == 12 * 144


def test_flipped_triangles_are_rewound_and_the_solid_stays_closed(tmp_path) -> None:
    mesh = trimesh.creation.icosphere(subdivisions=3)
    faces = mesh.faces.copy()
    faces[3::7] = faces[3::7, ::-1]
    faces[0] = faces[0, ::-1]  # the first triangle too: the whole part is wound from it
    path = tmp_path / "flipped.obj"
    trimesh.Trimesh(mesh.vertices, faces, process=False).export(path)
    solid = meshes.load_mesh_solid(path)
    assert solid.closed and solid.volume() == pytest.approx(mesh.volume, rel=1e-6)


def test_a_moebius_strip_loads_open(tmp_path) -> None:
    n = 24
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = [(np.cos(a) * (1 + s * np.cos(a / 2)), np.sin(a) * (1 + s * np.cos(a / 2)),
             s * np.sin(a / 2)) for a in t for s in (-0.3, 0.3)]
    tris = []
    for i in range(n):
        a, b = 2 * i, 2 * i + 1
        c, d = (2 * i + 2, 2 * i + 3) if i < n - 1 else (1, 0)  # the half twist
        tris += [(a, c, b), (b, c, d)]
    path = tmp_path / "moebius.obj"
    trimesh.Trimesh(np.array(ring), np.array(tris), process=False).export(path)
    solid = meshes.load_mesh_solid(path)
    assert not solid.closed and len(solid.vertices) == 2 * n


def test_a_closed_mesh_of_no_volume_is_open(tmp_path) -> None:
    path = tmp_path / "sheet.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 3 2\n")
    assert not meshes.load_mesh_solid(path).closed


@pytest.mark.parametrize("make", ["torus", "grid", "ball"])
def test_the_unchecked_solid_is_what_polyhedron_validates(tmp_path, make) -> None:
    mesh = {"torus": lambda: trimesh.creation.torus(0.3, 0.1, 40, 20),
            "grid": lambda: _grid_box(5), "ball": lambda: trimesh.creation.icosphere(3)}[make]()
    path = tmp_path / f"{make}.stl"
    mesh.export(path)
    solid = meshes.load_mesh_solid(path, "part")
    checked = Polyhedron("part", solid.vertices, solid.faces, solid.closed)
    assert checked.faces == solid.faces and checked.closed == solid.closed
    assert np.allclose(checked.normals, solid.normals, atol=1e-12)
    assert checked.feature_names == solid.feature_names
    assert checked.feature_vertices == solid.feature_vertices
    assert solid.volume() == pytest.approx(mesh.volume, rel=1e-6)


# --- the disk cache --------------------------------------------------------------------------


@pytest.fixture
def counted(monkeypatch) -> list[int]:
    """How many times the expensive step (merging a mesh) runs."""
    calls = [0]
    prepare = meshes.prepare_mesh

    def counting(*args, **kwargs):
        calls[0] += 1
        return prepare(*args, **kwargs)

    monkeypatch.setattr(meshes, "prepare_mesh", counting)
    return calls


def _same(a: Polyhedron, b: Polyhedron) -> bool:
    return (np.array_equal(a.vertices, b.vertices) and a.faces == b.faces
            and a.closed == b.closed and np.array_equal(a.normals, b.normals)
            and a.feature_names == b.feature_names and a.feature_vertices == b.feature_vertices)


def _load_in_a_new_process(path, **kwargs) -> Polyhedron:
    meshes._LOADED.clear()
    return meshes.load_mesh_solid(path, **kwargs)


def _entries(tmp_path) -> list:
    return sorted((tmp_path / "cache").iterdir())


def test_the_second_load_comes_from_the_cache(tmp_path, counted) -> None:
    path = tmp_path / "torus.stl"
    trimesh.creation.torus(0.3, 0.1, 32, 16).export(path)
    fresh = _load_in_a_new_process(path, name="a")
    assert counted[0] == 1 and len(_entries(tmp_path)) == 1
    cached = _load_in_a_new_process(path, name="a")
    assert counted[0] == 1
    assert _same(fresh, cached)
    assert [p.suffix for p in _entries(tmp_path)] == [".npz"]  # no temporary file left


def test_a_changed_file_or_scale_is_not_served_from_the_cache(tmp_path, counted) -> None:
    path = _cube_obj(tmp_path, "cube.obj", 1.0)
    assert _extent(_load_in_a_new_process(path)) == pytest.approx([1.0] * 3)
    _cube_obj(tmp_path, "cube.obj", 2.0)
    assert _extent(_load_in_a_new_process(path)) == pytest.approx([2.0] * 3)
    assert _extent(_load_in_a_new_process(path, scale=0.5)) == pytest.approx([1.0] * 3)
    assert counted[0] == 3
    _load_in_a_new_process(path, scale=0.5)
    assert counted[0] == 3 and len(_entries(tmp_path)) == 3


def _garbage(entry) -> None:
    entry.write_bytes(b"not an npz file at all")


def _nan_vertex(entry) -> None:
    with np.load(entry) as npz:
        arrays = dict(npz)
    arrays["vertices"] = arrays["vertices"].copy()
    arrays["vertices"][0, 0] = np.nan
    np.savez(entry, **arrays)


def _index_out_of_range(entry) -> None:
    with np.load(entry) as npz:
        arrays = dict(npz)
    arrays["indices"] = arrays["indices"] + 100
    np.savez(entry, **arrays)


def _flat_face(entry) -> None:
    with np.load(entry) as npz:
        arrays = dict(npz)
    arrays["vertices"] = np.zeros_like(arrays["vertices"]) + np.arange(8)[:, None]  # collinear
    np.savez(entry, **arrays)


def _another_key(entry) -> None:
    with np.load(entry) as npz:
        arrays = dict(npz)
    arrays["key"] = np.array("something else")
    np.savez(entry, **arrays)


def _pickled(entry) -> None:
    with np.load(entry) as npz:
        arrays = dict(npz)
    arrays["closed"] = np.array([{"evil": 1}], dtype=object)
    np.savez(entry, **arrays)


@pytest.mark.parametrize("spoil", [_garbage, _nan_vertex, _index_out_of_range, _flat_face,
                                   _another_key, _pickled])
def test_a_bad_cache_entry_is_rebuilt_silently(tmp_path, counted, capsys, spoil) -> None:
    path = _cube_obj(tmp_path, "cube.obj")
    fresh = _load_in_a_new_process(path)
    (entry,) = _entries(tmp_path)
    spoil(entry)
    again = _load_in_a_new_process(path)
    assert counted[0] == 2 and _same(fresh, again)
    assert capsys.readouterr() == ("", "")
    _load_in_a_new_process(path)  # the entry was rewritten whole
    assert counted[0] == 2


def test_an_unwritable_cache_folder_is_skipped(tmp_path, monkeypatch, counted, capsys) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("CELLSIGHT_CACHE_DIR", str(blocker / "cache"))
    path = _cube_obj(tmp_path, "cube.obj")
    assert len(_load_in_a_new_process(path).faces) == 6
    assert len(_load_in_a_new_process(path).faces) == 6
    assert counted[0] == 2 and capsys.readouterr() == ("", "")


def test_the_cache_folder(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("CELLSIGHT_CACHE_DIR", str(tmp_path / "mine"))
    assert mesh_cache.cache_dir() == tmp_path / "mine"
    monkeypatch.delenv("CELLSIGHT_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert mesh_cache.cache_dir() == tmp_path / "xdg" / "cellsight"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert mesh_cache.cache_dir() == tmp_path / "home" / ".cache" / "cellsight"


def test_the_key_covers_the_bytes_the_parameters_and_the_version(monkeypatch) -> None:
    key = mesh_cache.entry_key(b"solid", {"scale": 1.0})
    assert key == mesh_cache.entry_key(b"solid", {"scale": 1.0})
    assert key != mesh_cache.entry_key(b"solid ", {"scale": 1.0})
    assert key != mesh_cache.entry_key(b"solid", {"scale": 2.0})
    monkeypatch.setattr(mesh_cache, "CACHE_VERSION", mesh_cache.CACHE_VERSION + 1)
    assert key != mesh_cache.entry_key(b"solid", {"scale": 1.0})

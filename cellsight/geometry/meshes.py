"""Solids from triangle mesh files (STL, OBJ) via trimesh, merged back into polygonal faces.

CAD exports triangulate every face; the BSP wants the original planar polygons (fewer surfaces,
the paper's feature-point sequences). Adjacent coplanar triangles (trimesh's ``facets``) are
merged, and the boundary of each merged region is walked into one counter-clockwise loop.
Vertices in the middle of a straight boundary edge are kept (they are mesh vertices).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cellsight.errors import GeometryError
from cellsight.geometry.polyhedron import Polyhedron


def _boundary_loop(name: str, triangles: np.ndarray) -> list[int]:
    """Walk the boundary of a set of consistently wound triangles into one vertex loop."""
    directed = {
        (int(t[i]), int(t[(i + 1) % 3])) for t in triangles for i in range(3)
    }
    boundary = [(a, b) for a, b in directed if (b, a) not in directed]
    nxt: dict[int, int] = {}
    for a, b in boundary:
        if a in nxt:
            raise GeometryError(f"solid '{name}': a merged face touches itself at vertex {a}")
        nxt[a] = b
    start = boundary[0][0]
    loop = [start]
    while nxt[loop[-1]] != start:
        loop.append(nxt[loop[-1]])
        if len(loop) > len(nxt):
            raise GeometryError(f"solid '{name}': broken face boundary")
    if len(loop) != len(nxt):
        raise GeometryError(
            f"solid '{name}': a planar region has a hole or several boundaries; "
            f"split it into simple faces"
        )
    return loop


def polyhedron_from_trimesh(name: str, mesh, scale: float = 1.0) -> Polyhedron:
    """Polyhedron from a :class:`trimesh.Trimesh`, merging adjacent coplanar triangles."""
    if not mesh.is_winding_consistent:
        raise GeometryError(f"solid '{name}': the mesh's triangles are not consistently wound")
    if mesh.is_watertight and mesh.volume < 0:
        mesh.invert()
    faces: list[list[int]] = []
    in_facet = np.zeros(len(mesh.faces), dtype=bool)
    for facet in mesh.facets:
        in_facet[facet] = True
        faces.append(_boundary_loop(name, mesh.faces[facet]))
    faces += [list(map(int, t)) for t in mesh.faces[~in_facet]]
    used = sorted({i for f in faces for i in f})
    remap = {old: new for new, old in enumerate(used)}
    vertices = np.asarray(mesh.vertices, dtype=float)[used] * scale
    return Polyhedron(
        name, vertices, tuple(tuple(remap[i] for i in f) for f in faces), bool(mesh.is_watertight)
    )


MESH_TYPES = (".stl", ".obj")  # file types read
MAX_MESH_BYTES = 100 * 2**20  # bytes, largest mesh file read


def _read_mesh(path: Path):
    """The triangle mesh in an STL or OBJ file, unprocessed; a :class:`GeometryError` naming
    the file when it is missing, of another type, too large or unreadable."""
    import trimesh

    if not path.is_file():
        raise GeometryError(f"mesh file {path} does not exist (or is not a file)")
    if path.suffix.lower() not in MESH_TYPES:
        raise GeometryError(f"mesh file {path}: type {path.suffix or '(none)'!r} is not one of "
                            f"{', '.join(MESH_TYPES)}")
    if path.stat().st_size > MAX_MESH_BYTES:
        raise GeometryError(f"mesh file {path}: {path.stat().st_size} bytes, more than "
                            f"{MAX_MESH_BYTES}")
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh's parsers raise anything on bad input
        detail = str(exc).splitlines()[0][:80] if str(exc) else type(exc).__name__
        raise GeometryError(f"mesh file {path}: not a readable mesh ({detail})") from exc
    if not isinstance(mesh, trimesh.Trimesh):
        raise GeometryError(f"mesh file {path}: not a triangle mesh")
    return mesh


def load_mesh_solid(path: str | Path, name: str | None = None, scale: float = 1.0) -> Polyhedron:
    """Load an STL or OBJ file as a polyhedron (see :func:`polyhedron_from_trimesh`).

    Refused, naming the file: a missing file, another type, a file trimesh cannot read, no
    triangles, a non-finite vertex (trimesh's own processing would drop the triangles that use
    it, silently opening a closed solid), a triangle naming a vertex that is not there.
    """
    path = Path(path)
    mesh = _read_mesh(path)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    if len(faces) == 0:
        raise GeometryError(f"mesh file {path} holds no triangles (empty, or not an "
                            f"{path.suffix[1:].upper()} file)")
    bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
    if len(bad):
        raise GeometryError(f"mesh file {path}: vertex {int(bad[0]) + 1} is not finite "
                            f"({np.asarray(vertices[bad[0]]).tolist()})")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise GeometryError(f"mesh file {path}: a triangle names a vertex outside "
                            f"1..{len(vertices)}")
    mesh.process()
    mesh.merge_vertices()
    return polyhedron_from_trimesh(name or path.stem, mesh, scale)

"""Solids from triangle mesh files (STL, OBJ, COLLADA) via trimesh, merged back into polygons.

CAD exports triangulate every face; the BSP wants the original planar polygons (fewer surfaces,
the paper's feature-point sequences). Any triangle mesh loads; the steps, with coordinates
already in metres (``scale`` applied first) so that the tolerances below are absolute:

1. Duplicate vertices are merged (trimesh, positions equal to 1e-8 m).
2. Degenerate triangles are removed without opening the mesh (:func:`drop_degenerate`): a
   triangle is degenerate when Polyhedron would refuse it, i.e. its area is at most
   ``AREA_TOL`` (1e-10 m^2) or an edge is at most 1e-9 m (times its size when over 1 m).
   A triangle with an edge of at most ``COLLAPSE_TOL`` (1e-6 m) has that edge collapsed (one
   end replaces the other everywhere, moving the surface by at most that much); any other one,
   (a, b, c) with b the vertex opposite its longest edge c->a, is removed together with its
   neighbour (a, c, d) across that edge, which is replaced by (a, b, d) and (b, c, d): the
   mesh stays closed and the volume changes by the flat tetrahedron abcd only. Where that
   edge has no single neighbour (an open or non-manifold edge) the triangle is just dropped,
   and so is every degenerate triangle left after 8 edits per degenerate triangle found.
3. Winding is made consistent where trimesh can (``fix_winding``); a watertight, consistently
   wound mesh gives ``closed=True`` wound outward (inverted if its volume is negative), any
   other one an open solid (``closed=False``).
4. Adjacent near-coplanar triangles (trimesh's ``facets``) are merged into one polygon only
   where the merge is exact: every vertex of the region within ``MERGE_TOL`` (1e-7 m, a tenth
   of Polyhedron's ``PLANARITY_TOL``, so that the volume is kept) of the region's
   least-squares plane, the triangles consistently wound, the boundary a single
   loop through each vertex once (no hole, no second loop, no pinched vertex), and the loop a
   valid polygon for :func:`~cellsight.geometry.polygon.check_polygon` (simple in its plane,
   no coincident vertices). Every other region keeps its triangles. Vertices in the middle of
   a straight boundary edge are kept (they are mesh vertices); vertices inside a merged face
   that no face uses any more are dropped.
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from cellsight.errors import GeometryError
from cellsight.geometry.polygon import AREA_TOL, check_polygon
from cellsight.geometry.polyhedron import Polyhedron

COLLAPSE_TOL = 1e-6  # m, a degenerate triangle's edge at most this long is collapsed
MERGE_TOL = 1e-7  # m, largest distance of a merged region's vertex from its fitted plane


def _is_degenerate(v: np.ndarray, tri: tuple[int, int, int]) -> bool:
    """True if Polyhedron would refuse triangle ``tri``: area <= AREA_TOL (m^2), or an edge
    <= 1e-9 m times max(1, size) (both with a 1 % margin)."""
    p, q, r = v[tri[0]], v[tri[1]], v[tri[2]]
    u, w = q - p, r - p
    cx, cy, cz = u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]
    area = 0.5 * math.sqrt(cx * cx + cy * cy + cz * cz)
    shortest = min(math.dist(p, q), math.dist(q, r), math.dist(r, p))
    size = max(max(p[i], q[i], r[i]) - min(p[i], q[i], r[i]) for i in range(3))
    return area <= 1.01 * AREA_TOL or shortest <= 1.01e-9 * max(size, 1.0)


class _TriangleSet:
    """Triangles by id with their directed edges and vertices, for local edits."""

    def __init__(self, faces) -> None:
        self.live: dict[int, tuple[int, int, int]] = {}
        self.by_edge: dict[tuple[int, int], set[int]] = defaultdict(set)
        self.by_vertex: dict[int, set[int]] = defaultdict(set)
        self.next_id = 0
        for f in faces:
            self.add(tuple(int(i) for i in f))

    def add(self, tri: tuple[int, int, int]) -> int:
        """Add a triangle; its id."""
        k, self.next_id = self.next_id, self.next_id + 1
        self.live[k] = tri
        for i in range(3):
            self.by_edge[(tri[i], tri[(i + 1) % 3])].add(k)
            self.by_vertex[tri[i]].add(k)
        return k

    def remove(self, k: int) -> tuple[int, int, int]:
        """Remove triangle ``k``; its vertices."""
        tri = self.live.pop(k)
        for i in range(3):
            self.by_edge[(tri[i], tri[(i + 1) % 3])].discard(k)
            self.by_vertex[tri[i]].discard(k)
        return tri


def _rotate_to(tri: tuple[int, ...], first: int) -> tuple[int, ...]:
    """The same cyclic triangle starting at vertex ``first``."""
    i = tri.index(first)
    return tri[i:] + tri[:i]


def _fix_degenerate(v: np.ndarray, ts: _TriangleSet, k: int) -> tuple[list[int], bool]:
    """Remove degenerate triangle ``k`` (see the module docstring); the ids of the triangles
    made and whether it had to be dropped (possibly opening the mesh)."""
    tri = ts.live[k]
    p = v[list(tri)]
    edges = np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1)  # edge i: tri[i] -> tri[i+1]
    if edges.min() <= COLLAPSE_TOL:
        i = int(edges.argmin())
        keep, gone = tri[i], tri[(i + 1) % 3]
        made = []
        for j in list(ts.by_vertex[gone]):
            new = tuple(keep if x == gone else x for x in ts.remove(j))
            if len(set(new)) == 3:
                made.append(ts.add(new))
        return made, False
    longest = int(edges.argmax())
    a, b, c = _rotate_to(tri, tri[(longest + 1) % 3])  # longest edge is c -> a
    twins = ts.by_edge.get((a, c), set())
    ts.remove(k)
    if len(twins) != 1:
        return [], True
    (t,) = twins
    _, _, d = _rotate_to(ts.remove(t), a)
    if d == b:  # two flat triangles back to back: both go
        return [], False
    return [ts.add((a, b, d)), ts.add((b, c, d))], False


def drop_degenerate(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, int]:
    """Triangles (t, 3) without degenerate ones, and how many had to be dropped outright
    (possibly opening the mesh). ``vertices`` in metres; the rules are in the module
    docstring. Triangles that repeat a vertex are dropped first (their edges cancel)."""
    v = np.asarray(vertices, dtype=float)
    ts = _TriangleSet(f for f in np.asarray(faces) if len(set(f.tolist())) == 3)
    queue = [k for k, tri in ts.live.items() if _is_degenerate(v, tri)]
    dropped, budget = 0, 8 * len(queue) + 16
    while queue:
        k = queue.pop()
        if k not in ts.live or not _is_degenerate(v, ts.live[k]):
            continue
        budget -= 1
        if budget < 0:  # edits keep making degenerate triangles: drop what is left
            ts.remove(k)
            dropped += 1
            continue
        made, was_dropped = _fix_degenerate(v, ts, k)
        dropped += was_dropped
        queue += [j for j in made if _is_degenerate(v, ts.live[j])]
    tris = np.array(list(ts.live.values()), dtype=np.int64).reshape(-1, 3)
    return tris, dropped


def _single_loop(triangles: np.ndarray) -> list[int] | None:
    """The boundary of a set of triangles as one vertex loop (in their winding), or None if
    the triangles are not consistently wound or the boundary is not one loop through each of
    its vertices once (a hole, several loops, a pinched vertex)."""
    directed = [(int(t[i]), int(t[(i + 1) % 3])) for t in triangles for i in range(3)]
    edge_set = set(directed)
    if len(edge_set) != len(directed):
        return None
    boundary = [(a, b) for a, b in directed if (b, a) not in edge_set]
    nxt = dict(boundary)
    if len(nxt) != len(boundary) or len(set(nxt.values())) != len(boundary) or not boundary:
        return None
    loop = [boundary[0][0]]
    while nxt[loop[-1]] != loop[0]:
        loop.append(nxt[loop[-1]])
    return loop if len(loop) == len(boundary) else None


def _merged_face(v: np.ndarray, triangles: np.ndarray) -> list[int] | None:
    """One polygon for a region of adjacent triangles (vertices in metres), or None unless
    the merge is exact (planar within MERGE_TOL, one simple boundary loop)."""
    p = v[np.unique(triangles)]
    centred = p - p.mean(axis=0)
    normal = np.linalg.svd(centred, full_matrices=False)[2][-1]
    if float(np.abs(centred @ normal).max()) > MERGE_TOL:
        return None
    loop = _single_loop(triangles)
    if loop is None:
        return None
    try:
        check_polygon(v[loop], "merged face")
    except GeometryError:
        return None
    return loop


def polyhedron_from_trimesh(name: str, mesh, scale: float = 1.0) -> Polyhedron:
    """Polyhedron from a :class:`trimesh.Trimesh` in file units times ``scale`` (m per unit),
    following the steps of the module docstring."""
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(mesh.vertices, dtype=float) * scale,
                           np.asarray(mesh.faces), process=False)
    mesh.merge_vertices()
    tris, _ = drop_degenerate(mesh.vertices, mesh.faces)
    if len(tris) == 0:
        raise GeometryError(f"solid '{name}': every triangle is degenerate (zero area)")
    mesh = trimesh.Trimesh(mesh.vertices, tris, process=False)
    if not mesh.is_winding_consistent:
        trimesh.repair.fix_winding(mesh)
    closed = bool(mesh.is_watertight and mesh.is_winding_consistent)
    if closed and mesh.volume < 0:
        mesh.invert()
    v, all_tris = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    faces: list[list[int]] = []
    in_face = np.zeros(len(all_tris), dtype=bool)
    for facet in mesh.facets:
        loop = _merged_face(v, all_tris[facet])
        if loop is not None:
            in_face[facet] = True
            faces.append(loop)
    faces += [list(map(int, t)) for t in all_tris[~in_face]]
    used = sorted({i for f in faces for i in f})
    remap = {old: new for new, old in enumerate(used)}
    return Polyhedron(name, v[used], tuple(tuple(remap[i] for i in f) for f in faces), closed)


MESH_TYPES = (".stl", ".obj", ".dae")  # file types read (COLLADA needs pycollada)
MAX_MESH_BYTES = 100 * 2**20  # bytes, largest mesh file read


def _read_mesh(path: Path):
    """The triangle mesh in an STL, OBJ or COLLADA file (a COLLADA scene's geometry is joined
    with its node transforms), unprocessed; a :class:`GeometryError` naming
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
    """Load an STL, OBJ or COLLADA (.dae) file as a polyhedron, its coordinates times
    ``scale`` (m per file unit; see :func:`polyhedron_from_trimesh`).

    Refused, naming the file: a missing file, another type, a file trimesh cannot read, no
    triangles, a non-finite vertex (trimesh's own processing would drop the triangles that use
    it, silently opening a closed solid), a triangle naming a vertex that is not there.
    """
    path = Path(path)
    key = _cache_key(path, scale)
    if key is not None and key in _LOADED:
        return _LOADED[key].renamed(name or path.stem)
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
    solid = polyhedron_from_trimesh(name or path.stem, mesh, scale)
    if key is not None:
        _LOADED[key] = solid
    return solid


#: Solids already loaded in this process, by (resolved file, size, modification time, scale):
#: a robot model's meshes are merged once however many arms use them (errors are not kept).
_LOADED: dict[tuple, Polyhedron] = {}


def _cache_key(path: Path, scale: float) -> tuple | None:
    """The key of ``path`` in ``_LOADED`` (None when it cannot be read: the load reports it)."""
    try:
        stat = path.resolve().stat()
    except OSError:
        return None
    return (str(path.resolve()), stat.st_size, stat.st_mtime_ns, float(scale))

"""Solids from triangle mesh files (STL, OBJ, COLLADA) via trimesh, merged back into polygons.

CAD exports triangulate every face; the BSP wants the original planar polygons (fewer surfaces,
the paper's feature-point sequences). Any triangle mesh loads; the steps, with coordinates
already in metres so that the tolerances below are absolute:

0. Units: a COLLADA file's coordinates are times its ``<unit meter="...">`` (metres per unit,
   from the root ``<asset>``; 1 when there is none, COLLADA's default), then times ``scale``;
   STL and OBJ have no units: times ``scale`` only.
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
3. Winding is made consistent where it can be, as trimesh's ``fix_winding`` does it (each
   connected part keeps the winding of its lowest-numbered triangle); a watertight,
   consistently wound mesh with a non-zero volume gives ``closed=True`` wound outward
   (inverted if its volume is negative), any other one an open solid (``closed=False``).
4. Adjacent near-coplanar triangles (trimesh's ``facets``) are merged into one polygon only
   where the merge is exact: every vertex of the region within ``MERGE_TOL`` (1e-7 m, a tenth
   of Polyhedron's ``PLANARITY_TOL``, so that the volume is kept) of the region's
   least-squares plane, the triangles consistently wound, the boundary a single
   loop through each vertex once (no hole, no second loop, no pinched vertex) of at most
   ``MERGE_MAX_VERTICES`` (4096) vertices, and the loop a valid polygon for
   :func:`~cellsight.geometry.polygon.check_polygon` (simple in its plane, no coincident
   vertices). Every other region keeps its triangles. All regions are tested at once with
   numpy (the cost grows with the number of triangles, and with the square of a loop's
   length for the simplicity test). Vertices in the middle of a straight boundary edge are
   kept (they are mesh vertices).
5. Vertices that no face uses (unused in the file, collapsed in step 2, inside a merged face)
   are dropped: the solid's vertices, hence its default feature points, are exactly the
   vertices of its faces.

Every face is valid by construction (steps 2 and 4 apply Polyhedron's own criteria), so the
solid is built without Polyhedron's per-face Python checks. The result of steps 0-5 is kept
on disk by :mod:`cellsight.geometry.mesh_cache`, keyed by the file's SHA-256 digest.
"""

from __future__ import annotations

import dataclasses
import io
import math
import xml.etree.ElementTree as ET
from collections import defaultdict
from pathlib import Path

import numpy as np

from cellsight.errors import GeometryError, short_repr
from cellsight.geometry import mesh_cache, mesh_merge
from cellsight.geometry.mesh_cache import PreparedMesh
from cellsight.geometry.mesh_merge import merged_faces
from cellsight.geometry.polygon import AREA_TOL, PLANARITY_TOL
from cellsight.geometry.polyhedron import Polyhedron

COLLAPSE_TOL = 1e-6  # m, a degenerate triangle's edge at most this long is collapsed


def _degenerate(v: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Per triangle of ``tris`` (t, 3), whether Polyhedron would refuse it: area <= AREA_TOL
    (m^2), or an edge <= 1e-9 m times max(1, size) (both with a 1 % margin)."""
    p, q, r = v[tris[:, 0]], v[tris[:, 1]], v[tris[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(q - p, r - p), axis=1)
    shortest = np.minimum(np.minimum(np.linalg.norm(q - p, axis=1),
                                     np.linalg.norm(r - q, axis=1)),
                          np.linalg.norm(p - r, axis=1))
    size = (np.maximum(np.maximum(p, q), r) - np.minimum(np.minimum(p, q), r)).max(axis=1)
    return (area <= 1.01 * AREA_TOL) | (shortest <= 1.01e-9 * np.maximum(size, 1.0))


class _TriangleSet:
    """Triangles by id, the input's (ids 0..t-1) then the ones added, with lookups by vertex
    and by directed edge for local edits. The input is indexed once with numpy, so an edit
    costs the same whatever the size of the mesh."""

    def __init__(self, faces: np.ndarray, n_vertices: int) -> None:
        self.faces = faces
        self.alive = np.ones(len(faces), dtype=bool)
        order = np.argsort(faces.ravel(), kind="stable")
        self.by_vertex = order // 3  # input triangle ids, grouped by vertex
        self.start = np.searchsorted(faces.ravel()[order], np.arange(n_vertices + 1))
        self.added: dict[int, tuple[int, int, int]] = {}
        self.added_by_vertex: dict[int, set[int]] = defaultdict(set)
        self.next_id = len(faces)

    def get(self, k: int) -> tuple[int, int, int] | None:
        """Triangle ``k``'s vertices, None once removed."""
        if k < len(self.faces):
            return tuple(map(int, self.faces[k])) if self.alive[k] else None
        return self.added.get(k)

    def around(self, vertex: int) -> list[int]:
        """The ids of the triangles using ``vertex``."""
        mine = self.by_vertex[self.start[vertex]:self.start[vertex + 1]]
        return [int(k) for k in mine[self.alive[mine]]] + sorted(self.added_by_vertex[vertex])

    def with_edge(self, a: int, b: int) -> list[int]:
        """The ids of the triangles with the directed edge a -> b."""
        return [k for k in self.around(a) if b == _rotate_to(self.get(k), a)[1]]

    def add(self, tri: tuple[int, int, int]) -> int:
        """Add a triangle; its id."""
        k, self.next_id = self.next_id, self.next_id + 1
        self.added[k] = tri
        for i in tri:
            self.added_by_vertex[i].add(k)
        return k

    def remove(self, k: int) -> tuple[int, int, int]:
        """Remove triangle ``k``; its vertices."""
        tri = self.get(k)
        if k < len(self.faces):
            self.alive[k] = False
        else:
            del self.added[k]
            for i in tri:
                self.added_by_vertex[i].discard(k)
        return tri

    def triangles(self) -> np.ndarray:
        """The live triangles (t, 3): the input's in order, then the added ones in order."""
        added = np.array(list(self.added.values()), dtype=np.int64).reshape(-1, 3)
        return np.concatenate([self.faces[self.alive], added])


def _rotate_to(tri: tuple[int, ...], first: int) -> tuple[int, ...]:
    """The same cyclic triangle starting at vertex ``first``."""
    i = tri.index(first)
    return tri[i:] + tri[:i]


def _fix_degenerate(v: np.ndarray, ts: _TriangleSet, k: int) -> tuple[list[int], bool]:
    """Remove degenerate triangle ``k`` (see the module docstring); the ids of the triangles
    made and whether it had to be dropped (possibly opening the mesh)."""
    tri = ts.get(k)
    p = v[list(tri)]
    edges = np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1)  # edge i: tri[i] -> tri[i+1]
    if edges.min() <= COLLAPSE_TOL:
        i = int(edges.argmin())
        keep, gone = tri[i], tri[(i + 1) % 3]
        made = []
        for j in ts.around(gone):
            new = tuple(keep if x == gone else x for x in ts.remove(j))
            if len(set(new)) == 3:
                made.append(ts.add(new))
        return made, False
    longest = int(edges.argmax())
    a, b, c = _rotate_to(tri, tri[(longest + 1) % 3])  # longest edge is c -> a
    twins = ts.with_edge(a, c)
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
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]
    queue = np.flatnonzero(_degenerate(v, f)).tolist()
    if not queue:
        return f, 0
    ts = _TriangleSet(f, len(v))
    dropped, budget = 0, 8 * len(queue) + 16
    while queue:  # a triangle never changes (edits replace it), so a queued one stays flat
        k = queue.pop()
        if ts.get(k) is None:
            continue
        budget -= 1
        if budget < 0:  # edits keep making degenerate triangles: drop what is left
            ts.remove(k)
            dropped += 1
            continue
        made, was_dropped = _fix_degenerate(v, ts, k)
        dropped += was_dropped
        if made:
            queue += np.array(made)[_degenerate(v, np.array([ts.get(j) for j in made]))].tolist()
    return ts.triangles(), dropped


def _newell_normals(v: np.ndarray, indices: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Newell's area-weighted normal (F, 3), |n| = 2 area, of each face (CSR ``indices``,
    ``offsets``) of vertices ``v``."""
    following = np.arange(1, len(indices) + 1)
    following[offsets[1:] - 1] = offsets[:-1]
    p, q = v[indices], v[indices[following]]
    terms = (p[:, [1, 2, 0]] - q[:, [1, 2, 0]]) * (p[:, [2, 0, 1]] + q[:, [2, 0, 1]])
    return np.add.reduceat(terms, offsets[:-1], axis=0)


def _edge_follows(tris: np.ndarray, u: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Per row, whether triangle ``tris`` (n, 3) has the directed edge u -> w."""
    at = np.argmax(tris == u[:, None], axis=1)
    return tris[np.arange(len(tris)), (at + 1) % 3] == w


def _consistently_wound(mesh) -> np.ndarray:
    """The triangles of trimesh ``mesh`` with some reversed so that two triangles sharing an
    edge (of exactly two triangles) traverse it in opposite directions where they can:
    what ``trimesh.repair.fix_winding`` does (a breadth-first tree per connected part, each
    part keeping the winding of its lowest-numbered triangle), with numpy and scipy instead of
    a Python loop per triangle. Where the parts cannot be wound consistently (a Moebius strip),
    the tree decides."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    tris, n = np.asarray(mesh.faces, dtype=np.int64), len(mesh.faces)
    pairs, edges = np.asarray(mesh.face_adjacency), np.asarray(mesh.face_adjacency_edges)
    same = (_edge_follows(tris[pairs[:, 0]], edges[:, 0], edges[:, 1])
            == _edge_follows(tris[pairs[:, 1]], edges[:, 0], edges[:, 1]))
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    part = connected_components(graph, directed=False)[1]
    roots = np.unique(part, return_index=True)[1]
    links = np.concatenate([pairs, np.stack([np.full(len(roots), n), roots], axis=1)])
    tree = coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(n + 1, n + 1))
    parent = breadth_first_order(tree, n, directed=False, return_predecessors=True)[1]
    parent[n] = n
    key = np.minimum(pairs[:, 0], pairs[:, 1]) * (n + 1) + np.maximum(pairs[:, 0], pairs[:, 1])
    order = np.argsort(key)
    child = np.arange(n)
    found = np.minimum(np.searchsorted(key[order], np.minimum(parent[:n], child) * (n + 1)
                                       + np.maximum(parent[:n], child)), len(order) - 1)
    flip = np.append((parent[:n] != n) & same[order[found]], False)
    jump = parent
    while np.any(jump != n):  # flip relative to the root: XOR along the path, by doubling
        flip, jump = flip ^ flip[jump], jump[jump]
    tris[flip[:n]] = tris[flip[:n]][:, ::-1]
    return tris


def _cleaned(label: str, vertices: np.ndarray, faces: np.ndarray):
    """Steps 1-3 of the module docstring: the vertices (metres), the triangles, trimesh's
    facets (lists of triangle ids) and whether the mesh is closed; ``label`` names the mesh in
    errors. The trimesh mesh and its caches are freed on return."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.merge_vertices()
    tris, _ = drop_degenerate(mesh.vertices, mesh.faces)
    if len(tris) == 0:
        raise GeometryError(f"{label}: every triangle is degenerate (zero area)")
    mesh = trimesh.Trimesh(mesh.vertices, tris, process=False)
    if not mesh.is_winding_consistent:
        mesh = trimesh.Trimesh(mesh.vertices, _consistently_wound(mesh), process=False)
    closed = bool(mesh.is_watertight and mesh.is_winding_consistent)
    v, tris = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    if closed and np.einsum("ij,ij->", v[tris[:, 0]], np.cross(v[tris[:, 1]], v[tris[:, 2]])) < 0:
        mesh.invert()  # the signed volume (times 6) was negative
    return np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64), mesh.facets, closed


def prepare_mesh(label: str, vertices: np.ndarray, faces: np.ndarray) -> PreparedMesh:
    """Steps 1-5 of the module docstring on triangles ``faces`` (t, 3) over ``vertices``
    (n, 3), finite, already in metres; ``label`` names the mesh in errors."""
    v, tris, facets, closed = _cleaned(label, np.asarray(vertices, dtype=float), faces)
    loops, lengths, in_face = merged_faces(v, tris, facets)
    rest = tris[~in_face]
    indices = np.concatenate([loops, rest.ravel()])
    offsets = np.concatenate([[0], np.cumsum(np.append(lengths, np.full(len(rest), 3)))])
    used, indices = np.unique(indices, return_inverse=True)
    if closed:  # the signed volume as Polyhedron computes it, divergence theorem
        volume = np.einsum("ij,ij->", _newell_normals(v, used[indices], offsets),
                           v[used[indices[offsets[:-1]]]]) / 6.0
        closed = bool(volume > 0.0)
    return PreparedMesh(v[used], indices.astype(np.int64), offsets.astype(np.int64), closed)


def _unit_normals(prepared: PreparedMesh) -> np.ndarray | None:
    """The faces' unit normals (F, 3) (Newell, right-hand rule), or None when a face has no
    area (possible only in a cache entry not made by :func:`prepare_mesh`)."""
    normals = _newell_normals(*prepared[:3])
    length = np.linalg.norm(normals, axis=1)
    return normals / length[:, None] if np.all(length > 0.0) else None


def _solid(name: str, prepared: PreparedMesh, normals: np.ndarray) -> Polyhedron:
    """The Polyhedron of ``prepared`` with its unit ``normals``, every vertex a feature (``f1``,
    ``f2``, ... in vertex order), built without Polyhedron's per-face checks (Python, about
    0.1 ms a face): steps 2-4 of the module docstring apply the same criteria to every face."""
    idx, off = prepared.indices, prepared.offsets
    runs = np.concatenate([[0], np.flatnonzero(np.diff(np.diff(off))) + 1, [len(off) - 1]])
    faces: list[tuple[int, ...]] = []
    for a, b in zip(runs[:-1], runs[1:], strict=True):  # faces a..b-1 have the same length
        block = idx[off[a]:off[b]].reshape(b - a, -1)
        faces += map(tuple, block.tolist())
    n = len(prepared.vertices)
    values = {"name": name, "vertices": prepared.vertices, "closed": prepared.closed,
              "faces": tuple(faces), "feature_names": tuple(map("f{}".format, range(1, n + 1))),
              "feature_vertices": tuple(range(n)), "normals": normals}
    solid = object.__new__(Polyhedron)
    for f in dataclasses.fields(Polyhedron):  # a field added to Polyhedron fails here
        object.__setattr__(solid, f.name, values[f.name])
    return solid


MESH_TYPES = (".stl", ".obj", ".dae")  # file types read (COLLADA needs pycollada)
MAX_MESH_BYTES = 100 * 2**20  # bytes, largest mesh file read


def _file_bytes(path: Path) -> bytes:
    """The bytes of mesh file ``path``; a :class:`GeometryError` naming it when it is missing,
    of another type, too large or unreadable."""
    if not path.is_file():
        raise GeometryError(f"mesh file {path} does not exist (or is not a file)")
    if path.suffix.lower() not in MESH_TYPES:
        raise GeometryError(f"mesh file {path}: type {path.suffix or '(none)'!r} is not one of "
                            f"{', '.join(MESH_TYPES)}")
    if path.stat().st_size > MAX_MESH_BYTES:
        raise GeometryError(f"mesh file {path}: {path.stat().st_size} bytes, more than "
                            f"{MAX_MESH_BYTES}")
    try:
        return path.read_bytes()
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise GeometryError(f"mesh file {path}: cannot be read ({reason})") from exc


def _root_unit(data: bytes) -> str | None:
    """The ``meter`` attribute of ``<unit>`` in the root ``<asset>`` of COLLADA document
    ``data`` (None without one), parsing only up to the end of that ``<asset>``."""
    tags: list[str] = []
    for event, element in ET.iterparse(io.BytesIO(data), events=("start", "end")):
        if event == "end":
            if tags.pop() == "asset" and len(tags) == 1:
                return None
            continue
        tags.append(element.tag.rpartition("}")[2])
        if len(tags) == 2 and tags[1] != "asset":
            return None
        if tags[1:] == ["asset", "unit"] and element.get("meter") is not None:
            return element.get("meter")
    return None


def collada_unit(data: bytes, path: Path) -> float:
    """Metres per unit of COLLADA document ``data`` (from file ``path``): the ``meter``
    attribute of ``<unit>`` in the root ``<asset>``, 1.0 without one (COLLADA's default). A
    :class:`GeometryError` naming the file and the value unless it is a positive finite
    number."""
    try:
        raw = _root_unit(data)
    except ET.ParseError as exc:
        raise GeometryError(f"mesh file {path}: not a readable mesh ({exc})") from exc
    if raw is None:
        return 1.0
    try:
        unit = float(raw)
    except ValueError:
        unit = math.nan
    if not (math.isfinite(unit) and unit > 0.0):
        raise GeometryError(f"mesh file {path}: <unit meter={short_repr(raw)}>: expected a "
                            f"positive number of metres per unit")
    return unit


def _read_mesh(path: Path, data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """The vertices (n, 3) in file units and triangles (t, 3) in the bytes ``data`` of STL, OBJ
    or COLLADA file ``path`` (a COLLADA scene's geometry joined with its node transforms),
    unprocessed; a :class:`GeometryError` naming the file when trimesh cannot read it."""
    import trimesh

    try:
        mesh = trimesh.load(io.BytesIO(data), file_type=path.suffix.lower()[1:], force="mesh",
                            process=False, resolver=trimesh.resolvers.FilePathResolver(path))
    except Exception as exc:  # trimesh's parsers raise anything on bad input
        detail = str(exc).splitlines()[0][:80] if str(exc) else type(exc).__name__
        raise GeometryError(f"mesh file {path}: not a readable mesh ({detail})") from exc
    if not isinstance(mesh, trimesh.Trimesh):
        raise GeometryError(f"mesh file {path}: not a triangle mesh")
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces)


def _prepared(path: Path, data: bytes, scale: float) -> PreparedMesh:
    """Steps 0-5 of the module docstring on the bytes ``data`` of mesh file ``path``.

    Refused, naming the file: a file trimesh cannot read, no triangles, a non-finite vertex
    (trimesh's own processing would drop the triangles that use it, silently opening a closed
    solid), a triangle naming a vertex that is not there, a COLLADA unit that is not a
    positive number.
    """
    vertices, faces = _read_mesh(path, data)
    if len(faces) == 0:
        raise GeometryError(f"mesh file {path} holds no triangles (empty, or not an "
                            f"{path.suffix[1:].upper()} file)")
    bad = np.flatnonzero(~np.isfinite(vertices).all(axis=1))
    if len(bad):
        raise GeometryError(f"mesh file {path}: vertex {int(bad[0]) + 1} is not finite "
                            f"({vertices[bad[0]].tolist()})")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise GeometryError(f"mesh file {path}: a triangle names a vertex outside "
                            f"1..{len(vertices)}")
    if path.suffix.lower() == ".dae":
        scale = scale * collada_unit(data, path)
    return prepare_mesh(f"mesh file {path}", vertices * scale, faces)


def load_mesh_solid(path: str | Path, name: str | None = None, scale: float = 1.0) -> Polyhedron:
    """Load an STL, OBJ or COLLADA (.dae) file as a polyhedron in metres: its coordinates
    times the COLLADA unit if any, times ``scale`` (see the module docstring), refused as
    :func:`_file_bytes` and :func:`_prepared` say.

    Kept per process (by file, size, modification time and scale) and on disk
    (:mod:`~cellsight.geometry.mesh_cache`, by the file's SHA-256): only a new or changed file
    is merged again.
    """
    path = Path(path)
    key = _process_key(path, scale)
    if key is not None and key in _LOADED:
        return _LOADED[key].renamed(name or path.stem)
    data = _file_bytes(path)
    entry = mesh_cache.entry_key(data, _parameters(scale))
    prepared = mesh_cache.read(entry)
    normals = None if prepared is None else _unit_normals(prepared)
    if normals is None:
        prepared = _prepared(path, data, scale)
        mesh_cache.write(entry, prepared)
        normals = _unit_normals(prepared)
    solid = _solid(name or path.stem, prepared, normals)
    if key is not None:
        _LOADED[key] = solid
    return solid


def _parameters(scale: float) -> dict:
    """What a prepared solid depends on besides the file's bytes (part of its cache key)."""
    return {"scale": float(scale), "collapse_tol": COLLAPSE_TOL, "merge_tol": mesh_merge.MERGE_TOL,
            "area_tol": AREA_TOL, "planarity_tol": PLANARITY_TOL,
            "merge_max_vertices": mesh_merge.MERGE_MAX_VERTICES}


#: Solids already loaded in this process, by (resolved file, size, modification time, scale):
#: a robot model's meshes are merged once however many arms use them (errors are not kept).
_LOADED: dict[tuple, Polyhedron] = {}


def _process_key(path: Path, scale: float) -> tuple | None:
    """The key of ``path`` in ``_LOADED`` (None when it cannot be read: the load reports it)."""
    try:
        stat = path.resolve().stat()
    except OSError:
        return None
    return (str(path.resolve()), stat.st_size, stat.st_mtime_ns, float(scale))

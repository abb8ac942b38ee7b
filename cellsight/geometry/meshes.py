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
from cellsight.geometry import mesh_cache
from cellsight.geometry.mesh_cache import PreparedMesh
from cellsight.geometry.polygon import AREA_TOL, PLANARITY_TOL
from cellsight.geometry.polyhedron import Polyhedron

COLLAPSE_TOL = 1e-6  # m, a degenerate triangle's edge at most this long is collapsed
MERGE_TOL = 1e-7  # m, largest distance of a merged region's vertex from its fitted plane
MERGE_MAX_VERTICES = 4096  # longest boundary loop merged into one face
_PAIRS_PER_CHUNK = 2**18  # edge pairs tested at once by the simplicity test (memory bound)


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


def _planar_regions(v: np.ndarray, tris: np.ndarray, region: np.ndarray, n: int) -> np.ndarray:
    """Per region (0..n-1, ``region`` per triangle of ``tris``), whether every vertex of its
    triangles is within MERGE_TOL of their least-squares plane (through their mean, normal
    the covariance's least eigenvector, as an SVD of the centred points would give)."""
    pairs = np.unique(region[:, None] * len(v) + tris)  # (region, vertex), sorted by region
    g, p = pairs // len(v), v[pairs % len(v)]
    count = np.bincount(g, minlength=n)
    mean = np.stack([np.bincount(g, p[:, i], minlength=n) for i in range(3)], axis=1)
    centred = p - (mean / count[:, None])[g]
    cov = np.empty((n, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[:, i, j] = cov[:, j, i] = np.bincount(g, centred[:, i] * centred[:, j],
                                                      minlength=n)
    normal = np.linalg.eigh(cov)[1][:, :, 0]
    dist = np.abs(np.einsum("ij,ij->i", centred, normal[g]))
    return np.maximum.reduceat(dist, np.searchsorted(g, np.arange(n))) <= MERGE_TOL


def _region_boundaries(tris: np.ndarray, region: np.ndarray, n: int, nv: int):
    """The boundary edges of each region (triangles ``tris`` of ``region`` 0..n-1, ``nv``
    vertices), as rows (region, from, to) in triangle order, and per region whether they can
    form one loop: the triangles consistently wound (no directed edge twice, no edge in three
    triangles), some boundary, every boundary vertex starting one boundary edge and ending one,
    at most MERGE_MAX_VERTICES of them."""
    a, b = tris.ravel(), tris[:, [1, 2, 0]].ravel()
    label = np.repeat(region, 3)
    edge = np.unique(np.minimum(a, b) * nv + np.maximum(a, b), return_inverse=True)[1]
    _, where, count = np.unique(label * (edge.max() + 1) + edge, return_inverse=True,
                                return_counts=True)
    forward = np.bincount(where, (a < b).astype(float))
    ok = np.ones(n, dtype=bool)
    ok[label[((count > 2) | ((count == 2) & (forward != 1)))[where]]] = False
    rows = np.stack([label, a, b], axis=1)[count[where] == 1]
    for ends in (rows[:, 1], rows[:, 2]):  # each vertex starts and ends one boundary edge
        _, first, times = np.unique(rows[:, 0] * nv + ends, return_index=True,
                                    return_counts=True)
        ok[rows[first[times > 1], 0]] = False
    size = np.bincount(rows[:, 0], minlength=n)
    ok &= (size > 0) & (size <= MERGE_MAX_VERTICES)
    return rows, ok


def _loops(rows: np.ndarray, n: int, nv: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The boundary rows (region, from, to) of regions whose boundary edges each start at a
    distinct vertex and end at a distinct one, as loops: per region, whether its boundary is a
    single loop, and the loops' vertices (in winding order, starting at the first row's
    vertex) with their region per vertex. Pointer doubling: log2(loop length) numpy passes."""
    node = rows[:, 0] * nv + rows[:, 1]
    order = np.argsort(node)
    succ = order[np.searchsorted(node[order], rows[:, 0] * nv + rows[:, 2])]  # next row
    rounds = int(math.ceil(math.log2(MERGE_MAX_VERTICES))) + 1
    lowest, jump = np.arange(len(rows)), succ.copy()
    for _ in range(rounds):  # lowest row of each cycle
        lowest, jump = np.minimum(lowest, lowest[jump]), jump[jump]
    first = np.unique(rows[:, 0], return_index=True)[1]
    cycles = np.bincount(rows[lowest == np.arange(len(rows)), 0], minlength=n)
    is_first = np.zeros(len(rows) + 1, dtype=bool)
    is_first[first] = True
    nxt = np.append(np.where(is_first[succ], len(rows), succ), len(rows))
    left = np.append(np.ones(len(rows), dtype=np.int64), 0)
    for _ in range(rounds):  # rows left until the loop is back at its first row
        left, nxt = left + left[nxt], nxt[nxt]
    walk = np.lexsort((-left[:-1], rows[:, 0]))
    return cycles == 1, rows[walk, 1], rows[walk, 0]


def _touching(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Per row, whether the 2D segments ab and cd intersect, touching within 1e-9 counting:
    :func:`cellsight.geometry.polygon._segments_cross` on arrays (n, 2)."""

    def orient(p, q, r):
        return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])

    def on_segment(p, q, r):
        return ((np.minimum(p, q) - 1e-9 <= r) & (r <= np.maximum(p, q) + 1e-9)).all(axis=1)

    quad = np.stack([a, b, c, d], axis=1)
    e = 1e-9 * np.maximum(np.ptp(quad, axis=1).max(axis=1), 1e-12)
    o1, o2, o3, o4 = orient(a, b, c), orient(a, b, d), orient(c, d, a), orient(c, d, b)
    crossing = ((((o1 > e) & (o2 < -e)) | ((o1 < -e) & (o2 > e)))
                & (((o3 > e) & (o4 < -e)) | ((o3 < -e) & (o4 > e))))
    return (crossing | ((np.abs(o1) <= e) & on_segment(a, b, c))
            | ((np.abs(o2) <= e) & on_segment(a, b, d)) | ((np.abs(o3) <= e) & on_segment(c, d, a))
            | ((np.abs(o4) <= e) & on_segment(c, d, b)))


def _simple(xy: np.ndarray) -> np.ndarray:
    """Per polygon of ``xy`` (g, k, 2), whether no two non-adjacent edges touch (tested in
    chunks of at most _PAIRS_PER_CHUNK edge pairs)."""
    g, k = xy.shape[:2]
    i, j = np.triu_indices(k, 2)
    keep = ~((i == 0) & (j == k - 1))
    i, j = i[keep], j[keep]
    simple = np.ones(g, dtype=bool)
    if len(i) == 0:
        return simple
    step_pairs = min(len(i), _PAIRS_PER_CHUNK)
    step_polys = max(1, _PAIRS_PER_CHUNK // step_pairs)
    for s in range(0, g, step_polys):
        for t in range(0, len(i), step_pairs):
            ii, jj = i[t:t + step_pairs], j[t:t + step_pairs]
            p = xy[s:s + step_polys]
            hit = _touching(*(p[:, idx].reshape(-1, 2) for idx in
                              (ii, (ii + 1) % k, jj, (jj + 1) % k)))
            simple[s:s + step_polys] &= ~hit.reshape(len(p), -1).any(axis=1)
    return simple


def _valid_polygons(p: np.ndarray) -> np.ndarray:
    """Per polygon of ``p`` (g, k, 3), finite, in metres, whether
    :func:`~cellsight.geometry.polygon.check_polygon` accepts it: no coincident consecutive
    vertices, area above AREA_TOL, every vertex within PLANARITY_TOL of the plane through the
    mean (Newell normal), simple in that plane."""
    q = np.roll(p, -1, axis=1)
    size = np.ptp(p, axis=1).max(axis=1)
    edges = np.linalg.norm(q - p, axis=2)
    ok = (edges > 1e-9 * np.maximum(size, 1.0)[:, None]).all(axis=1)
    normal = np.stack([np.sum((p[..., i] - q[..., i]) * (p[..., j] + q[..., j]), axis=1)
                       for i, j in ((1, 2), (2, 0), (0, 1))], axis=1)
    area = 0.5 * np.linalg.norm(normal, axis=1)
    ok &= area > AREA_TOL
    p, normal = p[ok], normal[ok] / (2 * area[ok, None])
    dist = np.einsum("gkc,gc->gk", p - p.mean(axis=1, keepdims=True), normal)
    flat = np.abs(dist).max(axis=1) <= PLANARITY_TOL
    helper = np.where((np.abs(normal[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    u = np.cross(helper, normal)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    basis = np.stack([u, np.cross(normal, u)], axis=1)  # (g, 2, 3), as plane_basis
    xy = np.einsum("gkc,gdc->gkd", p - p[:, :1], basis)
    ok[ok] = flat & _simple(xy)
    return ok


def _merged_faces(v: np.ndarray, tris: np.ndarray, facets):
    """The regions of ``facets`` (lists of triangle ids into ``tris``) that merge exactly (step
    4 of the module docstring), as vertex loops in facet order (their vertices one after the
    other, and their lengths), and per triangle whether it is in one of them."""
    in_face = np.zeros(len(tris), dtype=bool)
    none = np.zeros(0, dtype=np.int64)
    if len(facets) == 0:
        return none, none, in_face
    n = len(facets)
    ids = np.concatenate(facets)
    region = np.repeat(np.arange(n), [len(f) for f in facets])
    rows, ok = _region_boundaries(tris[ids], region, n, len(v))
    ok &= _planar_regions(v, tris[ids], region, n)
    rows = rows[ok[rows[:, 0]]]
    if len(rows) == 0:
        return none, none, in_face
    single, loop_vertices, loop_region = _loops(rows, n, len(v))
    ok &= single
    starts = np.searchsorted(loop_region, np.arange(n + 1))
    length = np.diff(starts)
    for k in np.unique(length[ok]):
        which = np.flatnonzero(ok & (length == k))
        ok[which] = _valid_polygons(v[loop_vertices[starts[which, None] + np.arange(k)]])
    in_face[ids[ok[region]]] = True
    return loop_vertices[ok[loop_region]], length[ok], in_face


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
    loops, lengths, in_face = _merged_faces(v, tris, facets)
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
    return {"scale": float(scale), "collapse_tol": COLLAPSE_TOL, "merge_tol": MERGE_TOL,
            "area_tol": AREA_TOL, "planarity_tol": PLANARITY_TOL,
            "merge_max_vertices": MERGE_MAX_VERTICES}


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

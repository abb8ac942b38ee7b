"""Coplanar triangles merged back into polygons (for :mod:`.meshes`): the planar regions of a
triangle mesh, their boundary loops, and the loops that are simple, valid polygons."""

from __future__ import annotations

import math

import numpy as np

from cellsight.geometry.polygon import AREA_TOL, PLANARITY_TOL

MERGE_TOL = 1e-7  # m, largest distance of a merged region's vertex from its fitted plane
MERGE_MAX_VERTICES = 4096  # longest boundary loop merged into one face
_PAIRS_PER_CHUNK = 2**18  # edge pairs tested at once by the simplicity test (memory bound)


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


def valid_polygons(p: np.ndarray) -> np.ndarray:
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


def merged_faces(v: np.ndarray, tris: np.ndarray, facets):
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
        ok[which] = valid_polygons(v[loop_vertices[starts[which, None] + np.arange(k)]])
    in_face[ids[ok[region]]] = True
    return loop_vertices[ok[loop_region]], length[ok], in_face

"""Numba kernel building a BSP tree of a polygon soup (paper, Section II).

Every node's partition plane is the plane of one of the soup's polygons. Polygons (or pieces of
polygons, *fragments*) are classified against it with that polygon's own plane thickness ``eps``
(local, see :mod:`.soup`; kept per node in ``node_eps`` for the visit): COPLANAR when
every vertex is within ``eps`` of the plane (stored in the node), FRONT / BACK when no vertex is
more than ``eps`` on the other side, SPANNING otherwise (split in two). A fragment's bounding
sphere decides most cases; its vertices are looked at only when the sphere meets the plane.
The splitter is the candidate plane with the lowest ``w * splits + (1 - w) * |front - back|``
(all the fragments' planes when there are at most ``n_candidates``, a seeded sample otherwise).

The build is iterative: an explicit stack of fragment lists kept in a pool used as a stack
allocator (a list is rewritten in place by its children), so depth is never limited by
recursion. Buffers grow by doubling. Nodes only keep the *original* polygon index of their
fragments: the visit tests the original polygon (see :mod:`._visit_kernel`); fragments are only
needed here, to place each piece of a polygon in the right subtree.

Tree layout: ``node_planes`` (M, 4) = (n, d) of the partition plane; ``node_links`` (M, 4) int64 =
(front child, back child, first surface, surface count), -1 for an empty child; the surfaces of
node ``m`` are ``surfaces[first:first + count]`` (original polygon indices). Node 0 is the root.

Performance note: numba passes an array to a call as a dozen scalars plus reference counting,
which costs more than classifying a fragment. Hence the loops over fragments are written inline
and the helpers called per fragment take scalars (or one array, on rare paths).
"""

from __future__ import annotations

import numpy as np
from numba import njit

COPLANAR, FRONT, BACK, SPANNING = 0, 1, 2, 3
_LCG_MUL = 6364136223846793005
_LCG_ADD = 1442695040888963407


@njit(cache=True)
def _grown(a, need):
    """A copy of ``a`` with room for ``max(need, 2 * len(a))`` rows."""
    b = np.empty((max(need, 2 * a.shape[0]),) + a.shape[1:], a.dtype)
    b[: a.shape[0]] = a
    return b


@njit(cache=True)
def _vertex_side(fv, first, k, nx, ny, nz, dd, eps) -> int:
    """FRONT / BACK / COPLANAR / SPANNING of the vertex loop ``fv[first:first + k]``."""
    pos = False
    neg = False
    for j in range(first, first + k):
        sj = nx * fv[j, 0] + ny * fv[j, 1] + nz * fv[j, 2] - dd
        pos = pos or sj > eps
        neg = neg or sj < -eps
    side = COPLANAR
    if pos:
        side = SPANNING if neg else FRONT
    elif neg:
        side = BACK
    return side


@njit(cache=True)
def _sphere_side(s, radius, eps) -> int:
    """Side of a bounding sphere whose centre is at signed distance ``s``; COPLANAR: undecided."""
    reach = radius + eps
    return FRONT if s > reach else (BACK if s < -reach else COPLANAR)


@njit(cache=True)
def _next_random(state):
    """One step of a 64-bit linear congruential generator (wrapping int64 arithmetic)."""
    return state * _LCG_MUL + _LCG_ADD


@njit(cache=True)
def _emit_side(fv, first, k, dist, eps, sign, out) -> int:
    """Write the part of a fragment loop on one side (``sign`` +1 front, -1 back) at ``out``.

    Sutherland-Hodgman walk: a vertex within ``eps`` of the plane goes to both sides; an edge
    with its ends strictly on opposite sides adds its crossing point to both, computed from the
    same expression for both sides (so the two pieces share it bit for bit). Non-convex loops
    give one loop per side, possibly with edges doubled along the cut; its vertices still span
    the piece, which is all the classification needs. Returns the vertex count.
    """
    n = 0
    for i in range(k):
        j = i + 1 if i + 1 < k else 0
        si, sj = dist[i], dist[j]
        if sign * si >= -eps:
            for a in range(3):
                fv[out + n, a] = fv[first + i, a]
            n += 1
        if (si > eps and sj < -eps) or (si < -eps and sj > eps):
            t = si / (si - sj)
            for a in range(3):
                fv[out + n, a] = fv[first + i, a] + t * (fv[first + j, a] - fv[first + i, a])
            n += 1
    return n


@njit(cache=True)
def _set_fragment(frag, poly, start, k, fv, fint, fsphere) -> None:
    """Record fragment ``frag`` = vertices ``fv[start:start + k]`` of polygon ``poly``."""
    fint[frag, 0], fint[frag, 1], fint[frag, 2] = start, k, poly
    cx = cy = cz = 0.0
    for j in range(start, start + k):
        cx += fv[j, 0]
        cy += fv[j, 1]
        cz += fv[j, 2]
    cx, cy, cz = cx / k, cy / k, cz / k
    r2 = 0.0
    for j in range(start, start + k):
        r2 = max(r2, (fv[j, 0] - cx) ** 2 + (fv[j, 1] - cy) ** 2 + (fv[j, 2] - cz) ** 2)
    fsphere[frag, 0], fsphere[frag, 1], fsphere[frag, 2] = cx, cy, cz
    fsphere[frag, 3] = np.sqrt(r2)


@njit(cache=True)
def _split(frag, plane, eps, fragments, n_verts, new, dist) -> int:
    """Split a SPANNING fragment into fragments ``new`` (front) and ``new + 1`` (back).

    ``fragments`` = ``(fv, fint, fsphere)`` (see :func:`build_tree`). Capacities must already
    hold ``4 * k`` more vertices and 2 more fragments, ``dist`` k values. Returns the new
    vertex count.
    """
    fv, fint, fsphere = fragments
    first, k, poly = fint[frag, 0], fint[frag, 1], fint[frag, 2]
    for i in range(k):
        j = first + i
        dist[i] = plane[0] * fv[j, 0] + plane[1] * fv[j, 1] + plane[2] * fv[j, 2] - plane[3]
    k_front = _emit_side(fv, first, k, dist, eps, 1.0, n_verts)
    _set_fragment(new, poly, n_verts, k_front, fv, fint, fsphere)
    n_verts += k_front
    k_back = _emit_side(fv, first, k, dist, eps, -1.0, n_verts)
    _set_fragment(new + 1, poly, n_verts, k_back, fv, fint, fsphere)
    return n_verts + k_back


@njit(cache=True)
def build_tree(vertices, offsets, planes, spheres, poly_eps, n_candidates, weight, seed):
    """Build the tree; returns ``(node_planes, node_eps, node_links, surfaces, n_splits, depth)``.

    ``poly_eps`` (P,): each polygon's plane thickness; ``node_eps`` (M,): that of the node's
    partition plane (its polygon's), the one used against that plane everywhere.

    ``depth`` counts nodes on the longest root-to-leaf path (0 for an empty soup).
    Fragment ``f``: ``fint[f]`` = (first vertex in ``fv``, vertex count, polygon),
    ``fsphere[f]`` = bounding sphere (centre, radius).
    """
    n_poly = offsets.shape[0] - 1
    n_verts = vertices.shape[0]
    fv = np.empty((2 * n_verts + 64, 3))
    fv[:n_verts] = vertices
    fint = np.empty((2 * n_poly + 16, 3), np.int64)
    fsphere = np.empty((2 * n_poly + 16, 4))
    for i in range(n_poly):
        fint[i, 0], fint[i, 1], fint[i, 2] = offsets[i], offsets[i + 1] - offsets[i], i
        for a in range(4):
            fsphere[i, a] = spheres[i, a]
    n_frags = n_poly
    pool = np.empty(2 * n_poly + 16, np.int64)
    pool[:n_poly] = np.arange(n_poly)
    front_tmp = np.empty(2 * n_poly + 16, np.int64)
    back_tmp = np.empty(2 * n_poly + 16, np.int64)
    dist = np.empty(64)
    node_planes = np.empty((n_poly + 16, 4))
    node_links = np.empty((n_poly + 16, 4), np.int64)
    node_eps = np.empty(n_poly + 16)
    surfaces = np.empty(n_poly + 16, np.int64)
    n_nodes = n_surf = n_splits = max_depth = 0
    stack = np.empty((64, 5), np.int64)  # (pool start, count, parent, side 0=front 1=back, depth)
    n_stack = 0
    if n_poly > 0:
        stack[0, 0], stack[0, 1], stack[0, 2], stack[0, 3], stack[0, 4] = 0, n_poly, -1, 0, 1
        n_stack = 1
    rng = np.int64(seed)
    while n_stack > 0:
        n_stack -= 1
        start, count, parent = stack[n_stack, 0], stack[n_stack, 1], stack[n_stack, 2]
        side, depth = stack[n_stack, 3], stack[n_stack, 4]
        # splitter: the candidate plane with the lowest score (written inline, see module doc)
        best = np.inf
        q = fint[pool[start], 2]
        for c in range(min(count, n_candidates)):
            pick = c
            if count > n_candidates:
                rng = _next_random(rng)
                pick = ((rng >> 33) & 0x7FFFFFFF) % count
            cand = fint[pool[start + pick], 2]
            nx, ny, nz, dd = planes[cand, 0], planes[cand, 1], planes[cand, 2], planes[cand, 3]
            eps = poly_eps[cand]
            n_front = n_back = n_split = 0
            for i in range(count):
                frag = pool[start + i]
                if fint[frag, 2] == cand:
                    continue
                s = nx * fsphere[frag, 0] + ny * fsphere[frag, 1] + nz * fsphere[frag, 2] - dd
                kind = _sphere_side(s, fsphere[frag, 3], eps)
                if kind == COPLANAR:
                    kind = _vertex_side(fv, fint[frag, 0], fint[frag, 1], nx, ny, nz, dd, eps)
                n_front += kind == FRONT
                n_back += kind == BACK
                n_split += kind == SPANNING
                if weight * n_split >= best:
                    break
            score = weight * n_split + (1.0 - weight) * abs(n_front - n_back)
            if score < best:
                best, q = score, cand
            if best == 0.0:
                break
        nx, ny, nz, dd = planes[q, 0], planes[q, 1], planes[q, 2], planes[q, 3]
        eps = poly_eps[q]
        node = n_nodes
        n_nodes += 1
        if n_nodes > node_planes.shape[0]:
            node_planes, node_links = _grown(node_planes, n_nodes), _grown(node_links, n_nodes)
            node_eps = _grown(node_eps, n_nodes)
        for a in range(4):
            node_planes[node, a] = planes[q, a]
        node_eps[node] = eps
        node_links[node, 0], node_links[node, 1], node_links[node, 2] = -1, -1, n_surf
        if parent >= 0:
            node_links[parent, side] = node
        max_depth = max(max_depth, depth)
        if 2 * count > front_tmp.shape[0]:
            front_tmp, back_tmp = _grown(front_tmp, 2 * count), _grown(back_tmp, 2 * count)
        n_front = n_back = 0
        for i in range(count):
            frag = pool[start + i]
            kind = COPLANAR
            if fint[frag, 2] != q:
                s = nx * fsphere[frag, 0] + ny * fsphere[frag, 1] + nz * fsphere[frag, 2] - dd
                kind = _sphere_side(s, fsphere[frag, 3], eps)
                if kind == COPLANAR:
                    kind = _vertex_side(fv, fint[frag, 0], fint[frag, 1], nx, ny, nz, dd, eps)
            if kind == COPLANAR:
                if n_surf >= surfaces.shape[0]:
                    surfaces = _grown(surfaces, n_surf + 1)
                surfaces[n_surf] = fint[frag, 2]
                n_surf += 1
            elif kind == FRONT:
                front_tmp[n_front] = frag
                n_front += 1
            elif kind == BACK:
                back_tmp[n_back] = frag
                n_back += 1
            else:
                k = fint[frag, 1]
                if n_verts + 4 * k > fv.shape[0]:
                    fv = _grown(fv, n_verts + 4 * k)
                if n_frags + 2 > fint.shape[0]:
                    fint, fsphere = _grown(fint, n_frags + 2), _grown(fsphere, n_frags + 2)
                if k > dist.shape[0]:
                    dist = _grown(dist, k)
                n_verts = _split(frag, node_planes[node], eps, (fv, fint, fsphere), n_verts,
                                 n_frags, dist)
                front_tmp[n_front] = n_frags
                back_tmp[n_back] = n_frags + 1
                n_front += 1
                n_back += 1
                n_frags += 2
                n_splits += 1
        node_links[node, 3] = n_surf - node_links[node, 2]
        if start + n_front + n_back > pool.shape[0]:
            pool = _grown(pool, start + n_front + n_back)
        for i in range(n_back):
            pool[start + i] = back_tmp[i]
        for i in range(n_front):
            pool[start + n_back + i] = front_tmp[i]
        if n_stack + 2 > stack.shape[0]:
            stack = _grown(stack, n_stack + 2)
        if n_back > 0:
            stack[n_stack, 0], stack[n_stack, 1], stack[n_stack, 2] = start, n_back, node
            stack[n_stack, 3], stack[n_stack, 4] = 1, depth + 1
            n_stack += 1
        if n_front > 0:
            stack[n_stack, 0], stack[n_stack, 1], stack[n_stack, 2] = start + n_back, n_front, node
            stack[n_stack, 3], stack[n_stack, 4] = 0, depth + 1
            n_stack += 1
    return (node_planes[:n_nodes].copy(), node_eps[:n_nodes].copy(), node_links[:n_nodes].copy(),
            surfaces[:n_surf].copy(), n_splits, max_depth)

"""Numba kernel of the paper's ``not_occluded`` visit (Section III-B) for many points at once.

Every plane comes with its own thickness ``eps`` (its polygon's, local: see :mod:`.soup`):
:attr:`TreeArrays.eps` for a node's partition plane, that of
:class:`~._crossing.PolygonArrays` for a surface's plane.

Points are first located in the tree: pushed down FRONT (n.x - d > eps) or BACK (< -eps); a point
within ``eps`` of a node's plane stays at that node, and a point reaching an empty child stays at
that leaf position. Each node thus has three *slots*: ``3m`` (on its plane), ``3m + 1`` (its empty
front child), ``3m + 2`` (its empty back child).

The tree is then visited back to front from the viewpoint with an explicit stack. At node ``m``,
with ``s`` the viewpoint's signed distance to its plane and ``eps`` that plane's thickness:

- ``s > eps`` (IN_FRONT_OF): back subtree, ``process_surfaces(m)``, slot ``3m``, front subtree;
- ``s < -eps`` (IN_BACK_OF): front subtree, ``process_surfaces(m)``, slot ``3m``, back subtree;
- otherwise (ON_THE_PLANE): slot ``3m``, front subtree, back subtree; the node's surfaces are
  seen edge-on and hide nothing, and the points on the plane join before both subtrees.

Visiting a slot adds its points to the active set (visible). ``process_surfaces`` first skips a
surface whose box misses the box of the viewpoint and the active points (cheap bounding test)
or that is seen edge-on, then tests each active point against the surface ``q``, on the
original polygon, by the crossing test of :mod:`._crossing`: ``q`` hides the point ``p`` when
the segment from the viewpoint crosses ``q`` strictly before ``p`` (within the thicknesses and
the caller's surface tolerance ``tol`` described there).

A hidden point stays in the active set so that the nearest occluder (smallest ``t``, the surface
the camera actually sees along that line of sight) is kept; a polygon only needs testing when it
would cross before the best crossing found so far.

Why testing the original polygon (not the fragment) is exact: a reported crossing is a real one,
and for any real crossing of ``q`` the fragment of ``q`` containing it lies between the point and
the viewpoint in the back-to-front order, so it is visited after the point was added.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from cellsight.occlusion._crossing import (
    NO_CROSSING,
    crossing,
    on_polygon,
    plane_distance,
    polygon,
)

_VISIT, _SURFACES, _SLOT = 0, 1, 2
#: ``bad`` answers of :func:`visit_tree`: all finite, or the viewpoint is not (else: a point).
NO_BAD_INPUT, BAD_VIEWPOINT = -1, -2


class TreeArrays(NamedTuple):
    """A BSP tree's flat arrays as :func:`visit_tree` reads them (one argument; see
    :class:`~cellsight.occlusion.bsp.BSPTree`): per node its partition plane ``planes`` (M, 4),
    thickness ``eps`` (M,) and ``links`` (M, 4) = (front child, back child, first surface,
    surface count); ``surfaces``: the polygon indices stored in the nodes; ``depth``: nodes on
    the longest root-leaf path."""

    planes: np.ndarray
    eps: np.ndarray
    links: np.ndarray
    surfaces: np.ndarray
    depth: int


@njit(cache=True)
def _first_non_finite(points, view) -> int:
    """First point with a non-finite coordinate, ``BAD_VIEWPOINT``, or ``NO_BAD_INPUT``."""
    bad = NO_BAD_INPUT
    if not (np.isfinite(view[0]) and np.isfinite(view[1]) and np.isfinite(view[2])):
        bad = BAD_VIEWPOINT
    for p in range(points.shape[0]):
        if bad == NO_BAD_INPUT and not (
            np.isfinite(points[p, 0]) and np.isfinite(points[p, 1]) and np.isfinite(points[p, 2])
        ):
            bad = p
    return bad


@njit(cache=True)
def _locate(points, tree):
    """Slot of every point, as linked lists: ``head[slot]`` and ``following[point]``."""
    node_planes, node_eps, node_links = tree.planes, tree.eps, tree.links
    n_nodes = node_planes.shape[0]
    head = np.full(3 * n_nodes, -1, np.int64)
    following = np.empty(points.shape[0], np.int64)
    for p in range(points.shape[0]):
        node = 0
        while True:
            s = (node_planes[node, 0] * points[p, 0] + node_planes[node, 1] * points[p, 1]
                 + node_planes[node, 2] * points[p, 2] - node_planes[node, 3])
            eps = node_eps[node]
            if s > eps:
                child, slot = node_links[node, 0], 3 * node + 1
            elif s < -eps:
                child, slot = node_links[node, 1], 3 * node + 2
            else:
                child, slot = -1, 3 * node
            if child < 0:
                break
            node = child
        following[p] = head[slot]
        head[slot] = p
    return head, following


@njit(cache=True)
def visit_tree(polys, tree, points, view, tol, relevant):
    """Visible flags (N,), nearest occluder indices (N,) int32 (-1 if visible) and ``bad`` of
    ``points`` (N, 3) seen from ``view`` (3,) among the polygons ``polys``
    (:class:`~._crossing.PolygonArrays`) partitioned by ``tree`` (:class:`TreeArrays`).

    ``bad`` is ``NO_BAD_INPUT``, ``BAD_VIEWPOINT`` or the first point with a non-finite
    coordinate (then nothing is computed). ``tol``: the surface tolerance (:mod:`._crossing`).
    ``relevant`` (P,) bool: the polygons that may hide a point (the caller's exact cull, e.g.
    per camera); the others are skipped.

    The per-node and per-(surface, point) work passes no array to a function (the crossing
    test's per-pair stage is inlined and takes scalars): numba updates the reference counts of
    every array a function receives, which would cost more than the geometry itself. Only the
    rare point-in-polygon stage is a call (:mod:`._crossing`).
    """
    node_planes, node_eps, node_links, surfaces = tree.planes, tree.eps, tree.links, tree.surfaces
    n_points = points.shape[0]
    visible = np.zeros(n_points, np.bool_)
    occluder = np.full(n_points, -1, np.int32)
    bad = _first_non_finite(points, view)
    if bad != NO_BAD_INPUT or node_planes.shape[0] == 0:
        visible[:] = bad == NO_BAD_INPUT
        return visible, occluder, bad
    best_t = np.full(n_points, np.inf)
    head, following = _locate(points, tree)
    active = np.empty(n_points, np.int64)
    n_active = 0
    stack = np.empty(3 * tree.depth + 4, np.int64)  # codes (index << 2) | action
    stack[0] = _VISIT
    n_stack = 1
    vx, vy, vz = view[0], view[1], view[2]
    view3 = (vx, vy, vz)
    reach = np.empty(6)  # box of the viewpoint and the active points
    for a in range(3):
        reach[a], reach[3 + a] = view[a], view[a]
    while n_stack > 0:
        n_stack -= 1
        action, index = stack[n_stack] & 3, stack[n_stack] >> 2
        if action == _VISIT:
            s = node_planes[index, 0] * vx + node_planes[index, 1] * vy \
                + node_planes[index, 2] * vz - node_planes[index, 3]
            front, back = node_links[index, 0], node_links[index, 1]
            front_code = (front << 2) | _VISIT if front >= 0 else ((3 * index + 1) << 2) | _SLOT
            back_code = (back << 2) | _VISIT if back >= 0 else ((3 * index + 2) << 2) | _SLOT
            if abs(s) > node_eps[index]:  # IN_FRONT_OF / IN_BACK_OF: far, surfaces, own, near
                near, far = (front_code, back_code) if s > 0.0 else (back_code, front_code)
                stack[n_stack] = near
                stack[n_stack + 1] = ((3 * index) << 2) | _SLOT
                stack[n_stack + 2] = (index << 2) | _SURFACES
                stack[n_stack + 3] = far
                n_stack += 4
            else:  # ON_THE_PLANE: own points, front, back; the surfaces are seen edge-on
                stack[n_stack] = back_code
                stack[n_stack + 1] = front_code
                stack[n_stack + 2] = ((3 * index) << 2) | _SLOT
                n_stack += 3
        elif action == _SLOT:  # the visit passes these points' place: they join, visible
            p = head[index]
            while p >= 0:
                active[n_active] = p
                n_active += 1
                visible[p] = True
                for a in range(3):
                    reach[a] = min(reach[a], points[p, a])
                    reach[3 + a] = max(reach[3 + a], points[p, a])
                p = following[p]
        else:  # process_surfaces(index)
            for k in range(node_links[index, 2], node_links[index, 2] + node_links[index, 3]):
                q = surfaces[k]
                if not relevant[q]:
                    continue
                poly = polygon(polys, q)
                eps = poly.eps
                if (poly.xmin - eps > reach[3] or poly.xmax + eps < reach[0]
                        or poly.ymin - eps > reach[4] or poly.ymax + eps < reach[1]
                        or poly.zmin - eps > reach[5] or poly.zmax + eps < reach[2]):
                    continue  # the polygon's box misses the box of every active segment
                sv = plane_distance(poly, vx, vy, vz)
                if abs(sv) <= eps:  # seen edge-on: hides nothing
                    continue
                for i in range(n_active):
                    p = active[i]
                    point = (points[p, 0], points[p, 1], points[p, 2])
                    t = crossing(poly, sv, view3, point, tol, best_t[p])
                    if t != NO_CROSSING and on_polygon(polys, q, t, view3, point):
                        best_t[p] = t
                        occluder[p] = q
                        visible[p] = False
    return visible, occluder, bad

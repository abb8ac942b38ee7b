"""Numba kernel of the paper's ``not_occluded`` visit (Section III-B) for many points at once.

Every plane comes with its own thickness ``eps`` (its polygon's, local: see :mod:`.soup`):
``node_eps`` for a node's partition plane, ``poly_eps`` for a surface's plane.

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
surface whose box misses the box of the viewpoint and the active points (cheap bounding test),
then tests each active point against the surface ``q``, on the original polygon: ``q`` hides the
point ``p`` when the segment from the viewpoint ``v`` crosses ``q`` strictly before ``p``. With
``sv``/``sp`` the signed distances of ``v``/``p`` to ``q``'s plane and ``eps`` its thickness:
``|sv| > eps`` (else edge-on), ``sv`` and ``sp`` of opposite signs with ``|sp| > max(eps, tol)``
(a point on the polygon, e.g. a vertex of its own face, is not hidden by it; ``tol``, the
caller's surface tolerance, extends this to points resting on a surface, such as a part's
bottom corners on its support), i.e. the crossing parameter ``t = sv / (sv - sp)`` satisfies
``t < 1 - eps / (|sv| + |sp|)``; then the crossing ``v + t (p - v)`` must fall in ``q``'s box
(grown by ``eps``) and inside ``q`` (even-odd rule in the coordinate plane most parallel to
``q``: any simple polygon, convex or not).

A hidden point stays in the active set so that the nearest occluder (smallest ``t``, the surface
the camera actually sees along that line of sight) is kept; a polygon only needs testing when it
would cross before the best crossing found so far.

Why testing the original polygon (not the fragment) is exact: a reported crossing is a real one,
and for any real crossing of ``q`` the fragment of ``q`` containing it lies between the point and
the viewpoint in the back-to-front order, so it is visited after the point was added.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cellsight.occlusion._soup_kernels import drop_axis

_VISIT, _SURFACES, _SLOT = 0, 1, 2
#: ``bad`` answers of :func:`visit_tree`: all finite, or the viewpoint is not (else: a point).
NO_BAD_INPUT, BAD_VIEWPOINT = -1, -2


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
def _locate(points, node_planes, node_eps, node_links):
    """Slot of every point, as linked lists: ``head[slot]`` and ``following[point]``."""
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
def _inside(x0, x1, q, a0, a1, vertices, offsets) -> bool:
    """Even-odd test of the 2D point (x0, x1) against polygon ``q`` projected on axes a0, a1."""
    inside = False
    start, stop = offsets[q], offsets[q + 1]
    j = stop - 1
    for i in range(start, stop):
        yi, yj = vertices[i, a1], vertices[j, a1]
        if (yi > x1) != (yj > x1):
            xi, xj = vertices[i, a0], vertices[j, a0]
            if x0 < xi + (xj - xi) * (x1 - yi) / (yj - yi):
                inside = not inside
        j = i
    return inside


@njit(cache=True)
def visit_tree(vertices, offsets, planes, poly_eps, boxes, node_planes, node_eps, node_links,
               surfaces, depth, tol, points, view, relevant):
    """Visible flags (N,), nearest occluder indices (N,) int32 (-1 if visible) and ``bad``.

    ``bad`` is ``NO_BAD_INPUT``, ``BAD_VIEWPOINT`` or the first point with a non-finite
    coordinate (then nothing is computed). ``relevant`` (P,) bool: the polygons that may hide a
    point (the caller's exact cull, e.g. per camera); the others are skipped.

    The per-node and per-(surface, point) work is written inline: numba keeps reference-count
    updates of every array passed to a call that LLVM does not inline, which would cost more
    than the geometry itself. Only the (rare) point-in-polygon test is a call.
    """
    n_points = points.shape[0]
    visible = np.zeros(n_points, np.bool_)
    occluder = np.full(n_points, -1, np.int32)
    bad = _first_non_finite(points, view)
    if bad != NO_BAD_INPUT or node_planes.shape[0] == 0:
        visible[:] = bad == NO_BAD_INPUT
        return visible, occluder, bad
    best_t = np.full(n_points, np.inf)
    head, following = _locate(points, node_planes, node_eps, node_links)
    active = np.empty(n_points, np.int64)
    n_active = 0
    stack = np.empty(3 * depth + 4, np.int64)  # codes (index << 2) | action
    stack[0] = _VISIT
    n_stack = 1
    vx, vy, vz = view[0], view[1], view[2]
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
                eps = poly_eps[q]
                if (boxes[q, 0] - eps > reach[3] or boxes[q, 3] + eps < reach[0]
                        or boxes[q, 1] - eps > reach[4] or boxes[q, 4] + eps < reach[1]
                        or boxes[q, 2] - eps > reach[5] or boxes[q, 5] + eps < reach[2]):
                    continue  # the polygon's box misses the box of every active segment
                nx, ny, nz, dq = planes[q, 0], planes[q, 1], planes[q, 2], planes[q, 3]
                sv = nx * vx + ny * vy + nz * vz - dq
                if abs(sv) <= eps:  # seen edge-on: hides nothing
                    continue
                a0, a1 = drop_axis(nx, ny, nz)
                on_plane = max(eps, tol)
                for i in range(n_active):
                    p = active[i]
                    px, py, pz = points[p, 0], points[p, 1], points[p, 2]
                    sp = nx * px + ny * py + nz * pz - dq
                    if (sv > 0.0 and sp >= -on_plane) or (sv < 0.0 and sp <= on_plane):
                        continue  # same side as the viewpoint, or on the plane
                    t = sv / (sv - sp)
                    if t >= best_t[p]:
                        continue  # a nearer occluder is known
                    x0, x1, x2 = vx + t * (px - vx), vy + t * (py - vy), vz + t * (pz - vz)
                    if (x0 < boxes[q, 0] - eps or x0 > boxes[q, 3] + eps
                            or x1 < boxes[q, 1] - eps or x1 > boxes[q, 4] + eps
                            or x2 < boxes[q, 2] - eps or x2 > boxes[q, 5] + eps):
                        continue
                    u = x0 if a0 == 0 else (x1 if a0 == 1 else x2)
                    w = x0 if a1 == 0 else (x1 if a1 == 1 else x2)
                    if _inside(u, w, q, a0, a1, vertices, offsets):
                        best_t[p] = t
                        occluder[p] = q
                        visible[p] = False
    return visible, occluder, bad

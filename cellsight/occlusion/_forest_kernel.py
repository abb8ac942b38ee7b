"""Numba kernel of the static per-object mode of the cell-level predictor: segments from a
camera's optical centre to query points, tested against every object's bounding-volume
hierarchy in the object's own frame (see :mod:`.forest`).

Lengths in metres. The crossing test of a segment ``v -> p`` and polygon ``q`` is the one of
:mod:`._crossing` (the BSP visit's and the direct test's), done in ``q``'s object frame. The
nearest crossing (smallest ``t``) names the occluder, as in the visit; coincident surfaces
crossed at the same ``t`` (within ``TIE``) name the one listed first.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import numpy as np
from numba import njit, prange
from numba.core.errors import NumbaWarning

from cellsight.occlusion._crossing import (
    NO_CROSSING,
    crossing,
    on_polygon,
    plane_distance,
    polygon,
)

# numba tries its TBB threading layer first and warns when the installed TBB is too old, then
# uses another layer (OpenMP or its own): nothing for a user to act on.
warnings.filterwarnings("ignore", message="The TBB threading layer requires TBB",
                        category=NumbaWarning)

SLACK = 1e-9  # m: rounding allowance of the box tests (moving a point to a frame: ~1e-15 m)
#: Crossings this close in ``t`` (a fraction of the segment) are a tie, e.g. a part's bottom on
#: the table's top: the lower polygon index wins, as in the oracle (objects in cell order).
TIE = 1e-12
STACK = 128  # deepest traversal stack (a hierarchy is at most ~64 levels deep)


class ForestArrays(NamedTuple):
    """The per-object hierarchies as :func:`forest_occluders` reads them (one argument; built
    by :meth:`~cellsight.occlusion.forest.ObjectForest.arrays`). Object k's hierarchy starts at
    node ``object_root[k]`` (-1: none) and lies in the ball ``object_sphere[k]`` (object-frame
    centre, radius, m); a node is ``node_box`` (min xyz, max xyz, its polygons' boxes grown by
    their eps, m) and ``node_links`` = (first child, second child, first polygon, polygon
    count): a leaf has count > 0 and lists ``node_polys[first:first + count]``.
    ``cull_backs[k]``: object k is a closed solid whose back faces are skipped when the camera
    is outside its root box grown by ``contain_margin`` (m): a line of sight entering it
    crosses a front face first."""

    node_box: np.ndarray
    node_links: np.ndarray
    node_polys: np.ndarray
    object_root: np.ndarray
    object_sphere: np.ndarray
    cull_backs: np.ndarray
    contain_margin: float


@njit(cache=True)
def _slab(box, v0, v1, v2, d0, d1, d2, tmax):  # pragma: no cover - jit
    """Whether the segment ``v + t d``, ``0 <= t <= tmax``, meets ``box`` (min xyz, max xyz)
    grown by ``SLACK``."""
    lo, hi = 0.0, tmax
    for a in range(3):
        o = v0 if a == 0 else (v1 if a == 1 else v2)
        d = d0 if a == 0 else (d1 if a == 1 else d2)
        bmin, bmax = box[a] - SLACK, box[3 + a] + SLACK
        if d == 0.0:
            if o < bmin or o > bmax:
                return False
            continue
        t1, t2 = (bmin - o) / d, (bmax - o) / d
        if t1 > t2:
            t1, t2 = t2, t1
        lo, hi = max(lo, t1), min(hi, t2)
        if lo > hi:
            return False
    return True


@njit(cache=True)
def _cone(views, points, c, a, b):  # pragma: no cover - jit
    """The cone from ``views[c]`` holding ``points[a:b]``: unit axis (3,), cosine and sine of
    its half-angle, and its length (the farthest point's distance)."""
    axis = np.zeros(3)
    length = 0.0
    for i in range(a, b):
        d0, d1 = points[i, 0] - views[c, 0], points[i, 1] - views[c, 1]
        d2 = points[i, 2] - views[c, 2]
        norm = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        length = max(length, norm)
        if norm > 0.0:
            axis[0] += d0 / norm
            axis[1] += d1 / norm
            axis[2] += d2 / norm
    norm = np.sqrt(axis[0] ** 2 + axis[1] ** 2 + axis[2] ** 2)
    if norm < 1e-9:  # directions all round: the cone is every direction
        return axis, -1.0, 0.0, length
    axis /= norm
    cos_half = 1.0
    for i in range(a, b):
        d0, d1 = points[i, 0] - views[c, 0], points[i, 1] - views[c, 1]
        d2 = points[i, 2] - views[c, 2]
        norm = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if norm > 0.0:
            cos_half = min(cos_half, (d0 * axis[0] + d1 * axis[1] + d2 * axis[2]) / norm)
    cos_half = max(-1.0, cos_half - 1e-9)
    return axis, cos_half, np.sqrt(max(0.0, 1.0 - cos_half * cos_half)), length


@njit(cache=True)
def _sphere_misses_cone(x, y, z, r, axis, cos_half, sin_half, length):  # pragma: no cover - jit
    """Whether the sphere of centre (x, y, z) (relative to the cone's apex) and radius ``r``
    lies wholly outside the cone (apex, unit ``axis``, half-angle cosine/sine, ``length``)."""
    dist = np.sqrt(x * x + y * y + z * z)
    if dist <= r or cos_half <= -1.0:
        return dist - r > length  # apex inside the sphere, or an all-round cone: length only
    if dist - r > length:
        return True
    along = x * axis[0] + y * axis[1] + z * axis[2]
    across = np.sqrt(max(0.0, dist * dist - along * along))
    # angle of the centre off the axis minus the sphere's angular radius beyond the half-angle:
    # cos(phi - half) < sqrt(1 - (r/dist)^2) <=> the sphere misses the cone's sides
    cos_off = along / dist
    sin_off = across / dist
    cos_gap = cos_off * cos_half + sin_off * sin_half  # cos(phi - half), phi the off-axis angle
    if cos_off >= cos_half:
        return False  # the centre is inside the cone
    return cos_gap < np.sqrt(max(0.0, 1.0 - (r / dist) ** 2))


@njit(cache=True, parallel=True)
def forest_occluders(polys, forest, poses, views, starts, points, tol):  # pragma: no cover - jit
    """Nearest occluding polygon (Q,) int32 (-1: visible) of every query point.

    Polygons ``polys`` (:class:`~._crossing.PolygonArrays`) are in their object's frame and
    ``forest`` (:class:`ForestArrays`) holds each object's hierarchy of them. ``poses`` (K, 4,
    4): object -> base frame. Camera c at ``views[c]`` (base frame) asks for
    ``points[starts[c]:starts[c + 1]]`` (base frame); ``tol`` (m): the surface tolerance.

    The cameras in parallel (:func:`forest_occluders_serial`: one after the other, the same
    answers), each by :func:`_camera_occluders`.
    """
    occluder = np.full(points.shape[0], -1, np.int32)
    best = np.ones(points.shape[0])
    for c in prange(views.shape[0]):
        _camera_occluders(c, polys, forest, poses, views, starts, points, tol, occluder, best)
    return occluder


@njit(cache=True)
def forest_occluders_serial(polys, forest, poses, views, starts,
                            points, tol):  # pragma: no cover - jit
    """:func:`forest_occluders`, one camera after the other (no thread started)."""
    occluder = np.full(points.shape[0], -1, np.int32)
    best = np.ones(points.shape[0])
    for c in range(views.shape[0]):
        _camera_occluders(c, polys, forest, poses, views, starts, points, tol, occluder, best)
    return occluder


@njit(cache=True)
def _camera_occluders(c, polys, forest, poses, views, starts, points, tol, occluder,
                      best):  # pragma: no cover - jit
    """Camera ``c``'s points of :func:`forest_occluders`: their ``occluder`` and crossing
    ``best`` (fraction of the segment) written in place. An object whose ball misses the cone
    from the camera through its points is skipped; per point, an object whose ball misses the
    segment is skipped; else the segment, moved to the object's frame, descends the
    hierarchy."""
    node_box, node_links, node_polys = forest.node_box, forest.node_links, forest.node_polys
    object_root, object_sphere = forest.object_root, forest.object_sphere
    cull_backs, contain_margin = forest.cull_backs, forest.contain_margin
    a, b = starts[c], starts[c + 1]
    if b > a:
        axis, cos_half, sin_half, length = _cone(views, points, c, a, b)
        stack = np.empty(STACK, np.int64)
        for k in range(object_root.shape[0]):
            root = object_root[k]
            if root < 0:
                continue
            T = poses[k]
            sx, sy, sz, r = object_sphere[k, 0], object_sphere[k, 1], object_sphere[k, 2], \
                object_sphere[k, 3]
            cx = T[0, 0] * sx + T[0, 1] * sy + T[0, 2] * sz + T[0, 3] - views[c, 0]
            cy = T[1, 0] * sx + T[1, 1] * sy + T[1, 2] * sz + T[1, 3] - views[c, 1]
            cz = T[2, 0] * sx + T[2, 1] * sy + T[2, 2] * sz + T[2, 3] - views[c, 2]
            if _sphere_misses_cone(cx, cy, cz, r, axis, cos_half, sin_half, length):
                continue
            wx, wy, wz = views[c, 0] - T[0, 3], views[c, 1] - T[1, 3], views[c, 2] - T[2, 3]
            v0 = T[0, 0] * wx + T[1, 0] * wy + T[2, 0] * wz
            v1 = T[0, 1] * wx + T[1, 1] * wy + T[2, 1] * wz
            v2 = T[0, 2] * wx + T[1, 2] * wy + T[2, 2] * wz
            backs = not cull_backs[k] or (
                node_box[root, 0] - contain_margin <= v0 <= node_box[root, 3] + contain_margin
                and node_box[root, 1] - contain_margin <= v1 <= node_box[root, 4] + contain_margin
                and node_box[root, 2] - contain_margin <= v2 <= node_box[root, 5] + contain_margin)
            for i in range(a, b):
                e0, e1, e2 = points[i, 0] - views[c, 0], points[i, 1] - views[c, 1], \
                    points[i, 2] - views[c, 2]
                ee = e0 * e0 + e1 * e1 + e2 * e2
                u = 0.0 if ee == 0.0 else min(1.0, max(0.0, (cx * e0 + cy * e1 + cz * e2) / ee))
                if (cx - u * e0) ** 2 + (cy - u * e1) ** 2 + (cz - u * e2) ** 2 > r * r:
                    continue  # the segment passes outside the object's ball
                wx, wy, wz = points[i, 0] - T[0, 3], points[i, 1] - T[1, 3], points[i, 2] - T[2, 3]
                p0 = T[0, 0] * wx + T[1, 0] * wy + T[2, 0] * wz
                p1 = T[0, 1] * wx + T[1, 1] * wy + T[2, 1] * wz
                p2 = T[0, 2] * wx + T[1, 2] * wy + T[2, 2] * wz
                d0, d1, d2 = p0 - v0, p1 - v1, p2 - v2
                view, point = (v0, v1, v2), (p0, p1, p2)
                # a crossing counts when nearer than the best, or as near (within TIE) and of a
                # lower index: before ``later`` for a polygon listed after the best, else at most
                # best + TIE (before the next float)
                later = best[i] - TIE
                sooner = np.nextafter(best[i] + TIE, np.inf)
                stack[0] = root
                n_stack = 1
                while n_stack > 0:
                    n_stack -= 1
                    node = stack[n_stack]
                    if not _slab(node_box[node], v0, v1, v2, d0, d1, d2, best[i] + TIE):
                        continue
                    count = node_links[node, 3]
                    if count == 0:
                        stack[n_stack] = node_links[node, 1]
                        stack[n_stack + 1] = node_links[node, 0]
                        n_stack += 2
                        continue
                    first = node_links[node, 2]
                    for j in range(first, first + count):
                        q = node_polys[j]
                        poly = polygon(polys, q)
                        sv = plane_distance(poly, v0, v1, v2)
                        if sv <= poly.eps and (not backs or sv >= -poly.eps):
                            continue  # edge-on, or a closed solid's back face seen from outside
                        t = crossing(poly, sv, view, point, tol,
                                     later if q >= occluder[i] >= 0 else sooner)
                        if t != NO_CROSSING and on_polygon(polys, q, t, view, point):
                            best[i] = t
                            occluder[i] = q
                            later = best[i] - TIE
                            sooner = np.nextafter(best[i] + TIE, np.inf)

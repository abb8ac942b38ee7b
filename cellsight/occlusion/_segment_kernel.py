"""Numba kernels of the direct path of :func:`~cellsight.occlusion.bsp.visible_mask`: an exact
cull of the polygons that cannot cross any viewpoint->point segment, and a brute-force
segment-vs-polygon test of every (point, kept polygon) pair.

Lengths are in the soup's unit (metres in cellsight). The per-pair test is the BSP visit's
(:mod:`._visit_kernel`), with the same per-polygon plane thickness ``eps`` (see :mod:`.soup`):
with ``sv``/``sp`` the signed distances of the viewpoint ``v``/point ``p`` to the plane of
polygon ``q``, ``q`` hides ``p`` iff ``|sv| > eps`` (else seen edge-on, hides nothing), ``sv``
and ``sp`` have opposite signs with ``|sp| > max(eps, tol)`` (a point within ``eps`` of the
plane is not hidden by it), and the crossing ``v + t (p - v)``, ``t = sv / (sv - sp)``, lies in
``q``'s box grown by ``eps`` and inside ``q`` (even-odd rule in the coordinate plane most
parallel to ``q``, boundary rounding as in the visit). The BSP visit reports a point hidden iff
one of its polygons passes this same test (it only orders the tests), so the two paths agree
except where the tree's point location within ``eps`` of another plane decides (the oracle's
ambiguous cases).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cellsight.occlusion._soup_kernels import drop_axis
from cellsight.occlusion._visit_kernel import _inside


@njit(cache=True)
def cull_segments(planes, poly_eps, boxes, spheres, points, view):  # pragma: no cover - jit
    """Indices (K,) int64 of the polygons that may cross a segment ``view`` -> ``points[i]``.

    Dropped (exactly: such a polygon hides no point under the module's test): a polygon whose
    box, grown by its ``eps``, misses the box of the viewpoint and all points (every crossing
    lies on a segment, hence in that box); a polygon whose bounding sphere lies entirely
    farther from the viewpoint than the farthest point plus ``eps``; a polygon whose plane
    passes within ``eps`` of the viewpoint (seen edge-on).
    """
    reach = np.empty(6)
    for a in range(3):
        reach[a], reach[3 + a] = view[a], view[a]
    far2 = 0.0
    for p in range(points.shape[0]):
        d2 = 0.0
        for a in range(3):
            reach[a] = min(reach[a], points[p, a])
            reach[3 + a] = max(reach[3 + a], points[p, a])
            d2 += (points[p, a] - view[a]) ** 2
        far2 = max(far2, d2)
    far = np.sqrt(far2)
    kept = np.empty(planes.shape[0], np.int64)
    n_kept = 0
    for q in range(planes.shape[0]):
        eps = poly_eps[q]
        if (boxes[q, 0] - eps > reach[3] or boxes[q, 3] + eps < reach[0]
                or boxes[q, 1] - eps > reach[4] or boxes[q, 4] + eps < reach[1]
                or boxes[q, 2] - eps > reach[5] or boxes[q, 5] + eps < reach[2]):
            continue
        dc = np.sqrt((spheres[q, 0] - view[0]) ** 2 + (spheres[q, 1] - view[1]) ** 2
                     + (spheres[q, 2] - view[2]) ** 2)
        if dc - spheres[q, 3] > far + eps:
            continue
        sv = planes[q, 0] * view[0] + planes[q, 1] * view[1] + planes[q, 2] * view[2] - planes[q, 3]
        if abs(sv) <= eps:
            continue
        kept[n_kept] = q
        n_kept += 1
    return kept[:n_kept]


@njit(cache=True)
def segment_visible(vertices, offsets, planes, poly_eps, boxes, kept, tol, points,
                    view):  # pragma: no cover - jit
    """Visible flags (N,) of ``points`` (N, 3) from ``view`` (3,) against the polygons ``kept``.

    A point is hidden iff some kept polygon passes the module's crossing test (``tol``, m: the
    caller's surface tolerance, at least ``eps`` is used). All input must be finite. Per pair
    the work is written inline (see :func:`._visit_kernel.visit_tree` on call overheads); a
    point is no longer tested once hidden. Cost O(N * K).
    """
    n_points = points.shape[0]
    hidden = np.zeros(n_points, np.bool_)
    vx, vy, vz = view[0], view[1], view[2]
    for k in range(kept.shape[0]):
        q = kept[k]
        eps = poly_eps[q]
        nx, ny, nz, dq = planes[q, 0], planes[q, 1], planes[q, 2], planes[q, 3]
        sv = nx * vx + ny * vy + nz * vz - dq
        if abs(sv) <= eps:
            continue
        a0, a1 = drop_axis(nx, ny, nz)
        on_plane = max(eps, tol)
        for p in range(n_points):
            if hidden[p]:
                continue
            px, py, pz = points[p, 0], points[p, 1], points[p, 2]
            sp = nx * px + ny * py + nz * pz - dq
            if (sv > 0.0 and sp >= -on_plane) or (sv < 0.0 and sp <= on_plane):
                continue
            t = sv / (sv - sp)
            x0, x1, x2 = vx + t * (px - vx), vy + t * (py - vy), vz + t * (pz - vz)
            if (x0 < boxes[q, 0] - eps or x0 > boxes[q, 3] + eps
                    or x1 < boxes[q, 1] - eps or x1 > boxes[q, 4] + eps
                    or x2 < boxes[q, 2] - eps or x2 > boxes[q, 5] + eps):
                continue
            u = x0 if a0 == 0 else (x1 if a0 == 1 else x2)
            w = x0 if a1 == 0 else (x1 if a1 == 1 else x2)
            if _inside(u, w, q, a0, a1, vertices, offsets):
                hidden[p] = True
    return ~hidden

"""Numba kernels of the direct path of :func:`~cellsight.occlusion.bsp.visible_mask`: an exact
cull of the polygons that cannot cross any viewpoint->point segment, and a brute-force
segment-vs-polygon test of every (point, kept polygon) pair.

Lengths are in the soup's unit (metres in cellsight). The per-pair test is the crossing test of
:mod:`._crossing`, the BSP visit's, with the same per-polygon plane thickness ``eps`` (see
:mod:`.soup`). The BSP visit reports a point hidden iff one of its polygons passes this same
test (it only orders the tests), so the two paths agree except where the tree's point location
within ``eps`` of another plane decides (the oracle's ambiguous cases).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cellsight.occlusion._crossing import (
    NO_CROSSING,
    crossing,
    on_polygon,
    plane_distance,
    polygon,
)


@njit(cache=True)
def cull_segments(polys, spheres, points, view):  # pragma: no cover - jit
    """Indices (K,) int64 of the polygons of ``polys`` (:class:`~._crossing.PolygonArrays`)
    that may cross a segment ``view`` -> ``points[i]``; ``spheres`` (P, 4): their bounding
    spheres (centre, radius).

    Dropped (exactly: such a polygon hides no point under the crossing test): a polygon whose
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
    kept = np.empty(polys.eps.shape[0], np.int64)
    n_kept = 0
    for q in range(polys.eps.shape[0]):
        poly = polygon(polys, q)
        eps = poly.eps
        if (poly.xmin - eps > reach[3] or poly.xmax + eps < reach[0]
                or poly.ymin - eps > reach[4] or poly.ymax + eps < reach[1]
                or poly.zmin - eps > reach[5] or poly.zmax + eps < reach[2]):
            continue
        dc = np.sqrt((spheres[q, 0] - view[0]) ** 2 + (spheres[q, 1] - view[1]) ** 2
                     + (spheres[q, 2] - view[2]) ** 2)
        if dc - spheres[q, 3] > far + eps:
            continue
        if abs(plane_distance(poly, view[0], view[1], view[2])) <= eps:
            continue
        kept[n_kept] = q
        n_kept += 1
    return kept[:n_kept]


@njit(cache=True)
def segment_visible(polys, kept, points, view, tol):  # pragma: no cover - jit
    """Visible flags (N,) of ``points`` (N, 3) from ``view`` (3,) against the polygons ``kept``
    of ``polys`` (:class:`~._crossing.PolygonArrays`).

    A point is hidden iff some kept polygon passes the crossing test (``tol``, m: the caller's
    surface tolerance, at least ``eps`` is used). All input must be finite. The test is inlined
    (see :mod:`._crossing` on call overheads); a point is no longer tested once hidden. Cost
    O(N * K).
    """
    n_points = points.shape[0]
    hidden = np.zeros(n_points, np.bool_)
    view3 = (view[0], view[1], view[2])
    for k in range(kept.shape[0]):
        q = kept[k]
        poly = polygon(polys, q)
        sv = plane_distance(poly, view3[0], view3[1], view3[2])
        if abs(sv) <= poly.eps:
            continue
        for p in range(n_points):
            if hidden[p]:
                continue
            point = (points[p, 0], points[p, 1], points[p, 2])
            t = crossing(poly, sv, view3, point, tol, np.inf)
            if t != NO_CROSSING and on_polygon(polys, q, t, view3, point):
                hidden[p] = True
    return ~hidden

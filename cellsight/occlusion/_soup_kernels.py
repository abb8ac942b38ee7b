"""Numba kernels on flat polygon arrays: planes by Newell's method and the simplicity check.

Flat layout (shared by every kernel of :mod:`cellsight.occlusion`): polygon ``i`` is
``vertices[offsets[i]:offsets[i + 1]]``, a closed loop (the last vertex joins the first).
Lengths are in the caller's unit (metres in cellsight).
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: Status codes of :func:`polygon_planes` (first failing polygon wins).
STATUS_OK = 0
STATUS_BAD_OFFSETS = 1
STATUS_FEW_VERTICES = 2
STATUS_NOT_FINITE = 3
STATUS_ZERO_AREA = 4
_TINY = float(np.finfo(np.float64).tiny)


@njit(cache=True)
def polygon_planes(vertices: np.ndarray, offsets: np.ndarray, eps_rel: float, round_rel: float):
    """Planes, bounds and plane thicknesses of every polygon of a flat soup, in one pass.

    Returns ``(planes, boxes, spheres, areas, deviations, eps, status, where)``:

    - ``planes`` (P, 4): unit normal ``n`` (Newell's method on vertices taken relative to their
      mean, so the right-hand rule of the vertex order fixes its sign) and ``d`` with the plane
      ``n . x = d`` through the vertex mean;
    - ``boxes`` (P, 6): axis-aligned box ``(xmin, ymin, zmin, xmax, ymax, zmax)``;
    - ``spheres`` (P, 4): vertex mean and largest vertex distance from it;
    - ``areas`` (P,): polygon area (half the Newell vector's length; exact for simple planar
      polygons, convex or not);
    - ``deviations`` (P,): largest distance of a vertex from the plane;
    - ``eps`` (P,): the polygon's own plane thickness (same unit as the vertices), the largest
      of ``eps_rel`` times its box diagonal, ``round_rel`` times its largest absolute
      coordinate (rounding), twice ``deviations`` and the smallest positive double: it depends
      on nothing but the polygon itself;
    - ``status``/``where``: a ``STATUS_*`` code and the first polygon it concerns.

    The loop is written inline: numba helpers taking arrays cost reference counting per call.
    """
    n_poly = offsets.shape[0] - 1
    planes = np.zeros((n_poly, 4))
    boxes = np.zeros((n_poly, 6))
    spheres = np.zeros((n_poly, 4))
    areas = np.zeros(n_poly)
    deviations = np.zeros(n_poly)
    eps = np.zeros(n_poly)
    status, where = STATUS_OK, 0
    if offsets[0] != 0 or offsets[n_poly] != vertices.shape[0]:
        status = STATUS_BAD_OFFSETS
    for i in range(n_poly if status == STATUS_OK else 0):
        start, stop = offsets[i], offsets[i + 1]
        if stop - start < 3:
            status, where = STATUS_FEW_VERTICES, i
            break
        finite = True
        cx = cy = cz = 0.0
        for a in range(3):
            boxes[i, a], boxes[i, 3 + a] = np.inf, -np.inf
        for j in range(start, stop):
            x, y, z = vertices[j, 0], vertices[j, 1], vertices[j, 2]
            finite = finite and np.isfinite(x) and np.isfinite(y) and np.isfinite(z)
            cx, cy, cz = cx + x, cy + y, cz + z
            boxes[i, 0], boxes[i, 3] = min(boxes[i, 0], x), max(boxes[i, 3], x)
            boxes[i, 1], boxes[i, 4] = min(boxes[i, 1], y), max(boxes[i, 4], y)
            boxes[i, 2], boxes[i, 5] = min(boxes[i, 2], z), max(boxes[i, 5], z)
        if not finite:
            status, where = STATUS_NOT_FINITE, i
            break
        k = stop - start
        cx, cy, cz = cx / k, cy / k, cz / k
        nx = ny = nz = 0.0
        for j in range(start, stop):
            jn = j + 1 if j + 1 < stop else start
            x0, y0, z0 = vertices[j, 0] - cx, vertices[j, 1] - cy, vertices[j, 2] - cz
            x1, y1, z1 = vertices[jn, 0] - cx, vertices[jn, 1] - cy, vertices[jn, 2] - cz
            nx += (y0 - y1) * (z0 + z1)
            ny += (z0 - z1) * (x0 + x1)
            nz += (x0 - x1) * (y0 + y1)
        length = np.sqrt(nx * nx + ny * ny + nz * nz)
        if not length > 0.0:
            status, where = STATUS_ZERO_AREA, i
            break
        nx, ny, nz = nx / length, ny / length, nz / length
        radius2 = deviation = 0.0
        for j in range(start, stop):
            x0, y0, z0 = vertices[j, 0] - cx, vertices[j, 1] - cy, vertices[j, 2] - cz
            radius2 = max(radius2, x0 * x0 + y0 * y0 + z0 * z0)
            deviation = max(deviation, abs(nx * x0 + ny * y0 + nz * z0))
        planes[i, 0], planes[i, 1], planes[i, 2] = nx, ny, nz
        planes[i, 3] = nx * cx + ny * cy + nz * cz
        spheres[i, 0], spheres[i, 1], spheres[i, 2] = cx, cy, cz
        spheres[i, 3] = np.sqrt(radius2)
        areas[i] = 0.5 * length
        deviations[i] = deviation
        diagonal2 = magnitude = 0.0
        for a in range(3):
            diagonal2 += (boxes[i, 3 + a] - boxes[i, a]) ** 2
            magnitude = max(magnitude, max(abs(boxes[i, a]), abs(boxes[i, 3 + a])))
        eps[i] = max(max(eps_rel * np.sqrt(diagonal2), round_rel * magnitude),
                     max(2.0 * deviation, _TINY))
    return planes, boxes, spheres, areas, deviations, eps, status, where


@njit(cache=True)
def drop_axis(nx: float, ny: float, nz: float):
    """The two coordinate axes kept when a polygon with normal ``n`` is projected to 2D."""
    ax, ay, az = abs(nx), abs(ny), abs(nz)
    if ax >= ay and ax >= az:
        return 1, 2
    if ay >= az:
        return 2, 0
    return 0, 1


@njit(cache=True)
def _point_segment_distance(px, py, ax, ay, bx, by) -> float:
    """Distance from point p to the segment a-b in 2D."""
    ex, ey = bx - ax, by - ay
    length2 = ex * ex + ey * ey
    u = 0.0
    if length2 > 0.0:
        u = min(1.0, max(0.0, ((px - ax) * ex + (py - ay) * ey) / length2))
    dx, dy = px - ax - u * ex, py - ay - u * ey
    return np.sqrt(dx * dx + dy * dy)


@njit(cache=True)
def _folded_triangle(vertices, start, a0, a1, tol):
    """The first edge pair (0, 1), (0, 2), (1, 2) of the triangle at ``vertices[start:start
    + 3]`` whose far ends lie within ``tol`` of the other edge (projected on axes a0, a1), as
    :func:`first_non_simple`'s loop finds it: ``(edge_a, edge_b, distance)``, -1 if none."""
    x0, y0 = vertices[start, a0], vertices[start, a1]
    x1, y1 = vertices[start + 1, a0], vertices[start + 1, a1]
    x2, y2 = vertices[start + 2, a0], vertices[start + 2, a1]
    d2 = _point_segment_distance(x2, y2, x0, y0, x1, y1)  # vertex 2 to edge 0 (0-1)
    d0 = _point_segment_distance(x0, y0, x1, y1, x2, y2)  # vertex 0 to edge 1 (1-2)
    d1 = _point_segment_distance(x1, y1, x2, y2, x0, y0)  # vertex 1 to edge 2 (2-0)
    if min(d2, d0) <= tol:
        return 0, 1, min(d2, d0)
    if min(d2, d1) <= tol:
        return 0, 2, min(d2, d1)
    if min(d0, d1) <= tol:
        return 1, 2, min(d0, d1)
    return -1, -1, 0.0


@njit(cache=True)
def _segment_distance(ax, ay, bx, by, cx, cy, dx, dy) -> float:
    """Distance between the 2D segments a-b and c-d (0 when they cross)."""
    o1 = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
    o2 = (bx - ax) * (dy - ay) - (by - ay) * (dx - ax)
    o3 = (dx - cx) * (ay - cy) - (dy - cy) * (ax - cx)
    o4 = (dx - cx) * (by - cy) - (dy - cy) * (bx - cx)
    if o1 * o2 < 0.0 and o3 * o4 < 0.0:
        return 0.0
    return min(
        min(_point_segment_distance(ax, ay, cx, cy, dx, dy),
            _point_segment_distance(bx, by, cx, cy, dx, dy)),
        min(_point_segment_distance(cx, cy, ax, ay, bx, by),
            _point_segment_distance(dx, dy, ax, ay, bx, by)),
    )


@njit(cache=True)
def first_non_simple(vertices: np.ndarray, offsets: np.ndarray, planes: np.ndarray, tol_rel: float):
    """Find the first polygon whose boundary touches or crosses itself.

    Each polygon is projected on the coordinate plane most parallel to it. Two non-adjacent
    edges closer than ``tol_rel`` times the polygon's 2D box diagonal, or two adjacent edges
    folding back on each other (including a repeated vertex), make it non-simple.
    Returns ``(polygon, edge_a, edge_b, distance)``, polygon = -1 when all are simple.
    """
    for i in range(offsets.shape[0] - 1):
        start, k = offsets[i], offsets[i + 1] - offsets[i]
        a0, a1 = drop_axis(planes[i, 0], planes[i, 1], planes[i, 2])
        lo0 = hi0 = vertices[start, a0]
        lo1 = hi1 = vertices[start, a1]
        for j in range(start, start + k):
            lo0, hi0 = min(lo0, vertices[j, a0]), max(hi0, vertices[j, a0])
            lo1, hi1 = min(lo1, vertices[j, a1]), max(hi1, vertices[j, a1])
        tol = tol_rel * np.sqrt((hi0 - lo0) ** 2 + (hi1 - lo1) ** 2)
        if k == 3:  # every edge pair is adjacent: the loop below, with each distance once
            ea, eb, dist = _folded_triangle(vertices, start, a0, a1, tol)
            if ea >= 0:
                return i, ea, eb, dist
            continue
        for ea in range(k):
            pa, qa = start + ea, start + (ea + 1) % k
            for eb in range(ea + 1, k):
                pb, qb = start + eb, start + (eb + 1) % k
                if qa == pb:  # adjacent: qa is shared; the far ends must stay off the other edge
                    dist = min(
                        _point_segment_distance(vertices[qb, a0], vertices[qb, a1],
                                                vertices[pa, a0], vertices[pa, a1],
                                                vertices[qa, a0], vertices[qa, a1]),
                        _point_segment_distance(vertices[pa, a0], vertices[pa, a1],
                                                vertices[pb, a0], vertices[pb, a1],
                                                vertices[qb, a0], vertices[qb, a1]),
                    )
                elif qb == pa:  # adjacent the other way round (first and last edge)
                    dist = min(
                        _point_segment_distance(vertices[pb, a0], vertices[pb, a1],
                                                vertices[pa, a0], vertices[pa, a1],
                                                vertices[qa, a0], vertices[qa, a1]),
                        _point_segment_distance(vertices[qa, a0], vertices[qa, a1],
                                                vertices[pb, a0], vertices[pb, a1],
                                                vertices[qb, a0], vertices[qb, a1]),
                    )
                else:
                    dist = _segment_distance(
                        vertices[pa, a0], vertices[pa, a1], vertices[qa, a0], vertices[qa, a1],
                        vertices[pb, a0], vertices[pb, a1], vertices[qb, a0], vertices[qb, a1],
                    )
                if dist <= tol:
                    return i, ea, eb, dist
    return -1, -1, -1, 0.0

"""The segment-polygon crossing test, the one every occlusion kernel uses (the BSP visit
:mod:`._visit_kernel`, the direct test :mod:`._segment_kernel`, the per-object hierarchies
:mod:`._forest_kernel`), and the polygon arrays it reads.

Lengths are in the soup's unit (metres in cellsight). Every polygon ``q`` has its own plane
thickness ``eps`` (:mod:`.soup`). With ``sv``/``sp`` the signed distances
(:func:`plane_distance`) of the viewpoint ``v`` and of the point ``p`` to ``q``'s plane, ``q``
hides ``p`` iff

- ``|sv| > eps``: else ``q`` is seen edge-on and hides nothing (the caller's test, once per
  polygon where it can; a kernel may skip more, such as a closed solid's back faces);
- ``sv`` and ``sp`` have opposite signs with ``|sp| > max(eps, tol)``: a point on the polygon
  (a vertex of its own face) is not hidden by it, and ``tol``, the caller's surface tolerance,
  extends this to points resting on a surface (a part's bottom corners on its support);
- the crossing ``v + t (p - v)``, ``t = sv / (sv - sp)``, lies in ``q``'s box grown by ``eps``
  (:func:`crossing`) and inside ``q`` (:func:`on_polygon`: even-odd rule in the coordinate
  plane most parallel to ``q``, any simple polygon, convex or not).

A kernel tests a pair as ``crossing(...) != NO_CROSSING and on_polygon(...)``. The first
stage, run for every pair, takes scalars only (the polygon's :class:`Polygon`, read once) and is
compiled into the caller (``inline="always"``): numba updates the reference counts of every
array an inlined or called function receives, which would cost more than the geometry itself.
The second stage, reached by the few crossings inside a polygon's box, is a call on the arrays.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from cellsight.occlusion._soup_kernels import drop_axis

#: :func:`crossing`'s answer when the segment does not cross the polygon (nearer than asked).
NO_CROSSING = -1.0


class PolygonArrays(NamedTuple):
    """A polygon soup's flat arrays as the kernels read them (one argument; see :mod:`.soup`):
    polygon ``q`` is ``vertices[offsets[q]:offsets[q + 1]]`` (V, 3) float64, with its plane
    ``planes[q]`` = (unit normal, d) (P, 4), thickness ``eps[q]`` (P,) and box ``boxes[q]`` =
    (min xyz, max xyz) (P, 6)."""

    vertices: np.ndarray
    offsets: np.ndarray
    planes: np.ndarray
    eps: np.ndarray
    boxes: np.ndarray


class Polygon(NamedTuple):
    """One polygon's plane ``n . x = d`` (unit normal), thickness and box, as scalars."""

    nx: float
    ny: float
    nz: float
    d: float
    eps: float
    xmin: float
    ymin: float
    zmin: float
    xmax: float
    ymax: float
    zmax: float


@njit(cache=True, inline="always")
def polygon(polys, q):  # pragma: no cover - jit
    """Polygon ``q`` of ``polys`` (:class:`PolygonArrays`) as a :class:`Polygon`."""
    plane, box = polys.planes, polys.boxes
    return Polygon(plane[q, 0], plane[q, 1], plane[q, 2], plane[q, 3], polys.eps[q],
                   box[q, 0], box[q, 1], box[q, 2], box[q, 3], box[q, 4], box[q, 5])


@njit(cache=True, inline="always")
def plane_distance(poly, x, y, z):  # pragma: no cover - jit
    """Signed distance of the point (x, y, z) to the plane of ``poly`` (a :class:`Polygon`),
    positive on the side its normal points to."""
    return poly.nx * x + poly.ny * y + poly.nz * z - poly.d


@njit(cache=True, inline="always")
def crossing(poly, sv, view, point, tol, t_max):  # pragma: no cover - jit
    """The first stage of the test (module doc) of the segment ``view`` -> ``point``
    (3-tuples of floats) against ``poly`` (a :class:`Polygon`): the fraction ``t`` of the
    segment (0 at ``view``) where it crosses the plane, when ``poly`` may hide ``point`` there
    (opposite sides, the crossing in the polygon's grown box) at ``t < t_max`` (nearer than a
    crossing already known), else :data:`NO_CROSSING`. ``sv``: ``plane_distance`` of
    ``view``, with ``|sv| > eps`` (the caller's check); ``tol``: the surface tolerance."""
    eps = poly.eps
    sp = plane_distance(poly, point[0], point[1], point[2])
    on_plane = max(eps, tol)
    if (sv > 0.0 and sp >= -on_plane) or (sv < 0.0 and sp <= on_plane):
        return NO_CROSSING  # same side as the viewpoint, or on the plane
    t = sv / (sv - sp)
    if t >= t_max:
        return NO_CROSSING  # a nearer crossing is known
    x0 = view[0] + t * (point[0] - view[0])
    x1 = view[1] + t * (point[1] - view[1])
    x2 = view[2] + t * (point[2] - view[2])
    if (x0 < poly.xmin - eps or x0 > poly.xmax + eps or x1 < poly.ymin - eps
            or x1 > poly.ymax + eps or x2 < poly.zmin - eps or x2 > poly.zmax + eps):
        return NO_CROSSING
    return t


@njit(cache=True)
def on_polygon(polys, q, t, view, point) -> bool:  # pragma: no cover - jit
    """The second stage of the test (module doc): whether the point at ``t`` on the segment
    ``view`` -> ``point`` (:func:`crossing`'s answer) lies inside polygon ``q`` of ``polys``
    (:class:`PolygonArrays`), by the even-odd rule in the coordinate plane most parallel to
    it."""
    x0 = view[0] + t * (point[0] - view[0])
    x1 = view[1] + t * (point[1] - view[1])
    x2 = view[2] + t * (point[2] - view[2])
    a0, a1 = drop_axis(polys.planes[q, 0], polys.planes[q, 1], polys.planes[q, 2])
    u = x0 if a0 == 0 else (x1 if a0 == 1 else x2)
    w = x0 if a1 == 0 else (x1 if a1 == 1 else x2)
    vertices, offsets = polys.vertices, polys.offsets
    inside = False
    start, stop = offsets[q], offsets[q + 1]
    j = stop - 1
    for i in range(start, stop):
        yi, yj = vertices[i, a1], vertices[j, a1]
        if (yi > w) != (yj > w):
            xi, xj = vertices[i, a0], vertices[j, a0]
            if u < xi + (xj - xi) * (w - yi) / (yj - yi):
                inside = not inside
        j = i
    return inside

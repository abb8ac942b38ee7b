"""Planar polygons in 3D: plane, area, and the checks that make a polygon usable as a surface.

A polygon is a (k, 3) array of vertices in order. Its normal follows the right-hand rule of that
order (Newell's method), so a face listed counter-clockwise seen from outside a solid has an
outward normal. Lengths are in metres; tolerances are absolute unless stated.
"""

from __future__ import annotations

import numpy as np

from cellsight.errors import GeometryError

PLANARITY_TOL = 1e-6  # m, largest allowed distance of a vertex from the polygon's plane
AREA_TOL = 1e-10  # m^2, smallest allowed area


def newell_normal(points: np.ndarray) -> np.ndarray:
    """Area-weighted normal (not normalised) of a polygon by Newell's method; |n| = 2 * area."""
    p = np.asarray(points, dtype=float)
    q = np.roll(p, -1, axis=0)
    return np.array(
        [
            np.sum((p[:, 1] - q[:, 1]) * (p[:, 2] + q[:, 2])),
            np.sum((p[:, 2] - q[:, 2]) * (p[:, 0] + q[:, 0])),
            np.sum((p[:, 0] - q[:, 0]) * (p[:, 1] + q[:, 1])),
        ]
    )


def plane_basis(normal: np.ndarray) -> np.ndarray:
    """A 2x3 matrix whose rows are orthonormal in-plane axes (u, v) with u x v = normal."""
    n = normal / np.linalg.norm(normal)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(helper, n)
    u /= np.linalg.norm(u)
    return np.vstack([u, np.cross(n, u)])


def _segments_cross(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, tol: float) -> bool:
    """True if 2D segments ab and cd intersect (touching within ``tol`` counts)."""

    def orient(p, q, r):
        return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])

    def on_segment(p, q, r):
        return (
            min(p[0], q[0]) - tol <= r[0] <= max(p[0], q[0]) + tol
            and min(p[1], q[1]) - tol <= r[1] <= max(p[1], q[1]) + tol
        )

    scale = max(np.ptp(np.vstack([a, b, c, d]), axis=0).max(), 1e-12)
    e = tol * scale
    o1, o2, o3, o4 = orient(a, b, c), orient(a, b, d), orient(c, d, a), orient(c, d, b)
    if ((o1 > e and o2 < -e) or (o1 < -e and o2 > e)) and (
        (o3 > e and o4 < -e) or (o3 < -e and o4 > e)
    ):
        return True
    return bool(
        (abs(o1) <= e and on_segment(a, b, c))
        or (abs(o2) <= e and on_segment(a, b, d))
        or (abs(o3) <= e and on_segment(c, d, a))
        or (abs(o4) <= e and on_segment(c, d, b))
    )


def check_polygon(points, label: str, planarity_tol: float = PLANARITY_TOL) -> np.ndarray:
    """Validate a polygon and return it as a float (k, 3) array.

    Checks: at least 3 vertices, all finite, no repeated consecutive vertex, area above
    ``AREA_TOL``, every vertex within ``planarity_tol`` of the best plane, and simple (no two
    non-adjacent edges touch). ``label`` names the polygon in the error, e.g. "solid 'part'
    face 3".
    """
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise GeometryError(f"{label}: vertices must have shape (k, 3), got {p.shape}")
    if p.shape[0] < 3:
        raise GeometryError(f"{label}: a polygon needs at least 3 vertices, got {p.shape[0]}")
    if not np.all(np.isfinite(p)):
        raise GeometryError(f"{label}: non-finite vertex coordinates {p.tolist()}")
    size = float(np.ptp(p, axis=0).max())
    edges = np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1)
    if np.any(edges <= 1e-9 * max(size, 1.0)):
        i = int(np.argmin(edges))
        raise GeometryError(f"{label}: vertices {i} and {(i + 1) % len(p)} coincide (degenerate)")
    n = newell_normal(p)
    area = 0.5 * np.linalg.norm(n)
    if area <= AREA_TOL:
        _zero_area(p, label, area)
    n_unit = n / (2 * area)
    dist = (p - p.mean(axis=0)) @ n_unit
    worst = float(np.abs(dist).max())
    if worst > planarity_tol:
        raise GeometryError(
            f"{label}: non-planar polygon (vertex {int(np.abs(dist).argmax())} is {worst:.3g} m "
            f"from the plane; tolerance {planarity_tol:.3g} m)"
        )
    _check_simple((p - p[0]) @ plane_basis(n_unit).T, label)
    return p


def _check_simple(xy: np.ndarray, label: str) -> None:
    """Raise unless no two non-adjacent edges of the 2D polygon ``xy`` (k, 2) touch."""
    k = len(xy)
    for i in range(k):
        for j in range(i + 1, k):
            if j == i + 1 or (i == 0 and j == k - 1):
                continue
            if _segments_cross(xy[i], xy[(i + 1) % k], xy[j], xy[(j + 1) % k], 1e-9):
                raise GeometryError(f"{label}: edges {i} and {j} intersect (polygon is not "
                                    f"simple: self-intersecting)")


def _zero_area(p: np.ndarray, label: str, area: float) -> None:
    """Name why a polygon's (signed, Newell) area vanishes: collinear vertices, or a bow-tie
    whose two loops cancel (self-intersecting); always raises."""
    centred = p - p.mean(axis=0)
    _, s, axes = np.linalg.svd(centred, full_matrices=False)
    if s[1] > 1e-9 * max(s[0], 1e-12):  # the vertices span a plane: the outline crosses itself
        _check_simple(centred @ axes[:2].T, label)
        raise GeometryError(f"{label}: degenerate polygon (zero area, the outline folds back "
                            f"on itself)")
    raise GeometryError(f"{label}: degenerate polygon (area {area:.3g} m^2, collinear vertices)")

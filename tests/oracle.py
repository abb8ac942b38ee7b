"""Independent segment-polygon oracle for visibility tests (no code shared with cellsight).

``segment_oracle(polygons, points, viewpoint)`` decides, for every (point, polygon) pair, whether
the open segment from the viewpoint to the point crosses the polygon, in plain numpy: best-fit
plane by SVD, crossing of the segment's line with that plane, winding number of the crossing in
an orthonormal 2D frame of the plane. Conventions match ``cellsight.occlusion`` (see its docs):

- a polygon whose plane is within ``contact`` of the viewpoint hides nothing (seen edge-on);
- a point within ``contact`` of a polygon's plane is not hidden by it (contact at the point);
- ``contact`` = ``CONTACT_REL`` times the scene size (box diagonal of the polygons).

It also reports, per pair, the diagnostics needed to leave out ambiguous cases (whose answer
depends on the last bits of rounding or on the exact tolerance): ``ambiguous`` marks a point for
which some polygon has the crossing within ``BAND_HI`` (relative) of its boundary, or has the
point / viewpoint between ``BAND_LO`` and ``BAND_HI`` (relative) off its plane while being near
the polygon. Points exactly on a plane (below ``BAND_LO``, e.g. a solid's vertex on its own faces)
are *not* ambiguous: they are not hidden by that polygon.

``embree_visible`` is a second, coarser opinion (trimesh + embreex ray casts on an earcut
triangulation, float32) used to check the oracle itself.

Random scene generators (soups of convex / star / L polygons, convex hull solids with merged
faces, extruded non-convex prisms) live here too, so that other tests can reuse them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

CONTACT_REL = 1e-9
BAND_LO = 1e-11
BAND_HI = 1e-6


@dataclass
class OracleAnswer:
    """Per point (N,) and per (point, polygon) (N, P) answers of :func:`segment_oracle`."""

    hits: np.ndarray  # (N, P) bool: polygon crosses the open segment strictly before the point
    t: np.ndarray  # (N, P) line parameter of the plane crossing, v + t (p - v); nan if parallel
    edge_dist: np.ndarray  # (N, P) distance of the crossing to the polygon's boundary
    point_plane: np.ndarray  # (N, P) distance of the point to the polygon's plane
    view_plane: np.ndarray  # (P,) distance of the viewpoint to the polygon's plane
    ambiguous: np.ndarray  # (N,) bool
    visible: np.ndarray  # (N,) bool
    occluder: np.ndarray  # (N,) int: crossed polygon with the smallest t, -1 if visible


def _frame(polygon: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Centre, unit normal and in-plane orthonormal axes (u, w) of a polygon, by SVD."""
    centre = polygon.mean(axis=0)
    _, _, vt = np.linalg.svd(polygon - centre)
    return centre, vt[2], vt[0], vt[1]


def winding_inside(poly2d: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Non-zero winding test of points ``xy`` (N, 2) against a polygon ``poly2d`` (k, 2)."""
    a = poly2d[None, :, :]
    b = np.roll(poly2d, -1, axis=0)[None, :, :]
    p = xy[:, None, :]
    left = (b[..., 0] - a[..., 0]) * (p[..., 1] - a[..., 1]) - (p[..., 0] - a[..., 0]) * (
        b[..., 1] - a[..., 1]
    )
    up = (a[..., 1] <= p[..., 1]) & (b[..., 1] > p[..., 1]) & (left > 0)
    down = (a[..., 1] > p[..., 1]) & (b[..., 1] <= p[..., 1]) & (left < 0)
    return (up.sum(axis=1) - down.sum(axis=1)) != 0


def boundary_distance(poly2d: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Distance (N,) of points ``xy`` to the boundary of a 2D polygon."""
    a = poly2d[None, :, :]
    e = np.roll(poly2d, -1, axis=0)[None, :, :] - a
    rel = xy[:, None, :] - a
    u = np.clip((rel * e).sum(-1) / np.maximum((e * e).sum(-1), 1e-300), 0.0, 1.0)
    return np.linalg.norm(rel - u[..., None] * e, axis=-1).min(axis=1)


def segment_oracle(polygons, points, viewpoint, surface_tolerance: float = 0.0,
                   prune: bool = False) -> OracleAnswer:
    """Exact-arithmetic-style answers for every (point, polygon) pair; see the module doc.

    ``surface_tolerance`` (absolute): a point nearer than this to a polygon's plane is not hidden
    by it either (a feature resting on a surface); points within the band around that distance
    are ambiguous. ``prune``: skip the polygons whose bounding sphere stays farther than the
    tolerances from every segment (they can neither hide a point nor make it ambiguous); their
    pairs read not hit, ``t`` nan and infinite distances (for big scenes: a robot cell)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    view = np.asarray(viewpoint, dtype=float)
    polygons = [np.asarray(p, dtype=float) for p in polygons]
    n, m = len(points), len(polygons)
    allv = np.concatenate(polygons) if polygons else np.zeros((1, 3))
    scale = float(np.linalg.norm(allv.max(0) - allv.min(0))) or 1.0
    contact, lo, hi = CONTACT_REL * scale, BAND_LO * scale, BAND_HI * scale
    hits = np.zeros((n, m), bool)
    t = np.full((n, m), np.nan)
    edge = np.full((n, m), np.inf)
    sp_all = np.full((n, m), np.inf)
    sv_all = np.full(m, np.inf)
    amb = np.zeros(n, bool)
    pad = 2 * (surface_tolerance + hi + contact)
    near = _near_segments(polygons, points, view, pad) if prune else np.ones(m, bool)
    for q, poly in enumerate(polygons):
        if not near[q]:
            continue
        centre, normal, u, w = _frame(poly)
        to2d = np.stack([u, w], axis=1)
        poly2d = (poly - centre) @ to2d
        sv = float((view - centre) @ normal)
        sp = (points - centre) @ normal
        with np.errstate(divide="ignore", invalid="ignore"):
            tq = sv / (sv - sp)
            x = view + tq[:, None] * (points - view)
        xy = (x - centre) @ to2d
        ok = np.isfinite(tq)
        inside = np.zeros(n, bool)
        dist = np.full(n, np.inf)
        inside[ok] = winding_inside(poly2d, xy[ok])
        dist[ok] = boundary_distance(poly2d, xy[ok])
        region = np.where(inside, 0.0, dist)
        crossing = ((abs(sv) > contact) & (np.abs(sp) > max(contact, surface_tolerance))
                    & (sv * sp < 0))
        hits[:, q] = crossing & inside
        t[:, q], edge[:, q], sp_all[:, q], sv_all[q] = tq, dist, np.abs(sp), abs(sv)
        # ambiguous: crossing near the boundary, or point / viewpoint in the tolerance band
        amb |= (abs(sv) > lo) & (np.abs(sp) > lo) & (sv * sp < 0) & (dist < hi)
        p_region = _region_distance(poly2d, (points - centre) @ to2d)
        amb |= (np.abs(sp) > lo) & (np.abs(sp) < hi) & (np.minimum(p_region, region) < hi)
        if surface_tolerance > 0:
            amb |= (np.abs(np.abs(sp) - surface_tolerance) < hi) & (sv * sp < 0) & inside
        if lo < abs(sv) < hi:
            v_region = _region_distance(poly2d, ((view - centre) @ to2d)[None, :])[0]
            amb |= min(v_region, region.min(initial=np.inf)) < hi
    visible = ~hits.any(axis=1)
    t_hit = np.where(hits, t, np.inf)
    occluder = np.where(visible, -1, np.argmin(t_hit, axis=1) if m else -1)
    return OracleAnswer(hits, t, edge, sp_all, sv_all, amb, visible, occluder)


def _near_segments(polygons, points: np.ndarray, view: np.ndarray, pad: float) -> np.ndarray:
    """(P,) bool: the polygons whose bounding sphere (about the vertex mean) comes within
    ``pad`` of some segment from ``view`` to a point."""
    if not polygons or not len(points):
        return np.zeros(len(polygons), bool)
    centres = np.array([p.mean(axis=0) for p in polygons])
    radii = np.array([np.linalg.norm(p - c, axis=1).max()
                      for p, c in zip(polygons, centres, strict=True)])
    d = points - view
    rel = centres - view
    along = np.clip((rel @ d.T) / np.maximum((d * d).sum(axis=1), 1e-300), 0.0, 1.0)
    gap = np.linalg.norm(rel[:, None, :] - along[..., None] * d[None], axis=-1).min(axis=1)
    return gap <= radii + pad


def _region_distance(poly2d: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Distance of 2D points to the polygon's region (0 inside)."""
    return np.where(winding_inside(poly2d, xy), 0.0, boundary_distance(poly2d, xy))


def embree_visible(polygons, points, viewpoint, margin: float) -> np.ndarray:
    """Visibility by float32 ray casts (trimesh + embreex) on an earcut triangulation.

    A point is hidden when a triangle is hit farther than ``margin`` from both ends.
    """
    import mapbox_earcut
    import trimesh
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    verts, faces = [], []
    base = 0
    for poly in polygons:
        poly = np.asarray(poly, dtype=float)
        centre, _, u, w = _frame(poly)
        tri = mapbox_earcut.triangulate_float64(
            (poly - centre) @ np.stack([u, w], axis=1), np.array([len(poly)], dtype=np.uint32)
        )
        verts.append(poly)
        faces.append(tri.reshape(-1, 3) + base)
        base += len(poly)
    mesh = trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=False)
    points = np.asarray(points, dtype=float)
    direction = points - viewpoint
    length = np.linalg.norm(direction, axis=1)
    origins = np.repeat(np.asarray(viewpoint, dtype=float)[None, :], len(points), axis=0)
    locations, ray_index, _ = RayMeshIntersector(mesh).intersects_location(
        origins, direction / length[:, None], multiple_hits=True
    )
    along = np.linalg.norm(locations - origins[ray_index], axis=1)
    blocking = (along > margin) & (along < length[ray_index] - margin)
    hidden = np.zeros(len(points), bool)
    hidden[ray_index[blocking]] = True
    return ~hidden


# ---------------------------------------------------------------- random scenes


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random 3x3 rotation matrix."""
    return Rotation.random(random_state=rng.integers(2**31)).as_matrix()


def random_polygon_2d(rng: np.random.Generator, kind: str | None = None) -> np.ndarray:
    """A simple 2D polygon of size ~1, counter-clockwise: 'convex', 'star' or 'L'."""
    kind = kind or str(rng.choice(["convex", "star", "L"]))
    if kind == "L":
        w, h = rng.uniform(0.5, 1.0, 2)
        a, b = rng.uniform(0.15, 0.85, 2)
        return np.array([[0, 0], [w, 0], [w, b * h], [a * w, b * h], [a * w, h], [0, h]])
    k = int(rng.integers(3, 9)) if kind == "convex" else int(rng.integers(3, 7))
    if kind == "convex":
        angles = np.linspace(0, 2 * np.pi, k, endpoint=False) + rng.uniform(0, 0.5 / k, k)
        radii = np.ones(k) * rng.uniform(0.3, 0.6)
    else:
        angles = np.linspace(0, 2 * np.pi, 2 * k, endpoint=False) + rng.uniform(0, 0.3 / k, 2 * k)
        radii = np.where(np.arange(2 * k) % 2 == 0, 0.6, rng.uniform(0.1, 0.35))
    return np.stack([radii * np.cos(angles), radii * np.sin(angles)], axis=1)


def place_polygon(poly2d: np.ndarray, rng: np.random.Generator, scale: float, centre) -> np.ndarray:
    """Embed a 2D polygon in 3D: scaled, randomly rotated, translated to ``centre``."""
    flat = np.column_stack([poly2d * scale, np.zeros(len(poly2d))])
    if rng.random() < 0.5:
        flat = flat[::-1]
    return flat @ random_rotation(rng).T + np.asarray(centre)


def random_soup(rng: np.random.Generator, n_polygons: int) -> list[np.ndarray]:
    """Random polygons (convex, star-shaped, L) of random sizes and orientations in [-1, 1]^3."""
    return [
        place_polygon(random_polygon_2d(rng), rng, rng.uniform(0.3, 1.2), rng.uniform(-1, 1, 3))
        for _ in range(n_polygons)
    ]


def hull_solid(points: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Faces (outward, coplanar hull triangles merged) and vertices of a convex hull."""
    hull = ConvexHull(points)
    keys = np.round(hull.equations, 9)
    faces = []
    for key in np.unique(keys, axis=0):
        group = np.flatnonzero((keys == key).all(axis=1))
        ids = np.unique(hull.simplices[group])
        normal = hull.equations[group[0], :3]
        pts = points[ids]
        centre = pts.mean(axis=0)
        u = pts[0] - centre
        u /= np.linalg.norm(u)
        w = np.cross(normal, u)
        rel = pts - centre
        order = np.argsort(np.arctan2(rel @ w, rel @ u))
        faces.append(pts[order])
    return faces, points[hull.vertices]


def random_convex_solid(rng: np.random.Generator, centre, size: float):
    """Convex hull of random lattice points (so many faces are merged polygons), rotated."""
    while True:
        pts = rng.integers(-3, 4, size=(int(rng.integers(8, 20)), 3)).astype(float)
        if np.linalg.matrix_rank(pts - pts.mean(0)) == 3:
            break
    pts = pts / 3.0 * size @ random_rotation(rng).T + np.asarray(centre)
    return hull_solid(pts)


def random_prism(rng: np.random.Generator, centre, size: float):
    """Extruded non-convex (star or L) prism: faces (outward) and vertices, rotated."""
    base = random_polygon_2d(rng, str(rng.choice(["star", "L"])))
    k = len(base)
    height = rng.uniform(0.3, 1.0)
    bottom = np.column_stack([base, np.zeros(k)])
    top = np.column_stack([base, np.full(k, height)])
    faces = [bottom[::-1], top]
    for i in range(k):
        j = (i + 1) % k
        faces.append(np.array([bottom[i], bottom[j], top[j], top[i]]))
    rot = random_rotation(rng)
    shift = np.asarray(centre) - np.array([0, 0, height / 2]) @ rot.T * size
    faces = [f * size @ rot.T + shift for f in faces]
    return faces, np.concatenate([bottom, top]) * size @ rot.T + shift


def cell_scene(cell, snapshot, part: str | None = None
               ) -> tuple[list[np.ndarray], list[str], np.ndarray]:
    """Every surface of a cell snapshot in the base frame with its object's label ('self' for
    the workpiece ``part``, by default the first), and that workpiece's features (F, 3)."""
    from cellsight.geometry.transforms import transform_points

    part = cell.workpiece(part) if part else cell.workpieces[0]
    polygons, labels = [], []
    for obj, T in zip(cell.objects, snapshot.poses, strict=True):
        for k in range(len(obj.solid.faces)):
            polygons.append(transform_points(T, obj.solid.face_points(k)))
            labels.append("self" if obj.name == part.name else obj.label)
    return polygons, labels, transform_points(snapshot.pose(part.name), part.feature_points)


def soup_and_solids(rng: np.random.Generator) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """A random soup of 3-24 polygons plus a convex solid and a non-convex prism: the
    polygons, and the two solids' vertex arrays."""
    polygons = random_soup(rng, int(rng.integers(3, 25)))
    vertices = []
    for make in (random_convex_solid, random_prism):
        faces, corners = make(rng, rng.uniform(-1, 1, 3), rng.uniform(0.3, 0.8))
        polygons += faces
        vertices.append(corners)
    return polygons, vertices

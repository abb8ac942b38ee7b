"""Compiled per-frame kernels of the cell-level predictor: moving the surfaces to the base
frame and culling the surfaces that cannot hide a feature from a camera (exact; see
:mod:`cellsight.occlusion.predictor`). Lengths in metres; "normalised" image coordinates are
(x/z, y/z) in camera axes."""

from __future__ import annotations

import numpy as np
from numba import njit

from cellsight._camera_kernel import project_point, to_camera


@njit(cache=True)
def transform_vertices(local, vertex_owner, moving, poses, out):  # pragma: no cover - jit
    """``out[i] = poses[vertex_owner[i]] @ local[i]`` for the vertex indices in ``moving``."""
    for i in moving:
        T = poses[vertex_owner[i]]
        x, y, z = local[i, 0], local[i, 1], local[i, 2]
        for r in range(3):
            out[i, r] = T[r, 0] * x + T[r, 1] * y + T[r, 2] * z + T[r, 3]


SLACK = 1e-9  # m (and normalised units): rounding allowance of the box tests (errors ~1e-15)
BOX_NEAR = 1e-3  # m: a box nearer than this to the focal plane is not tested in the image


@njit(cache=True)
def place_polygons(local, offsets, polys, pose, out):  # pragma: no cover - jit
    """``out[j] = pose @ local[j]`` for every vertex j of the polygons ``polys`` (the same
    arithmetic as :func:`transform_vertices`, so the result is identical bit for bit)."""
    for p in polys:
        for i in range(offsets[p], offsets[p + 1]):
            x, y, z = local[i, 0], local[i, 1], local[i, 2]
            for r in range(3):
                out[i, r] = pose[r, 0] * x + pose[r, 1] * y + pose[r, 2] * z + pose[r, 3]


@njit(cache=True)
def gather_polygons(vertices, offsets, polys):  # pragma: no cover - jit
    """The vertices (V', 3) and offsets (P'+1,) of the polygons ``polys``, in that order."""
    out_offsets = np.zeros(polys.shape[0] + 1, np.int64)
    for i in range(polys.shape[0]):
        out_offsets[i + 1] = out_offsets[i] + offsets[polys[i] + 1] - offsets[polys[i]]
    out = np.empty((out_offsets[-1], 3))
    for i in range(polys.shape[0]):
        start = out_offsets[i] - offsets[polys[i]]
        for j in range(offsets[polys[i]], offsets[polys[i] + 1]):
            out[start + j, 0], out[start + j, 1], out[start + j, 2] = (
                vertices[j, 0], vertices[j, 1], vertices[j, 2])
    return out, out_offsets


@njit(cache=True)
def _box_may_hide(T, box, feats, n_feats, margin):  # pragma: no cover - jit
    """Whether something inside the object-frame box ``box`` = (min xyz, max xyz), seen through
    ``T`` = ``T_cam_obj``, may hide a feature: False only when every point of the box is at
    least as far as every feature (depth), or lies, in normalised image coordinates, more than
    ``margin`` away from every nearer feature (``feats[:n_feats]`` = (x/z, y/z, z)). The box's
    corners span it, depth is linear and x/z, y/z are extreme at corners when all z > 0, so
    the test is exact up to ``SLACK``. Returns (may hide, (lo, hi) of the corners in camera
    axes, 6 values)."""
    ext = np.empty(6)
    for a in range(3):
        ext[a], ext[3 + a] = np.inf, -np.inf
    xmin = ymin = np.inf
    xmax = ymax = -np.inf
    for c in range(8):
        px = box[3] if c & 1 else box[0]
        py = box[4] if c & 2 else box[1]
        pz = box[5] if c & 4 else box[2]
        q0 = T[0, 0] * px + T[0, 1] * py + T[0, 2] * pz + T[0, 3]
        q1 = T[1, 0] * px + T[1, 1] * py + T[1, 2] * pz + T[1, 3]
        q2 = T[2, 0] * px + T[2, 1] * py + T[2, 2] * pz + T[2, 3]
        ext[0], ext[1], ext[2] = min(ext[0], q0), min(ext[1], q1), min(ext[2], q2)
        ext[3], ext[4], ext[5] = max(ext[3], q0), max(ext[4], q1), max(ext[5], q2)
        if q2 > 0.0:
            xmin, xmax = min(xmin, q0 / q2), max(xmax, q0 / q2)
            ymin, ymax = min(ymin, q1 / q2), max(ymax, q1 / q2)
    zmin = ext[2] - SLACK
    in_image = ext[2] > BOX_NEAR
    grow = margin + SLACK
    for f in range(n_feats):
        if feats[f, 2] <= zmin:
            continue
        if not in_image or (xmin - grow <= feats[f, 0] <= xmax + grow
                            and ymin - grow <= feats[f, 1] <= ymax + grow):
            return True, ext
    return False, ext


@njit(cache=True)
def _polygon_may_hide(vertices, s, e, R, t, closed, feats, n_feats, margin):  # pragma: no cover
    """The per-polygon test of :func:`cull_camera` on vertices ``s:e`` (base frame)."""
    zmin, xmin, xmax, ymin, ymax = np.inf, np.inf, -np.inf, np.inf, -np.inf
    nx = ny = nz = 0.0
    cx0 = cy0 = cz0 = 0.0
    for j in range(s, e):
        jn = j + 1 if j + 1 < e else s
        ax, ay, az = to_camera(R, t, vertices[j])
        bx, by, bz = to_camera(R, t, vertices[jn])
        nx += (ay - by) * (az + bz)
        ny += (az - bz) * (ax + bx)
        nz += (ax - bx) * (ay + by)
        if j == s:
            cx0, cy0, cz0 = ax, ay, az
        zmin = min(zmin, az)
        if az > 1e-6:
            xmin, xmax = min(xmin, ax / az), max(xmax, ax / az)
            ymin, ymax = min(ymin, ay / az), max(ymax, ay / az)
    if closed and nx * -cx0 + ny * -cy0 + nz * -cz0 <= 0.0:
        return False
    for f in range(n_feats):
        if zmin >= feats[f, 2]:
            continue
        if zmin <= 1e-6 or (xmax >= feats[f, 0] - margin and xmin <= feats[f, 0] + margin
                            and ymax >= feats[f, 1] - margin and ymin <= feats[f, 1] + margin):
            return True
    return False


@njit(cache=True)
def _place_cluster(local, offsets, cluster_polys, cluster_start, c, pose, ready,
                   vertices):  # pragma: no cover - jit
    """Move cluster ``c``'s polygons to the base frame unless done this frame."""
    if not ready[c]:
        place_polygons(local, offsets, cluster_polys[cluster_start[c]:cluster_start[c + 1]],
                       pose, vertices)
        ready[c] = True


@njit(cache=True)
def cull_camera(local, offsets, poses, object_closed, object_box, object_clusters, cluster_box,
                cluster_polys, cluster_start, T_cam_base, points, status, margin,
                contain_margin, vertices, ready, keep, bit):  # pragma: no cover - jit
    """Set ``bit`` in ``keep`` (P,) uint8 for the polygons that may hide a feature from one
    camera (exact).

    ``points`` (N, 3): the features (base frame), ``status`` their projection status (0: in the
    image; only those count). ``T_cam_base`` maps base to camera coordinates; ``poses[k]`` =
    ``T_base_obj`` of object k, whose clusters are ``object_clusters[k]:object_clusters[k+1]``;
    cluster c holds the polygons ``cluster_polys[cluster_start[c]:cluster_start[c + 1]]``,
    within the object-frame box ``cluster_box[c]`` (``object_box[k]`` for the whole object).
    A polygon is kept when it faces the camera (or its solid is open, or the solid's box in
    camera axes, grown by ``contain_margin`` m, holds the optical centre: the camera may be
    inside the solid or on its boundary) and, for some feature, part of it is nearer than the
    feature and its normalised bounding box, grown by ``margin``, holds the feature's
    normalised coordinates — or it reaches the camera's focal plane (z <= 1e-6 m), where its
    projection is unbounded. A segment from the optical centre to a feature that crosses a
    polygon crosses it at the feature's normalised coordinates, nearer: nothing that can hide a
    feature is dropped. Whole clusters and objects are skipped first by the same test on their
    box (:func:`_box_may_hide`). Polygons are moved to the base frame (into ``vertices``) only
    when looked at; ``ready[c]``: cluster c already moved this frame.
    """
    R = T_cam_base[:3, :3]
    t = T_cam_base[:3, 3]
    feats = np.empty((points.shape[0], 3))
    n_feats = 0
    for i in range(points.shape[0]):
        if status[i] == 0:
            x, y, z = to_camera(R, t, points[i])
            feats[n_feats, 0], feats[n_feats, 1], feats[n_feats, 2] = x / z, y / z, z
            n_feats += 1
    T = np.zeros((4, 4))
    for k in range(object_box.shape[0]):
        for r in range(3):  # T = T_cam_obj = T_cam_base @ poses[k]
            for col in range(4):
                T[r, col] = (T_cam_base[r, 0] * poses[k, 0, col]
                             + T_cam_base[r, 1] * poses[k, 1, col]
                             + T_cam_base[r, 2] * poses[k, 2, col])
            T[r, 3] += T_cam_base[r, 3]
        hide, ext = _box_may_hide(T, object_box[k], feats, n_feats, margin)
        if not hide:
            continue
        closed = object_closed[k]
        m = contain_margin + SLACK
        if closed and (ext[0] <= m and ext[1] <= m and ext[2] <= m
                       and ext[3] >= -m and ext[4] >= -m and ext[5] >= -m):
            closed = _camera_outside(local, offsets, poses[k], object_clusters[k],
                                     object_clusters[k + 1], cluster_polys, cluster_start, R, t,
                                     contain_margin, vertices, ready)
        for c in range(object_clusters[k], object_clusters[k + 1]):
            if not _box_may_hide(T, cluster_box[c], feats, n_feats, margin)[0]:
                continue
            _place_cluster(local, offsets, cluster_polys, cluster_start, c, poses[k], ready,
                           vertices)
            for i in range(cluster_start[c], cluster_start[c + 1]):
                p = cluster_polys[i]
                if not keep[p] & bit and _polygon_may_hide(vertices, offsets[p], offsets[p + 1],
                                                           R, t, closed, feats, n_feats, margin):
                    keep[p] |= bit


@njit(cache=True)
def _camera_outside(local, offsets, pose, first, last, cluster_polys, cluster_start, R, t,
                    contain_margin, vertices, ready):  # pragma: no cover - jit
    """Whether the box (camera axes) of the vertices of clusters ``first:last`` misses the
    optical centre by more than ``contain_margin`` (moving them to the base frame first)."""
    lo0 = lo1 = lo2 = np.inf
    hi0 = hi1 = hi2 = -np.inf
    for c in range(first, last):
        _place_cluster(local, offsets, cluster_polys, cluster_start, c, pose, ready, vertices)
        for i in range(cluster_start[c], cluster_start[c + 1]):
            p = cluster_polys[i]
            for j in range(offsets[p], offsets[p + 1]):
                x, y, z = to_camera(R, t, vertices[j])
                lo0, lo1, lo2 = min(lo0, x), min(lo1, y), min(lo2, z)
                hi0, hi1, hi2 = max(hi0, x), max(hi1, y), max(hi2, z)
    m = contain_margin
    return not (lo0 <= m and lo1 <= m and lo2 <= m and hi0 >= -m and hi1 >= -m and hi2 >= -m)


@njit(cache=True)
def label_answers(vis, occ, polys, poly_owner, query, feature_owner, n_ring, visible, occluder,
                  near):  # pragma: no cover - jit
    """Write one camera's answers for the features ``query`` (indices into the feature list).

    ``vis``/``occ``: the visit's answers for the query points, then ``n_ring`` ring points per
    query point (in order); ``occ`` indexes ``polys`` (the tree's polygons, indices into the
    predictor's list, owned by the objects ``poly_owner``). Sets ``visible``, ``occluder`` (the
    hiding object, -1 when visible) and ``near`` (visible, and a ring point hidden by an object
    other than the feature's own, ``feature_owner``)."""
    m = query.shape[0]
    for j in range(m):
        i = query[j]
        visible[i] = vis[j]
        occluder[i] = -1 if vis[j] else poly_owner[polys[occ[j]]]
        if vis[j]:
            for k in range(m + j * n_ring, m + (j + 1) * n_ring):
                if not vis[k] and poly_owner[polys[occ[k]]] != feature_owner[i]:
                    near[i] = True
                    break


@njit(cache=True)
def project_points(points, T_cam_base, K, dist, width, height, px, status, box):  # pragma: no cover
    """Project base-frame ``points`` (N, 3) into a camera (the model of
    :mod:`cellsight._camera_kernel`, ``dist`` = ``Camera.dist5``). Fills ``px`` (N, 2) (NaN
    behind the camera), ``status`` (N,) (0 inside the image, 1 behind the camera, 2 outside the
    image) and ``box`` = (xmin, xmax, ymin, ymax, zmax) of the inside points in normalised
    coordinates; returns their count."""
    R = T_cam_base[:3, :3]
    t = T_cam_base[:3, 3]
    box[0] = box[2] = np.inf
    box[1] = box[3] = box[4] = -np.inf
    count = 0
    for i in range(points.shape[0]):
        x, y, z = to_camera(R, t, points[i])
        if z <= 1e-9:
            px[i, 0] = px[i, 1] = np.nan
            status[i] = 1
            continue
        u, v = project_point(K, dist, x, y, z)
        px[i, 0], px[i, 1] = u, v
        if -0.5 <= u <= width - 0.5 and -0.5 <= v <= height - 0.5:
            status[i] = 0
            xn, yn = x / z, y / z
            count += 1
            box[0], box[1] = min(box[0], xn), max(box[1], xn)
            box[2], box[3] = min(box[2], yn), max(box[3], yn)
            box[4] = max(box[4], z)
        else:
            status[i] = 2
    return count

"""Compiled per-frame kernels of the ``frame-bsp`` back-end: moving the surfaces to the base
frame and culling the surfaces that cannot hide a feature from a camera (exact; see
:mod:`cellsight.occlusion.frame_bsp`). Lengths in metres; "normalised" image coordinates are
(x/z, y/z) in camera axes."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from cellsight._camera_kernel import to_camera

SLACK = 1e-9  # m (and normalised units): rounding allowance of the box tests (errors ~1e-15)
BOX_NEAR = 1e-3  # m: a box nearer than this to the focal plane is not tested in the image


class ClusterArrays(NamedTuple):
    """The cell's surfaces grouped for culling, as :func:`cull_camera` reads them (one
    argument). ``local`` (V, 3): every polygon's vertices in its object's frame, polygon p being
    ``local[offsets[p]:offsets[p + 1]]``; ``object_closed`` (K,): object k is a closed solid;
    object k's clusters are ``object_clusters[k]:object_clusters[k + 1]`` and its object-frame
    box ``object_box[k]`` (min xyz, max xyz); cluster c holds the polygons
    ``cluster_polys[cluster_start[c]:cluster_start[c + 1]]`` within the object-frame box
    ``cluster_box[c]``. ``contain_margin`` (m): growth of a solid's box in the camera-inside
    test."""

    local: np.ndarray
    offsets: np.ndarray
    object_closed: np.ndarray
    object_box: np.ndarray
    object_clusters: np.ndarray
    cluster_box: np.ndarray
    cluster_polys: np.ndarray
    cluster_start: np.ndarray
    contain_margin: float


@njit(cache=True)
def place_polygons(local, offsets, polys, pose, out):  # pragma: no cover - jit
    """``out[j] = pose @ local[j]`` for every vertex j of the polygons ``polys`` (the same
    arithmetic as :func:`._frame_kernel.transform_vertices`, so the result is identical bit
    for bit)."""
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
def _box_may_hide(T, box, feats, margin):  # pragma: no cover - jit
    """Whether something inside the object-frame box ``box`` = (min xyz, max xyz), seen through
    ``T`` = ``T_cam_obj``, may hide a feature: False only when every point of the box is at
    least as far as every feature (depth), or lies, in normalised image coordinates, more than
    ``margin`` away from every nearer feature (``feats`` = (x/z, y/z, z) (F, 3)). The box's
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
    for f in range(feats.shape[0]):
        if feats[f, 2] <= zmin:
            continue
        if not in_image or (xmin - grow <= feats[f, 0] <= xmax + grow
                            and ymin - grow <= feats[f, 1] <= ymax + grow):
            return True, ext
    return False, ext


@njit(cache=True)
def _polygon_may_hide(vertices, s, e, R, t, closed, feats, margin):  # pragma: no cover - jit
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
    for f in range(feats.shape[0]):
        if zmin >= feats[f, 2]:
            continue
        if zmin <= 1e-6 or (xmax >= feats[f, 0] - margin and xmin <= feats[f, 0] + margin
                            and ymax >= feats[f, 1] - margin and ymin <= feats[f, 1] + margin):
            return True
    return False


@njit(cache=True)
def _place_cluster(layout, c, pose, ready, vertices):  # pragma: no cover - jit
    """Move cluster ``c``'s polygons (of ``layout``, :class:`ClusterArrays`) to the base frame
    unless done this frame."""
    if not ready[c]:
        place_polygons(layout.local, layout.offsets,
                       layout.cluster_polys[layout.cluster_start[c]:layout.cluster_start[c + 1]],
                       pose, vertices)
        ready[c] = True


@njit(cache=True)
def cull_camera(layout, poses, T_cam_base, points, status, margin, behind, frame,
                bit):  # pragma: no cover - jit
    """Set ``bit`` in ``keep`` (P,) uint8 for the polygons that may hide a feature from one
    camera (exact).

    ``layout``: the surfaces and their clusters (:class:`ClusterArrays`). ``points`` (N, 3):
    the features (base frame), ``status`` their projection status (0: in the image; only those
    count), each standing for query points up to ``behind`` m deeper (the far half of its
    near-occluder ring). ``T_cam_base`` maps base to camera coordinates; ``poses[k]`` =
    ``T_base_obj`` of object k. ``frame`` = ``(vertices, ready, keep)``: the frame's base-frame
    vertex buffer, ``ready[c]`` (cluster c already moved into it this frame) and the ``keep``
    bits. A polygon is kept when it faces the camera (or its solid is open, or the solid's box
    in camera axes, grown by ``contain_margin`` m, holds the optical centre: the camera may be
    inside the solid or on its boundary) and, for some feature, part of it is nearer than the
    feature's depth plus ``behind`` and its normalised bounding box, grown by ``margin``, holds
    the feature's normalised coordinates — or it reaches the camera's focal plane (z <= 1e-6
    m), where its projection is unbounded. A segment from the optical centre to a feature that
    crosses a polygon crosses it at the feature's normalised coordinates, nearer: nothing that
    can hide a feature is dropped. Whole clusters and objects are skipped first by the same
    test on their box (:func:`_box_may_hide`). Polygons are moved to the base frame (into
    ``vertices``) only when looked at.
    """
    vertices, ready, keep = frame
    object_box, object_clusters = layout.object_box, layout.object_clusters
    cluster_polys, cluster_start, offsets = layout.cluster_polys, layout.cluster_start, \
        layout.offsets
    R = T_cam_base[:3, :3]
    t = T_cam_base[:3, 3]
    normalised = np.empty((points.shape[0], 3))
    n_feats = 0
    for i in range(points.shape[0]):
        if status[i] == 0:
            x, y, z = to_camera(R, t, points[i])
            normalised[n_feats, 0], normalised[n_feats, 1] = x / z, y / z
            normalised[n_feats, 2] = z + behind
            n_feats += 1
    feats = normalised[:n_feats]
    T = np.zeros((4, 4))
    for k in range(object_box.shape[0]):
        for r in range(3):  # T = T_cam_obj = T_cam_base @ poses[k]
            for col in range(4):
                T[r, col] = (T_cam_base[r, 0] * poses[k, 0, col]
                             + T_cam_base[r, 1] * poses[k, 1, col]
                             + T_cam_base[r, 2] * poses[k, 2, col])
            T[r, 3] += T_cam_base[r, 3]
        hide, ext = _box_may_hide(T, object_box[k], feats, margin)
        if not hide:
            continue
        closed = layout.object_closed[k]
        m = layout.contain_margin + SLACK
        if closed and (ext[0] <= m and ext[1] <= m and ext[2] <= m
                       and ext[3] >= -m and ext[4] >= -m and ext[5] >= -m):
            closed = _camera_outside(layout, poses[k], object_clusters[k],
                                     object_clusters[k + 1], R, t, vertices, ready)
        for c in range(object_clusters[k], object_clusters[k + 1]):
            if not _box_may_hide(T, layout.cluster_box[c], feats, margin)[0]:
                continue
            _place_cluster(layout, c, poses[k], ready, vertices)
            for i in range(cluster_start[c], cluster_start[c + 1]):
                p = cluster_polys[i]
                if not keep[p] & bit and _polygon_may_hide(vertices, offsets[p], offsets[p + 1],
                                                           R, t, closed, feats, margin):
                    keep[p] |= bit


@njit(cache=True)
def _camera_outside(layout, pose, first, last, R, t, vertices, ready):  # pragma: no cover - jit
    """Whether the box (camera axes) of the vertices of clusters ``first:last`` of ``layout``
    (:class:`ClusterArrays`) misses the optical centre by more than ``layout.contain_margin``
    (moving them to the base frame first)."""
    offsets, cluster_polys, cluster_start = layout.offsets, layout.cluster_polys, \
        layout.cluster_start
    lo0 = lo1 = lo2 = np.inf
    hi0 = hi1 = hi2 = -np.inf
    for c in range(first, last):
        _place_cluster(layout, c, pose, ready, vertices)
        for i in range(cluster_start[c], cluster_start[c + 1]):
            p = cluster_polys[i]
            for j in range(offsets[p], offsets[p + 1]):
                x, y, z = to_camera(R, t, vertices[j])
                lo0, lo1, lo2 = min(lo0, x), min(lo1, y), min(lo2, z)
                hi0, hi1, hi2 = max(hi0, x), max(hi1, y), max(hi2, z)
    m = layout.contain_margin
    return not (lo0 <= m and lo1 <= m and lo2 <= m and hi0 >= -m and hi1 >= -m and hi2 >= -m)

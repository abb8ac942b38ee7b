"""Compiled per-frame kernels of the cell-level predictor: moving the surfaces to the base
frame and culling the surfaces that cannot hide a feature from a camera (exact; see
:mod:`cellsight.occlusion.predictor`)."""

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


@njit(cache=True)
def cull_polygons(vertices, offsets, object_polys, object_closed, T_cam_base, box, margin,
                  contain_margin, keep):  # pragma: no cover - jit
    """Mark in ``keep`` the polygons that may hide a point of the features' box from a camera.

    ``T_cam_base`` maps base to camera coordinates; ``box`` = (xmin, xmax, ymin, ymax, zmax):
    the features' bounds in normalised image coordinates (x/z, y/z) and their largest depth.
    Object ``k`` owns the polygons ``object_polys[k]:object_polys[k + 1]``; ``object_closed[k]``
    says whether it is a closed solid. A polygon is kept when some vertex is nearer than
    ``zmax``, it faces the camera (or its solid is open, or the solid's bounding box in camera
    axes, grown by ``contain_margin`` m, holds the optical centre: the camera may be inside the
    solid or on its boundary, where a line of sight can leave it through a back face) and its
    normalised bounding box overlaps ``box`` grown by ``margin`` — or when it reaches the
    camera's focal plane (z <= 1e-6 m), where its projection is unbounded.
    """
    R = T_cam_base[:3, :3]
    t = T_cam_base[:3, 3]
    for k in range(object_polys.shape[0] - 1):
        first, last = object_polys[k], object_polys[k + 1]
        closed = object_closed[k]
        if closed:  # does the solid's box (camera axes) hold the optical centre (the origin)?
            lo0 = lo1 = lo2 = np.inf
            hi0 = hi1 = hi2 = -np.inf
            for j in range(offsets[first], offsets[last]):
                x, y, z = to_camera(R, t, vertices[j])
                lo0, lo1, lo2 = min(lo0, x), min(lo1, y), min(lo2, z)
                hi0, hi1, hi2 = max(hi0, x), max(hi1, y), max(hi2, z)
            m = contain_margin
            closed = not (lo0 <= m and lo1 <= m and lo2 <= m
                          and hi0 >= -m and hi1 >= -m and hi2 >= -m)
        for p in range(first, last):
            if keep[p]:
                continue
            s, e = offsets[p], offsets[p + 1]
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
            if zmin >= box[4]:
                continue
            if closed and nx * -cx0 + ny * -cy0 + nz * -cz0 <= 0.0:
                continue
            if zmin <= 1e-6:
                keep[p] = True
            elif (xmax >= box[0] - margin and xmin <= box[1] + margin
                  and ymax >= box[2] - margin and ymin <= box[3] + margin):
                keep[p] = True


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

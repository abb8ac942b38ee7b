"""Compiled per-frame kernels every cell-level back-end shares (:mod:`.predictor`): placing
surface vertices in the base frame, projecting the workpiece features into a camera, and
writing a camera's answers as labels. Lengths in metres, pixels as in the image."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from cellsight._camera_kernel import project_point, to_camera


class Answer(NamedTuple):
    """One camera's occlusion answers for the features in its image, as :func:`label_answers`
    reads them: ``query`` (M,) the features' indices into the feature list; ``visible`` and
    ``occluder`` (M + M * n_ring,) for the features, then ``n_ring`` ring points per feature
    (in order; the first half in front of the feature, the second behind it); ``occluder``
    indexes ``polys`` (-1: visible), whose entries index the predictor's polygon list
    (``CellSurfaces.poly_owner``)."""

    query: np.ndarray
    visible: np.ndarray
    occluder: np.ndarray
    polys: np.ndarray
    n_ring: int


@njit(cache=True)
def transform_vertices(local, vertex_owner, moving, poses, out):  # pragma: no cover - jit
    """``out[i] = poses[vertex_owner[i]] @ local[i]`` for the vertex indices in ``moving``."""
    for i in moving:
        T = poses[vertex_owner[i]]
        x, y, z = local[i, 0], local[i, 1], local[i, 2]
        for r in range(3):
            out[i, r] = T[r, 0] * x + T[r, 1] * y + T[r, 2] * z + T[r, 3]


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


@njit(cache=True)
def label_answers(query, vis, occ, polys, n_ring, poly_owner, feature_owner, robot_owned,
                  visible, occluder, near):  # pragma: no cover - jit
    """Write one camera's :class:`Answer` (its five fields, passed one by one: a tuple would
    be typed in Python at each call, 80 us) for its features: sets ``visible``, ``occluder`` (the
    hiding object, an index into the cell's objects, -1 when visible) and ``near``, each (F,)
    over the feature list. ``poly_owner``: the object of each polygon; ``feature_owner``: the
    object of each feature; ``robot_owned`` (bool, per object): a robot's link or tool. A
    visible feature is ``near`` when the first half of its ring (in front of it) has a point
    hidden by an object other than its own, or when the second half (far behind it) meets a
    robot, or more than one thing besides its own object: two objects, or an object and nothing
    (-1), are a silhouette's edge in the background beside it."""
    m = query.shape[0]
    front = n_ring // 2
    for j in range(m):
        i = query[j]
        visible[i] = vis[j]
        occluder[i] = -1 if vis[j] else poly_owner[polys[occ[j]]]
        if not vis[j]:
            continue
        behind = -2  # the first thing met behind besides the feature's own object; -2: none yet
        for r in range(n_ring):
            k = m + j * n_ring + r
            owner = -1 if vis[k] else poly_owner[polys[occ[k]]]
            if owner == feature_owner[i]:
                continue
            if r < front:
                hit = owner >= 0
            elif owner >= 0 and robot_owned[owner]:
                hit = True
            else:
                hit = behind != -2 and owner != behind
                behind = owner
            if hit:
                near[i] = True
                break

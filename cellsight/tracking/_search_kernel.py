"""The whole-image search's compiled scoring (for :mod:`.search`): poses ``(x, y, psi)`` of a
part on its support plane, its feature points projected into one camera and matched against
that camera's distance image, without the (G * F, 3) arrays the same sums need in NumPy.

The same sums as with NumPy arrays (``tests/test_search_kernel.py``, ``bench/bench_search.py``):
the point ``(c px - s py + x, s px + c py + y, pz + z)``, the camera's ``T_cam_base``
(:func:`cellsight._camera_kernel.to_camera`), the distorted projection
(:func:`cellsight._camera_kernel.project_point`), the pixel rounded half to even; each match
in float64 (NumPy divides the float32 distance image in float32).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cellsight._camera_kernel import project_point, to_camera


@njit(cache=True, inline="always")
def _placed(poses, points, z, g, f, c, s):  # pragma: no cover - jit
    """The base-frame point of feature ``f`` with the part at pose ``g`` (``c``, ``s``: the
    cosine and sine of its turn)."""
    px, py = points[f, 0], points[f, 1]
    return (c * px - s * py + poses[g, 0], s * px + c * py + poses[g, 1], points[f, 2] + z)


@njit(cache=True)
def depths(poses, points, z, R, t):  # pragma: no cover - jit
    """(G * F,) m: every placed point's depth in the camera (``R``, ``t`` of ``T_cam_base``),
    pose by pose."""
    n_f = points.shape[0]
    out = np.empty(poses.shape[0] * n_f)
    for g in range(poses.shape[0]):
        c, s = np.cos(poses[g, 2]), np.sin(poses[g, 2])
        for f in range(n_f):
            out[g * n_f + f] = to_camera(R, t, _placed(poses, points, z, g, f, c, s))[2]
    return out


@njit(cache=True)
def scores(poses, points, z, R, t, K, dist, distance, tol, hard):  # pragma: no cover - jit
    """(G,) each pose's score in the camera: per point in front of it and projecting inside
    the image, ``1 - d / tol`` for the ``distance`` image's value ``d <= tol`` (px) at its
    rounded pixel, or 1 per such point (``hard``)."""
    h, w = distance.shape
    out = np.zeros(poses.shape[0])
    for g in range(poses.shape[0]):
        total = 0.0
        c, s = np.cos(poses[g, 2]), np.sin(poses[g, 2])
        for f in range(points.shape[0]):
            x, y, zc = to_camera(R, t, _placed(poses, points, z, g, f, c, s))
            if not zc > 0.0:
                continue
            u, v = project_point(K, dist, x, y, zc)
            if not (np.isfinite(u) and np.isfinite(v)):
                continue
            ui, vi = int(np.rint(u)), int(np.rint(v))
            if ui < 0 or ui >= w or vi < 0 or vi >= h:
                continue
            match = max(0.0, 1.0 - distance[vi, ui] / tol)
            total += (1.0 if match > 0.0 else 0.0) if hard else match
        out[g] = total
    return out

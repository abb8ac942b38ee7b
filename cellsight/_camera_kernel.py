"""Numba twin of :class:`cellsight.camera.Camera`: the camera model for compiled kernels.

Same conventions as :mod:`cellsight.camera` (OpenCV pinhole: camera frame x right, y down,
z forward; pixel (u, v) = (column, row); ``K`` 3x3 in px; ``dist`` = (k1, k2, p1, p2, k3), a
float64 5-vector, zeros for no distortion: ``Camera.dist5``). A change of lens model is made
here and in ``camera.py`` together; ``tests/test_camera.py`` checks that the two agree.

Scalar functions are inlined into their callers (``inline="always"``), so the loops that call
them compile to the same code as a hand-written copy.
"""

from __future__ import annotations

from numba import njit


@njit(cache=True, inline="always")
def to_camera(R, t, v):  # pragma: no cover - jit
    """Camera coordinates (x, y, z) (m) of the base-frame point ``v``, with ``R`` = the
    rotation and ``t`` = the translation of ``T_cam_base``."""
    return (
        R[0, 0] * v[0] + R[0, 1] * v[1] + R[0, 2] * v[2] + t[0],
        R[1, 0] * v[0] + R[1, 1] * v[1] + R[1, 2] * v[2] + t[1],
        R[2, 0] * v[0] + R[2, 1] * v[1] + R[2, 2] * v[2] + t[2],
    )


@njit(cache=True, inline="always")
def project_point(K, dist, x, y, z):  # pragma: no cover - jit
    """Pixel (u, v) of the camera-frame point (x, y, z), z > 0, through the distorted model
    (:meth:`Camera.project_camera`)."""
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    xn, yn = x / z, y / z
    r2 = xn * xn + yn * yn
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
    return K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]


@njit(cache=True, inline="always")
def pinhole_jacobian(K, x, y, z):  # pragma: no cover - jit
    """Ideal pinhole pixel (u, v) of the camera-frame point (x, y, z), z > 0, and its 2x3
    Jacobian ``d(u, v)/d(x, y, z)`` (px/m) as a pair of rows::

        u = fx x/z + s y/z + cx,   v = fy y/z + cy
        J = (1/z) [[fx, s, -(fx x + s y)/z], [0, fy, -fy y/z]]   (x, y here normalised)
    """
    fx, s, cx, fy, cy = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    iz = 1.0 / z
    xn = x * iz
    yn = y * iz
    u = fx * xn + s * yn + cx
    v = fy * yn + cy
    d = ((fx * iz, s * iz, -(fx * xn + s * yn) * iz), (0.0, fy * iz, -fy * yn * iz))
    return u, v, d


@njit(cache=True)
def pinhole_jacobians(K, points, pixels, jac):  # pragma: no cover - jit
    """:func:`pinhole_jacobian` of each camera-frame point (N, 3): ``pixels`` (N, 2) and
    ``jac`` (N, 2, 3) are filled."""
    for i in range(points.shape[0]):
        u, v, d = pinhole_jacobian(K, points[i, 0], points[i, 1], points[i, 2])
        pixels[i, 0], pixels[i, 1] = u, v
        for r in range(2):
            for c in range(3):
                jac[i, r, c] = d[r][c]


"""Rotation vectors and matrices, compiled for the 500 Hz control loop.

SciPy's :class:`~scipy.spatial.transform.Rotation` gives the same numbers (tests check them to
1e-12) but costs 10-20 us a call, three calls a control step. Conventions as SciPy's: a
rotation vector is ``angle * axis`` (rad), ``angle`` in ``[0, pi]``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def rotvec_of_matrix(R: np.ndarray) -> np.ndarray:
    """The rotation vector (3,) of a rotation matrix, through its unit quaternion (Shepperd's
    choice of the largest pivot, so exact at every angle, pi included)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    q = np.empty(4)  # x, y, z, w
    pivots = np.array([R[0, 0], R[1, 1], R[2, 2], tr])
    k = int(np.argmax(pivots))
    if k == 3:
        q[3] = 1.0 + tr
        q[0], q[1], q[2] = R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]
    else:
        i, j, m = k, (k + 1) % 3, (k + 2) % 3
        q[i] = 1.0 - tr + 2.0 * R[i, i]
        q[j] = R[j, i] + R[i, j]
        q[m] = R[m, i] + R[i, m]
        q[3] = R[m, j] - R[j, m]
    q /= np.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    if q[3] < 0.0:
        q = -q
    s = np.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2)
    angle = 2.0 * np.arctan2(s, q[3])
    # angle / sin(angle / 2), by its series where s is tiny
    scale = angle / s if s > 1e-6 else 2.0 / q[3] * (1.0 + s * s / (6.0 * q[3] * q[3]))
    return q[:3] * scale


@njit(cache=True)
def matrix_of_rotvec(w: np.ndarray) -> np.ndarray:
    """The rotation matrix (3, 3) of a rotation vector (Rodrigues' formula; its series below
    1e-6 rad)."""
    theta = np.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2)
    if theta > 1e-6:
        a, b = np.sin(theta) / theta, (1.0 - np.cos(theta)) / (theta * theta)
    else:
        a, b = 1.0 - theta * theta / 6.0, 0.5 - theta * theta / 24.0
    x, y, z = w[0], w[1], w[2]
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + a * K + b * (K @ K)

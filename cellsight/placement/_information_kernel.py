"""Numba kernel of :mod:`.scoring`: the pose information of many cameras' visible features."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def pose_information(R_cb, pc, visible, arms, fx, fy, out):  # pragma: no cover - compiled
    """``out[c]`` (6, 6) = sum over features f visible in camera c of ``m^T m`` for both rows
    ``m = [a, arm_f x a]`` of the pose Jacobian, ``a`` being the pinhole Jacobian row
    (``fx / z, 0, -fx x / z^2`` or ``0, fy / z, -fy y / z^2``) times ``R_cb[c]``.

    ``R_cb`` (C, 3, 3) camera <- base rotations; ``pc`` (C, F, 3) the features in each camera's
    frame (m); ``visible`` (C, F); ``arms`` (F, 3) each feature minus the part's origin (base
    frame, m); ``fx``, ``fy`` (px). Translation first (px^2/m^2), then rotation (px^2/rad^2)."""
    C, F = visible.shape
    m = np.empty(6)
    for c in range(C):
        for i in range(6):
            for j in range(6):
                out[c, i, j] = 0.0
        for f in range(F):
            if not visible[c, f]:
                continue
            x, y, z = pc[c, f, 0], pc[c, f, 1], pc[c, f, 2]
            for row in range(2):
                if row == 0:
                    j0, j1, j2 = fx / z, 0.0, -fx * x / (z * z)
                else:
                    j0, j1, j2 = 0.0, fy / z, -fy * y / (z * z)
                for k in range(3):
                    m[k] = j0 * R_cb[c, 0, k] + j1 * R_cb[c, 1, k] + j2 * R_cb[c, 2, k]
                rx, ry, rz = arms[f, 0], arms[f, 1], arms[f, 2]
                m[3] = ry * m[2] - rz * m[1]
                m[4] = rz * m[0] - rx * m[2]
                m[5] = rx * m[1] - ry * m[0]
                for i in range(6):
                    for j in range(6):
                        out[c, i, j] += m[i] * m[j]

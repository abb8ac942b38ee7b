"""Per-camera pinhole measurement model of a workpiece's feature points, with its Jacobian.

For camera ``c`` (pose ``T_base_cam``, intrinsics ``K``) and a feature with model coordinates
``p_j`` (part frame, m), the measurement is the ideal (undistorted) pinhole pixel::

    p^c = R_cb (o + R(roll, pitch, yaw) p_j) + t_cb        (camera frame, m)
    u   = fx x/z + s y/z + cx,    v = fy y/z + cy            (px)

where ``[R_cb | t_cb] = T_cam_base``, ``o`` is the part position and ``R`` its rotation in the base
frame (state layout in :mod:`cellsight.tracking.motion`). Lens distortion is removed from the
measured pixels (:meth:`Camera.undistort <cellsight.camera.Camera.undistort>`) rather than
modelled here; the pinhole projection and its Jacobian are the camera module's
(:func:`cellsight._camera_kernel.pinhole_jacobian`).

Analytic Jacobian of one point (2x12; the velocity columns are zero)::

    d(u,v)/dp^c   = (1/z) [[fx, s, -(fx x + s y)/z], [0, fy, -fy y/z]]
    dp^c/do       = R_cb
    dp^c/d(rpy)   = -R_cb S(R p_j) E(pitch, yaw)

``S(a)`` is the skew matrix (``S(a) b = a x b``) and ``E`` maps roll-pitch-yaw rates to the
angular velocity in the base frame, for ``R = Rz(yaw) Ry(pitch) Rx(roll)``::

    E = [[cos(yaw) cos(pitch), -sin(yaw), 0],
         [sin(yaw) cos(pitch),  cos(yaw), 0],
         [-sin(pitch),          0,        1]]

Measurement noise: independent pixel noise, ``R = sigma^2 I`` (sigma in px).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from cellsight._camera_kernel import pinhole_jacobian
from cellsight.camera import Camera
from cellsight.tracking.motion import POSE_DIM, POSITION


def rotation_of_state(state: np.ndarray) -> np.ndarray:
    """Rotation ``R_base_part`` (3x3) of a state's roll-pitch-yaw, ``Rz(yaw) Ry(pitch)
    Rx(roll)``: the convention of :func:`cellsight.geometry.transforms.pose_from_xyz_rpy`
    (tests check they agree), written out because SciPy's conversion costs ~30 us per call in
    the per-frame loop."""
    return _rpy_matrix(float(state[3]), float(state[4]), float(state[5]))


@numba.njit(cache=True)
def _rpy_matrix(roll, pitch, yaw):
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def euler_rate_matrix(pitch: float, yaw: float) -> np.ndarray:
    """``E`` (3x3): angular velocity in the base frame = ``E @ [roll, pitch, yaw]`` rates."""
    cp, sp, cy, sy = np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.array([[cy * cp, -sy, 0.0], [sy * cp, cy, 0.0], [-sp, 0.0, 1.0]])


@dataclass(frozen=True)
class PinholeMeasurement:
    """Measurement model of one camera: feature model points -> ideal pinhole pixels.

    ``sigma_px`` is the default pixel noise standard deviation (px); the filter may replace it
    with an adaptive estimate.
    """

    camera: Camera
    sigma_px: float = 0.5

    def __post_init__(self) -> None:
        if not self.sigma_px > 0:
            raise ValueError(f"PinholeMeasurement: sigma_px must be > 0, got {self.sigma_px}")

    def function(
        self, state: np.ndarray, points_model: np.ndarray, rotation: np.ndarray | None = None
    ) -> np.ndarray:
        """Predicted pixels (n, 2) of ``points_model`` (n, 3) for the pose in ``state``.

        ``rotation`` may pass ``R_base_part`` already computed from ``state``.
        """
        return self.evaluate(state, points_model, rotation)[0]

    def evaluate(
        self, state: np.ndarray, points_model: np.ndarray, rotation: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Predicted pixels (n, 2) and the Jacobian (2n, 12) w.r.t. the state.

        Rows are stacked per point: ``[u_0, v_0, u_1, v_1, ...]``. Points must lie in front of
        the camera (z > 0).
        """
        R = rotation_of_state(state) if rotation is None else rotation
        state = np.asarray(state, dtype=np.float64)
        return _evaluate(
            np.ascontiguousarray(points_model, dtype=np.float64).reshape(-1, 3),
            np.ascontiguousarray(R, dtype=np.float64),
            state[POSITION].copy(),
            self.camera.T_cam_base,
            self.camera.K,
            euler_rate_matrix(state[4], state[5]),
        )


@numba.njit(cache=True)
def _evaluate(pts, R, o, T_cam_base, K, E):
    """Pixels (n, 2) and Jacobian (2n, 12) of the module docstring's model."""
    n = len(pts)
    pix = np.empty((n, 2))
    J = np.zeros((2 * n, 12))
    Rcb = T_cam_base[:3, :3]
    q = np.empty(3)
    pc = np.empty(3)
    for j in range(n):
        for a in range(3):  # q = R p_j (base frame), pc = R_cb (o + q) + t_cb
            q[a] = R[a, 0] * pts[j, 0] + R[a, 1] * pts[j, 1] + R[a, 2] * pts[j, 2]
        for a in range(3):
            pc[a] = T_cam_base[a, 3]
            for b in range(3):
                pc[a] += Rcb[a, b] * (o[b] + q[b])
        pix[j, 0], pix[j, 1], d = pinhole_jacobian(K, pc[0], pc[1], pc[2])
        for r in range(2):
            row = 2 * j + r
            g0 = d[r][0] * Rcb[0, 0] + d[r][1] * Rcb[1, 0] + d[r][2] * Rcb[2, 0]
            g1 = d[r][0] * Rcb[0, 1] + d[r][1] * Rcb[1, 1] + d[r][2] * Rcb[2, 1]
            g2 = d[r][0] * Rcb[0, 2] + d[r][1] * Rcb[1, 2] + d[r][2] * Rcb[2, 2]
            J[row, 0] = g0
            J[row, 1] = g1
            J[row, 2] = g2
            # -(g x q) E: angular part
            c0 = -(g1 * q[2] - g2 * q[1])
            c1 = -(g2 * q[0] - g0 * q[2])
            c2 = -(g0 * q[1] - g1 * q[0])
            for k in range(3):
                J[row, 3 + k] = c0 * E[0, k] + c1 * E[1, k] + c2 * E[2, k]
    return pix, J


@dataclass(frozen=True)
class Observation:
    """Pixels of some features of one workpiece measured in one camera.

    ``pixels`` (n, 2) are ideal pinhole pixels (distortion removed); ``points_model`` (n, 3) are
    the features' model coordinates (part frame, m); ``feature_ids`` (n,) their indices;
    ``lag_s``: how long before the filter's time (s) the camera was exposed (its trigger
    skew): the filter measures the pose it had then (:meth:`exposed_state`).
    """

    model: PinholeMeasurement
    camera_index: int
    feature_ids: np.ndarray
    points_model: np.ndarray
    pixels: np.ndarray
    lag_s: float = 0.0

    def evaluate(self, state: np.ndarray,
                 rotation: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Predicted pixels (n, 2) and Jacobian (2n, 12) at the filter's ``state`` of the
        features as exposed ``lag_s`` earlier: the pose moved back along its velocity
        (:meth:`exposed_state`; the process noise over the lag, a few milliseconds, is
        neglected). The Jacobian is the pose's alone (its velocity columns zero, as without a
        lag): the filter learns no velocity from the lag. With the lag's own ``-lag_s`` times
        the pose columns it would, and two cameras exposed a few milliseconds apart that
        disagree by the few pixels calibrated cameras do would show a still part moving at
        centimetres per second (measured: 15-30 mm/s on `harsh` runs, which the grasp
        followed). ``rotation``: the state's ``R_base_part``, when the caller has it (used
        without a lag)."""
        if self.lag_s == 0.0:
            return self.model.evaluate(state, self.points_model, rotation)
        return self.model.evaluate(self.exposed_state(state), self.points_model)

    def exposed_state(self, state: np.ndarray) -> np.ndarray:
        """The state (12,) moved back ``lag_s`` seconds at its own velocity."""
        out = np.array(state, dtype=float)
        out[:POSE_DIM] -= self.lag_s * out[POSE_DIM:]
        return out


"""Constant-velocity motion model of a workpiece pose (the EKF's transition model).

State vector ``w`` (12,), base frame, SI units::

    w = [x, y, z, roll, pitch, yaw, vx, vy, vz, roll_rate, pitch_rate, yaw_rate]

position of the part frame's origin in the base frame (m), roll-pitch-yaw of ``R_base_part``
(rad, ``R = Rz(yaw) Ry(pitch) Rx(roll)``, see :mod:`cellsight.geometry.transforms`) and their
time derivatives (m/s, rad/s).

Transition over ``dt`` seconds: ``w_k = A w_{k-1} + g_k`` with ``A = [[I6, dt I6], [0, I6]]`` and
``g_k ~ N(0, Q)``. ``Q`` is the continuous white-acceleration model, per axis
``q [[dt^3/3, dt^2/2], [dt^2/2, dt]]``, with spectral density ``q_linear`` (m^2/s^3) on the three
position axes and ``q_angular`` (rad^2/s^3) on the three angles. Over one second an unmodelled
acceleration changes the velocity by about ``sqrt(q)`` (m/s or rad/s, one sigma).

The model is an object separate from the filter (Stone Soup style): the filter asks it for
``matrix(dt)`` and ``covar(dt)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STATE_DIM = 12
POSE_DIM = 6
POSITION, ANGLES = slice(0, 3), slice(3, 6)  # the state's parts: m, rad (roll, pitch, yaw)
VELOCITY, ANGLE_RATES = slice(6, 9), slice(9, 12)  # m/s, rad/s


@dataclass(frozen=True)
class ConstantVelocity:
    """Constant-velocity pose model with white-acceleration process noise.

    ``q_linear`` (m^2/s^3) and ``q_angular`` (rad^2/s^3) are the acceleration spectral densities.
    The defaults suit a part carried by a conveyor or by a robot's smooth moves (velocity
    changes of about 0.1 m/s and 0.2 rad/s per second); raise them for faster parts, at the
    price of noisier estimates. (With 0.003, the built-in cell's held part lagged up to 8 mm
    in depth while a single camera saw it being lifted.)
    """

    q_linear: float = 0.01
    q_angular: float = 0.05

    def __post_init__(self) -> None:
        if not (self.q_linear >= 0 and self.q_angular >= 0):
            raise ValueError(
                f"ConstantVelocity: spectral densities must be >= 0, got q_linear={self.q_linear}, "
                f"q_angular={self.q_angular}"
            )

    def matrix(self, dt: float) -> np.ndarray:
        """Transition matrix ``A`` (12x12) over ``dt`` seconds."""
        A = np.eye(STATE_DIM)
        A[:POSE_DIM, POSE_DIM:] = dt * np.eye(POSE_DIM)
        return A

    def covar(self, dt: float) -> np.ndarray:
        """Process noise covariance ``Q`` (12x12) over ``dt`` seconds."""
        q = np.array([self.q_linear] * 3 + [self.q_angular] * 3)
        Q = np.zeros((STATE_DIM, STATE_DIM))
        idx = np.arange(POSE_DIM)
        Q[idx, idx] = q * dt**3 / 3.0
        Q[idx, idx + POSE_DIM] = q * dt**2 / 2.0
        Q[idx + POSE_DIM, idx] = q * dt**2 / 2.0
        Q[idx + POSE_DIM, idx + POSE_DIM] = q * dt
        return Q

    def function(self, state: np.ndarray, dt: float) -> np.ndarray:
        """Propagate a state (12,) over ``dt`` seconds without noise."""
        state = np.asarray(state, dtype=float)
        out = state.copy()
        out[:POSE_DIM] += dt * state[POSE_DIM:]
        return out

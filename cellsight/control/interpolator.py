"""Second-order interpolating filter: 26 Hz pose targets in, smooth 500 Hz set-points out.

The planner hands over a target pose with its twist and acceleration at the vision rate.
Between two updates the reference moves on with them (second-order hold: constant
acceleration), and the output follows the reference through a second-order filter, per
component of the position and of the rotation-vector error::

    a = a_ref + wn^2 (p_ref - p) + 2 zeta wn (v_ref - v)                 position
    alpha = alpha_ref + wn^2 rotvec(R_ref R^T) + 2 zeta wn (w_ref - w)   orientation

integrated with semi-implicit Euler at ``dt``. The output velocity is continuous; the output
acceleration jumps at an update only by ``wn^2`` times the jump of the reference position plus
``2 zeta wn`` times that of its velocity, which the hold keeps small when the targets are
consistent. A reference that follows its own velocity and acceleration (a planned trajectory) is
reproduced without lag; a jump of the reference (a new goal, a noisy estimate) is smoothed,
without overshoot when ``zeta = 1`` (critically damped). Poses are ``T_base_tcp`` 4x4 matrices;
twists (linear m/s, angular rad/s) and accelerations (m/s^2, rad/s^2) are in the base frame.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cellsight.control._rotations import matrix_of_rotvec, rotvec_of_matrix
from cellsight.rates import CONTROL_HZ


class InterpolatingFilter:
    """Critically damped (by default) second-order filter on a pose, stepped at ``dt`` (s).

    ``natural_frequency`` wn in rad/s, ``damping`` zeta (dimensionless). Call :meth:`reset`
    once with the current pose, :meth:`set_target` at the planner rate and :meth:`step` at the
    control rate.
    """

    def __init__(self, natural_frequency: float = 10.0, damping: float = 1.0,
                 dt: float = 1 / CONTROL_HZ) -> None:
        if natural_frequency <= 0 or damping <= 0 or dt <= 0:
            raise ValueError(
                f"InterpolatingFilter: natural_frequency, damping and dt must be positive, got "
                f"{natural_frequency}, {damping}, {dt}")
        if natural_frequency * dt > 0.2:
            raise ValueError(f"InterpolatingFilter: natural_frequency * dt = "
                             f"{natural_frequency * dt:.3g} is too coarse (keep it under 0.2)")
        self.natural_frequency = float(natural_frequency)
        self.damping = float(damping)
        self.dt = float(dt)
        self._T = np.eye(4)
        self._twist = np.zeros(6)
        self._T_ref = np.eye(4)
        self._twist_ref = np.zeros(6)
        self._accel_ref = np.zeros(6)

    def reset(self, T: np.ndarray, twist: np.ndarray | None = None) -> None:
        """Set output and reference to the pose ``T`` with velocity ``twist`` (default zero)."""
        self._T = np.array(T, dtype=float)
        self._twist = np.zeros(6) if twist is None else np.array(twist, dtype=float)
        self.set_target(T, twist)

    def set_target(self, T: np.ndarray, twist: np.ndarray | None = None,
                   accel: np.ndarray | None = None) -> None:
        """New reference: pose ``T`` with ``twist`` and ``accel`` (default zero), held until
        the next update."""
        self._T_ref = np.array(T, dtype=float)
        self._twist_ref = np.zeros(6) if twist is None else np.array(twist, dtype=float)
        self._accel_ref = np.zeros(6) if accel is None else np.array(accel, dtype=float)

    def step(self) -> tuple[np.ndarray, np.ndarray]:
        """Advance by ``dt``: the output for ``dt`` after the state's time (the time of the last
        :meth:`set_target` or :meth:`reset`, plus ``dt`` per step since); copies."""
        _filter_step(self._T, self._twist, self._T_ref, self._twist_ref, self._accel_ref,
                     self.dt, self.natural_frequency, self.damping)
        return self._T.copy(), self._twist.copy()


@njit(cache=True)
def _filter_step(T, twist, T_ref, twist_ref, accel_ref, dt, wn, zeta):
    """One step of the module docstring's filter, in place on the output ``T``, ``twist`` and
    the held reference ``T_ref``, ``twist_ref`` (``accel_ref`` constant)."""
    error = np.empty(6)
    error[:3] = T_ref[:3, 3] - T[:3, 3]
    error[3:] = rotvec_of_matrix(np.ascontiguousarray(T_ref[:3, :3])
                                 @ np.ascontiguousarray(T[:3, :3].T))
    accel = accel_ref + wn * wn * error + 2.0 * zeta * wn * (twist_ref - twist)
    twist += accel * dt
    twist_ref += accel_ref * dt
    T[:3, 3] += twist[:3] * dt
    T_ref[:3, 3] += twist_ref[:3] * dt
    T[:3, :3] = matrix_of_rotvec(twist[3:] * dt) @ np.ascontiguousarray(T[:3, :3])
    T_ref[:3, :3] = matrix_of_rotvec(twist_ref[3:] * dt) @ np.ascontiguousarray(T_ref[:3, :3])

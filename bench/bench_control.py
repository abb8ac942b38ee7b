"""The 500 Hz control loop's two steps, per call, on the built-in cell's R7AX.

Every control period the task steps the interpolating filter (``InterpolatingFilter.step``)
and the CLIK (``Clik.step``): 24,000 times each in experiment 3. Compared, median of
``CALLS`` calls (µs):

- the filter's compiled step against the same step written with SciPy's ``Rotation`` (the
  module docstring's equations; the implementation before it was compiled), run side by side
  from the same state, and the largest difference of their outputs;
- the compiled rotation vector of a matrix against SciPy's ``Rotation.from_matrix(...)
  .as_rotvec()``;
- the CLIK step (forward kinematics, Jacobian, damped least squares).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation
from timing import warm_median_s

from cellsight import load_cell
from cellsight.control import Clik, InterpolatingFilter
from cellsight.control._rotations import rotvec_of_matrix
from cellsight.geometry.transforms import make_pose

CALLS = 3000


def _median_us(fn) -> float:
    return 1e6 * warm_median_s(fn, CALLS, warmup=50)


class ScipyFilter:
    """The interpolating filter's step with SciPy's rotations (the reference)."""

    def __init__(self, T: np.ndarray, T_ref: np.ndarray, twist_ref: np.ndarray, wn: float,
                 zeta: float, dt: float) -> None:
        self.T, self.twist = T.copy(), np.zeros(6)
        self.T_ref, self.twist_ref, self.accel_ref = T_ref.copy(), twist_ref.copy(), np.zeros(6)
        self.wn, self.zeta, self.dt = wn, zeta, dt

    def step(self) -> np.ndarray:
        dt, wn, zeta = self.dt, self.wn, self.zeta
        turn = Rotation.from_matrix(self.T_ref[:3, :3] @ self.T[:3, :3].T, assume_valid=True)
        error = np.concatenate([self.T_ref[:3, 3] - self.T[:3, 3], turn.as_rotvec()])
        accel = self.accel_ref + wn * wn * error + 2.0 * zeta * wn * (self.twist_ref - self.twist)
        self.twist += accel * dt
        self.twist_ref += self.accel_ref * dt
        self.T[:3, 3] += self.twist[:3] * dt
        self.T_ref[:3, 3] += self.twist_ref[:3] * dt
        turns = Rotation.from_rotvec([self.twist[3:] * dt, self.twist_ref[3:] * dt]).as_matrix()
        self.T[:3, :3] = turns[0] @ self.T[:3, :3]
        self.T_ref[:3, :3] = turns[1] @ self.T_ref[:3, :3]
        return self.T


def main() -> None:
    cell = load_cell()
    robot = cell.robot("R7AX")
    q = np.clip(np.zeros(robot.chain.n), robot.chain.qlim[:, 0], robot.chain.qlim[:, 1])
    T0 = robot.tcp_pose(q)
    goal = make_pose(Rotation.from_rotvec([0.2, -0.1, 0.3]).as_matrix() @ T0[:3, :3],
                     T0[:3, 3] + [0.05, -0.02, 0.03])
    twist = np.array([0.01, 0.0, -0.005, 0.0, 0.02, 0.0])
    ours = InterpolatingFilter()
    ours.reset(T0)
    ours.set_target(goal, twist)
    peer = ScipyFilter(T0, goal, twist, ours.natural_frequency, ours.damping, ours.dt)
    worst = 0.0
    for _ in range(500):  # the same 1 s from the same state: the same outputs
        worst = max(worst, float(np.abs(ours.step()[0] - peer.step()).max()))
    t_ours, t_peer = _median_us(ours.step), _median_us(peer.step)
    R = Rotation.from_rotvec([0.3, -1.2, 0.7]).as_matrix()
    t_rot = _median_us(lambda: rotvec_of_matrix(R))
    t_rot_peer = _median_us(lambda: Rotation.from_matrix(R).as_rotvec())
    clik = Clik(robot)
    T, tw = ours.step()
    t_clik = _median_us(lambda: clik.step(q, T, tw, ours.dt))
    print(f"interpolating filter step: {t_ours:.1f} us compiled, {t_peer:.1f} us with SciPy "
          f"({t_peer / t_ours:.1f}x); outputs differ by at most {worst:.1e} over 500 steps")
    print(f"rotation vector of a matrix: {t_rot:.2f} us compiled, {t_rot_peer:.1f} us SciPy "
          f"({t_rot_peer / t_rot:.1f}x)")
    print(f"CLIK step (R7AX, 7 joints): {t_clik:.1f} us; a control step (both) "
          f"{t_ours + t_clik:.1f} us, against {t_peer + t_clik:.1f} us with SciPy's filter")


if __name__ == "__main__":
    main()

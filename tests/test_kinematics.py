"""DH forward kinematics and Jacobian against independent formulations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from cellsight import load_cell
from cellsight.errors import KinematicsError
from cellsight.kinematics import DHChain, DHLink


def _twist_hat(axis: np.ndarray, point: np.ndarray, prismatic: bool) -> np.ndarray:
    """4x4 se(3) matrix of a unit screw: rotation about ``axis`` through ``point``, or a
    translation along ``axis``."""
    S = np.zeros((4, 4))
    if prismatic:
        S[:3, 3] = axis
    else:
        w = axis
        S[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
        S[:3, 3] = -np.cross(w, point)
    return S


def _poe_fkine(chain: DHChain, q: np.ndarray) -> np.ndarray:
    """End frame by the product of exponentials (space form), with the screws read off the
    zero configuration built from elementary rotations/translations. Independent of fkine."""

    def rot(axis, angle):
        c, s = np.cos(angle), np.sin(angle)
        R = np.eye(4)
        i, j = {"x": (1, 2), "z": (0, 1)}[axis]
        R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
        return R

    def trans(axis, dist):
        T = np.eye(4)
        T["xyz".index(axis), 3] = dist
        return T

    frames = [np.eye(4)]
    for lk in chain.links:
        frames.append(frames[-1] @ rot("z", lk.theta) @ trans("z", lk.d) @ trans("x", lk.a)
                      @ rot("x", lk.alpha))
    T = np.eye(4)
    for i, lk in enumerate(chain.links):
        S = _twist_hat(frames[i][:3, 2], frames[i][:3, 3], lk.kind == "prismatic")
        T = T @ expm(S * q[i])
    return T @ frames[-1]


@pytest.mark.parametrize("robot", ["R7AX", "R6AX"])
def test_fkine_matches_product_of_exponentials(robot: str) -> None:
    chain = load_cell().robot(robot).chain
    rng = np.random.default_rng(1)
    for _ in range(1000):
        q = chain.random_q(rng)
        np.testing.assert_allclose(chain.fkine(q)[-1], _poe_fkine(chain, q), atol=1e-9)


def test_fkine_planar_and_cylindrical_closed_forms() -> None:
    planar = DHChain([DHLink(a=0.7), DHLink(a=0.5), DHLink(a=0.2)])
    cylindrical = DHChain([
        DHLink(d=0.3),  # revolute about z
        DHLink(kind="prismatic", alpha=-np.pi / 2, qlim=(0.0, 1.0)),  # lift along z
        DHLink(kind="prismatic", qlim=(0.0, 0.8)),  # reach along the arm
    ])
    rng = np.random.default_rng(2)
    for _ in range(1000):
        q = rng.uniform(-np.pi, np.pi, 3)
        s1, s12, s123 = q[0], q[0] + q[1], q.sum()
        x = 0.7 * np.cos(s1) + 0.5 * np.cos(s12) + 0.2 * np.cos(s123)
        y = 0.7 * np.sin(s1) + 0.5 * np.sin(s12) + 0.2 * np.sin(s123)
        T = planar.fkine(q)
        assert T.shape == (4, 4, 4)
        np.testing.assert_allclose(T[-1][:3, 3], [x, y, 0.0], atol=1e-9)
        np.testing.assert_allclose(T[-1][:2, 0], [np.cos(s123), np.sin(s123)], atol=1e-9)

        qc = np.array([rng.uniform(-np.pi, np.pi), rng.uniform(0, 1), rng.uniform(0, 0.8)])
        # closed form: lift qc[1] along z, then reach qc[2] along y of frame 1 (z of frame 2)
        Tc = cylindrical.fkine(qc)[-1]
        direction = np.array([-np.sin(qc[0]), np.cos(qc[0]), 0.0])
        expected = np.array([0.0, 0.0, 0.3 + qc[1]]) + qc[2] * direction
        np.testing.assert_allclose(Tc[:3, 3], expected, atol=1e-9)


@pytest.mark.parametrize("robot", ["R7AX", "R6AX"])
def test_jacobian_matches_finite_differences(robot: str) -> None:
    chain = load_cell().robot(robot).chain
    rng = np.random.default_rng(3)
    h = 1e-6
    for _ in range(50):
        q = chain.random_q(rng)
        J = chain.jacobian(q)
        T0 = chain.fkine(q)[-1]
        for i in range(chain.n):
            dq = np.zeros(chain.n)
            dq[i] = h
            T1 = chain.fkine(q + dq)[-1]
            np.testing.assert_allclose((T1[:3, 3] - T0[:3, 3]) / h, J[:3, i], atol=1e-5)
            dR = (T1[:3, :3] - T0[:3, :3]) / h @ T0[:3, :3].T
            omega = np.array([dR[2, 1], dR[0, 2], dR[1, 0]])
            np.testing.assert_allclose(omega, J[3:, i], atol=1e-5)


def test_bad_joint_vectors_are_rejected_with_the_joint_named() -> None:
    chain = load_cell().robot("R6AX").chain
    with pytest.raises(KinematicsError, match="expected 6 joint values, got 5"):
        chain.fkine(np.zeros(5))
    with pytest.raises(KinematicsError, match=r"joint 3 is not finite \(q\[2\] = nan\)"):
        chain.fkine([0, 0, np.nan, 0, 0, 0])
    with pytest.raises(KinematicsError, match="joint 2 = 3 outside its limits"):
        chain.check_q([0, 3.0, 0, 0, 0, 0], check_limits=True)
    with pytest.raises(KinematicsError, match="revolute"):
        DHLink(kind="spherical")  # type: ignore[arg-type]

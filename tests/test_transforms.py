"""Roll-pitch-yaw conversions written out (cellsight.geometry.transforms) against SciPy's."""

import math
import warnings

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from cellsight.geometry.transforms import (
    GIMBAL_LOCK,
    RPY_SEQUENCE,
    pose_from_xyz_rpy,
    xyz_rpy_from_pose,
)

angle = st.floats(-math.pi, math.pi, allow_nan=False)
pitch = st.floats(-math.pi / 2, math.pi / 2, allow_nan=False)
coordinate = st.floats(-10.0, 10.0, allow_nan=False)


def _wrapped(a: np.ndarray) -> np.ndarray:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


@settings(max_examples=300, deadline=None)
@given(st.tuples(coordinate, coordinate, coordinate), angle, pitch, angle)
def test_pose_from_rpy_is_scipys_matrix(xyz, roll, pitch_, yaw):
    T = pose_from_xyz_rpy(xyz, [roll, pitch_, yaw])
    R = Rotation.from_euler(RPY_SEQUENCE, [roll, pitch_, yaw]).as_matrix()
    assert np.allclose(T[:3, :3], R, rtol=0.0, atol=1e-14)
    assert np.array_equal(T[:3, 3], xyz) and np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0])


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_rpy_of_any_rotation_is_scipys(seed):
    """Random rotations (uniform on SO(3)), and the same turned near the gimbal lock."""
    R = Rotation.random(random_state=seed)
    near_lock = Rotation.from_euler("y", math.pi / 2 - 10.0 ** -(seed % 9)) * R
    for rotation in (R, near_lock):
        T = np.eye(4)
        T[:3, :3] = rotation.as_matrix()
        T[:3, 3] = [0.1, -0.2, 0.3]
        xyz, rpy = xyz_rpy_from_pose(T)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # SciPy warns of the gimbal lock
            expected = Rotation.from_matrix(T[:3, :3]).as_euler(RPY_SEQUENCE)
        assert np.array_equal(xyz, T[:3, 3])
        # both describe the matrix; away from the lock they are the same numbers
        back = pose_from_xyz_rpy(xyz, rpy)
        assert np.allclose(back[:3, :3], T[:3, :3], rtol=0.0, atol=1e-7)
        if math.cos(expected[1]) > 1e-3:
            assert np.allclose(_wrapped(rpy - expected), 0.0, rtol=0.0, atol=1e-11)
        assert abs(rpy[1]) <= math.pi / 2 and np.all(np.abs(rpy) <= math.pi)


def test_at_the_gimbal_lock_scipy_splits_the_turn():
    for p in (math.pi / 2, -math.pi / 2, math.pi / 2 - GIMBAL_LOCK / 10):
        T = pose_from_xyz_rpy([0.0, 0.0, 0.0], [0.4, p, -0.3])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # SciPy warns of the gimbal lock
            _, rpy = xyz_rpy_from_pose(T)
        assert rpy[2] == 0.0  # SciPy's choice
        assert np.allclose(pose_from_xyz_rpy([0, 0, 0], rpy)[:3, :3], T[:3, :3], atol=1e-7)


def test_a_nan_pose_gives_nan_angles():
    T = np.eye(4)
    T[0, 0] = np.nan
    _, rpy = xyz_rpy_from_pose(T)
    assert np.isnan(rpy).any()

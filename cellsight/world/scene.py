"""The MuJoCo state the world's parts share: what they write (joint values, jaw openings,
workpiece poses) and the body and site poses MuJoCo computes from it.

Writes only mark the state stale; :meth:`Scene.sync` runs MuJoCo's forward kinematics
(``mj_kinematics``) before the next read, so a control step that writes many things computes
the poses once.
"""

from __future__ import annotations

import mujoco
import numpy as np


def pose_of(xpos: np.ndarray, xmat: np.ndarray) -> np.ndarray:
    """4x4 pose from MuJoCo's position (3,) and row-major rotation matrix (9,)."""
    T = np.eye(4)
    T[:3, :3] = xmat.reshape(3, 3)
    T[:3, 3] = xpos
    return T


class Scene:
    """A MuJoCo model and its data, with the stale flag of the module docstring."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self.model = model
        self.data = data
        mujoco.mj_forward(model, data)  # also places the fixed cameras and lights
        self._stale = False

    def sync(self) -> None:
        """Bring MuJoCo's body, geom, site and camera poses up to date with the writes."""
        if self._stale:
            mujoco.mj_kinematics(self.model, self.data)
            self._stale = False

    def step(self) -> None:
        """Integrate MuJoCo's dynamics over one timestep (``mj_step``: actuators, contacts);
        the poses it leaves are those before the step, so they are stale."""
        mujoco.mj_step(self.model, self.data)
        self._stale = True

    def set_qpos(self, addresses: np.ndarray | list[int], values: np.ndarray | float) -> None:
        """Write joint positions (rad or m) at ``qpos`` addresses."""
        self.data.qpos[addresses] = values
        self._stale = True

    def set_mocap(self, mocap_id: int, T: np.ndarray) -> None:
        """Place a mocap body (a workpiece) at pose ``T`` (4x4, base frame)."""
        self.data.mocap_pos[mocap_id] = T[:3, 3]
        mujoco.mju_mat2Quat(self.data.mocap_quat[mocap_id], np.ascontiguousarray(T[:3, :3]).ravel())
        self._stale = True

    def move_camera(self, name: str, T_base_cam: np.ndarray) -> None:
        """Put the fixed camera ``name`` at the OpenCV camera pose ``T_base_cam`` (its MJCF
        orientation: :func:`~cellsight.world.mjcf.mjcf_camera`)."""
        cid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, name)
        R = np.asarray(T_base_cam, dtype=float)[:3, :3] @ np.diag([1.0, -1.0, -1.0])
        self.model.cam_pos[cid] = np.asarray(T_base_cam, dtype=float)[:3, 3]
        mujoco.mju_mat2Quat(self.model.cam_quat[cid], np.ascontiguousarray(R).ravel())
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)  # cameras: not in mj_kinematics
        self._stale = False

    def body_pose(self, body_id: int) -> np.ndarray:
        """``T_base_body`` (4x4), up to date."""
        self.sync()
        return pose_of(self.data.xpos[body_id], self.data.xmat[body_id])

    def body_poses(self, body_ids: np.ndarray) -> np.ndarray:
        """``T_base_body`` of several bodies, (n, 4, 4), up to date."""
        self.sync()
        T = np.zeros((len(body_ids), 4, 4))
        T[:, :3, :3] = self.data.xmat[body_ids].reshape(-1, 3, 3)
        T[:, :3, 3] = self.data.xpos[body_ids]
        T[:, 3, 3] = 1.0
        return T

    def site_pose(self, site_id: int) -> np.ndarray:
        """``T_base_site`` (4x4), up to date."""
        self.sync()
        return pose_of(self.data.site_xpos[site_id], self.data.site_xmat[site_id])

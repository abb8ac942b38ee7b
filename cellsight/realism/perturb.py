"""The world's own cell: the cell file's, with the errors a real cell has against its model.

Pure functions of a nominal :class:`~cellsight.model.Cell` and drawn numbers (SI units: m, rad):
the cameras' extrinsics and intrinsics, the robots' bases and link lengths, the gripper's and
the part's sizes (each solid scaled along its own axes about its frame's origin, so that faces
stay planar), the part's start pose, and the static objects' heights (a table or a conveyor
higher or lower than the cell file says, with the part that rests on it). The nominal cell is
never changed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from cellsight.camera import Camera
from cellsight.geometry.polyhedron import Polyhedron
from cellsight.geometry.transforms import make_pose
from cellsight.kinematics import DHChain, KinematicChain, SerialChain
from cellsight.model import Cell
from cellsight.model.cell import StaticObject, Workpiece
from cellsight.model.landing import Landing
from cellsight.model.robot import Robot


def small_pose(position: np.ndarray, rotvec: np.ndarray) -> np.ndarray:
    """A pose from a translation (3,) m and a rotation vector (3,) rad."""
    return make_pose(Rotation.from_rotvec(rotvec).as_matrix(), position)


@dataclass(frozen=True)
class CameraError:
    """One camera's errors, as a calibration leaves them. The intrinsics are off by ``focal``
    (relative, fx and fy), ``principal`` (2,) px and ``k1`` (added to its distortion); the
    hand-eye calibration, done with those intrinsics and fitted to points in the work area,
    turns the camera about its optical centre so that the ``work_point`` (base frame) still
    projects where the cell file says, and leaves its own error: ``position`` (3,) m at the work
    point, along the camera's axes, and ``rotation`` (3,) rad, a rotation vector in the
    camera's axes turning the camera about the work point. So the error is smallest in the work
    area and grows away from it, as a calibration's does."""

    position: np.ndarray
    rotation: np.ndarray
    work_point: np.ndarray
    focal: float
    principal: np.ndarray
    k1: float

    def moved(self, T_base_cam: np.ndarray, K: np.ndarray, K_built: np.ndarray) -> np.ndarray:
        """The camera's pose as built (``T_base_cam`` as calibrated, with intrinsics ``K``;
        ``K_built`` the camera's own)."""
        T_base_cam = T_base_cam @ make_pose(_absorbing(T_base_cam, K, K_built, self.work_point))
        R_cam = T_base_cam[:3, :3]
        R = R_cam @ Rotation.from_rotvec(self.rotation).as_matrix() @ R_cam.T
        c = self.work_point
        return make_pose(R, c - R @ c + R_cam @ self.position) @ T_base_cam


def _absorbing(T_base_cam: np.ndarray, K: np.ndarray, K_built: np.ndarray,
               work_point: np.ndarray) -> np.ndarray:
    """The rotation (camera frame) that makes a camera with intrinsics ``K_built`` see the
    work point where one with ``K`` at ``T_base_cam`` sees it (what a calibration with the
    wrong intrinsics does to the extrinsics)."""
    p = np.linalg.inv(T_base_cam)[:3] @ np.append(work_point, 1.0)
    pixel = K @ (p / p[2])
    seen = np.linalg.solve(K_built, pixel)
    R, _ = Rotation.align_vectors([p / np.linalg.norm(p)], [seen / np.linalg.norm(seen)])
    return R.as_matrix()


def camera_as_built(camera: Camera, err: CameraError) -> Camera:
    """The camera as the world has it (the camera itself when ``err`` is all zero)."""
    if not (np.any(err.position) or np.any(err.rotation) or err.focal or np.any(err.principal)
            or err.k1):
        return camera
    K = camera.K.copy()
    K[0, 0] *= 1.0 + err.focal
    K[1, 1] *= 1.0 + err.focal
    K[0, 2] += err.principal[0]
    K[1, 2] += err.principal[1]
    dist = camera.dist
    if err.k1 != 0.0:
        dist = np.zeros(5) if dist is None else np.array(dist, dtype=float)
        dist[0] += err.k1
    T = err.moved(camera.T_base_cam, camera.K, K)
    return Camera(K, camera.width, camera.height, T, dist, camera.name)


@dataclass(frozen=True)
class RobotError:
    """One robot's errors: ``base`` (4x4, in its own frame 0: ``T_base_robot @ base``),
    ``links`` (n, 3) m: per joint, the DH (a, d, -) changes or the URDF origin's shift, and
    ``gripper_scale`` (3,) relative sizes of its palm and jaws."""

    base: np.ndarray
    links: np.ndarray
    gripper_scale: np.ndarray


def chain_as_built(chain: KinematicChain, links: np.ndarray) -> KinematicChain:
    """The chain with its link lengths changed by ``links`` (n, 3) m (:class:`RobotError`)."""
    if isinstance(chain, DHChain):
        return DHChain([replace(lk, a=lk.a + dl[0], d=lk.d + dl[1])
                        for lk, dl in zip(chain.links, links, strict=True)], chain.name)
    if isinstance(chain, SerialChain):
        origins = chain.origins.copy()
        origins[:, :3, 3] += links
        return SerialChain(origins, chain.axes, chain.kinds, chain.qlim, chain.name,
                           chain.link_names, chain.joint_names)
    raise TypeError(f"no link errors for a {type(chain).__name__}")


def scaled(solid: Polyhedron, scale: np.ndarray) -> Polyhedron:
    """The solid scaled by ``scale`` (3,) along its own axes (validated again)."""
    if np.all(scale == 1.0):
        return solid
    return solid.transformed(np.diag([*scale, 1.0]))


def robot_as_built(robot: Robot, err: RobotError) -> Robot:
    """The robot as the world has it (the robot itself when ``err`` is all zero)."""
    if (np.array_equal(err.base, np.eye(4)) and not np.any(err.links)
            and np.all(err.gripper_scale == 1.0)):
        return robot
    tool = robot.tool
    if tool is not None:
        tool = replace(tool, palm=tuple(scaled(s, err.gripper_scale) for s in tool.palm))
        tool = tool.with_jaw_solids(tuple(scaled(j.solid, err.gripper_scale) for j in tool.jaws))
    return replace(robot, T_base_robot=robot.T_base_robot @ err.base,
                   chain=chain_as_built(robot.chain, err.links), tool=tool)


def size_scale(solid: Polyhedron, change_m: np.ndarray) -> np.ndarray:
    """Per-axis scale that changes the solid's extent along its axes by ``change_m`` (3,) m."""
    extent = np.ptp(solid.vertices, axis=0)
    return 1.0 + np.divide(change_m, extent, out=np.zeros(3), where=extent > 0)


@dataclass(frozen=True)
class PartError:
    """A workpiece's errors: ``size_m`` (3,) changes of its extents, and where it starts:
    ``shift`` (2,) m in the base x-y plane, ``yaw`` rad about the base z axis through its
    origin, ``lift`` m along the base z axis (its support's height error)."""

    size_m: np.ndarray
    shift: np.ndarray
    yaw: float
    lift: float = 0.0


def part_as_built(part: Workpiece, err: PartError) -> Workpiece:
    """The workpiece as the world has it (itself when ``err`` is all zero)."""
    if not (np.any(err.size_m) or np.any(err.shift) or err.yaw or err.lift):
        return part
    T = part.T_base_part.copy()
    if err.yaw != 0.0:
        T[:3, :3] = Rotation.from_rotvec([0.0, 0.0, err.yaw]).as_matrix() @ T[:3, :3]
    T[:2, 3] += err.shift
    T[2, 3] += err.lift
    return replace(part, solid=scaled(part.solid, size_scale(part.solid, err.size_m)),
                   T_base_part=T)


SUPPORT_TOUCH_M = 1e-3
"""A workpiece whose lowest vertices are within this height (m) of a static object's top at
its start rests on that object."""


def resting_on(part: Workpiece, static: Sequence[StaticObject]) -> str | None:
    """The name of the static object ``part`` rests on at its start (the one it would fall onto
    from at most :data:`SUPPORT_TOUCH_M` above); None when it rests on none."""
    drops = {obj.name: Landing([obj]).drop(part.solid.vertices, part.T_base_part)
             for obj in static}
    drops = {name: drop for name, drop in drops.items() if drop is not None}
    under = min(drops, key=drops.get, default=None)
    return under if under is not None and drops[under] <= SUPPORT_TOUCH_M else None


def static_as_built(obj: StaticObject, lift: float) -> StaticObject:
    """The static object raised by ``lift`` (m, base z; itself when 0)."""
    if lift == 0.0:
        return obj
    T = obj.T_base_obj.copy()
    T[2, 3] += lift
    return replace(obj, T_base_obj=T)


def cell_as_built(cell: Cell, cameras: Mapping[str, CameraError],
                  robots: Mapping[str, RobotError], parts: Mapping[str, PartError],
                  heights: Mapping[str, float] | None = None) -> Cell:
    """The world's cell: ``cell`` with the errors of each named camera, robot and workpiece,
    and each named static object raised by its ``heights`` (m) together with the workpiece
    resting on it (the others as they are)."""
    heights = {name: h for name, h in (heights or {}).items() if h != 0.0}
    parts = dict(parts)
    for p in cell.workpieces:
        under = resting_on(p, cell.static) if heights else None
        if under in heights:
            err = parts.get(p.name, PartError(np.zeros(3), np.zeros(2), 0.0))
            parts[p.name] = replace(err, lift=err.lift + heights[under])
    return Cell(
        cell.name,
        [robot_as_built(r, robots[r.name]) if r.name in robots else r for r in cell.robots],
        [part_as_built(p, parts[p.name]) if p.name in parts else p for p in cell.workpieces],
        [static_as_built(s, heights.get(s.name, 0.0)) for s in cell.static],
        [camera_as_built(c, cameras[c.name]) if c.name in cameras else c for c in cell.cameras],
        cell.source, cell.experiments)

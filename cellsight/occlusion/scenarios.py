"""Random cell configurations for checking and benchmarking occlusion prediction.

A configuration draws every robot's joints uniformly inside their limits and puts each
workpiece either near its nominal place (random position and yaw, sometimes lifted and
tipped) or between the jaws of a robot's gripper whose tool centre point a camera sees, above
the floor (so that grippers and links hide it). Seeded: the same seed gives the same sequence.
"""

from __future__ import annotations

import numpy as np

from cellsight.geometry.transforms import pose_from_xyz_rpy
from cellsight.model.cell import Cell, Snapshot

HELD_ABOVE_FLOOR_M = 0.2
"""How high (m, base z; the floor is z = 0) a random held part's tool centre point is at least."""


def random_snapshots(cell: Cell, n: int, seed: int = 0, in_gripper: float = 0.4) -> list[Snapshot]:
    """``n`` random snapshots; a fraction ``in_gripper`` holds each part at a random robot's
    tool centre point, the others place it on the table top area near its nominal pose."""
    rng = np.random.default_rng(seed)
    grippers = [r for r in cell.robots if r.tool is not None]
    out = []
    for _ in range(n):
        joints = {r.name: r.chain.random_q(rng) for r in cell.robots}
        poses = {}
        for part in cell.workpieces:
            if grippers and rng.random() < in_gripper:
                robot = grippers[rng.integers(len(grippers))]
                joints[robot.name] = _joints_with_tcp_in_view(cell, robot, rng)
                tcp = robot.tcp_pose(joints[robot.name])
                tilt = pose_from_xyz_rpy(rng.normal(0, 0.01, 3), rng.normal(0, 0.2, 3))
                poses[part.name] = tcp @ tilt @ pose_from_xyz_rpy([0, 0, -0.015], [0, 0, 0])
            else:
                nominal = part.T_base_part[:3, 3]
                xyz = nominal + np.array([rng.uniform(-0.3, 0.4), rng.uniform(-0.12, 0.12), 0])
                rpy = [0.0, 0.0, rng.uniform(-np.pi, np.pi)]
                if rng.random() < 0.3:  # tipped over or lifted
                    xyz[2] += rng.uniform(0.05, 0.4)
                    rpy = rng.uniform(-np.pi, np.pi, 3)
                poses[part.name] = pose_from_xyz_rpy(xyz, rpy)
        openings = {r.name: rng.uniform(0.0, r.tool.max_opening) for r in grippers}
        out.append(cell.snapshot(joints, poses, openings))
    return out


def _joints_with_tcp_in_view(cell: Cell, robot, rng: np.random.Generator, tries: int = 2000):
    """Random joints of ``robot`` whose tool centre point some camera sees, at least
    :data:`HELD_ABOVE_FLOOR_M` above the floor (rejection sampling; the part it holds would
    otherwise be under the floor, where no arm can take it and the simulated world's floor
    plane, which the cell file does not have, hides it); the last draw if none is found in
    ``tries``."""
    for _ in range(tries):
        q = robot.chain.random_q(rng)
        tcp = robot.tcp_pose(q)[:3, 3][None]
        if tcp[0, 2] >= HELD_ABOVE_FLOOR_M and any(cam.sees(tcp)[0] for cam in cell.cameras):
            return q
    return q

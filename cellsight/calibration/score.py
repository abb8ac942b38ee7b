"""A calibration's errors against the simulated world's truth (never seen by the calibration
itself; only the simulated cell has a truth to score against).

The calibration's frame is the reference robot's own base (frame 0): every estimate is compared
with the world's truth expressed in the reference robot's true base. A camera's pose error is
given where it matters, at the work area: how far the estimated camera puts a point of the work
area from where the true camera puts it (mm), and the angle between the two orientations (deg).
Intrinsics: the focal lengths' error (% of the true one) and the principal point's (px). What
the tracker feels of them together: ``image_at_work_px``, the largest distance between where
the estimated and the true camera see the corners of a cube of ``WORK_HALF_M`` about the work
point (a principal point off and a rotation that makes up for it cancel there). Another
robot's base: its origin's error and the error at the work area (mm), and its angle (deg).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from cellsight.camera import Camera
from cellsight.geometry.transforms import invert_pose, rotation_angle, transform_points
from cellsight.model import Cell

WORK_HALF_M = 0.1
"""Half the side (m) of the cube about the work point where the cameras' images are compared."""


def _at_work(estimate: np.ndarray, truth: np.ndarray, work: np.ndarray) -> float:
    """How far (m) the frame ``estimate`` puts the point ``work`` (given in frame ``truth``'s
    coordinates through ``truth``) from where ``truth`` puts it: ``|E T^-1 p - p|``."""
    moved = transform_points(estimate @ invert_pose(truth), work[None])[0]
    return float(np.linalg.norm(moved - work))


def camera_errors(estimate: Camera, truth: Camera, T_ref_cam_true: np.ndarray,
                  work_ref: np.ndarray) -> dict[str, float]:
    """One camera's errors: ``estimate`` (its pose ``T_base_cam`` in the reference robot's
    frame) against the world's ``truth`` camera, whose pose in the same frame is
    ``T_ref_cam_true``; ``work_ref``: the work point (m, reference frame)."""
    T = estimate.T_base_cam
    focal = (np.array([estimate.K[0, 0], estimate.K[1, 1]])
             / np.array([truth.K[0, 0], truth.K[1, 1]]) - 1.0)
    principal = estimate.K[:2, 2] - truth.K[:2, 2]
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    cube = work_ref + WORK_HALF_M * signs
    seen = Camera(truth.K, truth.width, truth.height, T_ref_cam_true, truth.dist, truth.name)
    gap = np.linalg.norm(estimate.project(cube) - seen.project(cube), axis=1)
    return {"image_at_work_px": float(gap.max()),
            "position_at_work_mm": 1e3 * _at_work(T, T_ref_cam_true, work_ref),
            "centre_mm": 1e3 * float(np.linalg.norm(T[:3, 3] - T_ref_cam_true[:3, 3])),
            "rotation_deg": math.degrees(rotation_angle(T[:3, :3] @ T_ref_cam_true[:3, :3].T)),
            "focal_percent": 100.0 * float(np.max(np.abs(focal))),
            "principal_point_px": float(np.linalg.norm(principal))}


def base_errors(T_ref_robot: np.ndarray, T_ref_robot_true: np.ndarray,
                work_ref: np.ndarray) -> dict[str, float]:
    """Another robot's base (its frame 0 in the reference robot's frame) against the truth."""
    return {"origin_mm": 1e3 * float(np.linalg.norm(T_ref_robot[:3, 3]
                                                    - T_ref_robot_true[:3, 3])),
            "position_at_work_mm": 1e3 * _at_work(T_ref_robot, T_ref_robot_true, work_ref),
            "rotation_deg": math.degrees(rotation_angle(T_ref_robot[:3, :3]
                                                        @ T_ref_robot_true[:3, :3].T))}


def score(cameras: Sequence[Camera], T_ref_robot: Mapping[str, np.ndarray], world: Cell,
          reference: str, work_base: np.ndarray) -> dict[str, dict[str, dict[str, float]]]:
    """Every estimate's errors (module docstring): ``cameras`` (poses in the reference robot's
    frame, ``world.cameras`` order) and ``T_ref_robot`` (robot name -> base in the reference
    robot's frame) against the simulated ``world``'s own cell; ``work_base``: the work point
    (m, the cell's base frame, e.g. the workpiece's start)."""
    T_ref_b = invert_pose(world.robot(reference).T_base_robot)
    work_ref = transform_points(T_ref_b, np.asarray(work_base, dtype=float)[None])[0]
    out: dict[str, dict[str, dict[str, float]]] = {"cameras": {}, "robots": {}}
    for estimate, truth in zip(cameras, world.cameras, strict=True):
        out["cameras"][truth.name] = camera_errors(estimate, truth, T_ref_b @ truth.T_base_cam,
                                                   work_ref)
    for name, T in T_ref_robot.items():
        if name != reference:
            out["robots"][name] = base_errors(T, T_ref_b @ world.robot(name).T_base_robot,
                                              work_ref)
    return out

"""What the calibration's joint refinement (:mod:`.solve`) takes and gives: the views of the
board (:class:`View`), the first estimates (:class:`Start`), and the solution with its
standard deviations (:class:`Solution`, :class:`PoseStd`, :class:`CameraStd`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellsight.camera import Camera
from cellsight.errors import CellsightError
from cellsight.kinematics import KinematicChain

IDENTIFIABLE_SINE = 1e-3  # least sine between an offset's column and the others' span
_IDENTITY_TOL = 1e-9


@dataclass(frozen=True)
class View:
    """One camera's image of the board at one robot pose.

    ``camera``: index into the cameras; ``robot``: the robot holding the board; ``pose``: the
    index of the robot's pose (several cameras see the same pose); ``joints`` (n,): the
    encoder readings at that pose (rad, m); ``ids`` (m,): detected corner ids (rows of the
    board points); ``pixels`` (m, 2): their image coordinates (px, distorted, as detected).
    """

    camera: int
    robot: str
    pose: int
    joints: np.ndarray
    ids: np.ndarray
    pixels: np.ndarray


@dataclass(frozen=True)
class Start:
    """Values to start from, all in ref (the reference robot's frame 0): ``cameras``
    (:class:`cellsight.camera.Camera`, ``T_base_cam`` meaning ``T_ref_cam``), every robot's
    base ``T_ref_robot`` (the reference robot's is the identity) and the board's mount on each
    robot's flange ``T_flange_board``."""

    cameras: list[Camera]
    T_ref_robot: dict[str, np.ndarray]
    T_flange_board: dict[str, np.ndarray]

    @property
    def reference(self) -> str:
        """The reference robot: the one whose ``T_ref_robot`` is the identity."""
        found = [name for name, T in self.T_ref_robot.items()
                 if np.allclose(T, np.eye(4), rtol=0.0, atol=_IDENTITY_TOL)]
        if len(found) != 1:
            raise CellsightError(f"calibration start: exactly one robot's T_ref_robot must be "
                                 f"the identity (the reference robot), got {found or 'none'}; "
                                 f"give the others' bases in the reference robot's frame 0")
        return found[0]


@dataclass(frozen=True)
class PoseStd:
    """Standard deviations of a pose: ``position_mm`` (3,) of its origin along the axes of
    the frame it is given in (mm); ``rotation_deg`` (3,) of its rotation about those axes
    (the board's: about the flange's axes) (deg)."""

    position_mm: np.ndarray
    rotation_deg: np.ndarray


@dataclass(frozen=True)
class CameraStd:
    """Standard deviations of a camera's estimates: ``pose`` (``T_ref_cam``'s, in ref);
    ``focal_pct`` (2,) of fx, fy (% of the value); ``principal_px`` (2,) of cx, cy (px);
    ``distortion`` (4,) of k1, k2, p1, p2. NaN where the intrinsics were held."""

    pose: PoseStd
    focal_pct: np.ndarray
    principal_px: np.ndarray
    distortion: np.ndarray


@dataclass(frozen=True)
class Solution:
    """A calibration, in ref (the reference robot's frame 0).

    ``cameras``: the calibrated cameras (same names and sizes as the start's; ``T_base_cam``
    is ``T_ref_cam``); ``T_ref_robot`` (every robot, the reference's the identity);
    ``T_flange_board``; ``joint_offsets`` (n,) per robot (rad, m; zeros when not estimated
    or fixed by the gauge). ``residuals_px``: per view, in the views' order, the projected
    minus the detected pixels (m, 2); ``view_rms_px`` and ``camera_rms_px``: the RMS of the
    corners' reprojection distances per view and per camera; ``rms_px`` over all corners.
    Standard deviations: ``camera_std``, ``robot_std`` (NaN for the reference),
    ``board_std``, ``joint_offset_std`` (rad, m; NaN where not estimated).
    ``joint_offset_sine``: per offset, the sine of the angle between its column of the
    (column-normalised) Jacobian and the span of all the other columns: 1 when no other
    estimate can mimic it, 0 when it is unobservable (NaN where not estimated).
    ``initial``: OpenCV's first estimates the refinement started from.
    """

    cameras: list[Camera]
    T_ref_robot: dict[str, np.ndarray]
    T_flange_board: dict[str, np.ndarray]
    joint_offsets: dict[str, np.ndarray]
    residuals_px: list[np.ndarray]
    view_rms_px: np.ndarray
    camera_rms_px: np.ndarray
    rms_px: float
    camera_std: list[CameraStd]
    robot_std: dict[str, PoseStd]
    board_std: dict[str, PoseStd]
    joint_offset_std: dict[str, np.ndarray]
    joint_offset_sine: dict[str, np.ndarray]
    initial: Start

    @property
    def joint_offsets_identifiable(self) -> dict[str, np.ndarray]:
        """Per robot (n,) bool: the offset was estimated and its sine is at least
        ``IDENTIFIABLE_SINE`` (the data pin it within 1000 times the precision they would
        give were everything else known)."""
        return {r: np.nan_to_num(s, nan=0.0) >= IDENTIFIABLE_SINE
                for r, s in self.joint_offset_sine.items()}


@dataclass(frozen=True)
class Problem:
    """The checked input: ``robots`` (the reference first), ``poses`` (robot, pose) -> the
    joints read there, ``flange`` (robot, pose) -> ``T_robot_flange`` at those readings."""

    views: list[View]
    points: np.ndarray
    chains: dict[str, KinematicChain]
    start: Start
    robots: list[str]
    poses: dict[tuple[str, int], np.ndarray]
    flange: dict[tuple[str, int], np.ndarray]

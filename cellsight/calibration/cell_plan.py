"""The calibration poses judged (``cellsight calibrate``): one robot's, every camera needing
enough of them (:func:`plan_poses`), or the whole cell's (:func:`plan_cell`): every robot's
plan (:func:`.plan.plan_reach`), each robot presenting the board to the cameras it can reach,
tied together: every camera seen by some robot, every robot's base placed through a camera it
shares with the others."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from cellsight.calibration import POSES_PER_CAMERA
from cellsight.calibration.plan import MIN_POSES, Plan, plan_reach, with_cameras, work_centre
from cellsight.calibration.presenting import BoardOnFlange
from cellsight.errors import CellsightError
from cellsight.model.cell import Cell


def plan_poses(cell: Cell, robot: str, board: BoardOnFlange, *,
               per_camera: int = POSES_PER_CAMERA,
               min_poses: int = MIN_POSES, seed: int = 0, cameras: Sequence[str] | None = None,
               start: ArrayLike | None = None) -> Plan:
    """The poses in which ``robot`` presents the ``board`` to the cell's cameras (or to those
    named in ``cameras``) (:func:`~.plan.plan_reach`, the same arguments); a
    :class:`CellsightError` when a camera gets fewer than ``min_poses``, naming it, why poses
    were dropped and what to do."""
    if not 1 <= min_poses <= per_camera:
        raise CellsightError(f"calibration plan for robot {robot}: needs 1 <= min_poses <= "
                             f"per_camera, got min_poses={min_poses}, per_camera={per_camera}")
    plan = plan_reach(cell, robot, board, per_camera=per_camera, seed=seed, cameras=cameras,
                      start=start)
    _refuse_short(plan, with_cameras(cell, cameras), min_poses)
    return plan


def plan_cell(cell: Cell, robots: Sequence[str], board: BoardOnFlange, *,
              per_camera: int = POSES_PER_CAMERA, min_poses: int = MIN_POSES,
              seed: int = 0) -> list[Plan]:
    """The poses of each of ``robots`` (:func:`~.plan.plan_reach`), the first the reference
    (its base is the calibration's frame), each presenting the board to the cameras it can:
    a camera needs ``min_poses`` from one robot at least (on a line, each arm reaches the
    views near it), and each robot a camera it shares with the others, so that the cameras
    and bases tie together from the reference's. Else a :class:`CellsightError` naming the
    camera or the robot, each robot's poses there, why poses were dropped and what to do."""
    plans = [plan_reach(cell, robot, board, per_camera=per_camera, seed=seed)
             for robot in robots]
    _refuse_untied(plans, cell, min_poses)
    return plans


def _refuse_untied(plans: list[Plan], cell: Cell, min_poses: int) -> None:
    """A :class:`CellsightError` naming each camera that no robot presents the board to in
    ``min_poses`` poses, or else a robot that shares no such camera with the reference's
    (``plans[0]``) tied cameras and robots (:func:`plan_cell`)."""
    counts = {plan.robot: plan.per_camera() for plan in plans}
    enough = {robot: {name for name, n in seen.items() if n >= min_poses}
              for robot, seen in counts.items()}
    short = [cam.name for cam in cell.cameras if not any(cam.name in e for e in enough.values())]
    if short:
        poses = "; ".join(f"{name}: " + ", ".join(f"{robot} {seen.get(name, 0)}"
                                                  for robot, seen in counts.items())
                          for name in short)
        why = "; ".join(f"{plan.robot}: {_dropped(plan)}" for plan in plans)
        raise CellsightError(
            f"calibration plan: no robot can present the board to camera {' or '.join(short)} "
            f"in the {min_poses} poses a calibration needs (poses per robot, {poses}; "
            f"candidate poses dropped, {why}); aim {' and '.join(short)} at the work area "
            f"around {np.round(work_centre(cell), 2).tolist()} m where a robot can reach, or "
            f"leave it out of the cell")
    tied, cameras = {plans[0].robot}, set(enough[plans[0].robot])
    while True:
        more = {robot for robot, seen in enough.items() if robot not in tied and seen & cameras}
        if not more:
            break
        tied |= more
        cameras |= set().union(*(enough[robot] for robot in more))
    for plan in plans:
        if plan.robot not in tied:
            raise CellsightError(
                f"calibration plan: robot {plan.robot} presents the board in {min_poses} poses "
                f"to {' and '.join(sorted(enough[plan.robot])) or 'no camera'}, none of them a "
                f"camera tied to {plans[0].robot}'s base ({', '.join(sorted(cameras))}): its "
                f"base cannot be placed in the calibration's frame; give it a camera it shares "
                f"with the others")


def _refuse_short(plan: Plan, cell: Cell, min_poses: int) -> None:
    """A :class:`CellsightError` naming the robot and each camera with fewer than
    ``min_poses`` poses, why poses were dropped, and what to do."""
    counts = plan.per_camera()
    short = [cam.name for cam in cell.cameras if counts.get(cam.name, 0) < min_poses]
    if not short:
        return
    centre = np.round(work_centre(cell), 2).tolist()
    raise CellsightError(
        f"calibration plan: robot {plan.robot} can present the board to camera "
        f"{', '.join(f'{name} in {counts.get(name, 0)}' for name in short)} pose(s), fewer "
        f"than the {min_poses} a calibration needs (candidate poses dropped: "
        f"{_dropped(plan)}); aim "
        f"{' and '.join(short)} at the work area around {centre} m where {plan.robot} can "
        f"reach, or leave it out (cameras=...) and calibrate it with another robot")


def _dropped(plan: Plan) -> str:
    """How many candidate poses each check of ``plan`` dropped, as words ("none": none)."""
    return ", ".join(f"{n} {reason}" for reason, n in sorted(plan.dropped.items())) or "none"

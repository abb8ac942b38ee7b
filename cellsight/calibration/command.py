"""``cellsight calibrate`` in the simulated world: the seed's world (:func:`calibrate_world`),
then the folder written (:mod:`.output`) and the verdict printed (:func:`calibrate_command`).

For each robot in turn, the grasping robot (the reference: the calibration's frame is its base)
first: the poses are planned on the cell file (:mod:`.plan`: what the calibration knows), the
board is bolted to that robot's flange in the world the seed draws (:func:`.board.board_world`:
the same cameras, robots, servo, images and noise as ``cellsight run --seed N``, without the
profile's faults and unmodelled bodies), the robot moves through them and the cameras
photograph the board (:mod:`.shoot`). One joint fit over every view (:mod:`.solve`) starts from
the cell file's cameras and bases. The world's truth only scores the result (:mod:`.score`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

from cellsight.calibration.board import Board, board_world
from cellsight.calibration.folder import read_calibration
from cellsight.calibration.output import is_calibration_output, write_calibration
from cellsight.calibration.plan import Plan, plan_poses
from cellsight.calibration.score import score
from cellsight.calibration.shoot import photograph
from cellsight.calibration.solve import Solution, Start, View, calibrate
from cellsight.camera import Camera
from cellsight.errors import CellsightError
from cellsight.geometry.transforms import invert_pose, transform_points
from cellsight.model import Cell
from cellsight.model.loader import load_cell
from cellsight.realism import draw_world
from cellsight.runfolder import cell_digest, check_out_folder, make_out_folder


@dataclass(frozen=True)
class WorldCalibration:
    """A calibration made in the simulated world: the cell file's ``cell``, the ``reference``
    robot, the ``plans``, the ``views``, the ``solution`` and its ``errors`` against the
    world's truth (:func:`.score.score`)."""

    cell: Cell
    reference: str
    plans: list[Plan]
    views: list[View]
    solution: Solution
    errors: dict


def reference_robot(cell: Cell) -> str:
    """The robot whose base is the calibration's frame: the one that grasps (the cell file's
    experiments), else the first."""
    return cell.experiments.robot or cell.robots[0].name


def _start(cell: Cell, reference: str, board: Board) -> Start:
    """The cell file's cameras and bases in the reference robot's frame, the nominal mount."""
    T_ref_b = invert_pose(cell.robot(reference).T_base_robot)
    cameras = [Camera(c.K, c.width, c.height, T_ref_b @ c.T_base_cam, c.dist, c.name)
               for c in cell.cameras]
    return Start(cameras, {r.name: T_ref_b @ r.T_base_robot for r in cell.robots},
                 {r.name: board.T_flange_board for r in cell.robots})


def calibrate_world(cell_arg: str | Path | None, realism: str, seed: int, board: Board,
                    per_camera: int = 8, joint_offsets: bool = False,
                    progress: bool = True) -> WorldCalibration:
    """The calibration of the seed's world (module docstring)."""
    cell = load_cell(cell_arg)
    draws = draw_world(realism, cell, seed)
    errors = replace(draws.errors, intruders=(), kidnap=None, knock=None)
    reference = reference_robot(cell)
    robots = [reference, *(r.name for r in cell.robots if r.name != reference)]
    corners_flange = transform_points(board.T_flange_board, board.corners())
    normal = board.T_flange_board[:3, :3] @ board.face_normal
    outline = transform_points(board.T_flange_board, board.outline())
    plans = [plan_poses(cell, r, corners_flange, normal, outline, per_camera=per_camera,
                        seed=seed) for r in robots]
    views: list[View] = []
    with Progress(TextColumn("calibrating {task.description}"), BarColumn(),
                  MofNCompleteColumn(), disable=not progress) as bar:
        for plan in plans:
            task = bar.add_task(plan.robot, total=len(plan.joints))
            world = board_world(draws.cell, plan.robot, board, seed=seed, errors=errors)
            try:
                views += photograph(world, plan.robot, plan.joints, board.detect,
                                    tick=lambda t=task: bar.advance(t))
            finally:
                world.close()
    solution = calibrate(views, board.corners(), {r.name: r.chain for r in cell.robots},
                         _start(cell, reference, board), joint_offsets=joint_offsets)
    work = (cell.workpieces[0].T_base_part[:3, 3] if cell.workpieces
            else np.mean([c.T_base_cam[:3, 3] for c in cell.cameras], axis=0))
    return WorldCalibration(cell, reference, plans, views, solution,
                            score(solution.cameras, solution.T_ref_robot, draws.cell,
                                  reference, work))


def verdict(result: WorldCalibration) -> str:
    """One line: how well the board's corners fit, per camera."""
    s = result.solution
    per = ", ".join(f"{c.name} {r:.3f} px" for c, r in zip(s.cameras, s.camera_rms_px,
                                                           strict=True))
    return (f"calibrated {len(s.cameras)} cameras and {len(s.T_ref_robot)} robot bases in "
            f"{result.reference}'s base frame from {len(result.views)} views: reprojection RMS "
            f"{s.rms_px:.3f} px ({per})")


def write_world_calibration(out: Path, cell_arg: str | Path | None, realism: str, seed: int,
                            board: Board, per_camera: int = 8, joint_offsets: bool = False,
                            progress: bool = True,
                            stale: Sequence[Path] = ()) -> WorldCalibration:
    """Calibrate the seed's world (:func:`calibrate_world`) and write the folder ``out``
    (:mod:`.output`); ``stale``: the earlier outputs there to clear
    (:func:`~cellsight.runfolder.check_out_folder`), once the calibration is made."""
    started = time.perf_counter()
    result = calibrate_world(cell_arg, realism, seed, board, per_camera, joint_offsets,
                             progress)
    make_out_folder(out, list(stale), "--out")
    facts = {"world": {"realism": realism, "seed": seed}, "errors": result.errors,
             "board": {"squares": list(board.squares), "square_m": board.square_m,
                       "marker_m": board.marker_m, "dictionary": board.dictionary},
             "poses": {p.robot: len(p.joints) for p in result.plans},
             "verdict": verdict(result), "wall_s": round(time.perf_counter() - started, 1)}
    write_calibration(out, result.cell, result.reference, result.solution, result.views, facts)
    return result


def finished_calibration(folder: Path, cell_arg: str | Path | None, realism: str,
                         seed: int) -> bool:
    """Whether ``folder`` holds a calibration of this cell as it is now (by its SHA-256), made
    in the world of ``realism`` and ``seed``: a sweep reuses it."""
    try:
        data = read_calibration(folder)
        digest = cell_digest(load_cell(cell_arg))
    except CellsightError:
        return False
    return (data.get("cell_sha256") == digest
            and data.get("world") == {"realism": realism, "seed": seed})


def calibrate_command(cell_arg: str | None, realism: str, seed: int, out: Path,
                      board_file: str | None, per_camera: int, joint_offsets: bool,
                      progress: bool, overwrite: bool) -> int:
    """``cellsight calibrate`` (module docstring): the folder checked first, written last."""
    if seed < 0:
        raise CellsightError(f"--seed: expected a whole number >= 0, got {seed}")
    if per_camera < 6:
        raise CellsightError(f"--poses: expected at least 6 poses per camera, got {per_camera}")
    stale = check_out_folder(out, overwrite, "--out", "--overwrite", is_calibration_output)
    board = Board() if board_file is None else Board.from_yaml(board_file)
    result = write_world_calibration(out, cell_arg, realism, seed, board, per_camera,
                                     joint_offsets, progress, stale)
    print(verdict(result))
    for name, e in result.errors["cameras"].items():
        print(f"  {name}: {e['position_at_work_mm']:.3f} mm and {e['rotation_deg']:.4f} deg at "
              f"the work area, focal {e['focal_percent']:.3f} %, principal point "
              f"{e['principal_point_px']:.2f} px (against the world's truth)")
    for name, e in result.errors["robots"].items():
        print(f"  {name}'s base: {e['origin_mm']:.3f} mm, {e['rotation_deg']:.4f} deg")
    print(f"wrote {out}: cell.yaml, cameras/, calibration.json, residuals.png, report.html")
    return 0

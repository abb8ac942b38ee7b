"""``cellsight calibrate``: in the simulated world (:func:`calibrate_world`) or from a
recording of a calibration motion (:func:`calibrate_recorded`), then the folder written
(:mod:`.output`) and the verdict printed (:func:`calibrate_command`).

In the simulated world, for each robot in turn, the grasping robot (the reference: the
calibration's frame is its base) first: the poses are planned on the cell file (:mod:`.plan`:
what the calibration knows), the board is bolted to that robot's flange in the world the seed
draws (:func:`.board.board_world`: the same cameras, robots, servo, images and noise as
``cellsight run --seed N``, without the profile's faults and unmodelled bodies), the robot
moves through them and the cameras photograph the board (:mod:`.shoot`), the motion recorded
with ``--record`` (:mod:`.record`). From a recording, the poses are the frames where the robots
stood still (:mod:`.recorded`). Either way one joint fit over every view (:mod:`.solve`)
starts from the cell file's cameras and bases. The world's truth only scores the result
(:mod:`.score`): the seed's world, or the one a recording made by ``--record`` names.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

from cellsight.calibration import POSES_PER_CAMERA
from cellsight.calibration.board import Board, board_world
from cellsight.calibration.cell_plan import plan_cell
from cellsight.calibration.folder import read_calibration
from cellsight.calibration.output import is_calibration_output, write_calibration
from cellsight.calibration.record import MotionRecorder
from cellsight.calibration.recorded import RecordedMotion, recorded_views
from cellsight.calibration.score import score
from cellsight.calibration.shoot import photograph
from cellsight.calibration.solution import Solution, Start, View
from cellsight.calibration.solve import calibrate
from cellsight.camera import Camera
from cellsight.errors import CellsightError
from cellsight.export.rosbag import check_jpeg, check_output
from cellsight.geometry.transforms import invert_pose
from cellsight.model import Cell
from cellsight.model.loader import load_cell
from cellsight.realism import draw_world
from cellsight.recording.names import load_topic_map
from cellsight.recording.reader import open_recording
from cellsight.runfolder import cell_digest, check_out_folder, make_out_folder


@dataclass(frozen=True)
class CellCalibration:
    """A calibration made: the cell file's ``cell``, the ``reference`` robot, the ``poses``
    each robot took, the ``views``, the ``solution``, its ``errors`` against a simulated
    world's truth (:func:`.score.score`; None without a world to score against) and where it
    comes from (``source``: ``world`` and/or ``recording`` facts for calibration.json);
    ``joint_offsets``: whether the robots' joint zero offsets were estimated."""

    cell: Cell
    reference: str
    poses: dict[str, int]
    views: list[View]
    solution: Solution
    errors: dict | None
    source: dict
    joint_offsets: bool


def reference_robot(cell: Cell) -> str:
    """The robot whose base is the calibration's frame: the one that grasps (the cell file's
    experiments), else the first."""
    return cell.experiments.robot or cell.robots[0].name


def _cell_file_start(cell: Cell, reference: str) -> tuple[list[Camera], dict[str, np.ndarray]]:
    """The cell file's cameras and bases in the reference robot's frame."""
    T_ref_b = invert_pose(cell.robot(reference).T_base_robot)
    cameras = [Camera(c.K, c.width, c.height, T_ref_b @ c.T_base_cam, c.dist, c.name)
               for c in cell.cameras]
    return cameras, {r.name: T_ref_b @ r.T_base_robot for r in cell.robots}


def _start(cell: Cell, reference: str, board: Board) -> Start:
    """The cell file's cameras and bases in the reference robot's frame, the nominal mount."""
    return Start(*_cell_file_start(cell, reference),
                 {r.name: board.T_flange_board for r in cell.robots})


def _solve(cell: Cell, views: list[View], board: Board, joint_offsets: bool) -> Solution:
    return calibrate(views, board.corners(), {r.name: r.chain for r in cell.robots},
                     _start(cell, reference_robot(cell), board), joint_offsets=joint_offsets)


def world_errors(cell: Cell, solution: Solution, world_cell: Cell) -> dict:
    """The solution's errors against ``world_cell`` (the simulated world's truth), at the work
    area: the first workpiece's start (else the cameras' mean position); under ``cell_file``,
    those of the cell file's own cameras and bases (where the calibration started), to
    compare."""
    work = (cell.workpieces[0].T_base_part[:3, 3] if cell.workpieces
            else np.mean([c.T_base_cam[:3, 3] for c in cell.cameras], axis=0))
    reference = reference_robot(cell)
    cameras, bases = _cell_file_start(cell, reference)
    return {**score(solution.cameras, solution.T_ref_robot, world_cell, reference, work),
            "cell_file": score(cameras, bases, world_cell, reference, work)}


def calibrate_world(cell_arg: str | Path | None, realism: str, seed: int, board: Board,
                    per_camera: int = POSES_PER_CAMERA, joint_offsets: bool = True,
                    progress: bool = True, log: MotionRecorder | None = None
                    ) -> CellCalibration:
    """The calibration of the seed's world (module docstring); ``log`` records the motion
    (``--record``)."""
    cell = load_cell(cell_arg)
    draws = draw_world(realism, cell, seed)
    errors = replace(draws.errors, intruders=(), kidnap=None, knock=None)
    reference = reference_robot(cell)
    robots = [reference, *(r.name for r in cell.robots if r.name != reference)]
    on_flange = board.on_flange()
    plans = plan_cell(cell, robots, on_flange, per_camera=per_camera, seed=seed)
    views: list[View] = []
    with Progress(TextColumn("calibrating {task.description}"), BarColumn(),
                  MofNCompleteColumn(), disable=not progress) as bar:
        for plan in plans:
            task = bar.add_task(plan.robot, total=len(plan.joints))
            world = board_world(draws.cell, plan.robot, board, seed=seed, errors=errors)
            try:
                if log is not None:
                    log.start(world)
                views += photograph(world, plan.robot, plan.joints, board.detect,
                                    tick=lambda t=task: bar.advance(t), log=log)
            finally:
                world.close()
    solution = _solve(cell, views, board, joint_offsets)
    return CellCalibration(cell, reference, {p.robot: len(p.joints) for p in plans}, views,
                           solution, world_errors(cell, solution, draws.cell),
                           {"world": {"realism": realism, "seed": seed}}, joint_offsets)


def calibrate_recorded(recording_path: str | Path, cell_arg: str | Path | None, board: Board,
                       topics: str | None = None, tolerance_s: float = 0.019,
                       joint_offsets: bool = True) -> CellCalibration:
    """The calibration of the motion in a recording (:mod:`.recorded`); scored against the
    simulated world a recording of ``cellsight calibrate --record`` names in its metadata."""
    cell = load_cell(cell_arg)
    with open_recording(recording_path) as recording:
        motion: RecordedMotion = recorded_views(recording, cell, board, load_topic_map(topics),
                                                tolerance_s)
        made_in = recording.metadata("cellsight")
    solution = _solve(cell, motion.views, board, joint_offsets)
    source: dict = {"recording": {"path": str(recording_path), "frames": motion.frames,
                                  "frames_moving": motion.moving}}
    errors = None
    if made_in.get("motion") == "cellsight calibrate" and "realism" in made_in:
        world = {"realism": made_in["realism"], "seed": int(made_in["seed"])}
        source["world"] = world
        errors = world_errors(cell, solution,
                              draw_world(world["realism"], cell, world["seed"]).cell)
    return CellCalibration(cell, reference_robot(cell), motion.poses, motion.views, solution,
                           errors, source, joint_offsets)


def verdict(result: CellCalibration) -> str:
    """One line: how well the board's corners fit, per camera."""
    s = result.solution
    per = ", ".join(f"{c.name} {r:.3f} px" for c, r in zip(s.cameras, s.camera_rms_px,
                                                           strict=True))
    return (f"calibrated {len(s.cameras)} cameras and {len(s.T_ref_robot)} robot bases in "
            f"{result.reference}'s base frame from {len(result.views)} views: reprojection RMS "
            f"{s.rms_px:.3f} px ({per})")


def write_result(out: Path, result: CellCalibration, board: Board, stale: Sequence[Path],
                 wall_s: float) -> None:
    """The folder ``out`` (:mod:`.output`), ``stale`` (earlier outputs there) cleared first."""
    make_out_folder(out, list(stale), "--out")
    facts = {**result.source, "errors": result.errors,
             "board": {"squares": list(board.squares), "square_m": board.square_m,
                       "marker_m": board.marker_m, "dictionary": board.dictionary},
             "poses": result.poses, "joint_offsets_estimated": result.joint_offsets,
             "verdict": verdict(result), "wall_s": round(wall_s, 1)}
    write_calibration(out, result.cell, result.reference, result.solution, result.views, facts)


def write_world_calibration(out: Path, cell_arg: str | Path | None, realism: str, seed: int,
                            board: Board, stale: Sequence[Path] = ()) -> CellCalibration:
    """Calibrate the seed's world with the defaults, quietly (:func:`calibrate_world`), and
    write the folder ``out``; ``stale``: the earlier outputs there to clear
    (:func:`~cellsight.runfolder.check_out_folder`), once the calibration is made."""
    started = time.perf_counter()
    result = calibrate_world(cell_arg, realism, seed, board, progress=False)
    write_result(out, result, board, stale, time.perf_counter() - started)
    return result


def finished_calibration(folder: Path, cell_arg: str | Path | None, realism: str,
                         seed: int) -> bool:
    """Whether ``folder`` holds a calibration of this cell as it is now (by its SHA-256), made
    in the world of ``realism`` and ``seed`` with the defaults (the joint offsets estimated):
    a sweep reuses it."""
    try:
        data = read_calibration(folder)
        digest = cell_digest(load_cell(cell_arg))
    except CellsightError:
        return False
    return (data.get("cell_sha256") == digest and data.get("joint_offsets_estimated") is True
            and data.get("world") == {"realism": realism, "seed": seed})


@dataclass(frozen=True)
class CalibrateRequest:
    """``cellsight calibrate``'s arguments (:mod:`cellsight.commands.calibrate`)."""

    out: Path
    cell: str | None = None
    recording: str | None = None
    realism: str = "lab"
    seed: int = 0
    board: str | None = None
    poses: int = POSES_PER_CAMERA
    joint_offsets: bool = True
    record: str | None = None
    record_jpeg: int | None = None
    topics: str | None = None
    sync_tolerance: float = 0.019
    progress: bool = True
    overwrite: bool = False


def _checked(request: CalibrateRequest) -> list[Path]:
    """Every argument and output checked before the work starts; the stale outputs."""
    if request.seed < 0:
        raise CellsightError(f"--seed: expected a whole number >= 0, got {request.seed}")
    if request.poses < 6:
        raise CellsightError(f"--poses: expected at least 6 poses per camera, got "
                             f"{request.poses}")
    if request.recording is not None and request.record is not None:
        raise CellsightError("--record: records the simulated calibration motion; a "
                             "RECORDING is calibrated as it is")
    stale = check_out_folder(request.out, request.overwrite, "--out", "--overwrite",
                             is_calibration_output)
    if request.record is not None:
        check_jpeg(request.record_jpeg, "--record-jpeg")
        check_output(request.record, request.overwrite, request.out, "--record")
    return stale


def _calibration(request: CalibrateRequest, board: Board) -> CellCalibration:
    if request.recording is not None:
        return calibrate_recorded(request.recording, request.cell, board, request.topics,
                                  request.sync_tolerance, request.joint_offsets)
    log = None
    if request.record is not None:
        log = MotionRecorder(Path(request.record), load_cell(request.cell),
                             {"realism": request.realism, "seed": str(request.seed)},
                             request.record_jpeg)
    complete = False
    try:
        result = calibrate_world(request.cell, request.realism, request.seed, board,
                                 request.poses, request.joint_offsets, request.progress, log)
        complete = True
    finally:
        if log is not None:
            log.close(complete)
    return result


def calibrate_command(request: CalibrateRequest) -> int:
    """``cellsight calibrate`` (module docstring): the outputs checked first, written last."""
    stale = _checked(request)
    board = Board() if request.board is None else Board.from_yaml(request.board)
    started = time.perf_counter()
    result = _calibration(request, board)
    write_result(request.out, result, board, stale, time.perf_counter() - started)
    print(verdict(result))
    for name, e in (result.errors or {}).get("cameras", {}).items():
        print(f"  {name}: {e['position_at_work_mm']:.3f} mm and {e['rotation_deg']:.4f} deg at "
              f"the work area, focal {e['focal_percent']:.3f} %, principal point "
              f"{e['principal_point_px']:.2f} px (against the world's truth)")
    for name, e in (result.errors or {}).get("robots", {}).items():
        print(f"  {name}'s base: {e['origin_mm']:.3f} mm, {e['rotation_deg']:.4f} deg")
    print(f"wrote {request.out}: cell.yaml, cameras/, calibration.json, residuals.png, "
          f"report.html" + (f"; the motion in {request.record}" if request.record else ""))
    return 0

"""``cellsight calibrate RECORDING``: a calibration motion read from a recording.

The recording is written with the recorder of ``cellsight run --record`` (MCAP, ROS 2
messages) for the built-in cell: each robot in turn carries the board through the poses the
planner gives (:func:`~cellsight.calibration.cell_plan.plan_poses`), the joint states at the
start, halfway through the settling and at each shot, plus a frame taken while the robot still
moved and a second frame of the same pose. The images are the oracle's, not the renderer's:
OpenCV's own printed board (``CharucoBoard.generateImage``) warped by the homography of the
true board pose in each camera (``K [r1 r2 t]``, the cell file's cameras, no distortion).

Checked: every pose is found once and given to the robot that carried it, the frame in motion
and the repeated frame are left out, and the calibration recovers the cell file's cameras and
second base (its truth here): the work area's image within 0.2 px, the cameras' centres and
the second base within 0.5 mm.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cellsight.calibration.board import Board
from cellsight.calibration.cell_plan import plan_poses
from cellsight.calibration.command import calibrate_recorded
from cellsight.calibration.recorded import recorded_views
from cellsight.camera import Camera
from cellsight.errors import CellsightError
from cellsight.geometry.transforms import invert_pose
from cellsight.model import Cell
from cellsight.model.loader import load_cell
from cellsight.recording.names import TopicMap
from cellsight.recording.reader import open_recording
from cellsight.recording.recorder import Recorder

PX_PER_M = 1300.0  # the printed board's texture: about the cameras' own scale at the board
T0 = 1_700_000_000.0  # s: the recording's clock at its start


def _undistorted(cell: Cell) -> Cell:
    cameras = [Camera(c.K, c.width, c.height, c.T_base_cam, np.zeros(5), c.name)
               for c in cell.cameras]
    return Cell(cell.name, cell.robots, cell.workpieces, cell.static, cameras, cell.source,
                cell.experiments, cell.files)


def _image(camera: Camera, board: Board, T_base_board: np.ndarray) -> np.ndarray:
    """The board as ``camera`` sees it at ``T_base_board``: the printed face warped by the
    plane's homography (a texture pixel's centre half a pixel in from its outer corner; the
    image's pixel centres at integer coordinates, as K has them)."""
    texture = board.texture(PX_PER_M)
    s = round(board.square_m * PX_PER_M) / board.square_m  # the texture's px per m
    T = invert_pose(camera.T_base_cam) @ T_base_board
    to_board = np.array([[1 / s, 0.0, 0.5 / s - board.margin_m],
                         [0.0, 1 / s, 0.5 / s - board.margin_m], [0.0, 0.0, 1.0]])
    H = camera.K @ np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]]) @ to_board
    return cv2.warpPerspective(texture, H, (camera.width, camera.height),
                               flags=cv2.INTER_LINEAR, borderValue=110)


def _board_pose(cell: Cell, robot: str, q: np.ndarray, board: Board) -> np.ndarray:
    r = cell.robot(robot)
    return r.T_base_robot @ r.chain.fkine(q)[-1] @ board.T_flange_board


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> tuple[Path, dict[str, np.ndarray], Cell]:
    """The recording (module docstring), the planned joints per robot, the cell (its truth)."""
    cell, board = _undistorted(load_cell("dual-arm")), Board()
    plans = {r.name: plan_poses(cell, r.name, board.on_flange(), per_camera=6, seed=3).joints
             for r in cell.robots}
    path = tmp_path_factory.mktemp("rec") / "motion.mcap"
    recorder = Recorder(path, cell, cell.workpieces[0].name)
    joints = {r.name: r.home.copy() for r in cell.robots}
    t = T0
    recorder.joints(t, joints, {})
    for robot, poses in plans.items():
        for k, q in enumerate(poses):
            if k == 1:  # a frame while the robot is still on its way
                joints[robot] = 0.5 * (joints[robot] + q)
                t += 0.5
                recorder.frame(t, [np.full((c.height, c.width), 110, np.uint8)
                                   for c in cell.cameras], None, joints, {}, None)
            joints[robot] = q.copy()
            t += 1.0
            recorder.joints(t, joints, {})
            images = [_image(c, board, _board_pose(cell, robot, q, board))
                      for c in cell.cameras]
            for _ in range(2):  # the shot, and the same pose again
                t += 0.4
                recorder.frame(t, images, None, joints, {}, None)
        joints[robot] = cell.robot(robot).home.copy()  # home again before the next one
        t += 1.0
        recorder.joints(t, joints, {})
    recorder.close(True, {"motion": "cellsight calibrate", "realism": "exact", "seed": "0"})
    return path, plans, cell


def test_every_pose_is_found_once_and_given_to_the_robot_that_carried_it(recording):
    path, plans, cell = recording
    with open_recording(path) as rec:
        motion = recorded_views(rec, cell, Board(), TopicMap(), 0.019)
    assert motion.poses == {robot: len(q) for robot, q in plans.items()}
    assert motion.moving == len(plans)  # the one frame in motion per robot
    for view in motion.views:
        np.testing.assert_allclose(view.joints, plans[view.robot][view.pose], atol=1e-9)
    seen = {(v.robot, v.pose) for v in motion.views}
    assert len(seen) >= 0.9 * sum(len(q) for q in plans.values())


def test_the_recorded_motion_calibrates_the_cell(recording, monkeypatch):
    """Scored against the world the metadata names (``exact``: the cell file itself, here
    without distortion, as the images were made)."""
    path, _, cell = recording
    monkeypatch.setattr("cellsight.calibration.command.load_cell", lambda _arg: cell)
    monkeypatch.setattr("cellsight.calibration.command.draw_world",
                        lambda *_a: type("Draws", (), {"cell": cell})())
    result = calibrate_recorded(path, None, Board())
    assert result.solution.rms_px < 0.15  # OpenCV's own corners in OpenCV's warped board
    for name, e in result.errors["cameras"].items():
        assert e["image_at_work_px"] < 0.2, name
        assert e["centre_mm"] < 0.5, name
    assert result.errors["robots"]["R6AX"]["origin_mm"] < 0.5
    assert result.source["world"] == {"realism": "exact", "seed": 0}
    before = result.errors["cell_file"]  # the cell file's own, here the truth itself
    assert all(e["image_at_work_px"] < 1e-9 and e["centre_mm"] < 1e-9
               for e in before["cameras"].values())
    assert before["robots"]["R6AX"]["origin_mm"] < 1e-9


def test_a_recording_in_which_nothing_moves_is_refused(tmp_path):
    cell, board = _undistorted(load_cell("dual-arm")), Board()
    path = tmp_path / "still.mcap"
    recorder = Recorder(path, cell, cell.workpieces[0].name)
    joints = {r.name: r.home.copy() for r in cell.robots}
    image = _image(cell.cameras[0], board, _board_pose(cell, "R7AX", joints["R7AX"], board))
    for k in range(3):
        recorder.frame(T0 + k, [image, image], None, joints, {}, None)
    recorder.close(True)
    with open_recording(path) as rec, pytest.raises(CellsightError, match="no robot moved"):
        recorded_views(rec, cell, board, TopicMap(), 0.019)


def test_a_board_that_is_not_the_one_in_the_images_is_named(recording):
    path, _, cell = recording
    other = Board(dictionary="DICT_4X4_50")
    with open_recording(path) as rec, pytest.raises(
            CellsightError, match=r"camera cam1 and cam2 found the board in none of the \d+ "
                                  r"poses.*DICT_4X4_50\) may not be the one in the images "
                                  r"\(--board FILE\)"):
        recorded_views(rec, cell, other, TopicMap(), 0.019)


def test_a_recording_of_another_cell_is_refused_naming_what_it_lacks(recording):
    """The UR cell has a third camera and other robots: the recording has neither."""
    path, _, _ = recording
    with open_recording(path) as rec, pytest.raises(
            CellsightError, match="no images of camera cam3 .*it holds: /cam1/camera_info"):
        recorded_views(rec, load_cell("ur-cell"), Board(), TopicMap(), 0.019)

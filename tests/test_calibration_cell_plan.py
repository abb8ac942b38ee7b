"""The whole cell's calibration poses (cellsight.calibration.cell_plan) and the board's views:

- each camera needs one robot presenting the board to it in enough poses, and each robot a
  camera it shares with the robots tied to the reference's base: checked on plans written by
  hand for the line cell's six cameras (a camera no robot covers, a robot whose cameras are
  all its own, and two arms each covering its end of the line, tied by one camera);
- a detection whose corners lie on one line of the board gives no view (six corners in a row
  sent OpenCV's calibrateCamera of a whole camera astray);
- slow, end to end: ``cellsight calibrate --cell line-cell`` calibrates the line's six
  cameras and its second arm's base in ``lab``, scored against the world's truth.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from cellsight.calibration.board import Board, _on_a_line
from cellsight.calibration.cell_plan import _refuse_untied
from cellsight.calibration.plan import MIN_POSES, Plan
from cellsight.cli import main
from cellsight.errors import CellsightError
from cellsight.model.loader import load_cell


@pytest.fixture(scope="module")
def line():
    return load_cell("line-cell")


def _plan(robot: str, seen: dict[str, int]) -> Plan:
    """A plan of ``robot`` whose poses each show the board to one camera, ``seen[camera]``
    poses a camera (joints and flanges left empty: the refusal reads the cameras alone)."""
    cameras = tuple((name,) for name, n in seen.items() for _ in range(n))
    return Plan(robot, np.zeros((len(cameras), 6)), np.tile(np.eye(4), (len(cameras), 1, 1)),
                cameras, {"collision": 7})


def test_two_arms_tied_by_one_camera_are_enough(line):
    enough = MIN_POSES
    _refuse_untied([_plan("R7AX", {"cam1": enough, "cam2": enough, "cam3": enough}),
                    _plan("R6AX", {"cam3": enough, "cam4": enough, "cam5": enough,
                                   "cam6": enough})], line, MIN_POSES)


def test_a_camera_no_robot_covers_is_named_with_each_robots_poses(line):
    plans = [_plan("R7AX", {"cam1": 8, "cam2": 8, "cam3": 8}),
             _plan("R6AX", {"cam3": 8, "cam4": 8, "cam5": 8, "cam6": MIN_POSES - 1})]
    with pytest.raises(CellsightError, match=rf"camera cam6 .*cam6: R7AX 0, R6AX "
                                             rf"{MIN_POSES - 1}.*collision.*aim cam6"):
        _refuse_untied(plans, line, MIN_POSES)


def test_a_robot_whose_cameras_are_all_its_own_is_named(line):
    plans = [_plan("R7AX", {"cam1": 8, "cam2": 8, "cam3": 8}),
             _plan("R6AX", {"cam3": MIN_POSES - 1, "cam4": 8, "cam5": 8, "cam6": 8})]
    with pytest.raises(CellsightError, match=r"robot R6AX .*cam4 and cam5 and cam6.*R7AX's "
                                             r"base \(cam1, cam2, cam3\)"):
        _refuse_untied(plans, line, MIN_POSES)


@pytest.mark.parametrize(("ids", "on_a_line"), [
    (np.arange(6), True),  # the first row of the 6 x 4 inner corners
    (np.arange(0, 24, 6), True),  # a column
    (np.array([0, 7, 14, 21]), True),  # a diagonal
    (np.array([0, 1, 2, 6, 7, 8]), False),  # two rows
    (np.arange(24), False),
])
def test_corners_on_one_line_of_the_board_give_no_view(ids, on_a_line):
    board = Board()
    assert _on_a_line(board.corners()[ids, :2], board.square_m) is on_a_line


@pytest.mark.slow
def test_the_line_cell_calibrates_its_six_cameras_and_second_arm(tmp_path, capsys):
    out = tmp_path / "calibration"
    assert main(["calibrate", "--cell", "line-cell", "--realism", "lab", "--seed", "1",
                 "--out", str(out), "--quiet"]) == 0
    result = json.loads((out / "calibration.json").read_text())
    cameras = result["errors"]["cameras"]
    assert sorted(cameras) == [f"cam{k}" for k in range(1, 7)]
    for name, error in cameras.items():  # the world draws 1 mm and 0.05 deg (lab)
        assert error["image_at_work_px"] < 0.5, (name, error)
        assert error["position_at_work_mm"] < 2.0, (name, error)
    assert result["errors"]["robots"]["R6AX"]["origin_mm"] < 0.5
    assert set(result["poses"]) == {"R7AX", "R6AX"}

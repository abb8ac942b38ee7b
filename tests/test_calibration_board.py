"""The ChArUco calibration board (cellsight.calibration.board) against independent oracles:
its corners against OpenCV's own board, its detection on its own printed image (whose scale is
known), its board file's refusals, and the simulated world rendering it on a robot's flange,
detected, against the true camera's projection of the corners by forward kinematics."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from cellsight.calibration.board import STANDOFF_M, Board, board_world
from cellsight.camera import Camera
from cellsight.control.ik import IKError, solve_ik
from cellsight.errors import CellFileError
from cellsight.geometry.transforms import make_pose, transform_points
from cellsight.model import Cell
from cellsight.model.loader import load_cell

BOARDS = [Board(), Board((5, 7), 0.04, 0.03, "DICT_4X4_50"), Board((3, 2), 0.05, 0.035,
                                                                  "DICT_APRILTAG_36h11")]
ROBOT, CAMERA, DISTANCE_M = "R7AX", "cam1", 1.3  # the board 1.3 m in front of cam1


@pytest.mark.parametrize("board", BOARDS, ids=lambda b: f"{b.squares}")
def test_corners_are_opencvs_own(board: Board):
    cv_corners = board.cv_board().getChessboardCorners()  # float32, row i = corner id i
    assert board.corners().shape == cv_corners.shape
    np.testing.assert_allclose(board.corners(), cv_corners, rtol=0, atol=1e-7)
    outline = board.outline()
    assert (board.corners()[:, :2] > outline.min(axis=0)[:2]).all()
    assert (board.corners()[:, :2] < outline.max(axis=0)[:2]).all()


@pytest.mark.parametrize("px_per_m", [1500.0, 2000.0, 5000.0])
def test_detection_on_the_printed_image_finds_every_corner_where_it_is(px_per_m: float):
    """A fronto-parallel image of known scale: corner (x, y) m is at pixel
    ``(x + margin) px_per_m - 0.5`` (OpenCV's pixel centres); squares of 45 to 150 px."""
    board = Board()
    image = board.texture(px_per_m)
    extent = np.ptp(board.outline()[:, :2], axis=0) * px_per_m
    assert image.shape == tuple(np.round(extent[::-1]).astype(int))
    ids, pixels = board.detect(image)
    np.testing.assert_array_equal(ids, np.arange(len(board.corners())))
    expected = (board.corners()[:, :2] + board.margin_m) * px_per_m - 0.5
    assert np.abs(pixels - expected).max() < 0.1


def test_the_printed_face_faces_minus_z():
    """A camera that reads the printed image (OpenCV's pose of the board from its detected
    corners) sees the face normal pointing at it, and the board frame right-handed."""
    board = Board()
    px_per_m = 2000.0
    ids, pixels = board.detect(board.texture(px_per_m))
    K = np.array([[1000.0, 0, 240], [0, 1000.0, 180], [0, 0, 1]])
    # the image seen 0.5 m away by a camera of focal 1000 px: pixels scaled by 1000 / 0.5 / px_per_m
    scaled = (pixels - pixels.mean(axis=0)) * (1000.0 / 0.5 / px_per_m) + K[:2, 2]
    ok, rvec, _ = cv2.solvePnP(board.corners()[ids], scaled, K, None)
    assert ok
    R = cv2.Rodrigues(rvec)[0]
    assert (R @ board.face_normal)[2] < -0.99  # toward the camera (camera z looks away)
    assert np.linalg.det(R) > 0.99


def test_default_mount_centres_the_face_on_the_flange():
    board = Board()
    T = board.T_flange_board
    centre = transform_points(T, board.corners()).mean(axis=0)
    np.testing.assert_allclose(centre, [0.0, 0.0, STANDOFF_M], atol=1e-12)
    np.testing.assert_allclose(T[:3, :3] @ board.face_normal, [0.0, 0.0, 1.0], atol=1e-12)
    plate = board.plate()
    np.testing.assert_allclose(plate.size_m, np.ptp(board.outline()[:, :2], axis=0))
    np.testing.assert_allclose(plate.T_flange_face @ [0, 0, 0, 1], T @ [*board.outline()[0], 1])


def test_board_file(tmp_path):
    path = tmp_path / "board.yaml"
    path.write_text("squares: [5, 7]\nsquare_m: 0.04\nmarker_m: 0.03\ndictionary: DICT_4X4_50\n"
                    "mount: {xyz: [0.0, 0.0, 0.02], rpy: [3.14159, 0, 0]}\n")
    board = Board.from_yaml(path)
    assert (board.squares, board.square_m, board.marker_m, board.dictionary) == \
        ((5, 7), 0.04, 0.03, "DICT_4X4_50")
    np.testing.assert_allclose(board.T_flange_board[:3, 3], [0.0, 0.0, 0.02])
    matrix = make_pose(np.diag([1.0, -1.0, -1.0]), (0.01, 0.0, 0.03)).tolist()
    path.write_text(f"mount: {matrix}\n")
    np.testing.assert_allclose(Board.from_yaml(path).T_flange_board, matrix)
    path.write_text("")
    assert Board.from_yaml(path).squares == Board().squares


@pytest.mark.parametrize("text, field, value", [
    ("dictionary: DICT_5X5_1OO", "dictionary", "DICT_5X5_1OO"),
    ("dictionary: DICT_4X4_50\nsquares: [11, 11]", "dictionary", "DICT_4X4_50"),
    ("marker_m: 0.03", "marker_m", "0.03"),
    ("square_m: 0.0", "square_m", "0.0"),
    ("thickness_m: -0.01", "thickness_m", "-0.01"),
    ("squares: [1, 5]", "squares", "(1, 5)"),
    ("mount: [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]", "mount", "2.0"),
    ("mount: [[1, 0, 0], [0, 1, 0]]", "mount", "[[1, 0, 0]"),
    ("mount: {xyz: [0, 0]}", "mount.xyz", "[0, 0]"),
    ("sqaures: [7, 5]", "sqaures", "[7, 5]"),
])
def test_board_file_refusals_name_the_file_field_and_value(tmp_path, text, field, value):
    path = tmp_path / "bad.yaml"
    path.write_text(text + "\n")
    with pytest.raises(CellFileError) as info:
        Board.from_yaml(path)
    assert str(path) in str(info.value)
    assert info.value.field == field
    assert value in str(info.value)


def test_boards_built_in_code_are_checked():
    with pytest.raises(CellFileError, match="T_flange_board"):
        Board(T_flange_board=np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(CellFileError, match="marker_m"):
        Board(square_m=0.02)


def _facing_pose(cell: Cell, board: Board) -> np.ndarray:
    """Joints of ROBOT (the cell's IK, without its tool: the TCP is the flange) that put the
    board's centre DISTANCE_M along CAMERA's axis, its face toward the camera, every corner at
    least 40 px inside the image: the first of four turns about the normal that has one."""
    robot, cam = cell.robot(ROBOT), next(c for c in cell.cameras if c.name == CAMERA)
    axis = cam.T_base_cam[:3, 2]
    z = -axis  # the flange's z, the face's normal, toward the camera
    x0 = np.cross(z, [0.0, 0.0, 1.0])
    x0 /= np.linalg.norm(x0)
    for turn in np.radians([0.0, 90.0, 180.0, 270.0]):
        x = np.cos(turn) * x0 + np.sin(turn) * np.cross(z, x0)
        R = np.column_stack([x, np.cross(z, x), z])
        T_base_flange = make_pose(R, cam.center + DISTANCE_M * axis - STANDOFF_M * z)
        try:
            solutions = solve_ik(replace(robot, tool=None), T_base_flange, seeds=8).solutions
        except IKError:
            continue
        for s in solutions:
            pixels = cam.project(_true_corners(robot, s.q, board))
            if cam.in_image(pixels, margin=40.0).all():
                return s.q
    raise AssertionError("no joints found that show the board to the camera")


def _true_corners(robot, q: np.ndarray, board: Board) -> np.ndarray:
    """The corners (base frame, m) by forward kinematics: the oracle, never MuJoCo."""
    T_base_flange = robot.T_base_robot @ robot.chain.fkine(q)[-1]
    return transform_points(T_base_flange @ board.T_flange_board, board.corners())


@pytest.fixture(scope="module")
def shown():
    """The built-in cell's world (exact: no realism errors) with ROBOT carrying the default
    board, facing CAMERA; a third camera, CAMERA's twin with lens distortion; rendered once."""
    cell, board = load_cell(None), Board()
    q = _facing_pose(cell, board)
    cam = next(c for c in cell.cameras if c.name == CAMERA)
    twin = Camera(cam.K, cam.width, cam.height, cam.T_base_cam,
                  [-0.25, 0.12, 0.0008, -0.0005, 0.0], f"{CAMERA}_distorted")
    world_cell = Cell(cell.name, cell.robots, cell.workpieces, cell.static,
                      [*cell.cameras, twin])
    world = board_world(world_cell, ROBOT, board, initial_joints={ROBOT: q})
    world.step()
    images = world.render(cameras=[0, 2])
    yield world, board, q, [world_cell.cameras[0], twin], [images[0], images[2]]
    world.close()


def test_the_world_with_a_board_is_clear_and_holds_the_joints(shown):
    world, board, q, _, _ = shown
    np.testing.assert_allclose(world.true_joints()[ROBOT], q, atol=1e-9)
    assert world.collisions() == []
    assert ROBOT not in world.jaw_openings()


@pytest.mark.parametrize("view", [0, 1], ids=["pinhole", "distorted"])
def test_the_board_on_the_flange_is_detected_where_the_true_camera_sees_it(shown, view):
    world, board, q, cameras, images = shown
    cam, image = cameras[view], images[view]
    ids, pixels = board.detect(image)
    assert len(ids) >= 0.8 * len(board.corners())
    errors = np.linalg.norm(pixels - cam.project(_true_corners(world.cell.robot(ROBOT), q,
                                                                board)[ids]), axis=1)
    assert np.median(errors) <= 0.3
    assert errors.max() <= 1.0

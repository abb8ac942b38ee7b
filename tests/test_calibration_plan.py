"""The robot poses of a cell calibration (cellsight.calibration.plan) on the built-in cell, for
each of its robots, checked independently of the planner:

- projections by ``cv2.projectPoints`` (the camera's K, distortion and pose) of the board's
  corners placed by the robot's own forward kinematics at the planned joints: inside every
  intended camera's image with the margin, in front of it, squares wide enough, the face
  turned toward the camera;
- collisions in the simulated world (:class:`cellsight.world.ReplayWorld`, MuJoCo's contacts)
  with the robot's tool removed and the board's plate as a workpiece, at every pose and along
  every straight joint-space move between them; and, as MuJoCo does not collide a workpiece
  (a mocap body) with static objects, the plate's points against the static solids' faces here;
- occlusion by the world's MuJoCo ray casts (``true_views``), not the planner's predictor;
- hand-eye observability: the axes of the relative rotations between poses span 3D;
- a camera looking away from everything is refused, naming the robot and the camera; so is a
  start where the board hits the robot's forearm, naming both.

The flange link of the built-in cell's robots reaches 30 mm through the plate (its wrist solid
overshoots the flange, where the gripper was): their contact is the mount, and a ray it stops
is no occlusion (the planner leaves that link out of the occluders, for the same reason).
"""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cellsight.calibration.board import Board
from cellsight.calibration.cell_plan import plan_poses
from cellsight.calibration.plan import SAME_POSE
from cellsight.calibration.presenting import BoardOnFlange
from cellsight.camera import Camera
from cellsight.errors import CellsightError
from cellsight.geometry.polyhedron import Polyhedron
from cellsight.geometry.transforms import look_at, make_pose
from cellsight.model.cell import Cell, Workpiece
from cellsight.model.loader import load_cell
from cellsight.world import ReplayWorld

SQUARE = 0.03  # m
FACE_Z = 0.01  # m: the printed face, out of the flange along its z
PLATE = 0.005  # m: the plate's thickness, behind the face
MARGIN_PX, MAX_VIEW_DEG, MIN_SQUARE_PX = 20.0, 60.0, 15.0
LIMIT_MARGIN = 0.05  # rad or m
MOVE_STEP = 0.05  # rad or m: the oracle's sampling of each move


def _board() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 7 x 5 ChArUco board of 30 mm squares centred on the flange axis, its face 10 mm out
    along flange z: the 6 x 4 inner corners (row-major, x fastest), the normal, the outline."""
    xs, ys = np.meshgrid((np.arange(6) - 2.5) * SQUARE, (np.arange(4) - 1.5) * SQUARE)
    corners = np.column_stack([xs.ravel(), ys.ravel(), np.full(24, FACE_Z)])
    hx, hy = 3.5 * SQUARE, 2.5 * SQUARE
    outline = np.array([[-hx, -hy, FACE_Z], [hx, -hy, FACE_Z], [hx, hy, FACE_Z],
                        [-hx, hy, FACE_Z]])
    return corners, np.array([0.0, 0.0, 1.0]), outline


CORNERS, NORMAL, OUTLINE = _board()
BOARD = BoardOnFlange.from_flange(CORNERS, NORMAL, OUTLINE)


def _plate() -> Polyhedron:
    """The plate (flange frame) as a box behind the face, its features the corners."""
    hx, hy = 3.5 * SQUARE, 2.5 * SQUARE
    box = np.array([[x, y, z] for z in (FACE_Z - PLATE, FACE_Z) for y in (-hy, hy)
                    for x in (-hx, hx)])
    faces = ((0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (1, 3, 7, 5), (3, 2, 6, 7),
             (2, 0, 4, 6))
    return Polyhedron("board", np.vstack([box, CORNERS]), faces,
                      feature_vertices=tuple(range(8, 8 + len(CORNERS))))


@pytest.fixture(scope="module")
def cell() -> Cell:
    return load_cell(None)


@pytest.fixture(scope="module", params=["R7AX", "R6AX"])
def planned(request, cell):
    """(robot name, plan)."""
    return request.param, plan_poses(cell, request.param, BOARD)


def _flange(cell: Cell, robot: str, q: np.ndarray) -> np.ndarray:
    """``T_base_flange`` by the robot's own forward kinematics."""
    r = cell.robot(robot)
    return r.T_base_robot @ r.chain.fkine(q)[-1]


def test_every_camera_gets_enough_poses_inside_the_limits(cell, planned):
    robot, plan = planned
    counts = plan.per_camera()
    assert {cam.name for cam in cell.cameras} <= set(counts), counts
    assert min(counts.values()) >= 6, counts
    qlim = cell.robot(robot).chain.qlim
    assert plan.joints.shape == (len(plan.cameras), cell.robot(robot).n_joints)
    assert np.all(plan.joints >= qlim[:, 0] + LIMIT_MARGIN - 1e-9)
    assert np.all(plan.joints <= qlim[:, 1] - LIMIT_MARGIN + 1e-9)
    for q, T in zip(plan.joints, plan.T_base_flange, strict=True):
        np.testing.assert_allclose(T, _flange(cell, robot, q), atol=1e-9)
    apart = np.abs(plan.joints[:, None] - plan.joints[None]).max(axis=2)
    np.fill_diagonal(apart, np.inf)
    assert apart.min() > SAME_POSE  # no pose twice (two candidates' IK can meet)


def test_more_poses_keep_every_pose_of_fewer(cell):
    """The search gives every camera 8 poses first (``FIRST_ROUND``), then seeks more: the plan
    of 16 holds every pose of the plan of 8, so no camera has fewer (sought at once, a camera
    easy to reach drew the tries and a hard one's poses no longer fitted the route: with the
    default board, seed 6 gave cam2 5 poses of 16 and was refused)."""
    mounted = Board().on_flange()
    fewer = plan_poses(cell, "R6AX", mounted, per_camera=8, seed=6)
    more = plan_poses(cell, "R6AX", mounted, per_camera=16, seed=6)
    assert len(more.joints) > len(fewer.joints)
    for q in fewer.joints:
        assert np.abs(more.joints - q).max(axis=1).min() < 1e-12
    counts = more.per_camera()
    assert all(counts[name] >= n for name, n in fewer.per_camera().items()), (counts, fewer)


def test_the_intended_cameras_see_the_whole_board_by_opencv(cell, planned):
    robot, plan = planned
    for q, names in zip(plan.joints, plan.cameras, strict=True):
        T = _flange(cell, robot, q)
        points = CORNERS @ T[:3, :3].T + T[:3, 3]
        centre = points.mean(axis=0)
        for name in names:
            cam = cell.camera(name)
            R, t = cam.T_cam_base[:3, :3], cam.T_cam_base[:3, 3]
            px, _ = cv2.projectPoints(points, cv2.Rodrigues(R)[0], t, cam.K,
                                      np.zeros(5) if cam.dist is None else cam.dist)
            px = px.reshape(-1, 2)
            assert np.all(points @ R[2] + t[2] > 0)
            assert px.min() >= MARGIN_PX - 0.5
            assert np.all(px <= np.array([cam.width, cam.height]) - 0.5 - MARGIN_PX)
            grid = px.reshape(4, 6, 2)
            steps = np.concatenate([np.diff(grid, axis=0).reshape(-1, 2),
                                    np.diff(grid, axis=1).reshape(-1, 2)])
            assert np.linalg.norm(steps, axis=1).min() >= MIN_SQUARE_PX
            sight = cam.T_base_cam[:3, 3] - centre
            cosine = (T[:3, :3] @ NORMAL) @ sight / np.linalg.norm(sight)
            assert cosine >= math.cos(math.radians(MAX_VIEW_DEG)) - 1e-9


def _world(cell: Cell, robot: str) -> ReplayWorld:
    """The world with the robot's tool removed and the plate a workpiece, parked far away."""
    robots = [replace(r, tool=None) if r.name == robot else r for r in cell.robots]
    parts = [*cell.workpieces, Workpiece("board", _plate(), make_pose(None, (0, 0, 50)))]
    return ReplayWorld(Cell("with board", robots, parts, cell.static, cell.cameras))


def _static_hits(cell: Cell, T_base_flange: np.ndarray) -> list[str]:
    """The static objects (convex solids) and the floor that points of the plate are inside."""
    hx, hy = 3.5 * SQUARE, 2.5 * SQUARE
    u, v, w = np.meshgrid(np.linspace(-hx, hx, 15), np.linspace(-hy, hy, 11),
                          (FACE_Z - PLATE, FACE_Z))
    points = np.column_stack([u.ravel(), v.ravel(), w.ravel()])
    points = points @ T_base_flange[:3, :3].T + T_base_flange[:3, 3]
    hits = ["floor"] if points[:, 2].min() < 0 else []
    for obj in cell.static:
        for solid in obj.solids:
            local = (points - obj.T_base_obj[:3, 3]) @ obj.T_base_obj[:3, :3]
            anchors = np.array([solid.vertices[f[0]] for f in solid.faces])
            outside = ((local[:, None, :] - anchors[None]) * solid.normals[None]).sum(axis=2)
            if (outside.max(axis=1) < 0).any():
                hits.append(obj.name)
    return hits


def _move(q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """The straight joint-space move from ``q0`` to ``q1``, every ``MOVE_STEP`` at most, its
    end included."""
    steps = max(1, math.ceil(np.abs(q1 - q0).max() / MOVE_STEP))
    return q0 + np.linspace(0.0, 1.0, steps + 1)[1:, None] * (q1 - q0)


def test_the_oracles_see_a_board_in_the_table_or_in_a_gripper(cell):
    assert _static_hits(cell, make_pose(None, (0.8, 0.3, 0.53))) == ["table"]
    world = _world(cell, "R6AX")
    try:
        r7 = cell.robot("R7AX")
        world.show_state({}, {"board": r7.tool_pose(r7.home)})
        world.contacts.check(0.1)
        assert {"R7AX.gripper", "board"} in [set(c["bodies"]) for c in world.collisions()]
    finally:
        world.close()


def test_poses_and_moves_are_free_of_collisions_and_the_board_is_not_hidden(cell, planned):
    robot, plan = planned
    world = _world(cell, robot)
    flange_link = f"{robot}.{cell.robot(robot).link_groups()[-1][1]}"
    names = [cam.name for cam in cell.cameras]
    t, previous = 0.0, cell.robot(robot).home
    try:
        for q_end, seen_by in zip(plan.joints, plan.cameras, strict=True):
            for q in _move(previous, q_end):
                T = _flange(cell, robot, q)
                world.show_state({robot: q}, {"board": T})
                t += 0.2
                world.contacts.check(t)
                assert _static_hits(cell, T) == [], (robot, q)
            previous = q_end
            views = world.true_views()["board"]
            for name in seen_by:
                hidden = [why for why in views[names.index(name)].reason
                          if why not in ("", flange_link)]
                assert hidden == [], (robot, name, q_end, hidden)
        hits = [c["bodies"] for c in world.collisions()
                if sorted(c["bodies"]) != sorted(["board", flange_link])]
        assert hits == [], f"{robot}: {hits}"
    finally:
        world.close()


def test_relative_rotations_turn_about_axes_in_every_direction(cell, planned):
    robot, plan = planned
    R = [_flange(cell, robot, q)[:3, :3] for q in plan.joints]
    turns = Rotation.from_matrix([a.T @ b for i, a in enumerate(R) for b in R[i + 1:]])
    vectors = turns.as_rotvec()
    axes = vectors[turns.magnitude() > math.radians(5)]
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    sigma = np.linalg.svd(axes, compute_uv=False)
    assert sigma[-1] / sigma[0] > 0.2, (robot, sigma)


def test_a_camera_looking_away_is_refused(cell):
    away = Camera.from_intrinsics(640, 480, look_at((0.8, 0.0, 2.0), (0.8, 0.0, 4.0),
                                                    up=(0.0, 1.0, 0.0)), 600.0,
                                  name="cam3")
    with_away = Cell(cell.name, cell.robots, cell.workpieces, cell.static,
                     [*cell.cameras, away])
    with pytest.raises(CellsightError, match=r"R7AX.*cam3.*aim it at the work area"):
        plan_poses(with_away, "R7AX", BOARD)
    with pytest.raises(CellsightError, match="no camera 'cam9'"):
        plan_poses(cell, "R7AX", BOARD, cameras=["cam9"])
    with pytest.raises(CellsightError, match="no robot 'R9'"):
        plan_poses(cell, "R9", BOARD)


def test_a_start_where_the_board_hits_the_forearm_is_refused(cell):
    folded = cell.robot("R6AX").home.copy()
    folded[4] = 2.15  # the wrist bent further than HOME's 1.839 rad: the plate meets link4
    with pytest.raises(CellsightError, match=r"R6AX.*R6AX\.link4.*calibration_board.*start="):
        plan_poses(cell, "R6AX", BOARD, start=folded)

"""The joint least-squares solver of the cell calibration (cellsight.calibration.solve) on a
synthetic cell with a known truth: two cameras (768 x 576 px, f ~1930 px, ~1.3 m from the work
area, with distortion), two six-axis robots (standard DH), a 7 x 5 board of 30 mm squares (its
24 inner corners) bolted to each flange, 16 poses per robot tilting the board about every axis.

The oracle: the corners' pixels by ``cv2.projectPoints`` (the true K, distortion and the board's
pose in the camera from the true bases, mounts and joints), never the solver's projection. The
solver starts from values off the truth (cameras by ~10 mm, 1 deg and 1 % of focal length, the
other base by ~5 mm, the mounts by ~5 mm and 1 deg) and sees only pixels and joint readings.

- without noise it recovers the truth to 1e-6 (m, rad, relative focal length) and reprojects
  to below 1e-6 px; with joint offsets free (true offsets 0.01-0.03 deg on every joint) it
  recovers the middle joints' offsets and, for the first and last joints, which the gauge
  holds at zero, the truth carried into the gauge (module docstring of the solver); a robot
  whose last two joints are coaxial gets the second-last offset reported not identifiable;
- with 0.2 px of Gaussian noise (20 seeds) the reported standard deviations of a camera's
  position and focal lengths agree with the spread of the estimates around the truth within a
  factor of 2: the spread of 20 draws is sigma sqrt(chi2_20 / 20), below sigma / 2 with
  probability 1e-4 and above 2 sigma with about 1e-9 (a factor 1.5 would fail with about 2 %
  per quantity);
- OpenCV's hand-eye, as the solver maps it, gives the camera in the base and the board on the
  flange;
- each refusal names the camera or the robot, the poses, and what to do.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cellsight.calibration.first_estimate import hand_eye
from cellsight.calibration.solution import Start, View
from cellsight.calibration.solve import calibrate
from cellsight.calibration.solve_checks import MIN_POSES
from cellsight.camera import Camera
from cellsight.errors import CellsightError
from cellsight.geometry.transforms import invert_pose, look_at, make_pose
from cellsight.kinematics import DHChain, DHLink

HALF_PI = np.pi / 2
WIDTH, HEIGHT = 768, 576
CENTRE = np.array([0.85, 0.05, 0.85])  # m: the work area, in the reference robot's frame
NOMINAL = np.array([0.0, 0.2, 0.4, 0.0, -2.17, 0.0])  # rad: the flange up, over the centre
SPREAD = np.array([0.12, 0.1, 0.1, 0.6, 0.35, 1.0])  # rad: the poses' draw around it
POSES = 16  # per robot
MARGIN_PX = 10.0
MAX_VIEW_DEG = 70.0  # the board's face at most this far from facing a camera
NOISE_PX, SEEDS = 0.2, 20
DQ = {"R1": np.radians([0.02, -0.015, 0.025, 0.01, -0.03, 0.02]),
      "R2": np.radians([-0.01, 0.03, -0.02, 0.015, 0.02, -0.025])}


def _links() -> list[DHLink]:
    """A six-axis arm's standard DH links (m, rad)."""
    return [DHLink(a=0.15, alpha=-HALF_PI, d=0.45), DHLink(a=0.59, theta=-HALF_PI),
            DHLink(a=0.13, alpha=-HALF_PI), DHLink(d=0.647, alpha=HALF_PI),
            DHLink(alpha=-HALF_PI), DHLink(d=0.095)]


def _board_points() -> np.ndarray:
    """The 6 x 4 inner corners of a 7 x 5 board of 30 mm squares, centred, z = 0 (m)."""
    x, y = np.meshgrid(np.arange(6) * 0.03 - 0.075, np.arange(4) * 0.03 - 0.045)
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


def _pose(rpy_deg, xyz) -> np.ndarray:
    return make_pose(Rotation.from_euler("xyz", rpy_deg, degrees=True).as_matrix(), xyz)


CHAINS = {name: DHChain(_links(), name) for name in ("R1", "R2")}
BOARD = _board_points()
CAMERAS = [
    Camera.from_intrinsics(WIDTH, HEIGHT, look_at((0.85, -1.0, 1.6), CENTRE), (1930.0, 1925.0),
                           principal=(380.0, 290.0), name="cam1",
                           dist=np.array([-0.12, 0.08, 0.0, 0.0, 0.01])),
    Camera.from_intrinsics(WIDTH, HEIGHT, look_at((0.25, 0.95, 1.7), CENTRE), (1935.0, 1932.0),
                           principal=(388.0, 284.0), name="cam2",
                           dist=np.array([-0.1, 0.05, 0.0, 0.0, 0.0])),
]
BASES = {"R1": np.eye(4), "R2": _pose((0.0, 0.0, 180.0), (1.70, 0.1, 0.0))}
MOUNTS = {"R1": _pose((2.0, -3.0, 40.0), (0.004, -0.006, 0.012)),
          "R2": _pose((-2.0, 1.0, -70.0), (-0.003, 0.005, 0.011))}


def _pixels(camera: Camera, T_ref_board: np.ndarray) -> np.ndarray:
    """The oracle: the board's corners by ``cv2.projectPoints`` (px, distorted)."""
    T = invert_pose(camera.T_base_cam) @ T_ref_board
    pixels, _ = cv2.projectPoints(BOARD, cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], camera.K,
                                  camera.dist5)
    return pixels.reshape(-1, 2)


def _board_pose(robot: str, q: np.ndarray, chains=CHAINS) -> np.ndarray:
    return BASES[robot] @ chains[robot].fkine(q)[-1] @ MOUNTS[robot]


def _in_view(T_ref_board: np.ndarray) -> bool:
    """Every corner inside both images with the margin, the face turned to both cameras."""
    for camera in CAMERAS:
        pixels = _pixels(camera, T_ref_board)
        facing = -(invert_pose(camera.T_base_cam) @ T_ref_board)[2, 2]
        inside = (pixels >= MARGIN_PX) & (pixels <= np.array([WIDTH, HEIGHT]) - MARGIN_PX)
        if not inside.all() or facing < np.cos(np.radians(MAX_VIEW_DEG)):
            return False
    return True


@pytest.fixture(scope="module")
def joints() -> dict[str, np.ndarray]:
    """The true joints (POSES, 6) of each robot: random around NOMINAL, the board in view."""
    rng = np.random.default_rng(1)
    out = {}
    for robot in CHAINS:
        found: list[np.ndarray] = []
        while len(found) < POSES:
            q = NOMINAL + rng.uniform(-SPREAD, SPREAD)
            if _in_view(_board_pose(robot, q)):
                found.append(q)
        out[robot] = np.array(found)
    return out


def _views(joints: dict[str, np.ndarray], offsets: dict[str, np.ndarray] | None = None,
           noise: float = 0.0, seed: int = 0, chains=CHAINS) -> list[View]:
    """Every camera's view of every pose; the encoders read the true joints minus the
    offsets (true = reading + offset)."""
    rng = np.random.default_rng(seed)
    views = []
    for robot, qs in joints.items():
        for pose, q in enumerate(qs):
            reading = q - (offsets[robot] if offsets else 0.0)
            for c, camera in enumerate(CAMERAS):
                pixels = _pixels(camera, _board_pose(robot, q, chains))
                pixels = pixels + rng.normal(0.0, noise, pixels.shape)
                views.append(View(c, robot, pose, reading, np.arange(len(BOARD)), pixels))
    return views


def _off(T: np.ndarray, mm: float, deg: float, rng: np.random.Generator) -> np.ndarray:
    """``T`` turned by ``deg`` about a random axis and moved by ``mm`` in a random direction."""
    axis, way = rng.normal(size=3), rng.normal(size=3)
    turn = Rotation.from_rotvec(np.radians(deg) * axis / np.linalg.norm(axis)).as_matrix()
    return make_pose(turn @ T[:3, :3], T[:3, 3] + 1e-3 * mm * way / np.linalg.norm(way))


def _start(chains=CHAINS) -> Start:
    """The truth made wrong: cameras by 10 mm, 1 deg, +1 % / -1 % focal, 5 / -4 px principal
    point and no distortion (k3 as the truth's: it is held), R2's base by 5 mm and 0.5 deg,
    the mounts by 5 mm and 1 deg."""
    rng = np.random.default_rng(5)
    cameras = []
    for camera in CAMERAS:
        K = camera.K * np.array([[1.01, 1, 1], [1, 0.99, 1], [1, 1, 1]]) + [[0, 0, 5], [0, 0, -4],
                                                                           [0, 0, 0]]
        cameras.append(Camera(K, WIDTH, HEIGHT, _off(camera.T_base_cam, 10.0, 1.0, rng),
                              np.array([0.0, 0.0, 0.0, 0.0, camera.dist5[4]]), camera.name))
    return Start(cameras, {"R1": np.eye(4), "R2": _off(BASES["R2"], 5.0, 0.5, rng)},
                 {r: _off(MOUNTS[r], 5.0, 1.0, rng) for r in chains})


def _pose_error(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Position (m) and angle (rad) between two poses."""
    angle = Rotation.from_matrix(estimate[:3, :3].T @ truth[:3, :3]).magnitude()
    return float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3])), float(angle)


def _assert_pose(estimate: np.ndarray, truth: np.ndarray, tol: float = 1e-6) -> None:
    position, angle = _pose_error(estimate, truth)
    assert position < tol and angle < tol, (position, angle)


def _assert_cameras(solution, truths: list[np.ndarray]) -> None:
    for camera, true, T in zip(solution.cameras, CAMERAS, truths, strict=True):
        _assert_pose(camera.T_base_cam, T)
        focal = np.array([camera.K[0, 0], camera.K[1, 1]]) / [true.K[0, 0], true.K[1, 1]] - 1
        assert np.abs(focal).max() < 1e-6, focal
        assert np.abs(camera.K[:2, 2] - true.K[:2, 2]).max() < 1e-4  # px
        assert np.abs(camera.dist5 - true.dist5).max() < 1e-6
        assert (camera.name, camera.width, camera.height) == (true.name, WIDTH, HEIGHT)


@pytest.fixture(scope="module")
def exact(joints):
    return calibrate(_views(joints), BOARD, CHAINS, _start())


def test_the_start_is_off_the_truth():
    start = _start()
    for camera, true in zip(start.cameras, CAMERAS, strict=True):
        assert _pose_error(camera.T_base_cam, true.T_base_cam)[0] > 5e-3
    assert _pose_error(start.T_ref_robot["R2"], BASES["R2"])[0] > 2e-3


def test_without_noise_the_truth_is_recovered(exact):
    _assert_cameras(exact, [camera.T_base_cam for camera in CAMERAS])
    for robot in CHAINS:
        _assert_pose(exact.T_ref_robot[robot], BASES[robot])
        _assert_pose(exact.T_flange_board[robot], MOUNTS[robot])
        assert not exact.joint_offsets[robot].any()
        assert np.isnan(exact.joint_offset_std[robot]).all()
    assert exact.rms_px < 1e-6
    assert np.max(exact.view_rms_px) < 1e-6 and np.max(exact.camera_rms_px) < 1e-6
    assert len(exact.residuals_px) == 2 * len(CHAINS) * POSES
    assert all(r.shape == (len(BOARD), 2) for r in exact.residuals_px)


def test_the_reference_base_is_not_estimated(exact):
    assert np.array_equal(exact.T_ref_robot["R1"], np.eye(4))
    assert np.isnan(exact.robot_std["R1"].position_mm).all()
    assert np.isfinite(exact.robot_std["R2"].position_mm).all()


def _first(chain: DHChain, dq: float) -> np.ndarray:
    """What an offset of the first joint does: ``fkine(q + dq e1) = G fkine(q)``."""
    q = NOMINAL.copy()
    moved = q.copy()
    moved[0] += dq
    return chain.fkine(moved)[-1] @ invert_pose(chain.fkine(q)[-1])


def _last(chain: DHChain, dq: float) -> np.ndarray:
    """What an offset of the last joint does: ``fkine(q + dq en) = fkine(q) X``."""
    q = NOMINAL.copy()
    moved = q.copy()
    moved[-1] += dq
    return invert_pose(chain.fkine(q)[-1]) @ chain.fkine(moved)[-1]


def test_joint_offsets_are_recovered_up_to_the_gauge(joints):
    solution = calibrate(_views(joints, DQ), BOARD, CHAINS, _start(), joint_offsets=True)
    # the gauge: the first and last offsets are zero; the truth seen through them
    G = {r: _first(CHAINS[r], DQ[r][0]) for r in CHAINS}
    X = {r: _last(CHAINS[r], DQ[r][-1]) for r in CHAINS}
    T_gauge_ref = invert_pose(G["R1"])
    _assert_cameras(solution, [T_gauge_ref @ camera.T_base_cam for camera in CAMERAS])
    _assert_pose(solution.T_ref_robot["R2"], T_gauge_ref @ BASES["R2"] @ G["R2"])
    for robot in CHAINS:
        _assert_pose(solution.T_flange_board[robot], X[robot] @ MOUNTS[robot])
        estimated = solution.joint_offsets[robot]
        assert np.abs(estimated[1:-1] - DQ[robot][1:-1]).max() < 1e-6
        assert estimated[0] == estimated[-1] == 0.0
        identifiable = solution.joint_offsets_identifiable[robot]
        assert identifiable.tolist() == [False, True, True, True, True, False]
        assert np.isnan(solution.joint_offset_std[robot][[0, -1]]).all()
    assert solution.rms_px < 1e-6


def test_an_offset_coaxial_with_the_last_joint_is_not_identifiable(joints):
    """R2 with a seventh joint on the flange's axis (its readings zero): the sixth joint's
    offset then turns the board as the seventh's, which the mount absorbs."""
    chains = {**CHAINS, "R2": DHChain([*_links(), DHLink()], "R2")}
    joints = {**joints, "R2": np.column_stack([joints["R2"], np.zeros(POSES)])}
    solution = calibrate(_views(joints, chains=chains), BOARD, chains, _start(chains),
                         joint_offsets=True)
    assert solution.rms_px < 1e-6
    assert solution.joint_offsets_identifiable["R2"].tolist() == [False, True, True, True,
                                                                  True, False, False]
    assert solution.joint_offset_sine["R2"][5] < 1e-6
    assert solution.joint_offsets_identifiable["R1"][1:-1].all()


def test_held_intrinsics_stay_and_the_poses_are_recovered(joints):
    """The start's intrinsics (the truth's) held; a known pixel noise scales the deviations
    (the residuals, zero here, do not)."""
    start = _start()
    start = replace(start, cameras=[replace(true, T_base_cam=camera.T_base_cam)
                                    for camera, true in zip(start.cameras, CAMERAS,
                                                            strict=True)])
    solution = calibrate(_views(joints), BOARD, CHAINS, start, free_intrinsics=False,
                         pixel_sigma=NOISE_PX)
    _assert_cameras(solution, [camera.T_base_cam for camera in CAMERAS])
    for camera, true in zip(solution.cameras, CAMERAS, strict=True):
        assert np.array_equal(camera.K, true.K)
    std = solution.camera_std[0]
    assert np.isnan(std.focal_pct).all() and np.isnan(std.principal_px).all()
    assert np.all((std.pose.position_mm > 0.01) & (std.pose.position_mm < 10.0))


def test_hand_eye_gives_the_camera_in_the_base_and_the_board_on_the_flange(joints):
    """OpenCV's robot-world hand-eye as the solver maps it, on exact poses."""
    T_base_flange = np.array([CHAINS["R2"].fkine(q)[-1] for q in joints["R2"]])
    T_base_cam = invert_pose(BASES["R2"]) @ CAMERAS[1].T_base_cam
    T_cam_board = invert_pose(T_base_cam) @ T_base_flange @ MOUNTS["R2"]
    found_cam, found_board = hand_eye(T_cam_board, T_base_flange)
    _assert_pose(found_cam, T_base_cam, 1e-8)
    _assert_pose(found_board, MOUNTS["R2"], 1e-8)


@pytest.fixture(scope="module")
def noisy(joints):
    """(per seed: camera 0's position (m), its fx and fy (px); their reported standard
    deviations (mm, %)) over SEEDS draws of NOISE_PX noise."""
    start = _start()
    runs = []
    for seed in range(SEEDS):
        solution = calibrate(_views(joints, noise=NOISE_PX, seed=seed), BOARD, CHAINS, start)
        camera, std = solution.cameras[0], solution.camera_std[0]
        runs.append((camera.T_base_cam[:3, 3], camera.K[[0, 1], [0, 1]],
                     std.pose.position_mm, std.focal_pct, solution.rms_px))
    return [np.array(column) for column in zip(*runs, strict=True)]


def test_the_reported_deviations_match_the_spread_under_noise(noisy):
    position, focal, position_mm, focal_pct, rms = noisy
    truth = CAMERAS[0]
    spread_mm = 1e3 * np.sqrt(np.mean((position - truth.T_base_cam[:3, 3]) ** 2, axis=0))
    true_focal = np.array([truth.K[0, 0], truth.K[1, 1]])
    spread_pct = 100 * np.sqrt(np.mean((focal / true_focal - 1) ** 2, axis=0))
    for spread, reported in ((spread_mm, position_mm), (spread_pct, focal_pct)):
        ratio = spread / reported.mean(axis=0)
        assert np.all((ratio > 0.5) & (ratio < 2.0)), (spread, reported.mean(axis=0))
    assert np.abs(rms / (NOISE_PX * np.sqrt(2)) - 1).max() < 0.05  # px: two coordinates


REFUSALS = ["camera cam3 has no view", "camera cam2 sees the board in 4 distinct poses",
            f"robot 'R2' shows the board in {MIN_POSES - 1} distinct poses .*R2 pose 4.* plan",
            r"robot 'R2', poses \[0, 1, .*\]: the flange turns about one axis only",
            "reference robot 'R1' shows the board to no camera"]


def _refused(message: str, joints: dict[str, np.ndarray]) -> tuple[list[View], Start]:
    """The input refused with ``message``: a camera without views, a camera with too few
    poses, a robot with too few poses, a robot whose flange turns about its own axis only, a
    reference robot that shows the board to no camera."""
    views, start = _views(joints), _start()
    if message.startswith("camera cam3"):
        return views, replace(start, cameras=[*start.cameras, replace(CAMERAS[1], name="cam3")])
    if message.startswith("camera cam2"):
        return [v for v in views if v.camera == 0 or v.robot == "R1" and v.pose < 4], start
    if "distinct poses" in message:
        return [v for v in views if v.robot == "R1" or v.pose < MIN_POSES - 1], start
    if "one axis" in message:
        turning = np.array([NOMINAL + [0, 0, 0, 0, 0, a] for a in np.linspace(-1.0, 1.0, 8)])
        return _views({**joints, "R2": turning}), start
    return [v for v in views if v.robot == "R2"], start


@pytest.mark.parametrize("message", REFUSALS)
def test_each_refusal_names_what_and_what_to_do(message, joints):
    views, start = _refused(message, joints)
    with pytest.raises(CellsightError, match=message):
        calibrate(views, BOARD, CHAINS, start)


def test_a_malformed_view_is_refused(joints):
    view = _views({"R1": joints["R1"][:1]})[0]
    bad = replace(view, ids=np.array([0, 1, 2, 99]), pixels=view.pixels[:4])
    with pytest.raises(CellsightError, match=r"camera 0, robot 'R1', pose 0: .*\[0, 24\)"):
        calibrate([bad], BOARD, CHAINS, _start())
    with pytest.raises(CellsightError, match="camera 7.*no such camera"):
        calibrate([replace(view, camera=7)], BOARD, CHAINS, _start())
    with pytest.raises(CellsightError, match="pose 0: R1: expected 6 joint values, got 5"):
        calibrate([replace(view, joints=view.joints[:5])], BOARD, CHAINS, _start())

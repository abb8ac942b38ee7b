"""Cameras from calibration files (issue 15, part 2): intrinsics from OpenCV FileStorage
YAML/XML or ROS camera_info, poses from eye-to-hand hand-eye results (easy_handeye, OpenCV),
the writers of the same formats and ``cellsight cameras``.

Oracles, independent of cellsight's readers: files written by ``cv2.FileStorage`` or by hand in
the ROS layout (tests/data/calibration holds an OpenCV calibration sample's output, a ROS
camera_calibration ``ost.yaml`` and an easy_handeye result); the projection of
``cv2.projectPoints`` with the file's K and D and ``rvec``/``tvec`` computed here from the
pose; quaternions turned into matrices by their formula here; written files read back by
``cv2.FileStorage`` and ``yaml.safe_load``.
"""

from __future__ import annotations

import argparse
import copy
import re
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsight.camera import Camera
from cellsight.commands.cameras import register, write_cameras
from cellsight.errors import CellFileError, CellsightError
from cellsight.geometry.transforms import look_at
from cellsight.model.calibration import (
    read_hand_eye,
    read_intrinsics,
    write_easy_handeye,
    write_opencv_hand_eye,
    write_opencv_intrinsics,
    write_ros_camera_info,
)
from cellsight.model.calibration_text import MAX_CALIBRATION_BYTES
from cellsight.model.loader import builtin_cell_path, load_cell, parse_cell_text
from cellsight.model.yaml_input import read_cell_text
from cellsight.occlusion.backends import visibility_predictor

DATA = Path(__file__).resolve().parent / "data" / "calibration"
BUILTIN = yaml.safe_load(builtin_cell_path().read_text())
CAM2_POSE = look_at([1.5, 1.1, 1.7], [0.72, -0.1, 0.68])
LOOK = {"eye": [0.25, 1.15, 1.75], "target": [0.72, -0.1, 0.68]}


def _cell(folder: Path, cameras: list[dict], name: str = "cell.yaml") -> Path:
    """The built-in cell with these cameras, written in ``folder``."""
    data = copy.deepcopy(BUILTIN)
    data["cameras"] = cameras
    path = folder / name
    path.write_text(yaml.safe_dump(data))
    return path


def _quaternion_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """The rotation of a unit quaternion, by its formula."""
    n = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _cv_project(points: np.ndarray, R_base_cam: np.ndarray, t_base_cam: np.ndarray,
                K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """``cv2.projectPoints`` of base-frame points by a camera at (R, t) in the base frame."""
    R_cam_base = R_base_cam.T
    rvec, _ = cv2.Rodrigues(R_cam_base)
    tvec = -R_cam_base @ t_base_cam
    pixels, _ = cv2.projectPoints(points.reshape(-1, 1, 3), rvec, tvec, K, D)
    return pixels.reshape(-1, 2)


def _points_in_view(R_base_cam: np.ndarray, t_base_cam: np.ndarray, seed: int = 0) -> np.ndarray:
    """Base-frame points 1-3 m in front of the camera, inside about its field of view."""
    rng = np.random.default_rng(seed)
    z = rng.uniform(1.0, 3.0, 60)
    cam = np.column_stack([rng.uniform(-0.15, 0.15, 60) * z, rng.uniform(-0.12, 0.12, 60) * z, z])
    return cam @ R_base_cam.T + t_base_cam


def _assert_projects_like_opencv(camera: Camera, R: np.ndarray, t: np.ndarray, K: np.ndarray,
                                 D: np.ndarray) -> None:
    points = _points_in_view(R, t)
    expected = _cv_project(points, R, t, K, D)
    assert np.allclose(camera.project(points), expected, rtol=0, atol=1e-7)


def _write_storage(path: Path, items: dict) -> Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in items.items():
        fs.write(key, value)
    fs.release()
    return path


def _ros_text(K: np.ndarray, D: list[float], model: str = "plumb_bob", size=(768, 576)) -> str:
    """A ROS camera_info YAML in camera_calibration's layout, by hand."""
    def matrix(rows: int, cols: int, data) -> str:
        numbers = ", ".join(repr(float(v)) for v in data)
        return f"  rows: {rows}\n  cols: {cols}\n  data: [{numbers}]\n"
    P = np.hstack([K, np.zeros((3, 1))])
    return (f"image_width: {size[0]}\nimage_height: {size[1]}\ncamera_name: cam\n"
            f"camera_matrix:\n{matrix(3, 3, K.ravel())}distortion_model: {model}\n"
            f"distortion_coefficients:\n{matrix(1, len(D), D)}"
            f"rectification_matrix:\n{matrix(3, 3, np.eye(3).ravel())}"
            f"projection_matrix:\n{matrix(3, 4, P.ravel())}")


# ------------------------------------------------------------------ loading real-world files


def test_sample_files_give_cameras_that_project_like_opencv(tmp_path) -> None:
    """An OpenCV calibration sample's output, a ROS ost.yaml, an easy_handeye result and a
    cv2.FileStorage hand-eye file (OpenCV's R_cam2base names), relative to the cell file."""
    (tmp_path / "calib").mkdir()
    for f in DATA.iterdir():
        shutil.copy(f, tmp_path / "calib" / f.name)
    _write_storage(tmp_path / "calib" / "cam2_handeye.xml",
                   {"R_cam2base": CAM2_POSE[:3, :3], "t_cam2base": CAM2_POSE[:3, 3]})
    cell = load_cell(_cell(tmp_path, [
        {"name": "cam1", "calibration": "calib/opencv_calibration_sample.yml",
         "hand_eye": "calib/easy_handeye_eye_on_base.yaml"},
        {"name": "cam2", "calibration": {"file": "calib/ros_camera_info.yaml", "format": "ros"},
         "hand_eye": {"file": "calib/cam2_handeye.xml", "format": "opencv"}}]))
    cam1, cam2 = cell.cameras
    fs = cv2.FileStorage(str(DATA / "opencv_calibration_sample.yml"), cv2.FILE_STORAGE_READ)
    K1, D1 = fs.getNode("camera_matrix").mat(), fs.getNode("distortion_coefficients").mat()
    tr = yaml.safe_load((DATA / "easy_handeye_eye_on_base.yaml").read_text())["transformation"]
    R1 = _quaternion_matrix(tr["qx"], tr["qy"], tr["qz"], tr["qw"])
    t1 = np.array([tr["x"], tr["y"], tr["z"]])
    assert (cam1.width, cam1.height, cam1.name) == (768, 576, "cam1")
    _assert_projects_like_opencv(cam1, R1, t1, K1, D1)
    ros = yaml.safe_load((DATA / "ros_camera_info.yaml").read_text())
    K2 = np.reshape(ros["camera_matrix"]["data"], (3, 3)).astype(float)
    D2 = np.array(ros["distortion_coefficients"]["data"], dtype=float)
    _assert_projects_like_opencv(cam2, CAM2_POSE[:3, :3], CAM2_POSE[:3, 3], K2, D2)
    assert cam1.dist is not None and cam2.dist is not None


DISTORTIONS = {  # (coefficients, shape written): OpenCV's models with what cellsight uses
    "4 as a row": ([-0.2, 0.1, 1e-3, -2e-3], (1, 4)),
    "5 as a column": ([-0.25, 0.12, 5e-4, 1e-3, -0.03], (5, 1)),
    "8 rational, k4-k6 zero": ([0.1, -0.05, 0.0, 2e-4, 0.01, 0.0, 0.0, 0.0], (8, 1)),
    "14, the rest zero": ([-0.3, 0.2, 1e-4, 0.0, -0.1] + [0.0] * 9, (1, 14)),
}


@pytest.mark.parametrize("ext", ["yaml", "xml", "json"])
@pytest.mark.parametrize("keys", [("camera_matrix", "distortion_coefficients"), ("K", "D"),
                                  ("K", "dist_coeffs")], ids=lambda k: "+".join(k))
@pytest.mark.parametrize("dist", list(DISTORTIONS), ids=list(DISTORTIONS))
def test_opencv_filestorage_cameras_project_like_opencv(tmp_path, ext, keys, dist) -> None:
    K = np.array([[1500.5, 0.0, 390.25], [0.0, 1498.0, 280.75], [0.0, 0.0, 1.0]])
    coefficients, shape = DISTORTIONS[dist]
    D = np.array(coefficients).reshape(shape)
    _write_storage(tmp_path / f"cam.{ext}", {"image_width": 800, "image_height": 600,
                                            keys[0]: K, keys[1]: D})
    R, t = CAM2_POSE[:3, :3], CAM2_POSE[:3, 3]
    _write_storage(tmp_path / f"pose.{ext}", {"R_base_camera": R, "t_base_camera": t})
    cell = load_cell(_cell(tmp_path, [{"name": "c", "calibration": f"cam.{ext}",
                                       "hand_eye": f"pose.{ext}"}]))
    (camera,) = cell.cameras
    assert (camera.width, camera.height) == (800, 600)
    _assert_projects_like_opencv(camera, R, t, K, D.ravel())


@pytest.mark.parametrize("model", ["plumb_bob", "rational_polynomial"])
def test_ros_camera_info_cameras_project_like_opencv(tmp_path, model) -> None:
    K = np.array([[1200.0, 0.0, 330.5], [0.0, 1210.0, 245.25], [0.0, 0.0, 1.0]])
    D = [-0.28, 0.09, -4e-4, 7e-4, -0.01] + ([0.0] * 3 if model == "rational_polynomial" else [])
    (tmp_path / "cam.yaml").write_text(_ros_text(K, D, model, (640, 480)))
    cell = load_cell(_cell(tmp_path, [{"name": "c", "calibration": "cam.yaml",
                                       "look_at": LOOK}]))
    (camera,) = cell.cameras
    T = look_at(LOOK["eye"], LOOK["target"])
    assert (camera.width, camera.height) == (640, 480)
    _assert_projects_like_opencv(camera, T[:3, :3], T[:3, 3], K, np.array(D))


def test_a_hand_eye_pose_in_a_robots_base_frame(tmp_path) -> None:
    """``hand_eye: {robot: R6AX}``: the file's pose is in R6AX's base frame."""
    shutil.copy(DATA / "easy_handeye_eye_on_base.yaml", tmp_path / "he.yaml")
    cell = load_cell(_cell(tmp_path, [
        {"name": "c", "calibration": str(DATA / "ros_camera_info.yaml"),
         "hand_eye": {"file": "he.yaml", "robot": "R6AX"}}]))
    tr = yaml.safe_load((tmp_path / "he.yaml").read_text())["transformation"]
    T_robot_cam = np.eye(4)
    T_robot_cam[:3, :3] = _quaternion_matrix(tr["qx"], tr["qy"], tr["qz"], tr["qw"])
    T_robot_cam[:3, 3] = [tr["x"], tr["y"], tr["z"]]
    expected = cell.robot("R6AX").T_base_robot @ T_robot_cam
    assert np.allclose(cell.cameras[0].T_base_cam, expected, rtol=0, atol=1e-12)


def test_every_existing_way_of_writing_a_camera_still_loads() -> None:
    cell = load_cell()
    assert [c.name for c in cell.cameras] == ["cam1", "cam2"]
    assert cell.cameras[0].K[0, 0] == pytest.approx(16.0 / 0.0083)


# ------------------------------------------------------------------ writing and reading back

_unit = st.floats(-1.0, 1.0, allow_nan=False)


@st.composite
def cameras(draw) -> Camera:
    width, height = draw(st.integers(16, 4096)), draw(st.integers(16, 4096))
    fx, fy = draw(st.floats(50.0, 1e4)), draw(st.floats(50.0, 1e4))
    cx, cy = draw(st.floats(-100.0, 5000.0)), draw(st.floats(-100.0, 5000.0))
    skew = draw(st.sampled_from([0.0, draw(st.floats(-5.0, 5.0))]))
    dist = draw(st.lists(st.floats(-1.0, 1.0), min_size=5, max_size=5))
    q = np.array(draw(st.lists(_unit, min_size=4, max_size=4).filter(
        lambda v: np.linalg.norm(v) > 0.1)))
    T = np.eye(4)
    T[:3, :3] = _quaternion_matrix(*q)
    T[:3, 3] = draw(st.lists(st.floats(-10.0, 10.0), min_size=3, max_size=3))
    K = np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    P = None
    if draw(st.booleans()):  # a rectified image's projection, a stereo right camera's Tx
        P = np.hstack([K * draw(st.floats(0.5, 1.5)), [[draw(st.floats(-500.0, 0.0))], [0.0],
                                                       [0.0]]])
        P[2, 2] = 1.0
    return Camera(K, width, height, T, np.array(dist), draw(st.sampled_from(["cam1", "true"])),
                  P)


def _same_intrinsics(camera: Camera, read) -> None:
    assert (read.width, read.height) == (camera.width, camera.height)
    assert np.array_equal(read.K, camera.K)
    K0 = np.hstack([camera.K, np.zeros((3, 1))])  # what a P of None stands for
    assert np.array_equal(read.P if read.P is not None else K0,
                          camera.P if camera.P is not None else K0)
    assert np.array_equal(read.dist if read.dist is not None else np.zeros(5), camera.dist5)


@settings(max_examples=40, deadline=None)
@given(camera=cameras())
def test_written_files_read_back_the_same_camera(camera) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for ext in ("yaml", "xml"):
            path = write_opencv_intrinsics(folder / f"cam.{ext}", camera)
            _same_intrinsics(camera, read_intrinsics(path))
            fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)  # the oracle
            assert np.array_equal(fs.getNode("camera_matrix").mat(), camera.K)
            assert np.array_equal(fs.getNode("distortion_coefficients").mat().ravel(),
                                  camera.dist5)
            assert int(fs.getNode("image_width").real()) == camera.width
            assert fs.getNode("projection_matrix").empty() == (camera.P is None)
            path = write_opencv_hand_eye(folder / f"pose.{ext}", camera.T_base_cam)
            assert np.array_equal(read_hand_eye(path), camera.T_base_cam)
            fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
            assert np.array_equal(fs.getNode("R_base_camera").mat(), camera.T_base_cam[:3, :3])
            assert np.array_equal(fs.getNode("t_base_camera").mat().ravel(),
                                  camera.T_base_cam[:3, 3])
        path = write_ros_camera_info(folder / "ros.yaml", camera)
        _same_intrinsics(camera, read_intrinsics(path))
        ros = yaml.safe_load(path.read_text())
        assert ros["camera_matrix"]["data"] == camera.K.ravel().tolist()
        assert ros["distortion_coefficients"]["data"] == camera.dist5.tolist()
        assert ros["distortion_model"] == "plumb_bob"
        P = camera.P if camera.P is not None else np.hstack([camera.K, np.zeros((3, 1))])
        assert ros["projection_matrix"]["data"] == P.ravel().tolist()
        assert (ros["image_width"], ros["camera_name"]) == (camera.width, camera.name)
        path = write_easy_handeye(folder / "he.yaml", camera.T_base_cam)
        assert np.allclose(read_hand_eye(path), camera.T_base_cam, rtol=0, atol=1e-12)
        he = yaml.safe_load(path.read_text())
        tr = he["transformation"]
        assert he["parameters"]["eye_on_hand"] is False
        assert [tr["x"], tr["y"], tr["z"]] == camera.T_base_cam[:3, 3].tolist()
        assert np.allclose(_quaternion_matrix(tr["qx"], tr["qy"], tr["qz"], tr["qw"]),
                           camera.T_base_cam[:3, :3], rtol=0, atol=1e-12)


# ------------------------------------------------------------------------ cellsight cameras


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="cellsight")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def _same_cameras(a: list[Camera], b: list[Camera]) -> None:
    assert [c.name for c in a] == [c.name for c in b]
    for ca, cb in zip(a, b, strict=True):
        assert (ca.width, ca.height) == (cb.width, cb.height)
        assert np.array_equal(ca.K, cb.K) and np.array_equal(ca.dist5, cb.dist5)
        assert np.allclose(ca.T_base_cam, cb.T_base_cam, rtol=0, atol=1e-12)


def _same_answers(a, b) -> None:
    for part in a:
        for va, vb in zip(a[part], b[part], strict=True):
            assert va.camera == vb.camera
            assert np.array_equal(va.visible, vb.visible)
            assert np.array_equal(va.status, vb.status)
            assert [va.object_labels[i] if i >= 0 else None for i in va.occluder] == \
                [vb.object_labels[i] if i >= 0 else None for i in vb.occluder]
            assert np.allclose(va.pixels, vb.pixels, rtol=0, atol=1e-8, equal_nan=True)


@pytest.mark.parametrize("fmt", ["opencv-yaml", "opencv-xml", "ros"])
def test_the_builtin_cell_rewritten_through_its_calibration_files(tmp_path, fmt, capsys) -> None:
    assert _run(["cameras", "--write", str(tmp_path / "out"), "--format", fmt]) == 0
    lines = capsys.readouterr().out.splitlines()  # not a terminal: paths do not wrap
    assert lines[-1] == f"wrote {tmp_path / 'out' / 'cell.yaml'}"
    original, again = load_cell(), load_cell(tmp_path / "out" / "cell.yaml")
    _same_cameras(original.cameras, again.cameras)
    fragment = yaml.safe_load((tmp_path / "out" / "cameras.yaml").read_text())["cameras"]
    ext = ".xml" if fmt == "opencv-xml" else ".yaml"
    assert fragment[0]["calibration"]["file"] == f"cam1_intrinsics{ext}"
    assert fragment[0]["hand_eye"]["file"] == f"cam1_handeye{ext}"
    r7ax = original.robot("R7AX")
    for joints in ({}, {"R7AX": r7ax.final},
                   {"R6AX": np.array([0.6, -0.2, 0.4, 0.3, 1.2, 0.1])}):
        _same_answers(visibility_predictor(original).predict(joints),
                      visibility_predictor(again).predict(joints))


def test_a_cell_with_files_of_its_own_loads_from_the_written_folder(tmp_path) -> None:
    """The written cell.yaml names the cell's mesh by an absolute path; calibration files the
    cell had are rewritten in the new format."""
    (tmp_path / "src").mkdir()
    shutil.copy(DATA / "ros_camera_info.yaml", tmp_path / "src" / "c.yaml")
    (tmp_path / "src" / "crate.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n")
    data = copy.deepcopy(BUILTIN)
    data["static"].append({"name": "crate", "pose": {"xyz": [3, 3, 0]},
                           "solids": [{"mesh": {"file": "crate.obj"}}]})
    data["cameras"] = [{"name": "cam1", "calibration": "c.yaml", "look_at": LOOK}]
    source = tmp_path / "src" / "cell.yaml"
    source.write_text(yaml.safe_dump(data))
    assert _run(["cameras", "--cell", str(source), "--write", str(tmp_path / "out")]) == 0
    again = load_cell(tmp_path / "out" / "cell.yaml")
    _same_cameras(load_cell(source).cameras, again.cameras)
    assert "crate" in [s.name for s in again.static]


def test_the_table_lists_every_camera(capsys) -> None:
    assert _run(["cameras", "--cell", "ur-cell"]) == 0
    out = capsys.readouterr().out
    for text in ("cam1", "cam2", "cam3", "768x576", "1927.71", "1686.75", "383.50", "none"):
        assert text in out


def test_written_files_are_not_overwritten_unless_asked(tmp_path) -> None:
    path = builtin_cell_path()
    spec, raw = parse_cell_text(read_cell_text(path), str(path), path.parent)
    cameras = load_cell().cameras
    write_cameras(path, raw, cameras, tmp_path, "ros")
    with pytest.raises(CellsightError, match=r"already holds cam1_intrinsics.yaml, "
                                             r"cam1_handeye.yaml, .*--overwrite"):
        write_cameras(path, raw, cameras, tmp_path, "ros")
    assert len(write_cameras(path, raw, cameras, tmp_path, "ros", overwrite=True)) == 6
    (tmp_path / "file").write_text("")
    with pytest.raises(CellsightError, match="is not a folder"):
        write_cameras(path, raw, cameras, tmp_path / "file", "ros")


# ------------------------------------------------------------------------------- bad input

GOOD_CV = (DATA / "opencv_calibration_sample.yml").read_text()
GOOD_ROS = (DATA / "ros_camera_info.yaml").read_text()
GOOD_HE = (DATA / "easy_handeye_eye_on_base.yaml").read_text()
K_OK = np.array([[1000.0, 0.0, 320.0], [0.0, 1000.0, 240.0], [0.0, 0.0, 1.0]])


def _storage(items: dict, ext: str = ".yaml") -> str:
    fs = cv2.FileStorage(ext, cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    for key, value in items.items():
        fs.write(key, value)
    return fs.releaseAndGetString()


def _cv(**changes) -> str:
    items = {"image_width": 640, "image_height": 480, "camera_matrix": K_OK,
             "distortion_coefficients": np.zeros((5, 1))}
    items.update(changes)
    return _storage({k: v for k, v in items.items() if v is not None})


CV_HEADER = "%YAML:1.0\n"
BAD_INTRINSICS = [  # (case, the calibration file's text, key, what the message says)
    ("missing file", None, "<file>", r"got '[^']*c\.yaml'; expected an existing calibration "
                                     r"file$"),
    ("not UTF-8", b"\xff\xfe\x00junk", "<file>", r"UTF-8 text \(byte 0"),
    ("empty", "", "<file>", r"it is empty"),
    ("broken OpenCV YAML", CV_HEADER + "camera_matrix: [1, 2\n", "<file>",
     r"got 'line \d+: .*'; expected an OpenCV FileStorage file"),
    ("broken ROS YAML", "image_width: [\n", "line 2", r"valid YAML"),
    ("OpenCV sequence root", CV_HEADER + "- 1\n- 2\n", "<file>", r"a mapping of keys"),
    ("no image_width", GOOD_CV.replace("image_width: 768\n", ""), "image_width",
     r"got <missing>; expected a key 'image_width' \(the file has \["),
    ("no camera_matrix (ROS)", GOOD_ROS.replace("camera_matrix", "camera_matrx"),
     "camera_matrix", r"got <missing>"),
    ("no distortion (OpenCV)", _cv(distortion_coefficients=None), "distortion_coefficients",
     r"the distortion coefficients under one of the keys distortion_coefficients, D, "
     r"dist_coeffs"),
    ("2x2 camera matrix", _cv(camera_matrix=np.eye(2)), "camera_matrix",
     r"got 'a 2x2 matrix'; expected a 3x3 matrix"),
    ("short ROS data", GOOD_ROS.replace("0, 0, 1]", "0, 1]", 1), "camera_matrix.data",
     r"rows x cols = 9 numbers"),
    ("NaN in a ROS K", GOOD_ROS.replace("1925.412345", ".nan"), "camera_matrix.data",
     r"got \[nan, 0, .*; expected finite numbers"),
    ("inf in an OpenCV K", _cv(camera_matrix=np.array([[np.inf, 0, 1], [0, 1, 1], [0, 0, 1]])),
     "camera_matrix.data", r"got \[inf, .*expected finite numbers"),
    ("not a camera matrix", _cv(camera_matrix=np.diag([1000.0, 1000.0, 2.0])), "camera_matrix",
     r"expected a camera matrix \[\[fx, s, cx\], \[0, fy, cy\], \[0, 0, 1\]\]"),
    ("negative focal length", GOOD_ROS.replace("1925.412345", "-1925.4"), "camera_matrix",
     r"with fx, fy > 0"),
    ("fisheye model", GOOD_ROS.replace("plumb_bob", "equidistant"), "distortion_model",
     r"got 'equidistant'; expected a distortion model cellsight can use: plumb_bob, or "
     r"rational_polynomial with k4 = k5 = k6 = 0 \(the fisheye \(equidistant, Kannala-Brandt\) "
     r"model is not supported"),
    ("kannala_brandt model", _ros_text(K_OK, [0.1, 0.01, 0, 0], "kannala_brandt"),
     "distortion_model", r"got 'kannala_brandt'; .*the fisheye .* model is not supported"),
    ("unknown model", GOOD_ROS.replace("plumb_bob", "pinhole"), "distortion_model",
     r"got 'pinhole'; expected a distortion model cellsight can use: plumb_bob, or "
     r"rational_polynomial with k4 = k5 = k6 = 0$"),
    ("fisheye_model: 1 (OpenCV)", _cv(fisheye_model=1, distortion_coefficients=np.zeros((4, 1))),
     "fisheye_model", r"got 1; expected 0, the pinhole model: the fisheye \(equidistant, "
                      r"Kannala-Brandt\) model is not supported"),
    ("rational with k4", _ros_text(K_OK, [0.1, 0, 0, 0, 0, 0.3, 0, 0], "rational_polynomial"),
     "distortion_coefficients", r"the coefficients after the fifth \(k4 k5 k6 \.\.\.\) must be "
                                r"zero"),
    ("plumb_bob with 8", _ros_text(K_OK, [0.1] + [0] * 7), "distortion_coefficients",
     r"got 'a 1x8 matrix'; expected a row or column of 5 numbers"),
    ("OpenCV 8 with k6", _cv(distortion_coefficients=np.array([[0.1, 0, 0, 0, 0, 0, 0, 1e-3]])),
     "distortion_coefficients", r"must be zero"),
    ("OpenCV 6 coefficients", _cv(distortion_coefficients=np.zeros((6, 1))),
     "distortion_coefficients", r"a row or column of 4 or 5 or 8 or 12 or 14 numbers"),
    ("OpenCV 2x5 distortion", _cv(distortion_coefficients=np.zeros((2, 5))),
     "distortion_coefficients", r"got 'a 2x5 matrix'"),
    ("boolean width (ROS)", GOOD_ROS.replace("image_width: 768", "image_width: true"),
     "image_width", r"got True; expected a positive integer \(px\)"),
    ("real height (OpenCV)", _cv(image_height=480.5), "image_height",
     r"got 480.5; expected a positive integer"),
    ("zero width (OpenCV)", _cv(image_width=0), "image_width", r"got 0; expected a positive"),
    ("text in a ROS K", GOOD_ROS.replace("1925.412345", "'fx'"), "camera_matrix.data",
     r"expected numbers"),
    ("deep brackets (OpenCV)", CV_HEADER + "a: " + "[" * 100_000 + "\n", "<file>",
     r"got 'nesting 100000 deep'; expected brackets and elements nested at most 64 deep"),
    ("deep elements (XML)", '<?xml version="1.0"?>\n<opencv_storage>' + "<a>" * 100_000,
     "<file>", r"nested at most 64 deep"),
    ("negative cols (OpenCV)", GOOD_CV.replace("cols: 3", "cols: -3"), "camera_matrix.cols",
     r"got -3; expected a count"),
    ("huge rows (OpenCV)", GOOD_CV.replace("rows: 3\n   cols: 3", "rows: 100000\n   cols: "
                                           "100000"), "camera_matrix.data",
     r"rows x cols = 10000000000 numbers"),
    ("too big", GOOD_ROS + "#" * MAX_CALIBRATION_BYTES, "<file>",
     rf"expected a calibration file of at most {MAX_CALIBRATION_BYTES} bytes"),
]


def _refused(cell: Path, field: str, file: Path | str, key: str, pattern: str) -> str:
    with pytest.raises(CellFileError) as info:
        load_cell(cell)
    message = str(info.value)
    assert message.startswith(f"{cell}: field '{field}': got "), message
    assert f"expected {file}: key '{key}': " in message, message
    flat = message.replace(f"expected {file}: key '{key}': ", "expected ")  # got V; expected E
    assert re.search(pattern, flat), message
    assert "\n" not in message and len(message) < 900
    return message


@pytest.mark.parametrize(("case", "text", "key", "pattern"), BAD_INTRINSICS,
                         ids=[c[0] for c in BAD_INTRINSICS])
def test_bad_intrinsics_files_name_cell_field_file_and_key(tmp_path, case, text, key,
                                                           pattern) -> None:
    calib = tmp_path / ("c.xml" if "XML" in case else "c.yaml")
    if isinstance(text, bytes):
        calib.write_bytes(text)
    elif text is not None:
        calib.write_text(text)
    cell = _cell(tmp_path, [{"name": "cam1", "calibration": calib.name, "look_at": LOOK}])
    _refused(cell, "cameras[0].calibration", calib, key, pattern)


def _fisheye_sample(path: Path, fisheye: int, K: np.ndarray, D: np.ndarray) -> Path:
    """A calibration file written by cv2.FileStorage in the order and with the keys of OpenCV's
    calibration sample (camera_calibration.cpp, saveCameraParams), which writes
    ``fisheye_model`` and, for the fisheye model, 4 coefficients k1..k4 (4x1)."""
    return _write_storage(path, {
        "calibration_time": "Tue 14 May 2024 09:12:44 CEST", "nr_of_frames": 30,
        "image_width": 768, "image_height": 576, "board_width": 9, "board_height": 6,
        "square_size": 0.025, "flags": 14 if fisheye else 0, "fisheye_model": fisheye,
        "camera_matrix": K, "distortion_coefficients": D.reshape(4, 1),
        "avg_reprojection_error": 0.31})


def test_a_fisheye_calibration_is_refused_not_misread(tmp_path) -> None:
    """Read as k1 k2 p1 p2, a fisheye result's corners land hundreds of pixels from where
    cv2.fisheye.projectPoints puts them: the file is refused, naming the file, the key and the
    value; the same file with fisheye_model 0 loads and projects like cv2.projectPoints."""
    K = np.array([[420.0, 0.0, 383.5], [0.0, 421.0, 287.5], [0.0, 0.0, 1.0]])
    D = np.array([-0.03, 0.005, -0.002, 0.0004])
    corner = cv2.fisheye.undistortPoints(np.array([[[5.0, 5.0]]]), K, D).reshape(2)
    ray = np.array([[[corner[0], corner[1], 1.0]]])
    fisheye, _ = cv2.fisheye.projectPoints(ray, np.zeros(3), np.zeros(3), K, D)
    pinhole, _ = cv2.projectPoints(ray, np.zeros(3), np.zeros(3), K, D)
    assert np.linalg.norm(fisheye - pinhole) > 40  # what reading it as plumb_bob would cost
    calib = _fisheye_sample(tmp_path / "fisheye.yml", 1, K, D)
    assert "fisheye_model: 1" in calib.read_text()
    cell = _cell(tmp_path, [{"name": "cam1", "calibration": calib.name, "look_at": LOOK}])
    message = _refused(cell, "cameras[0].calibration", calib, "fisheye_model",
                       r"got 1; expected 0, the pinhole model: the fisheye \(equidistant, "
                       r"Kannala-Brandt\) model is not supported")
    assert "k1 k2 p1 p2 k3" in message
    _fisheye_sample(calib, 0, K, D)
    (camera,) = load_cell(cell).cameras
    T = look_at(LOOK["eye"], LOOK["target"])
    _assert_projects_like_opencv(camera, T[:3, :3], T[:3, 3], K, D)


def test_a_file_read_as_the_wrong_format(tmp_path) -> None:
    """OpenCV's YAML is no YAML PyYAML reads; a ROS file read by cv2.FileStorage gives the
    same camera (its matrices are maps of rows, cols, data), but not a model it cannot use."""
    (tmp_path / "c.yaml").write_text(GOOD_CV)
    cell = _cell(tmp_path, [{"name": "cam1", "look_at": LOOK,
                             "calibration": {"file": "c.yaml", "format": "ros"}}])
    _refused(cell, "cameras[0].calibration", tmp_path / "c.yaml", "line 1", "valid YAML")
    (tmp_path / "c.yaml").write_text(GOOD_ROS)
    as_opencv = load_cell(_cell(tmp_path, [{"name": "cam1", "look_at": LOOK, "calibration": {
        "file": "c.yaml", "format": "opencv"}}])).cameras
    as_ros = load_cell(_cell(tmp_path, [{"name": "cam1", "look_at": LOOK,
                                         "calibration": "c.yaml"}])).cameras
    _same_cameras(as_opencv, as_ros)
    (tmp_path / "c.yaml").write_text(GOOD_ROS.replace("plumb_bob", "equidistant"))
    cell = _cell(tmp_path, [{"name": "cam1", "look_at": LOOK,
                             "calibration": {"file": "c.yaml", "format": "opencv"}}])
    _refused(cell, "cameras[0].calibration", tmp_path / "c.yaml", "distortion_model",
             "got 'equidistant'")


BAD_HAND_EYE = [  # (case, the hand-eye file's text, key, what the message says)
    ("eye on hand (easy_handeye)", GOOD_HE.replace("eye_on_hand: false", "eye_on_hand: true"),
     "parameters.eye_on_hand", r"got True; expected an eye-to-hand \(eye-on-base\) calibration "
                               r"of a fixed camera"),
    ("no eye_on_hand", GOOD_HE.replace("  eye_on_hand: false\n", ""), "parameters.eye_on_hand",
     r"got <missing>"),
    ("eye_on_hand text", GOOD_HE.replace("eye_on_hand: false", "eye_on_hand: maybe"),
     "parameters.eye_on_hand", r"got 'maybe'; expected false \(0\)"),
    ("no parameters", GOOD_HE.replace("parameters:", "params:"), "parameters", r"<missing>"),
    ("a number for the frame", GOOD_HE.replace("frame: cam1_optical_frame", "frame: 5"),
     "parameters.tracking_base_frame", r"got 5; expected a frame name$"),
    ("no qw", GOOD_HE.replace("qw:", "w:"), "transformation.qw", r"got <missing>"),
    ("text x", GOOD_HE.replace("x: 0.2483", "x: abc"), "transformation.x",
     r"got 'abc'; expected numbers"),
    ("NaN z", GOOD_HE.replace("z: 1.7462", "z: .nan"), "transformation.z",
     r"expected finite numbers"),
    ("not a unit quaternion", GOOD_HE.replace("qw: 0.077418", "qw: 2.0"),
     "transformation.qx..qw", r"expected a unit quaternion"),
    ("eye on hand (OpenCV)", _storage({"R_cam2gripper": np.eye(3), "t_cam2gripper": np.zeros(3)}),
     "R_cam2gripper", r"got 'an eye-on-hand result'; expected an eye-to-hand"),
    ("eye_on_hand: 1 (OpenCV)", _storage({"eye_on_hand": 1, "R_base_camera": np.eye(3),
                                          "t_base_camera": np.zeros(3)}), "eye_on_hand",
     r"got 1; expected an eye-to-hand"),
    ("a reflection", _storage({"R_base_camera": np.diag([1.0, 1.0, -1.0]),
                               "t_base_camera": np.zeros(3)}, ".xml"), "R_base_camera",
     r"expected a rotation matrix \(orthonormal, det \+1"),
    ("a scaled rotation", _storage({"R_cam2base": 2 * np.eye(3), "t_cam2base": np.zeros(3)}),
     "R_cam2base", r"expected a rotation matrix"),
    ("no translation", _storage({"R_base_camera": np.eye(3)}), "t_base_camera",
     r"got <missing>"),
    ("no pose at all", _storage({"camera_matrix": np.eye(3)}), "R_base_camera",
     r"got <missing>; expected the camera's pose in the base frame: R_base_camera"),
    ("two poses", _storage({"R_base_camera": np.eye(3), "t_base_camera": np.zeros(3),
                            "R_cam2base": np.eye(3), "t_cam2base": np.zeros(3)}),
     "R_base_camera", r"one pair"),
    ("t of 2", _storage({"R_base_camera": np.eye(3), "t_base_camera": np.zeros(2)}),
     "t_base_camera", r"got 'a 2x1 matrix'; expected a row or column of 3 numbers"),
    ("rotation vector for R", _storage({"R_base_camera": np.zeros((3, 1)),
                                        "t_base_camera": np.zeros(3)}),
     "R_base_camera", r"got 'a 3x1 matrix'; expected a 3x3 matrix"),
]


@pytest.mark.parametrize(("case", "text", "key", "pattern"), BAD_HAND_EYE,
                         ids=[c[0] for c in BAD_HAND_EYE])
def test_bad_hand_eye_files_name_cell_field_file_and_key(tmp_path, case, text, key,
                                                         pattern) -> None:
    he = tmp_path / ("he.xml" if text.startswith("<?xml") else "he.yaml")
    he.write_text(text)
    shutil.copy(DATA / "ros_camera_info.yaml", tmp_path / "ok.yaml")
    cell = _cell(tmp_path, [{"name": "cam1", "calibration": "ok.yaml", "hand_eye": he.name}])
    _refused(cell, "cameras[0].hand_eye", he, key, pattern)


BAD_ENTRIES = [  # (case, the camera entry, field, what the message says)
    ("calibration and fx", {"calibration": "ok.yaml", "fx": 1000.0, "look_at": LOOK},
     r"cameras\[0\]", r"'calibration' gives the image size, K and distortion: drop fx "
                      r"\(or the calibration file\)"),
    ("calibration and size", {"calibration": "ok.yaml", "width": 768, "height": 576,
                              "look_at": LOOK}, r"cameras\[0\]", r"drop width, height"),
    ("calibration and lens", {"calibration": "ok.yaml", "lens_mm": 16.0, "pixel_mm": 0.0083,
                              "dist": [0, 0, 0, 0], "look_at": LOOK}, r"cameras\[0\]",
     r"drop lens_mm, pixel_mm, dist"),
    ("hand_eye and look_at", {"calibration": "ok.yaml", "hand_eye": "he.yaml", "look_at": LOOK},
     r"cameras\[0\]", r"give exactly one of pose, look_at or hand_eye; got look_at, hand_eye"),
    ("no pose", {"calibration": "ok.yaml"}, r"cameras\[0\]",
     r"exactly one of pose, look_at or hand_eye; got none"),
    ("no size, no file", {"fx": 1000.0, "look_at": LOOK}, r"cameras\[0\]",
     r"width and height \(px\), or a calibration file"),
    ("unknown format", {"calibration": {"file": "ok.yaml", "format": "fisheye"},
                        "look_at": LOOK}, r"cameras\[0\]\.calibration\.format",
     r"got 'fisheye'; expected Input should be 'opencv' or 'ros'"),
    ("unknown hand-eye key", {"calibration": "ok.yaml",
                              "hand_eye": {"file": "he.yaml", "frame": "body"}},
     r"cameras\[0\]\.hand_eye\.frame", r"Extra inputs are not permitted"),
    ("number for a file", {"calibration": 7, "look_at": LOOK}, r"cameras\[0\]\.calibration",
     r"got 7; expected a file name, or a mapping \{file, format, \.\.\.\}"),
    ("unknown robot", {"calibration": "ok.yaml", "hand_eye": {"file": "he.yaml", "robot": "R9"}},
     r"cameras\[0\]\.hand_eye\.robot", r"got 'R9'; expected one of the cell's robots "
                                       r"\['R6AX', 'R7AX'\]"),
]


@pytest.mark.parametrize(("case", "entry", "field", "pattern"), BAD_ENTRIES,
                         ids=[c[0] for c in BAD_ENTRIES])
def test_contradictory_or_incomplete_entries_are_refused(tmp_path, case, entry, field,
                                                         pattern) -> None:
    shutil.copy(DATA / "ros_camera_info.yaml", tmp_path / "ok.yaml")
    shutil.copy(DATA / "easy_handeye_eye_on_base.yaml", tmp_path / "he.yaml")
    cell = _cell(tmp_path, [{"name": "cam1", **entry}])
    with pytest.raises(CellFileError, match=rf"^{re.escape(str(cell))}: field "
                                            rf"'{field}': .*{pattern}"):
        load_cell(cell)


def test_hostile_file_names_are_clear_errors(tmp_path) -> None:
    for name, expected in (("x" * 300, r"a readable file \(File name too long\)"),
                           ("a\x00b", r"an existing calibration file"),
                           (".", "an existing calibration file"),
                           ("../../nope", "an existing calibration file")):
        cell = _cell(tmp_path, [{"name": "cam1", "calibration": name, "look_at": LOOK}])
        with pytest.raises(CellFileError, match=r"field 'cameras\[0\]\.calibration'.*key "
                                                rf"'<file>': {expected}$") as info:
            load_cell(cell)
        assert "\x00" not in str(info.value) and len(str(info.value)) < 700

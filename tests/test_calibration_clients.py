"""Calibration files as their other writers leave them (issue 15, part 3): CameraInfo messages
dumped by ``ros2 topic echo``; the projection matrix P a camera_info gives, kept and written
out again; easy_handeye results against a camera's body frame (``camera_link``); ``cellsight
cameras --json`` and its table when piped.

Oracles, independent of cellsight's readers: the dumps are written here the way the tools
write them (``ros2 topic echo`` prints ``rosidl_runtime_py.message_to_yaml``, a block-style
``yaml.dump`` of the fields in order, then ``---``); the projection of ``cv2.projectPoints``
with the message's K and D; written files read by ``yaml.safe_load`` and ``cv2.FileStorage``;
REP 103's body-to-optical rotation built here from its axes, quaternions checked against their
formula.
"""

from __future__ import annotations

import copy
import json
import logging
import re
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from cellsight.camera import Camera
from cellsight.cli import main
from cellsight.errors import CameraError, CellFileError
from cellsight.export.ros import camera_info
from cellsight.geometry.transforms import look_at
from cellsight.model.calibration import read_hand_eye, write_easy_handeye
from cellsight.model.loader import builtin_cell_path, load_cell

DATA = Path(__file__).resolve().parent / "data" / "calibration"
BUILTIN = yaml.safe_load(builtin_cell_path().read_text())
LOOK = {"eye": [0.25, 1.15, 1.75], "target": [0.72, -0.1, 0.68]}
K_MSG = [1200.0, 0.0, 330.5, 0.0, 1210.0, 245.25, 0.0, 0.0, 1.0]
D_MSG = [-0.28, 0.09, -0.0004, 0.0007, -0.01]
P_MSG = [1180.5, 0.0, 328.0, 0.0, 0.0, 1190.25, 244.5, 0.0, 0.0, 0.0, 1.0, 0.0]


def _cell(folder: Path, cameras: list[dict]) -> Path:
    """The built-in cell with these cameras, written in ``folder``."""
    data = copy.deepcopy(BUILTIN)
    data["cameras"] = cameras
    path = folder / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _message(k=K_MSG, d=D_MSG, p=P_MSG, model: str = "plumb_bob", **changes) -> dict:
    """A sensor_msgs/CameraInfo (ROS 2 field names, in the message's order) of 640x480 px."""
    message = {"header": {"stamp": {"sec": 1715671964, "nanosec": 120034567},
                          "frame_id": "cam1_optical_frame"},
               "height": 480, "width": 640, "distortion_model": model, "d": list(d),
               "k": list(k), "r": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "p": list(p),
               "binning_x": 0, "binning_y": 0,
               "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0,
                       "do_rectify": False}}
    message.update(changes)
    return message


def _echo(*messages: dict) -> str:
    """What ``ros2 topic echo /cam1/camera_info`` prints for these messages: per message,
    ``print(message_to_yaml(msg), end='---\\n')``, message_to_yaml being
    ``yaml.dump(fields, allow_unicode=True, width=sys.maxsize, default_flow_style=False)``
    with the fields in the message's order."""
    return "".join(yaml.dump(m, allow_unicode=True, width=sys.maxsize, default_flow_style=False,
                             sort_keys=False) + "---\n" for m in messages)


def _assert_projects_like_opencv(camera, T: np.ndarray, K: np.ndarray, D: np.ndarray) -> None:
    """``camera`` (at ``T`` = T_base_cam) projects points in its view as cv2.projectPoints
    does with K and D."""
    rng = np.random.default_rng(0)
    z = rng.uniform(1.0, 3.0, 60)
    cam = np.column_stack([rng.uniform(-0.2, 0.2, 60) * z, rng.uniform(-0.15, 0.15, 60) * z, z])
    points = cam @ T[:3, :3].T + T[:3, 3]
    R_cam_base = T[:3, :3].T
    rvec, _ = cv2.Rodrigues(R_cam_base)
    expected, _ = cv2.projectPoints(points.reshape(-1, 1, 3), rvec, -R_cam_base @ T[:3, 3], K, D)
    assert np.allclose(camera.project(points), expected.reshape(-1, 2), rtol=0, atol=1e-7)


def _load_refused(tmp_path: Path, text: str, key: str, pattern: str) -> str:
    """Loading a cell whose camera's calibration is ``text`` fails in one line naming the cell
    file, the field, the calibration file, the key; the rest matches ``pattern``."""
    calib = tmp_path / "info.yaml"
    calib.write_text(text)
    cell = _cell(tmp_path, [{"name": "cam1", "calibration": calib.name, "look_at": LOOK}])
    with pytest.raises(CellFileError) as info:
        load_cell(cell)
    message = str(info.value)
    assert message.startswith(f"{cell}: field 'cameras[0].calibration': got "), message
    assert f"; expected {calib}: key '{key}': " in message and "\n" not in message, message
    flat = message.replace(f"expected {calib}: key '{key}': ", "expected ")  # got V; expected E
    assert re.search(pattern, flat), message
    return message


# ------------------------------------------------------------------ ros2 topic echo dumps


@pytest.mark.parametrize("model", ["plumb_bob", "rational_polynomial"])
def test_a_ros2_topic_echo_dump_gives_the_messages_camera(tmp_path, model) -> None:
    """Two messages; the first is read (the second has another K)."""
    d = D_MSG + [0.0] * 3 if model == "rational_polynomial" else D_MSG
    other = _message(k=[900.0, 0.0, 320.0, 0.0, 900.0, 240.0, 0.0, 0.0, 1.0], d=d, model=model)
    text = _echo(_message(d=d, model=model), other)
    assert text.startswith("header:\n  stamp:\n    sec: 1715671964\n")
    assert "\nk:\n- 1200.0\n" in text
    assert text.count("\n---\n") == 2 and text.endswith("do_rectify: false\n---\n")
    (tmp_path / "info.yaml").write_text(text)
    cell = load_cell(_cell(tmp_path, [{"name": "cam1", "calibration": "info.yaml",
                                       "look_at": LOOK}]))
    (camera,) = cell.cameras
    assert (camera.width, camera.height, camera.name) == (640, 480, "cam1")
    _assert_projects_like_opencv(camera, look_at(LOOK["eye"], LOOK["target"]),
                                 np.reshape(K_MSG, (3, 3)), np.array(d))


def test_message_info_before_the_message_and_ros1_names(tmp_path) -> None:
    """``ros2 topic echo --include-message-info`` prints the stamps as a document before the
    message; ROS 1's ``rostopic echo`` names the arrays D K R P (flow lists)."""
    info = yaml.dump({"source_timestamp": 1715671964120034567,
                      "received_timestamp": 1715671964121000000}) + "---\n"
    ros1 = _message()
    for key in ("d", "k", "r", "p"):
        ros1[key.upper()] = ros1.pop(key)
    ros1["header"] = {"seq": 7, "stamp": {"secs": 1715671964, "nsecs": 120034567},
                      "frame_id": "cam1_optical_frame"}
    for text in (info + _echo(_message()), yaml.safe_dump(ros1, sort_keys=False,
                                                          default_flow_style=None) + "---\n"):
        (tmp_path / "info.yaml").write_text(text)
        (camera,) = load_cell(_cell(tmp_path, [{"name": "cam1", "calibration": "info.yaml",
                                                "look_at": LOOK}])).cameras
        _assert_projects_like_opencv(camera, look_at(LOOK["eye"], LOOK["target"]),
                                     np.reshape(K_MSG, (3, 3)), np.array(D_MSG))


BAD_MESSAGES = [  # (case, the dump, key, what the message says)
    ("equidistant", _echo(_message(d=D_MSG[:4], model="equidistant")), "distortion_model",
     r"got 'equidistant'; expected .*the fisheye \(equidistant, Kannala-Brandt\) model is not "
     r"supported"),
    ("binned", _echo(_message(binning_x=2, binning_y=2)), "binning_x",
     r"got 2; expected 0 or 1: a binned image's K is the full sensor's"),
    ("cropped", _echo(_message(roi={"x_offset": 64, "y_offset": 0, "height": 480, "width": 512,
                                    "do_rectify": False})), "roi",
     r"expected no region of interest \(all zeros, or the whole 640x480 image\)"),
    ("uncalibrated", _echo(_message(k=[0.0] * 9, d=[], p=[0.0] * 12)), "k",
     r"with fx, fy > 0"),
    ("4 numbers for plumb_bob", _echo(_message(d=D_MSG[:4])), "d",
     r"got \[-0.28, .*\]; expected a list of 5 numbers \(plumb_bob\)"),
    ("8 numbers for k", _echo(_message(k=K_MSG[:8])), "k", r"9 numbers \(a 3x3 matrix\)"),
    ("P's last row", _echo(_message(p=P_MSG[:8] + [0.0, 0.0, 1.0, 0.5])), "p",
     r"expected a projection matrix \[\[fx', s, cx', Tx\], \[0, fy', cy', Ty\], \[0, 0, 1, 0\]\]"),
    ("P of 9", _echo(_message(p=K_MSG)), "p", r"12 numbers \(a 3x4 matrix\)"),
    ("no width", _echo({k: v for k, v in _message().items() if k != "width"}), "width",
     r"got <missing>; expected a key 'width'"),
    ("only ---", "# dumped\n---\n---\n", "<file>",
     r"got ''; expected a ROS camera_info \(the file has only '---' lines"),
    ("broken after message info", "source_timestamp: 1\n---\nk: [1, 2\n---\n", "line 4",
     r"expected valid YAML"),
]


@pytest.mark.parametrize(("case", "text", "key", "pattern"), BAD_MESSAGES,
                         ids=[c[0] for c in BAD_MESSAGES])
def test_bad_echo_dumps_are_one_line_errors(tmp_path, case, text, key, pattern) -> None:
    _load_refused(tmp_path, text, key, pattern)


# ------------------------------------------------------------ the projection matrix P, kept


def _ros_p(path: Path) -> np.ndarray:
    """The projection_matrix of a camera_calibration-layout file, by yaml.safe_load."""
    return np.reshape(yaml.safe_load(path.read_text())["projection_matrix"]["data"],
                      (3, 4)).astype(float)


def test_a_kept_p_is_the_exported_camera_infos_p(tmp_path) -> None:
    """camera_calibration's ost.yaml (P: the rectified image's, not [K | 0]) and an echo dump
    keep their P on the camera, and the ROS CameraInfo export writes it; a camera without one
    (all zeros in the dump, or a cell camera without a file) exports [K | 0]."""
    shutil.copy(DATA / "ros_camera_info.yaml", tmp_path / "ost.yaml")
    (tmp_path / "echo.yaml").write_text(_echo(_message()))
    (tmp_path / "zero.yaml").write_text(_echo(_message(p=[0.0] * 12)))
    expected = _ros_p(tmp_path / "ost.yaml")
    K_file = np.reshape(yaml.safe_load((tmp_path / "ost.yaml").read_text())["camera_matrix"]
                        ["data"], (3, 3))
    assert abs(expected[0, 0] - K_file[0, 0]) > 30  # the file's P is not [K | 0]
    cell = load_cell(_cell(tmp_path, [
        {"name": name, "calibration": f"{name}.yaml", "look_at": LOOK}
        for name in ("ost", "echo", "zero")] + [
        {"name": "plain", "width": 640, "height": 480, "fx": 900.0, "look_at": LOOK}]))
    ost, echo, zero, plain = cell.cameras
    assert np.array_equal(ost.P, expected)
    assert camera_info(0, "ost_optical", ost)["p"] == expected.ravel().tolist()
    assert camera_info(0, "echo_optical", echo)["p"] == P_MSG
    for camera in (zero, plain):
        assert camera.P is None
        assert camera_info(0, "f", camera)["p"] == np.hstack([camera.K, np.zeros((3, 1))]).ravel(
            ).tolist()


@pytest.mark.parametrize("fmt", ["ros", "opencv-yaml", "opencv-xml"])
def test_cellsight_cameras_writes_the_kept_p(tmp_path, fmt, capsys) -> None:
    """``cellsight cameras --write DIR``: the intrinsics file has the source's P (ROS:
    projection_matrix, read back by yaml.safe_load; OpenCV: projection_matrix, read back by
    cv2.FileStorage), and the written cell.yaml loads the same P back."""
    shutil.copy(DATA / "ros_camera_info.yaml", tmp_path / "ost.yaml")
    cell = _cell(tmp_path, [{"name": "cam1", "calibration": "ost.yaml", "look_at": LOOK}])
    out = tmp_path / "out"
    assert main(["cameras", "--cell", str(cell), "--write", str(out), "--format", fmt]) == 0
    capsys.readouterr()
    expected = _ros_p(tmp_path / "ost.yaml")
    if fmt == "ros":
        assert np.array_equal(_ros_p(out / "cam1_intrinsics.yaml"), expected)
    else:
        ext = ".xml" if fmt == "opencv-xml" else ".yaml"
        fs = cv2.FileStorage(str(out / f"cam1_intrinsics{ext}"), cv2.FILE_STORAGE_READ)
        assert np.array_equal(fs.getNode("projection_matrix").mat(), expected)
    (camera,) = load_cell(out / "cell.yaml").cameras
    assert np.array_equal(camera.P, expected)


def test_a_camera_takes_a_3x4_p_or_none() -> None:
    K = np.array([[900.0, 0.0, 320.0], [0.0, 900.0, 240.0], [0.0, 0.0, 1.0]])
    for bad in (K, np.full((3, 4), np.nan)):
        with pytest.raises(CameraError, match=r"^camera c: P must be None or a finite 3x4 "):
            Camera(K, 640, 480, np.eye(4), None, "c", bad)
    camera = Camera(K, 640, 480, np.eye(4), None, "c", [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]])
    assert camera.P.dtype == float and camera.P.shape == (3, 4)


# ------------------------------------------------- hand-eye results against a body frame


def _link_optical() -> np.ndarray:
    """REP 103: the optical frame (x right, y down, z forward) in the camera's body frame (x
    forward, y left, z up): optical x = -body y, optical y = -body z, optical z = body x."""
    ex, ey, ez = np.eye(3)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([-ey, -ez, ex])
    return T


def _quaternion_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """The rotation of a unit quaternion, by its formula."""
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _easy_handeye_text(T: np.ndarray, tracking_base_frame: str) -> str:
    """An easy_handeye result (eye on base) of the pose ``T`` of ``tracking_base_frame``."""
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    assert np.allclose(_quaternion_matrix(*q), T[:3, :3], rtol=0, atol=1e-12)
    return yaml.safe_dump({
        "parameters": {"eye_on_hand": False, "freehand_robot_movement": False,
                       "move_group": "manipulator", "namespace": "/cell_eye_on_base/",
                       "robot_base_frame": "base", "robot_effector_frame": "tool0",
                       "tracking_base_frame": tracking_base_frame,
                       "tracking_marker_frame": "aruco_marker_frame"},
        "transformation": dict(zip(("x", "y", "z", "qx", "qy", "qz", "qw"),
                                   map(float, (*T[:3, 3], *q)), strict=True))})


def test_a_hand_eye_result_against_camera_link_gives_the_optical_frame(tmp_path,
                                                                        caplog) -> None:
    """The file's pose is camera_link's, T_base_link = T_base_optical @ inv(T_link_optical):
    the camera loads at T_base_optical, and a warning names the frame converted; against an
    optical frame, the same pose loads unchanged and nothing is logged."""
    T_base_optical = look_at(LOOK["eye"], LOOK["target"])
    T_base_link = T_base_optical @ np.linalg.inv(_link_optical())
    assert np.allclose(T_base_link[:3, 0], T_base_optical[:3, 2])  # camera_link's x looks ahead
    shutil.copy(DATA / "ros_camera_info.yaml", tmp_path / "ost.yaml")
    (tmp_path / "link.yaml").write_text(_easy_handeye_text(T_base_link, "camera_link"))
    (tmp_path / "optical.yaml").write_text(
        _easy_handeye_text(T_base_optical, "camera_color_optical_frame"))
    cell = _cell(tmp_path, [{"name": name, "calibration": "ost.yaml", "hand_eye": f"{name}.yaml"}
                            for name in ("link", "optical")])
    with caplog.at_level(logging.WARNING, logger="cellsight.model.calibration"):
        link, optical = load_cell(cell).cameras
    for camera in (link, optical):
        assert np.allclose(camera.T_base_cam, T_base_optical, rtol=0, atol=1e-9)
    (record,) = caplog.records
    assert record.name == "cellsight.model.calibration" and record.levelno == logging.WARNING
    message = record.getMessage()
    assert message.startswith(f"{tmp_path / 'link.yaml'}: tracking_base_frame 'camera_link' is "
                              "not an optical frame")
    assert "converted to the camera's optical frame" in message and "\n" not in message


def test_easy_handeye_files_written_against_a_body_frame_read_back(tmp_path, caplog) -> None:
    """Written against camera_link, the file holds the link's pose (quaternion by its formula)
    and reads back as the optical frame's pose."""
    T_base_optical = look_at([1.5, 1.1, 1.7], [0.72, -0.1, 0.68])
    path = write_easy_handeye(tmp_path / "he.yaml", T_base_optical, "base", "camera_link")
    data = yaml.safe_load(path.read_text())
    assert data["parameters"]["tracking_base_frame"] == "camera_link"
    tr = data["transformation"]
    R_base_link = (T_base_optical @ np.linalg.inv(_link_optical()))[:3, :3]
    assert np.allclose(_quaternion_matrix(tr["qx"], tr["qy"], tr["qz"], tr["qw"]), R_base_link,
                       rtol=0, atol=1e-12)
    with caplog.at_level(logging.WARNING, logger="cellsight.model.calibration"):
        assert np.allclose(read_hand_eye(path), T_base_optical, rtol=0, atol=1e-12)
    assert len(caplog.records) == 1


# --------------------------------------------------------- cellsight cameras: JSON and pipes


def test_cameras_json_is_the_loaded_cells_cameras(capsys) -> None:
    assert main(["cameras", "--json"]) == 0
    records = json.loads(capsys.readouterr().out)
    cameras = load_cell().cameras
    assert [r["name"] for r in records] == [c.name for c in cameras]
    for r, c in zip(records, cameras, strict=True):
        assert (r["width"], r["height"]) == (c.width, c.height)
        assert np.array_equal(r["K"], c.K) and np.array_equal(r["T_base_cam"], c.T_base_cam)
        assert r["dist"] is None and c.dist is None and r["P"] is None
        assert r["source_file"] == r["cell_file"] == str(builtin_cell_path().resolve())
        assert r["hand_eye_file"] is None


def test_cameras_json_names_the_calibration_files(tmp_path, capsys) -> None:
    shutil.copy(DATA / "ros_camera_info.yaml", tmp_path / "ost.yaml")
    shutil.copy(DATA / "easy_handeye_eye_on_base.yaml", tmp_path / "he.yaml")
    cell = _cell(tmp_path, [{"name": "cam1", "calibration": "ost.yaml", "hand_eye": "he.yaml"}])
    assert main(["cameras", "--cell", str(cell), "--json"]) == 0
    (record,) = json.loads(capsys.readouterr().out)
    (camera,) = load_cell(cell).cameras
    ost = yaml.safe_load((tmp_path / "ost.yaml").read_text())
    assert record["K"] == np.reshape(ost["camera_matrix"]["data"], (3, 3)).tolist()
    assert record["dist"] == ost["distortion_coefficients"]["data"]
    assert record["P"] == np.reshape(ost["projection_matrix"]["data"], (3, 4)).tolist()
    assert np.array_equal(record["T_base_cam"], camera.T_base_cam)
    assert (record["source_file"], record["hand_eye_file"], record["cell_file"]) == (
        str(tmp_path.resolve() / "ost.yaml"), str(tmp_path.resolve() / "he.yaml"),
        str(cell.resolve()))


def test_the_table_does_not_wrap_in_a_pipe(tmp_path, capsys) -> None:
    """Captured output is no terminal: the long cell path and every row stay on one line."""
    folder = tmp_path / ("a_folder_with_a_long_name_" * 6)
    folder.mkdir()
    shutil.copy(DATA / "ros_camera_info.yaml", folder / "ost.yaml")
    cell = _cell(folder, [{"name": "cam1", "calibration": "ost.yaml", "look_at": LOOK},
                          {"name": "cam2", "width": 640, "height": 480, "fx": 900.0,
                           "dist": [-0.2, 0.1, 0.001, -0.002, 0.05], "look_at": LOOK}])
    assert len(str(cell)) > 160
    assert main(["cameras", "--cell", str(cell)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(str(cell) in line for line in lines)
    for name, distortion in (("cam1", "-0.1901 0.1205 -0.000412 0.001134 0"),
                             ("cam2", "-0.2 0.1 0.001 -0.002 0.05")):
        (row,) = [line for line in lines if f" {name} " in line]
        assert distortion in row and "[0.250, 1.150, 1.750]" in row
    assert main(["cameras", "--cell", str(cell), "--write", str(folder / "out")]) == 0
    assert str(folder / "out" / "cell.yaml") in capsys.readouterr().out.splitlines()[-1]

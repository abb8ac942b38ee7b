"""Camera calibration files: intrinsics and fixed cameras' hand-eye poses, read and written.

Intrinsics (image size, ``K``, distortion), two formats:

- ``opencv``: an OpenCV ``FileStorage`` file, YAML or XML, as the calibration sample writes
  it: ``image_width``, ``image_height`` (integers, px), ``camera_matrix`` (or ``K``: a 3x3
  ``opencv-matrix``) and ``distortion_coefficients`` (or ``D``, ``dist_coeffs``: 4, 5, 8, 12
  or 14 numbers, ``k1 k2 p1 p2 [k3 [k4 k5 k6 [s1..s4 [tx ty]]]]``). Read with
  ``cv2.FileStorage`` itself, from memory (after the checks below); other keys are ignored,
  but for ``fisheye_model`` (OpenCV's calibration sample writes it): a nonzero one, the
  ``cv2.fisheye`` model, is refused.
- ``ros``: a ROS ``camera_info`` YAML as ``camera_calibration`` writes it: ``image_width``,
  ``image_height``, ``camera_name``, ``camera_matrix: {rows: 3, cols: 3, data: [9]}``,
  ``distortion_model`` (``plumb_bob``: 5 numbers; ``rational_polynomial``: 8),
  ``distortion_coefficients: {rows, cols, data}``, ``projection_matrix`` (3x4, px: the
  rectified image's ``P``, kept on the camera and written out again; all zeros or ``[K | 0]``:
  None); the ``rectification_matrix`` is not used: cellsight models the raw image.
  Also a ``sensor_msgs/CameraInfo`` message as ``ros2 topic echo /cam/camera_info`` prints it
  (``header``, ``height``, ``width``, ``distortion_model``, ``d``, ``k``, ``r``, ``p``: flat
  row-major lists, ``p`` kept as ``projection_matrix`` is; ``binning_x``, ``binning_y``,
  ``roi``; ROS 1's ``rostopic echo``: ``D K R P``), each message ended by a line ``---``: the
  first message is read (a document without ``k`` / ``camera_matrix`` before it,
  ``--include-message-info``'s, is skipped). A binned or cropped (``roi``) image is refused:
  its ``K`` is the full sensor's.

cellsight's lens model is OpenCV's ``k1 k2 p1 p2 k3`` (:mod:`cellsight.camera`): coefficients
beyond the fifth (rational, thin-prism, tilt) must be zero, or the file is refused. The fisheye
(equidistant, Kannala-Brandt) model is refused: its 4 coefficients ``k1..k4`` of the angle
``theta`` read as ``k1 k2 p1 p2`` would put points tens to hundreds of pixels off near the
image's corners (``cv2.fisheye.projectPoints`` against ``cv2.projectPoints``).

Hand-eye poses of a fixed (eye-to-hand, "eye on base") camera, two formats; both give the
pose of the camera's optical frame (x right, y down, z forward: the frame OpenCV-based trackers
report in) in the robot's base frame, ``T_base_camera``, which maps camera coordinates to base
coordinates (``p_base = R p_camera + t``), the pose :class:`cellsight.camera.Camera` stores:

- ``easy_handeye``: the YAML easy_handeye saves: ``parameters: {eye_on_hand: false,
  robot_base_frame, tracking_base_frame, ...}``, ``transformation: {x, y, z, qx, qy, qz, qw}``
  (the ``tracking_base_frame``'s pose in the ``robot_base_frame``; metres, unit quaternion).
  A ``tracking_base_frame`` whose name does not end in ``optical_frame`` or ``_optical`` (say
  ``camera_link``) is taken for a ROS body frame (REP 103: x forward, y left, z up) at the
  optical frame's origin: its pose is turned into the optical frame's, ``T_base_link @
  T_LINK_OPTICAL``, and a warning is logged (logger ``cellsight.model.calibration``).
- ``opencv``: an OpenCV ``FileStorage`` (YAML or XML) with ``R_base_camera`` (3x3) and
  ``t_base_camera`` (3x1, metres), or the same under OpenCV's own names ``R_cam2base`` /
  ``t_cam2base`` (what ``cv2.calibrateHandEye`` returns when given base-to-gripper poses for
  an eye-to-hand set-up: it maps camera coordinates to base coordinates, the same direction).

An eye-on-hand (eye-in-hand) result is refused: ``eye_on_hand: true``, or OpenCV keys
``R_cam2gripper`` / ``R_gripper2cam``; cellsight's cameras are fixed. Rotations may be off a
proper rotation by up to ``ROTATION_TOL`` (a rounded file) and are then made exact (the nearest
rotation; a quaternion normalised).

A format is given or guessed: an ``.xml`` or ``.json`` name, an XML text, a ``%YAML:`` header
(OpenCV's, which PyYAML cannot read) or an ``!!opencv-matrix`` tag mean ``opencv``; else the
ROS layout (``ros`` / ``easy_handeye``). Files are read as UTF-8 of at most
``MAX_CALIBRATION_BYTES``, brackets and tags nested at most ``MAX_NESTING`` deep (OpenCV's
parsers recurse without a limit). Every refusal is a :class:`CalibrationError` naming the file,
the key, the value and what was expected.

Writers: :func:`write_opencv_intrinsics` (YAML or XML by the file's extension, through
``cv2.FileStorage``), :func:`write_ros_camera_info`, :func:`write_easy_handeye` and
:func:`write_opencv_hand_eye` (``R_base_camera`` / ``t_base_camera``); each writes what the
matching reader reads back exactly (floats to 17 significant digits, the pose's quaternion
aside).
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from cellsight.camera import Camera
from cellsight.errors import CellsightError
from cellsight.model.calibration_text import (
    MISSING,
    ROTATION_TOL,
    CalibrationError,
    _camera_matrix,
    _entry,
    _finite,
    _first,
    _format,
    _lens,
    _matrix,
    _pose,
    _projection,
    _rotation,
    _size,
    _vector,
    _yaml_mapping,
    opencv_storage,
    read_text,
)

log = logging.getLogger(__name__)

OPENCV, ROS, EASY_HANDEYE = "opencv", "ros", "easy_handeye"
INTRINSICS_FORMATS = (OPENCV, ROS)
HAND_EYE_FORMATS = (OPENCV, EASY_HANDEYE)
K_KEYS = ("camera_matrix", "K")
DIST_KEYS = ("distortion_coefficients", "D", "dist_coeffs")
DIST_SIZES = (4, 5, 8, 12, 14)  # numbers in an OpenCV distortion vector
ROS_MODELS = {"plumb_bob": 5, "rational_polynomial": 8}  # distortion model -> numbers
FISHEYE_MODELS = ("equidistant", "fisheye", "kannala_brandt")  # ROS names, lower case
NO_FISHEYE = ("the fisheye (equidistant, Kannala-Brandt) model is not supported: cellsight's "
              "cameras are pinhole with OpenCV's k1 k2 p1 p2 k3 distortion")
HAND_EYE_KEYS = (("R_base_camera", "t_base_camera"), ("R_cam2base", "t_cam2base"))
EYE_ON_HAND_KEYS = ("R_cam2gripper", "t_cam2gripper", "R_gripper2cam", "t_gripper2cam")
QUATERNION_KEYS = ("qx", "qy", "qz", "qw")
OPTICAL_SUFFIXES = ("optical_frame", "_optical")  # a frame name's ending for an optical frame
#: REP 103: a camera's optical frame (x right, y down, z forward) in its body frame (x forward,
#: y left, z up), same origin; columns: optical x = -body y, optical y = -body z, z = body x
T_LINK_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0],
                           [0.0, 0.0, 0.0, 1.0]])
DOCUMENT_START = re.compile(r"^---(?=[ \t]|$)", re.MULTILINE)  # a YAML "---" line
MESSAGE_K_KEYS, MESSAGE_D_KEYS = ("k", "K"), ("d", "D")  # CameraInfo: ROS 2, ROS 1 names
MESSAGE_P_KEYS, P_KEY = ("p", "P"), "projection_matrix"
CAMERA_INFO_KEYS = (*MESSAGE_K_KEYS, "camera_matrix")  # a YAML document of a camera_info


@dataclass(frozen=True)
class Intrinsics:
    """What an intrinsics file gives: image size (px), ``K`` (3x3, px), the distortion ``k1 k2
    p1 p2 k3`` (None: none), the camera's name in the file (ROS ``camera_name``, or None) and
    the projection matrix ``P`` (3x4, px; None: the file has none)."""

    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray | None
    name: str | None = None
    P: np.ndarray | None = None

    def camera(self, T_base_cam: np.ndarray, name: str) -> Camera:
        return Camera(self.K, self.width, self.height, T_base_cam, self.dist, name, self.P)


# ----------------------------------------------------------------------------- reading text


# --------------------------------------------------------------------------- checked values




# ------------------------------------------------------------------ OpenCV FileStorage input


# ---------------------------------------------------------------------------- intrinsics in


def _distortion_model(file: str, model: object) -> int:
    """The number of coefficients of a ROS distortion model cellsight can use."""
    if model not in ROS_MODELS:
        fisheye = isinstance(model, str) and model.lower() in FISHEYE_MODELS
        raise CalibrationError(file, "distortion_model", model, "a distortion model cellsight "
                               "can use: plumb_bob, or rational_polynomial with k4 = k5 = k6 = 0"
                               + (f" ({NO_FISHEYE})" if fisheye else ""))
    return ROS_MODELS[model]


def _opencv_intrinsics(file: str, keys: dict) -> Intrinsics:
    if "distortion_model" in keys:  # a ROS file read by cv2.FileStorage: mind its model
        _distortion_model(file, keys["distortion_model"])
    if keys.get("fisheye_model", 0) != 0:  # OpenCV's calibration sample's cv2.fisheye result
        raise CalibrationError(file, "fisheye_model", keys["fisheye_model"],
                               f"0, the pinhole model: {NO_FISHEYE}")
    width = _size(file, "image_width", _entry(file, keys, "image_width"))
    height = _size(file, "image_height", _entry(file, keys, "image_height"))
    k_key = _first(file, keys, K_KEYS, "a 3x3 camera matrix")
    K = _camera_matrix(file, k_key, _matrix(file, k_key, keys[k_key], (3, 3)))
    d_key = _first(file, keys, DIST_KEYS, "the distortion coefficients")
    dist = _lens(file, d_key, _vector(file, d_key, keys[d_key], DIST_SIZES))
    name = keys.get("camera_name")
    P = _projection(file, P_KEY, _matrix(file, P_KEY, keys[P_KEY], (3, 4)), K) \
        if P_KEY in keys else None
    return Intrinsics(width, height, K, dist, name if isinstance(name, str) else None, P)


def _ros_intrinsics(file: str, raw: dict) -> Intrinsics:
    width = _size(file, "image_width", _entry(file, raw, "image_width"))
    height = _size(file, "image_height", _entry(file, raw, "image_height"))
    K = _camera_matrix(file, "camera_matrix",
                       _matrix(file, "camera_matrix", _entry(file, raw, "camera_matrix"), (3, 3)))
    size = _distortion_model(file, _entry(file, raw, "distortion_model"))
    d_key = "distortion_coefficients"
    dist = _lens(file, d_key, _vector(file, d_key, _entry(file, raw, d_key), (size,)))
    name = raw.get("camera_name")
    P = _projection(file, P_KEY, _matrix(file, P_KEY, raw[P_KEY], (3, 4)), K) \
        if P_KEY in raw else None
    return Intrinsics(width, height, K, dist, name if isinstance(name, str) else None, P)


def _documents(text: str) -> list[tuple[int, str]]:
    """``(offset, text)`` of each YAML document of ``text``, split at ``---`` lines; parts of
    comments only are dropped, directives (``%YAML``) kept with the document they precede."""
    docs, start = [], 0
    for m in [*DOCUMENT_START.finditer(text), None]:
        end, after = (m.start(), m.end()) if m else (len(text), len(text))
        lines = [line for line in text[start:end].splitlines()
                 if line.strip() and not line.lstrip().startswith("#")]
        if lines and all(line.startswith("%") for line in lines):
            continue  # directives: part of the next document
        if lines:
            docs.append((start, text[start:end]))
        start = after
    return docs


def _first_camera_info(file: str, text: str) -> dict:
    """The YAML mapping of a ROS file. Of a stream of documents (``ros2 topic echo``: each
    message ended by ``---``), the first, or the second when it has one of
    ``CAMERA_INFO_KEYS`` and the first has not (``--include-message-info`` puts the message's
    stamps before it). Line numbers in errors are the file's."""
    if not DOCUMENT_START.search(text):
        return _yaml_mapping(file, text)
    found: list[dict] = []
    for start, chunk in _documents(text)[:2]:
        found.append(_yaml_mapping(file, "\n" * text.count("\n", 0, start) + chunk))
        if any(key in found[-1] for key in CAMERA_INFO_KEYS):
            return found[-1]
    if not found:
        raise CalibrationError(file, "<file>", "", "a ROS camera_info (the file has only "
                               "'---' lines, comments and directives)")
    return found[0]


def _full_image(file: str, raw: dict, width: int, height: int) -> None:
    """Refuse a CameraInfo of a binned or cropped image (its K is the full sensor's)."""
    for key in ("binning_x", "binning_y"):
        value = raw.get(key, 0)
        if isinstance(value, bool) or value not in (0, 1):
            raise CalibrationError(file, key, value, "0 or 1: a binned image's K is the full "
                                   "sensor's; cellsight models the image as published")
    roi = raw.get("roi", {})
    if not isinstance(roi, dict):
        raise CalibrationError(file, "roi", roi, "a mapping {x_offset, y_offset, height, width, "
                               "do_rectify}")
    offset = (roi.get("x_offset", 0), roi.get("y_offset", 0))
    size = (roi.get("width", 0), roi.get("height", 0))
    if offset != (0, 0) or size not in ((0, 0), (width, height)):
        raise CalibrationError(file, "roi", roi, "no region of interest (all zeros, or the whole "
                               f"{width}x{height} image): a cropped image's K is the full "
                               "sensor's")


def _message_intrinsics(file: str, raw: dict) -> Intrinsics:
    """A ``sensor_msgs/CameraInfo`` as ``ros2 topic echo`` (or ROS 1's ``rostopic echo``)
    prints it: ``width``, ``height`` (px), ``k`` (9 numbers, row-major), ``distortion_model``,
    ``d`` and ``p`` (12 numbers, row-major; optional)."""
    width = _size(file, "width", _entry(file, raw, "width"))
    height = _size(file, "height", _entry(file, raw, "height"))
    _full_image(file, raw, width, height)
    k_key = _first(file, raw, MESSAGE_K_KEYS, "the camera matrix (9 numbers, row-major)")
    K = _camera_matrix(file, k_key, _finite(file, k_key, raw[k_key], (3, 3)))
    model = _entry(file, raw, "distortion_model")
    size = _distortion_model(file, model)
    d_key = _first(file, raw, MESSAGE_D_KEYS, "the distortion coefficients")
    if not isinstance(raw[d_key], list) or len(raw[d_key]) != size:
        raise CalibrationError(file, d_key, raw[d_key], f"a list of {size} numbers ({model})")
    dist = _lens(file, d_key, _finite(file, d_key, raw[d_key], (size,)))
    p_key = next((k for k in MESSAGE_P_KEYS if k in raw), None)
    P = None if p_key is None else _projection(file, p_key,
                                               _finite(file, p_key, raw[p_key], (3, 4)), K)
    return Intrinsics(width, height, K, dist, None, P)


def read_intrinsics(path: str | Path, fmt: str | None = None) -> Intrinsics:
    """Image size, ``K`` and distortion from an OpenCV FileStorage (``fmt="opencv"``) or ROS
    (``"ros"``: a ``camera_info`` file, or a CameraInfo message echoed) file; None: guessed
    (:func:`guess_format`)."""
    path = Path(path)
    text = read_text(path)
    if _format(path, text, fmt, INTRINSICS_FORMATS) == OPENCV:
        return _opencv_intrinsics(str(path), opencv_storage(str(path), text))
    raw = _first_camera_info(str(path), text)
    if "image_width" not in raw and any(k in raw for k in (*MESSAGE_K_KEYS, "width")):
        return _message_intrinsics(str(path), raw)
    return _ros_intrinsics(str(path), raw)


# ------------------------------------------------------------------------------ hand-eye in


def _eye_on_hand(file: str, key: str, value) -> None:
    if value is True or value == 1:
        raise CalibrationError(file, key, value, "an eye-to-hand (eye-on-base) calibration of a "
                               "fixed camera: cellsight's cameras do not move with a robot")
    if value is not False and value != 0:
        raise CalibrationError(file, key, value, "false (0): a fixed, eye-to-hand camera")


def _easy_handeye(file: str, raw: dict) -> np.ndarray:
    params = _entry(file, raw, "parameters")
    if not isinstance(params, dict):
        raise CalibrationError(file, "parameters", params, "a mapping (eye_on_hand, "
                               "robot_base_frame, tracking_base_frame, ...)")
    _eye_on_hand(file, "parameters.eye_on_hand",
                 _entry(file, params, "eye_on_hand", "parameters."))
    tr = _entry(file, raw, "transformation")
    if not isinstance(tr, dict):
        raise CalibrationError(file, "transformation", tr, "a mapping {x, y, z, qx, qy, qz, qw}")
    xyz, q = ([_finite(file, f"transformation.{k}", _entry(file, tr, k, "transformation."), ())
               for k in keys] for keys in (("x", "y", "z"), QUATERNION_KEYS))
    q = np.array(q, dtype=float)
    if abs(np.linalg.norm(q) - 1.0) > ROTATION_TOL:
        raise CalibrationError(file, "transformation.qx..qw", q.tolist(),
                               f"a unit quaternion (norm 1 within {ROTATION_TOL})")
    T = _pose(Rotation.from_quat(q / np.linalg.norm(q)).as_matrix(), np.array(xyz, float))
    return _optical_pose(file, params.get("tracking_base_frame"), T)


def _is_optical(frame: str) -> bool:
    return frame.endswith(OPTICAL_SUFFIXES)


def _optical_pose(file: str, frame: object, T: np.ndarray) -> np.ndarray:
    """The optical frame's pose from ``T``, the pose of the frame named ``frame`` (None: not
    named, taken for the optical frame): ``T`` itself for an optical frame, else ``T @
    T_LINK_OPTICAL`` (a body frame), with a warning."""
    if frame is None:
        return T
    if not isinstance(frame, str) or not frame:
        raise CalibrationError(file, "parameters.tracking_base_frame", frame, "a frame name")
    if _is_optical(frame):
        return T
    log.warning("%s: tracking_base_frame '%s' is not an optical frame (its name does not end in "
                "optical_frame or _optical): taken for a ROS body frame (REP 103: x forward, y "
                "left, z up) and converted to the camera's optical frame at the same origin "
                "(optical z = body x, x = -body y, y = -body z)", file, frame)
    return T @ T_LINK_OPTICAL


def _opencv_hand_eye(file: str, keys: dict) -> np.ndarray:
    if found := [k for k in EYE_ON_HAND_KEYS if k in keys]:
        raise CalibrationError(file, found[0], "an eye-on-hand result", "an eye-to-hand "
                               "(eye-on-base) result of a fixed camera: R_base_camera and "
                               "t_base_camera (or R_cam2base and t_cam2base)")
    if "eye_on_hand" in keys:
        _eye_on_hand(file, "eye_on_hand", keys["eye_on_hand"])
    pairs = [p for p in HAND_EYE_KEYS if p[0] in keys or p[1] in keys]
    if len(pairs) != 1:
        raise CalibrationError(file, HAND_EYE_KEYS[0][0], [k for p in pairs for k in p] or
                               MISSING, "the camera's pose in the base frame: R_base_camera "
                               "(3x3) and t_base_camera (3x1, m), or R_cam2base and t_cam2base; "
                               "one pair")
    r_key, t_key = pairs[0]
    R = _rotation(file, r_key, _matrix(file, r_key, _entry(file, keys, r_key), (3, 3)))
    return _pose(R, _vector(file, t_key, _entry(file, keys, t_key), (3,)))


def read_hand_eye(path: str | Path, fmt: str | None = None) -> np.ndarray:
    """``T_base_camera`` (4x4: the camera's optical frame in the robot's base frame) from an
    eye-to-hand calibration: an easy_handeye YAML (``fmt="easy_handeye"``) or an OpenCV
    FileStorage (``"opencv"``); None: guessed (:func:`guess_format`)."""
    path = Path(path)
    text = read_text(path)
    if _format(path, text, fmt, HAND_EYE_FORMATS) == OPENCV:
        return _opencv_hand_eye(str(path), opencv_storage(str(path), text))
    return _easy_handeye(str(path), _yaml_mapping(str(path), text))


# ---------------------------------------------------------------------------------- writing


def _save(path: Path, text: str) -> Path:
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise CellsightError(f"{path}: cannot write the file ({exc.strerror})") from exc
    return path


def _storage_text(path: Path, items: list[tuple[str, object]], comment: str = "") -> str:
    """An OpenCV FileStorage text (YAML, or XML for an ``.xml`` name) of ``items``."""
    suffix = path.suffix.lower()
    if suffix not in (".yaml", ".yml", ".xml"):
        raise CellsightError(f"{path}: an OpenCV FileStorage file is named .yaml, .yml or .xml")
    fs = cv2.FileStorage(suffix, cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    if comment:
        fs.writeComment(comment)
    for key, value in items:
        fs.write(key, value)
    return fs.releaseAndGetString()


def write_opencv_intrinsics(path: str | Path, camera: Camera) -> Path:
    """``camera_name``, ``image_width``, ``image_height``, ``camera_matrix`` (3x3),
    ``distortion_coefficients`` (5x1, ``k1 k2 p1 p2 k3``) and, for a camera that kept one,
    ``projection_matrix`` (3x4) through ``cv2.FileStorage``: YAML, or XML for an ``.xml``
    name."""
    path = Path(path)
    kept = [] if camera.P is None else [(P_KEY, camera.P)]
    return _save(path, _storage_text(path, [
        ("camera_name", camera.name), ("image_width", camera.width),
        ("image_height", camera.height), ("camera_matrix", camera.K),
        ("distortion_coefficients", camera.dist5.reshape(5, 1)), *kept]))


def _ros_matrix(M: np.ndarray) -> dict:
    return {"rows": M.shape[0], "cols": M.shape[1], "data": [float(v) for v in M.ravel()]}


def write_ros_camera_info(path: str | Path, camera: Camera) -> Path:
    """A ROS ``camera_info`` YAML in ``camera_calibration``'s layout (``plumb_bob``; identity
    rectification; projection: the camera's kept ``P``, else ``[K | 0]``)."""
    P = camera.P if camera.P is not None else np.hstack([camera.K, np.zeros((3, 1))])
    data = {"image_width": camera.width, "image_height": camera.height,
            "camera_name": camera.name, "camera_matrix": _ros_matrix(camera.K),
            "distortion_model": "plumb_bob",
            "distortion_coefficients": _ros_matrix(camera.dist5.reshape(1, 5)),
            "rectification_matrix": _ros_matrix(np.eye(3)), P_KEY: _ros_matrix(P)}
    return _save(Path(path), yaml.safe_dump(data, sort_keys=False, default_flow_style=None))


def write_easy_handeye(path: str | Path, T_base_cam: np.ndarray, robot_base_frame: str = "base",
                       tracking_base_frame: str = "camera_optical_frame") -> Path:
    """An easy_handeye YAML of a fixed camera (``eye_on_hand: false``): the pose of
    ``tracking_base_frame`` as ``transformation: {x, y, z, qx, qy, qz, qw}``, ``T_base_cam``
    (its optical frame's pose) itself for an optical frame's name, else the body frame's
    ``T_base_cam @ inv(T_LINK_OPTICAL)`` (what :func:`read_hand_eye` turns back)."""
    T = np.asarray(T_base_cam, dtype=float)
    if not _is_optical(tracking_base_frame):
        T = T @ T_LINK_OPTICAL.T  # the inverse of a rotation about the origin
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    transformation = dict(zip(("x", "y", "z", *QUATERNION_KEYS),
                              (float(v) for v in (*T[:3, 3], *q)), strict=True))
    data = {"parameters": {"eye_on_hand": False, "robot_base_frame": robot_base_frame,
                           "tracking_base_frame": tracking_base_frame},
            "transformation": transformation}
    return _save(Path(path), yaml.safe_dump(data, sort_keys=False))


def write_opencv_hand_eye(path: str | Path, T_base_cam: np.ndarray) -> Path:
    """``R_base_camera`` (3x3), ``t_base_camera`` (3x1, m) and ``eye_on_hand: 0`` through
    ``cv2.FileStorage`` (YAML, or XML for an ``.xml`` name)."""
    path = Path(path)
    T = np.asarray(T_base_cam, dtype=float)
    comment = ("The camera's optical frame (x right, y down, z forward) in the base frame: "
               "p_base = R_base_camera p_camera + t_base_camera (m)")
    return _save(path, _storage_text(path, [
        ("eye_on_hand", 0), ("R_base_camera", T[:3, :3].copy()),
        ("t_base_camera", T[:3, 3].reshape(3, 1).copy())], comment))

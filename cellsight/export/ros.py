"""ROS 2 messages, as the plain dicts ``mcap-ros2-support`` encodes, from cellsight's types.

Time: a run's time ``t`` (s) is written as ROS time ``EPOCH_NS + t`` ns, ``EPOCH_NS`` = 0 (the
Unix epoch): a run that starts at t = 0 starts on 1970-01-01T00:00:00 UTC in ROS tools. Poses
are 4x4 rigid transforms (``T_parent_child``, m); quaternions are ``(x, y, z, w)``.
"""

from __future__ import annotations

import re

import numpy as np
from scipy.spatial.transform import Rotation

from cellsight.camera import Camera
from cellsight.errors import CellsightError

EPOCH_NS = 0
"""ROS time (ns since the Unix epoch) of a run's t = 0."""

GREEN = (0.1, 0.85, 0.2, 1.0)
RED = (0.95, 0.15, 0.1, 1.0)
GREY = (0.6, 0.6, 0.6, 1.0)
WHITE = (1.0, 1.0, 1.0, 1.0)

SPHERE_LIST, LINE_LIST, TEXT_VIEW_FACING, DELETEALL = 7, 5, 9, 3  # Marker type / action


def time_ns(t: float) -> int:
    """ROS time (ns) of run time ``t`` (s, >= 0)."""
    return EPOCH_NS + int(round(t * 1e9))


def stamp(ns: int) -> dict:
    """``builtin_interfaces/Time`` of a time in ns."""
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def header(ns: int, frame_id: str) -> dict:
    return {"stamp": stamp(ns), "frame_id": frame_id}


def topic_token(name: str) -> str:
    """A cellsight name (camera, workpiece) as a ROS 2 topic name token: characters other than
    letters, digits and ``_`` become ``_``, and a leading digit gets a ``_`` before it."""
    token = re.sub(r"[^A-Za-z0-9_]", "_", name)
    return "_" + token if token[:1].isdigit() else token


def quaternion(R: np.ndarray) -> dict:
    """``geometry_msgs/Quaternion`` of a rotation matrix (scalar-last, w >= 0)."""
    q = Rotation.from_matrix(R).as_quat()
    q = -q if q[3] < 0 else q
    return {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}


def point(p) -> dict:
    return {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])}


def pose(T: np.ndarray) -> dict:
    """``geometry_msgs/Pose`` of a 4x4 pose."""
    return {"position": point(T[:3, 3]), "orientation": quaternion(T[:3, :3])}


def transform(ns: int, parent: str, child: str, T: np.ndarray) -> dict:
    """``geometry_msgs/TransformStamped``: frame ``child`` at ``T`` (= ``T_parent_child``) in
    frame ``parent``."""
    return {"header": header(ns, parent), "child_frame_id": child,
            "transform": {"translation": point(T[:3, 3]), "rotation": quaternion(T[:3, :3])}}


def pose_stamped(ns: int, frame_id: str, T: np.ndarray) -> dict:
    return {"header": header(ns, frame_id), "pose": pose(T)}


def distortion(camera: Camera) -> tuple[str, list[float]]:
    """The ROS distortion model and ``D`` of a camera: ``plumb_bob`` (k1, k2, p1, p2, k3) for
    up to 5 coefficients (none: zeros), ``rational_polynomial`` (k1, k2, p1, p2, k3, k4, k5,
    k6) for 6 to 8, in OpenCV's order; more is a model ROS has no name for."""
    d = [] if camera.dist is None else [float(v) for v in np.ravel(camera.dist)]
    if len(d) <= 5:
        return "plumb_bob", d + [0.0] * (5 - len(d))
    if len(d) <= 8:
        return "rational_polynomial", d + [0.0] * (8 - len(d))
    raise CellsightError(f"camera {camera.name}: {len(d)} distortion coefficients; a ROS "
                         f"CameraInfo takes at most 8 (rational_polynomial)")


def camera_info(ns: int, frame_id: str, camera: Camera) -> dict:
    """``sensor_msgs/CameraInfo`` of a camera: K, D, R = I and P, the camera's kept ``P`` (its
    calibration file's, the rectified image's projection), else ``[K | 0]`` (a monocular
    camera: rectified images would keep ``K``)."""
    model, d = distortion(camera)
    K = np.asarray(camera.K, dtype=float)
    P = camera.P if camera.P is not None else np.hstack([K, np.zeros((3, 1))])
    return {"header": header(ns, frame_id), "height": camera.height, "width": camera.width,
            "distortion_model": model, "d": d, "k": K.ravel().tolist(),
            "r": np.eye(3).ravel().tolist(), "p": P.ravel().tolist(), "binning_x": 0,
            "binning_y": 0, "roi": {"x_offset": 0, "y_offset": 0, "height": 0, "width": 0,
                                    "do_rectify": False}}


def joint_state(ns: int, names: list[str], positions: list[float]) -> dict:
    """``sensor_msgs/JointState`` of named positions (rad, m), no velocities or efforts."""
    return {"header": header(ns, ""), "name": list(names),
            "position": [float(v) for v in positions], "velocity": [], "effort": []}


def mono8_image(ns: int, frame_id: str, image: np.ndarray) -> dict:
    """``sensor_msgs/Image`` of an (H, W) uint8 grayscale image."""
    image = np.ascontiguousarray(image, dtype=np.uint8)
    if image.ndim != 2:
        raise ValueError(f"expected an (H, W) grayscale image, got shape {image.shape}")
    h, w = image.shape
    return {"header": header(ns, frame_id), "height": h, "width": w, "encoding": "mono8",
            "is_bigendian": 0, "step": w, "data": image.tobytes()}


def color(rgba) -> dict:
    return {"r": float(rgba[0]), "g": float(rgba[1]), "b": float(rgba[2]), "a": float(rgba[3])}


def marker(stamp: dict, key: tuple[str, int], kind: int, *, scale=(1.0, 1.0, 1.0),
           points=(), colors=(), text: str = "", position=(0.0, 0.0, 0.0)) -> dict:
    """A white ``visualization_msgs/Marker`` to add, ``stamp`` its :func:`header`, ``key`` its
    namespace and id (lifetime 0: until replaced by the next one of the same key);
    ``colors``: per point."""
    namespace, marker_id = key
    return {"header": stamp, "ns": namespace, "id": marker_id, "type": kind,
            "action": 0, "pose": {"position": point(position),
                                  "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
            "scale": {"x": float(scale[0]), "y": float(scale[1]), "z": float(scale[2])},
            "color": color(WHITE), "lifetime": {"sec": 0, "nanosec": 0}, "frame_locked": False,
            "points": [point(p) for p in points], "colors": [color(c) for c in colors],
            "text": text}

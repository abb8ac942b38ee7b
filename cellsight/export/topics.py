"""The topic and joint-name conventions a run is recorded and exported with (ROS 2 message
types, topic names, ``/joint_states`` names); how a recording that names things otherwise is
read: :mod:`cellsight.recording.names`. ``<cam>``, ``<part>``: the cell's camera and workpiece
names as ROS name tokens (:func:`~cellsight.export.ros.topic_token`)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from cellsight.export.ros import topic_token
from cellsight.model.cell import Cell

JOINT_STATES = "/joint_states"
IMAGE, COMPRESSED, CAMERA_INFO, JOINT_STATE, POSE, TRANSFORM, TF = (
    "sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/CameraInfo",
    "sensor_msgs/msg/JointState", "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/TransformStamped", "tf2_msgs/msg/TFMessage")
TRUTH_TYPES = (POSE, TRANSFORM, TF)
OPENING = "jaw_opening"


def joint_name(robot: str, joint: str) -> str:
    """The conventional name of a robot's joint in ``/joint_states``."""
    return f"{robot}/{joint}"


def joint_positions(cell: Cell, joints: Mapping[str, np.ndarray],
                    openings: Mapping[str, float]) -> tuple[list[str], list[float]]:
    """The ``/joint_states`` names and positions of robots' joints (robot -> joint vector,
    rad / m) and of grippers' jaw openings (robot -> m), named by the convention; a URDF
    hand's opening as its two finger joints' values (m), as the robot's driver gives them."""
    names, positions = [], []
    for robot, q in joints.items():
        names += [joint_name(robot, j) for j in cell.robot(robot).chain.joint_names]
        positions += [float(v) for v in q]
    for robot, opening in openings.items():
        tool = cell.robot(robot).tool
        fingers = [] if tool is None else [jaw.joint for jaw in tool.jaws if jaw.joint]
        if fingers:  # a URDF hand: its fingers' own joints, the mimic's too
            names += [joint_name(robot, j) for j in fingers]
            positions += [float(v) for v in tool.jaw_values(opening)]
        else:
            names.append(joint_name(robot, OPENING))
            positions.append(float(opening))
    return names, positions


def image_topic(camera: str) -> str:
    return f"/{topic_token(camera)}/image_raw"


def compressed_topic(camera: str) -> str:
    return f"{image_topic(camera)}/compressed"


def camera_info_topic(camera: str) -> str:
    return f"/{topic_token(camera)}/camera_info"


def truth_topic(part: str) -> str:
    return f"/{topic_token(part)}/true_pose"

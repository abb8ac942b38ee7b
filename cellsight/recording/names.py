"""Where a recording keeps what the tracker needs: the topic and joint-name conventions, and
the YAML topic map for recordings that name things otherwise.

Conventions (``<cam>``, ``<part>``: the cell's camera and workpiece names as ROS name tokens,
:func:`~cellsight.export.ros.topic_token`):

- ``/<cam>/image_raw`` (``sensor_msgs/msg/Image``) or ``/<cam>/image_raw/compressed``
  (``sensor_msgs/msg/CompressedImage``): each camera's images, stamped with their exposure
  time;
- ``/<cam>/camera_info`` (``sensor_msgs/msg/CameraInfo``, optional; beside a mapped image
  topic, ``/ns/camera_info`` for ``/ns/image_raw``): checked against the cell;
- ``/joint_states`` (``sensor_msgs/msg/JointState``): every robot's joints, named
  ``<robot>/<joint>`` (the URDF's joint names; ``joint1`` .. ``joint<n>`` for DH robots), and
  each gripper's jaw opening (m) as the joint ``<robot>/jaw_opening`` (a URDF hand's as its
  finger joints, ``<robot>/panda_finger_joint1``: the leader's value gives the opening, its
  mimic's is not read);
- ``/<part>/true_pose`` (``geometry_msgs/msg/PoseStamped`` in the cell's base frame,
  optional): the part's true pose, where something measured it (the simulator, a motion
  capture), for the metrics. The topic map may name instead a ``TransformStamped`` topic or a
  TF topic (``tf2_msgs/msg/TFMessage``), whose transform to the child frame ``<part>_true``
  (or the map's ``truth_frames``) is the pose in the cell's base frame.

A topic map (``--topics FILE``) names other topics and joints; everything it leaves out
follows the conventions::

    cameras: {cam1: /left/image_raw, cam2: /right/image_raw/compressed}
    camera_info: {cam1: /left/camera_info}
    joint_states: [/robot_a/joint_states, /robot_b/joint_states]
    joints: {a_shoulder_pan_joint: UR5A/shoulder_pan_joint}   # recorded name -> robot/joint
    openings: {a_gripper_opening: UR5A}                       # recorded name -> robot (m)
    ignore_joints: [conveyor_belt]                            # recorded names not used
    bits: {cam1: 12}                   # significant (low) bits of a camera's mono16 images
    truth: {part: /tf}
    truth_frames: {part: mocap/part}                          # the TF child frame
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from cellsight.errors import CellFileError
from cellsight.export.topics import (  # the conventions, shared with the exports
    CAMERA_INFO,
    COMPRESSED,
    IMAGE,
    JOINT_STATE,
    JOINT_STATES,
    OPENING,
    POSE,
    TF,
    TRANSFORM,
    TRUTH_TYPES,
    camera_info_topic,
    compressed_topic,
    image_topic,
    joint_name,
    joint_positions,
    truth_topic,
)
from cellsight.model.cell import Cell
from cellsight.model.yaml_input import load_yaml, read_cell_text

MONO16_BITS = (10, 16)  # the significant bits a topic map may declare for mono16 images

__all__ = [
    "CAMERA_INFO",
    "COMPRESSED",
    "IMAGE",
    "JOINT_STATE",
    "JOINT_STATES",
    "OPENING",
    "POSE",
    "TF",
    "TRANSFORM",
    "TRUTH_TYPES",
    "camera_info_topic",
    "compressed_topic",
    "image_topic",
    "joint_name",
    "joint_positions",
    "truth_topic",
    "MONO16_BITS",
    "TopicMap",
    "load_topic_map",
]


class TopicMap(BaseModel):
    """Topics and joint names of a recording that departs from the conventions (module
    docstring); an empty map means the conventions throughout."""

    model_config = ConfigDict(extra="forbid", strict=True)

    cameras: dict[str, str] = Field(default_factory=dict)
    camera_info: dict[str, str] = Field(default_factory=dict)
    joint_states: list[str] = Field(default_factory=lambda: [JOINT_STATES])
    joints: dict[str, str] = Field(default_factory=dict)
    openings: dict[str, str] = Field(default_factory=dict)
    ignore_joints: list[str] = Field(default_factory=list)
    truth: dict[str, str] = Field(default_factory=dict)
    truth_frames: dict[str, str] = Field(default_factory=dict)
    bits: dict[str, int] = Field(default_factory=dict)
    file: str = "<topic map>"

    def truth_frame(self, part: str) -> str:
        """The TF child frame of a workpiece's true pose."""
        return self.truth_frames.get(part, f"{part}_true")

    def check(self, cell: Cell) -> None:
        """Every camera, robot, joint and workpiece the map names is the cell's (a
        :class:`CellFileError` naming the map's file and field otherwise)."""
        cameras = [c.name for c in cell.cameras]
        for name, bits in self.bits.items():
            if not MONO16_BITS[0] <= bits <= MONO16_BITS[1]:
                raise CellFileError(self.file, f"bits.{name}", bits,
                                    f"the significant bits of a mono16 image, "
                                    f"{MONO16_BITS[0]} to {MONO16_BITS[1]}")
        for field, names in (("cameras", self.cameras), ("camera_info", self.camera_info),
                             ("bits", self.bits)):
            for name in names:
                if name not in cameras:
                    raise CellFileError(self.file, f"{field}.{name}", name,
                                        f"a camera of cell {cell.source}: {', '.join(cameras)}")
        joints = {joint_name(r.name, j) for r in cell.robots for j in r.chain.joint_names}
        for recorded, target in self.joints.items():
            if target not in joints:
                raise CellFileError(self.file, f"joints.{recorded}", target,
                                    f"ROBOT/JOINT of the cell: {', '.join(sorted(joints))}")
        grippers = [r.name for r in cell.robots if r.tool is not None]
        for recorded, robot in self.openings.items():
            if robot not in grippers:
                raise CellFileError(self.file, f"openings.{recorded}", robot,
                                    f"a robot with a gripper: {', '.join(grippers) or 'none'}")
        parts = [p.name for p in cell.workpieces]
        for field, names in (("truth", self.truth), ("truth_frames", self.truth_frames)):
            for part in names:
                if part not in parts:
                    raise CellFileError(self.file, f"{field}.{part}", part,
                                        f"a workpiece of the cell: {', '.join(parts)}")


def load_topic_map(path: str | Path | None) -> TopicMap:
    """The topic map in the YAML file ``path`` (None: the conventions); a malformed one is a
    :class:`CellFileError` naming the file, the field and the value."""
    if path is None:
        return TopicMap()
    file = str(path)
    if not Path(path).is_file():
        raise CellFileError(file, "<file>", file, "an existing YAML topic map")
    raw = load_yaml(read_cell_text(Path(path)), file) or {}
    if not isinstance(raw, dict):
        raise CellFileError(file, "<root>", raw, "a mapping (cameras, joint_states, joints, "
                            "openings, ignore_joints, camera_info, truth, truth_frames, bits)")
    try:
        return TopicMap.model_validate({**raw, "file": file})
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(p) for p in err["loc"])
        expected = (f"one of the keys {', '.join(k for k in TopicMap.model_fields if k != 'file')}"
                    if err["type"] == "extra_forbidden" else err["msg"])
        raise CellFileError(file, loc, err.get("input"), expected) from exc

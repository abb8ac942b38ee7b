"""``cellsight run --record FILE``: a run's sensor data written as a real cell records it, in
an MCAP file of ROS 2 messages, as the run goes.

Per vision frame at time ``t`` (log time ``t``; topics: :mod:`.names`):

- ``/joint_states``: every robot's joints as the encoders read them (what the tracker was
  given), ``<robot>/<joint>``, and each gripper's jaw opening ``<robot>/jaw_opening`` (m),
  stamped ``t``;
- per camera, unless the frame was dropped: its whole image as the camera exposed it (with the
  realism profile's image effects), ``/<cam>/image_raw`` (mono8, lossless) or, with a JPEG
  quality, ``/<cam>/image_raw/compressed``; and ``/<cam>/camera_info`` (the cell's
  calibration), both stamped with the exposure time;
- ``/<part>/true_pose``: the part's true pose in the base frame (the simulator's truth),
  stamped ``t``;
- once, ``/tf_static``: the cell's fixed frames (:mod:`cellsight.export.frames`), latched
  (rosbag2's QoS metadata, written by :class:`cellsight.export.rosbag.RosBag` as the export
  writes it).

``cellsight track`` over the file gives the run's estimates again (the same images, joints,
openings and stamps reach the tracker). Time: ROS time ``t`` ns from the Unix epoch, as the
export (:mod:`cellsight.export.ros`). The file is written under a temporary name and takes its
name when closed; a run that ends early closes it with the frames so far (its ``cellsight``
metadata says ``complete: false``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from cellsight.export import frames as tf
from cellsight.export import ros
from cellsight.export.rosbag import RosBag, check_jpeg, jpeg_image
from cellsight.model.cell import Cell
from cellsight.recording import names
from cellsight.runfolder.digest import cell_digest
from cellsight.runfolder.writes import AtomicFile, RunWrites
from cellsight.session.frames import FrameRecord
from cellsight.session.protocols import RunContext
from cellsight.tracking.grabbing import grabbed

JOINT_STATE, IMAGE, COMPRESSED, CAMERA_INFO, POSE, TF = (
    "sensor_msgs/JointState", "sensor_msgs/Image", "sensor_msgs/CompressedImage",
    "sensor_msgs/CameraInfo", "geometry_msgs/PoseStamped", "tf2_msgs/TFMessage")


class Recorder:
    """Writes a run's sensor data to ``path`` (module docstring); ``jpeg``: JPEG quality of
    the images (None: lossless mono8)."""

    def __init__(self, path: Path, cell: Cell, part: str, jpeg: int | None = None) -> None:
        check_jpeg(jpeg, "--record-jpeg")
        self.path, self.cell, self.part, self.jpeg = Path(path), cell, part, jpeg
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = AtomicFile(self.path)
        self._bag = RosBag(self._file, "cellsight run --record")
        self._write = self._bag.write
        self.frames = 0

    def frame(self, t: float, observed: Sequence | None, stamps: Sequence[float | None] | None,
              joints: Mapping[str, np.ndarray], openings: Mapping[str, float],
              T_true: np.ndarray | None) -> None:
        """Record frame ``t`` (s): ``observed`` the cameras' exposures (images or shots; None
        for a camera, or the whole frame, that gave nothing), ``stamps`` their exposure times
        (None: ``t``), the measured ``joints``, the jaw ``openings`` and the part's true pose
        (None: not recorded, as in a calibration motion)."""
        ns = ros.time_ns(t)
        if self.frames == 0:
            static = tf.static_transforms(self.cell, self.part)
            self._write("/tf_static", TF, {"transforms": [ros.transform(ns, *s)
                                                          for s in static]}, ns)
        self._write(names.JOINT_STATES, JOINT_STATE,
                    ros.joint_state(ns, *names.joint_positions(self.cell, joints, openings)), ns)
        for c, cam in enumerate(self.cell.cameras):
            image = None if observed is None else observed[c]
            if image is None:
                continue
            stamp = stamps[c] if stamps is not None and stamps[c] is not None else t
            self._image(c, image, ros.time_ns(stamp), ns)
            info = ros.camera_info(ros.time_ns(stamp), tf.optical_frame(cam.name), cam)
            self._write(names.camera_info_topic(cam.name), CAMERA_INFO, info, ns)
        if T_true is not None:
            self._write(names.truth_topic(self.part), POSE,
                        ros.pose_stamped(ns, tf.ROOT, T_true), ns)
        self.frames += 1

    def _image(self, c: int, observed: object, stamp_ns: int, ns: int) -> None:
        cam = self.cell.cameras[c]
        image = np.asarray(grabbed(observed))
        frame = tf.optical_frame(cam.name)
        if self.jpeg is None:
            self._write(names.image_topic(cam.name), IMAGE,
                        ros.mono8_image(stamp_ns, frame, image), ns)
        else:
            self._write(names.compressed_topic(cam.name), COMPRESSED,
                        jpeg_image(stamp_ns, frame, image, self.jpeg), ns)

    def joints(self, t: float, joints: Mapping[str, np.ndarray],
               openings: Mapping[str, float]) -> None:
        """Record the encoders' ``joints`` (and jaw ``openings``) alone at ``t`` (s)."""
        ns = ros.time_ns(t)
        self._write(names.JOINT_STATES, JOINT_STATE,
                    ros.joint_state(ns, *names.joint_positions(self.cell, joints, openings)), ns)

    def close(self, complete: bool, facts: Mapping[str, str] | None = None) -> None:
        """Finish the file (its metadata says whether the run ended ``complete``, and
        ``facts``) and give it its name."""
        self._bag.close({
            "cell": str(self.cell.source), "cell_sha256": cell_digest(self.cell) or "",
            "part": self.part, "frames": str(self.frames),
            "images": "mono8" if self.jpeg is None else f"jpeg quality {self.jpeg}",
            "time": "stamps and log times: the run's time t (s) from the Unix epoch",
            "complete": "true" if complete else "false", **(facts or {})})
        self._file.commit()


class RecordingSink:
    """The sink that records a run (:class:`Recorder`) into ``path``; ``jpeg``: JPEG quality
    of the images (None: lossless mono8). The file's metadata says whether the run
    completed."""

    def __init__(self, path: Path, jpeg: int | None = None) -> None:
        self.path, self.jpeg = Path(path), jpeg
        self.recorder: Recorder | None = None
        self.part: str | None = None  # the workpiece recorded
        self.writes: RunWrites | None = None

    def start(self, run: RunContext) -> None:
        self.writes = run.writes
        self.part = run.part.name  # a line's first pick, as its frames.csv
        with run.writes.guard(self.path):
            self.recorder = Recorder(self.path, run.cell, self.part, self.jpeg)

    def frame(self, record: FrameRecord) -> None:
        frame, truth = record.frame, record.truth_of(self.part)
        with self.writes.guard(self.path):
            self.recorder.frame(frame.t, frame.observed, frame.stamps, frame.joints,
                                frame.openings, None if truth.part is None
                                else truth.part.T_base_part)

    def close(self, completed: bool) -> None:
        self.writes.close(self.path, lambda: self.recorder.close(completed))

"""``--live``: a run, or a recording being tracked, streamed to Foxglove as it happens.

A Foxglove WebSocket server (``foxglove-sdk``) at ``ws://HOST:PORT`` (WebSocket subprotocol
``foxglove.sdk.v1``; in Foxglove: Open connection, Foxglove WebSocket). Channels, in
Foxglove's own protobuf schemas (``<cam>``, ``<part>``: ROS name tokens of the cell's names):

- ``/tf`` (``foxglove.FrameTransforms``): the cell's fixed frames and every robot's chain
  frames at the measured joints (the TF tree of :mod:`cellsight.export.frames`), the part's
  estimate ``<part>_est`` and, where the truth is known, ``<part>_true``;
- ``/<part>/estimate`` (``foxglove.PoseInFrame``, in the root frame) where there is one;
- ``/<cam>/visibility`` (``foxglove.SceneUpdate``): a sphere per feature at the estimated pose,
  green where predicted visible, red where hidden;
- ``/<cam>/image`` (``foxglove.CompressedImage``, JPEG, half the resolution): the camera's
  image with the tracker's predictions, windows and measurements drawn
  (:func:`~cellsight.report.overlay.draw_camera_overlay`), every ``image_every``-th frame;
- ``/status`` (``foxglove.Log``): the tracker's status, info / warning / error.

Time: every message is stamped with the wall clock at the first frame plus the run's ``t``.
Nothing the run computes reads the stream back. Messages are only made for channels a client
subscribes to; the images are drawn and encoded in a thread of their own, one frame at a time
(a frame arriving while one is in hand is dropped, :attr:`LiveStream.dropped`), and the SDK
drops the messages a slow client cannot take: the run never waits for a viewer.
"""

from __future__ import annotations

import logging
import queue
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from cellsight.errors import CellsightError
from cellsight.export import frames as tf
from cellsight.export.ros import topic_token
from cellsight.geometry.transforms import transform_points
from cellsight.model.cell import Cell
from cellsight.report.overlay import FeatureMarks, draw_camera_overlay
from cellsight.session.frames import FrameRecord
from cellsight.session.protocols import RunContext
from cellsight.tracking.records import PartFrame
from cellsight.view.inputs import check_port

log = logging.getLogger(__name__)

DEFAULT_PORT = 8765
LEVELS = {"lost": "Error", "degraded": "Warning", "coasting": "Warning"}
"""``foxglove.LogLevel`` of the tracker's statuses (the others: ``Info``)."""


def parse_address(text: str) -> tuple[str, int]:
    """``HOST:PORT``, ``:PORT`` or ``PORT`` (host 127.0.0.1) as (host, port); port 0 picks a
    free one. The port is tried before anything runs: one in use, or a host this machine
    cannot listen on, is a :class:`CellsightError` naming ``--live`` and the address."""
    host, _, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not 0 <= number <= 65535:
        raise CellsightError(f"--live: expected [HOST:]PORT with a port 0-65535, got {text!r}")
    host = host or "127.0.0.1"
    check_port(host, number, "--live", "--live")
    return host, number


def _stamp(ns: int):
    from foxglove.messages import Timestamp

    return Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def _vector_quaternion(T: np.ndarray) -> tuple:
    """A 4x4 pose's translation (``foxglove.Vector3``) and rotation (``foxglove.Quaternion``)."""
    from foxglove.messages import Quaternion, Vector3

    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    return (Vector3(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
            Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))


def _pose(T: np.ndarray):
    from foxglove.messages import Pose

    position, orientation = _vector_quaternion(T)
    return Pose(position=position, orientation=orientation)


def _transform(ns: int, parent: str, child: str, T: np.ndarray):
    from foxglove.messages import FrameTransform

    translation, rotation = _vector_quaternion(T)
    return FrameTransform(timestamp=_stamp(ns), parent_frame_id=parent, child_frame_id=child,
                          translation=translation, rotation=rotation)


class _Painter:
    """Draws and sends the cameras' images in a thread of its own, one frame at a time."""

    def __init__(self, channels: list, names: list[str]) -> None:
        self.channels, self.names = channels, names
        self.dropped = 0
        self._queue: queue.Queue = queue.Queue(maxsize=1)
        self._thread = threading.Thread(target=self._work, name="cellsight-live", daemon=True)
        self._thread.start()

    def offer(self, job: tuple) -> None:
        try:
            self._queue.put_nowait(job)
        except queue.Full:
            self.dropped += 1

    def _work(self) -> None:
        from foxglove.messages import CompressedImage

        while (job := self._queue.get()) is not None:
            ns, images, rec, unknown = job
            for c, image in enumerate(images):
                if image is None:
                    continue
                plan = rec.windows[c]
                marks = FeatureMarks(rec.pixels[c], rec.predicted_visible[c], rec.selected[c],
                                     rec.measured[c], rec.rejected[c])
                picture = draw_camera_overlay(
                    image, marks, title=self.names[c],
                    boxes=np.zeros((0, 4), int) if plan is None else plan.boxes,
                    unknown=unknown[c] if c < len(unknown) else None)
                small = cv2.resize(picture, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
                ok, data = cv2.imencode(".jpg", cv2.cvtColor(small, cv2.COLOR_RGB2BGR),
                                        [cv2.IMWRITE_JPEG_QUALITY, 80])
                if ok:
                    self.channels[c].log(CompressedImage(
                        timestamp=_stamp(ns), frame_id=tf.optical_frame(self.names[c]),
                        data=data.tobytes(), format="jpeg"), log_time=ns)

    def close(self) -> None:
        self._queue.put(None)
        self._thread.join(timeout=5.0)


class LiveStream:
    """The Foxglove server of one run (module docstring) for workpiece ``part`` of ``cell``;
    ``image_every``: an image every so many frames."""

    def __init__(self, cell: Cell, part: str, host: str = "127.0.0.1",
                 port: int = DEFAULT_PORT, image_every: int = 2) -> None:
        import foxglove
        from foxglove.channels import (
            CompressedImageChannel,
            FrameTransformsChannel,
            LogChannel,
            PoseInFrameChannel,
            SceneUpdateChannel,
        )

        self.cell, self.part, self.image_every = cell, cell.workpiece(part), image_every
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(name="cellsight", host=host, port=port,
                                                context=self.context)
        except RuntimeError as exc:  # taken between the check and now
            raise CellsightError(f"--live: {host}:{port} is already in use ({exc})") from None
        token, ctx = topic_token(part), self.context
        self.tf = FrameTransformsChannel("/tf", context=ctx)
        self.estimate = PoseInFrameChannel(f"/{token}/estimate", context=ctx)
        self.status = LogChannel("/status", context=ctx)
        cams = [topic_token(c.name) for c in cell.cameras]
        self.visibility = [SceneUpdateChannel(f"/{c}/visibility", context=ctx) for c in cams]
        self.images = [CompressedImageChannel(f"/{c}/image", context=ctx) for c in cams]
        self.painter = _Painter(self.images, [c.name for c in cell.cameras])
        self.static = tf.static_transforms(cell, part)
        self.frames = 0
        self._t0_ns: int | None = None
        log.info("live: Foxglove WebSocket at ws://%s:%d", host, self.port)
        print(f"cellsight: live at ws://{host}:{self.port} (Foxglove: Open connection, Foxglove "
              f"WebSocket)", file=sys.stderr)

    @property
    def port(self) -> int:
        return int(self.server.port)

    @property
    def dropped(self) -> int:
        """Frames whose images were not sent: the painter had one in hand."""
        return self.painter.dropped

    def frame(self, t: float, joints: Mapping[str, np.ndarray], rec: PartFrame,
              unknown: Sequence[Any], images: Sequence[Any] | None = None,
              T_true: np.ndarray | None = None) -> None:
        """Stream the frame at run time ``t`` (s): the measured ``joints``, the tracker's
        record ``rec`` of the part, the unknown-occluder maps, the cameras' ``images`` (arrays,
        or anything with ``preview(scale)``; None: none) and the part's true pose if known."""
        if self._t0_ns is None:
            self._t0_ns = time.time_ns() - int(round(t * 1e9))
        ns = self._t0_ns + int(round(t * 1e9))
        estimate = rec.T_base_part if rec.status.has_estimate else None
        if self.tf.has_sinks():
            self._transforms(ns, joints, estimate, T_true)
        if estimate is not None and self.estimate.has_sinks():
            from foxglove.messages import PoseInFrame

            self.estimate.log(PoseInFrame(timestamp=_stamp(ns), frame_id=tf.ROOT,
                                          pose=_pose(estimate)), log_time=ns)
        if self.status.has_sinks():
            from foxglove.messages import Log, LogLevel

            level = getattr(LogLevel, LEVELS.get(str(rec.status), "Info"))
            self.status.log(Log(timestamp=_stamp(ns), level=level, message=rec.status_text,
                                name="cellsight"), log_time=ns)
        if estimate is not None:
            self._visibility(ns, rec, estimate)
        if images is not None and self.frames % self.image_every == 0 and any(
                ch.has_sinks() for ch in self.images):
            shown = [None if i is None else i.preview(0.5) if hasattr(i, "preview")
                     else np.asarray(i) for i in images]
            self.painter.offer((ns, shown, rec, list(unknown)))
        self.frames += 1

    def _transforms(self, ns: int, joints: Mapping[str, np.ndarray],
                    estimate: np.ndarray | None, T_true: np.ndarray | None) -> None:
        from foxglove.messages import FrameTransforms

        moving = [t for r in self.cell.robots if r.name in joints
                  for t in tf.robot_transforms(r, joints[r.name])]
        true_frame, est_frame = tf.part_frames(self.part.name)
        for frame, T in ((true_frame, T_true), (est_frame, estimate)):
            if T is not None and np.all(np.isfinite(T)):
                moving.append((tf.ROOT, frame, T))
        self.tf.log(FrameTransforms(transforms=[_transform(ns, *t)
                                                for t in [*self.static, *moving]]), log_time=ns)

    def _visibility(self, ns: int, rec: PartFrame, estimate: np.ndarray) -> None:
        from foxglove.messages import Color, SceneEntity, SceneUpdate, SpherePrimitive, Vector3

        points = transform_points(estimate, self.part.feature_points)
        size = Vector3(x=0.01, y=0.01, z=0.01)
        green, red = Color(r=0.1, g=0.85, b=0.2, a=1.0), Color(r=0.95, g=0.15, b=0.1, a=1.0)
        for c, channel in enumerate(self.visibility):
            if not channel.has_sinks():
                continue
            spheres = [SpherePrimitive(pose=_pose(_translation(p)), size=size,
                                       color=green if rec.predicted_visible[c, j] else red)
                       for j, p in enumerate(points)]
            entity = SceneEntity(timestamp=_stamp(ns), frame_id=tf.ROOT,
                                 id=f"{self.part.name}/{self.cell.cameras[c].name}",
                                 spheres=spheres)
            channel.log(SceneUpdate(entities=[entity]), log_time=ns)

    def close(self) -> None:
        """Stop the painter and the server."""
        self.painter.close()
        self.server.stop()
        if self.painter.dropped:
            log.info("live: %d of %d frames' images not sent (the painter was busy)",
                     self.painter.dropped, self.frames)


class LiveSink:
    """The sink that streams a run to Foxglove (:class:`LiveStream`) at ``address``
    (``[HOST:]PORT``); ``paced``: at the run's own pace (a recording: each frame no sooner
    than its time since the first), else as fast as the run goes."""

    def __init__(self, address: str, paced: bool = False) -> None:
        self.address, self.paced = parse_address(address), paced
        self.stream: LiveStream | None = None
        self.part: str | None = None  # the workpiece streamed
        self._start: tuple[float, float] | None = None  # (wall clock, run time) s

    def start(self, run: RunContext) -> None:
        self.part = run.part.name  # a line's first pick, as its frames.csv
        self.stream = LiveStream(run.cell, self.part, *self.address)

    def frame(self, record: FrameRecord) -> None:
        frame, truth = record.frame, record.truth_of(self.part)
        if self.paced:
            self._wait(frame.t)
        self.stream.frame(frame.t, frame.joints, record.result.parts[self.part],
                          record.result.unknown,
                          frame.observed if frame.images else None,
                          None if truth.part is None else truth.part.T_base_part)

    def _wait(self, t: float) -> None:
        """Wait until the wall clock has moved on as far as the run since its first frame."""
        now = time.monotonic()
        if self._start is None:
            self._start = (now, t)
        time.sleep(max(0.0, (t - self._start[1]) - (now - self._start[0])))

    def close(self, completed: bool) -> None:
        self.stream.close()


def _translation(p: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = p
    return T

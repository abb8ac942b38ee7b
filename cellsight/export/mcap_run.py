"""A run folder (``cellsight run``) as an MCAP file of ROS 2 messages, for ROS 2 tools and
Foxglove.

Topics (``<cam>``, ``<part>``: the camera's and the workpiece's names as ROS name tokens,
:func:`~cellsight.export.ros.topic_token`):

- ``/tf_static`` (``tf2_msgs/msg/TFMessage``, once, at the first frame, latched: its channel's
  rosbag2 QoS metadata offers durability ``transient_local``, :func:`qos_profiles`, so that
  ``ros2 bag play`` republishes it latched): the fixed frames of
  :mod:`cellsight.export.frames` (REP 103/105 names, root ``world``): robots' bases, a URDF
  robot's fixed links (``<robot>/base_link``, ``<robot>/tool0``, ...), tools and TCPs,
  cameras' optical frames ``<cam>_optical_frame``, static objects;
- ``/robot_description`` (``std_msgs/msg/String``, once, at the first frame, latched): a URDF
  robot's URDF text (:func:`robot_descriptions`; ``/<robot>/robot_description`` each when the
  cell has several; none for DH robots), so that Foxglove's URDF layer and ROS tools draw the
  robot from TF (its links are ``<robot>/<link>``: set the layer's frame prefix to
  ``<robot>/``);
- ``/tf`` (one per frame): every robot's chain frames at the logged joints, ``<part>_true``
  and, in frames where the tracker has one, ``<part>_est``;
- ``/joint_states`` (``sensor_msgs/msg/JointState``, one per frame): every robot's logged
  (true) joints (rad, m), named ``<robot>/<joint>`` (the chain's joint names: the URDF's,
  ``joint1`` .. for DH robots; :func:`cellsight.export.topics.joint_name`), and the grasping
  robot's jaw opening (m) as ``<robot>/jaw_opening`` in frames that log it: the convention
  ``cellsight track`` reads (:mod:`cellsight.recording.names`);
- ``/<part>/true_pose``, ``/<part>/est_pose`` (``geometry_msgs/msg/PoseStamped``, frame
  ``world``; the estimate only in frames that have one) and, with the estimate,
  ``/<part>/est_pose_with_covariance`` (``geometry_msgs/msg/PoseWithCovarianceStamped``, for
  ROS tools that take an estimator's output): frames.csv keeps no covariance of the estimate,
  so it is marked unknown, the ROS convention: ``covariance[0] = -1``, the rest 0;
- ``/<cam>/visibility`` (``visualization_msgs/msg/MarkerArray``, one per frame):
  :mod:`cellsight.export.markers`;
- ``/<cam>/annotations`` (``visualization_msgs/msg/ImageMarker``, two per frame): the tracker's
  windows and measured corners on the camera's image (:mod:`cellsight.export.image_markers`);
- ``/diagnostics`` (``diagnostic_msgs/msg/DiagnosticArray``, one per frame, Foxglove's
  Diagnostics panel): the tracker's status for ``cellsight/<part>``, level OK (tracking,
  acquired), WARN (degraded, coasting), ERROR (lost) or STALE (waiting), the status text
  (``degraded: 96% not found in cam1``) as its message and the health figures of each camera
  (``nis_<cam>``, ``notfound_<cam>``, ``rejfrac_<cam>``; empty when not judged) as values;
- ``/<cam>/camera_info`` (``sensor_msgs/msg/CameraInfo``) and ``/<cam>/image_raw``
  (``sensor_msgs/msg/Image``, mono8, frame ``<cam>_optical_frame``; with a ``jpeg`` quality,
  ``/<cam>/image_raw/compressed`` instead, ``sensor_msgs/msg/CompressedImage``, format
  ``jpeg``, image_transport's topic), every ``every``-th frame
  (frames 0, every, 2 every, ...): the images are rendered again by MuJoCo at the logged state
  (robots' joints, the part at its true pose, the grasping robot's jaw opening), so the same
  for either sensor; ``images=False`` leaves the images out (the camera info stays).

Time: message stamps, log and publish times are all the start time (``start_time``,
``--start-time``: ISO 8601 or ns since the Unix epoch, :func:`start_time_ns`; default 0, the
Unix epoch) plus the frame's run time ``t``. Give a start time for tf2 and ROS tools: stamp 0
means "the latest" to tf2, so a run at 1970 reads wrongly there.

The file is written as the frames go, under a temporary name in its folder
(:class:`~cellsight.runfolder.writes.AtomicFile`), and takes its name once closed properly;
when interrupted (SIGINT, or the caller's :class:`Stop`) or failing, it is closed with the
frames written so far (its ``cellsight`` metadata then says ``complete: false``). When writing
the file itself fails (a full disk) nothing takes its name (a file there before, with
``overwrite``, is left as it was) and the failure is one
:class:`~cellsight.errors.CellsightError` naming the file and why.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from cellsight.errors import CellsightError
from cellsight.export import frames as tf
from cellsight.export import image_markers, markers, ros, topics
from cellsight.export.rosbag import (
    END_NS,
    RosBag,
    check_jpeg,
    check_output,
    jpeg_image,
    start_time_ns,
)
from cellsight.geometry.transforms import transform_points
from cellsight.model.cell import Cell
from cellsight.runfolder import RunData, WriteError, load_run
from cellsight.runfolder.framelog import camera_column, decode_corners, decode_windows
from cellsight.runfolder.writes import AtomicFile

TF, POSE, CAMERA_INFO, IMAGE, MARKERS, DIAGNOSTICS, JOINT_STATE = (
    "tf2_msgs/TFMessage", "geometry_msgs/PoseStamped", "sensor_msgs/CameraInfo",
    "sensor_msgs/Image", "visualization_msgs/MarkerArray", "diagnostic_msgs/DiagnosticArray",
    "sensor_msgs/JointState")
STRING, POSE_COV, COMPRESSED, IMAGE_MARKER = (
    "std_msgs/String", "geometry_msgs/PoseWithCovarianceStamped", "sensor_msgs/CompressedImage",
    "visualization_msgs/ImageMarker")
UNKNOWN_COVARIANCE = [-1.0] + [0.0] * 35  # ROS: element 0 at -1, no covariance known
LEVELS = {"tracking": 0, "acquired": 0, "degraded": 1, "coasting": 1, "predicting": 1,
          "lost": 2}  # DiagnosticStatus levels of the tracker's statuses (else STALE, 3)
HEALTH_COLUMNS = ("nis", "notfound", "rejfrac")  # frames.csv's health columns, per camera


class Stop(BaseException):  # a signal, like KeyboardInterrupt: not caught as an Exception
    """Raised (by a signal handler) to end an export early; ``args[0]`` names the signal."""


@dataclass
class ExportResult:
    """What was written: ``topics`` topic -> [message type, count]; ``frames`` of the run's
    ``total`` frames; ``stopped_by`` the signal that ended it early (None: complete)."""

    path: Path
    topics: dict[str, list] = field(default_factory=dict)
    frames: int = 0
    total: int = 0
    images: int = 0
    t_first: float = float("nan")
    t_last: float = float("nan")
    start_ns: int = 0
    stopped_by: str | None = None


@runtime_checkable
class RunImages(Protocol):
    """The cameras' images of a run's frames, one (H, W) uint8 array per camera of frame
    ``k``, as :func:`export_mcap` asks for them (every ``every``-th frame, in order); the
    simulated world re-renders them (:class:`cellsight.world.replay_images.ReplayImages`)."""

    def render(self, k: int) -> list[np.ndarray]:
        ...

    def close(self) -> None:
        ...


@dataclass(frozen=True)
class ExportOptions:
    """How to export: camera images and camera info every ``every``-th frame; ``jpeg``: the
    images' JPEG quality (None: raw mono8); ``start_time``: the ROS time of the run's t = 0
    (:func:`start_time_ns`); ``cell``: the run's cell, overriding the one its metrics.json
    names; ``overwrite``: replace the file; ``progress``: show a progress bar."""

    every: int = 1
    jpeg: int | None = None
    start_time: int | str = 0
    cell: str | Path | None = None
    overwrite: bool = False
    progress: bool = True


def robot_descriptions(cell: Cell) -> list[tuple[str, str]]:
    """(topic, URDF text) of each URDF robot of the cell: the file as it is (its lengths in
    its own unit, ``package://`` names unresolved), on ``/robot_description`` when the cell has
    one URDF robot, else on ``/<robot>/robot_description``; none for DH robots."""
    files = tf.urdf_files(cell)
    return [("/robot_description" if len(files) == 1
             else f"/{ros.topic_token(robot)}/robot_description",
             urdf.path.read_text(encoding="utf-8")) for robot, urdf in files.items()]


def _topic_tokens(run: RunData) -> tuple[list[str], str]:
    """The cameras' and the workpiece's names as topic tokens, checked distinct."""
    cams = [ros.topic_token(c.name) for c in run.cell.cameras]
    if len(set(cams)) != len(cams):
        raise CellsightError(f"cell {run.cell.source}: cameras {[c.name for c in run.cell.cameras]}"
                             f" give the same ROS topic names {cams}")
    return cams, ros.topic_token(run.part.name)


class _Frames:
    """The messages of each frame of a run (module docstring), buffered per frame so that an
    interruption falls between frames."""

    def __init__(self, run: RunData, every: int, images: RunImages | None,
                 jpeg: int | None = None, start_ns: int = 0) -> None:
        self.run, self.every, self.images, self.start_ns = run, every, images, start_ns
        self.jpeg = jpeg
        self.cams, self.part = _topic_tokens(run)
        self.static = tf.static_transforms(run.cell, run.part.name)
        self.descriptions = robot_descriptions(run.cell)
        self.size = markers.marker_size(run.part.feature_points)
        self.joint_states, self.joint_positions = topics.JOINT_STATES, topics.joint_positions
        self.holder = run.gripper
        n = len(run.part.feature_points)  # each camera's rejected corners, decoded once
        self.rejected = [run.frames.bits(camera_column("rej", c), n)
                         for c in range(1, len(run.cell.cameras) + 1)]

    def ns(self, k: int) -> int:
        """The ROS time (ns) of frame ``k``: the start time plus the run's time ``t``."""
        return self.start_ns + ros.time_ns(self.run.t[k])

    def once(self) -> list[tuple[str, str, dict]]:
        """The messages written once, at the first frame: /tf_static, the robot
        descriptions."""
        ns = self.ns(0)
        return ([("/tf_static", TF, {"transforms": [ros.transform(ns, *t)
                                                    for t in self.static]})]
                + [(topic, STRING, {"data": text}) for topic, text in self.descriptions])

    def messages(self, k: int) -> list[tuple[str, str, dict]]:
        """Every message of frame ``k``: (topic, type, message)."""
        run = self.run
        ns = self.ns(k)
        true_frame, est_frame = tf.part_frames(run.part.name)
        opening = run.opening[k] if np.isfinite(run.opening[k]) else None
        transforms = [t for r in run.cell.robots for t in tf.robot_transforms(
            r, run.joints[r.name][k], opening if r.name == self.holder else None)]
        has_true = bool(np.all(np.isfinite(run.T_true[k])))
        has_est = bool(np.all(np.isfinite(run.T_est[k])))
        if has_true:
            transforms.append((tf.ROOT, true_frame, run.T_true[k]))
        if has_est:
            transforms.append((tf.ROOT, est_frame, run.T_est[k]))
        out = [("/tf", TF, {"transforms": [ros.transform(ns, *t) for t in transforms]}),
               (self.joint_states, JOINT_STATE, self._joint_state(k, ns))]
        if has_true:
            out.append((f"/{self.part}/true_pose", POSE,
                        ros.pose_stamped(ns, tf.ROOT, run.T_true[k])))
        if has_est:
            out += [(f"/{self.part}/est_pose", POSE, ros.pose_stamped(ns, tf.ROOT, run.T_est[k])),
                    (f"/{self.part}/est_pose_with_covariance", POSE_COV, {
                        "header": ros.header(ns, tf.ROOT), "pose": {
                            "pose": ros.pose(run.T_est[k]), "covariance": UNKNOWN_COVARIANCE}})]
        out += self._markers(k, ns, run.T_true[k] if has_true else run.T_est[k])
        out += self._annotations(k, ns)
        out.append(("/diagnostics", DIAGNOSTICS, self._diagnostics(k, ns)))
        if k % self.every == 0:
            out += self._camera_messages(k, ns)
        return out

    def _joint_state(self, k: int, ns: int) -> dict:
        """Every robot's logged joints at frame ``k`` and the gripper's jaw opening (m), where
        logged (module docstring)."""
        run = self.run
        openings = ({self.holder: float(run.opening[k])}
                    if self.holder is not None and np.isfinite(run.opening[k]) else {})
        return ros.joint_state(ns, *self.joint_positions(
            run.cell, {r: q[k] for r, q in run.joints.items()}, openings))

    def _markers(self, k: int, ns: int, T_part: np.ndarray) -> list[tuple[str, str, dict]]:
        """Each camera's visibility markers at the part's pose ``T_part`` (the truth, else
        the estimate; none without either)."""
        if not np.all(np.isfinite(T_part)):
            return []
        run, out = self.run, []
        points = transform_points(T_part, run.part.feature_points)
        for c, (cam, token) in enumerate(zip(run.cell.cameras, self.cams, strict=True)):
            predicted = run.vis_pred[c][k] if run.vis_pred_present[c][k] else None
            truth = run.vis_true[c][k] if run.vis_true_present[c][k] else None
            out.append((f"/{token}/visibility", MARKERS, markers.visibility_markers(
                ns, points, run.part.feature_names, cam.center, predicted, truth, self.size)))
        return out

    def _diagnostics(self, k: int, ns: int) -> dict:
        """The tracker's status and health at frame ``k`` (module docstring)."""
        frames = self.run.frames
        status = frames.text("status")[k]
        values = [{"key": f"{column}_{cam.name}",
                   "value": frames.text(camera_column(column, c))[k]}
                  for c, cam in enumerate(self.run.cell.cameras, start=1)
                  for column in HEALTH_COLUMNS]
        return {"header": ros.header(ns, tf.ROOT),
                "status": [{"level": LEVELS.get(status.split(":")[0], 3),
                            "name": f"cellsight/{self.run.part.name}", "message": status,
                            "hardware_id": "", "values": values}]}

    def _annotations(self, k: int, ns: int) -> list[tuple[str, str, dict]]:
        """Each camera's windows and measured corners of frame ``k`` on its image
        (:mod:`cellsight.export.image_markers`)."""
        frames, n = self.run.frames, len(self.run.part.feature_points)
        out = []
        for c, (cam, token) in enumerate(zip(self.run.cell.cameras, self.cams, strict=True),
                                         start=1):
            try:
                _, boxes = decode_windows(frames.text(camera_column("windows", c))[k])
                corners = decode_corners(frames.text(camera_column("corners", c))[k], n)
            except ValueError as exc:
                raise CellsightError(f"frames.csv row {k + 1}: {exc}") from exc
            out += [(f"/{token}/annotations", IMAGE_MARKER, m) for m in image_markers.annotations(
                ns, tf.optical_frame(cam.name), boxes, corners, self.rejected[c - 1][k])]
        return out

    def _camera_messages(self, k: int, ns: int) -> list[tuple[str, str, dict]]:
        images = self.images.render(k) if self.images is not None else None
        out = []
        for c, (cam, token) in enumerate(zip(self.run.cell.cameras, self.cams, strict=True)):
            frame = tf.optical_frame(cam.name)
            out.append((f"/{token}/camera_info", CAMERA_INFO, ros.camera_info(ns, frame, cam)))
            if images is not None and self.jpeg is not None:
                out.append((f"/{token}/image_raw/compressed", COMPRESSED,
                            jpeg_image(ns, frame, images[c], self.jpeg)))
            elif images is not None:
                out.append((f"/{token}/image_raw", IMAGE, ros.mono8_image(ns, frame, images[c])))
        return out


def _progress_bar(enabled: bool):
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("frames"), TimeElapsedColumn(), TimeRemainingColumn(),
                    disable=not enabled, transient=False)


def _images_note(source: _Frames) -> str:
    if source.images is None:
        return "none"
    return "rendered by MuJoCo at the logged state" + (
        "" if source.jpeg is None else f", JPEG quality {source.jpeg}")


def _metadata(source: _Frames, result: ExportResult,
              error: BaseException | None) -> dict[str, str]:
    """The file's ``cellsight`` metadata record: where it came from and how it ended."""
    run = source.run
    m = run.metrics
    data = {"run": str(run.folder), "cell": str(run.cell.source),
            "experiment": str(m.get("experiment")), "seed": str(m.get("seed")),
            "sensor": str(m.get("sensor")),
            "time": "stamps, log and publish times: start_time_ns + the run's time t (s)",
            "start_time_ns": str(source.start_ns),
            "frames": f"{result.frames}/{result.total}", "image_every": str(source.every),
            "images": _images_note(source),
            "complete": "true" if result.frames == result.total else "false"}
    if result.stopped_by:
        data["stopped_by"] = result.stopped_by
    if error is not None:
        data["error"] = f"{type(error).__name__}: {error}"[:500]
    return data


def export_mcap(run_dir: str | Path, out: str | Path, options: ExportOptions | None = None,
                images: Callable[[RunData], RunImages] | None = None) -> ExportResult:
    """Write the run in ``run_dir`` to the MCAP file ``out`` (module docstring), as
    ``options`` say; ``images`` makes the cameras' images of the run (None: none, the camera
    info stays; :class:`cellsight.world.replay_images.ReplayImages` renders a simulated run's
    again). Returns what was written; stopped by SIGINT (or :class:`Stop`), the file holds the
    frames before it and ``stopped_by`` says so."""
    options = options or ExportOptions()
    every, jpeg = options.every, options.jpeg
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise CellsightError(f"--every: expected a whole number >= 1, got {every!r}")
    check_jpeg(jpeg)
    if jpeg is not None and images is None:
        raise CellsightError("--jpeg: without images (--no-images) there is nothing to encode")
    start_ns = start_time_ns(options.start_time)
    run = load_run(run_dir, options.cell)
    if run.n and start_ns + ros.time_ns(run.t[-1]) >= END_NS:
        raise CellsightError("--start-time: the run would end after 2038-01-19T03:14:08Z, "
                             "past ROS time's int32 seconds")
    path = check_output(out, options.overwrite, run.folder)
    if images is not None and "recording" in run.metrics:
        raise CellsightError(f"{run_dir}: tracked from recording {run.metrics['recording']}, "
                             f"which holds its images; no world to render them again: pass "
                             f"--no-images")
    result = ExportResult(path, total=run.n, start_ns=start_ns)
    renderer = images(run) if images is not None else None
    source = _Frames(run, every, renderer, jpeg, start_ns)
    error: BaseException | None = None
    try:
        with _open_output(path) as file, _progress_bar(options.progress) as bar:
            bag = RosBag(file)
            result.topics = bag.topics
            task = bar.add_task("exporting", total=run.n)
            try:
                _write_all(bag, source, result, lambda: bar.advance(task))
            except (KeyboardInterrupt, Stop) as exc:
                result.stopped_by = (exc.args[0] if isinstance(exc, Stop) and exc.args
                                     else "SIGINT")
            except BaseException as exc:
                error = exc
                raise
            finally:
                if renderer is not None:
                    renderer.close()
                if not file.failed:  # a failed write leaves nothing to close: it is removed
                    bag.close(_metadata(source, result, error))
                    file.commit()
    except WriteError as exc:
        raise CellsightError(f"--mcap: cannot write {str(path)!r} ({exc.reason}); it is left as "
                             f"it was") from exc
    return result


def _open_output(path: Path) -> AtomicFile:
    """The output file opened for writing under a temporary name (its folder made), or a clear
    error naming it."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return AtomicFile(path)
    except (OSError, WriteError) as exc:
        raise CellsightError(f"--mcap: cannot write {str(path)!r} "
                             f"({getattr(exc, 'reason', None) or exc.strerror or exc})") from exc


def _write_all(bag: RosBag, source: _Frames, result: ExportResult,
               advance: Callable[[], None]) -> None:
    run = source.run
    for k in range(run.n):
        batch = (source.once() if k == 0 else []) + source.messages(k)
        ns = source.ns(k)
        for topic, kind, message in batch:
            bag.write(topic, kind, message, ns)
        result.frames = k + 1
        result.images += sum(kind in (IMAGE, COMPRESSED) for _, kind, _ in batch)
        result.t_first = float(run.t[0])
        result.t_last = float(run.t[k])
        advance()

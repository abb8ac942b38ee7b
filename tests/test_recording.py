"""``cellsight run --record`` and ``cellsight track`` (cellsight.recording): a rendered run
recorded, tracked back from the MCAP file and from a rosbag2 SQLite folder written by
``rosbags`` under other names, against the run's own estimates; each bad recording refused in
one line."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader
from recordings import T, read_mcap, tf_message, write_rosbag2
from rosbags.typesys import Stores, get_typestore

from cellsight import load_cell
from cellsight.errors import CellFileError
from cellsight.experiments import RunConfig, run_experiment
from cellsight.export import ExportOptions, export_mcap
from cellsight.geometry.transforms import pose_from_xyz_rpy, transform_points
from cellsight.recording import TopicMap
from cellsight.recording.reader import RecordingError, open_recording
from cellsight.recording.track import TrackOptions, track_recording
from cellsight.runfolder import FrameLog
from cellsight.runfolder.framelog import decode_corners, decode_windows
from cellsight.trackers import DEFAULT_TRACKER, TrackerChoice

DURATION = 3.0


def _run(folder: Path, jpeg: int | None = None,
         tracker: TrackerChoice = DEFAULT_TRACKER) -> tuple[Path, Path]:
    record = folder / "rec.mcap"
    run_experiment(RunConfig(3, folder / "run", duration=DURATION, progress=False,
                             record=record, record_jpeg=jpeg, tracker=tracker))
    return folder / "run", record


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> tuple[Path, Path]:
    return _run(tmp_path_factory.mktemp("recorded"))


def _track(recording: Path, out: Path, **options) -> FrameLog:
    track_recording(None, recording, out, TrackOptions(progress=False, **options))
    return FrameLog.read(out / "frames.csv")


def _estimates(log: FrameLog) -> np.ndarray:
    return log.poses("est")


def test_the_recording_holds_what_the_tracker_was_given(recorded):
    run, record = recorded
    log = FrameLog.read(run / "frames.csv")
    messages = read_mcap(record)
    kinds = {topic: kind for topic, kind, _, _ in messages}
    assert kinds["/cam1/image_raw"] == "sensor_msgs/msg/Image"
    assert kinds["/joint_states"] == "sensor_msgs/msg/JointState"
    states = [m for topic, _, _, m in messages if topic == "/joint_states"]
    assert len(states) == log.n
    assert "R6AX/joint1" in states[0].name and "R7AX/jaw_opening" in states[0].name
    truth = [m for topic, _, _, m in messages if topic == "/part/true_pose"]
    xyz = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z] for m in truth])
    assert np.allclose(xyz, log.poses("true")[:, :3], atol=1e-12)


def test_tracking_the_recording_gives_the_runs_estimates(recorded, tmp_path):
    run, record = recorded
    ran = FrameLog.read(run / "frames.csv")
    tracked = _track(record, tmp_path / "track")
    assert tracked.n == ran.n
    assert np.array_equal(ran.floats("t"), tracked.floats("t"))
    est_run, est_track = _estimates(ran), _estimates(tracked)
    assert np.array_equal(np.isnan(est_run), np.isnan(est_track))
    assert np.nanmax(np.abs(est_run[:, :3] - est_track[:, :3])) < 1e-9
    assert np.nanmax(np.abs(est_run[:, 3:] - est_track[:, 3:])) < 1e-9
    assert ran.text("meas_c1") == tracked.text("meas_c1")
    metrics = json.loads((tmp_path / "track" / "metrics.json").read_text())
    assert metrics["frames_tracked"] == ran.n and metrics["gaps"] == []
    # the default tracker, from the recording alone: the cameras registered at HOME, the part
    # on the cell file's support (the gripper holds nothing in these 3 s)
    assert metrics["tracker"] == "kinematic" and metrics["kinematic_prior"]
    assert metrics["registration"]["cam1"]["where"] == "home"
    assert (tmp_path / "track" / "report.html").is_file()


@pytest.mark.slow
def test_a_run_of_the_plain_tracker_tracks_back_with_it(tmp_path):
    """The plain tracker's run and its recording tracked with the plain tracker agree; the
    default tracker's track of the same recording does not."""
    plain = TrackerChoice("plain")
    run, record = _run(tmp_path, tracker=plain)
    ran = _estimates(FrameLog.read(run / "frames.csv"))
    tracked = _estimates(_track(record, tmp_path / "plain", tracker=plain))
    assert np.array_equal(np.isnan(ran), np.isnan(tracked))
    assert np.nanmax(np.abs(ran - tracked)) < 1e-9
    assert json.loads((tmp_path / "plain" / "metrics.json").read_text())["tracker"] == "plain"
    default = _estimates(_track(record, tmp_path / "default"))
    assert np.nanmax(np.abs(ran - default)) > 1e-6


@pytest.mark.slow
def test_a_jpeg_recording_tracks_within_a_tenth_of_a_millimetre(tmp_path):
    run, record = _run(tmp_path, jpeg=90)
    assert any(t == "/cam1/image_raw/compressed" for t, _, _, _ in read_mcap(record))
    track_recording(None, record, tmp_path / "track", TrackOptions(progress=False))
    a = json.loads((run / "metrics.json").read_text())["position_rmse_mm"]
    b = json.loads((tmp_path / "track" / "metrics.json").read_text())["position_rmse_mm"]
    assert abs(a - b) < 0.1


NAMES = {"/cam1/image_raw": "/left/image", "/cam2/image_raw": "/right/image",
         "/cam1/camera_info": "/left/info", "/joint_states": "/robot/joints"}


def test_a_rosbag2_sqlite_folder_under_other_names_tracks_the_same(recorded, tmp_path):
    run, record = recorded
    joints = {f"R6AX/joint{j}": f"r6ax_joint_{j}" for j in range(1, 7)}
    bag = write_rosbag2(record, tmp_path / "bag", topics=NAMES,
                        joints={**joints, "R7AX/jaw_opening": "gripper"})
    topic_map = tmp_path / "topics.yaml"
    topic_map.write_text(
        "cameras: {cam1: /left/image, cam2: /right/image}\n"
        "camera_info: {cam1: /left/info}\n"
        "joint_states: [/robot/joints]\n"
        "joints: {" + ", ".join(f"{v}: {k}" for k, v in joints.items()) + "}\n"
        "openings: {gripper: R7AX}\n")
    tracked = _track(bag, tmp_path / "track", topics=topic_map)
    ran = FrameLog.read(run / "frames.csv")
    assert tracked.n == ran.n
    assert np.nanmax(np.abs(_estimates(ran) - _estimates(tracked))) < 1e-9


def test_the_true_pose_from_a_tf_topic(recorded, tmp_path):
    def to_tf(topic, m, k):
        if topic != "/part/true_pose":
            return m
        return "tf2_msgs/msg/TFMessage", tf_message(m.header, "mocap/part", m.pose)

    bag = write_rosbag2(recorded[1], tmp_path / "bag", frames=10, edit=to_tf,
                        topics={"/part/true_pose": "/tf"})
    topic_map = tmp_path / "topics.yaml"
    topic_map.write_text("truth: {part: /tf}\ntruth_frames: {part: mocap/part}\n")
    tracked = _track(bag, tmp_path / "track", topics=topic_map)
    ran = FrameLog.read(recorded[0] / "frames.csv")
    assert tracked.n == 10
    assert np.allclose(tracked.poses("true"), ran.poses("true")[:10], atol=1e-12)


def _bag(recorded, tmp_path: Path, frames: int = 8, **kwargs) -> Path:
    return write_rosbag2(recorded[1], tmp_path / "bag", frames=frames, **kwargs)


def _refused(bag: Path, tmp_path: Path, *needles: str, **options) -> str:
    with pytest.raises(RecordingError) as err:
        track_recording(None, bag, tmp_path / "out", TrackOptions(progress=False, **options))
    text = str(err.value)
    assert "\n" not in text
    for needle in needles:
        assert needle in text
    return text


def test_a_truncated_mcap_file_is_refused(recorded, tmp_path):
    data = recorded[1].read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    _refused(cut, tmp_path, "cut.mcap", "truncated")


def test_a_missing_camera_topic_is_refused_with_what_the_recording_holds(recorded, tmp_path):
    bag = _bag(recorded, tmp_path, edit=lambda topic, m, k: None if "cam2" in topic else m)
    text = _refused(bag, tmp_path, "camera cam2", "/cam2/image_raw", "/cam1/image_raw (Image")
    assert "topic map" in text


def test_an_unknown_joint_name_is_refused(recorded, tmp_path):
    bag = _bag(recorded, tmp_path, joints={"R6AX/joint3": "elbow"})
    _refused(bag, tmp_path, "/joint_states", "'elbow'", "ignore_joints")


def test_stamps_going_backwards_are_refused(recorded, tmp_path):
    def back(topic, m, k):
        if topic == "/cam1/image_raw" and k == 5:
            m.header.stamp.sec, m.header.stamp.nanosec = 0, 1000
        return m

    _refused(_bag(recorded, tmp_path, edit=back), tmp_path, "/cam1/image_raw, message 5",
             "backwards")


def test_an_unsupported_encoding_is_refused(recorded, tmp_path):
    def yuv(topic, m, k):
        if topic == "/cam2/image_raw":
            m.encoding = "yuv422"
        return m

    _refused(_bag(recorded, tmp_path, edit=yuv), tmp_path, "/cam2/image_raw", "'yuv422'",
             "mono8")


def _wider(topic, m, k):
    if topic == "/cam1/camera_info":
        m.k = m.k.copy()
        m.k[0] += 12.0
    return m


def test_a_camera_info_against_the_cell_is_refused_or_used_when_asked(recorded, tmp_path):
    bag = _bag(recorded, tmp_path, edit=_wider)
    fx = load_cell().cameras[0].K[0, 0]
    _refused(bag, tmp_path, "/cam1/camera_info", f"fx = {fx + 12:.6g}", f"{fx:.6g}",
             "--calibration-from-bag")
    track_recording(None, bag, tmp_path / "used", TrackOptions(progress=False,
                                                                 calibration_from_bag=True))
    log = (tmp_path / "used" / "run.log").read_text()
    assert f"cam1: calibration from /cam1/camera_info (fx {fx + 12:.2f} px)" in log


def test_a_fisheye_camera_info_is_refused(recorded, tmp_path):
    def fisheye(topic, m, k):
        if topic == "/cam1/camera_info":
            m.distortion_model = "equidistant"
            m.d = np.array([0.1, 0.01, 0.0, 0.0])
        return m

    _refused(_bag(recorded, tmp_path, edit=fisheye), tmp_path, "'equidistant'", "fisheye")


def test_a_recording_without_truth_tracks_with_no_error_figures(recorded, tmp_path):
    bag = _bag(recorded, tmp_path, edit=lambda topic, m, k: None if "true_pose" in topic else m)
    log = _track(bag, tmp_path / "out")
    assert log.n == 8 and log.present("est_x").all() and not log.present("true_x").any()
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["position_rmse_mm"] is None and metrics["visibility_accuracy"] is None
    assert metrics["wrong_accepted"] is None and metrics["truth"] is None


def test_a_dropped_image_is_a_prediction_step_and_reported(recorded, tmp_path):
    def drop(topic, m, k):
        return None if topic.endswith("image_raw") and k in (6, 7) else m

    log = _track(_bag(recorded, tmp_path, frames=12, edit=drop), tmp_path / "out")
    t = log.floats("t")
    assert len(t) == 12 and np.allclose(np.diff(t), 1 / 26, atol=2.1e-3)
    assert log.text("meas_c1")[5:7] == ["0" * 16] * 2 and "1" in log.text("meas_c1")[7]
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["frames_dropped"] == 2 and len(metrics["gaps"]) == 1
    assert "gap: no images from" in (tmp_path / "out" / "run.log").read_text()


def test_a_bad_topic_map_names_the_file_and_field(tmp_path):
    path = tmp_path / "topics.yaml"
    path.write_text("cameras: {cam9: /x}\n")
    from cellsight.recording import load_topic_map

    with pytest.raises(CellFileError, match=r"topics.yaml: field 'cameras.cam9'"):
        load_topic_map(path).check(load_cell())
    path.write_text("camras: {cam1: /x}\n")
    with pytest.raises(CellFileError, match=r"field 'camras'"):
        load_topic_map(path)
    assert TopicMap().joint_states == ["/joint_states"]


@pytest.mark.slow
def test_the_command_line_tracks_and_refuses_in_one_line(recorded, tmp_path):
    cli = [sys.executable, "-m", "cellsight.cli", "track"]
    done = subprocess.run([*cli, str(recorded[1]), "--out", str(tmp_path / "ok"), "--quiet",
                           "--mcap", str(tmp_path / "ok.mcap")],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "position_rmse_mm" in done.stdout
    log = FrameLog.read(tmp_path / "ok" / "frames.csv")
    poses = [m for topic, _, _, m in read_mcap(tmp_path / "ok.mcap") if topic == "/part/est_pose"]
    assert len(poses) == int(log.present("est_x").sum()) > 0
    last = poses[-1].pose.position
    assert np.allclose([last.x, last.y, last.z], log.poses("est")[-1, :3], atol=1e-12)
    bad = subprocess.run([*cli, str(tmp_path / "none.mcap"), "--out", str(tmp_path / "no")],
                         capture_output=True, text=True, timeout=300)
    assert bad.returncode != 0
    assert bad.stderr.strip().count("\n") == 0 and "no such file" in bad.stderr


def test_the_logged_corners_are_the_measured_ones(recorded):
    run, _ = recorded
    log = FrameLog.read(run / "frames.csv")
    cell = load_cell()
    part = cell.workpieces[0]
    truth = log.poses("true")
    checked = 0
    for k in range(0, log.n, 5):
        T = pose_from_xyz_rpy(truth[k, :3], truth[k, 3:])
        for c, cam in enumerate(cell.cameras, start=1):
            corners = decode_corners(log.text(f"corners_c{c}")[k], len(part.feature_points))
            measured = np.all(np.isfinite(corners), axis=1)
            assert np.array_equal(measured, log.bits(f"meas_c{c}", 16)[k])
            if not measured.any():
                continue
            true_px = cam.project(transform_points(T, part.feature_points))
            err = np.median(np.linalg.norm(corners[measured] - true_px[measured], axis=1))
            assert abs(err - log.floats(f"err_px_c{c}")[k]) < 1e-3
            checked += 1
    assert checked > 10


def test_the_export_draws_the_windows_and_corners_on_the_images(recorded, tmp_path):
    run, _ = recorded
    path = tmp_path / "run.mcap"
    export_mcap(run, path, ExportOptions(progress=False))
    log = FrameLog.read(run / "frames.csv")
    store = get_typestore(Stores.ROS2_HUMBLE)
    with path.open("rb") as f:
        markers = [store.deserialize_cdr(m.data, "visualization_msgs/msg/ImageMarker")
                   for _, ch, m in make_reader(f).iter_messages(topics=["/cam2/annotations"],
                                                                 log_time_order=True)]
    assert len(markers) == 2 * log.n
    for k in (0, log.n // 2, log.n - 1):
        windows, corners = markers[2 * k], markers[2 * k + 1]
        _, boxes = decode_windows(log.text("windows_c2")[k])
        assert windows.ns == "windows" and len(windows.points) == 8 * len(boxes)
        if len(boxes):
            assert (windows.points[0].x, windows.points[0].y) == tuple(boxes[0, :2])
        measured = decode_corners(log.text("corners_c2")[k], 16)
        got = np.array([[p.x, p.y] for p in corners.points]).reshape(-1, 2)
        assert np.allclose(got, measured[np.all(np.isfinite(measured), axis=1)])


def test_sigterm_ends_the_tracking_at_a_frame_with_everything_written(recorded, tmp_path,
                                                                      monkeypatch):
    from cellsight.recording import track as track_module

    frame = track_module.RecordingSource._frame
    calls = []

    def signalled(self, k, recorded_frame):  # the signal comes as the 6th frame is read
        calls.append(recorded_frame.t)
        if len(calls) == 6:
            os.kill(os.getpid(), signal.SIGTERM)
        return frame(self, k, recorded_frame)

    monkeypatch.setattr(track_module.RecordingSource, "_frame", signalled)
    result = track_recording(None, recorded[1], tmp_path / "out", TrackOptions(progress=False))
    assert result.frames == 5 and result.metrics["interrupted"] is True
    assert result.metrics["signal"] == "SIGTERM"
    assert FrameLog.read(tmp_path / "out" / "frames.csv").n == 5
    assert (tmp_path / "out" / "report.html").is_file()
    assert "interrupted by SIGTERM" in (tmp_path / "out" / "run.log").read_text()


def test_the_camera_info_beside_a_mapped_image_topic_is_checked(recorded, tmp_path):
    bag = _bag(recorded, tmp_path, edit=_wider, topics={"/cam1/image_raw": "/left/image_raw",
                                                         "/cam1/camera_info": "/left/camera_info"})
    topic_map = tmp_path / "topics.yaml"
    topic_map.write_text("cameras: {cam1: /left/image_raw}\n")
    _refused(bag, tmp_path, "/left/camera_info", "--calibration-from-bag", topics=topic_map)


def test_tracking_never_writes_over_its_recording(recorded, tmp_path, capsys):
    from cellsight.cli import main

    copy = tmp_path / "rec.mcap"
    copy.write_bytes(recorded[1].read_bytes())
    before = copy.read_bytes()
    code = main(["track", str(copy), "--out", str(tmp_path / "out"), "--quiet", "--mcap",
                 str(copy), "--overwrite"])
    assert code == 2 and "is the recording being tracked" in capsys.readouterr().err
    assert copy.read_bytes() == before and not (tmp_path / "out").exists()


def test_a_misspelt_map_key_lists_the_keys(tmp_path):
    from cellsight.recording import load_topic_map

    path = tmp_path / "topics.yaml"
    path.write_text("camera: {cam1: /x}\n")
    with pytest.raises(CellFileError, match=r"field 'camera'.*one of the keys cameras, "
                                            r"camera_info, joint_states"):
        load_topic_map(path)


def _encoded(encoding: str, bits: int = 16):
    """An edit that re-encodes every raw image: as ``encoding`` (mono16: v * 257, or in the low
    ``bits`` bits v * 2^(bits - 8) + 2^(bits - 8) - 1; the colour encodings: grey in every
    channel, rows padded by 4 bytes), or ``png``: a PNG CompressedImage."""
    def edit(topic, m, k):
        if not topic.endswith("image_raw"):
            return m
        gray = np.frombuffer(bytes(m.data), np.uint8).reshape(m.height, m.width)
        if encoding == "png":
            ok, data = cv2.imencode(".png", gray)
            compressed = T["sensor_msgs/msg/CompressedImage"](header=m.header, format="png",
                                                               data=data.ravel())
            return "sensor_msgs/msg/CompressedImage", compressed
        if encoding == "mono16":
            scale = 2 ** (bits - 8)
            values = gray.astype("<u2") * 257 if bits == 16 else gray.astype("<u2") * scale \
                + (scale - 1)
            pixels = values.view(np.uint8).reshape(m.height, -1)
        else:
            channels = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4}[encoding]
            pixels = np.repeat(gray[:, :, None], channels, axis=2).reshape(m.height, -1)
        padded = np.zeros((m.height, pixels.shape[1] + 4), np.uint8)
        padded[:, :pixels.shape[1]] = pixels
        m.encoding, m.step, m.data = encoding, padded.shape[1], padded.ravel()
        return m
    return edit


@pytest.mark.parametrize("encoding", ["mono16", "rgb8", "bgra8", "png"])
def test_every_image_encoding_tracks_as_mono8(recorded, tmp_path, encoding):
    topics = ({"/cam1/image_raw": "/cam1/image_raw/compressed",
               "/cam2/image_raw": "/cam2/image_raw/compressed"} if encoding == "png" else None)
    bag = write_rosbag2(recorded[1], tmp_path / "bag", frames=12, edit=_encoded(encoding),
                        topics=topics)
    tracked = _track(bag, tmp_path / "out")
    ran = FrameLog.read(recorded[0] / "frames.csv")
    assert tracked.n == 12
    assert np.nanmax(np.abs(tracked.poses("est") - ran.poses("est")[:12])) < 1e-9


def test_12_bit_data_in_mono16_is_refused_unless_declared_then_tracks_as_mono8(recorded,
                                                                             tmp_path):
    bag = write_rosbag2(recorded[1], tmp_path / "bag", frames=12, edit=_encoded("mono16", 12))
    _refused(bag, tmp_path, "/cam1/image_raw, message 1", "fit in 12 bits (largest ",
             "bits: {CAMERA: 12}")
    topic_map = tmp_path / "topics.yaml"
    topic_map.write_text("bits: {cam1: 12, cam2: 12}\n")
    tracked = _track(bag, tmp_path / "declared", topics=topic_map)
    ran = FrameLog.read(recorded[0] / "frames.csv")
    assert tracked.n == 12
    assert np.nanmax(np.abs(tracked.poses("est") - ran.poses("est")[:12])) < 1e-9
    topic_map.write_text("bits: {cam1: 20}\n")
    with pytest.raises(CellFileError, match=r"field 'bits.cam1'.*10 to 16"):
        _track(bag, tmp_path / "out2", topics=topic_map)


def test_an_image_of_another_size_is_refused(recorded, tmp_path):
    def crop(topic, m, k):
        if topic == "/cam1/image_raw":
            m.width, m.step = m.width - 8, m.step - 8
            gray = np.frombuffer(bytes(m.data), np.uint8).reshape(m.height, -1)
            m.data = np.ascontiguousarray(gray[:, :-8]).ravel()
        return m

    _refused(_bag(recorded, tmp_path, edit=crop), tmp_path, "/cam1/image_raw, message 1",
             "760x576", "768x576")


def test_a_fifo_is_refused_without_waiting_for_a_writer(tmp_path):
    import os
    import threading

    fifo = tmp_path / "live.mcap"
    os.mkfifo(fifo)
    errors: list[Exception] = []
    thread = threading.Thread(target=lambda: errors.append(
        pytest.raises(RecordingError, open_recording, fifo).value), daemon=True)
    thread.start()
    thread.join(10)
    assert not thread.is_alive() and "not a regular file (a FIFO" in str(errors[0])


@pytest.mark.parametrize("quaternion", [(0.0, 0.0, 0.0, 0.0), (float("nan"), 0.0, 0.0, 1.0),
                                        (0.0, 0.0, 0.0, 2.0)])
def test_a_bad_quaternion_in_the_truth_topic_names_the_topic_and_message(recorded, tmp_path,
                                                                         quaternion):
    def bad(topic, m, k):
        if topic == "/part/true_pose" and k == 3:
            o = m.pose.orientation
            o.x, o.y, o.z, o.w = quaternion
        return m

    _refused(_bag(recorded, tmp_path, edit=bad), tmp_path, "/part/true_pose, message ",
             "expected finite values and a unit quaternion")


@pytest.mark.parametrize("field, change", [("k", lambda m: m.k.__setitem__(0, m.k[0] * 1.01)),
                                           ("width", lambda m: setattr(m, "width", 640))])
def test_a_camera_info_that_changes_mid_recording_is_refused(recorded, tmp_path, field,
                                                             change):
    def edit(topic, m, k):
        if topic == "/cam2/camera_info" and k >= 4:
            change(m)
        return m

    _refused(_bag(recorded, tmp_path, edit=edit), tmp_path, "/cam2/camera_info, message ",
             f"field {field!r}", "changes mid-recording")


def test_joint_states_on_another_clock_are_refused(recorded, tmp_path):
    """The joint states stamped an hour earlier than the images (another clock): refused at
    the first frame, naming the topic and both times, not tracked with the last sample held."""
    def earlier(topic, m, k):
        if topic == "/joint_states":
            m.header.stamp.sec -= 3600
        return m

    _refused(_bag(recorded, tmp_path, edit=earlier), tmp_path, "the joint states (/joint_states)",
             "another clock")


def test_without_cell_the_recordings_own_cell_is_taken_and_checked(tmp_path):
    """A recording names its cell and the cell's SHA-256: tracked without --cell, that cell
    is used; the cell file changed since, the recording is refused, saying to pass --cell."""
    import shutil

    from cellsight.model.registry import builtin_cell_path

    cell_file = tmp_path / "my_cell.yaml"
    shutil.copy(builtin_cell_path(), cell_file)
    record = tmp_path / "rec.mcap"
    run_experiment(RunConfig(1, tmp_path / "run", cell=cell_file, duration=0.3, progress=False,
                             record=record, video_every=0))
    result = track_recording(None, record, tmp_path / "track", TrackOptions(progress=False))
    assert result.metrics["cell"] == str(cell_file) and result.frames > 0
    cell_file.write_text(cell_file.read_text() + "\n# edited\n")
    _refused(record, tmp_path, "made with the cell", "my_cell.yaml", "has changed since",
             "--cell")


def test_a_bag_that_names_no_cell_says_the_built_in_cell_was_assumed(recorded, tmp_path):
    bag = _bag(recorded, tmp_path, joints={"R6AX/joint3": "elbow"})
    _refused(bag, tmp_path, "'elbow'", "no --cell given, and the recording names none: the "
             "built-in cell was assumed; pass --cell")

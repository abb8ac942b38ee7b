"""``cellsight export`` read as ROS 2 clients read it (issue: what real ROS 2 users found): the
UR cell's export (URDF robots) and the built-in cell's, read back with the plain ``mcap``
reader, ``mcap_ros2``'s decoder and ``rosbags`` (its ROS 2 Humble typestore and its rosbag2
MCAP reader), checked against truths found here: the URDF read by ``yourdfpy`` and ``lxml``
and its forward kinematics, frames.csv read with the csv module."""

from __future__ import annotations

import argparse
import csv
import io
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
import yourdfpy
from lxml import etree
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from scipy.spatial.transform import Rotation

from cellsight import load_cell
from cellsight.commands.export import register
from cellsight.errors import CellsightError
from cellsight.experiments import RunConfig, run_experiment
from cellsight.export import ExportOptions, export_mcap
from cellsight.export.mcap_run import robot_descriptions
from cellsight.export.rosbag import start_time_ns
from cellsight.model.registry import builtin_cell_path
from cellsight.world.replay_images import ReplayImages

UR_CELL = builtin_cell_path("ur-cell")
LATCHED = {"/tf_static", "/UR5A/robot_description", "/UR5B/robot_description"}


@pytest.fixture(scope="module")
def ur_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("export_clients") / "ur"
    run_experiment(RunConfig(3, out, cell=UR_CELL, sensor="ideal", duration=0.5,
                             progress=False))
    return out


@pytest.fixture(scope="module")
def ur_rows(ur_run: Path) -> list[dict[str, str]]:
    with (ur_run / "frames.csv").open(newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def ur_export(ur_run: Path) -> Path:
    path = ur_run.parent / "ur.mcap"
    export_mcap(ur_run, path, ExportOptions(progress=False))
    return path


def decoded(path: Path) -> dict[str, list]:
    """topic -> [(log time, message decoded by mcap_ros2)], in log-time order."""
    out = defaultdict(list)
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, msg in reader.iter_decoded_messages(log_time_order=True):
            out[channel.topic].append((message.log_time, msg))
    return out


def _matrix(transform) -> np.ndarray:
    r, p = transform.rotation, transform.translation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
    T[:3, 3] = [p.x, p.y, p.z]
    return T


def _edges(messages, k: int) -> list[tuple[str, str, np.ndarray]]:
    """(parent, child, T) of every transform of /tf_static and of frame k's /tf."""
    return [(ts.header.frame_id, ts.child_frame_id, _matrix(ts.transform))
            for _, msg in messages["/tf_static"] + [messages["/tf"][k]]
            for ts in msg.transforms]


def _in_world(tree: dict, frame: str) -> np.ndarray:
    T = np.eye(4)
    while frame != "world":
        parent, T_parent = tree[frame]
        T, frame = T_parent @ T, parent
    return T


def _urdf_path(cell) -> Path:
    (path,) = {Path(f) for f in cell.files if f.endswith(".urdf")}
    return path


def test_ur_cell_tf_tree_is_the_urdfs_links_under_one_world_root(ur_export, ur_rows) -> None:
    """REP 103/105: one root ``world``; every frame has one parent; each UR5's frames are the
    URDF's links (lxml reads their names), fixed links (base_link, tool0) included, placed as
    yourdfpy's forward kinematics of the URDF places them at the logged joints."""
    cell = load_cell(UR_CELL)
    urdf_path = _urdf_path(cell)
    links = etree.parse(str(urdf_path)).getroot().xpath("/robot/link/@name")
    assert {"base_link", "tool0", "wrist_3_link"} <= set(links)
    urdf = yourdfpy.URDF.load(str(urdf_path), load_meshes=False,
                              build_collision_scene_graph=False, load_collision_meshes=False)
    messages = decoded(ur_export)
    for k in (0, len(ur_rows) - 1):
        edges = _edges(messages, k)
        children = [child for _, child, _ in edges]
        assert len(children) == len(set(children)), "a frame with two parents"
        assert {parent for parent, _, _ in edges} - set(children) == {"world"}
        tree = {child: (parent, T) for parent, child, T in edges}
        for robot in cell.robots:
            q = [float(ur_rows[k][f"q_{robot.name}_{j}"]) for j in range(1, 7)]
            urdf.update_cfg(dict(zip(urdf.actuated_joint_names, q, strict=True)))
            for link in links:
                T_root_link = urdf.get_transform(link, urdf.base_link)
                assert np.allclose(_in_world(tree, f"{robot.name}/{link}"),
                                   robot.T_base_robot @ T_root_link, atol=1e-9), link
            assert tree[f"{robot.name}/tool"][0] == f"{robot.name}/tool0"
            assert np.allclose(_in_world(tree, f"{robot.name}/tcp"), robot.tcp_pose(q),
                               atol=1e-9)
        for cam in cell.cameras:
            assert tree[f"{cam.name}_optical_frame"][0] == "world"
            assert np.allclose(_in_world(tree, f"{cam.name}_optical_frame"), cam.T_base_cam)


def test_tf_static_is_latched_in_rosbag2s_qos_metadata(ur_export) -> None:
    """The ``offered_qos_profiles`` channel metadata, read back by the mcap reader and parsed
    by rosbags (as rosbag2 reads it), offers ``transient_local`` on /tf_static and the robot
    descriptions only; rosbags' rosbag2 reader of the file finds the same."""
    from rosbags.interfaces import QosDurability, QosReliability
    from rosbags.rosbag2 import Reader
    from rosbags.rosbag2.metadata import parse_qos

    with ur_export.open("rb") as f:
        reader = make_reader(f)
        channels = {c.topic: c for c in reader.get_summary().channels.values()}
        distro = {m.name: m.metadata for m in reader.iter_metadata()}["rosbag2"]
    assert distro == {"ROS_DISTRO": "humble"}
    for topic, channel in channels.items():
        (qos,) = parse_qos(channel.metadata["offered_qos_profiles"])
        assert qos.reliability == QosReliability.RELIABLE
        assert qos.durability == (QosDurability.TRANSIENT_LOCAL if topic in LATCHED
                                  else QosDurability.VOLATILE), topic
    assert LATCHED <= set(channels)
    with Reader(ur_export) as bag:
        (tf_static,) = [c for c in bag.connections if c.topic == "/tf_static"]
        (qos,) = tf_static.ext.offered_qos_profiles
        assert qos.durability == QosDurability.TRANSIENT_LOCAL and qos.depth == 1


def _raw(path: Path, topic: str) -> list[tuple[str, int, bytes]]:
    """(schema name, log time, CDR bytes) of every message of ``topic``, in log-time order."""
    with path.open("rb") as f:
        return [(schema.name, message.log_time, message.data) for schema, channel, message
                in make_reader(f).iter_messages(topics=[topic], log_time_order=True)]


def test_joint_states_are_frames_csvs_joints_by_urdf_joint_name(ur_export, ur_rows) -> None:
    """/joint_states decoded by rosbags' ROS 2 Humble typestore: one per frame, stamped at the
    frame, named ``<robot>/<URDF joint>`` (yourdfpy's actuated joints, in the URDF's order),
    the positions frames.csv's ``q_<robot>_<j>``, the gripper's ``jaw_opening`` with them."""
    from rosbags.typesys import Stores, get_typestore

    humble = get_typestore(Stores.ROS2_HUMBLE)
    cell = load_cell(UR_CELL)
    urdf = yourdfpy.URDF.load(str(_urdf_path(cell)), load_meshes=False,
                              build_collision_scene_graph=False, load_collision_meshes=False)
    joints = list(urdf.actuated_joint_names)
    states = _raw(ur_export, "/joint_states")
    assert len(states) == len(ur_rows)
    for (schema, log_time, data), row in zip(states, ur_rows, strict=True):
        msg = humble.deserialize_cdr(data, schema)
        assert log_time == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        assert log_time == round(float(row["t"]) * 1e9)
        expected = {f"{r.name}/{joint}": float(row[f"q_{r.name}_{j}"])
                    for r in cell.robots for j, joint in enumerate(joints, start=1)}
        if row["jaw_opening"]:
            expected["UR5A/jaw_opening"] = float(row["jaw_opening"])
        assert dict(zip(msg.name, msg.position.tolist(), strict=True)) == expected
        assert len(msg.velocity) == len(msg.effort) == 0
    assert any(row["jaw_opening"] for row in ur_rows)


def test_robot_descriptions_are_the_urdf_files_text(ur_export) -> None:
    """One latched std_msgs/String per UR5 (two URDF robots: a topic each), decoded by rosbags'
    Humble typestore: the URDF file's text, which yourdfpy reads back with the file's links."""
    from rosbags.typesys import Stores, get_typestore

    humble = get_typestore(Stores.ROS2_HUMBLE)
    path = _urdf_path(load_cell(UR_CELL))
    links = set(etree.parse(str(path)).getroot().xpath("/robot/link/@name"))
    for robot in ("UR5A", "UR5B"):
        ((schema, log_time, data),) = _raw(ur_export, f"/{robot}/robot_description")
        assert schema == "std_msgs/msg/String"
        text = humble.deserialize_cdr(data, schema).data
        assert text == path.read_text()
        read = yourdfpy.URDF.load(io.BytesIO(text.encode()), load_meshes=False,
                                  build_collision_scene_graph=False,
                                  load_collision_meshes=False)
        assert set(read.link_map) == links
    assert "/robot_description" not in decoded(ur_export)


def test_a_single_urdf_robot_is_described_on_robot_description(tmp_path) -> None:
    """The UR cell with UR5A alone: its URDF on /robot_description."""
    raw = yaml.safe_load(UR_CELL.read_text())
    raw["robots"] = raw["robots"][:1]
    raw["experiments"].pop("crossing")
    (tmp_path / "one_ur5.yaml").write_text(yaml.safe_dump(raw))
    cell = load_cell(tmp_path / "one_ur5.yaml")
    ((topic, text),) = robot_descriptions(cell)
    assert (topic, text) == ("/robot_description", _urdf_path(cell).read_text())
    assert robot_descriptions(load_cell("dual-arm")) == []


def test_estimate_is_a_pose_with_unknown_covariance(ur_export, ur_rows) -> None:
    """/part/est_pose_with_covariance decoded by rosbags' Humble typestore:
    PoseWithCovarianceStamped in ``world``, the pose frames.csv's ``est_*`` (roll-pitch-yaw:
    scipy's extrinsic xyz), the covariance marked unknown (element 0 at -1, the rest 0), in
    the frames with an estimate."""
    from rosbags.typesys import Stores, get_typestore

    humble = get_typestore(Stores.ROS2_HUMBLE)
    estimates = _raw(ur_export, "/part/est_pose_with_covariance")
    with_estimate = [row for row in ur_rows if row["est_x"]]
    assert len(estimates) == len(with_estimate) > 0
    for (schema, log_time, data), row in zip(estimates, with_estimate, strict=True):
        assert schema == "geometry_msgs/msg/PoseWithCovarianceStamped"
        msg = humble.deserialize_cdr(data, schema)
        assert msg.header.frame_id == "world" and log_time == round(float(row["t"]) * 1e9)
        p, r = msg.pose.pose.position, msg.pose.pose.orientation
        xyz = [float(row[f"est_{a}"]) for a in "xyz"]
        rpy = [float(row[f"est_{a}"]) for a in ("roll", "pitch", "yaw")]
        assert np.allclose([p.x, p.y, p.z], xyz, atol=1e-12)
        turn = Rotation.from_quat([r.x, r.y, r.z, r.w]) * Rotation.from_euler("xyz", rpy).inv()
        assert turn.magnitude() < 1e-9
        assert msg.pose.covariance[0] == -1.0 and not np.any(msg.pose.covariance[1:])


START = "2024-05-01T12:00:00.250Z"
START_NS = 1714564800_250_000_000  # date -u -d 2024-05-01T12:00:00.25Z +%s%N


def _export_cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="cellsight")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["export", *argv])
    return args.func(args)


def _stamp_ns(msg) -> int | None:
    """The header stamp (ns) of a message, or of a TFMessage's transforms (all equal)."""
    if hasattr(msg, "transforms"):
        (ns,) = {ts.header.stamp.sec * 10**9 + ts.header.stamp.nanosec for ts in msg.transforms}
        return ns
    header = getattr(msg, "header", None)
    return None if header is None else header.stamp.sec * 10**9 + header.stamp.nanosec


def test_start_time_shifts_every_stamp_and_log_time(ur_run, ur_rows, tmp_path, capsys) -> None:
    """``--start-time``: rosbags' rosbag2 reader finds every message's log time and header
    stamp at the start time plus the frame's t (frames.csv), none at 0."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    humble = get_typestore(Stores.ROS2_HUMBLE)
    path = tmp_path / "started.mcap"
    assert _export_cli([str(ur_run), "--mcap", str(path), "--no-images", "--quiet",
                        "--start-time", START]) == 0
    assert "2024-05-01T12:00:00+00:00" in capsys.readouterr().out
    frame_ns = {START_NS + round(float(row["t"]) * 1e9) for row in ur_rows}
    seen = defaultdict(int)
    with Reader(path) as bag:
        assert bag.start_time == START_NS + round(float(ur_rows[0]["t"]) * 1e9)
        for connection, log_time, data in bag.messages():
            msg = humble.deserialize_cdr(data, connection.msgtype)
            assert log_time in frame_ns, connection.topic
            assert _stamp_ns(msg) in (log_time, None), connection.topic
            seen[connection.topic] += 1
    assert seen["/tf"] == seen["/joint_states"] == len(ur_rows)
    assert seen["/tf_static"] == 1


def test_start_time_forms_and_bad_ones() -> None:
    assert start_time_ns(START) == start_time_ns(str(START_NS)) == START_NS
    assert start_time_ns("2024-05-01T14:00:00.25+02:00") == START_NS
    assert start_time_ns("2024-05-01 12:00:00.25") == START_NS  # no offset: UTC
    assert start_time_ns(0) == start_time_ns("0") == 0
    for bad in ("yesterday", "-5", "2040-01-01T00:00:00Z", "", 2**31 * 10**9, True):
        with pytest.raises(CellsightError, match="--start-time: expected an ISO 8601 time"):
            start_time_ns(bad)


def test_a_run_ending_past_2038_is_refused(ur_run, tmp_path) -> None:
    with pytest.raises(CellsightError, match="would end after 2038-01-19"):
        export_mcap(ur_run, tmp_path / "late.mcap",
                    ExportOptions(progress=False, start_time="2038-01-19T03:14:07.9Z"))
    assert not (tmp_path / "late.mcap").exists()


def test_jpeg_images_decode_close_to_the_render(ur_run, ur_rows, tmp_path) -> None:
    """``--jpeg 90``: /<cam>/image_raw/compressed (no image_raw), CompressedImage of format
    jpeg decoded by rosbags' Humble typestore; cv2.imdecode gives the world's render at the
    logged state (ReplayWorld, the part at its true pose) within JPEG's error (quality 90:
    0.08-0.16 grey levels on average, at most 18, measured)."""
    from rosbags.typesys import Stores, get_typestore

    from cellsight.geometry.transforms import pose_from_xyz_rpy
    from cellsight.world import ReplayWorld

    humble = get_typestore(Stores.ROS2_HUMBLE)
    path = tmp_path / "jpeg.mcap"
    assert _export_cli([str(ur_run), "--mcap", str(path), "--jpeg", "90", "--every", "7",
                        "--quiet"]) == 0
    topics = set(decoded(path))
    cell = load_cell(UR_CELL)
    assert not any(t.endswith("/image_raw") for t in topics)
    row = ur_rows[7]  # the second image
    world = ReplayWorld(cell)
    try:
        world.show_state({r.name: np.array([float(row[f"q_{r.name}_{j}"]) for j in range(1, 7)])
                          for r in cell.robots},
                         {"part": pose_from_xyz_rpy(
                             [float(row[f"true_{a}"]) for a in "xyz"],
                             [float(row[f"true_{a}"]) for a in ("roll", "pitch", "yaw")])},
                         {"UR5A": float(row["jaw_opening"])})
        rendered = world.render()
    finally:
        world.close()
    for c, cam in enumerate(cell.cameras):
        images = _raw(path, f"/{cam.name}/image_raw/compressed")
        assert len(images) == len(range(0, len(ur_rows), 7))
        schema, log_time, data = images[1]
        msg = humble.deserialize_cdr(data, schema)
        assert (schema, msg.format) == ("sensor_msgs/msg/CompressedImage", "jpeg")
        assert msg.header.frame_id == f"{cam.name}_optical_frame"
        image = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_UNCHANGED)
        assert image.shape == (cam.height, cam.width) and image.dtype == np.uint8
        error = np.abs(image.astype(int) - rendered[c].astype(int))
        assert rendered[c].std() > 5 and error.mean() < 0.5 and error.max() < 32, (
            cam.name, error.mean(), error.max())


def test_jpeg_quality_is_checked(ur_run, tmp_path) -> None:
    for bad in (0, 101, True, 9.5):
        with pytest.raises(CellsightError, match="--jpeg: expected a JPEG quality 1 to 100"):
            export_mcap(ur_run, tmp_path / "x.mcap", ExportOptions(jpeg=bad, progress=False),
                        ReplayImages)
    with pytest.raises(CellsightError, match="--jpeg: without images"):
        export_mcap(ur_run, tmp_path / "x.mcap", ExportOptions(jpeg=90, progress=False))
    assert not (tmp_path / "x.mcap").exists()


def test_cellsight_track_reads_an_export(ur_run, ur_rows, tmp_path) -> None:
    """An export with images (JPEG, a start time) is a recording ``cellsight track`` reads:
    the tracked frames.csv has the run's times, joints, jaw openings and true poses (read
    from /joint_states and /part/true_pose) and tracks the part from the rendered images."""
    from cellsight.recording.track import TrackOptions, track_recording
    from cellsight.trackers import TrackerChoice

    path = tmp_path / "as_recording.mcap"
    export_mcap(ur_run, path, ExportOptions(jpeg=95, start_time=START, progress=False),
                ReplayImages)
    track_recording(UR_CELL, path, tmp_path / "tracked",  # the plain tracker: reading is tested
                    TrackOptions(progress=False, tracker=TrackerChoice("plain")))
    with (tmp_path / "tracked" / "frames.csv").open(newline="") as f:
        tracked = list(csv.DictReader(f))
    columns = ["jaw_opening"] + [c for c in ur_rows[0] if c.startswith(("q_", "true_"))]
    origin = (START_NS % 10**9) / 1e9  # track's t counts from the first stamp's whole second
    assert len(tracked) == len(ur_rows)
    for mine, theirs in zip(tracked, ur_rows, strict=True):
        assert float(mine["t"]) == pytest.approx(float(theirs["t"]) + origin, abs=1e-9)
        assert {c: float(mine[c]) for c in columns} == pytest.approx(
            {c: float(theirs[c]) for c in columns}, abs=1e-9)
    last = tracked[-1]
    error = np.linalg.norm([float(last[f"est_{a}"]) - float(last[f"true_{a}"]) for a in "xyz"])
    assert last["status"] == "tracking" and error < 0.001  # 0.17 mm measured

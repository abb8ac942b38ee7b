"""``cellsight export RUN_DIR --mcap FILE`` (cellsight.export): a short run exported and read
back by independent readers (``mcap_ros2``'s decoder, the plain ``mcap`` reader and, when it
is installed, ``rosbags`` with the official ROS 2 message definitions), checked against truths
computed here: frames.csv read with the csv module, the cell's forward kinematics, MuJoCo's
TCP, ``Camera.project``, ``ReplayWorld.render``."""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import shutil
import signal
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from scipy.spatial.transform import Rotation

from cellsight import load_cell
from cellsight.camera import Camera
from cellsight.commands.export import register
from cellsight.errors import CellsightError
from cellsight.experiments import RunConfig, run_experiment
from cellsight.export import ExportOptions, export_mcap
from cellsight.export.ros import camera_info
from cellsight.geometry.transforms import invert_pose, look_at, pose_from_xyz_rpy
from cellsight.world import ReplayWorld
from cellsight.world.replay_images import ReplayImages

EVERY = 3
GREEN, RED = (0.1, 0.85, 0.2), (0.95, 0.15, 0.1)


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("export") / "run"
    run_experiment(RunConfig(3, out, sensor="ideal", duration=1.0, progress=False))
    return out


@pytest.fixture(scope="module")
def rows(run_dir: Path) -> list[dict[str, str]]:
    with (run_dir / "frames.csv").open(newline="") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module")
def cell(run_dir: Path):
    return load_cell(json.loads((run_dir / "metrics.json").read_text())["cell"])


@pytest.fixture(scope="module")
def exported(run_dir: Path) -> Path:
    path = run_dir.parent / "run.mcap"
    result = export_mcap(run_dir, path, ExportOptions(every=EVERY, progress=False), ReplayImages)
    assert result.stopped_by is None and result.frames == result.total
    return path


def read_messages(path: Path) -> dict[str, list]:
    """topic -> [(log_time, publish_time, decoded message)] in log-time order, decoded by
    mcap-ros2-support from the schemas in the file."""
    out = defaultdict(list)
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=True):
            out[channel.topic].append((message.log_time, message.publish_time, decoded))
    return out


@pytest.fixture(scope="module")
def messages(exported: Path) -> dict[str, list]:
    return read_messages(exported)


def _ns(t: str) -> int:
    return int(round(float(t) * 1e9))


def _pose(row: dict[str, str], prefix: str) -> np.ndarray:
    values = [float(row[f"{prefix}_{a}"]) for a in ("x", "y", "z", "roll", "pitch", "yaw")]
    return pose_from_xyz_rpy(values[:3], values[3:])


def _joints(row: dict[str, str], cell) -> dict[str, np.ndarray]:
    return {r.name: np.array([float(row[f"q_{r.name}_{j}"]) for j in range(1, r.n_joints + 1)])
            for r in cell.robots}


def _matrix(translation, rotation) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([rotation.x, rotation.y, rotation.z, rotation.w]).as_matrix()
    T[:3, 3] = [translation.x, translation.y, translation.z]
    return T


def _tf_tree(messages, k: int) -> dict[str, tuple[str, np.ndarray]]:
    """child -> (parent, T_parent_child) from /tf_static and frame k's /tf."""
    tree = {}
    for _, _, msg in messages["/tf_static"] + [messages["/tf"][k]]:
        for ts in msg.transforms:
            tree[ts.child_frame_id] = (ts.header.frame_id,
                                       _matrix(ts.transform.translation, ts.transform.rotation))
    return tree


def _in_world(tree, frame: str) -> np.ndarray:
    T = np.eye(4)
    while frame != "world":
        parent, T_parent = tree[frame]
        T, frame = T_parent @ T, parent
    return T


def _export_cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="cellsight")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["export", *argv])
    return args.func(args)


def test_diagnostics_carry_the_trackers_status_and_health(messages, rows, cell) -> None:
    diagnostics = messages["/diagnostics"]
    assert len(diagnostics) == len(rows)
    levels = {"tracking": 0, "acquired": 0, "degraded": 1, "coasting": 1, "lost": 2,
              "waiting": 3}
    for (log, _, msg), row in zip(diagnostics, rows, strict=True):
        (status,) = msg.status
        assert log == _ns(row["t"]) and status.name == "cellsight/part"
        assert status.message == row["status"]
        assert status.level == levels[row["status"].split(":")[0]]
        values = {v.key: v.value for v in status.values}
        for c, cam in enumerate(cell.cameras, start=1):
            assert values[f"nis_{cam.name}"] == row[f"nis_c{c}"]
            assert values[f"notfound_{cam.name}"] == row[f"notfound_c{c}"]
    assert {r["status"] for r in rows} >= {"tracking"}


def test_message_counts_and_stamps(messages, rows, cell) -> None:
    n = len(rows)
    images = math.ceil(n / EVERY)
    assert len(messages["/tf_static"]) == 1
    for topic in ["/tf", "/joint_states", "/part/true_pose"] + [f"/{c.name}/visibility"
                                                                for c in cell.cameras]:
        assert len(messages[topic]) == n, topic
    assert len(messages["/part/est_pose"]) == sum(bool(r["est_x"]) for r in rows)
    assert len(messages["/part/est_pose_with_covariance"]) == len(messages["/part/est_pose"])
    assert not any(t.endswith("robot_description") for t in messages)  # DH robots: no URDF
    for c in cell.cameras:
        assert len(messages[f"/{c.name}/image_raw"]) == images
        assert len(messages[f"/{c.name}/camera_info"]) == images
    for topic in ("/tf", "/part/true_pose"):
        for (log, publish, msg), row in zip(messages[topic], rows, strict=True):
            stamp = (msg.transforms[0] if topic == "/tf" else msg).header.stamp
            assert log == publish == stamp.sec * 10**9 + stamp.nanosec == _ns(row["t"])
    image_times = [log for log, _, _ in messages[f"/{cell.cameras[0].name}/image_raw"]]
    assert image_times == [_ns(rows[k]["t"]) for k in range(0, n, EVERY)]


def test_file_is_a_ros2_mcap_with_well_formed_schemas(exported: Path) -> None:
    with exported.open("rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
    names = {s.name for s in summary.schemas.values()}
    assert names == {"tf2_msgs/msg/TFMessage", "geometry_msgs/msg/PoseStamped",
                     "geometry_msgs/msg/PoseWithCovarianceStamped",
                     "visualization_msgs/msg/MarkerArray", "sensor_msgs/msg/CameraInfo",
                     "sensor_msgs/msg/Image", "diagnostic_msgs/msg/DiagnosticArray",
                     "sensor_msgs/msg/JointState", "visualization_msgs/msg/ImageMarker"}
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    for schema in summary.schemas.values():  # every type used is defined once in the text
        text = schema.data.decode()
        defined = {line.split()[1] for line in text.splitlines() if line.startswith("MSG: ")}
        assert len(defined) == text.count("\nMSG: ")
        for line in text.splitlines():
            kind = line.split()[0].split("[")[0] if line.strip() else ""
            if "/" in kind:
                assert kind in defined, (schema.name, kind)


def test_messages_decode_with_the_official_ros2_definitions(exported: Path) -> None:
    """rosbags' own Humble and Jazzy definitions read every channel's CDR, and the type hashes
    (RIHS01) of the file's schemas equal the official ones."""
    typesys = pytest.importorskip("rosbags.typesys")
    with exported.open("rb") as f:
        reader = make_reader(f)
        first = {}
        for schema, channel, message in reader.iter_messages():
            first.setdefault(channel.topic, (schema, message))
    for store in (typesys.Stores.ROS2_HUMBLE, typesys.Stores.ROS2_JAZZY):
        official = typesys.get_typestore(store)
        for schema, message in first.values():
            official.deserialize_cdr(message.data, schema.name)
            mine = typesys.get_typestore(typesys.Stores.EMPTY)
            mine.register(typesys.get_types_from_msg(schema.data.decode(), schema.name))
            assert mine.hash_rihs01(schema.name) == official.hash_rihs01(schema.name)


def test_tf_chain_is_the_forward_kinematics_and_the_worlds_tcp(messages, rows, cell) -> None:
    world = ReplayWorld(cell)
    try:
        for k in (0, len(rows) // 2, len(rows) - 1):
            tree, joints = _tf_tree(messages, k), _joints(rows[k], cell)
            world.show_state(joints, {})
            for robot in cell.robots:
                links = robot.link_poses(joints[robot.name])
                names = getattr(robot.chain, "link_names", None) or [
                    f"link{i}" for i in range(robot.n_joints + 1)]
                for i, name in enumerate(names):
                    assert np.allclose(_in_world(tree, f"{robot.name}/{name}"), links[i],
                                       atol=1e-9)
                tcp = _in_world(tree, f"{robot.name}/tcp")
                assert np.allclose(tcp, robot.tcp_pose(joints[robot.name]), atol=1e-9)
                assert np.allclose(tcp, world.grippers.tcp_pose(robot.name), atol=1e-6)
            gripper = [float(rows[k][f"gripper_{a}"]) for a in "xyz"]
            assert np.allclose(_in_world(tree, "R7AX/tcp")[:3, 3], gripper, atol=1e-9)
    finally:
        world.close()


def test_tf_tree_of_urdf_robots_is_their_forward_kinematics() -> None:
    """The UR cell's robots (URDF chains, frames named after their links)."""
    from cellsight.export.frames import robot_transforms, static_transforms

    cell = load_cell("ur-cell")
    rng = np.random.default_rng(3)
    joints = {r.name: r.chain.random_q(rng) for r in cell.robots}
    tree = {child: (parent, T) for parent, child, T in static_transforms(cell, "part")}
    for robot in cell.robots:
        tree.update({child: (parent, T)
                     for parent, child, T in robot_transforms(robot, joints[robot.name])})
    for robot in cell.robots:
        links = robot.link_poses(joints[robot.name])
        for i, name in enumerate(robot.chain.link_names):
            assert np.allclose(_in_world(tree, f"{robot.name}/{name}"), links[i], atol=1e-9)
        assert np.allclose(_in_world(tree, f"{robot.name}/tcp"),
                           robot.tcp_pose(joints[robot.name]), atol=1e-9)
    for cam in cell.cameras:
        assert np.allclose(_in_world(tree, f"{cam.name}_optical_frame"), cam.T_base_cam)
    for obj in cell.static:
        assert np.allclose(_in_world(tree, obj.name), obj.T_base_obj)


def test_part_poses_are_the_logged_ones(messages, rows) -> None:
    est_rows = [r for r in rows if r["est_x"]]
    for (_, _, msg), row in zip(messages["/part/true_pose"], rows, strict=True):
        assert msg.header.frame_id == "world"
        assert np.allclose(_matrix(msg.pose.position, msg.pose.orientation), _pose(row, "true"),
                           atol=1e-12)
    for (_, _, msg), row in zip(messages["/part/est_pose"], est_rows, strict=True):
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == _ns(row["t"])
        assert np.allclose(_matrix(msg.pose.position, msg.pose.orientation), _pose(row, "est"),
                           atol=1e-12)
    k = max(i for i, row in enumerate(rows) if row["est_x"])
    tree = _tf_tree(messages, k)
    assert np.allclose(_in_world(tree, "part_true"), _pose(rows[k], "true"), atol=1e-12)
    assert np.allclose(_in_world(tree, "part_est"), _pose(rows[k], "est"), atol=1e-12)


def test_camera_info_and_tf_project_features_where_the_camera_does(messages, rows,
                                                                   cell) -> None:
    part = cell.workpiece("part")
    tree = _tf_tree(messages, 0)
    for cam in cell.cameras:
        (_, _, info), = messages[f"/{cam.name}/camera_info"][:1]
        K, D = np.array(info.k).reshape(3, 3), np.array(info.d)
        assert info.header.frame_id == f"{cam.name}_optical_frame"
        assert (info.width, info.height, info.distortion_model) == (cam.width, cam.height,
                                                                     "plumb_bob")
        assert np.array_equal(K, cam.K) and np.array_equal(D, cam.dist5)
        assert np.array_equal(np.array(info.r), np.eye(3).ravel())
        assert np.array_equal(np.array(info.p).reshape(3, 4)[:, :3], cam.K)
        T_cam_base = invert_pose(_in_world(tree, f"{cam.name}_optical_frame"))
        for k in (0, len(rows) - 1):
            points = (_pose(rows[k], "true") @ np.c_[part.feature_points,
                                                     np.ones(len(part.feature_points))].T)
            rvec, _ = cv2.Rodrigues(T_cam_base[:3, :3])
            pixels, _ = cv2.projectPoints(points[:3].T, rvec, T_cam_base[:3, 3], K, D)
            assert np.allclose(pixels.reshape(-1, 2), cam.project(points[:3].T), atol=1e-6)


def test_camera_info_of_a_distorted_camera_projects_like_it() -> None:
    T = look_at([1.0, 0.5, 1.0], [0.0, 0.0, 0.0])
    cam = Camera.from_intrinsics(640, 480, T, (600.0, 590.0), principal=(330.0, 236.0),
                                 dist=np.array([-0.2, 0.05, 0.001, -0.002, 0.01]), name="d")
    info = camera_info(0, "d_optical_frame", cam)
    assert info["distortion_model"] == "plumb_bob"
    points = np.random.default_rng(1).uniform(-0.2, 0.2, (20, 3))
    rvec, _ = cv2.Rodrigues(cam.T_cam_base[:3, :3])
    pixels, _ = cv2.projectPoints(points, rvec, cam.T_cam_base[:3, 3],
                                  np.array(info["k"]).reshape(3, 3), np.array(info["d"]))
    assert np.allclose(pixels.reshape(-1, 2), cam.project(points), atol=1e-6)


def test_images_are_the_world_rendered_at_the_logged_state(messages, rows, cell) -> None:
    k = EVERY  # the second image
    row = rows[k]
    world = ReplayWorld(cell)
    try:
        world.show_state(_joints(row, cell), {"part": _pose(row, "true")},
                         {"R7AX": float(row["jaw_opening"])})
        expected = world.render()
    finally:
        world.close()
    for c, cam in enumerate(cell.cameras):
        _, _, msg = messages[f"/{cam.name}/image_raw"][1]
        assert (msg.encoding, msg.width, msg.height, msg.step) == ("mono8", cam.width,
                                                                   cam.height, cam.width)
        assert msg.header.frame_id == f"{cam.name}_optical_frame"
        image = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)
        assert image.std() > 5  # a picture, not a blank
        assert np.array_equal(image, expected[c])


def _colour(c) -> tuple[float, float, float]:
    return (round(c.r, 3), round(c.g, 3), round(c.b, 3))


def test_visibility_markers_sit_on_the_features_coloured_by_the_bits(messages, rows,
                                                                      cell) -> None:
    part = cell.workpiece("part")
    for c, cam in enumerate(cell.cameras, start=1):
        for (_, _, msg), row in zip(messages[f"/{cam.name}/visibility"], rows, strict=True):
            spheres, ring, *names = msg.markers
            assert (spheres.ns, spheres.type, ring.ns, ring.type) == ("predicted", 7, "truth", 5)
            T = _pose(row, "true")
            expected = part.feature_points @ T[:3, :3].T + T[:3, 3]
            points = np.array([[p.x, p.y, p.z] for p in spheres.points])
            assert spheres.header.frame_id == "world" and np.allclose(points, expected)
            predicted = [_colour(col) for col in spheres.colors]
            assert predicted == [GREEN if b == "1" else RED for b in row[f"vis_pred_c{c}"]]
            per_ring = len(ring.colors) // len(expected)
            truth = [_colour(col) for col in ring.colors[::per_ring]]
            assert truth == [GREEN if b == "1" else RED for b in row[f"vis_true_c{c}"]]
            assert [m.text for m in names] == list(part.feature_names)


def test_cli_without_images_and_every_n(run_dir: Path, rows, tmp_path: Path, capsys) -> None:
    path = tmp_path / "sub" / "no_images.mcap"
    assert _export_cli([str(run_dir), "--mcap", str(path), "--no-images", "--every", "2",
                        "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "/cam1/camera_info" in out and f"{path} (" in out
    assert f"{len(rows)} of {len(rows)} frames" in out
    counts = {topic: len(m) for topic, m in read_messages(path).items()}
    assert not any(t.endswith("image_raw") for t in counts)
    assert counts["/cam1/camera_info"] == math.ceil(len(rows) / 2)
    assert counts["/tf"] == len(rows)


def _stopping_render(monkeypatch, after: int, action) -> None:
    """``ReplayImages.render`` that calls ``action`` on its call number ``after`` + 1."""
    calls = {"n": 0}
    original = ReplayImages.render

    def render(self, k):
        calls["n"] += 1
        if calls["n"] > after:
            action()
        return original(self, k)

    monkeypatch.setattr(ReplayImages, "render", render)


def _read_back(path: Path) -> tuple[dict[str, int], dict[str, str]]:
    counts = defaultdict(int, {topic: len(m) for topic, m in read_messages(path).items()})
    with path.open("rb") as f:
        (metadata,) = [m.metadata for m in make_reader(f).iter_metadata()
                       if m.name == "cellsight"]
    return counts, metadata


def test_ctrl_c_leaves_a_readable_file_of_the_frames_before(run_dir, tmp_path, monkeypatch):
    def interrupt():
        raise KeyboardInterrupt

    _stopping_render(monkeypatch, 2, interrupt)
    path = tmp_path / "cut.mcap"
    result = export_mcap(run_dir, path, ExportOptions(progress=False), ReplayImages)
    assert (result.stopped_by, result.frames, result.images) == ("SIGINT", 2, 4)
    counts, metadata = _read_back(path)
    assert counts["/tf"] == counts["/cam1/image_raw"] == 2
    assert metadata["complete"] == "false" and metadata["frames"].startswith("2/")


def test_sigterm_ends_the_export_with_status_143(run_dir, tmp_path, monkeypatch, capsys):
    _stopping_render(monkeypatch, 1, lambda: os.kill(os.getpid(), signal.SIGTERM))
    path = tmp_path / "term.mcap"
    assert _export_cli([str(run_dir), "--mcap", str(path), "--quiet"]) == 143
    assert "interrupted by SIGTERM" in capsys.readouterr().err
    counts, metadata = _read_back(path)
    assert counts["/tf"] == 1 and metadata["stopped_by"] == "SIGTERM"


def _copy_run(run_dir: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "copy"
    shutil.copytree(run_dir, copy)
    return copy


def _rewrite_frames(folder: Path, keep=lambda column: True, edit=lambda i, column, v: v) -> None:
    """frames.csv with only the columns ``keep`` keeps, field values through ``edit``; its
    SHA-256 left out of metrics.json, as a run from before it was recorded (which the checks
    behind it must still catch)."""
    metrics = json.loads((folder / "metrics.json").read_text())
    metrics.pop("frames_sha256", None)
    (folder / "metrics.json").write_text(json.dumps(metrics))
    with (folder / "frames.csv").open(newline="") as f:
        table = list(csv.DictReader(f))
    header = [c for c in table[0] if keep(c)]
    with (folder / "frames.csv").open("w", newline="") as f:
        writer = csv.writer(f, quoting=csv.QUOTE_MINIMAL)
        writer.writerow(header)
        for i, row in enumerate(table):
            writer.writerow([edit(i, c, row[c]) for c in header])


def test_bad_inputs_are_clear_errors(run_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "x.mcap"
    with pytest.raises(CellsightError, match="does not exist"):
        export_mcap(tmp_path / "nowhere", out, ExportOptions(progress=False), ReplayImages)
    with pytest.raises(CellsightError, match="no metrics.json"):
        export_mcap(tmp_path, out, ExportOptions(progress=False), ReplayImages)
    with pytest.raises(CellsightError, match="--every: expected a whole number >= 1, got 0"):
        export_mcap(run_dir, out, ExportOptions(every=0, progress=False), ReplayImages)
    out.write_bytes(b"")
    with pytest.raises(CellsightError, match="exists; pass --overwrite"):
        export_mcap(run_dir, out, ExportOptions(progress=False), ReplayImages)
    with pytest.raises(CellsightError, match="the run's own frames.csv"):
        export_mcap(run_dir, run_dir / "frames.csv", ExportOptions(overwrite=True, progress=False),
                    ReplayImages)


def test_a_run_without_joint_columns_asks_for_a_new_run(run_dir: Path, tmp_path: Path) -> None:
    old = _copy_run(run_dir, tmp_path)
    _rewrite_frames(old, keep=lambda c: not c.startswith("q_"))
    with pytest.raises(CellsightError, match=r"no joint columns .*run the experiment again"):
        export_mcap(old, tmp_path / "x.mcap", ExportOptions(progress=False), ReplayImages)
    assert not (tmp_path / "x.mcap").exists()


def test_a_bad_field_names_its_row_and_column(run_dir: Path, tmp_path: Path) -> None:
    bad = _copy_run(run_dir, tmp_path)
    _rewrite_frames(bad, edit=lambda i, c, v: "" if (i, c) == (4, "q_R6AX_2") else v)
    with pytest.raises(CellsightError, match=r"frames.csv row 5 \(t = .* s\): field "
                                             r"'q_R6AX_2' is empty"):
        export_mcap(bad, tmp_path / "x.mcap", ExportOptions(progress=False), ReplayImages)
    (bad / "run_cell.yaml").unlink()  # a run from before cells were kept
    metrics = json.loads((bad / "metrics.json").read_text())
    metrics["cell"] = str(tmp_path / "gone.yaml")
    metrics.pop("cell_files", None)
    (bad / "metrics.json").write_text(json.dumps(metrics))
    with pytest.raises(CellsightError, match=r"metrics.json: field 'cell': .*gone.yaml.*--cell"):
        export_mcap(bad, tmp_path / "x.mcap", ExportOptions(progress=False), ReplayImages)


def test_joint_states_of_dh_robots_are_joint1_to_n(messages, rows, cell) -> None:
    for (log, _, msg), row in zip(messages["/joint_states"], rows, strict=True):
        expected = {f"{r.name}/joint{j}": float(row[f"q_{r.name}_{j}"])
                    for r in cell.robots for j in range(1, r.n_joints + 1)}
        expected["R7AX/jaw_opening"] = float(row["jaw_opening"])
        assert log == _ns(row["t"])
        assert dict(zip(msg.name, msg.position, strict=True)) == expected

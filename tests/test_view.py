"""``cellsight view``: started on 127.0.0.1 at a free port, checked through what it serves.

The HTTP index page of the viser client, and the scene as a browser receives it: a websocket
client (:class:`SceneClient`) decodes viser's wire format and keeps every scene node and GUI
element. Checked against the cell model, independently of the view's own code: one mesh per
cell object at its snapshot pose, one frustum per camera at the camera's extrinsics (its optical
axis projecting to the principal point) with its field of view, the feature points' colours
against the VisibilityPredictor and, replaying a short experiment-3 run, against the log's bits;
moving the timeline slider (as the browser does) puts the robots' links where forward
kinematics puts them for that frame's logged joints.
"""

from __future__ import annotations

import csv
import json
import shutil
import socket
import time
import urllib.request
from pathlib import Path

import cv2
import msgspec
import numpy as np
import pytest
import viser
import zstandard
from scipy.spatial.transform import Rotation
from websockets.sync.client import connect

from cellsight.cli import main
from cellsight.errors import CellsightError
from cellsight.experiments import RunConfig, run_experiment
from cellsight.geometry.transforms import pose_from_xyz_rpy, transform_points
from cellsight.model.loader import load_cell
from cellsight.occlusion.backends import visibility_predictor
from cellsight.runfolder.framelog import FrameLog, decode_corners, decode_windows
from cellsight.view.app import ViewApp
from cellsight.view.replay import RunReplay
from cellsight.view.states import static_state

GREEN, RED = (40, 210, 70), (235, 45, 45)  # the overlay's visible / occluded colours


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _decode(raw: bytes) -> list[dict]:
    """viser's server -> client frame: sizes, zstd msgpack, 8-byte aligned binary buffers."""
    size, compressed = int.from_bytes(raw[:8], "little"), int.from_bytes(raw[8:16], "little")
    inner = msgspec.msgpack.decode(zstandard.ZstdDecompressor().decompress(
        raw[16:16 + compressed], max_output_size=size))
    offset, buffers = 16 + compressed, []
    for n in inner["binaryBufferLengths"]:
        offset += (8 - offset % 8) % 8
        buffers.append(raw[offset:offset + n])
        offset += n

    def fill(value):
        if isinstance(value, dict):
            if "__binary_index" in value and "dtype" in value:
                return np.frombuffer(buffers[value["__binary_index"]], np.dtype(value["dtype"]))
            return {k: fill(v) for k, v in value.items()}
        return [fill(v) for v in value] if isinstance(value, list) else value

    return [fill(m) for m in inner["messages"]]


class SceneClient:
    """A websocket client of the view: scene nodes by name (type, props, position, wxyz,
    visible) and GUI elements by uuid, as a browser would hold them."""

    def __init__(self, port: int) -> None:
        self.ws = connect(f"ws://127.0.0.1:{port}", max_size=None,
                          subprotocols=[f"viser-v{viser.__version__}"])
        self.nodes: dict[str, dict] = {}
        self.gui: dict[str, dict] = {}
        # a browser reports its viewpoint first; viser counts it as connected from then on
        self.ws.send(msgspec.msgpack.encode({
            "type": "ViewerCameraMessage", "wxyz": [1.0, 0.0, 0.0, 0.0],
            "position": [3.0, 3.0, 3.0], "fov": 1.0, "near": 0.01, "far": 100.0,
            "image_height": 900, "image_width": 1400, "look_at": [0.0, 0.0, 0.0],
            "up_direction": [0.0, 0.0, 1.0]}))

    def _apply(self, m: dict) -> None:
        kind, name = m["type"], m.get("name")
        if kind.endswith("Message") and "props" in m and name is not None:
            self.nodes[name] = {"type": kind, "props": m["props"], "visible": True,
                                "position": np.zeros(3), "wxyz": np.array([1.0, 0, 0, 0])}
        elif kind == "SetPositionMessage" and name in self.nodes:
            self.nodes[name]["position"] = np.array(m["position"])
        elif kind == "SetOrientationMessage" and name in self.nodes:
            self.nodes[name]["wxyz"] = np.array(m["wxyz"])
        elif kind == "SetSceneNodeVisibilityMessage" and name in self.nodes:
            self.nodes[name]["visible"] = m["visible"]
        elif kind == "SceneNodeUpdateMessage" and name in self.nodes:
            self.nodes[name]["props"].update(m["updates"])
        elif kind.startswith("Gui") and "props" in m and "uuid" in m:
            self.gui[m["uuid"]] = {"type": kind, **m["props"], "value": m.get("value")}
        elif kind == "GuiUpdateMessage" and m["uuid"] in self.gui:
            self.gui[m["uuid"]].update(m["updates"])

    def pump(self, seconds: float = 0.3) -> None:
        """Take in what arrives until the link has been quiet for ``seconds``."""
        while True:
            try:
                raw = self.ws.recv(timeout=seconds)
            except TimeoutError:
                return
            for m in _decode(raw):
                self._apply(m)

    def wait(self, condition, timeout: float = 15.0) -> None:
        end = time.monotonic() + timeout
        while not condition():
            assert time.monotonic() < end, "the view did not get there in time"
            self.pump(0.1)

    def gui_uuid(self, kind: str, label: str) -> str:
        return next(u for u, g in self.gui.items() if g["type"] == kind and g["label"] == label)

    def set_gui(self, uuid: str, value) -> None:
        """What the browser sends when the user moves a control."""
        self.ws.send(msgspec.msgpack.encode({"type": "GuiUpdateMessage", "uuid": uuid,
                                             "updates": {"value": value}}))

    def pose(self, name: str) -> np.ndarray:
        node = self.nodes[name]
        T = np.eye(4)
        w, x, y, z = node["wxyz"]
        T[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()
        T[:3, 3] = node["position"]
        return T

    def colours(self, name: str) -> np.ndarray:
        return np.asarray(self.nodes[name]["props"]["colors"]).reshape(-1, 3)

    def close(self) -> None:
        self.ws.close()


def expected_colours(visible: np.ndarray) -> np.ndarray:
    return np.where(np.asarray(visible, bool)[:, None], GREEN, RED)


@pytest.fixture(scope="module")
def cell():
    return load_cell()


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """Experiment 3, ideal sensor, 5 s: R7AX starts its approach at 4 s."""
    out = tmp_path_factory.mktemp("view") / "e3"
    run_experiment(RunConfig(3, out, sensor="ideal", seed=1, duration=5.0, progress=False))
    return out


CROSSING = {"R6AX": np.array([-0.129, 0.194, -0.046, 0.342, 1.641, -0.372])}
"""R6AX's gripper hides three of the part's points from cam2, not from cam1."""


@pytest.fixture(scope="module")
def static_view(cell):
    app = ViewApp(cell, state=static_state(cell, CROSSING), port=free_port())
    client = SceneClient(app.port)
    client.pump()
    yield app, client
    client.close()
    app.close()


def test_serves_the_client_page(static_view):
    app, _ = static_view
    with urllib.request.urlopen(app.url, timeout=10) as reply:
        body = reply.read()
        assert reply.status == 200
        assert reply.headers["Content-Type"].startswith("text/html")
    assert b"<html" in body.lower()


def test_one_mesh_per_cell_object_at_its_pose(static_view, cell):
    _, client = static_view
    meshes = {n: v for n, v in client.nodes.items() if n.startswith("/cell/")}
    assert sorted(meshes) == sorted(f"/cell/{o.name}" for o in cell.objects)
    snapshot = cell.snapshot(CROSSING)
    for obj, T in zip(cell.objects, snapshot.poses, strict=True):
        node = meshes[f"/cell/{obj.name}"]
        assert node["type"] == "MeshMessage"
        assert len(node["props"]["vertices"]) == 3 * len(obj.solid.vertices)
        np.testing.assert_allclose(client.pose(f"/cell/{obj.name}"), T, atol=1e-6)


def test_one_frustum_per_camera_at_its_extrinsics(static_view, cell):
    _, client = static_view
    frustums = {n for n, v in client.nodes.items() if v["type"] == "CameraFrustumMessage"}
    assert frustums == {f"/cameras/{c.name}" for c in cell.cameras}
    for cam in cell.cameras:
        node, T = client.nodes[f"/cameras/{cam.name}"], client.pose(f"/cameras/{cam.name}")
        np.testing.assert_allclose(T, cam.T_base_cam, atol=1e-9)
        # optical axis (z) through the principal point, x to the right, y down in the image
        centre, R = T[:3, 3], T[:3, :3]
        ahead = np.array([centre + R[:, 2], centre + R[:, 2] + 0.01 * R[:, 0],
                          centre + R[:, 2] + 0.01 * R[:, 1]])
        (u0, v0), (u1, _), (_, v2) = cam.project(ahead)
        np.testing.assert_allclose([u0, v0], cam.K[:2, 2], atol=1e-6)
        assert u1 > u0 and v2 > v0
        fy = cam.K[1, 1]
        assert node["props"]["fov"] == pytest.approx(2 * np.arctan(cam.height / 2 / fy))
        assert node["props"]["aspect"] == pytest.approx(cam.width / cam.height, rel=1e-6)


def test_features_coloured_by_the_predictor_per_camera(static_view, cell):
    _, client = static_view
    part = cell.workpieces[0]
    views = visibility_predictor(cell).predict(CROSSING)[part.name]
    assert not np.array_equal(views[0].visible, views[1].visible)  # the choice matters
    name = f"/features/{part.name}"
    np.testing.assert_allclose(
        np.asarray(client.nodes[name]["props"]["points"]).reshape(-1, 3),
        transform_points(part.T_base_part, part.feature_points), atol=1e-6)
    dropdown = client.gui_uuid("GuiDropdownMessage", "seen by")
    for c, cam in list(enumerate(cell.cameras))[::-1]:
        client.set_gui(dropdown, cam.name)
        expected = expected_colours(views[c].visible)
        client.wait(lambda e=expected: np.array_equal(client.colours(name), e))


def _link_nodes(cell, frame_index_of=None):
    """(node name, robot, frame index) of every robot link object."""
    return [(f"/cell/{o.name}", f.owner, f.index)
            for o, f in zip(cell.objects, cell.frames, strict=True) if f.kind == "link"]


def test_replay_draws_the_logged_windows_and_corners(run_dir):
    replay = RunReplay(run_dir)
    log = FrameLog.read(run_dir / "frames.csv")
    drawn = 0
    for k in range(0, log.n, 10):
        features = replay.state(k).features[replay.part]
        for c in range(len(replay.cell.cameras)):
            _, boxes = decode_windows(log.text(f"windows_c{c + 1}")[k])
            np.testing.assert_array_equal(features.windows[c], boxes)
            measured = log.bits(f"meas_c{c + 1}", 16)[k]
            corners = decode_corners(log.text(f"corners_c{c + 1}")[k], 16)
            np.testing.assert_array_equal(features.measured_pixels[c][measured],
                                          corners[measured])
            drawn += len(boxes)
    assert drawn > 20


def test_replay_follows_the_timeline(run_dir, cell):
    replay = RunReplay(run_dir)
    log = FrameLog.read(run_dir / "frames.csv")
    q = {r: log.joints(r) for r in log.robots}
    k = log.n - 1
    assert not np.allclose(q["R7AX"][k], q["R7AX"][0])  # R7AX moved: the check means something
    app = ViewApp(replay.cell, replay=replay, port=free_port())
    client = SceneClient(app.port)
    try:
        client.pump()
        part = f"/features/{replay.part}"
        vis = log.bits("vis_pred_c1")
        np.testing.assert_array_equal(client.colours(part), expected_colours(vis[0]))
        client.set_gui(client.gui_uuid("GuiSliderMessage", "frame"), k)
        links = _link_nodes(cell)

        def at_frame_k() -> bool:
            return all(np.allclose(client.pose(n), cell.robot(r).link_poses(q[r][k])[i],
                                   atol=1e-6) for n, r, i in links)

        client.wait(at_frame_k)
        np.testing.assert_array_equal(client.colours(part), expected_colours(vis[k]))
        est = log.poses("est")[k]
        node = f"/estimate/{replay.part}"
        assert client.nodes[node]["visible"]
        np.testing.assert_allclose(client.pose(node), pose_from_xyz_rpy(est[:3], est[3:]),
                                   atol=1e-6)
        client.set_gui(client.gui_uuid("GuiCheckboxMessage", "ray-cast truth"), True)
        truth = log.bits("vis_true_c1")[k]
        client.wait(lambda: np.array_equal(client.colours(part), expected_colours(truth)))
        _check_images(app, client, cell)
    finally:
        client.close()
        app.close()


def _check_images(app, client, cell) -> None:
    """Each camera's image reaches the GUI panel, at the camera's size."""
    assert app.worker.wait_idle(30.0) and app.worker.error is None
    client.pump()
    images = [g for g in client.gui.values() if g["type"] == "GuiImageMessage"]
    assert sorted(g["label"] for g in images) == sorted(c.name for c in cell.cameras)
    for g in images:
        cam = cell.camera(g["label"])
        image = cv2.imdecode(np.frombuffer(bytes(g["_data"]), np.uint8), cv2.IMREAD_COLOR)
        assert image.shape == (cam.height, cam.width, 3) and image.std() > 5


def _copy_run(run_dir: Path, to: Path) -> Path:
    shutil.copytree(run_dir, to)
    return to


def _without_frames_digest(folder: Path) -> None:
    """metrics.json without frames.csv's SHA-256: a run from before it was recorded, whose
    frames.csv the test edits to reach the checks behind it."""
    metrics = json.loads((folder / "metrics.json").read_text())
    metrics.pop("frames_sha256", None)
    (folder / "metrics.json").write_text(json.dumps(metrics))


def test_run_errors_name_the_file(run_dir, tmp_path):
    with pytest.raises(CellsightError, match="no such run folder"):
        RunReplay(tmp_path / "nothing")
    with pytest.raises(CellsightError, match="no metrics.json"):
        RunReplay(tmp_path)
    bad_cell = _copy_run(run_dir, tmp_path / "bad_cell")
    (bad_cell / "run_cell.yaml").unlink()  # a run from before cells were kept
    metrics = json.loads((bad_cell / "metrics.json").read_text())
    metrics["cell"] = str(tmp_path / "gone.yaml")
    metrics.pop("cell_files", None)
    (bad_cell / "metrics.json").write_text(json.dumps(metrics))
    with pytest.raises(CellsightError, match=r"metrics.json: field 'cell': .*gone.yaml"):
        RunReplay(bad_cell)
    assert RunReplay(bad_cell, "dual-arm").n > 0  # --cell overrides it
    old = _copy_run(run_dir, tmp_path / "old")
    with (run_dir / "frames.csv").open(newline="") as f:
        rows = list(csv.reader(f))
    keep = [i for i, name in enumerate(rows[0]) if not name.startswith("q_")]
    with (old / "frames.csv").open("w", newline="") as f:
        csv.writer(f, quoting=csv.QUOTE_NONNUMERIC).writerows([[r[i] for i in keep]
                                                              for r in rows])
    _without_frames_digest(old)
    with pytest.raises(CellsightError, match=r"frames.csv: no joint columns .*logged before"):
        RunReplay(old)


def test_busy_port_and_command_line(run_dir, cell, capsys):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        with pytest.raises(CellsightError, match=f"127.0.0.1:{port} is already in use"):
            ViewApp(cell, port=port)
        assert main(["view", "--port", str(port), "--serve-for", "0"]) == 2
        assert "already in use" in capsys.readouterr().err
    assert main(["view", "--port", "0", "--serve-for", "0", "--time", "3", str(run_dir)]) == 0
    assert f"run {run_dir} at http://127.0.0.1:" in capsys.readouterr().out
    assert main(["view", "--joints", '{"R7AX": [1, 2]}', "--serve-for", "0", "--port", "0"]) == 2
    assert "R7AX" in capsys.readouterr().err
    assert main(["view", "--joints", "{}", "--port", "0", str(run_dir)]) == 2
    assert "not with RUN_DIR" in capsys.readouterr().err


def test_estimate_hidden_where_the_log_has_none(run_dir, tmp_path):
    lost = _copy_run(run_dir, tmp_path / "lost")
    with (run_dir / "frames.csv").open(newline="") as f:
        rows = list(csv.reader(f))
    est = [i for i, name in enumerate(rows[0]) if name.startswith("est_")]
    for i in est:
        rows[1][i] = ""
    with (lost / "frames.csv").open("w", newline="") as f:
        csv.writer(f, quoting=csv.QUOTE_NONNUMERIC).writerows(rows)
    _without_frames_digest(lost)
    replay = RunReplay(lost)
    assert not replay.state(0).estimates and replay.state(1).estimates
    app = ViewApp(replay.cell, replay=replay, port=free_port())
    client = SceneClient(app.port)
    try:
        client.pump()
        node = f"/estimate/{replay.part}"
        assert not client.nodes[node]["visible"]
        client.set_gui(client.gui_uuid("GuiSliderMessage", "frame"), 1)
        client.wait(lambda: client.nodes[node]["visible"])
    finally:
        client.close()
        app.close()

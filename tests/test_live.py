"""``--live`` (cellsight.export.live): a WebSocket client connects to a short rendered run's
Foxglove server as Foxglove does (subprotocol ``foxglove.sdk.v1``), subscribes to every
advertised channel and decodes the messages with the protobuf schemas the server advertises;
what it receives is checked against the cell and the run's own log, and the run's metrics
against the same run without ``--live``."""

from __future__ import annotations

import asyncio
import base64
import json
import socket
import struct
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import websockets
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

from cellsight import load_cell
from cellsight.errors import CellsightError
from cellsight.experiments import RunConfig, run_experiment
from cellsight.export.live import parse_address
from cellsight.runfolder import FrameLog, read_metrics

DURATION = 2.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _message_class(channel: dict):
    """The protobuf class of an advertised channel, from its FileDescriptorSet."""
    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for file in files.file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


async def _listen(port: int, received: dict, advertised: list, stop: threading.Event) -> None:
    deadline = time.time() + 120
    while True:
        try:
            ws = await websockets.connect(f"ws://127.0.0.1:{port}",
                                          subprotocols=["foxglove.sdk.v1"], max_size=None)
            break
        except OSError:
            if time.time() > deadline or stop.is_set():
                return
            await asyncio.sleep(0.05)
    classes, topics = {}, {}
    async with ws:
        while not stop.is_set():
            try:
                message = await asyncio.wait_for(ws.recv(), 0.5)
            except TimeoutError:
                continue
            except websockets.ConnectionClosed:
                return
            if isinstance(message, str):
                data = json.loads(message)
                if data["op"] == "advertise":
                    advertised += data["channels"]
                    for channel in data["channels"]:
                        classes[channel["id"]] = _message_class(channel)
                        topics[channel["id"]] = channel["topic"]
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": c["id"], "channelId": c["id"]} for c in data["channels"]]}))
            elif message[0] == 1:  # message data: opcode, subscription id, log time, payload
                sub, _ = struct.unpack_from("<IQ", message, 1)
                received.setdefault(topics[sub], []).append(classes[sub].FromString(message[13:]))


@pytest.fixture(scope="module")
def streamed(tmp_path_factory):
    folder = tmp_path_factory.mktemp("live")
    port = _free_port()
    received: dict = {}
    advertised: list = []
    stop = threading.Event()
    client = threading.Thread(target=asyncio.run,
                              args=(_listen(port, received, advertised, stop),), daemon=True)
    client.start()
    run_experiment(RunConfig(3, folder / "live", duration=DURATION, progress=False,
                             live=f"127.0.0.1:{port}"))
    stop.set()
    client.join(timeout=10)
    run_experiment(RunConfig(3, folder / "quiet", duration=DURATION, progress=False))
    return folder, received, advertised


@pytest.mark.slow
def test_the_channels_are_advertised(streamed):
    _, _, advertised = streamed
    topics = {c["topic"]: c["schemaName"] for c in advertised}
    assert topics == {"/tf": "foxglove.FrameTransforms", "/part/estimate": "foxglove.PoseInFrame",
                      "/status": "foxglove.Log", "/cam1/visibility": "foxglove.SceneUpdate",
                      "/cam2/visibility": "foxglove.SceneUpdate",
                      "/cam1/image": "foxglove.CompressedImage",
                      "/cam2/image": "foxglove.CompressedImage"}


@pytest.mark.slow
def test_tf_holds_the_cameras_where_the_cell_has_them(streamed):
    _, received, _ = streamed
    assert len(received["/tf"]) > 10
    cell = load_cell()
    last = {t.child_frame_id: t for t in received["/tf"][-1].transforms}
    for cam in cell.cameras:
        t = last[f"{cam.name}_optical"] if f"{cam.name}_optical" in last else last[
            f"{cam.name}_optical_frame"]
        xyz = [t.translation.x, t.translation.y, t.translation.z]
        assert np.allclose(xyz, cam.T_base_cam[:3, 3], atol=1e-12)


@pytest.mark.slow
def test_the_estimates_are_the_runs(streamed):
    folder, received, _ = streamed
    logged = FrameLog.read(folder / "live" / "frames.csv").poses("est")[:, :3]
    estimates = received["/part/estimate"]
    assert len(estimates) > 10
    for message in estimates:
        p = message.pose.position
        assert np.min(np.linalg.norm(logged - [p.x, p.y, p.z], axis=1)) < 1e-12


@pytest.mark.slow
def test_an_image_decodes_with_the_overlay(streamed):
    _, received, _ = streamed
    image = cv2.imdecode(np.frombuffer(received["/cam1/image"][-1].data, np.uint8),
                         cv2.IMREAD_COLOR)
    cam = load_cell().cameras[0]
    assert image.shape == (cam.height // 2, cam.width // 2, 3)
    b, g, r = (image[..., i].astype(int) for i in range(3))
    assert np.sum((g > 150) & (r < 100) & (b < 100)) > 20  # the green predicted-visible discs


@pytest.mark.slow
def test_the_run_is_the_same_with_and_without_live(streamed):
    folder, _, _ = streamed
    a, b = read_metrics(folder / "live"), read_metrics(folder / "quiet")
    skip = {"wall_s", "timing_ms", "frames_sha256"}  # frames.csv logs each stage's time
    assert {k: v for k, v in a.items() if k not in skip} == {
        k: v for k, v in b.items() if k not in skip}
    log_a = FrameLog.read(folder / "live" / "frames.csv")
    log_b = FrameLog.read(folder / "quiet" / "frames.csv")
    assert np.array_equal(log_a.poses("est"), log_b.poses("est"), equal_nan=True)


@pytest.mark.parametrize("text", ["host:port", "99999", "a:-1"])
def test_a_bad_address_is_one_clear_error(text):
    with pytest.raises(CellsightError, match="--live: expected"):
        parse_address(text)
    with pytest.raises(CellsightError, match="--live"):
        RunConfig(3, Path("/tmp/never"), live=text)


def test_a_port_in_use_is_refused_before_the_run_naming_it(tmp_path, capsys):
    """Another program listens on the port: the run is refused before its folder exists (no
    half run blocks the rerun), by the API and the command line, naming --live and the
    address; the same port free again is taken."""
    from cellsight.cli import main

    with socket.socket() as other:
        other.bind(("127.0.0.1", 0))
        other.listen()
        port = other.getsockname()[1]
        wanted = f"--live: 127.0.0.1:{port} is already in use"
        with pytest.raises(CellsightError, match=wanted.replace(".", r"\.")):
            RunConfig(1, tmp_path / "api", live=str(port))
        assert main(["run", "1", "--sensor", "ideal", "--out", str(tmp_path / "cli"),
                     "--live", f"127.0.0.1:{port}"]) == 2
        err = capsys.readouterr().err
        assert wanted in err and "pick another port, or 0 for a free one" in err
        assert not (tmp_path / "cli").exists() and not (tmp_path / "api").exists()
    assert parse_address(str(port)) == ("127.0.0.1", port)

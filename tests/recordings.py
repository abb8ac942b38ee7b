"""Test helpers: a recorded run's MCAP file rewritten as a rosbag2 folder by ``rosbags`` (SQLite
storage by default), with topics and joints renamed and messages edited on the way, as another
recorder would have written it."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

STORE = get_typestore(Stores.ROS2_HUMBLE)
T = STORE.types


def read_mcap(path: Path) -> list[tuple[str, str, int, object]]:
    """(topic, type, log time ns, decoded message) of every message, in log-time order."""
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(channel.topic, schema.name, int(message.log_time), decoded)
                for schema, channel, message, decoded
                in reader.iter_decoded_messages(log_time_order=True)]


def _time(stamp) -> object:
    return T["builtin_interfaces/msg/Time"](sec=int(stamp.sec), nanosec=int(stamp.nanosec))


def _header(h) -> object:
    return T["std_msgs/msg/Header"](stamp=_time(h.stamp), frame_id=str(h.frame_id))


def to_rosbags(kind: str, m) -> object | None:
    """The ``rosbags`` message of a decoded MCAP message (None for types not carried over)."""
    if kind == "sensor_msgs/msg/JointState":
        return T[kind](header=_header(m.header), name=list(m.name),
                       position=np.asarray(m.position, float),
                       velocity=np.asarray(m.velocity, float), effort=np.asarray(m.effort, float))
    if kind == "sensor_msgs/msg/Image":
        return T[kind](header=_header(m.header), height=m.height, width=m.width,
                       encoding=m.encoding, is_bigendian=m.is_bigendian, step=m.step,
                       data=np.frombuffer(bytes(m.data), np.uint8))
    if kind == "sensor_msgs/msg/CompressedImage":
        return T[kind](header=_header(m.header), format=m.format,
                       data=np.frombuffer(bytes(m.data), np.uint8))
    if kind == "sensor_msgs/msg/CameraInfo":
        roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                     do_rectify=False)
        return T[kind](header=_header(m.header), height=m.height, width=m.width,
                       distortion_model=m.distortion_model, d=np.asarray(m.d, float),
                       k=np.asarray(m.k, float), r=np.asarray(m.r, float),
                       p=np.asarray(m.p, float), binning_x=0, binning_y=0, roi=roi)
    if kind == "geometry_msgs/msg/PoseStamped":
        p, q = m.pose.position, m.pose.orientation
        pose = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=p.x, y=p.y, z=p.z),
            orientation=T["geometry_msgs/msg/Quaternion"](x=q.x, y=q.y, z=q.z, w=q.w))
        return T[kind](header=_header(m.header), pose=pose)
    return None


Edit = Callable[[str, object, int], object | None]
"""(topic, rosbags message, its index on the topic) -> the message to write (None: left out;
a tuple (type, message): a message of another type)."""


def tf_message(header, child: str, pose) -> object:
    """A ``tf2_msgs/msg/TFMessage`` of one transform: ``pose`` (a rosbags Pose) of frame
    ``child`` in ``header``'s frame."""
    p, q = pose.position, pose.orientation
    transform = T["geometry_msgs/msg/Transform"](
        translation=T["geometry_msgs/msg/Vector3"](x=p.x, y=p.y, z=p.z),
        rotation=T["geometry_msgs/msg/Quaternion"](x=q.x, y=q.y, z=q.z, w=q.w))
    stamped = T["geometry_msgs/msg/TransformStamped"](header=header, child_frame_id=child,
                                                      transform=transform)
    return T["tf2_msgs/msg/TFMessage"](transforms=[stamped])


def write_rosbag2(source: Path, out: Path, *, topics: dict[str, str] | None = None,
                  joints: dict[str, str] | None = None, edit: Edit | None = None,
                  frames: int | None = None,
                  storage: StoragePlugin = StoragePlugin.SQLITE3) -> Path:
    """``source`` (an MCAP recording) as a rosbag2 folder ``out``: topics renamed by
    ``topics``, joint names by ``joints``, each message passed through ``edit``; only the
    messages logged before the ``frames``-th distinct log time with ``frames``."""
    topics, joints = topics or {}, joints or {}
    messages = read_mcap(source)
    if frames is not None:
        times = sorted({ns for _, _, ns, _ in messages})
        messages = [m for m in messages if m[2] < times[min(frames, len(times) - 1)]]
    counts: dict[str, int] = {}
    with Writer(out, version=8, storage_plugin=storage) as writer:
        connections = {}
        for topic, kind, ns, decoded in messages:
            msg = to_rosbags(kind, decoded)
            if msg is None:
                continue
            if kind == "sensor_msgs/msg/JointState":
                msg.name = [joints.get(n, n) for n in msg.name]
            k = counts[topic] = counts.get(topic, 0) + 1
            if edit is not None:
                msg = edit(topic, msg, k)
                if msg is None:
                    continue
                if isinstance(msg, tuple):
                    kind, msg = msg
            name = topics.get(topic, topic)
            if name not in connections:
                connections[name] = writer.add_connection(name, kind, typestore=STORE)
            writer.write(connections[name], ns, STORE.serialize_cdr(msg, kind))
    return out

"""An MCAP file of ROS 2 messages as ros2 bag writes it (:class:`RosBag`), and what every
writer of one checks first: the output file, the JPEG quality, the start time."""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import yaml

from cellsight.errors import CellsightError
from cellsight.export import ros
from cellsight.export.msgdefs import msgdef, schema_name
from cellsight.runfolder import RUN_FILES

END_NS = 2**31 * 10**9  # builtin_interfaces/Time's int32 seconds end on 2038-01-19T03:14:08Z
UNIX_EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)
ROS_DISTRO = "humble"  # the message definitions' (msgdefs) and the QoS metadata's distribution


class RosBag:
    """An MCAP file of ROS 2 messages (``ros2`` profile) written to ``stream``: schemas and
    channels registered on first use, each channel with rosbag2's QoS metadata
    (:func:`qos_profiles`), messages encoded to CDR by ``mcap-ros2-support``; ``topics``:
    topic -> [message type, count]. The plain ``mcap`` writer is used, as
    ``mcap_ros2.writer.Writer`` registers its channels without metadata. The export and the
    recorder (:mod:`cellsight.recording.recorder`) both write through it."""

    def __init__(self, stream, library: str = "cellsight export") -> None:
        from mcap.writer import Writer

        self._writer = Writer(stream)  # zstd chunks of 1 MiB, as mcap_ros2's writer
        self._writer.start(profile="ros2", library=f"{library} (mcap, mcap-ros2-support)")
        self._schemas: dict[str, tuple[int, Callable[[dict], bytes]]] = {}
        self._channels: dict[str, int] = {}
        self.topics: dict[str, list] = {}

    def _schema(self, kind: str) -> tuple[int, Callable[[dict], bytes]]:
        """The schema id and the CDR encoder of message type ``kind``."""
        found = self._schemas.get(kind)
        if found is None:
            from mcap_ros2._dynamic import serialize_dynamic

            name, text = schema_name(kind), msgdef(kind)
            found = self._schemas[kind] = (
                self._writer.register_schema(name, "ros2msg", text.encode()),
                serialize_dynamic(name, text)[name])
        return found

    def write(self, topic: str, kind: str, message: dict, ns: int) -> None:
        schema, encode = self._schema(kind)
        channel = self._channels.get(topic)
        if channel is None:
            qos = {"offered_qos_profiles": qos_profiles(latched(topic))}
            channel = self._channels[topic] = self._writer.register_channel(topic, "cdr",
                                                                            schema, qos)
        self._writer.add_message(channel, log_time=ns, data=encode(message), publish_time=ns)
        self.topics.setdefault(topic, [schema_name(kind), 0])[1] += 1

    def close(self, metadata: dict[str, str]) -> None:
        self._writer.add_metadata("rosbag2", {"ROS_DISTRO": ROS_DISTRO})
        self._writer.add_metadata("cellsight", metadata)
        self._writer.finish()


def latched(topic: str) -> bool:
    """Whether a topic is latched (durability ``transient_local``): ``/tf_static`` and the
    robot descriptions."""
    return topic == "/tf_static" or topic.endswith("/robot_description")


def qos_profiles(is_latched: bool) -> str:
    """A channel's ``offered_qos_profiles`` (rosbag2's channel metadata): YAML of one profile as
    ROS 2 Humble's rosbag2 writes it, its policies as rmw's integers (history 1 keep_last,
    reliability 1 reliable, durability 1 transient_local or 2 volatile, liveliness 1
    automatic; durations 0 s: the default), depth 1 when latched (as tf2's static broadcaster
    and robot_state_publisher offer), else 10. Humble's ``ros2 bag play`` reads only
    integers; later rosbag2 reads them in a file whose ``rosbag2`` metadata record has no
    ``serialized_metadata`` (this one's holds ``ROS_DISTRO``)."""
    never = {"sec": 0, "nsec": 0}
    profile = {"history": 1, "depth": 1 if is_latched else 10, "reliability": 1,
               "durability": 1 if is_latched else 2, "deadline": never, "lifespan": never,
               "liveliness": 1, "liveliness_lease_duration": never,
               "avoid_ros_namespace_conventions": False}
    return yaml.safe_dump([profile], sort_keys=False)


def start_time_ns(value: int | str) -> int:
    """The ROS time (ns since the Unix epoch) of a run's t = 0, from ``--start-time``: a whole
    number of ns, or an ISO 8601 date and time (``2024-05-01T12:00:00Z``; without a UTC
    offset, UTC; to the microsecond), before 2038-01-19T03:14:08Z (:data:`END_NS`)."""
    given = value
    if isinstance(value, str) and value.strip().isdigit():
        value = int(value)
    elif isinstance(value, str):
        text = value.strip()
        text = text[:-1] + "+00:00" if text[-1:] in ("Z", "z") else text
        try:
            when = datetime.fromisoformat(text)
        except ValueError:
            value = None
        else:
            when = when if when.tzinfo is not None else when.replace(tzinfo=timezone.utc)
            delta = when - UNIX_EPOCH
            value = (delta.days * 86400 + delta.seconds) * 10**9 + delta.microseconds * 1000
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < END_NS:
        raise CellsightError(f"--start-time: expected an ISO 8601 time such as "
                             f"2024-05-01T12:00:00Z, or ns since the Unix epoch, from 1970 to "
                             f"2038-01-19T03:14:08Z (ROS time's int32 seconds), got {given!r}")
    return value


def check_output(path: str | Path, overwrite: bool, run_folder: Path,
                 option: str = "--mcap") -> Path:
    """The output file (of command-line ``option``), checked before the work starts and touching
    nothing: not a folder, not one of the run's own files (nor a link to one), not existing
    unless ``overwrite``, its folder creatable and the nearest existing one writable."""

    path = Path(path)
    if path.is_dir():
        raise CellsightError(f"{option}: {str(path)!r} is a folder; expected a file name")
    target = path.resolve()  # through links: a link to frames.csv is frames.csv
    if target.name in RUN_FILES and target.parent == run_folder.resolve():
        raise CellsightError(f"{option}: {str(path)!r} is the run's own {target.name}")
    if path.exists() and not overwrite:
        raise CellsightError(f"{option}: {str(path)!r} exists; pass --overwrite to replace it")
    parent = next((p for p in path.absolute().parents if p.exists()), None)
    if parent is not None and not parent.is_dir():
        raise CellsightError(f"{option}: {str(path)!r} is under {str(parent)!r}, a file")
    if parent is not None:
        try:  # an unnamed file (O_TMPFILE where the system has it): nothing is left behind
            with tempfile.TemporaryFile(dir=parent):
                pass
        except OSError as exc:
            raise CellsightError(f"{option}: cannot write under {str(parent)!r} "
                                 f"({exc.strerror or exc})") from None
    return path


def check_jpeg(quality: int | None, option: str = "--jpeg") -> None:
    """A JPEG quality (command-line ``option``): None, or 1 to 100."""
    if quality is not None and (isinstance(quality, bool) or not isinstance(quality, int)
                                or not 1 <= quality <= 100):
        raise CellsightError(f"{option}: expected a JPEG quality 1 to 100, got {quality!r}")


def jpeg_image(ns: int, frame_id: str, image: np.ndarray, quality: int) -> dict:
    """``sensor_msgs/CompressedImage`` of an (H, W) uint8 grayscale image, JPEG of
    ``quality`` (OpenCV's encoder), format ``jpeg``."""
    import cv2

    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(image, dtype=np.uint8),
                            [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise CellsightError(f"--jpeg: OpenCV could not encode an image of {frame_id} as JPEG")
    return {"header": ros.header(ns, frame_id), "format": "jpeg", "data": data.tobytes()}

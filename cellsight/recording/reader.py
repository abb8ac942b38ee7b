"""Open a recording: an MCAP file (read with ``mcap`` and ``mcap-ros2-support``) or a rosbag2
folder, of either storage (MCAP or SQLite, read with ``rosbags``).

:func:`open_recording` gives a :class:`Recording`: its topics (type and message count) and
its messages of some topics, decoded, in log-time order. Decoded messages are read by
attribute as in ROS 2 Python (``msg.header.stamp.sec``); arrays may be lists, bytes or NumPy
arrays depending on the reader, so read them through ``numpy.asarray``. A file that cannot be
read (not a recording, truncated, damaged) is one :class:`RecordingError` naming it and what
was read before the damage.
"""

from __future__ import annotations

import io
from collections.abc import Iterator, Sequence
from contextlib import redirect_stderr, suppress
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from cellsight.errors import CellsightError, short_repr


class RecordingError(CellsightError, ValueError):
    """A recording that cannot be tracked: unreadable, incomplete or inconsistent."""


@dataclass(frozen=True)
class Topic:
    """A topic of a recording: its message type (``pkg/msg/Type``) and message count."""

    name: str
    type: str
    count: int


class Recording:
    """An open recording (module docstring): :attr:`topics` and :meth:`messages`."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.topics: dict[str, Topic] = {}
        self.span_ns: tuple[int, int] = (0, 0)
        """The log times (ns) of the first and the last message."""

    def messages(self, topics: Sequence[str]) -> Iterator[tuple[str, int, Any]]:
        """(topic, log time in ns, decoded message) of ``topics``, in log-time order, each with
        the fields of its type as ROS 2 defines it (:func:`misfit`); a reader's failure is a
        :class:`RecordingError` saying how many were read before it, a message that does not
        fit its type one naming the topic, the message and the field."""
        read = 0
        counts = dict.fromkeys(topics, 0)
        try:
            for item in self._decoded(topics):
                read += 1
                topic, msg = item[0], item[2]
                counts[topic] = counts.get(topic, 0) + 1
                kind = self.topics[topic].type if topic in self.topics else "?"
                problem = misfit(kind, msg)
                if problem is not None:
                    raise RecordingError(
                        f"recording {self.path}: {topic}, message {counts[topic]}: {problem}: "
                        f"not a {kind} as ROS 2 defines it (the recording's definition of the "
                        f"type is another, or damaged)")
                yield item
        except (RecordingError, GeneratorExit):
            raise
        except Exception as exc:
            raise RecordingError(f"recording {self.path}: damaged after {read} messages of "
                                 f"{', '.join(topics)} ({type(exc).__name__}: {exc})") from exc

    def _decoded(self, topics: Sequence[str]) -> Iterator[tuple[str, int, Any]]:
        """The reader's own (topic, log time, message) of ``topics``."""
        raise NotImplementedError

    def _one_type(self, known: Topic | None, kind: str) -> str:
        """``kind``, the type of another channel of a topic seen before as ``known``: a
        :class:`RecordingError` when they differ (a topic carries one message type; its
        messages would be read as the other's)."""
        if known is not None and known.type != kind:
            self.close()
            raise RecordingError(f"recording {self.path}: topic {known.name} holds messages of "
                                 f"two types ({known.type} and {kind}); expected one type per "
                                 f"topic")
        return kind

    def metadata(self, name: str) -> dict[str, str]:
        """The recording's metadata record ``name`` (MCAP's; empty when there is none, and for
        a rosbag2 folder)."""
        return {}

    def close(self) -> None:
        """Release the file."""

    def listing(self) -> str:
        """The topics, one ``name (type, count)`` each, for error messages."""
        return "; ".join(f"{t.name} ({t.type.split('/')[-1]}, {t.count})"
                         for t in sorted(self.topics.values(), key=lambda t: t.name)) or "none"

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


class McapRecording(Recording):
    """An MCAP file of ROS 2 messages (``ros2msg`` schemas, CDR)."""

    def __init__(self, path: Path) -> None:
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        super().__init__(path)
        self._file: BinaryIO = path.open("rb")
        try:
            self._reader = make_reader(self._file, decoder_factories=[DecoderFactory()])
            summary = self._reader.get_summary()
        except Exception as exc:
            self.close()
            raise RecordingError(f"recording {path}: not a readable MCAP file, or one truncated "
                                 f"or damaged ({type(exc).__name__}: {str(exc)[:120]}); `mcap "
                                 f"recover` rebuilds what a cut-off file holds") from exc
        if summary is None:
            self.close()
            raise RecordingError(f"recording {path}: the MCAP file has no summary: truncated "
                                 f"(a recorder that did not close it) or damaged; `mcap "
                                 f"recover` rebuilds what it holds")
        stats = summary.statistics
        counts = stats.channel_message_counts if stats else {}
        if stats:
            self.span_ns = (int(stats.message_start_time), int(stats.message_end_time))
        for cid, channel in summary.channels.items():
            schema = summary.schemas.get(channel.schema_id)
            kind = schema.name if schema else "?"
            known = self.topics.get(channel.topic)
            count = int(counts.get(cid, 0)) + (known.count if known else 0)
            self.topics[channel.topic] = Topic(channel.topic, self._one_type(known, kind), count)

    def metadata(self, name: str) -> dict[str, str]:
        try:
            found = [dict(m.metadata) for m in self._reader.iter_metadata() if m.name == name]
        except Exception:  # a damaged metadata section: the messages may still be read
            return {}
        return found[-1] if found else {}

    def _decoded(self, topics: Sequence[str]) -> Iterator[tuple[str, int, Any]]:
        items = self._reader.iter_decoded_messages(topics=list(topics), log_time_order=True)
        while True:
            # the decoder prints a damaged schema's line to stderr before it raises; the
            # error it raises says the same, in messages()'s one line
            with redirect_stderr(io.StringIO()):
                item = next(items, None)
            if item is None:
                return
            _, channel, message, decoded = item
            yield channel.topic, int(message.log_time), decoded

    def close(self) -> None:
        with suppress(Exception):
            self._file.close()


class Rosbag2Recording(Recording):
    """A rosbag2 folder (``metadata.yaml`` and its storage files, MCAP or SQLite)."""

    def __init__(self, path: Path) -> None:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        super().__init__(path)
        try:
            self._reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            self._reader.open()
        except Exception as exc:
            raise RecordingError(f"recording {path}: not a readable rosbag2 folder "
                                 f"({type(exc).__name__}: {exc})") from exc
        self.span_ns = (int(self._reader.start_time), int(self._reader.end_time))
        for conn in self._reader.connections:
            known = self.topics.get(conn.topic)
            count = conn.msgcount + (known.count if known else 0)
            self.topics[conn.topic] = Topic(conn.topic, self._one_type(known, conn.msgtype), count)

    def _decoded(self, topics: Sequence[str]) -> Iterator[tuple[str, int, Any]]:
        wanted = [c for c in self._reader.connections if c.topic in set(topics)]
        for conn, ns, raw in self._reader.messages(connections=wanted):
            yield conn.topic, int(ns), self._reader.deserialize(raw, conn.msgtype)

    def close(self) -> None:
        with suppress(Exception):
            self._reader.close()


@lru_cache(maxsize=1)
def _ros2_fields() -> dict:
    """ROS 2's message types (rosbags' Humble store): type -> (constants, fields)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE).fielddefs


_ARRAYS = (list, tuple, bytes, bytearray, memoryview, np.ndarray)
_INTEGER = (int, np.integer)
_NUMBER = (int, float, np.integer, np.floating)


def _base_fits(name: str, value: Any) -> bool:
    """``value`` is a value of the ROS 2 base type ``name``."""
    if name == "string":
        return isinstance(value, str)
    if name.startswith("float"):
        return isinstance(value, _NUMBER)
    return isinstance(value, (*_INTEGER, bool, np.bool_)) or (
        isinstance(value, bytes) and len(value) == 1)  # a byte or char


def misfit(kind: str, msg: Any, prefix: str = "") -> str | None:
    """What about the decoded message ``msg`` does not fit the ROS 2 type ``kind`` (a field
    missing, of another kind, an array of another length), in words; None when it fits, or
    when ``kind`` is not a type ROS 2 defines. Arrays of numbers are not checked item by
    item. A recording that defines a type otherwise than ROS 2 (a damaged schema) gives
    messages without the fields cellsight reads."""
    from rosbags.interfaces import Nodetype

    definition = _ros2_fields().get(kind)
    if definition is None:
        return None
    for name, (node, details) in definition[1]:
        where = prefix + name
        if not hasattr(msg, name):
            return f"no field {where!r}"
        value = getattr(msg, name)
        if node == Nodetype.NAME:
            problem = misfit(details, value, where + ".")
        elif node == Nodetype.BASE:
            problem = (None if _base_fits(details[0], value) else
                       f"field {where!r} is {short_repr(value)}, not a {details[0]}")
        elif not isinstance(value, _ARRAYS):
            problem = f"field {where!r} is {short_repr(value)}, not an array"
        elif node == Nodetype.ARRAY and len(value) != details[1]:
            problem = f"field {where!r} has {len(value)} values, not {details[1]}"
        elif details[0][0] == Nodetype.NAME:
            problem = next((p for i, item in enumerate(value)
                            if (p := misfit(details[0][1], item, f"{where}[{i}]."))), None)
        else:
            problem = None
        if problem is not None:
            return problem
    return None


def open_recording(path: str | Path) -> Recording:
    """The recording at ``path``: an ``.mcap`` file, or a rosbag2 folder (or its
    ``metadata.yaml``, or one of its storage files)."""
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"recording {path}: no such file or folder")
    if path.is_file() and path.name == "metadata.yaml" or (
            path.is_file() and (path.parent / "metadata.yaml").is_file()):
        path = path.parent
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            raise RecordingError(f"recording {path}: a folder without metadata.yaml; expected a "
                                 f"rosbag2 folder or an .mcap file")
        return Rosbag2Recording(path)
    if not path.is_file():  # opening a FIFO would wait for a writer forever
        raise RecordingError(f"recording {path}: not a regular file (a FIFO, a socket or a "
                             f"device); expected an .mcap file or a rosbag2 folder")
    return McapRecording(path)

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

from collections.abc import Iterator, Sequence
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from cellsight.errors import CellsightError


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
        """(topic, log time in ns, decoded message) of ``topics``, in log-time order; a
        reader's failure is a :class:`RecordingError` saying how many were read before it."""
        read = 0
        try:
            for item in self._decoded(topics):
                read += 1
                yield item
        except (RecordingError, GeneratorExit):
            raise
        except Exception as exc:
            raise RecordingError(f"recording {self.path}: damaged after {read} messages of "
                                 f"{', '.join(topics)} ({type(exc).__name__}: {exc})") from exc

    def _decoded(self, topics: Sequence[str]) -> Iterator[tuple[str, int, Any]]:
        """The reader's own (topic, log time, message) of ``topics``."""
        raise NotImplementedError

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
            self.topics[channel.topic] = Topic(channel.topic, schema.name if schema else "?",
                                               int(counts.get(cid, 0)))

    def metadata(self, name: str) -> dict[str, str]:
        try:
            found = [dict(m.metadata) for m in self._reader.iter_metadata() if m.name == name]
        except Exception:  # a damaged metadata section: the messages may still be read
            return {}
        return found[-1] if found else {}

    def _decoded(self, topics: Sequence[str]) -> Iterator[tuple[str, int, Any]]:
        for _, channel, message, decoded in self._reader.iter_decoded_messages(
                topics=list(topics), log_time_order=True):
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
            self.topics[conn.topic] = Topic(conn.topic, conn.msgtype, count)

    def _decoded(self, topics: Sequence[str]) -> Iterator[tuple[str, int, Any]]:
        wanted = [c for c in self._reader.connections if c.topic in set(topics)]
        for conn, ns, raw in self._reader.messages(connections=wanted):
            yield conn.topic, int(ns), self._reader.deserialize(raw, conn.msgtype)

    def close(self) -> None:
        with suppress(Exception):
            self._reader.close()


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

"""What a recording says between the images: every robot's joints, each gripper's jaw
opening and, where it was measured, the part's true pose, as time series read at any instant.

Times are ROS times in ns (a message's ``header.stamp``; its log time where the stamp is
zero). A series' stamps must increase: a stamp that goes back is a
:class:`~cellsight.recording.reader.RecordingError` naming the topic and the message. A series
read at a stamp it holds gives that sample exactly; between samples, joints and openings are
interpolated linearly and poses by position and rotation (slerp); before the first sample or
after the last the nearest one is held, and the caller is told how long (:meth:`Series.at`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from cellsight.model.cell import Cell
from cellsight.recording.names import (
    OPENING,
    POSE,
    TRANSFORM,
    TRUTH_TYPES,
    TopicMap,
    joint_name,
)
from cellsight.recording.reader import Recording, RecordingError


@dataclass(frozen=True)
class _Stamped:
    """A bare header, read as a message by :func:`stamp_ns`."""

    header: Any


def stamp_ns(msg: Any, log_ns: int) -> int:
    """A message's header stamp (ns); its log time when the stamp is zero."""
    ns = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
    return ns if ns else int(log_ns)


@dataclass
class Series:
    """Samples of a value over time (module docstring); ``name`` names it in errors."""

    name: str
    ns: list[int] = field(default_factory=list)
    values: list[np.ndarray] = field(default_factory=list)

    def add(self, ns: int, value: np.ndarray, where: str) -> None:
        if self.ns and ns < self.ns[-1]:
            raise RecordingError(f"{where}: {self.name} stamped {ns / 1e9:.6f} s goes back "
                                 f"{(self.ns[-1] - ns) / 1e9:.6f} s from the one before; a "
                                 f"recording's stamps must not go backwards")
        if self.ns and ns == self.ns[-1]:
            self.values[-1] = value  # the same instant again: the later message holds
            return
        self.ns.append(ns)
        self.values.append(value)

    def at(self, ns: int) -> tuple[np.ndarray, float]:
        """The value at ``ns`` and how long (s) it was held beyond the samples (0 inside)."""
        times = self.ns
        k = int(np.searchsorted(times, ns))
        if k < len(times) and times[k] == ns:
            return self.values[k], 0.0
        if k == 0 or k == len(times):
            nearest = 0 if k == 0 else len(times) - 1
            return self.values[nearest], abs(ns - times[nearest]) / 1e9
        w = (ns - times[k - 1]) / (times[k] - times[k - 1])
        return self._between(k, w), 0.0

    def _between(self, k: int, w: float) -> np.ndarray:
        return (1.0 - w) * self.values[k - 1] + w * self.values[k]


class PoseSeries(Series):
    """A series of 4x4 poses: position linear, rotation slerp between samples."""

    def _between(self, k: int, w: float) -> np.ndarray:
        a, b = self.values[k - 1], self.values[k]
        T = np.eye(4)
        T[:3, 3] = (1.0 - w) * a[:3, 3] + w * b[:3, 3]
        slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([a[:3, :3], b[:3, :3]])))
        T[:3, :3] = slerp([w]).as_matrix()[0]
        return T


def pose_matrix(position: Any, orientation: Any, where: str = "a pose") -> np.ndarray:
    """The 4x4 pose of a ``geometry_msgs`` position (Point or Vector3) and Quaternion; a
    value that is not finite, or a quaternion far from unit length (0.9 to 1.1 is taken,
    normalised), is a :class:`RecordingError` naming ``where``."""
    q = np.array([orientation.x, orientation.y, orientation.z, orientation.w], dtype=float)
    p = np.array([position.x, position.y, position.z], dtype=float)
    norm = float(np.linalg.norm(q))
    if not (np.isfinite(q).all() and np.isfinite(p).all() and 0.9 <= norm <= 1.1):
        raise RecordingError(f"{where}: position {p.tolist()}, quaternion (x, y, z, w) "
                             f"{q.tolist()}: expected finite values and a unit quaternion")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(q / norm).as_matrix()
    T[:3, 3] = p
    return T


def _true_poses(kind: str, msg: Any, frame: str, where: str) -> list[tuple[Any, np.ndarray]]:
    """(header, pose) of a truth message: a PoseStamped, a TransformStamped, or the
    transforms of a TFMessage to the child ``frame``; ``where`` names the message."""
    if kind == POSE:
        return [(msg.header, pose_matrix(msg.pose.position, msg.pose.orientation, where))]
    stamped = [msg] if kind == TRANSFORM else [t for t in msg.transforms
                                               if t.child_frame_id == frame]
    return [(t.header, pose_matrix(t.transform.translation, t.transform.rotation, where))
            for t in stamped]


@dataclass
class Signals:
    """The recording's joints (recorded name -> series of one value), each robot's joints in
    chain order as recorded names (``robots``), each gripper's opening series and each
    workpiece's true-pose series."""

    joints: dict[str, Series]
    robots: dict[str, list[str]]
    openings: dict[str, Series]
    truth: dict[str, PoseSeries]

    def joints_at(self, ns: int) -> tuple[dict[str, np.ndarray], float]:
        """Every robot's joint vector at ``ns`` and the longest hold (s) among them."""
        out, held = {}, 0.0
        for robot, names in self.robots.items():
            values = []
            for name in names:
                value, h = self.joints[name].at(ns)
                values.append(float(value[0]))
                held = max(held, h)
            out[robot] = np.array(values)
        return out, held

    def openings_at(self, ns: int) -> dict[str, float]:
        return {robot: float(s.at(ns)[0][0]) for robot, s in self.openings.items()}

    def truth_at(self, part: str, ns: int, hold_s: float) -> np.ndarray | None:
        """The part's true pose at ``ns``; None without one within ``hold_s`` of a sample."""
        series = self.truth.get(part)
        if series is None or not series.ns:
            return None
        T, held = series.at(ns)
        return T if held <= hold_s else None


def _targets(cell: Cell, topic_map: TopicMap) -> dict[str, tuple[str, str]]:
    """Recorded joint name -> (``joint`` or ``opening``, ``robot/joint`` or robot)."""
    out = {joint_name(r.name, j): ("joint", joint_name(r.name, j))
           for r in cell.robots for j in r.chain.joint_names}
    out.update({joint_name(r.name, OPENING): ("opening", r.name)
                for r in cell.robots if r.tool is not None})
    for r in cell.robots:  # a URDF hand's fingers: the leader gives the opening
        for jaw, kind in zip(r.tool.jaws if r.tool else (), ("leader", "mimic"), strict=False):
            if jaw.joint:
                out[joint_name(r.name, jaw.joint)] = (kind, r.name)
    out.update({k: ("joint", v) for k, v in topic_map.joints.items()})
    out.update({k: ("opening", v) for k, v in topic_map.openings.items()})
    return out


class _SignalReader:
    """Builds :class:`Signals` from the messages of the joint and truth topics."""

    def __init__(self, cell: Cell, topic_map: TopicMap, truth_topics: dict[str, str]) -> None:
        self.cell, self.map = cell, topic_map
        self.targets = _targets(cell, topic_map)
        self.ignored = set(topic_map.ignore_joints)
        self.truth_parts: dict[str, list[str]] = {}
        for part, topic in truth_topics.items():
            self.truth_parts.setdefault(topic, []).append(part)
        self.kinds: dict[str, str] = {}
        self.series: dict[str, Series] = {}
        self.openings: dict[str, Series] = {}
        self.truth = {part: PoseSeries(f"{part}'s true pose") for part in truth_topics}
        self.count: dict[str, int] = {}

    def add(self, topic: str, log_ns: int, msg: Any) -> None:
        k = self.count[topic] = self.count.get(topic, 0) + 1
        where = f"{topic}, message {k}"
        if topic in self.truth_parts:
            for part in self.truth_parts[topic]:
                frame = self.map.truth_frame(part)
                for header, T in _true_poses(self.kinds[topic], msg, frame, where):
                    self.truth[part].add(stamp_ns(_Stamped(header), log_ns), T, where)
            return
        ns = stamp_ns(msg, log_ns)
        positions = np.asarray(msg.position, dtype=float)
        for i, name in enumerate(msg.name):
            if name in self.ignored:
                continue
            if name not in self.targets:
                raise RecordingError(
                    f"{where}: joint {name!r} is no joint of cell {self.cell.source}; expected "
                    f"ROBOT/JOINT ({', '.join(sorted(self.targets)[:6])}, ...), or a topic map "
                    f"(--topics) that maps it (joints:, openings:) or ignores it "
                    f"(ignore_joints:)")
            if i >= len(positions) or not np.isfinite(positions[i]):
                raise RecordingError(f"{where}: joint {name!r} has no finite position "
                                     f"({positions.tolist()[:12]})")
            kind, target = self.targets[name]
            if kind == "mimic":  # follows the leader, which gives the opening
                continue
            value = positions[i:i + 1].copy()
            if kind == "leader":
                value[0] = self.cell.robot(target).tool.opening_of(value[0])
            store = self.series if kind == "joint" else self.openings
            series = store.setdefault(target, Series(f"joint {name!r}"))
            series.add(ns, value, where)

    def signals(self, joint_topics: Iterable[str]) -> Signals:
        robots = {}
        for robot in self.cell.robots:
            names = [joint_name(robot.name, j) for j in robot.chain.joint_names]
            missing = [n for n in names if n not in self.series]
            if missing:
                raise RecordingError(
                    f"robot {robot.name}'s joints {', '.join(missing)} are in none of "
                    f"{', '.join(joint_topics)}; name them ROBOT/JOINT in the recording or map "
                    f"them in a topic map (--topics, joints:)")
            robots[robot.name] = names
        return Signals(self.series, robots, self.openings, self.truth)


def read_signals(recording: Recording, cell: Cell, topic_map: TopicMap,
                 truth_topics: dict[str, str]) -> Signals:
    """The joints, openings and true poses of a recording (one pass over their topics);
    ``truth_topics``: workpiece -> its pose topic (``PoseStamped``, ``TransformStamped`` or
    ``TFMessage``, in the cell's base frame: :mod:`.names`)."""
    reader = _SignalReader(cell, topic_map, truth_topics)
    for part, topic in truth_topics.items():
        kind = reader.kinds[topic] = recording.topics[topic].type
        if kind not in TRUTH_TYPES:
            raise RecordingError(f"recording {recording.path}: {topic} (the true pose of "
                                 f"{part}) is a {kind}; expected one of {', '.join(TRUTH_TYPES)}")
    topics = list(dict.fromkeys([*topic_map.joint_states, *truth_topics.values()]))
    for topic, log_ns, msg in recording.messages(topics):
        reader.add(topic, log_ns, msg)
    return reader.signals(topic_map.joint_states)

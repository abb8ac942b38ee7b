"""A recording's camera images as the tracker's frames.

:func:`resolve_topics` finds each camera's image topic (the topic map's, else
``/<cam>/image_raw`` or ``/<cam>/image_raw/compressed``), its optional ``camera_info`` (the
map's, else the one beside the image topic, as camera drivers publish it, else
``/<cam>/camera_info``) and the
workpieces' true-pose topics; a camera without images, or with both kinds, is one
:class:`~cellsight.recording.reader.RecordingError` that lists what the recording holds.

:class:`FrameGrouper` groups the images, in log-time order, into frames: the images of the
several cameras whose stamps lie within ``tolerance_s`` of the frame's first one. A frame is
complete when every camera has an image; an image of a camera the frame already has, or
stamped beyond the tolerance, starts the next frame (the cameras missing from the frame give
nothing in it). A frame's time ``t`` is its latest log time (when the tracker has the
images; never before an exposure), each camera's exposure its image's stamp. A camera whose
stamps go back is an error; so is a frame time that does not increase. Where the frames stop
for longer than 1.5 periods (the median interval so far), the missing frames (the gap over
the period, rounded) are given as frames without images, evenly spaced across the gap
(prediction steps), and each gap is reported; frames more than ``MAX_GAP_S`` apart are an
error (a stamp on another clock, or damaged: a gap of years would be filled for ever).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cellsight.camera import Camera
from cellsight.recording import names
from cellsight.recording.images import gray_image
from cellsight.recording.names import COMPRESSED, IMAGE, TopicMap
from cellsight.recording.reader import Recording, RecordingError
from cellsight.recording.series import stamp_ns

GAP_PERIODS = 1.5  # frames further apart than this many periods leave a gap
MIN_INTERVALS = 4  # intervals seen before gaps are judged
MAX_GAP_S = 60.0  # frames further apart than this are an error, not a gap


@dataclass(frozen=True)
class Topics:
    """Per camera (cell order) its image topic and type, and its camera-info topic (None: the
    recording has none) and the significant bits of its ``mono16`` images (None: not
    declared); per workpiece with one, its true-pose topic."""

    images: list[tuple[str, str]]
    camera_info: list[str | None]
    truth: dict[str, str]
    bits: list[int | None] = field(default_factory=list)


def _image_topic(recording: Recording, camera: str, topic_map: TopicMap) -> tuple[str, str]:
    chosen = topic_map.cameras.get(camera)
    candidates = [chosen] if chosen else [names.image_topic(camera),
                                          names.compressed_topic(camera)]
    found = [t for t in candidates if t in recording.topics]
    where = f"recording {recording.path}"
    if not found:
        raise RecordingError(f"{where}: no images of camera {camera} (looked for "
                             f"{' or '.join(candidates)}); it holds: {recording.listing()}; "
                             f"name the topic in a topic map (--topics, cameras:)")
    if len(found) > 1:
        raise RecordingError(f"{where}: camera {camera} has images on both {found[0]} and "
                             f"{found[1]}; choose one in a topic map (--topics, cameras:)")
    kind = recording.topics[found[0]].type
    if kind not in (IMAGE, COMPRESSED):
        raise RecordingError(f"{where}: {found[0]} (camera {camera}) holds {kind}; expected "
                             f"{IMAGE} or {COMPRESSED}")
    return found[0], kind


def _info_beside(image_topic: str) -> str:
    """The camera-info topic a camera driver publishes beside its images: ``/ns/camera_info``
    for ``/ns/image_raw`` (or ``/ns/image_raw/compressed``, ``/ns/image_rect``, ...)."""
    base = image_topic.removesuffix("/compressed")
    return f"{base.rsplit('/', 1)[0]}/camera_info"


def resolve_topics(recording: Recording, cameras: list[Camera], parts: list[str],
                   topic_map: TopicMap) -> Topics:
    """Where the recording keeps each camera's images and info and the parts' true poses."""
    images = [_image_topic(recording, c.name, topic_map) for c in cameras]
    info = []
    for c, (image, _) in zip(cameras, images, strict=True):
        topic = topic_map.camera_info.get(c.name)
        if topic is not None and topic not in recording.topics:
            raise RecordingError(f"recording {recording.path}: no {topic} (camera_info of "
                                 f"{c.name} in the topic map); it holds: {recording.listing()}")
        found = [t for t in (topic, _info_beside(image), names.camera_info_topic(c.name))
                 if t in recording.topics]
        info.append(found[0] if found else None)
    for topic in topic_map.joint_states:
        if topic not in recording.topics:
            raise RecordingError(f"recording {recording.path}: no joint states on {topic}; it "
                                 f"holds: {recording.listing()}; name the topic in a topic map "
                                 f"(--topics, joint_states:)")
    truth = {}
    for part in parts:
        topic = topic_map.truth.get(part, names.truth_topic(part))
        if topic in recording.topics:
            truth[part] = topic
        elif part in topic_map.truth:
            raise RecordingError(f"recording {recording.path}: no {topic} (true pose of {part} "
                                 f"in the topic map); it holds: {recording.listing()}")
    return Topics(images, info, truth, [topic_map.bits.get(c.name) for c in cameras])


@dataclass
class Frame:
    """One frame for the tracker: time ``t`` (s from the recording's origin), per camera its
    image (None: none in this frame) and exposure stamp (s, same origin; None without image)."""

    t: float
    ns: int
    images: list[np.ndarray | None]
    stamps: list[float | None]


@dataclass
class Gap:
    """Frames missing between ``t_from`` and ``t_to`` (s): ``frames`` of them."""

    t_from: float
    t_to: float
    frames: int


@dataclass
class FrameGrouper:
    """Frames of a recording's images (module docstring); ``origin_ns``: the ROS time of
    ``t = 0``."""

    recording: Recording
    cameras: list[Camera]
    topics: Topics
    tolerance_s: float
    origin_ns: int
    gaps: list[Gap] = field(default_factory=list)
    _last_stamp: list[int | None] = field(default_factory=list)
    _counts: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._last_stamp = [None] * len(self.cameras)
        self._camera = {topic: c for c, (topic, _) in enumerate(self.topics.images)}

    def frames(self) -> Iterator[Frame]:
        """The frames in time order, the gaps' empty frames among them."""
        group: dict[int, tuple[int, int, Any]] = {}
        last: Frame | None = None
        intervals: list[float] = []
        for topic, log_ns, msg in self.recording.messages([t for t, _ in self.topics.images]):
            c = self._camera[topic]
            ns = self._stamp(c, topic, log_ns, msg)
            if group and (c in group or abs(ns - min(s for s, _, _ in group.values()))
                          > self.tolerance_s * 1e9):
                yield from self._emit(group, last, intervals)
                last, group = self._last, {}
            group[c] = (ns, log_ns, msg)
            if len(group) == len(self.cameras):
                yield from self._emit(group, last, intervals)
                last, group = self._last, {}
        if group:
            yield from self._emit(group, last, intervals)

    def _stamp(self, c: int, topic: str, log_ns: int, msg: Any) -> int:
        k = self._counts[topic] = self._counts.get(topic, 0) + 1
        ns = stamp_ns(msg, log_ns)
        before = self._last_stamp[c]
        if before is not None and ns <= before:
            raise RecordingError(f"{topic}, message {k}: stamp {ns / 1e9:.6f} s is not after "
                                 f"the camera's previous image ({before / 1e9:.6f} s); a "
                                 f"recording's stamps must not go backwards")
        self._last_stamp[c] = ns
        return ns

    def _emit(self, group: dict, last: Frame | None, intervals: list[float]) -> Iterator[Frame]:
        ns = max(max(s, log) for s, log, _ in group.values())
        frame = Frame((ns - self.origin_ns) / 1e9, ns, [None] * len(self.cameras),
                      [None] * len(self.cameras))
        for c, (stamp, _, msg) in group.items():
            topic, kind = self.topics.images[c]
            where = f"{topic}, message {self._counts[topic]}"
            cam = self.cameras[c]
            bits = self.topics.bits[c] if self.topics.bits else None
            frame.images[c] = gray_image(kind, msg, where, (cam.width, cam.height), bits)
            frame.stamps[c] = (stamp - self.origin_ns) / 1e9
        if last is not None:
            if frame.ns <= last.ns:
                raise RecordingError(f"recording {self.recording.path}: the frame at "
                                     f"{frame.t:.6f} s is not after the one before "
                                     f"({last.t:.6f} s)")
            yield from self._gap(last, frame, intervals)
            intervals.append(frame.t - last.t)
        self._last = frame
        yield frame

    def _gap(self, last: Frame, frame: Frame, intervals: list[float]) -> Iterator[Frame]:
        """Empty frames where the images stopped for longer than ``GAP_PERIODS`` periods; a
        :class:`RecordingError` where they stopped for longer than ``MAX_GAP_S``."""
        span = frame.t - last.t
        if span > MAX_GAP_S:
            raise RecordingError(f"recording {self.recording.path}: no images from "
                                 f"{last.t:.3f} s to {frame.t:.3f} s, {span:.4g} s (more than "
                                 f"{MAX_GAP_S:g} s): an image stamped on another clock, or "
                                 f"damaged? Track the parts before and after as two "
                                 f"recordings")
        if len(intervals) < MIN_INTERVALS:
            return
        period = float(np.median(intervals[-50:]))
        if span <= GAP_PERIODS * period:
            return
        missing = max(int(round(span / period)) - 1, 1)
        self.gaps.append(Gap(last.t, frame.t, missing))
        step_ns = (frame.ns - last.ns) / (missing + 1)
        for i in range(1, missing + 1):
            ns = last.ns + int(round(i * step_ns))
            yield Frame((ns - self.origin_ns) / 1e9, ns, [None] * len(self.cameras),
                        [None] * len(self.cameras))

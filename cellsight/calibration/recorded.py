"""``cellsight calibrate RECORDING``: the views of a calibration motion read from a recording
(MCAP or rosbag2, as ``cellsight track`` reads them), as a real cell's calibration gives them.

The recording holds each camera's images and ``/joint_states`` (the topics and the topic map
of ``cellsight track``: :mod:`cellsight.recording.names`). The images are grouped into frames
(:class:`~cellsight.recording.frames.FrameGrouper`) and a frame is taken as a pose of the board
when every robot's joints at its time equal those :data:`STILL_S` before it within
:data:`STILL_RAD` (the robot stood still: no motion blur, no lag between the encoders and the
image); the frames that follow at the same joints are the same pose again and are left out.
The robot that carries the board at a pose is the one that moved last before it (the largest
change between two joint states, at the last change since the pose before): each robot has its
turn, the others stand by or go home first.
Each camera's image of a pose gives a view when the board's corners are found in it
(:meth:`~cellsight.calibration.board.Board.detect`, at least
:data:`~cellsight.calibration.shoot.MIN_CORNERS`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cellsight.calibration.board import Board
from cellsight.calibration.shoot import MIN_CORNERS
from cellsight.calibration.solution import View
from cellsight.model import Cell
from cellsight.recording.frames import FrameGrouper, resolve_topics
from cellsight.recording.names import TopicMap
from cellsight.recording.reader import Recording, RecordingError
from cellsight.recording.series import Signals, read_signals

STILL_S = 0.3
"""Seconds the joints must have stood still before a frame for it to be a pose."""
STILL_RAD = 2e-3
"""The largest change of any joint (rad, or m for a prismatic joint) that is standing still."""


@dataclass
class RecordedMotion:
    """What a recording's calibration motion gave: the ``views``, the poses taken per robot,
    the image frames read and those left out as the robots moved."""

    views: list[View] = field(default_factory=list)
    poses: dict[str, int] = field(default_factory=dict)
    frames: int = 0
    moving: int = 0


def _largest_change(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> dict[str, float]:
    return {robot: float(np.max(np.abs(a[robot] - b[robot]), initial=0.0)) for robot in a}


def _last_mover(signals: Signals, after_ns: int, until_ns: int) -> str | None:
    """The robot whose joints changed last between ``after_ns`` and ``until_ns`` (by more
    than :data:`STILL_RAD` from one joint state to the next; the largest change when several
    changed at once), or None when none did."""
    times = sorted({t for series in signals.joints.values() for t in series.ns
                    if after_ns <= t <= until_ns})
    states = [signals.joints_at(t)[0] for t in times]
    for before, now in zip(states[::-1][1:], states[::-1][:-1], strict=True):
        changed = _largest_change(now, before)
        mover = max(changed, key=changed.get)
        if changed[mover] > STILL_RAD:
            return mover
    return None


def recorded_views(recording: Recording, cell: Cell, board: Board, topic_map: TopicMap,
                   tolerance_s: float) -> RecordedMotion:
    """The views of the calibration motion in ``recording`` (module docstring);
    ``tolerance_s``: the images of one frame lie within it (as ``cellsight track
    --sync-tolerance``)."""
    topics = resolve_topics(recording, list(cell.cameras), [], topic_map)
    signals = read_signals(recording, cell, topic_map, {})
    start = recording.span_ns[0]
    grouper = FrameGrouper(recording, list(cell.cameras), topics, tolerance_s,
                           start - start % 1_000_000_000)
    motion, last_ns, last_pose = RecordedMotion(), start, None
    for frame in grouper.frames():
        if all(image is None for image in frame.images):
            continue
        motion.frames += 1
        joints, _ = signals.joints_at(frame.ns)
        before, _ = signals.joints_at(frame.ns - int(STILL_S * 1e9))
        if max(_largest_change(joints, before).values()) > STILL_RAD:
            motion.moving += 1
            continue
        if last_pose is not None and max(_largest_change(joints, last_pose).values()) \
                <= STILL_RAD:
            continue  # the same pose again
        holder = _last_mover(signals, last_ns, frame.ns)
        if holder is None:
            raise RecordingError(f"recording {recording.path}: no robot moved before the image "
                                 f"frame at {frame.t:.3f} s: which robot carries the board is "
                                 f"told by its motion")
        last_ns, last_pose = frame.ns, joints
        pose = motion.poses.get(holder, 0)
        motion.poses[holder] = pose + 1
        for camera, image in enumerate(frame.images):
            if image is None:
                continue
            ids, pixels = board.detect(image)
            if len(ids) >= MIN_CORNERS:
                motion.views.append(View(camera, holder, pose, joints[holder], ids, pixels))
    _check_seen(recording, cell, board, motion)
    return motion


def _check_seen(recording: Recording, cell: Cell, board: Board, motion: RecordedMotion) -> None:
    """A :class:`RecordingError` naming each camera that found the board in none of the
    poses, and the board it looked for."""
    seen = {view.camera for view in motion.views}
    blind = [c.name for k, c in enumerate(cell.cameras) if k not in seen]
    if not blind:
        return
    poses = sum(motion.poses.values())
    raise RecordingError(
        f"recording {recording.path}: camera {' and '.join(blind)} found the board in none of "
        f"the {poses} poses (frames where the robots stood still; {motion.moving} frames in "
        f"motion left out): the board looked for ({board.squares[0]} x {board.squares[1]} "
        f"squares of {board.square_m * 1e3:g} mm, markers {board.marker_m * 1e3:g} mm, "
        f"{board.dictionary}) may not be the one in the images (--board FILE), or the "
        f"camera never saw it")

"""``cellsight track``: the tracker over a recording, into a run folder.

:class:`RecordingSource` is a run session's source (:mod:`cellsight.session`): per frame of
the recording (:mod:`.frames`), every robot's joints and jaw openings at the frame's time
(:mod:`.series`), the images and their exposure stamps, and the part's recorded true pose
where there is one; the session steps the tracker of ``cellsight run``
(:mod:`cellsight.session.measured`, built on the cell, with the recording's calibration where
asked: :mod:`.calibration`). No robot is driven and no task runs: the frames' phase is
``recorded``.

Written into the output folder as it goes, the files of a ``cellsight run`` folder:
``frames.csv`` (the same columns; the ``q_*`` columns and the gripper's hold the recorded
joints; where the recording has the part's true pose, the ``true_*`` columns hold it and
``vis_true``/``occ_true``/``wrong`` are the cell's geometry seen at it, else they are empty),
``run.log`` (what was read, each gap, each hold of the joints), ``run_cell.yaml``; at the
end ``report.html`` and ``metrics.json`` (the figures of ``cellsight run`` where the truth
allows, and the recording's facts: its file, the time origin, the frames, gaps and holds). A
bad recording is one :class:`~cellsight.recording.reader.RecordingError`, raised before any
frame is tracked where the checks allow, and otherwise after the frames before it are written
(the metrics then say ``error``). SIGINT and SIGTERM end the tracking at the next frame, the
report and the metrics written (``"interrupted": true`` and the ``signal``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cellsight.errors import CellsightError
from cellsight.export.live import LiveSink, parse_address
from cellsight.model.cell import Cell, Workpiece
from cellsight.model.loader import load_cell
from cellsight.recording.calibration import checked_cell
from cellsight.recording.frames import Frame, FrameGrouper, resolve_topics
from cellsight.recording.names import TopicMap, load_topic_map
from cellsight.recording.reader import Recording, RecordingError, open_recording
from cellsight.recording.series import Signals, read_signals
from cellsight.runfolder import FrameLog, cell_digest
from cellsight.session.frames import SourceFrame
from cellsight.session.measured import PHASE, MeasuredCell, measured_parts
from cellsight.session.protocols import FrameSink, Priors
from cellsight.session.run import RunSession
from cellsight.trackers import DEFAULT_TRACKER, TrackerChoice
from cellsight.tracking.records import PartFrame

log = logging.getLogger(__name__)

HOLD_WARN_S = 0.1  # joints held this long past their samples are reported
CLOCK_GAP_S = 1.0  # the first image this far from every joint sample: another clock
TRUTH_HOLD_S = 0.05  # a true pose further than this from its samples is no truth


@dataclass
class TrackOptions:
    """How to track: ``topics`` a topic map file (None: the conventions); ``tolerance_s``:
    images of several cameras within it form one frame; ``calibration_from_bag``: the
    recording's CameraInfo replaces the cell's intrinsics; ``part``: the workpiece logged
    (default the cell's first); ``tracker``: the tracker, as in ``cellsight run``
    (:class:`~cellsight.trackers.TrackerChoice`): the ``kinematic`` one registers each
    camera to the gripper from the recorded images, joints and jaw openings, at HOME and by the
    part (:mod:`cellsight.tracking.registration`), and keeps the part where the gripper holds
    it while the recorded jaws stand at its grasp's opening, else on what it lies on
    (:mod:`cellsight.tracking.prior`); ``live``: ``[HOST:]PORT`` to stream the tracking to
    Foxglove (:mod:`cellsight.export.live`)."""

    topics: str | Path | None = None
    tolerance_s: float = 0.019
    calibration_from_bag: bool = False
    part: str | None = None
    tracker: TrackerChoice = DEFAULT_TRACKER
    overwrite: bool = False
    progress: bool = True
    live: str | None = None


@dataclass
class TrackResult:
    """What was tracked: the run folder, its metrics, the frames (``gaps`` of them empty)."""

    out: Path
    metrics: dict
    frames: int = 0
    gaps: list = field(default_factory=list)


class RecordingSource:
    """The frames of one recording on the cell ``cell`` (module docstring): a run session's
    source (:class:`~cellsight.session.protocols.FrameSource`)."""

    def __init__(self, cell: Cell, recording: Recording, options: TrackOptions,
                 topic_map: TopicMap) -> None:
        self.recording, self.options, self.topic_map = recording, options, topic_map
        self.part = _workpiece(cell, options.part)
        self.topics = resolve_topics(recording, list(cell.cameras),
                                     [p.name for p in cell.workpieces], topic_map)
        self.cell, self.calibration = checked_cell(cell, recording, self.topics.camera_info,
                                                   options.calibration_from_bag)
        self.signals: Signals = read_signals(recording, self.cell, topic_map, self.topics.truth)
        self.measured = MeasuredCell(self.cell, self.part, options.tracker.kinematic)
        self.robot = self.measured.robot
        start = recording.span_ns[0]
        self.origin_ns = start - start % 1_000_000_000  # the whole second of the first message
        self.grouper = FrameGrouper(recording, list(self.cell.cameras), self.topics,
                                    options.tolerance_s, self.origin_ns)
        self.held_s = 0.0
        self._t = 0.0

    def begin(self) -> None:
        log.info("tracking %s with cell %s", self.recording.path, self.cell.source)
        for line in self.calibration:
            log.info("%s", line)
        for robot in self.cell.robots:
            if robot.tool is not None and robot.name not in self.signals.openings:
                log.warning("%s: no jaw opening in the recording; the predictor takes the "
                            "gripper's jaws open%s", robot.name,
                            "; the kinematic tracker registers no camera without it"
                            if self.measured.registers and robot is self.robot else "")

    def progress(self) -> tuple[str, float]:
        return "tracking", (self.recording.span_ns[1] - self.origin_ns) / 1e9

    def time(self) -> float:
        return self._t

    def frames(self) -> Iterator[SourceFrame]:
        for k, frame in enumerate(self.grouper.frames()):
            self._t = frame.t
            yield self._frame(k, frame)

    def _frame(self, k: int, frame: Frame) -> SourceFrame:
        joints, held = self.signals.joints_at(frame.ns)
        if k == 0 and held > CLOCK_GAP_S:
            spans = [(s.ns[0], s.ns[-1]) for s in self.signals.joints.values() if len(s.ns)]
            first, last = (min(a for a, _ in spans), max(b for _, b in spans))
            raise RecordingError(
                f"recording {self.recording.path}: the joint states ("
                f"{', '.join(self.topic_map.joint_states)}) are stamped from "
                f"{(first - self.origin_ns) / 1e9:.3f} to {(last - self.origin_ns) / 1e9:.3f} s, "
                f"the first image at {frame.t:.3f} s ({held:.1f} s from the nearest joint "
                f"sample): are they stamped on another clock?")
        if held > HOLD_WARN_S and held > self.held_s + HOLD_WARN_S:
            log.warning("t = %.3f s: joints held %.3f s past their last sample", frame.t, held)
        self.held_s = max(self.held_s, held)
        openings = self.signals.openings_at(frame.ns)
        truth = self.measured.truth(joints, openings, self.signals.truth_at(
            self.part.name, frame.ns, TRUTH_HOLD_S))
        return SourceFrame(k, frame.t, frame.images, frame.stamps, joints, openings, truth)

    def priors(self, frame: SourceFrame, estimate: np.ndarray | None) -> Priors:
        return self.measured.priors(frame, estimate)

    def tracked(self, frame: SourceFrame, part: PartFrame) -> tuple[str, str]:
        """No task runs on a recording."""
        return PHASE, ""

    def close(self) -> None:
        for gap in self.grouper.gaps:
            log.warning("gap: no images from %.3f s to %.3f s (%d missing frame(s)); the tracker "
                        "predicted through it", gap.t_from, gap.t_to, gap.frames)

    def facts(self, frames: FrameLog) -> dict:
        """The recording's facts for ``metrics.json``."""
        return {"description": f"tracked from recording {self.recording.path.name}",
                "sensor": "recorded",
                "recording": str(self.recording.path),
                "recording_topics": {
                    "images": [t for t, _ in self.topics.images],
                    "camera_info": self.topics.camera_info, "truth": self.topics.truth},
                "time_origin_ns": self.origin_ns, "frames_tracked": frames.n,
                "gaps": [[round(g.t_from, 4), round(g.t_to, 4), g.frames]
                         for g in self.grouper.gaps],
                "frames_dropped": sum(g.frames for g in self.grouper.gaps),
                "joints_held_s": round(self.held_s, 4),
                "calibration": self.calibration,
                "truth": "the recorded pose; vis_true: the cell's geometry at it"
                         if self.topics.truth else None}


def _workpiece(cell: Cell, name: str | None) -> Workpiece:
    """The workpiece ``name`` of the cell (None: its first), or one error naming them."""
    if name is None:
        return cell.workpieces[0]
    try:
        return cell.workpiece(name)
    except KeyError as exc:
        raise RecordingError(f"--part: {exc.args[0]}") from None


def recorded_cell(rec: Recording) -> Cell | None:
    """The cell a cellsight recording names in its metadata (``cell``, checked against its
    ``cell_sha256``), None when it names none; a named cell that is gone or changed since is a
    :class:`RecordingError` saying to pass ``--cell``."""
    facts = rec.metadata("cellsight")
    source = facts.get("cell")
    if not source:
        return None
    try:
        cell = load_cell(source)
    except CellsightError as exc:
        raise RecordingError(f"recording {rec.path}: made with the cell {source!r}, which "
                             f"cannot be loaded here ({exc}); pass --cell NAME|FILE") from None
    recorded, now = facts.get("cell_sha256"), cell_digest(cell)
    if recorded and now and recorded != now:
        raise RecordingError(f"recording {rec.path}: made with the cell {source!r}, which has "
                             f"changed since (its SHA-256 differs from the recording's); pass "
                             f"--cell NAME|FILE to track with it anyway")
    log.info("the cell from the recording: %s", source)
    return cell


def track_recording(cell: str | Path | Cell | None, recording: str | Path, out: str | Path,
                    options: TrackOptions | None = None,
                    sinks: Sequence[FrameSink] = ()) -> TrackResult:
    """Track the workpieces through ``recording`` with the cell ``cell`` (a built-in cell's
    name, a cell file or a loaded cell; None: the cell a cellsight recording names, checked by
    its SHA-256, else the built-in cell) into the folder ``out`` (module docstring), each
    frame's record to ``sinks`` too (:mod:`cellsight.session`). Returns the folder and its
    metrics."""
    options = options or TrackOptions()
    if not (options.tolerance_s > 0 and np.isfinite(options.tolerance_s)):
        raise RecordingError(f"--sync-tolerance: expected a positive number of seconds, got "
                             f"{options.tolerance_s!r}")
    if options.live is not None:
        parse_address(options.live)
    session = RunSession(out, options.overwrite, options.progress)
    topic_map = load_topic_map(options.topics)
    with open_recording(recording) as rec:
        named = recorded_cell(rec) if cell is None else None
        assumed = cell is None and named is None
        cell = cell if isinstance(cell, Cell) else (named if named is not None else load_cell(cell))
        topic_map.check(cell)
        try:
            source = RecordingSource(cell, rec, options, topic_map)
        except RecordingError as exc:
            if assumed:  # the likely cause: another cell's recording
                raise RecordingError(f"{exc} (no --cell given, and the recording names none: "
                                     f"the built-in cell was assumed; pass --cell NAME|FILE, "
                                     f"the recording's cell)") from exc
            raise
        live = [] if options.live is None else [LiveSink(options.live, paced=True)]
        metrics = session.run(measured_parts(source, source.measured, options.tracker,
                                             [*live, *sinks]))
        return TrackResult(Path(out), metrics, session.frames, source.grouper.gaps)

"""``cellsight track``: the tracker over a recording, into a run folder.

Per frame of the recording (:mod:`.frames`): every robot's joints and jaw openings at the
frame's time (:mod:`.series`), the images and their exposure stamps into
:meth:`~cellsight.tracking.tracker.Tracker.step` (the tracker of ``cellsight run``:
:func:`~cellsight.tracking.setup.build_tracker`, built on the cell, with the recording's
calibration where asked: :mod:`.calibration`). No robot is driven and no task runs: the
frames' phase is ``recorded``.

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
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from cellsight.control.task import TaskTolerances
from cellsight.errors import CellsightError
from cellsight.experiments.baseline import PnPBaseline
from cellsight.experiments.metrics import frame_metrics
from cellsight.experiments.rows import FrameRows, FrameTruth, PartTruth
from cellsight.experiments.runner import StopSignals
from cellsight.export.live import LiveStream, parse_address
from cellsight.model.cell import Cell, Workpiece
from cellsight.model.grasp import grasp_opening, grasp_pose
from cellsight.model.landing import Landing
from cellsight.model.loader import load_cell
from cellsight.model.robot import Robot
from cellsight.occlusion.predictor import VisibilityPredictor
from cellsight.recording.calibration import checked_cell
from cellsight.recording.frames import Frame, FrameGrouper, resolve_topics
from cellsight.recording.names import TopicMap, load_topic_map
from cellsight.recording.reader import Recording, RecordingError, open_recording
from cellsight.recording.series import Signals, read_signals
from cellsight.report.run_report import write_report
from cellsight.runfolder import (
    FrameLog,
    FrameWriter,
    RunWrites,
    cell_digest,
    check_out_folder,
    checked_metrics,
    keep_cell,
    make_out_folder,
    write_metrics,
)
from cellsight.runfolder.writes import log_to, stop_logging_to
from cellsight.trackers import DEFAULT_TRACKER, TrackerChoice
from cellsight.tracking.prior import KinematicPrior, RecordedGrasp
from cellsight.tracking.registration import RegistrationRule
from cellsight.tracking.setup import build_tracker, tracker_facts

log = logging.getLogger(__name__)

PHASE = "recorded"
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


class _Session:
    """One recording tracked into one folder (module docstring)."""

    def __init__(self, cell: Cell, recording: Recording, out: Path, options: TrackOptions,
                 topic_map: TopicMap) -> None:
        self.recording, self.out, self.options = recording, out, options
        self.topic_map = topic_map
        self.part = _workpiece(cell, options.part)
        self.topics = resolve_topics(recording, list(cell.cameras),
                                     [p.name for p in cell.workpieces], topic_map)
        self.cell, self.calibration = checked_cell(cell, recording, self.topics.camera_info,
                                                   options.calibration_from_bag)
        self.signals: Signals = read_signals(recording, self.cell, topic_map, self.topics.truth)
        robot = next((r for r in self.cell.robots if r.tool is not None), self.cell.robots[0])
        self.robot = robot
        register = options.tracker.kinematic and robot.tool is not None
        self.tracker = build_tracker(self.cell, options.tracker, awaiting_registration=register)
        self.baseline = PnPBaseline.of(self.tracker, self.part.feature_points)
        self.truth_views = VisibilityPredictor(self.cell)
        self.registration = (RegistrationRule().registration(self.cell, robot.name)
                             if register else None)
        self._estimate: np.ndarray | None = None  # the part's last estimated pose
        self.prior = _prior(self.cell, robot, self.part) if options.tracker.kinematic else None
        self.rows = FrameRows(robot, len(self.cell.cameras), pixel_errors=True)
        start = recording.span_ns[0]
        self.origin_ns = start - start % 1_000_000_000  # the whole second of the first message
        self.grouper = FrameGrouper(recording, list(self.cell.cameras), self.topics,
                                    options.tolerance_s, self.origin_ns)
        self.frames = 0
        self.held_s = 0.0
        self.live: LiveStream | None = None
        self.stop = StopSignals()

    def run(self, writer: FrameWriter, writes: RunWrites) -> None:
        for line in self.calibration:
            log.info("%s", line)
        for robot in self.cell.robots:
            if robot.tool is not None and robot.name not in self.signals.openings:
                log.warning("%s: no jaw opening in the recording; the predictor takes the "
                            "gripper's jaws open%s", robot.name,
                            "; the kinematic tracker registers no camera without it"
                            if self.registration is not None and robot is self.robot else "")
        span = (self.recording.span_ns[1] - self.origin_ns) / 1e9
        with _progress(self.options.progress) as bar:
            task = bar.add_task("tracking", total=max(span, 1e-9))
            pace = _Pace() if self.live is not None else None
            for frame in self.grouper.frames():
                if self.stop.name is not None:
                    log.warning("interrupted by %s at t = %.2f s", self.stop.name, frame.t)
                    break
                if pace is not None:  # a viewer watches at the recording's own pace
                    pace.wait(frame.t)
                row = self._frame(frame)
                with writes.guard(writer.path):
                    writer.write(row)
                self.frames += 1
                bar.update(task, completed=frame.t)
        for gap in self.grouper.gaps:
            log.warning("gap: no images from %.3f s to %.3f s (%d missing frame(s)); the tracker "
                        "predicted through it", gap.t_from, gap.t_to, gap.frames)

    def _frame(self, frame: Frame) -> dict:
        joints, held = self.signals.joints_at(frame.ns)
        if self.frames == 0 and held > CLOCK_GAP_S:
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
        if self.registration is not None and self.robot.name in openings:
            part_at = None if self._estimate is None else self._estimate[:3, 3]
            self.registration.feed(self.tracker, frame.t, frame.images, joints, openings,
                                   frame.stamps, part_at)
        holders, supports = None, None
        if self.prior is not None:
            grasp, prior = self.prior
            holders, supports = prior.update(grasp.held_at(
                joints[self.robot.name], openings.get(self.robot.name), self._estimate))
        result = self.tracker.step(frame.images, joints, frame.t, openings or None, holders,
                                   stamps=frame.stamps, supports=supports)
        rec = result.parts[self.part.name]
        self._estimate = rec.T_base_part if rec.status.has_estimate else None
        T_true = self.signals.truth_at(self.part.name, frame.ns, TRUTH_HOLD_S)
        part_truth = None
        if T_true is not None:
            views = self.truth_views.predict(joints, {self.part.name: T_true}, openings)
            part_truth = PartTruth(T_true, views[self.part.name])
        opening = openings.get(self.robot.name, float("nan"))
        truth = FrameTruth(part_truth, joints, opening, False, False)
        pnp = self.baseline.update(frame.t, rec.measured)
        if self.live is not None:
            self.live.frame(frame.t, joints, rec, result.unknown, frame.images, T_true)
        return self.rows.row(frame.t, PHASE, "", result, rec, truth, pnp)

    def facts(self) -> dict:
        """The recording's facts for ``metrics.json``."""
        return {"recording": str(self.recording.path),
                "recording_topics": {
                    "images": [t for t, _ in self.topics.images],
                    "camera_info": self.topics.camera_info, "truth": self.topics.truth},
                "time_origin_ns": self.origin_ns, "frames_tracked": self.frames,
                "gaps": [[round(g.t_from, 4), round(g.t_to, 4), g.frames]
                         for g in self.grouper.gaps],
                "frames_dropped": sum(g.frames for g in self.grouper.gaps),
                "joints_held_s": round(self.held_s, 4),
                "calibration": self.calibration,
                "registration": None if self.registration is None else
                self.registration.record(),
                "kinematic_prior": self.prior is not None,
                "truth": "the recorded pose; vis_true: the cell's geometry at it"
                         if self.topics.truth else None}


def _prior(cell: Cell, robot: Robot, part: Workpiece) -> tuple[RecordedGrasp,
                                                                KinematicPrior] | None:
    """The kinematic prior of ``part`` grasped by ``robot`` from a recording's joints and jaw
    openings (:mod:`cellsight.tracking.prior`; the task's grasp and tolerance), or None, with a
    warning, where the robot has no gripper or its jaws would close on no material at the
    part's grasp."""
    T_part_tcp = None if robot.tool is None else grasp_pose(part, robot.tool)
    opening = None if robot.tool is None else grasp_opening(part.solid, robot.tool, T_part_tcp)
    if opening is None:
        log.warning("the kinematic tracker: %s's jaws close on no material of %s at its grasp; "
                    "no kinematic prior", robot.name, part.name)
        return None
    grasp = RecordedGrasp(robot, part, T_part_tcp, opening, TaskTolerances().opening)
    return grasp, KinematicPrior(part, Landing(cell.static))


def _workpiece(cell: Cell, name: str | None) -> Workpiece:
    """The workpiece ``name`` of the cell (None: its first), or one error naming them."""
    if name is None:
        return cell.workpieces[0]
    try:
        return cell.workpiece(name)
    except KeyError as exc:
        raise RecordingError(f"--part: {exc.args[0]}") from None


class _Pace:
    """Waits until the wall clock has moved on as far as the recording since its first
    frame."""

    def __init__(self) -> None:
        self._start: tuple[float, float] | None = None  # (wall clock, recording time) s

    def wait(self, t: float) -> None:
        now = time.monotonic()
        if self._start is None:
            self._start = (now, t)
        time.sleep(max(0.0, (t - self._start[1]) - (now - self._start[0])))


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


def _progress(enabled: bool) -> Progress:
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                    TextColumn("t = {task.completed:6.2f} / {task.total:.2f} s"),
                    TimeElapsedColumn(), disable=not enabled, transient=False)


def track_recording(cell: str | Path | Cell | None, recording: str | Path, out: str | Path,
                    options: TrackOptions | None = None) -> TrackResult:
    """Track the workpieces through ``recording`` with the cell ``cell`` (a built-in cell's
    name, a cell file or a loaded cell; None: the cell a cellsight recording names, checked by
    its SHA-256, else the built-in cell) into the folder ``out`` (module docstring). Returns
    the folder and its metrics."""
    options = options or TrackOptions()
    if not (options.tolerance_s > 0 and np.isfinite(options.tolerance_s)):
        raise RecordingError(f"--sync-tolerance: expected a positive number of seconds, got "
                             f"{options.tolerance_s!r}")
    if options.live is not None:
        parse_address(options.live)
    out = Path(out)
    stale = check_out_folder(out, options.overwrite, "--out", "--overwrite")
    topic_map = load_topic_map(options.topics)
    with open_recording(recording) as rec:
        named = recorded_cell(rec) if cell is None else None
        assumed = cell is None and named is None
        cell = cell if isinstance(cell, Cell) else (named if named is not None else load_cell(cell))
        topic_map.check(cell)
        try:
            session = _Session(cell, rec, out, options, topic_map)
        except RecordingError as exc:
            if assumed:  # the likely cause: another cell's recording
                raise RecordingError(f"{exc} (no --cell given, and the recording names none: "
                                     f"the built-in cell was assumed; pass --cell NAME|FILE, "
                                     f"the recording's cell)") from exc
            raise
        make_out_folder(out, stale, "--out")
        writes = RunWrites(out)
        cell_files = keep_cell(out, cell)
        return _tracked(session, writes, cell_files)


def _tracked(session: _Session, writes: RunWrites, cell_files: dict) -> TrackResult:
    """Run the session, logging, then write the report and the metrics (also on failure)."""
    out = session.out
    handler = log_to(writes)
    log.info("tracking %s with cell %s into %s", session.recording.path, session.cell.source,
             out)
    writer = FrameWriter(out / "frames.csv", len(session.cell.cameras),
                         {r.name: r.n_joints for r in session.cell.robots})
    wall = time.perf_counter()
    error: BaseException | None = None
    if session.options.live is not None:
        session.live = LiveStream(session.cell, session.part.name,
                                  *parse_address(session.options.live))
    try:
        with session.stop:
            session.run(writer, writes)
    except BaseException as exc:
        error = exc
        log.error("failed after %d frames: %s: %s", session.frames, type(exc).__name__, exc)
        raise
    finally:
        if session.live is not None:
            session.live.close()
        writes.close(writer.path, writer.close)
        metrics = _metrics(session, cell_files, time.perf_counter() - wall, error)
        stop_logging_to(handler, writes)
        write_report(out, metrics)
        metrics = write_metrics(out, metrics)
    return TrackResult(out, metrics, session.frames, session.grouper.gaps)


def _metrics(session: _Session, cell_files: dict, wall_s: float,
             error: BaseException | None) -> dict:
    frames = FrameLog.read(session.out / "frames.csv")
    cell = session.cell
    metrics = {"description": f"tracked from recording {session.recording.path.name}",
               "cell": cell.source, "cell_sha256": cell_digest(cell), "cell_files": cell_files,
               "sensor": "recorded", **tracker_facts(session.options.tracker),
               **session.facts(), **frame_metrics(frames), "wall_s": round(wall_s, 2),
               "interrupted": isinstance(error, KeyboardInterrupt) or bool(session.stop.name),
               **({"signal": session.stop.name} if session.stop.name else {}),
               "cameras": [c.name for c in cell.cameras],
               "features": len(session.part.feature_points), "robot": session.robot.name,
               "workpiece": session.part.name,
               "t_end_s": round(float(frames.floats("t")[-1]), 3) if frames.n else 0.0}
    if error is not None and not isinstance(error, KeyboardInterrupt):
        metrics["error"] = f"{type(error).__name__}: {error}"[:1000]
    log.info("tracked %d frames in %.1f s", session.frames, wall_s)
    return checked_metrics(session.out, metrics)

"""Run one of the paper's experiments end to end: world, tracker, task, control.

The loop only wires them. Per vision frame (``VISION_HZ``): the world's images (or, for the
ideal sensor, the true projections), joint measurements and jaw openings ->
:class:`~cellsight.tracking.Tracker` (BSP occlusion prediction at the predicted pose, selection,
windows, extraction, EKF) -> the grasping task's trajectory planner; between frames, the
``CONTROL_HZ`` control loop (interpolating filter + CLIK) drives the world. The world departs
from the cell file by the run's realism profile (:mod:`cellsight.realism`: its own cell and
imperfections, drawn from the seed): a camera may be exposed before the frame's time (its
trigger skew, :mod:`.exposure`), a frame may be dropped (no images), and its estimate reaches
the planner after the frame's latency (:mod:`.latency`), stamped with its exposure time. The
world is seen through :class:`~cellsight.experiments.plant.SimulatedCell` (the simulated
:class:`~cellsight.world.World` by default).

Written into the output directory (:mod:`cellsight.runfolder`) as the run goes:
``frames.csv`` (:mod:`cellsight.runfolder.framelog`, rows from :mod:`.rows`, with the PnP
baseline of :mod:`.baseline`), ``run.log`` (phase transitions, occlusion events and the grasp:
:mod:`.monitors`; the summary), ``keyframes.json`` + ``keyframes/*.png`` (:mod:`.keyframes`),
``views.mp4`` (rendered sensor); with ``record``, an MCAP file of the sensor data as a real cell
records it (:mod:`cellsight.recording.recorder`); with ``live``, a Foxglove WebSocket stream
(:mod:`cellsight.export.live`). After the loop (also when interrupted or failed), two steps
that read the log: ``report.html`` (:mod:`cellsight.report.run_report`), then, last and whole,
``metrics.json`` (:mod:`cellsight.experiments.metrics` plus the run's facts: the realism
profile and every draw, the structure, the collisions, the dropped frames).

Every file goes through :class:`~cellsight.runfolder.writes.RunWrites`: a failed write (a full
disk) ends the loop like any exception, or, for ``run.log``, a picture or the end of a file, is
recorded; either way the metrics' ``error`` names the file and why, so that a sweep never
reuses the run, and :meth:`ExperimentRun.run` raises the first failure
(:class:`~cellsight.runfolder.writes.WriteError`) once it has written what it could. When
``metrics.json`` itself cannot be written there is none: never one claiming success.

The output folder must be new or empty; with ``overwrite`` it is cleared first, but only when it
holds nothing but an earlier run's outputs (:func:`check_out_folder`). SIGINT and SIGTERM end
the loop at the next frame boundary (:class:`StopSignals`): the metrics then say
``"interrupted": true`` and which signal; an exception is recorded as ``"error"``.
"""

from __future__ import annotations

import json
import logging
import math
import signal
import threading
import time
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from rich.progress import BarColumn, Progress, TextColumn

from cellsight.calibration.folder import calibrated_cell, read_calibration
from cellsight.control import GraspTask, Phase
from cellsight.control.task import grasp_miss, last_setback
from cellsight.errors import CellsightError
from cellsight.experiments.baseline import PnPBaseline
from cellsight.experiments.exposure import Exposures
from cellsight.experiments.identity import run_identity
from cellsight.experiments.keyframes import KeyFrames, draw_frame
from cellsight.experiments.latency import Deliveries, Estimate
from cellsight.experiments.metrics import frame_metrics, position_rmse_in_arm_frame_mm
from cellsight.experiments.monitors import (
    GraspMonitor,
    KidnapMonitor,
    OcclusionEvents,
    knock_record,
)
from cellsight.experiments.plant import SimulatedCell
from cellsight.experiments.rows import FrameRows, FrameTruth, PartTruth
from cellsight.experiments.scenario import Scenario, scenario
from cellsight.experiments.sensors import IdealExtractor
from cellsight.experiments.views_video import ViewsVideo
from cellsight.export.live import LiveStream, parse_address
from cellsight.export.mcap_run import check_jpeg, check_output
from cellsight.geometry.transforms import invert_pose, transform_points
from cellsight.model.cell import Cell
from cellsight.model.grasp import grasp_opening, grasp_pose
from cellsight.model.landing import Landing
from cellsight.model.loader import load_cell
from cellsight.model.robot import Robot
from cellsight.occlusion.predictor import OBJECT_BVH, STRUCTURES
from cellsight.rates import VISION_HZ
from cellsight.realism import FrameClock, Profile, draw_world
from cellsight.realism.draws import WorldDraws
from cellsight.recording.recorder import Recorder
from cellsight.report.run_report import write_report
from cellsight.runfolder import (
    FrameLog,
    FrameWriter,
    RunWrites,
    WriteError,
    cell_digest,
    check_out_folder,
    checked_metrics,
    keep_cell,
    make_out_folder,
    write_metrics,
)
from cellsight.runfolder.writes import log_to, stop_logging_to
from cellsight.trackers import DEFAULT_TRACKER, TrackerChoice
from cellsight.tracking.grabbing import grabbed
from cellsight.tracking.prior import KinematicPrior
from cellsight.tracking.records import PartFrame
from cellsight.tracking.registration import RegistrationRule
from cellsight.tracking.setup import build_tracker, tracker_facts
from cellsight.world import World

log = logging.getLogger(__name__)

Sensor = Literal["rendered", "ideal"]


@dataclass(frozen=True)
class RunConfig:
    """One run. ``duration`` (s of simulated time): None runs until the task is done (plus
    ``tail_s``), at most ``max_duration``. ``ideal_sigma_px``: pixel noise of the ideal
    sensor, per coordinate (0.2 px: the rendered sensor's corners lie a median 0.245 px from
    the true projection on the built-in cell, i.e. 0.21 px per coordinate).
    ``tracker``: the tracker (:class:`~cellsight.trackers.TrackerChoice`). The
    ``kinematic`` one (the default): while the jaws are closed on the part, it predicts it by
    the gripper's motion measured from the joints, and starts it where the gripper holds it (the
    grasp the task chose) when it is not tracked (``holders`` of :meth:`Tracker.step`); until
    the jaws first close on it, the part keeps the height, roll and pitch of the cell file's
    pose of it, lying on its conveyor or table (``supports``), and once they let it go, those
    of where it falls to from the gripper, onto the cell file's static objects; with the
    rendered sensor, the cameras are registered to the gripper at HOME and by the part
    (:mod:`cellsight.tracking.registration`). ``video_every``: a frame of ``views.mp4`` every so
    many vision frames. ``full_frames``: the rendered cameras render every frame whole, instead of
    only the region the tracker reads (:mod:`cellsight.world.shots`; the same pixels, see
    :mod:`cellsight.world.render`). ``overwrite``: clear ``out`` first when it holds an earlier run
    (:func:`check_out_folder`; else a non-empty ``out`` is refused). ``record``: an MCAP file
    to record the sensor data in as the run goes (:mod:`cellsight.recording.recorder`; the
    rendered sensor only), its images JPEG of quality ``record_jpeg`` (None: lossless); a
    recorded run renders whole frames, so that the tracker reads the very pixels recorded.
    ``live``: ``[HOST:]PORT`` of a Foxglove WebSocket server streaming the run as it happens
    (:mod:`cellsight.export.live`). ``calibration``: a folder of ``cellsight calibrate`` whose
    cameras and robot bases the tracker and the task use instead of the cell file's
    (:mod:`cellsight.calibration.folder`); the world is still the one the seed draws from the
    cell file."""

    experiment: int
    out: Path
    cell: Path | None = None
    seed: int = 0
    sensor: Sensor = "rendered"
    tracker: TrackerChoice = DEFAULT_TRACKER
    duration: float | None = None
    max_duration: float = 80.0
    tail_s: float = 1.0
    ideal_sigma_px: float = 0.2
    video_every: int = 2
    full_frames: bool = False
    progress: bool = True
    overwrite: bool = False
    realism: str | Path | Profile = "exact"
    structure: str = OBJECT_BVH
    record: Path | None = None
    record_jpeg: int | None = None
    live: str | None = None
    calibration: Path | None = None

    def __post_init__(self) -> None:
        check_jpeg(self.record_jpeg, "--record-jpeg")
        if self.live is not None:
            parse_address(self.live)
        if self.record is not None and self.sensor != "rendered":
            raise CellsightError("--record: the ideal sensor takes no images to record; use the "
                                 "rendered sensor")
        duration = self.duration
        if duration is not None and not (duration > 0 and math.isfinite(duration)):
            raise CellsightError(f"RunConfig.duration: expected a positive, finite number of "
                                 f"seconds, got {duration!r}")
        if self.seed < 0:
            raise CellsightError(f"RunConfig.seed: expected a whole number >= 0, got {self.seed}")
        if self.structure not in STRUCTURES:
            raise CellsightError(f"RunConfig.structure: expected one of {', '.join(STRUCTURES)}, "
                                 f"got {self.structure!r}")


class StopSignals:
    """SIGINT and SIGTERM while a run holds them (a context manager): the first one only
    records its name (:attr:`name`) for the loop to stop at the next frame boundary; later ones
    are ignored, so that the final writing (metrics, report) is never cut. The previous
    handlers come back on exit. Python sets handlers only in the main thread; elsewhere
    nothing is installed and the signals act as before."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.name: str | None = None
        self._previous: dict[int, object] = {}

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                self._previous[sig] = signal.signal(sig, self._record)
        return self

    def _record(self, signum: int, frame: object) -> None:
        if self.name is None:
            self.name = signal.Signals(signum).name

    def __exit__(self, *exc_info: object) -> None:
        for sig, previous in self._previous.items():
            signal.signal(sig, signal.SIG_DFL if previous is None else previous)
        self._previous.clear()


class ExperimentRun:
    """One experiment run (module docstring); :meth:`run` does it and returns the metrics.
    ``world``: the cell to run on (default: the simulated world of the scenario). The output
    folder is checked first (:func:`check_out_folder`), cleared and created last."""

    def __init__(self, config: RunConfig, world: SimulatedCell | None = None) -> None:
        self.config = config
        self.out = Path(config.out)
        stale = check_out_folder(self.out, config.overwrite)
        if config.record is not None:
            check_output(config.record, config.overwrite, self.out, "--record")
        self.stop = StopSignals()
        self.cell: Cell = load_cell(config.cell)
        self.draws = draw_world(config.realism, self.cell, config.seed)  # of the cell file
        if config.calibration is not None:  # the model side: what the calibration found
            self.cell = calibrated_cell(self.cell, config.calibration)
        self.scenario: Scenario = scenario(self.cell, config.experiment, self.draws.scenario)
        sc, cell = self.scenario, self.cell
        self.robot, self.part = sc.robot, sc.workpiece
        self.world: SimulatedCell = (
            world if world is not None
            else World(self.draws.cell, seed=config.seed, conveyor=sc.conveyor, tasks=sc.tasks,
                       errors=self.draws.errors))
        self.clock = FrameClock(self.draws.profile.timing, config.seed)
        self.deliveries = Deliveries()
        self.frames_dropped = 0
        self.prior = (KinematicPrior(sc.workpiece, Landing(cell.static))
                      if config.tracker.kinematic else None)  # :meth:`_priors`
        kidnap = self.draws.errors.kidnap
        self.kidnap = None if kidnap is None else KidnapMonitor(kidnap)
        self.exposures = Exposures(self.world, self.draws.trigger_skew_s, config.sensor == "ideal",
                                   self.part.name, config.full_frames or config.record is not None)
        self.ideal = (IdealExtractor(config.ideal_sigma_px, config.seed)
                      if config.sensor == "ideal" else None)
        register = config.tracker.kinematic and config.sensor == "rendered"
        self.tracker = build_tracker(cell, config.tracker, structure=config.structure,
                                     extractor=self.ideal, awaiting_registration=register)
        self.registration = (RegistrationRule().registration(cell, self.robot.name)
                             if register else None)
        self._part_at: np.ndarray | None = None  # the part's last estimated position (m)
        tool = self.robot.tool  # GraspTask names a robot without one
        self.task = GraspTask(self.robot, self.part, grasp_opening=None if tool is None else
                              grasp_opening(self.part.solid, tool, grasp_pose(self.part, tool)))
        self.baseline = PnPBaseline.of(self.tracker, self.part.feature_points)
        self.grasp = GraspMonitor(self.world, self.robot.name)
        self.events = OcclusionEvents([c.name for c in cell.cameras])
        self.rows = FrameRows(self.robot, len(cell.cameras), config.sensor == "rendered")
        self.crossing = next(iter(sc.tasks), None)
        self.writes = RunWrites(self.out)
        self.recorder: Recorder | None = None
        self.live: LiveStream | None = None
        self.metrics: dict | None = None  # made after the loop, written last (:meth:`_finish`)
        make_out_folder(self.out, stale)
        self.cell_files = keep_cell(self.out, cell)

    def run(self) -> dict:
        """Run the experiment; write everything; return the metrics. On SIGINT or SIGTERM the
        loop ends at the next frame boundary and the metrics say ``"interrupted": true`` and
        ``"signal"``; an exception is recorded (``"error"``) and then propagates. Either way
        ``report.html`` and then ``metrics.json`` are written, and signals during that are
        ignored. A failed write is recorded in the metrics and raised at the end (module
        docstring)."""
        handler = log_to(self.writes)
        with self.stop:
            try:
                self._run_logged()
            except BaseException:
                stop_logging_to(handler, self.writes)
                self._finish(failed=True)
                raise
            stop_logging_to(handler, self.writes)
            return self._finish(failed=False)

    def _finish(self, failed: bool) -> dict | None:
        """``report.html`` and its figures from the run's metrics, then ``metrics.json``, whole,
        its ``error`` naming every write that failed; returns the metrics written. ``failed``:
        the run ends by an exception, which the caller raises: nothing is raised here, a report
        that cannot be made is only logged. Otherwise the first failure is raised."""
        problem: Exception | None = None
        try:
            write_report(self.out, self.metrics)
        except WriteError as exc:
            self.writes.record(exc.path, exc)
        except Exception as exc:  # the report's own failure: recorded, never over the first
            self.writes.note(f"report.html: {type(exc).__name__}: {exc}")
            problem = exc
            if failed:
                log.warning("no report.html for %s: %s: %s", self.out, type(exc).__name__, exc)
        metrics = self.metrics
        if metrics is not None:
            error = self.writes.error(metrics.get("error"))
            try:
                metrics = write_metrics(self.out, {**metrics, "error": error} if error
                                        else metrics)
            except WriteError as exc:  # no metrics.json: the folder is not a finished run
                self.writes.record(exc.path, exc)
        if not failed and (problem or self.writes.first):
            raise problem or self.writes.first
        return metrics

    def _run_logged(self) -> None:
        cfg = self.config
        log.info("experiment %d (%s) on %s; seed %d; sensor %s; %s",
                 cfg.experiment, self.scenario.description, self.cell.source, cfg.seed,
                 cfg.sensor, cfg.tracker.describe())
        writer = FrameWriter(self.out / "frames.csv", len(self.cell.cameras),
                             {r.name: r.n_joints for r in self.cell.robots})
        recorder = None
        if cfg.record is not None:
            with self.writes.guard(cfg.record):
                recorder = self.recorder = Recorder(cfg.record, self.cell, self.part.name,
                                                    cfg.record_jpeg)
        live = None
        if cfg.live is not None:
            live = self.live = LiveStream(self.cell, self.part.name, *parse_address(cfg.live))
        video = None
        if cfg.sensor == "rendered" and cfg.video_every > 0:
            video = ViewsVideo(self.out / "views.mp4", VISION_HZ / cfg.video_every,
                               self.cell.cameras, self.part.name)
        with self.writes.guard(self.out / "keyframes"):
            keys = KeyFrames(self.out, [c.name for c in self.cell.cameras], self.robot.name,
                             self.crossing)
        wall = time.perf_counter()
        ending: dict = {"interrupted": True}
        try:
            self._loop(writer, video, keys)
            ending = self._ending(None)
        except BaseException as exc:
            ending = self._ending(exc)
            raise
        finally:
            _close_all(self.writes, [
                (writer.path, writer.close),
                (video.path, video.close) if video is not None else None,
                (recorder.path, lambda: recorder.close(not ending["interrupted"]))
                if recorder is not None else None,
                (None, live.close) if live is not None else None,
                (None, self.world.close)])
            self.metrics = self._metrics(time.perf_counter() - wall, ending)

    def _ending(self, exc: BaseException | None) -> dict:
        """How the loop ended, for the metrics: ``interrupted`` (bool), and the ``signal``'s
        name (a KeyboardInterrupt counts as SIGINT) or the ``error`` (``"<type>: <message>"``)."""
        try:
            t = float(self.world.time)
        except Exception:  # a broken world: the ending is still recorded
            t = math.nan
        if exc is None and self.stop.name is None:
            return {"interrupted": False}
        if exc is None or isinstance(exc, KeyboardInterrupt):
            name = self.stop.name or "SIGINT"
            log.warning("interrupted by %s at t = %.2f s", name, t)
            return {"interrupted": True, "signal": name}
        error = f"{type(exc).__name__}: {exc}"
        log.error("failed at t = %.2f s: %s", t, error)
        return {"interrupted": False, "error": error[:1000]}

    def _loop(self, writer: FrameWriter, video: ViewsVideo | None, keys: KeyFrames) -> None:
        """Vision frames at ``VISION_HZ`` (on the control grid), control steps between them,
        until ``duration`` (or ``max_duration``), or ``tail_s`` after the task ends."""
        cfg, task = self.config, self.task
        end = cfg.duration if cfg.duration is not None else cfg.max_duration
        self.ended_by = (f"--duration {end:g} s" if cfg.duration is not None else
                         f"the time limit ({end:g} s) with the task not done")
        done_at = None
        k = 0
        with _progress_bar(cfg.progress) as progress:
            bar = progress.add_task(f"experiment {cfg.experiment}", total=end, phase="")
            while self.stop.name is None:
                t = self.world.time
                if done_at is not None and t >= done_at + cfg.tail_s:
                    self.ended_by = f"the task's end, {cfg.tail_s:g} s after it"
                    break
                if t > end + 1e-9:
                    break
                self._vision_frame(k, t, writer, video, keys)
                k += 1
                if done_at is None and task.phase in (Phase.DONE, Phase.FAILED):
                    done_at = t
                progress.update(bar, completed=min(t, end), phase=str(task.phase))
                self._control_until(k / VISION_HZ)

    def _control_until(self, t_next: float) -> None:
        """Control steps until the world's time reaches ``t_next`` (s); estimates reach the
        planner when their latency is over."""
        world, name = self.world, self.robot.name
        while world.time < t_next - 1e-9:
            self.exposures.before_step(t_next)
            for estimate in self.deliveries.due(world.time):
                self._plan(world.time, estimate, world.measured_joints()[name])
            q, opening = self.task.step_control(world.time, world.measured_joints()[name])
            world.step({name: q}, {name: opening})
            self.grasp.after_control_step(world.time)

    def _priors(self, q: np.ndarray, opening: float) -> tuple[dict | None, dict | None]:
        """The kinematic prior's ``holders`` and ``supports`` for :meth:`Tracker.step` (None
        without it; :mod:`cellsight.tracking.prior`), from the robot's measured joints ``q`` and
        jaw ``opening`` (m): the part is held while the jaws are closed on it at the opening of
        its grasp (the task's own check, :func:`~cellsight.control.task.grasp_miss`; closed at
        another, they caught it off its grasp, and it is not where the task's grasp puts it),
        at the grasp the task chose."""
        if self.prior is None:
            return None, None
        task = self.task
        closed = self.world.jaws_closed_on_part(self.robot.name)
        held = grasp_miss(closed, opening, task.grasp_opening, task.tolerances.opening) is None
        return self.prior.update(self.robot.tcp_pose(q) @ invert_pose(task.planner.chosen_grasp)
                                 if held else None)

    def _vision_frame(self, k: int, t: float, writer: FrameWriter, video: ViewsVideo | None,
                      keys: KeyFrames) -> None:
        """Frame ``k`` at time ``t`` (s): track, plan, log, picture."""
        world, name = self.world, self.robot.name
        fate = self.clock.next()
        joints = world.measured_joints()
        openings = world.jaw_openings()
        truth = FrameTruth.of(world, self.part.name, name)
        dropped = fate.dropped or (self.kidnap is not None and self.kidnap.kidnap.blind(t))
        observed = self._grab(dropped, truth.part)
        if self.registration is not None and not dropped:
            self.registration.feed(self.tracker, t, observed, joints, openings,
                                   self.exposures.stamps, self._part_at)
        holders, supports = self._priors(joints[name], openings[name])
        frame = self.tracker.step(observed, joints, t, openings, holders,
                                  None if dropped else self.exposures.stamps, supports)
        rec = frame.parts[self.part.name]
        estimate = Estimate.of(t, rec)
        self._part_at = None if estimate.pose is None else estimate.pose[:3, 3]
        if self.clock.ideal:
            self._plan(t, estimate, joints[name])
        elif not dropped:
            self.deliveries.add(t + fate.latency_s, estimate)
        phase = str(self.task.phase)
        self.events.update(t, phase, rec.reasons)
        if self.kidnap is not None:
            self.kidnap.update(t, str(rec.status), _error_mm(rec, truth.part),
                               int(truth.part.visible.sum(axis=1).max(initial=0)))
        pnp = self.baseline.update(t, rec.measured)
        if self.live is not None:
            self.live.frame(t, joints, rec, frame.unknown,
                            None if self.ideal is not None else observed, truth.part.T_base_part)
        if self.recorder is not None:
            with self.writes.guard(self.recorder.path):
                self.recorder.frame(t, observed, None if dropped else self.exposures.stamps,
                                    joints, openings, truth.part.T_base_part)
        with self.writes.guard(writer.path):
            writer.write(self.rows.row(t, phase, self.task.stage, frame, rec, truth, pnp))

        def shown() -> list:
            complete = self.ideal is None and all(i is not None for i in observed)
            return observed if complete else world.render(on_demand=True, picture=True)

        def draw(caption: str) -> np.ndarray:
            return draw_frame([grabbed(o) for o in shown()], frame, self.part.name,
                              truth.part.visible, self.cell.cameras, caption, 1.0)

        with suppress(WriteError), self.writes.guard(self.out / "keyframes.json"):
            keys.offer_frame(t, phase, rec, draw)  # recorded; the run goes on without it
        if video is not None and k % self.config.video_every == 0:
            with self.writes.guard(video.path):
                video.add(shown(), frame, truth.part.visible,
                          f"t = {t:5.2f} s   {phase}   tracker: {rec.status_text}")

    def _grab(self, dropped: bool, truth: PartTruth) -> list:
        """What the sensors take this frame, one entry per camera, each as it was exposed
        (:mod:`.exposure`): an image (rendered sensor) or an :class:`.sensors.IdealView` of
        ``truth`` (ideal sensor); None per camera when the frame is dropped."""
        self.frames_dropped += dropped
        if dropped:
            self.exposures.drop()
            return [None] * len(self.cell.cameras)
        return self.exposures.frame(truth)

    def _plan(self, t: float, estimate: Estimate, joints: np.ndarray) -> None:
        """The task's vision update at time ``t`` with the tracker's ``estimate`` (pose and
        linear velocity, of its exposure time)."""
        before = self.task.phase
        self.task.update_vision(t, estimate.pose, joints,
                                self.world.jaws_closed_on_part(self.robot.name),
                                estimate.velocity, stamp=estimate.t, part_lost=estimate.lost,
                                jaw_opening=self.world.jaw_openings()[self.robot.name])
        self.grasp.after_vision(before, self.task.phase)

    def _knock(self) -> dict | None:
        """The knocked camera's figures (:func:`~.monitors.knock_record`), if any."""
        knock = self.draws.errors.knock
        if knock is None:
            return None
        check = self.tracker.camera_check
        truth = getattr(self.world, "truth", None)
        points = transform_points(self.part.T_base_part, self.part.feature_points)
        return knock_record(knock, check.dropped, check.recovered, self.cell.cameras,
                            None if truth is None else truth.cell.cameras, points)

    def _registration(self) -> dict | None:
        """Each camera's registration to the gripper (:mod:`cellsight.tracking.registration`),
        for ``metrics.json``: its latest offset, its corners, when and where it was made
        (``home``, ``part``), its offset at HOME and, where the world's true camera is known,
        the true camera's offset at the part's nominal pose (the median, over its feature
        points, of the true camera's pixel less the cell file's camera's, px)."""
        if self.registration is None:
            return None
        truth = getattr(self.world, "truth", None)
        out = self.registration.record()
        if truth is not None:
            points = transform_points(self.part.T_base_part, self.part.feature_points)
            for cam, true_cam in zip(self.cell.cameras, truth.cell.cameras, strict=True):
                gap = true_cam.project(points) - cam.project(points)
                out[cam.name]["true_offset_px"] = np.round(np.median(gap, axis=0), 3).tolist()
        return out

    def _metrics(self, wall_s: float, ending: dict) -> dict:
        """The metrics for ``metrics.json`` (checked, not written yet): the run's facts, how it
        ended (``ending``: :meth:`_ending`; its ``error`` with every failed write so far),
        ``t_end_s`` (s, its last frame) and :func:`frame_metrics` of its log."""
        cfg = self.config
        frames = FrameLog.read(self.out / "frames.csv")
        t_end = float(frames.floats("t")[-1]) if frames.n else 0.0
        collisions = self.world.collisions()
        metrics = {
            "experiment": cfg.experiment,
            "description": self.scenario.description,
            "cell": self.cell.source,
            "cell_sha256": cell_digest(self.cell),
            "identity": run_identity(cfg),
            "calibration_folder": None if cfg.calibration is None else str(cfg.calibration),
            "calibration_errors": (None if cfg.calibration is None
                                   else read_calibration(cfg.calibration).get("errors")),
            "cell_files": self.cell_files,
            "seed": cfg.seed,
            "sensor": cfg.sensor,
            **tracker_facts(cfg.tracker),
            "structure": cfg.structure,
            "realism": self.draws.profile.name,
            "realism_file": self.draws.profile.file,
            "realism_spec": None if isinstance(cfg.realism, Profile) else str(cfg.realism),
            "draws": self.draws.record,
            "collisions": collisions,
            "collision_count": len(collisions),
            "frames_dropped": self.frames_dropped,
            "kidnap": None if self.kidnap is None else self.kidnap.record(
                VISION_HZ, getattr(getattr(self.world, "faults", None), "moved", None)),
            "cameras_dropped": {self.cell.cameras[c].name: round(t, 4)
                                for c, t in self.tracker.camera_check.dropped.items()},
            "knock": self._knock(),
            "registration": self._registration(),
            **_arm_error(self.draws, self.robot, frames, self.registration is not None),
            "grasp_success": bool(self.grasp.held_at_manipulate),
            "grasp_position_error_mm": self.grasp.error_mm,
            "ended_by": getattr(self, "ended_by", None),
            "last_setback": last_setback(self.task),
            "final_phase": str(self.task.phase),
            "failed_grasp_checks": self.task.attempts,
            **frame_metrics(frames),
            "wall_s": round(wall_s, 2),
            **ending,
            "t_end_s": round(t_end, 3),
            "cameras": [c.name for c in self.cell.cameras],
            "features": len(self.part.feature_points),
            "robot": self.robot.name,
            "workpiece": self.part.name,
            "crossing_robot": self.crossing,
            "phase_intervals": [[str(p), round(a, 3), round(b, 3)]
                                for p, a, b in self.task.phase_intervals(t_end)],
        }
        if error := self.writes.error(metrics.get("error")):
            metrics["error"] = error
        metrics = checked_metrics(self.out, metrics)
        log.info("metrics: %s", json.dumps({k: v for k, v in metrics.items()
                                            if not isinstance(v, list | dict)}))
        return metrics


def _arm_error(draws: WorldDraws, robot: Robot, frames: FrameLog, registered: bool) -> dict:
    """For a run whose cameras are registered to ``robot`` (``registered``), the world's truth
    of that arm's own error at HOME (``arm_home_error_mm``: its TCP there less where its model
    puts it, mm, base frame) and the position RMSE against the part's true positions moved by
    it (``position_rmse_arm_mm``: :func:`~.metrics.position_rmse_in_arm_frame_mm`); both None
    otherwise."""
    if not registered or robot.home is None:
        return {"arm_home_error_mm": None, "position_rmse_arm_mm": None}
    error = draws.tcp_error(robot, robot.home)
    return {"arm_home_error_mm": np.round(error * 1e3, 3).tolist(),
            "position_rmse_arm_mm": position_rmse_in_arm_frame_mm(frames, error)}


def _close_all(writes: RunWrites, closers: list) -> None:
    """Call each of ``closers``, ``(file, close)`` (None: skipped; file None: not a file the run
    writes): a failure to write a file's end is recorded in ``writes``, another one logged;
    the others still run."""
    for path, close in filter(None, closers):
        try:
            if path is None:
                close()
            else:
                writes.close(path, close)
        except Exception as exc:  # e.g. ffmpeg killed by the same Ctrl-C: keep the rest
            log.warning("closing %s failed: %s: %s", getattr(close, "__qualname__", close),
                        type(exc).__name__, exc)


def _progress_bar(enabled: bool) -> Progress:
    """The terminal's progress bar: simulated time and task phase (nothing when disabled)."""
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                    TextColumn("t = {task.completed:5.1f} / {task.total:.0f} s"),
                    TextColumn("{task.fields[phase]:>10}"),
                    disable=not enabled, transient=False)


def run_experiment(config: RunConfig) -> dict:
    """Run one experiment (see :class:`ExperimentRun`) and return its metrics."""
    return ExperimentRun(config).run()


def _error_mm(rec: PartFrame, truth: PartTruth) -> float | None:
    """The estimate's position error (mm) against the truth; None without an estimate."""
    if not rec.status.has_estimate or rec.T_base_part is None:
        return None
    return 1e3 * float(np.linalg.norm(rec.T_base_part[:3, 3] - truth.T_base_part[:3, 3]))

"""One run folder's lifecycle: frames from a source, through the tracker, to the sinks.

:class:`RunSession` is the one loop of ``cellsight run`` (the simulated world and its task:
:mod:`cellsight.experiments.runner`), ``cellsight track`` (a recording:
:mod:`cellsight.recording.track`) and a camera driver (:mod:`.driver`). Per frame of the
:class:`~.protocols.FrameSource`: the cameras' registration to the gripper is fed
(:mod:`cellsight.tracking.registration`), the source's priors are asked for, the tracker steps,
the source's task takes the estimate, and every :class:`~.protocols.FrameSink` gets the
frame's :class:`~.frames.FrameRecord`, in the order given.

The output folder must be new or empty; with ``overwrite`` it is cleared first, but only when
it holds nothing but an earlier run's outputs (checked when the session is made, before any
work: :func:`~cellsight.runfolder.check_out_folder`). Every file goes through
:class:`~cellsight.runfolder.writes.RunWrites`: ``run.log`` as the run goes, each sink's files,
then, after the loop (also when interrupted or failed), ``report.html`` and, last and whole,
``metrics.json`` (the source's facts, how the run ended, and the figures of ``frames.csv``:
:mod:`cellsight.runfolder.figures`). A failed write (a full disk) ends the loop like any
exception, or, for ``run.log``, a picture or the end of a file, is recorded; either way the
metrics' ``error`` names the file and why, so that a sweep never reuses the run, and
:meth:`RunSession.run` raises the first failure once it has written what it could. When
``metrics.json`` itself cannot be written there is none: never one claiming success. SIGINT and
SIGTERM end the loop at the next frame boundary (:class:`~.signals.StopSignals`): the metrics
then say ``"interrupted": true`` and which signal; an exception is recorded as ``"error"``.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from cellsight.model.cell import Workpiece
from cellsight.report.run_report import write_report
from cellsight.runfolder import (
    FrameLog,
    RunWrites,
    WriteError,
    cell_digest,
    check_out_folder,
    checked_metrics,
    keep_cell,
    make_out_folder,
    write_metrics,
)
from cellsight.runfolder.figures import frame_metrics
from cellsight.runfolder.writes import log_to, stop_logging_to
from cellsight.session.frames import FrameRecord, SourceFrame
from cellsight.session.protocols import FrameSink, FrameSource, RunContext
from cellsight.session.signals import StopSignals
from cellsight.tracking.registration import GripperRegistration
from cellsight.tracking.tracker import Tracker

log = logging.getLogger(__name__)


@dataclass
class RunParts:
    """What a session runs: the ``source`` of frames, the ``tracker`` built on the source's
    cell, the ``sinks`` in the order they get each record, the cameras' ``registration`` to
    the grasping robot's gripper (None: none) and the caller's ``facts`` for ``metrics.json``
    beside the source's (made at the end from the run's log: how it was asked for)."""

    source: FrameSource
    tracker: Tracker
    sinks: Sequence[FrameSink] = field(default_factory=list)
    registration: GripperRegistration | None = None
    facts: Callable[[FrameLog], dict] | None = None


class RunSession:
    """One run into the folder ``out`` (module docstring). ``option_names``: how the caller
    names the output folder and the overwrite switch in its errors."""

    def __init__(self, out: str | Path, overwrite: bool = False, progress: bool = True,
                 option_names: tuple[str, str] = ("--out", "--overwrite")) -> None:
        self.out = Path(out)
        self.option_names = option_names
        self._stale = check_out_folder(self.out, overwrite, *option_names)
        self.progress = progress
        self.stop = StopSignals()
        self.writes = RunWrites(self.out)
        self.metrics: dict | None = None  # made after the loop, written last (:meth:`_finish`)
        self.frames = 0  # frames tracked
        self._estimate: np.ndarray | None = None  # the part's last estimated T_base_part
        self._logged_part: Workpiece | None = None  # the part of frames.csv, once started

    def run(self, parts: RunParts) -> dict:
        """Run ``parts`` into the folder; write everything; return the metrics. A failure
        propagates once the report and the metrics are written (module docstring)."""
        make_out_folder(self.out, self._stale, self.option_names[0])
        cell_files = keep_cell(self.out, parts.source.cell)
        handler = log_to(self.writes)
        with self.stop:
            try:
                self._run_logged(parts, cell_files)
            except BaseException:
                stop_logging_to(handler, self.writes)
                self._finish(failed=True)
                raise
            stop_logging_to(handler, self.writes)
            return self._finish(failed=False)

    def _run_logged(self, parts: RunParts, cell_files: dict) -> None:
        source = parts.source
        source.begin()
        context = RunContext(self.out, self.writes, source.cell, source.part, source.robot)
        self._logged_part = source.part  # frames.csv's (a line's first pick)
        started: list[FrameSink] = []
        wall = time.perf_counter()
        ending: dict = {"interrupted": True}
        try:
            for sink in parts.sinks:
                sink.start(context)
                started.append(sink)
            self._loop(parts)
            ending = self._ending(source, None)
        except BaseException as exc:
            ending = self._ending(source, exc)
            raise
        finally:
            completed = not ending["interrupted"] and "error" not in ending
            _close_all([(sink.close, completed) for sink in started] + [(source.close, None)])
            self.metrics = self._metrics(parts, cell_files, time.perf_counter() - wall, ending)

    def _loop(self, parts: RunParts) -> None:
        source = parts.source
        label, total = source.progress()
        with _progress_bar(self.progress) as progress:
            bar = progress.add_task(label, total=max(total, 1e-9), phase="")
            for frame in source.frames():
                if self.stop.name is not None:
                    break
                record = self._track(parts, frame)
                for sink in parts.sinks:
                    sink.frame(record)
                self.frames += 1
                progress.update(bar, completed=min(frame.t, total), phase=record.phase)

    def _track(self, parts: RunParts, frame: SourceFrame) -> FrameRecord:
        """The tracker's step at ``frame``, and the task's with its estimate."""
        source, tracker, registration = parts.source, parts.tracker, parts.registration
        if (registration is not None and not frame.dropped
                and source.robot.name in frame.openings):
            registration.feed(tracker, frame.t, frame.observed, frame.joints, frame.openings,
                              frame.stamps, None if self._estimate is None
                              else self._estimate[:3, 3])
        holders, supports = source.priors(frame, self._estimate)
        result = tracker.step(frame.observed, frame.joints, frame.t, frame.openings or None,
                              holders, frame.stamps, supports)
        part = result.parts[source.part.name]
        self._estimate = np.array(part.T_base_part) if part.status.has_estimate else None
        phase, stage = source.tracked(frame, part)
        return FrameRecord(frame, result, part, phase, stage)

    def _ending(self, source: FrameSource, exc: BaseException | None) -> dict:
        """How the loop ended, for the metrics: ``interrupted`` (bool), and the ``signal``'s
        name (a KeyboardInterrupt counts as SIGINT) or the ``error`` (``"<type>: <message>"``)."""
        try:
            t = float(source.time())
        except Exception:  # a broken source: the ending is still recorded
            t = math.nan
        if exc is None and self.stop.name is None:
            return {"interrupted": False}
        if exc is None or isinstance(exc, KeyboardInterrupt):
            name = self.stop.name or "SIGINT"
            log.warning("interrupted by %s at t = %.2f s", name, t)
            return {"interrupted": True, "signal": name}
        error = f"{type(exc).__name__}: {exc}"
        log.error("failed at t = %.2f s after %d frames: %s", t, self.frames, error)
        return {"interrupted": False, "error": error[:1000]}

    def _metrics(self, parts: RunParts, cell_files: dict, wall_s: float, ending: dict) -> dict:
        """The metrics for ``metrics.json`` (checked, not written yet): the source's facts and
        the caller's, the cell's, how the run ended (its ``error`` with every failed write so
        far), ``t_end_s`` (s, its last frame) and the figures of its log."""
        frames = FrameLog.read(self.out / "frames.csv")
        t_end = float(frames.floats("t")[-1]) if frames.n else 0.0
        source = parts.source
        cell = source.cell
        metrics = {
            **source.facts(frames),
            **(parts.facts(frames) if parts.facts is not None else {}),
            "cell": cell.source,
            "cell_sha256": cell_digest(cell),
            "cell_files": cell_files,
            **frame_metrics(frames),
            "wall_s": round(wall_s, 2),
            **ending,
            "t_end_s": round(t_end, 3),
            "cameras": [c.name for c in cell.cameras],
            "features": len(self._logged_part.feature_points),
            "robot": source.robot.name,
            "workpiece": self._logged_part.name,
        }
        if error := self.writes.error(metrics.get("error")):
            metrics["error"] = error
        metrics = checked_metrics(self.out, metrics)
        log.info("metrics: %s", json.dumps({k: v for k, v in metrics.items()
                                            if not isinstance(v, list | dict)}))
        return metrics

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


def _close_all(closers: list) -> None:
    """Call each ``(close, argument)`` (argument None: called without one); a failure is
    logged and the others still run (a sink records its own failed writes)."""
    for close, argument in closers:
        try:
            close() if argument is None else close(argument)
        except Exception as exc:  # e.g. ffmpeg killed by the same Ctrl-C: keep the rest
            log.warning("closing %s failed: %s: %s", getattr(close, "__qualname__", close),
                        type(exc).__name__, exc)


def _progress_bar(enabled: bool) -> Progress:
    """The terminal's progress bar: the run's clock, the task's phase and the wall time
    (nothing when disabled)."""
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(),
                    TextColumn("t = {task.completed:5.1f} / {task.total:.0f} s"),
                    TextColumn("{task.fields[phase]:>10}"), TimeElapsedColumn(),
                    disable=not enabled, transient=False)

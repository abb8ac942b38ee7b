"""A live cell's camera and robot drivers as a run session's source: the API's hook.

Whatever reads the cell's cameras and joint encoders (a vendor SDK, a ROS 2 node) implements
:class:`CellDriver`: each call of :meth:`CellDriver.read` returns the next
:class:`DriverFrame`, or None when it has no more. :func:`track_driver` tracks the cell's
workpiece through them into a run folder, as ``cellsight track`` does through a recording (the
same tracker, prior, registration and files); extra sinks (a live stream, the user's own) get
each frame's record::

    from cellsight.session.driver import track_driver
    metrics = track_driver("dual-arm", my_driver, "out/live")
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from cellsight.errors import CellsightError
from cellsight.model.cell import Cell
from cellsight.model.loader import load_cell
from cellsight.runfolder import FrameLog
from cellsight.session.frames import SourceFrame
from cellsight.session.measured import PHASE, MeasuredCell, measured_parts
from cellsight.session.protocols import FrameSink, Priors
from cellsight.session.run import RunSession
from cellsight.trackers import DEFAULT_TRACKER, TrackerChoice
from cellsight.tracking.records import PartFrame


@dataclass(frozen=True)
class DriverFrame:
    """One frame of a live cell at time ``t`` (s, the driver's clock, increasing): per camera
    of the cell its ``images`` ((H, W) uint8, None for a camera that gave nothing), every
    robot's measured ``joints`` (rad, m), each gripper's jaw ``openings`` (m), per camera its
    exposure time ``stamps`` (s; None: ``t``), and the part's ``T_base_part`` where something
    measures it (a motion capture; None: unknown)."""

    t: float
    images: list
    joints: dict[str, np.ndarray]
    openings: dict[str, float] = field(default_factory=dict)
    stamps: list | None = None
    T_base_part: np.ndarray | None = None


@runtime_checkable
class CellDriver(Protocol):
    """A live cell's sensors, read one frame at a time."""

    def read(self) -> DriverFrame | None:
        """The next frame (blocking until it is taken), or None: no more."""
        ...


class DriverSource:
    """The frames of ``driver`` on ``cell`` (module docstring); ``duration`` (s of the
    driver's clock, None: until it stops) sizes the progress bar and ends the run."""

    def __init__(self, cell: Cell, driver: CellDriver, part: str | None = None,
                 kinematic: bool = True, duration: float | None = None) -> None:
        self.cell, self.driver, self.duration = cell, driver, duration
        self.part = cell.workpieces[0] if part is None else cell.workpiece(part)
        self.measured = MeasuredCell(cell, self.part, kinematic)
        self.robot = self.measured.robot
        self._t = 0.0
        self.frames_read = 0

    def begin(self) -> None:
        """Nothing to log: the driver is the user's."""

    def progress(self) -> tuple[str, float]:
        return "tracking", self.duration if self.duration is not None else 0.0

    def time(self) -> float:
        return self._t

    def frames(self) -> Iterator[SourceFrame]:
        while (read := self.driver.read()) is not None:
            if len(read.images) != len(self.cell.cameras):
                raise CellsightError(f"driver frame at t = {read.t:.3f} s: {len(read.images)} "
                                     f"image(s) for the cell's {len(self.cell.cameras)} cameras")
            if self.frames_read and read.t <= self._t:
                raise CellsightError(f"driver frame at t = {read.t:.3f} s: not after the "
                                     f"previous one ({self._t:.3f} s)")
            if self.duration is not None and read.t > self.duration:
                return
            self._t = read.t
            truth = self.measured.truth(read.joints, read.openings, read.T_base_part)
            stamps = read.stamps if read.stamps is not None else [read.t] * len(read.images)
            yield SourceFrame(self.frames_read, read.t, list(read.images), list(stamps),
                              read.joints, read.openings, truth)
            self.frames_read += 1

    def priors(self, frame: SourceFrame, estimate: np.ndarray | None) -> Priors:
        return self.measured.priors(frame, estimate)

    def tracked(self, frame: SourceFrame, part: PartFrame) -> tuple[str, str]:
        """No task runs here: the robots are the driver's."""
        return PHASE, ""

    def facts(self, frames: FrameLog) -> dict:
        return {"description": "tracked from a camera driver", "sensor": "driver",
                "frames_tracked": frames.n}

    def close(self) -> None:
        """The driver is the caller's to close."""


def track_driver(cell: str | Path | Cell, driver: CellDriver, out: str | Path,
                 tracker: TrackerChoice = DEFAULT_TRACKER, sinks: Sequence[FrameSink] = (),
                 duration: float | None = None, overwrite: bool = False,
                 progress: bool = False) -> dict:
    """Track ``cell``'s first workpiece through ``driver``'s frames into the run folder
    ``out`` (``frames.csv``, ``run.log``, ``report.html``, ``metrics.json``), with the
    ``tracker`` of ``cellsight run``, handing each frame's record to ``sinks`` too; returns
    the metrics. ``cell``: a built-in cell's name, a cell file or a loaded cell."""
    session = RunSession(out, overwrite, progress)
    cell = cell if isinstance(cell, Cell) else load_cell(cell)
    source = DriverSource(cell, driver, kinematic=tracker.kinematic, duration=duration)
    return session.run(measured_parts(source, source.measured, tracker, sinks))

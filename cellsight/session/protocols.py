"""The two kinds of component a run session wires: where frames come from and where each
frame's record goes (:mod:`cellsight.session.run`).

A source is the simulated world with its task (:mod:`cellsight.experiments.simulated`), a
recording (:mod:`cellsight.recording.track`) or a camera driver (:mod:`.driver`); a sink is
``frames.csv`` (:mod:`.rows`), the key frames, the video, the monitors
(:mod:`cellsight.experiments.sinks`), the recorder (:mod:`cellsight.recording.recorder`), the
live stream (:mod:`cellsight.export.live`) or a user's own (the guide's example).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from cellsight.model.cell import Cell, Workpiece
from cellsight.model.robot import Robot
from cellsight.runfolder.framelog import FrameLog
from cellsight.runfolder.writes import RunWrites
from cellsight.session.frames import FrameRecord, SourceFrame
from cellsight.tracking.records import PartFrame

Priors = tuple[dict | None, dict | None]  # the kinematic prior's holders and supports


@dataclass(frozen=True)
class RunContext:
    """What a sink knows of its run when it starts: the run folder ``out`` and its writes
    (:class:`~cellsight.runfolder.writes.RunWrites`: a sink writes its files through
    ``writes.guard(path)``, so that a failed write is recorded against its file), the
    tracker's ``cell``, the tracked ``part`` and the grasping ``robot``."""

    out: Path
    writes: RunWrites
    cell: Cell
    part: Workpiece
    robot: Robot


@runtime_checkable
class FrameSource(Protocol):
    """Where a run's frames come from, and what it knows beyond the tracker: the priors, the
    task, the facts for ``metrics.json``. ``cell`` is the tracker's cell (its cameras and
    robots), ``part`` the tracked workpiece, ``robot`` the grasping robot."""

    cell: Cell
    part: Workpiece
    robot: Robot

    def begin(self) -> None:
        """Log what the run reads and how (the run's log is open)."""
        ...

    def progress(self) -> tuple[str, float]:
        """The progress bar's label and its total (s of the run's clock)."""
        ...

    def frames(self) -> Iterator[SourceFrame]:
        """The frames, in time order; the next is asked for once the last one's record has
        gone to every sink."""
        ...

    def priors(self, frame: SourceFrame, estimate: np.ndarray | None) -> Priors:
        """The kinematic prior's ``holders`` and ``supports`` for the tracker at ``frame``
        (``estimate``: the part's last estimated ``T_base_part``); (None, None) without it."""
        ...

    def tracked(self, frame: SourceFrame, part: PartFrame) -> tuple[str, str]:
        """Take the tracker's record of the part at ``frame`` (the task plans with it);
        return the task's phase and stage."""
        ...

    def time(self) -> float:
        """The run's clock now (s)."""
        ...

    def facts(self, frames: FrameLog) -> dict:
        """The source's facts for ``metrics.json``, at the end (``frames``: the run's log)."""
        ...

    def close(self) -> None:
        """Release what the source holds; log what it found on the way (gaps, ...)."""
        ...


@runtime_checkable
class FrameSink(Protocol):
    """Where each frame's record goes. A sink writes only inside the run folder, through the
    context's writes; a failure it lets out ends the run (recorded in ``metrics.json``)."""

    def start(self, run: RunContext) -> None:
        """Open what the sink writes (called once, after the run folder is made)."""
        ...

    def frame(self, record: FrameRecord) -> None:
        """Take one frame's record."""
        ...

    def close(self, completed: bool) -> None:
        """Finish (also after a failure or an interruption: ``completed`` False)."""
        ...

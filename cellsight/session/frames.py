"""What flows through a run session, one vision frame at a time.

A :class:`~cellsight.session.protocols.FrameSource` gives a :class:`SourceFrame`: what the
cell's sensors took at the frame's time (images, joint encoders, jaw openings) and what is
known of the truth (:class:`FrameTruth`: the simulator's, a recording's, or nothing). After
the tracker and the task, each :class:`~cellsight.session.protocols.FrameSink` gets the
:class:`FrameRecord`. Units: s, m, rad, px; poses ``T_base_part`` in the cell's base frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from cellsight.tracking.records import PartFrame, TrackerFrame
from cellsight.visibility import CameraVisibility


@dataclass(frozen=True)
class PartTruth:
    """The truth about one workpiece at one frame: ``T_base_part`` and what each camera sees
    of it there (``views``, one per camera)."""

    T_base_part: np.ndarray
    views: list[CameraVisibility]

    @property
    def pixels(self) -> np.ndarray:
        """(C, F, 2) true projections (px, distorted; NaN behind a camera)."""
        return np.stack([v.pixels for v in self.views])

    @property
    def visible(self) -> np.ndarray:
        """(C, F) truly visible."""
        return np.stack([v.visible for v in self.views])


@dataclass(frozen=True)
class FrameTruth:
    """The truth at one vision frame, read once: the workpiece's (``part``; None where nothing
    knows it, e.g. a recording without the part's pose), every robot's ``joints`` (rad, m), and
    of the grasping robot: its jaw opening (m), its jaws closed on the part, the grasp
    engaged; on a line, ``others``: the truth of the other picked parts, by name."""

    part: PartTruth | None
    joints: dict[str, np.ndarray]
    jaw_opening: float
    jaws_closed: bool
    grasped: bool
    others: dict[str, PartTruth] = field(default_factory=dict)


@dataclass(frozen=True)
class SourceFrame:
    """Vision frame ``k`` at time ``t`` (s, the run's clock) as its source gives it.

    ``observed``: per camera what it took (an image, an image read on demand, the ideal
    sensor's view; None for a camera that gave nothing); ``images``: whether ``observed`` holds
    camera images (False for the ideal sensor's views); ``stamps``: per camera its exposure
    time (s), None for a dropped frame; ``joints``: robot -> measured joints (rad, m);
    ``openings``: robot -> measured jaw opening (m); ``truth``: what is known of the truth;
    ``dropped``: the frame was lost (no images); ``pictures``: the cameras' whole images for a
    picture of the frame (key frames, the video), made only when asked."""

    k: int
    t: float
    observed: list
    stamps: list | None
    joints: dict[str, np.ndarray]
    openings: dict[str, float]
    truth: FrameTruth
    dropped: bool = False
    images: bool = True
    pictures: Callable[[], list] | None = None


@dataclass(frozen=True)
class FrameRecord:
    """One frame's record, what every sink gets: the source's ``frame``, the tracker's
    ``result`` (every part) and its record of the tracked ``part``, and the task's ``phase``
    and ``stage`` once the frame's estimate has reached it (a recording's: ``recorded``,
    ``""``)."""

    frame: SourceFrame
    result: TrackerFrame
    part: PartFrame
    phase: str
    stage: str

    @property
    def t(self) -> float:
        return self.frame.t

    def truth_of(self, name: str) -> FrameTruth:
        """The frame's truth with workpiece ``name`` as its ``part``: as it is for the
        record's part, else from the truth's ``others`` (None where it is not known)."""
        truth = self.frame.truth
        return truth if name == self.part.name else replace(truth, part=truth.others.get(name))

    def shown(self) -> list:
        """The cameras' whole images for a picture of this frame."""
        frame = self.frame
        return frame.pictures() if frame.pictures is not None else frame.observed

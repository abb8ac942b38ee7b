"""When each camera exposes the frame: at the frame's time, or earlier by its trigger skew.

Unsynchronised cameras are exposed at different instants. A camera with a skew ``s`` (s, less
than a vision period) is exposed during the control steps before the frame, at the first step
at or after ``t_frame - s`` (:meth:`Exposures.before_step`); the others at the frame's time
(:meth:`Exposures.frame`); the tracker is told when each was exposed
(:attr:`Exposures.stamps`). For the rendered sensor an exposure is that camera's image; for
the ideal sensor it is that camera's true pixels, visibility and corners (an
:class:`~cellsight.experiments.sensors.IdealView`).
"""

from __future__ import annotations

import numpy as np

from cellsight.experiments.plant import SimulatedCell, part_truth
from cellsight.experiments.sensors import IdealView
from cellsight.session.frames import PartTruth


class Exposures:
    """Exposures of one run's frames (module docstring). ``skews`` (C,) s; ``ideal``: expose
    truths (ideal sensor) instead of images; ``part``: the workpiece whose truth is exposed;
    ``full_frames``: render each image whole at once, instead of shots that render what the
    tracker reads of them (:mod:`cellsight.world.shots`)."""

    def __init__(self, world: SimulatedCell, skews: np.ndarray, ideal: bool, part: str,
                 full_frames: bool = False) -> None:
        self.world, self.ideal, self.part = world, ideal, part
        self.full_frames = full_frames
        self.skews = np.asarray(skews, dtype=float)
        self._skewed = [int(c) for c in np.flatnonzero(self.skews > 0)]
        self._early: dict[int, tuple[float, object]] = {}
        self.stamps: list[float | None] = [None] * len(self.skews)
        """Each camera's exposure time (s) of the last frame (None: the frame's time)."""

    def before_step(self, t_frame: float) -> None:
        """Expose each skewed camera whose instant for the frame at ``t_frame`` has come."""
        now = self.world.time
        for c in self._skewed:
            if c not in self._early and now >= t_frame - self.skews[c] - 1e-9:
                self._early[c] = (now, self._expose([c])[c])

    def frame(self, truth: PartTruth | None = None) -> list:
        """Every camera's exposure for the frame now (the skewed ones taken earlier);
        ``truth``: the part's truth now, when the caller has it (ideal sensor)."""
        rest = [c for c in range(len(self.skews)) if c not in self._early]
        now = self._expose(rest, truth) if rest else [None] * len(self.skews)
        out = [self._early[c][1] if c in self._early else now[c] for c in range(len(self.skews))]
        self.stamps = [self._early[c][0] if c in self._early else None
                       for c in range(len(self.skews))]
        self._early = {}
        return out

    def drop(self) -> None:
        """The frame is lost: nothing more is exposed for it (the early exposures go too)."""
        self._early = {}

    def _expose(self, cameras: list[int], truth: PartTruth | None = None) -> list:
        if not self.ideal:
            return self.world.render(cameras, on_demand=not self.full_frames)
        truth = truth or part_truth(self.world, self.part)
        corners = self.world.true_corners()
        return [IdealView(truth.pixels[c], truth.visible[c], corners[c]) if c in cameras
                else None for c in range(len(self.skews))]

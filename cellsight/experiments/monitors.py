"""What the run watches and writes into ``run.log`` as it goes, besides the task's own phase
changes: the grasp (:class:`GraspMonitor`) and what hides the part (:class:`OcclusionEvents`)."""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Sequence

import numpy as np

from cellsight.control import Phase
from cellsight.experiments.plant import GroundTruth

log = logging.getLogger(__name__)


class GraspMonitor:
    """The grasping robot's grasp: the TCP's error from the grasp pose when the grasp first
    engages (the world's own figure, :meth:`GroundTruth.grasp`), and whether the part is
    really held when the task enters Manipulate (the grasp's success)."""

    def __init__(self, world: GroundTruth, robot: str) -> None:
        self.world = world
        self.robot = robot
        self.error_mm: float | None = None
        self.held_at_manipulate = False

    def after_control_step(self, t: float) -> None:
        """Call after each control step (``t``: the world's time, s): logs the engagement."""
        grasp = self.world.grasp(self.robot) if self.error_mm is None else None
        if grasp is None:
            return
        self.error_mm = 1e3 * grasp.position_error_m
        log.info("t=%6.2f s grasp engaged: TCP %.1f mm, %.1f deg from the grasp pose",
                 t, self.error_mm, np.degrees(grasp.angle_error_rad))

    def after_vision(self, before: Phase, after: Phase) -> None:
        """Call after the task's vision update, with its phase before and after."""
        if before == Phase.GRASP and after == Phase.MANIPULATE:
            self.held_at_manipulate = self.world.grasp(self.robot) is not None


class OcclusionEvents:
    """A line in the log (predicted visibility) whenever the set of what hides the part from a
    camera changes, or the count of visible points crosses 3 or 1."""

    def __init__(self, cameras: Sequence[str]) -> None:
        self.cameras = list(cameras)
        self._state: dict[int, tuple] = {}

    def update(self, t: float, phase: str, reasons: Sequence[Sequence[str]]) -> None:
        """``reasons``: per camera, per feature, '' or why it is predicted hidden."""
        for c, per_feature in enumerate(reasons):
            hidden = Counter(r for r in per_feature if r)
            n_visible = sum(1 for r in per_feature if not r)
            state = (frozenset(hidden), min(n_visible, 3), n_visible == 0)
            if self._state.get(c) == state:
                continue
            self._state[c] = state
            text = ", ".join(f"{label} {n}" for label, n in sorted(hidden.items()))
            log.info("t=%6.2f s %-10s %s: %d/%d visible%s", t, phase, self.cameras[c],
                     n_visible, len(per_feature), f"; hidden: {text}" if text else "")

"""A line's task: one robot picks several parts in turn, each through the grasping task's
phases (:class:`~cellsight.control.task.GraspTask`: Approach, Grasp, Manipulate, Release).

The next part's task starts, from where the robot stands (HOME), at the vision update in which
the last one is done, with no estimate of its part yet; it waits for one like the first. A
pick that fails ends the sequence (``failed``): the robot has given up a part, and the line's
run stops there. Seen from outside the sequence is one task: its ``phase`` and ``stage`` are
the current pick's (``current``, its planner and grasp), ``done`` only once the last pick
is. Times in seconds, poses ``T_base_tcp`` in the cell base frame.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence

import numpy as np

from cellsight.control.task import GraspTask, Phase, Stage
from cellsight.model.cell import Workpiece

log = logging.getLogger(__name__)


class PickSequence:
    """The grasping task of each of ``parts`` in turn (module docstring); ``task_for`` makes a
    part's task when its turn comes."""

    def __init__(self, parts: Sequence[Workpiece],
                 task_for: Callable[[Workpiece], GraspTask]) -> None:
        if not parts:
            raise ValueError("PickSequence: no parts to pick")
        self.parts = list(parts)
        self.task_for = task_for
        self.finished: list[GraspTask] = []  # the picks done, in order
        self.current = task_for(self.parts[0])

    @property
    def part(self) -> Workpiece:
        """The part being picked now (the last one once all are done)."""
        return self.parts[self.index]

    @property
    def index(self) -> int:
        """The current pick's place in the order (0-based)."""
        return len(self.finished)

    @property
    def phase(self) -> Phase:
        return self.current.phase

    @property
    def stage(self) -> Stage:
        return self.current.stage

    @property
    def attempts(self) -> int:
        """The failed grasp checks of every pick so far."""
        return sum(task.attempts for task in self.tasks)

    @property
    def tasks(self) -> list[GraspTask]:
        """Every pick's task so far, in order, the current one last."""
        return [*self.finished, self.current]

    @property
    def transitions(self) -> list[tuple[float, Phase, Phase, str]]:
        return [step for task in self.tasks for step in task.transitions]

    @property
    def events(self) -> list[tuple[float, Phase, str, str]]:
        return [event for task in self.tasks for event in task.events]

    def update_vision(self, t: float, part_pose: np.ndarray | None, joints_measured: np.ndarray,
                      jaws_closed: bool, part_velocity: np.ndarray | None = None,
                      stamp: float | None = None, part_lost: bool = False,
                      jaw_opening: float | None = None) -> None:
        """The current pick's vision update (:meth:`GraspTask.update_vision`, the estimate of
        the current part); once it is done, the next pick's task takes over."""
        self.current.update_vision(t, part_pose, joints_measured, jaws_closed, part_velocity,
                                   stamp, part_lost, jaw_opening)
        if self.current.phase is Phase.DONE and self.index + 1 < len(self.parts):
            self.finished.append(self.current)
            self.current = self.task_for(self.part)
            log.info("t=%.3f s: %s picked; picking %s (%d of %d)", t, self.parts[self.index - 1]
                     .name, self.part.name, self.index + 1, len(self.parts))
            # it starts now, from where the robot stands, with no estimate of its part yet
            self.current.update_vision(t, None, joints_measured, jaws_closed,
                                       jaw_opening=jaw_opening)

    def step_control(self, t: float, q_measured: np.ndarray) -> tuple[np.ndarray, float]:
        """The current pick's control step: joint set-point and gripper opening (m)."""
        return self.current.step_control(t, q_measured)

    def phase_intervals(self, t_end: float) -> list[tuple[Phase, float, float]]:
        """``(phase, start, end)`` of every phase of every pick so far: each finished pick's
        until the next one starts (its instant ``done`` left out), the current one's until
        ``t_end``."""
        out: list[tuple[Phase, float, float]] = []
        for task, after in zip(self.finished, self.tasks[1:], strict=True):
            out += [i for i in task.phase_intervals(after.servo.t0) if i[0] is not Phase.DONE]
        return out + self.current.phase_intervals(t_end)

"""Position-based visual servoing (paper, Fig. 7) and the grasping task's phases.

- :class:`TrajectoryPlanner` (vision rate, 26 Hz): TCP target from the task and the estimated
  part pose (minimum-jerk segments towards fixed or part-following goals).
- :class:`InterpolatingFilter`: second-order filter turning the 26 Hz targets into smooth 500 Hz
  pose set-points.
- :class:`Clik` (500 Hz): damped-least-squares closed-loop inverse kinematics with a null-space
  term keeping the joints away from their limits; joint position and velocity limits enforced.
- :class:`ServoLoop`: the three blocks above wired as in Fig. 7.
- :class:`GraspTask`: the phases approach, grasp, manipulate, release (:class:`Phase`) driving
  the servo loop. A new task (other phases) is a new class beside it; nothing outside this
  package knows the phases but by their names.

The loop, as the experiment runner drives it (``dt`` = 2 ms, a vision frame every 1/26 s)::

    task = GraspTask(robot, part)                      # timing=TaskTiming(...) to change durations
    for each control step at time t:
        if a vision frame is due:
            task.update_vision(t, T_base_part_estimate_or_None, q_measured, jaws_closed)
        q_setpoint, opening = task.step_control(t, q_measured)
    task.transitions                                   # [(t, from, to, reason), ...]
"""

from cellsight.control.clik import Clik, default_joint_velocity_limits
from cellsight.control.interpolator import InterpolatingFilter
from cellsight.control.planner import (
    PartGoal,
    PartMotion,
    PoseGoal,
    TrajectoryPlanner,
    min_jerk,
)
from cellsight.control.task import (
    GraspTask,
    Phase,
    ServoLoop,
    Stage,
    TaskMoves,
    TaskTiming,
    TaskTolerances,
)

__all__ = [
    "Clik",
    "GraspTask",
    "InterpolatingFilter",
    "PartGoal",
    "PartMotion",
    "Phase",
    "PoseGoal",
    "ServoLoop",
    "Stage",
    "TaskMoves",
    "TaskTiming",
    "TaskTolerances",
    "TrajectoryPlanner",
    "default_joint_velocity_limits",
    "min_jerk",
]

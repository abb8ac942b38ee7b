"""The grasping task of the paper (Section V) as a phase machine driving the servo loop of Fig. 7.

Phases, in order: ``waiting`` -> ``approach`` -> ``grasp`` -> ``manipulate`` -> ``release`` ->
``done`` (``failed`` if the grasp check fails ``max_attempts`` times). Each phase has stages:

- waiting: hold the start pose until the part is localised and ``t >= timing.start``.
- approach: ``over`` (go 5 cm above the part's grasp pose, following it while it moves) until the
  horizontal TCP error has stayed under tolerance for ``timing.stable``; ``descend`` (lower to the
  grasp pose, still following) until the grasp pose is reached. When the tracker says the part
  is lost, ``clear`` (back to the pose the robot started from, in ``timing.retreat``: the last
  estimate is stale, and an arm hovering over it can hide the part where it really is) until
  the part is found again, then ``over``.
- grasp: ``closing`` (close the jaws, keep moving with the part's last estimated horizontal
  velocity, without vision feedback, for ``timing.close``), then check the jaws; closed on the
  part, at the opening the part's section between the jaws gives at its grasp (within
  ``tolerances.opening``, when the task knows that opening and the jaws' reading): ``holding``
  for ``timing.hold``; not closed, or closed at another opening (the jaws caught a wider part
  of it, off the grasp): open the jaws and go back to ``approach``. Jaws that caught the part
  off its grasp were off along their own width (across it, closing jaws centre the part), by
  more than the grasp leaves them, and the estimate that put them there is off the same way
  on the next attempt: the next grasp is moved by ``retry_shift`` along the jaws' width, one
  way, then the other (:func:`shifted_grasp`).
- manipulate: ``lift`` by ``lift_height``, then ``home`` (back to the HOME pose carrying the part).
  No vision from here on: the planner uses the joint measurements only.
- release: ``final`` (go to the FINAL pose), ``opening`` (open the jaws, ``timing.open``), ``home``.

:meth:`GraspTask.update_vision` runs at the vision rate (26 Hz): phase logic, planner, new target
for the interpolating filter. :meth:`GraspTask.step_control` runs at the control rate (500 Hz):
filter step and CLIK, returning the joint set-point and the gripper opening command (m). The CLIK
integrates its own joint set-point, started from the first measured joints. Phase changes are
logged in ``transitions`` as ``(t, from, to, reason)``, stage changes in ``events`` as
``(t, phase, stage, note)``, and both through :mod:`logging`. Times in seconds, lengths in metres,
angles in radians, poses ``T_base_tcp`` in the cell base frame.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, fields, replace

import numpy as np

from cellsight.control.clik import Clik, rotation_error
from cellsight.control.interpolator import InterpolatingFilter
from cellsight.control.planner import PartGoal, PoseGoal, TrajectoryPlanner
from cellsight.fields import NamedEnum
from cellsight.model.cell import Workpiece
from cellsight.model.grasp import grasp_pose
from cellsight.model.robot import Robot

log = logging.getLogger(__name__)


class Phase(NamedEnum):
    """Task phases. A phase equals, prints and serialises as its name (``"approach"``)."""

    WAITING = "waiting"
    APPROACH = "approach"
    GRASP = "grasp"
    MANIPULATE = "manipulate"
    RELEASE = "release"
    DONE = "done"
    FAILED = "failed"

    @classmethod
    def working(cls) -> tuple[Phase, ...]:
        """The phases in which the robot works on the part, in task order (not ``waiting``,
        ``done`` or ``failed``): the ones the metrics break the errors down by."""
        return tuple(p for p in cls if p not in (cls.WAITING, cls.DONE, cls.FAILED))


class Stage(NamedEnum):
    """The task's stages within its phases (module docstring). A stage equals, prints and
    serialises as its name (``"descend"``), as ``frames.csv`` logs it."""

    START = "start"
    CLEAR = "clear"
    OVER = "over"
    DESCEND = "descend"
    CLOSING = "closing"
    HOLDING = "holding"
    LIFT = "lift"
    HOME = "home"
    FINAL = "final"
    OPENING = "opening"
    HOLD = "hold"


@dataclass(frozen=True)
class TaskTiming:
    """Durations of the task's steps (s). The defaults give the paper's timeline roughly: the
    approach from 4 s to about 12 s, the grasp about 8 s, and the whole task about 50 s."""

    start: float = 4.0  # earliest start of the approach
    over: float = 4.0  # move to the approach height over the part
    stable: float = 1.0  # horizontal error under tolerance for this long before descending
    descend: float = 2.0  # descent from the approach height to the grasp pose
    close: float = 1.5  # jaws closing before their state is checked
    hold: float = 6.5  # holding after a successful check, before manipulating
    retreat: float = 1.5  # back up after a failed check; stand clear when the part is lost
    lift: float = 3.0  # lift the part before returning HOME (gently: the tracker follows it)
    to_home: float = 7.0  # move to HOME (manipulate, and at the end of release)
    to_final: float = 8.0  # move from HOME to FINAL
    open: float = 1.5  # jaws opening at FINAL
    settle: float = 0.5  # least dwell at the end of a move before checking it is reached
    reach_timeout: float = 3.0  # after the end of a move, go on even if not reached

    def scaled(self, factor: float) -> TaskTiming:
        """All durations multiplied by ``factor`` (e.g. 0.4 for short test runs)."""
        return replace(self, **{f.name: getattr(self, f.name) * factor for f in fields(self)})


@dataclass(frozen=True)
class TaskTolerances:
    """When a pose counts as reached: ``horizontal`` (m) error in the base xy plane to start
    the descent, ``position`` (m) and ``angle`` (rad) for the end of a move; ``opening`` (m):
    how far the closed jaws' opening may be from the grasp's for the grasp to count."""

    horizontal: float = 0.005
    position: float = 0.005
    angle: float = 0.035
    opening: float = 0.005


@dataclass(frozen=True)
class TaskMoves:
    """The task's moves: the ``approach_height`` (m, 5 cm as in the paper) over the part and
    the ``lift_height`` (m) along base +z; the grasp check may fail ``max_attempts`` times;
    ``retry_shift`` (m): how far a retry after a grasp caught off the part moves the grasp
    along the jaws' width (module docstring; 0: not at all); ``place``: the TCP pose
    ``T_base_tcp`` the part is put down at (None: FINAL's)."""

    approach_height: float = 0.05
    lift_height: float = 0.10
    max_attempts: int = 3
    retry_shift: float = 0.0035
    place: np.ndarray | None = None


RETRY_SIDES = (1.0, -1.0)
"""Which way each retry after a grasp caught off the part moves the grasp, in turn."""


def shifted_grasp(T_part_tcp: np.ndarray, shift: float) -> np.ndarray:
    """The grasp ``T_part_tcp`` moved by ``shift`` (m) along the jaws' width (the TCP's x
    axis: the jaws close along its y and approach along its z); the grasp turned half a turn
    about z moves the same way in the part's frame."""
    T = np.array(T_part_tcp, dtype=float)
    T[:3, 3] += shift * T[:3, 0]
    return T


def grasp_miss(jaws_closed: bool, opening: float | None, expected: float | None,
               tolerance: float) -> str | None:
    """Why jaws closed at ``opening`` (m; None: no reading) do not hold a part whose grasp
    closes them to ``expected`` (m; None: not known) within ``tolerance`` (m), or None when
    they do."""
    if not jaws_closed:
        return "jaws not closed on the part"
    if opening is None or expected is None or abs(opening - expected) <= tolerance:
        return None
    return (f"jaws closed at {1e3 * opening:.1f} mm, not the grasp's {1e3 * expected:.1f} mm: "
            f"they caught the part off its grasp")


class ServoLoop:
    """The servo loop of the paper's Fig. 7 for one robot: the trajectory planner's target at
    the vision rate, the interpolating filter and the CLIK at the control rate (the
    interpolator's ``dt``, s). The CLIK integrates its own joint set-point, started from the
    first measured joints."""

    def __init__(self, robot: Robot, planner: TrajectoryPlanner, clik: Clik,
                 interpolator: InterpolatingFilter) -> None:
        self.robot = robot
        self.planner = planner
        self.clik = clik
        self.interpolator = interpolator
        self.t0 = 0.0
        self.T_start: np.ndarray | None = None  # the TCP pose at the first call of start
        self._q: np.ndarray | None = None

    def start(self, t: float, q: np.ndarray) -> None:
        """At the first call only: start from the measured joints ``q`` at time ``t`` (s)."""
        if self._q is not None:
            return
        self._q = self.robot.chain.check_q(q).copy()
        self.t0 = float(t)
        T = self.robot.tcp_pose(self._q)
        self.planner.reset(t, T)
        self.interpolator.reset(T)
        self.T_start = T

    def new_target(self, t: float) -> None:
        """Vision rate: the planner's target at time ``t`` (s) to the interpolating filter."""
        self.interpolator.set_target(*self.planner.target(t))

    def step(self) -> np.ndarray:
        """Control rate: the next joint set-point (one filter step, one CLIK step)."""
        T, twist = self.interpolator.step()
        self._q = self.clik.step(self._q, T, twist, self.interpolator.dt)
        return self._q.copy()


class GraspTask:
    """Phase machine + servo loop for one robot grasping one workpiece (paper, Section V).

    ``part`` gives the grasp geometry (:func:`~cellsight.model.grasp.grasp_pose`, with the
    robot's tool); ``moves``: the heights, attempts and retries (:class:`TaskMoves`).
    ``planner`` and ``interpolator`` default to a :class:`TrajectoryPlanner` and an
    :class:`InterpolatingFilter` with their default parameters, the CLIK is the robot's
    :class:`Clik`; the control period is the interpolator's ``dt``. Gripper commands:
    ``robot.tool.max_opening`` open, 0 closed. ``grasp_opening`` (m): the jaws' opening when
    closed on the part at its grasp (None: any opening counts).
    """

    def __init__(
        self,
        robot: Robot,
        part: Workpiece,
        *,
        timing: TaskTiming | None = None,
        tolerances: TaskTolerances | None = None,
        moves: TaskMoves | None = None,
        planner: TrajectoryPlanner | None = None,
        interpolator: InterpolatingFilter | None = None,
        grasp_opening: float | None = None,
    ) -> None:
        if robot.tool is None or robot.final is None:
            raise ValueError(f"GraspTask: robot {robot.name} needs a tool and a FINAL pose")
        self.robot = robot
        self.timing = timing or TaskTiming()
        self.tolerances = tolerances or TaskTolerances()
        moves = moves or TaskMoves()
        self.approach_height = float(moves.approach_height)
        self.lift_height = float(moves.lift_height)
        self.max_attempts = int(moves.max_attempts)
        self.servo = ServoLoop(robot, planner or TrajectoryPlanner(grasp_pose(part, robot.tool)),
                               Clik(robot), interpolator or InterpolatingFilter())
        self.planner = self.servo.planner
        self.T_home = robot.tcp_pose(robot.home)
        self.T_final = (robot.tcp_pose(robot.final) if moves.place is None
                        else np.array(moves.place, dtype=float))
        self.open_command = robot.tool.max_opening
        self.closed_command = 0.0
        self.grasp_opening = None if grasp_opening is None else float(grasp_opening)
        self.retry_shift = float(moves.retry_shift)
        self._first_grasp = self.planner.T_part_tcp.copy()
        self._shifts = 0
        self.phase = Phase.WAITING
        self.stage = Stage.START
        self.attempts = 0
        self.transitions: list[tuple[float, Phase, Phase, str]] = []
        self.events: list[tuple[float, Phase, str, str]] = []
        self._gripper = self.open_command
        self._stage_t = 0.0
        self._stable_since: float | None = None
        self._part_lost = False
        self._jaw_opening: float | None = None
        self._handlers = {
            Phase.WAITING: self._waiting, Phase.APPROACH: self._approach, Phase.GRASP: self._grasp,
            Phase.MANIPULATE: self._manipulate, Phase.RELEASE: self._release,
            Phase.FAILED: self._failed,
        }  # DONE: nothing left to do, the robot holds HOME

    # ---- rates -------------------------------------------------------------------------------

    def update_vision(self, t: float, part_pose: np.ndarray | None, joints_measured: np.ndarray,
                      jaws_closed: bool, part_velocity: np.ndarray | None = None,
                      stamp: float | None = None, part_lost: bool = False,
                      jaw_opening: float | None = None) -> None:
        """Vision-rate update at time ``t``: ``part_pose`` is the estimated ``T_base_part``
        (None when not localised) at time ``stamp`` (its image's exposure; default ``t``: no
        latency), ``part_velocity`` its optional linear velocity (m/s), ``joints_measured`` the
        robot's joints at ``t``, ``jaws_closed`` the gripper's jaw sensor at ``t``;
        ``part_lost``: the tracker has lost the part (the approach stands clear);
        ``jaw_opening``: the gripper's opening reading (m), if it has one."""
        self.servo.start(t, joints_measured)
        self._part_lost = bool(part_lost)
        self._jaw_opening = jaw_opening
        if self.phase in (Phase.WAITING, Phase.APPROACH, Phase.GRASP):
            self.planner.part.update(t if stamp is None else stamp, part_pose, part_velocity)
        T_meas = self.robot.tcp_pose(joints_measured)
        if self.phase is Phase.APPROACH and self.planner.keep_grasp_near(t, T_meas):
            self.events.append((t, self.phase, self.stage, "the part's estimate turned: the "
                                                           "twin grasp is nearer, switched to it"))
            log.info("t=%.3f s: the twin grasp is nearer now; switched to it", t)
        if handler := self._handlers.get(self.phase):
            handler(t, T_meas, bool(jaws_closed))
        self.servo.new_target(t)

    def step_control(self, t: float, q_measured: np.ndarray) -> tuple[np.ndarray, float]:
        """Control-rate step at time ``t``: next joint set-point and gripper opening (m)."""
        self.servo.start(t, q_measured)
        return self.servo.step(), self._gripper

    def phase_intervals(self, t_end: float) -> list[tuple[Phase, float, float]]:
        """``(phase, start, end)`` of every phase entered so far, the last one ending at
        ``t_end``."""
        starts = [(Phase.WAITING, self.servo.t0)] + [(to, t) for t, _, to, _ in self.transitions]
        ends = [t for _, t in starts[1:]] + [t_end]
        return [(phase, t0, t1) for (phase, t0), t1 in zip(starts, ends, strict=True)]

    # ---- phases (26 Hz) ----------------------------------------------------------------------

    def _waiting(self, t: float, T_meas: np.ndarray, jaws_closed: bool) -> None:
        if self.planner.part.known and t >= self.timing.start:
            self._go(t, Phase.APPROACH, "part localised")
            self._over(t, self.timing.over)

    def _approach(self, t: float, T_meas: np.ndarray, jaws_closed: bool) -> None:
        if self._part_lost and self.stage is not Stage.CLEAR:
            self._set_stage(t, Stage.CLEAR, "part lost: back to the start pose, clear of the views")
            log.info("t=%.3f s: %s/clear (part lost: back to the start pose, clear of the views)",
                     t, self.phase.value)
            self.planner.move_to(t, PoseGoal(self.servo.T_start, t), self.timing.retreat)
        elif self.stage is Stage.CLEAR and not self._part_lost:
            self._over(t, self.timing.over)
        elif self.stage is Stage.OVER and t >= self.planner.segment_end():
            goal, _ = self.planner.goal_at(self.planner.goal, t)
            error = float(np.linalg.norm(goal[:2, 3] - T_meas[:2, 3]))
            if error > self.tolerances.horizontal:
                self._stable_since = None
                if t < self.planner.segment_end() + self.timing.reach_timeout:
                    return
                note = f"horizontal error {1e3 * error:.1f} mm not settled; descending anyway"
            else:
                self._stable_since = t if self._stable_since is None else self._stable_since
                if t - self._stable_since < self.timing.stable:
                    return
                note = f"horizontal error {1e3 * error:.1f} mm stable"
            self._set_stage(t, Stage.DESCEND, note)
            self.planner.move_to(t, PartGoal(0.0), self.timing.descend)
        elif self.stage is Stage.DESCEND and (note := self._arrived(t, T_meas)):
            self._go(t, Phase.GRASP, f"grasp pose {note}")
            self._gripper = self.closed_command
            T, twist, _ = self.planner.target(t)
            self._set_stage(t, Stage.CLOSING, "jaws closing, following the part's last velocity")
            # horizontally only: a part rides its conveyor level; a vertical velocity is the
            # estimator's noise, and following it would push the held part into the conveyor
            self.planner.move_to(t, PoseGoal(T, t, twist[:3] * (1.0, 1.0, 0.0)), 0.0)

    def _grasp(self, t: float, T_meas: np.ndarray, jaws_closed: bool) -> None:
        if self.stage is Stage.CLOSING and t - self._stage_t >= self.timing.close:
            miss = grasp_miss(jaws_closed, self._jaw_opening, self.grasp_opening,
                              self.tolerances.opening)
            if miss is None:
                self._set_stage(t, Stage.HOLDING, "jaws closed on the part")
                self.planner.move_to(t, PoseGoal(self.planner.target(t)[0], t), 0.0)
                return
            self.attempts += 1
            self._gripper = self.open_command
            reason = f"{miss} (attempt {self.attempts})"
            if jaws_closed and self.retry_shift > 0:  # caught off the grasp: move it
                shift = RETRY_SIDES[self._shifts % len(RETRY_SIDES)] * self.retry_shift
                self._shifts += 1
                self.planner.T_part_tcp = shifted_grasp(self._first_grasp, shift)
                reason += f"; the next grasp {1e3 * shift:+.1f} mm along the jaws' width"
            if self.attempts >= self.max_attempts:
                self._go(t, Phase.FAILED, f"{reason}; giving up")
                self._set_stage(t, Stage.HOME, "returning HOME")
                self.planner.move_to(t, PoseGoal(self.T_home), self.timing.to_home)
            else:
                self._go(t, Phase.APPROACH, reason)
                self._over(t, self.timing.retreat)
        elif self.stage is Stage.HOLDING and t - self._stage_t >= self.timing.hold:
            self._go(t, Phase.MANIPULATE, "part held")
            self._set_stage(t, Stage.LIFT, f"lifting {1e2 * self.lift_height:.0f} cm")
            T = self.planner.target(t)[0]
            T[2, 3] += self.lift_height
            self.planner.move_to(t, PoseGoal(T), self.timing.lift)

    def _manipulate(self, t: float, T_meas: np.ndarray, jaws_closed: bool) -> None:
        if self.stage is Stage.LIFT and t >= self.planner.segment_end():
            self._set_stage(t, Stage.HOME, "returning HOME with the part")
            self.planner.move_to(t, PoseGoal(self.T_home), self.timing.to_home)
        elif self.stage is Stage.HOME and (note := self._arrived(t, T_meas)):
            self._go(t, Phase.RELEASE, f"HOME {note}")
            self._set_stage(t, Stage.FINAL, "going to FINAL")
            self.planner.move_to(t, PoseGoal(self.T_final), self.timing.to_final)

    def _release(self, t: float, T_meas: np.ndarray, jaws_closed: bool) -> None:
        if self.stage is Stage.FINAL and (note := self._arrived(t, T_meas)):
            self._set_stage(t, Stage.OPENING, f"FINAL {note}; opening the jaws")
            self._gripper = self.open_command
        elif self.stage is Stage.OPENING and t - self._stage_t >= self.timing.open:
            self._set_stage(t, Stage.HOME, "returning HOME")
            self.planner.move_to(t, PoseGoal(self.T_home), self.timing.to_home)
        elif self.stage is Stage.HOME and (note := self._arrived(t, T_meas)):
            self._go(t, Phase.DONE, f"HOME {note}")
            self._set_stage(t, Stage.HOLD, "task complete")

    def _failed(self, t: float, T_meas: np.ndarray, jaws_closed: bool) -> None:
        """Grasp given up: the robot returns HOME with the jaws open and stays there."""
        if self.stage is Stage.HOME and (note := self._arrived(t, T_meas)):
            self._set_stage(t, Stage.HOLD, f"HOME {note}; task failed")

    # ---- helpers -----------------------------------------------------------------------------

    def _over(self, t: float, duration: float) -> None:
        self._stable_since = None
        self._set_stage(t, Stage.OVER, f"{1e2 * self.approach_height:.0f} cm over the part")
        self.planner.move_to(t, PartGoal(self.approach_height), duration)

    def _arrived(self, t: float, T_meas: np.ndarray) -> str | None:
        """Why the current move counts as finished (reached, or timed out), or None."""
        end = self.planner.segment_end()
        if t < end + self.timing.settle:
            return None
        goal, _ = self.planner.goal_at(self.planner.goal, t)
        position = float(np.linalg.norm(goal[:3, 3] - T_meas[:3, 3]))
        angle = float(np.linalg.norm(rotation_error(goal[:3, :3], T_meas[:3, :3])))
        error = f"error {1e3 * position:.1f} mm, {np.degrees(angle):.1f} deg"
        if position <= self.tolerances.position and angle <= self.tolerances.angle:
            return f"reached ({error})"
        if t >= end + self.timing.reach_timeout:
            return f"not reached after {self.timing.reach_timeout:g} s ({error}); going on"
        return None

    def _go(self, t: float, to: Phase, reason: str) -> None:
        self.transitions.append((t, self.phase, to, reason))
        log.info("t=%.3f s: %s -> %s (%s)", t, self.phase.value, to.value, reason)
        self.phase = to

    def _set_stage(self, t: float, stage: Stage, note: str) -> None:
        self.stage = stage
        self._stage_t = t
        self.events.append((t, self.phase, stage, note))
        log.debug("t=%.3f s: %s/%s (%s)", t, self.phase.value, stage, note)


def last_setback(task: GraspTask) -> str | None:
    """The task's last step back, with its time, or None: a failed grasp check (back to the
    approach), a move that timed out ("not reached"), the part lost (the ``clear`` stage), the
    task failed (from its ``transitions`` and ``events``)."""
    found = [(t, f"{a} -> {b}: {why}") for t, a, b, why in task.transitions
             if b is Phase.FAILED or "not reached" in why
             or (b is Phase.APPROACH and a is not Phase.WAITING)]
    found += [(t, f"{phase}/{stage}: {note}") for t, phase, stage, note in task.events
              if stage == "clear" or "not reached" in note]
    if not found:
        return None
    t, text = max(found, key=lambda f: f[0])
    return f"t = {t:.1f} s, {text}"

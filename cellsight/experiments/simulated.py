"""The simulated cell as a run session's source of frames: the world, its task and its control.

Per vision frame (``VISION_HZ``): the world's images (or, for the ideal sensor, the true
projections), joint measurements and jaw openings, with the simulator's truth; once the
tracker has stepped (:class:`~cellsight.session.run.RunSession`), its estimate goes to the
grasping task's planner; between frames, the ``CONTROL_HZ`` control loop (interpolating filter
+ CLIK) drives the world. On a line the grasping robot picks the scenario's parts in turn
(:class:`~cellsight.control.sequence.PickSequence`): the tracked ``part`` is the one picked
now, and each frame's truth holds the other picks' too. The world departs from the cell file
by the run's realism profile (:mod:`cellsight.realism`): a camera may be exposed before the
frame's time (its trigger skew, :mod:`.exposure`), a frame may be dropped (no images), and its
estimate reaches the planner after the frame's latency (:mod:`.latency`), stamped with its
exposure time. The frames end at the duration, the time limit, or ``tail_s`` after the task's
end.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from dataclasses import dataclass
from functools import partial

import numpy as np

from cellsight.control import GraspTask, Phase
from cellsight.control.sequence import PickSequence
from cellsight.control.task import TaskMoves, grasp_miss, last_setback
from cellsight.experiments.exposure import Exposures
from cellsight.experiments.latency import Deliveries, Estimate
from cellsight.experiments.monitors import GraspMonitor, KidnapMonitor
from cellsight.experiments.plant import SimulatedCell, frame_truth
from cellsight.experiments.scenario import Scenario, place_pose
from cellsight.geometry.transforms import invert_pose
from cellsight.model.cell import Cell, Workpiece
from cellsight.model.grasp import grasp_opening, grasp_pose
from cellsight.model.landing import Landing
from cellsight.rates import VISION_HZ
from cellsight.realism import FrameClock
from cellsight.realism.draws import WorldDraws
from cellsight.runfolder.framelog import FrameLog
from cellsight.session.frames import PartTruth, SourceFrame
from cellsight.session.protocols import Priors
from cellsight.tracking.prior import KinematicPrior
from cellsight.tracking.records import PartFrame

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SimulatedRun:
    """How long a simulated run goes: ``end`` (s) the duration or the time limit, ``timed``:
    ``end`` is the duration asked for; ``tail_s`` (s) past the task's end; ``experiment``
    the experiment's number (the progress bar's label); ``heading``: the log's first line."""

    end: float
    timed: bool
    tail_s: float
    experiment: int
    heading: str = ""


def pick_task(cell: Cell, scenario: Scenario, part: Workpiece) -> GraspTask:
    """The grasping task of ``part`` (one of ``scenario``'s picks), with the opening its grasp
    closes the jaws to and the place it is put down at (:func:`~.scenario.place_pose`)."""
    robot, tool = scenario.robot, scenario.robot.tool  # GraspTask names a robot without one
    order = [p.name for p in scenario.picks].index(part.name)
    return GraspTask(robot, part, grasp_opening=None if tool is None else
                     grasp_opening(part.solid, tool, grasp_pose(part, tool)),
                     moves=TaskMoves(place=place_pose(cell, robot, order)))


class SimulatedSource:
    """Frames of the simulated ``world`` of ``scenario`` on the tracker's ``cell`` (module
    docstring). ``exposures``: how the cameras expose (:mod:`.exposure`); ``kinematic``: give
    the kinematic prior; ``draws``: the world's realism draws (its frame clock, the kidnapping);
    ``seed``: the frame clock's."""

    def __init__(self, cell: Cell, scenario: Scenario, world: SimulatedCell,
                 exposures: Exposures, draws: WorldDraws, run: SimulatedRun,
                 kinematic: bool, seed: int) -> None:
        self.cell, self.scenario, self.world, self.exposures = cell, scenario, world, exposures
        self.robot, self.run = scenario.robot, run
        self.clock = FrameClock(draws.profile.timing, seed)
        self.deliveries = Deliveries()
        self.frames_dropped = 0
        landing = Landing(cell.static)
        self.priors_of = ({p.name: KinematicPrior(p, landing)
                           for p in scenario.picks + scenario.passing} if kinematic else None)
        kidnap = draws.errors.kidnap
        self.kidnap = None if kidnap is None else KidnapMonitor(kidnap)
        self.task = PickSequence(scenario.picks, partial(pick_task, cell, scenario))
        self.grasp = GraspMonitor(world, self.robot.name)
        self.ended_by: str | None = None
        self._fate_latency_s = 0.0

    @property
    def part(self) -> Workpiece:
        """The part picked now (the tracked part of each frame's record)."""
        return self.task.part

    def begin(self) -> None:
        log.info("%s", self.run.heading)

    def progress(self) -> tuple[str, float]:
        return f"experiment {self.run.experiment}", self.run.end

    def time(self) -> float:
        return float(self.world.time)

    def frames(self) -> Iterator[SourceFrame]:
        """Vision frames at ``VISION_HZ`` (on the control grid), control steps between them,
        until the duration (or the time limit), or ``tail_s`` after the task ends."""
        run, task = self.run, self.task
        self.ended_by = (f"--duration {run.end:g} s" if run.timed else
                         f"the time limit ({run.end:g} s) with the task not done")
        done_at = None
        k = 0
        while True:
            t = self.world.time
            if done_at is not None and t >= done_at + run.tail_s:
                self.ended_by = f"the task's end, {run.tail_s:g} s after it"
                return
            if t > run.end + 1e-9:
                return
            yield self._frame(k, t)
            k += 1
            if done_at is None and task.phase in (Phase.DONE, Phase.FAILED):
                done_at = t
            self._control_until(k / VISION_HZ)

    def _frame(self, k: int, t: float) -> SourceFrame:
        """Frame ``k`` at time ``t`` (s): what the sensors take, and the truth."""
        world, name = self.world, self.robot.name
        fate = self.clock.next()
        self._fate_latency_s = fate.latency_s
        logged = self.scenario.picks + self.scenario.passing
        truth = frame_truth(world, self.part.name, name,
                            [p.name for p in logged] if len(logged) > 1 else ())
        dropped = fate.dropped or (self.kidnap is not None and self.kidnap.kidnap.blind(t))
        observed = self._grab(dropped, truth.part)
        ideal = self.exposures.ideal

        def pictures() -> list:
            complete = not ideal and all(i is not None for i in observed)
            return observed if complete else world.render(on_demand=True, picture=True)

        return SourceFrame(k, t, observed, None if dropped else self.exposures.stamps,
                           world.measured_joints(), world.jaw_openings(), truth, dropped,
                           images=not ideal, pictures=pictures)

    def _grab(self, dropped: bool, truth: PartTruth) -> list:
        """What the sensors take this frame, one entry per camera, each as it was exposed
        (:mod:`.exposure`): an image (rendered sensor) or an :class:`.sensors.IdealView` of
        ``truth`` (ideal sensor); None per camera when the frame is dropped."""
        self.frames_dropped += dropped
        if dropped:
            self.exposures.drop()
            return [None] * len(self.cell.cameras)
        return self.exposures.frame(truth)

    def priors(self, frame: SourceFrame, estimate: np.ndarray | None) -> Priors:
        """The kinematic prior's ``holders`` and ``supports`` (None without it;
        :mod:`cellsight.tracking.prior`), from the robot's measured joints and jaw opening:
        the part picked now is held while the jaws are closed on it at the opening of its
        grasp (the task's own check, :func:`~cellsight.control.task.grasp_miss`; closed at
        another, they caught it off its grasp, and it is not where the task's grasp puts it),
        at the grasp the task chose; a line's other picks and its passing parts are not
        held."""
        if self.priors_of is None:
            return None, None
        name, task = self.robot.name, self.task
        closed = self.world.jaws_closed_on_part(name)
        held = grasp_miss(closed, frame.openings[name], task.current.grasp_opening,
                          task.current.tolerances.opening) is None
        held_at = (self.robot.tcp_pose(frame.joints[name])
                   @ invert_pose(task.current.planner.chosen_grasp) if held else None)
        holders: dict = {}
        supports: dict = {}
        for part, prior in self.priors_of.items():
            held_by, lying_on = prior.update(held_at if part == self.part.name else None)
            holders.update(held_by or {})
            supports.update(lying_on or {})
        return holders or None, supports or None

    def tracked(self, frame: SourceFrame, part: PartFrame) -> tuple[str, str]:
        """The estimate to the planner: now (an ideal frame clock) or after the frame's
        latency; the kidnapping's monitor sees the frame."""
        estimate = Estimate.of(frame.t, part)
        if self.clock.ideal:
            self._plan(frame.t, estimate, frame.joints[self.robot.name])
        elif not frame.dropped:
            self.deliveries.add(frame.t + self._fate_latency_s, estimate)
        if self.kidnap is not None:
            truth = frame.truth.part
            error = (None if not part.status.has_estimate or part.T_base_part is None else
                     1e3 * float(np.linalg.norm(part.T_base_part[:3, 3]
                                                - truth.T_base_part[:3, 3])))
            self.kidnap.update(frame.t, str(part.status), error,
                               int(truth.visible.sum(axis=1).max(initial=0)))
        return str(self.task.phase), str(self.task.stage)

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

    def _plan(self, t: float, estimate: Estimate, joints: np.ndarray) -> None:
        """The task's vision update at time ``t`` with the tracker's ``estimate`` (pose and
        linear velocity, of its exposure time)."""
        before, pick = self.task.phase, self.task.index
        self.task.update_vision(t, estimate.pose, joints,
                                self.world.jaws_closed_on_part(self.robot.name),
                                estimate.velocity, stamp=estimate.t, part_lost=estimate.lost,
                                jaw_opening=self.world.jaw_openings()[self.robot.name])
        self.grasp.after_vision(before, self.task.phase)
        if self.task.index != pick:  # the next pick: the estimates on their way are the last's
            self.deliveries = Deliveries()

    def facts(self, frames: FrameLog) -> dict:
        """The world's and the task's facts: the scenario, the collisions, the dropped frames,
        the kidnapping, the grasp, how the run ended and the task's phases."""
        collisions = self.world.collisions()
        t_end = float(frames.floats("t")[-1]) if frames.n else 0.0
        return {
            "description": self.scenario.description,
            "collisions": collisions,
            "collision_count": len(collisions),
            "frames_dropped": self.frames_dropped,
            "kidnap": None if self.kidnap is None else self.kidnap.record(
                VISION_HZ, self.world.faults.moved),
            "grasp_success": self.grasp.held == [True] * len(self.scenario.picks),
            "grasp_position_error_mm": self.grasp.error_mm,
            "ended_by": self.ended_by,
            "last_setback": last_setback(self.task),
            "final_phase": str(self.task.phase),
            "failed_grasp_checks": self.task.attempts,
            "crossing_robot": next(iter(self.scenario.tasks), None),
            "phase_intervals": [[str(p), round(a, 3), round(b, 3)]
                                for p, a, b in self.task.phase_intervals(t_end)],
        }

    def close(self) -> None:
        self.world.close()

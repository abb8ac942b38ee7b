"""What the sources of a cell's measurements share (a recording, a camera driver): no task runs
and no world is driven; the part is held where the measured jaws stand at its grasp's opening
(the kinematic prior); the truth is a measured pose of the part where there is one.

:func:`measured_parts` wires such a source to the tracker of ``cellsight run``
(:func:`~cellsight.tracking.setup.build_tracker`), the cameras' registration to the grasping
robot's gripper (the kinematic tracker) and the sinks every run has.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from cellsight.control.task import TaskTolerances
from cellsight.model.cell import Cell, Workpiece
from cellsight.model.grasp import grasp_opening, grasp_pose
from cellsight.model.landing import Landing
from cellsight.model.robot import Robot
from cellsight.occlusion.backends import visibility_predictor
from cellsight.runfolder import FrameLog
from cellsight.session.baseline import PnPBaseline
from cellsight.session.events import OcclusionEvents
from cellsight.session.frames import FrameTruth, PartTruth, SourceFrame
from cellsight.session.protocols import FrameSink, FrameSource, Priors
from cellsight.session.rows import FrameRows, FramesCsv
from cellsight.session.run import RunParts
from cellsight.trackers import TrackerChoice
from cellsight.tracking.prior import KinematicPrior, RecordedGrasp
from cellsight.tracking.registration import RegistrationRule
from cellsight.tracking.setup import build_tracker, tracker_facts

log = logging.getLogger(__name__)

PHASE = "recorded"  # the phase of a frame no task runs on


class MeasuredCell:
    """The grasping ``robot`` of ``cell`` (its first with a gripper), the kinematic prior of
    ``part`` (``kinematic``) and the truth's views."""

    def __init__(self, cell: Cell, part: Workpiece, kinematic: bool) -> None:
        self.cell, self.part = cell, part
        self.robot = next((r for r in cell.robots if r.tool is not None), cell.robots[0])
        self.prior = _grasp_prior(cell, self.robot, part) if kinematic else None
        self.registers = kinematic and self.robot.tool is not None
        self._views = visibility_predictor(cell)

    def truth(self, joints: dict[str, np.ndarray], openings: dict[str, float],
              T_base_part: np.ndarray | None) -> FrameTruth:
        """The frame's truth: the part's measured pose (None: not measured) and what each
        camera sees of it there, by the cell's geometry."""
        part = None
        if T_base_part is not None:
            views = self._views.predict(joints, {self.part.name: T_base_part}, openings)
            part = PartTruth(T_base_part, views[self.part.name])
        return FrameTruth(part, joints, openings.get(self.robot.name, float("nan")), False,
                          False)

    def priors(self, frame: SourceFrame, estimate: np.ndarray | None) -> Priors:
        """The kinematic prior's: the part held where the measured jaws stand at its grasp's
        opening (:class:`~cellsight.tracking.prior.RecordedGrasp`)."""
        if self.prior is None:
            return None, None
        grasp, prior = self.prior
        return prior.update(grasp.held_at(frame.joints[self.robot.name],
                                          frame.openings.get(self.robot.name), estimate))


def _grasp_prior(cell: Cell, robot: Robot, part: Workpiece) -> tuple[RecordedGrasp,
                                                                     KinematicPrior] | None:
    """The kinematic prior of ``part`` grasped by ``robot`` from measured joints and jaw
    openings (:mod:`cellsight.tracking.prior`; the task's grasp and tolerance), or None, with a
    warning, where the robot has no gripper or its jaws would close on no material at the
    part's grasp."""
    T_part_tcp = None if robot.tool is None else grasp_pose(part, robot.tool)
    opening = None if robot.tool is None else grasp_opening(part.solid, robot.tool, T_part_tcp)
    if opening is None:
        log.warning("the kinematic tracker: %s's jaws close on no material of %s at its grasp; "
                    "no kinematic prior", robot.name, part.name)
        return None
    grasp = RecordedGrasp(robot, part, T_part_tcp, opening, TaskTolerances().opening)
    return grasp, KinematicPrior(part, Landing(cell.static))


def measured_parts(source: FrameSource, measured: MeasuredCell, tracker: TrackerChoice,
                   sinks: Sequence[FrameSink] = ()) -> RunParts:
    """The parts of a run on ``source``: the ``tracker`` on its cell, the cameras'
    registration to the grasping robot's gripper where ``measured`` registers, and the sinks:
    the occlusion events of ``run.log``, ``frames.csv``, then ``sinks``; the registration goes
    into ``metrics.json``."""
    cell = source.cell
    built = build_tracker(cell, tracker, awaiting_registration=measured.registers)
    registration = (RegistrationRule().registration(cell, measured.robot.name)
                    if measured.registers else None)
    every_run: list[FrameSink] = [
        OcclusionEvents(),
        FramesCsv(FrameRows(measured.robot, len(cell.cameras), pixel_errors=True),
                  PnPBaseline.of(built, source.part.feature_points))]

    def facts(frames: FrameLog) -> dict:
        return {**tracker_facts(tracker),
                "registration": None if registration is None else registration.record(),
                "kinematic_prior": measured.prior is not None}

    return RunParts(source, built, [*every_run, *sinks], registration, facts)

"""Experiment 3's crossing, designed (``cellsight design-crossing``): the second robot's
gripper put on a camera's line of sight to the part while that camera should be blind.

The part's path over the task and the grasping robot's joints come from a run of experiment 2
(ideal sensor; the same task without the crossing), read from its ``frames.csv``. For each
block ``(camera, t0, t1)`` the crossing robot's TCP goes, at ``t0`` and at ``t1``, to the point
``fraction`` of the way from the part (its features' centroid then) to the camera's optical
centre, its tool z axis along the line of sight towards the part (its x axis as close to its
HOME's as that allows); each pose is solved by inverse kinematics (:mod:`cellsight.control.ik`),
the branch nearest the previous waypoint in joint space. The robot leaves HOME (or the
previous block) ``lead`` seconds before ``t0`` and is back at HOME ``lead`` after ``t1``
(``lead``: the largest joint move at ``SPEED`` rad/s (or m/s), at least ``MIN_LEAD_S``).

Every fraction of ``FRACTIONS`` is tried; a design is judged along the whole crossing, every
``STEP_S``, with the part and the grasping robot where the run had them:

- blinding: per block, the most features its camera still sees during ``t0..t1`` (the
  occlusion predictor), against the most it sees with the crossing robot left at HOME;
- blinding elsewhere: the seconds a camera sees at most half its features (against the
  crossing robot at HOME) outside its own blocks, every ``2 STEP_S`` of the crossing (the
  robot on its way between blocks may pass through another view);
- clearance: the crossing robot's least distance to the other robots and the part (MuJoCo
  ``mj_geomDistance`` between their solids).

The design kept is the one that blinds best (fewest features left, summed over the blocks),
then blinds least elsewhere, among those whose clearance is at least ``clearance_m``, else the
one with the largest clearance.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cellsight.control.ik import IKError, solve_ik, tcp_frame
from cellsight.errors import CellsightError
from cellsight.experiments.crossing_check import least_distance, seen_with_and_without
from cellsight.experiments.task_path import TaskPath
from cellsight.model.cell import Cell
from cellsight.model.robot import Robot
from cellsight.occlusion.backends import visibility_predictor
from cellsight.occlusion.predictor import VisibilityPredictor
from cellsight.world.paths import JointTask, Waypoint

FRACTIONS = (0.25, 0.35, 0.45, 0.55, 0.65)
SPEED = 0.8  # rad/s (m/s for a prismatic joint): the crossing robot's planned joint speed
MIN_LEAD_S = 1.5
STEP_S = 0.1


@dataclass(frozen=True)
class Block:
    """Camera ``camera`` should be blind from ``t0`` to ``t1`` (s)."""

    camera: str
    t0: float
    t1: float


@dataclass(frozen=True)
class Design:
    """A crossing: its ``waypoints`` ((t, q) pairs), the ``fraction`` used, per block the most
    features its camera sees during it (``left``) and without the crossing (``of``), the seconds
    a camera is blinded outside its blocks (``elsewhere_s``, summed over the cameras) and when
    (``elsewhere``: (camera, from, to) s), and the least ``clearance_m`` with where
    (``closest``: solid, time)."""

    waypoints: list[tuple[float, np.ndarray]]
    fraction: float
    left: list[int]
    of: list[int]
    elsewhere_s: float
    clearance_m: float
    closest: tuple[str, float]
    elsewhere: tuple[tuple[str, float, float], ...] = ()

    def elsewhere_text(self) -> str:
        """``elsewhere`` in words: ``cam1 10.2-11.0 s, cam3 20.4 s``, or ``none``."""
        return ", ".join(f"{c} {t0:.1f} s" if t1 == t0 else f"{c} {t0:.1f}-{t1:.1f} s"
                         for c, t0, t1 in self.elsewhere) or "none"

    def yaml(self, robot: str) -> str:
        """The cell file's ``crossing:`` section (under ``experiments:``)."""
        lines = ["  crossing:", f"    robot: {robot}", "    waypoints:"]
        lines += [f"      - {{t: {t:.2f}, q: [{', '.join(f'{x:.4f}' for x in q)}]}}"
                  for t, q in self.waypoints]
        return "\n".join(lines)


def design_crossing(cell: Cell, blocks: Sequence[Block], path: TaskPath, *,
                    clearance_m: float = 0.10) -> Design:
    """The crossing of the module docstring for ``blocks`` (in time order)."""
    crosser = _crossing_robot(cell)
    part = cell.picked_workpieces()[0]
    designs, predictor = [], visibility_predictor(cell)
    for fraction in FRACTIONS:
        try:
            waypoints = _waypoints(cell, crosser, part.feature_points, blocks, path, fraction)
        except IKError:
            continue
        designs.append(_judged(cell, crosser, part.name, blocks, path, fraction, waypoints,
                               predictor))
    if not designs:
        raise CellsightError(f"design-crossing: {crosser.name} cannot reach any of the lines of "
                             f"sight at fractions {FRACTIONS} of the way to the cameras")
    clear = [d for d in designs if d.clearance_m >= clearance_m]
    if clear:
        return min(clear, key=lambda d: (sum(d.left), d.elsewhere_s, -d.clearance_m))
    return max(designs, key=lambda d: d.clearance_m)


def _crossing_robot(cell: Cell) -> Robot:
    setup = cell.experiments
    if setup.crossing_robot is not None:
        return cell.robot(setup.crossing_robot)
    others = [r for r in cell.robots if r.name != setup.robot]
    if setup.robot is None or not others:
        raise CellsightError("design-crossing: the cell file names no crossing robot "
                             "(experiments.crossing.robot) and has no second robot")
    return others[0]


def _waypoints(cell: Cell, robot: Robot, features: np.ndarray, blocks: Sequence[Block],
               path: TaskPath, fraction: float) -> list[tuple[float, np.ndarray]]:
    out: list[tuple[float, np.ndarray]] = []
    q_prev, t_free = robot.home, 0.0
    for block in blocks:
        cam = cell.camera(block.camera)
        qs = []
        for t in (block.t0, block.t1):
            T_part, _ = path.at(t)
            qs.append(_blocking_joints(robot, cam.center, T_part, features, fraction,
                                       qs[-1] if qs else q_prev))
        lead = _lead(q_prev, qs[0])
        start = block.t0 - lead
        if start > t_free + 1e-6:  # wait where it is until it must leave
            out.append((start, q_prev))
        out += [(block.t0, qs[0]), (block.t1, qs[1])]
        q_prev, t_free = qs[1], block.t1
    out.append((t_free + _lead(q_prev, robot.home), robot.home))
    if out[0][0] <= 0:
        needs = out[0][0] + _lead(robot.home, out[0][1])
        raise CellsightError(f"design-crossing: the first block starts too early: "
                             f"{robot.name} needs until {needs:.1f} s to get there from HOME")
    return out


def _blocking_joints(robot: Robot, centre: np.ndarray, T_part: np.ndarray,
                     features: np.ndarray, fraction: float, near: np.ndarray) -> np.ndarray:
    """Joints putting the TCP ``fraction`` of the way from the part to the camera, tool z
    along the line of sight, the branch nearest ``near``."""
    p = T_part[:3, :3] @ features.mean(axis=0) + T_part[:3, 3]
    z = (p - centre) / np.linalg.norm(p - centre)
    x_home = tcp_frame(robot, robot.home)[0][:3, 0]
    x = x_home - np.dot(x_home, z) * z
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = p + fraction * (centre - p)
    result = solve_ik(robot, T, seeds=24)
    return min((s.q for s in result.solutions), key=lambda q: float(np.abs(q - near).max()))


def _lead(q_from: np.ndarray, q_to: np.ndarray) -> float:
    return max(MIN_LEAD_S, float(np.abs(q_to - q_from).max()) / SPEED + 0.5)


def _judged(cell: Cell, robot: Robot, part: str, blocks: Sequence[Block], path: TaskPath,
            fraction: float, waypoints: list[tuple[float, np.ndarray]],
            predictor: VisibilityPredictor) -> Design:
    task = JointTask(robot.home, [Waypoint(t, q) for t, q in waypoints])
    left, of = [], []
    for block in blocks:
        c = [cam.name for cam in cell.cameras].index(block.camera)
        seen = []
        for t in np.arange(block.t0, block.t1 + 1e-9, STEP_S):
            T_part, joints = path.at(t)
            on, off = seen_with_and_without(predictor, joints, robot, task.at(t), part,
                                            T_part)[:, c]
            seen.append((on, off))
        left.append(max(s[0] for s in seen))
        of.append(max(s[1] for s in seen))
    spans = _elsewhere(cell, robot, part, blocks, path, task, waypoints[-1][0], predictor)
    clearance, closest = _clearance(cell, robot, part, path, task, waypoints[-1][0])
    return Design(waypoints, fraction, left, of, sum(t1 - t0 + 2 * STEP_S for _, t0, t1 in spans),
                  clearance, closest, spans)


def _elsewhere(cell: Cell, robot: Robot, part: str, blocks: Sequence[Block], path: TaskPath,
               task: JointTask, t_end: float, predictor: VisibilityPredictor
               ) -> tuple[tuple[str, float, float], ...]:
    """When a camera sees at most half its features (against the crossing robot at HOME)
    outside its blocks: (camera, first, last sample) s, samples every ``2 STEP_S`` joined
    into spans."""
    names = [cam.name for cam in cell.cameras]
    step = 2 * STEP_S
    spans: list[list] = []
    last: dict[str, list] = {}
    for t in np.arange(0.0, t_end + 1e-9, step):
        T_part, joints = path.at(t)
        on, off = seen_with_and_without(predictor, joints, robot, task.at(t), part, T_part)
        for c, name in enumerate(names):
            inside = any(b.camera == name and b.t0 - 1.0 <= t <= b.t1 + 1.0 for b in blocks)
            if inside or off[c] == 0 or 2 * on[c] > off[c]:
                continue
            span = last.get(name)
            if span is not None and t - span[2] <= step + 1e-9:
                span[2] = float(t)
            else:
                last[name] = [name, float(t), float(t)]
                spans.append(last[name])
    return tuple((c, t0, t1) for c, t0, t1 in sorted(spans, key=lambda s: (s[1], s[0])))


def _clearance(cell: Cell, robot: Robot, part: str, path: TaskPath, task: JointTask,
               t_end: float) -> tuple[float, tuple[str, float]]:
    """The least distance to the other robots and the part along the run's path
    (:func:`~cellsight.experiments.cellcheck.least_distance`), every ``2 STEP_S``."""
    def states():
        for t in np.arange(0.0, t_end + 1e-9, 2 * STEP_S):
            T_part, joints = path.at(t)
            yield float(t), {**joints, robot.name: task.at(t)}, T_part
    least, what, when = least_distance(cell, robot.name, part, states())
    return least, (what, when)

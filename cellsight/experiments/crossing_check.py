"""Experiment 3's crossing checked by ``cellsight check``: whether it blinds a camera (which,
when: the predictor along the crossing, with and without the crossing robot) and its
clearance to the other robots and the part (MuJoCo's distances)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cellsight.model.cell import Cell, Workpiece
from cellsight.model.robot import Robot
from cellsight.occlusion.backends import visibility_predictor
from cellsight.occlusion.predictor import VisibilityPredictor
from cellsight.world import ReplayWorld
from cellsight.world.paths import ConveyorPath, JointTask, Waypoint

if TYPE_CHECKING:
    from cellsight.experiments.task_path import TaskPath


CLEARANCE_M = 0.05  # m: the crossing robot's least distance to the other robots and the part


@dataclass(frozen=True)
class Finding:
    """One check's outcome: ``level`` (error, warning, ok) and one line saying it."""

    level: str
    line: str


def crossing_findings(cell: Cell, part: Workpiece, step_s: float,
                      path: TaskPath | None) -> list[Finding]:
    """The crossing's findings for ``part``, the predictor every ``step_s`` (s) along it
    (``path``: a run's path through the task, else the cell file's poses)."""
    setup = cell.experiments
    if not cell.workpieces:
        return []
    if setup.crossing_robot is None or not setup.crossing_waypoints:
        return [Finding("warning", "experiment 3: the cell file has no crossing "
                                   "(experiments.crossing: robot, waypoints); experiment 3 "
                                   "cannot run")]
    crosser = cell.robot(setup.crossing_robot)
    task = JointTask(crosser.home, [Waypoint(t, q) for t, q in setup.crossing_waypoints])
    predictor = visibility_predictor(cell)
    times = np.arange(0.0, setup.crossing_waypoints[-1][0] + step_s, step_s)
    states = list(_states(cell, part.name, crosser.name, times, path))
    seen = np.zeros((2, len(times), len(cell.cameras)), dtype=int)
    for k, (_, joints, T) in enumerate(states):
        seen[:, k] = seen_with_and_without(predictor, joints, crosser, task.at(times[k]),
                                           part.name, T)
    where = "along the task" if path is not None else "the other robots at HOME"
    return _blinding(cell, crosser.name, times, seen) + _clearance(
        cell, crosser.name, part.name,
        [(t, {**joints, crosser.name: task.at(t)}, T) for t, joints, T in states[::2]], where)


def _states(cell: Cell, part: str, crosser: str, times: np.ndarray,
            path: TaskPath | None) -> Iterator[tuple[float, dict, np.ndarray]]:
    """(t, the other robots' joints, the part's pose) at ``times``: from ``path``, else the
    part on the conveyor (its start pose when it has none) and the robots left out (HOME)."""
    setup = cell.experiments
    conveyor = (None if setup.conveyor_points is None or not len(setup.conveyor_points) else
                ConveyorPath(np.asarray(setup.conveyor_points, dtype=float), setup.conveyor_speed,
                             setup.conveyor_t_start))
    for t in times:
        if path is not None:
            T, joints = path.at(float(t))
            yield float(t), {r: q for r, q in joints.items() if r != crosser}, T
            continue
        T = cell.workpiece(part).T_base_part.copy()
        if conveyor is not None:
            T[:2, 3] = conveyor.position(t)
        yield float(t), {}, T


def seen_with_and_without(predictor: VisibilityPredictor, joints: dict, robot: Robot,
                          q: np.ndarray, part: str, T_part: np.ndarray) -> np.ndarray:
    """(2, C): the features of ``part`` (at ``T_part``) each camera sees with ``robot`` at
    ``q``, and with it at HOME; the other robots at ``joints`` (left out: HOME)."""
    return np.array([[v.count for v in predictor.predict({**joints, robot.name: at},
                                                         {part: T_part})[part]]
                     for at in (q, robot.home)])


def _blinding(cell: Cell, crosser: str, times: np.ndarray, seen: np.ndarray) -> list[Finding]:
    """Which camera the crossing blinds and when, from the features seen (2, T, C): with the
    crossing robot on its way, and left at HOME."""
    blinded = (seen[0] * 2 <= seen[1]) & (seen[1] > 0)
    out = []
    for c, cam in enumerate(cell.cameras):
        if blinded[:, c].any():
            ks = np.flatnonzero(blinded[:, c])
            out.append(Finding("ok", f"experiment 3: {crosser} blinds {cam.name} from "
                                     f"{times[ks[0]]:.1f} to {times[ks[-1]]:.1f} s (fewest "
                                     f"visible {seen[0, ks, c].min()} of "
                                     f"{seen[1, ks, c].max()})"))
    if not out:
        fewest = ", ".join(f"{cam.name} {seen[0, :, c].min()}" for c, cam
                           in enumerate(cell.cameras))
        out.append(Finding("error", f"experiment 3: {crosser}'s crossing blinds no camera "
                                    f"(fewest features visible: {fewest})"))
    return out


def _clearance(cell: Cell, crosser: str, part: str,
               states: list[tuple[float, dict, np.ndarray]], where: str) -> list[Finding]:
    """The crossing robot's least distance to the other robots' solids and the part over
    ``states`` (:func:`least_distance`); ``where`` says where the others were."""
    least, what, when = least_distance(cell, crosser, part, states)
    line = (f"experiment 3 ({where}): {crosser} keeps {least * 100:.1f} cm from the other "
            f"robots and the part (closest: {what}, at {when:.1f} s)")
    return [Finding("error" if least < CLEARANCE_M else "ok",
                    line + (f", under {CLEARANCE_M * 100:g} cm" if least < CLEARANCE_M else ""))]


def least_distance(cell: Cell, robot: str, part: str,
                   states: Iterable[tuple[float, dict, np.ndarray]]) -> tuple[float, str, float]:
    """The least distance (m; MuJoCo ``mj_geomDistance``, up to 1 m) between ``robot``'s solids
    and the other robots' and the workpiece ``part``'s, over ``states`` (time s, robot name ->
    joints (robots left out keep their last, at first HOME), the part's pose); with the
    closest solid's name and the time."""
    import mujoco  # after cellsight.world, which chooses MuJoCo's OpenGL back-end

    world = ReplayWorld(cell)
    model, data = world.scene.model, world.scene.data
    names = [model.geom(g).name for g in range(model.ngeom)]
    others = {r.name for r in cell.robots} - {robot}
    mine = [g for g, n in enumerate(names) if n.startswith(f"{robot}.")]
    theirs = [g for g, n in enumerate(names) if n == part or (
        "." in n and n.split(".")[0] in others)]
    fromto, least, what, when = np.zeros(6), np.inf, "", 0.0
    try:
        for t, joints, T_part in states:
            world.show_state(joints, {part: T_part})
            for i in mine:
                for j in theirs:
                    d = mujoco.mj_geomDistance(model, data, i, j, 1.0, fromto)
                    if d < least:
                        least, what, when = d, names[j], t
    finally:
        world.close()
    return float(least), what, float(when)

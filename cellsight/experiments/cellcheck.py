"""The checks of a cell file before anything runs (``cellsight check``): one line per problem.

- **Size and units:** each robot's reach (the farthest its TCP, or flange, gets from its base
  over ``REACH_SAMPLES`` random joint vectors inside the limits) against industrial arms'
  ``REACH_M`` range, and each workpiece's size against ``PART_M``: a file in inches, tenths
  of an inch or millimetres read as metres is 25.4x, 2.54x or 1000x too large.
- **The tool on its flange:** along the tool's z (its approach), the flange link's solids
  should end near the tool frame's origin: reaching more than ``MOUNT_M`` past it puts the
  gripper inside the arm (a flange link short of the real flange, such as a ``tool0`` at the
  wrist centre: set the tool's ``mount``), ending more than ``MOUNT_M`` before it leaves the
  gripper in the air; a warning either way.
- **Supports:** each robot's base stands on something: the bottom of its base's solids (its
  frame's origin without any) within ``SUPPORT_M`` of the floor (z = 0) or of the top of a
  static object's solid under it (its bounding box's, around the base's origin); a warning otherwise
  (a base left in the air: a wrong height or a missing pedestal).
- **Joint limits:** HOME, FINAL and the crossing's waypoints inside every joint's limits by at
  least ``LIMIT_MARGIN`` (rad or m): a joint on its limit passes the loader and stops the run
  at its first control step.
- **Key poses in view:** the part (each of a line's picks) at its start, at the conveyor's
  end, and held at the grasping robot's HOME and FINAL (by its grasp): every feature point
  inside each camera's image by ``margin_px``; an error when outside, a warning when within
  the margin; but outside or within the margin of a camera while at least
  :data:`MIN_WHOLE_VIEWS` others hold it whole (a line's cameras each see a stretch of it):
  ok, saying so.
- **The other robots out of the views:** each robot but the grasping one, at HOME, with the
  part at those key poses (the grasping robot at HOME, or at FINAL for the part held there):
  a warning for every camera from which it hides features (in experiments 1 and 2 it stays
  at HOME, "out of the cameras' view"; a HOME on a line of sight blinds a camera for the
  whole run).
- **Reach along the task:** the grasping robot's TCP followed from HOME, as the CLIK does
  (damped least squares from the last joints, every step clipped to the limits), over the part
  (``APPROACH_M`` above the grasp) and at the grasp, with the part at its start and every
  ``REACH_STEP_M`` along the conveyor, then holding it at HOME's and FINAL's TCP poses: an error
  where the joints cannot get within the task's tolerances (``TaskTolerances``: 5 mm, 2°);
  and the tool at each grasp against the static objects (MuJoCo's distances): an error where
  it goes more than that tolerance into one (contacts push the arm back), a warning where it
  touches.
- **Experiment 3's crossing:** along the crossing (every ``step_s``), the part on the conveyor
  and the grasping robot at HOME (or, given a run of the task, ``path``, the part and the other
  robots where that run had them), the features each camera sees (the occlusion predictor) with
  the crossing robot where its waypoints put it, against the same with it left at HOME. A
  camera is blinded while it sees at most half of them; the crossing must blind one. And the
  crossing robot's clearance to the other robots and the part there (MuJoCo's distances
  between their solids): an error below ``CLEARANCE_M``.

Each finding has a ``level``: ``error`` (the run would fail, or measure nothing the user
meant), ``warning`` (worth a look) or ``ok`` (a check passed, with its figure).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cellsight.camera import border_distance
from cellsight.control.ik import converge
from cellsight.control.task import TaskTolerances
from cellsight.experiments.crossing_check import Finding, crossing_findings
from cellsight.experiments.scenario import belt_place, place_pose
from cellsight.model.cell import Cell, Workpiece
from cellsight.model.grasp import HALF_TURN_Z, grasp_opening, grasp_pose
from cellsight.model.robot import Robot
from cellsight.occlusion.backends import visibility_predictor
from cellsight.world import ReplayWorld
from cellsight.world.contacts import mount_pairs
from cellsight.world.paths import ConveyorPath

if TYPE_CHECKING:
    from cellsight.experiments.task_path import TaskPath

REACH_M = (0.2, 4.0)  # m: the reach of industrial and collaborative arms, with room
PART_M = (0.005, 2.0)  # m: a workpiece's bounding-box diagonal
MIN_WHOLE_VIEWS = 2  # cameras holding a key pose whole, beyond which another may not see it
REACH_SAMPLES = 400
LIMIT_MARGIN = 1e-6  # rad or m
MOUNT_M = 0.05  # m: how far the flange link may end from the tool frame along its approach
SUPPORT_M = 0.02  # m: a robot's base this close above the floor or a static object stands on it
REACH_STEP_M = 0.02  # m between the part's positions along the conveyor checked for reach
APPROACH_M = 0.05  # m: the approach pose over the grasp (the task's approach height)


def check_cell(cell: Cell, *, margin_px: float = 20.0, step_s: float = 0.1,
               crossing: bool = True, path: TaskPath | None = None) -> list[Finding]:
    """Every check of the module docstring on ``cell``, in that order; ``crossing``: with
    experiment 3's crossing (the slow ones: the predictor and MuJoCo along the crossing);
    ``path``: a run of the task (experiment 2) giving the part's pose and the other robots'
    joints along the crossing (default: the part on the conveyor, the robots at HOME)."""
    findings = (_units(cell) + _mounts(cell) + _supports(cell) + _limits(cell)
                + _key_poses(cell, margin_px) + _idle_robots(cell)
                + _task_reach(cell))
    return findings + (crossing_findings(cell, _workpiece(cell), step_s, path) if crossing else [])


def _units(cell: Cell) -> list[Finding]:
    out = []
    rng = np.random.default_rng(0)
    for robot in cell.robots:
        reach = max(_reach(robot, robot.chain.random_q(rng)) for _ in range(REACH_SAMPLES))
        if not REACH_M[0] <= reach <= REACH_M[1]:
            out.append(Finding("error", f"robot {robot.name}: reaches {reach:.2f} m from its base"
                                        f", outside the {REACH_M[0]}-{REACH_M[1]} m of real arms"
                                        f"{_scale_hint(reach, 1.2)}"))
        else:
            out.append(Finding("ok", f"robot {robot.name}: reaches {reach:.2f} m"))
    for part in cell.workpieces:
        v = part.solid.vertices
        size = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
        if not PART_M[0] <= size <= PART_M[1]:
            out.append(Finding("error", f"workpiece {part.name}: {size:.3f} m across, outside "
                                        f"{PART_M[0]}-{PART_M[1]} m{_scale_hint(size, 0.2)}"))
    return out


def _mounts(cell: Cell) -> list[Finding]:
    out = []
    for robot in cell.robots:
        if robot.tool is None:
            continue
        frame, link, solids = robot.link_groups()[-1]
        T_tool = robot.tool_pose(robot.home)
        T_link = robot.link_poses(robot.home)[frame]
        if not solids:
            continue
        v = np.vstack([s.vertices for s in solids]) @ T_link[:3, :3].T + T_link[:3, 3]
        end = float(((v - T_tool[:3, 3]) @ T_tool[:3, 2]).max())
        if end > MOUNT_M:
            out.append(Finding("warning", f"robot {robot.name}: {link} reaches {end * 1e3:.0f} mm "
                                          f"past the tool's mount along its approach: the "
                                          f"gripper sits inside the arm (is the flange link "
                                          f"short of the real flange? set tool.mount)"))
        elif end < -MOUNT_M:
            out.append(Finding("warning", f"robot {robot.name}: {link} ends {-end * 1e3:.0f} mm "
                                          f"before the tool's mount: the gripper floats off "
                                          f"the flange (tool.mount)"))
    return out


def _supports(cell: Cell) -> list[Finding]:
    tops = []
    for obj in cell.static:
        for solid in obj.solids:
            v = solid.vertices @ obj.T_base_obj[:3, :3].T + obj.T_base_obj[:3, 3]
            tops.append((v[:, :2].min(axis=0), v[:, :2].max(axis=0), float(v[:, 2].max())))
    out = []
    for robot in cell.robots:
        origin = robot.T_base_robot[:3, 3]
        base = [s.vertices for frame, _, solids in robot.link_groups() if frame == 0
                for s in solids]
        bottom = (float((np.vstack(base) @ robot.T_base_robot[:3, :3].T)[:, 2].min()
                        + origin[2]) if base else float(origin[2]))
        under = [top for lo, hi, top in tops if np.all(lo - SUPPORT_M <= origin[:2])
                 and np.all(origin[:2] <= hi + SUPPORT_M)]
        if abs(bottom) <= SUPPORT_M or any(abs(bottom - top) <= SUPPORT_M for top in under):
            continue
        below = max([t for t in under if t < bottom] + [0.0])
        out.append(Finding("warning", f"robot {robot.name}: its base stands on nothing: its "
                                      f"bottom is {100 * (bottom - below):.1f} cm above "
                                      f"{'the floor' if below == 0.0 else 'the object under it'}"
                                      f" (base z = {origin[2]:g} m: a wrong height, or a "
                                      f"missing pedestal?)"))
    return out


def _reach(robot: Robot, q: np.ndarray) -> float:
    T = robot.tcp_pose(q) if robot.tool is not None else robot.link_poses(q)[-1]
    return float(np.linalg.norm(T[:3, 3] - robot.T_base_robot[:3, 3]))


def _scale_hint(value: float, typical: float) -> str:
    """Which unit mistakes ``value`` (m) looks like: those that bring it within 3x of a
    ``typical`` value, the closest first."""
    if value <= REACH_M[1]:
        return ""
    units = (("inches", 1 / 0.0254), ("tenths of an inch", 1 / 0.00254),
             ("millimetres", 1000.0), ("centimetres", 100.0))
    near = sorted((abs(np.log(value / factor / typical)), name, factor)
                  for name, factor in units if abs(np.log(value / factor / typical)) < np.log(3))
    if not near:
        return ""
    guesses = " or ".join(f"{name} (x {factor:g})" for _, name, factor in near)
    return f": is the file in {guesses}? set its unit in the cell file"


def _limits(cell: Cell) -> list[Finding]:
    out = []
    setup = cell.experiments
    for robot in cell.robots:
        named = [("HOME", robot.home)] + ([("FINAL", robot.final)] if robot.final is not None
                                          else [])
        if setup.crossing_robot == robot.name:
            named += [(f"crossing waypoint at {t:g} s", q) for t, q in setup.crossing_waypoints]
        for what, q in named:
            out += _joint_limits(robot, what, np.asarray(q, dtype=float))
    return out or [Finding("ok", "joint vectors: inside their limits")]


def _joint_limits(robot: Robot, what: str, q: np.ndarray) -> list[Finding]:
    qlim = robot.chain.qlim
    out = []
    for j in np.flatnonzero((q < qlim[:, 0] + LIMIT_MARGIN) | (q > qlim[:, 1] - LIMIT_MARGIN)):
        where = "past" if not qlim[j, 0] <= q[j] <= qlim[j, 1] else "on"
        out.append(Finding("error", f"robot {robot.name}: {what}: joint {j + 1} = {q[j]:.6g} is "
                                    f"{where} its limit [{qlim[j, 0]:.6g}, {qlim[j, 1]:.6g}]"))
    return out


def _key_states(cell: Cell, part: Workpiece) -> list[tuple[str, dict, np.ndarray]]:
    """The part's key poses, each named, with the grasping robot's joints there (empty: HOME):
    at its start, at the conveyor's end, and held at the grasping robot's HOME and FINAL (by
    its grasp)."""
    setup = cell.experiments
    states = [("at its start", {}, part.T_base_part)]
    if setup.conveyor_points is not None and len(setup.conveyor_points):
        end = part.T_base_part.copy()  # the path is the first pick's; the others keep places
        end[:2, 3] = (setup.conveyor_points[-1]
                      + belt_place(cell.picked_workpieces()[0], part, None))
        states.append(("at the conveyor's end", {}, end))
    robot = _grasping(cell)
    if robot is not None and robot.tool is not None:
        T_tcp_part = np.linalg.inv(grasp_pose(part, robot.tool))
        names = [p.name for p in cell.picked_workpieces()]
        place = place_pose(cell, robot, names.index(part.name)) if part.name in names else None
        for name, q in (("HOME", robot.home), ("FINAL", robot.final)):
            if q is not None:
                T = place if name == "FINAL" and place is not None else robot.tcp_pose(q)
                moved = ", moved to its place (experiments.place_step)" if T is place else ""
                states.append((f"held at {robot.name}'s {name}{moved}", {robot.name: q},
                               T @ T_tcp_part))
    return states


def _key_poses(cell: Cell, margin_px: float) -> list[Finding]:
    if not cell.workpieces or not cell.cameras:
        return []
    picks = cell.picked_workpieces()
    out = []
    for part in picks:
        name = "part" if len(picks) == 1 else part.name
        for what, _, T in _key_states(cell, part):
            points = part.feature_points @ T[:3, :3].T + T[:3, 3]
            worst = [float(border_distance(cam, cam.project(points)).min())
                     for cam in cell.cameras]
            whole = sum(w >= margin_px for w in worst)
            for cam, w in zip(cell.cameras, worst, strict=True):
                level = "error" if w < 0 else "warning" if w < margin_px else "ok"
                text = f"{-w:.0f} px out of" if w < 0 else f"{w:.0f} px inside"
                note = f" (margin {margin_px:g} px)" if level != "ok" else ""
                if level != "ok" and whole >= MIN_WHOLE_VIEWS:
                    level, note = "ok", f" ({whole} other cameras hold it whole)"
                out.append(Finding(level, f"{name} {what}: {text} {cam.name}'s image{note}"))
    return out


def _idle_robots(cell: Cell) -> list[Finding]:
    """The module docstring's check of the other robots at HOME, out of the views."""
    grasping = _grasping(cell)
    others = [r for r in cell.robots if grasping is None or r.name != grasping.name]
    if not cell.workpieces or not cell.cameras or not others:
        return []
    part = _workpiece(cell)
    states = _key_states(cell, part)
    predictor = visibility_predictor(cell)
    out = []
    for robot in others:
        hidden: dict[str, list[str]] = {}
        for what, joints, T in states:
            views = predictor.predict(joints, {part.name: T})[part.name]
            for view in views:
                count = sum(r.startswith(f"{robot.name}.") for r in view.reason)
                if count:
                    hidden.setdefault(view.camera, []).append(f"{count} with the part {what}")
        for camera, where in hidden.items():
            out.append(Finding("warning", f"{robot.name} at HOME hides features from {camera}: "
                                          f"{'; '.join(where)} (of {len(part.feature_points)}; "
                                          f"in experiments 1 and 2 it stays there)"))
        if not hidden:
            out.append(Finding("ok", f"{robot.name} at HOME hides no feature from any camera"))
    return out


def _part_positions(cell: Cell, part: Workpiece) -> list[tuple[str, np.ndarray]]:
    """The part's start pose, then its pose every ``REACH_STEP_M`` along the conveyor
    (:class:`~cellsight.world.paths.ConveyorPath` at 1 m/s: its position at ``t`` s is ``t`` m
    along; the part's height and orientation kept), each named."""
    setup = cell.experiments
    out = [("at its start", part.T_base_part)]
    if setup.conveyor_points is None or len(setup.conveyor_points) < 2:
        return out
    path = ConveyorPath(np.asarray(setup.conveyor_points, dtype=float), 1.0)
    for s in np.arange(REACH_STEP_M, path.length + 1e-9, REACH_STEP_M):
        T = part.T_base_part.copy()
        T[:2, 3] = path.position(float(s))
        out.append((f"{100 * s:.0f} cm along the conveyor", T))
    return out


def _task_reach(cell: Cell) -> list[Finding]:
    """The module docstring's reach along the task, for the grasping robot."""
    robot = _grasping(cell)
    if robot is None or robot.tool is None or not cell.workpieces:
        return []
    part = _workpiece(cell)
    tol = TaskTolerances()
    T_part_tcp = grasp_pose(part, robot.tool)
    turned = T_part_tcp @ HALF_TURN_Z  # the same grasp, half a turn about the approach axis
    raised = np.eye(4)
    raised[2, 3] = APPROACH_M
    q, misses, grasps = robot.home, [], []
    for where, T_part in _part_positions(cell, part):
        tries = [_follow(robot, q, [raised @ T_part @ g, T_part @ g], tol)
                 for g in (T_part_tcp, turned)]
        q_end, error = next((t for t in tries if t[1] is None), tries[0])
        if error is not None:
            misses.append(f"the grasp with the part {where} ({error})")
            continue
        q = q_end
        grasps.append((where, q))
    for name, q_key in (("HOME", robot.home), ("FINAL", robot.final)):
        if grasps and q_key is not None:  # from the last grasp, then from HOME as reached
            q, error = _follow(robot, q, [robot.tcp_pose(q_key)], tol)
            if error is not None:
                misses.append(f"{name}'s TCP pose holding the part ({error})")
    out = [Finding("error", f"reach: {robot.name} cannot get within the task's tolerances "
                            f"({tol.position * 1e3:g} mm, {np.degrees(tol.angle):.0f} deg) of "
                            f"{what}") for what in misses]
    if not misses:
        out.append(Finding("ok", f"reach: {robot.name} gets within the task's tolerances of the "
                                 f"grasp at {len(grasps)} positions of the part, HOME and FINAL"))
    return out + _grasp_contacts(cell, robot, part, grasps)


def _follow(robot: Robot, q0: np.ndarray, goals: list[np.ndarray],
            tol: TaskTolerances) -> tuple[np.ndarray, str | None]:
    """The joints reaching ``goals`` in turn from ``q0`` (:func:`converge`), and None; or, at
    the first goal missed, the joints that came closest and how far they stayed."""
    q = q0
    for T in goals:
        q, (e_m, e_rad) = converge(robot, T, q, 1e-5, 1e-4)
        if e_m > tol.position or e_rad > tol.angle:
            return q, f"{e_m * 1e3:.1f} mm and {np.degrees(e_rad):.1f} deg away"
    return q, None


def _grasp_contacts(cell: Cell, robot: Robot, part: Workpiece,
                    grasps: list[tuple[str, np.ndarray]]) -> list[Finding]:
    """The robot's deepest way into a static object over the grasps reached (MuJoCo's signed
    distances between the robot's solids and the static objects', jaws at the grasp's
    opening or open; mounts left out: :func:`~cellsight.world.contacts.mount_pairs`)."""
    import mujoco  # after cellsight.world, which chooses MuJoCo's OpenGL back-end

    if not grasps or not cell.static:
        return []
    world = ReplayWorld(cell)
    model, data = world.scene.model, world.scene.data
    mounts = mount_pairs(world.scene, cell)
    names = [model.geom(g).name for g in range(model.ngeom)]
    static = {obj.name for obj in cell.static}
    mine = [g for g, n in enumerate(names) if n.startswith(f"{robot.name}.")]
    theirs = [g for g, n in enumerate(names) if n.split(".")[0] in static or n in static]
    opening = grasp_opening(part.solid, robot.tool, grasp_pose(part, robot.tool))
    fromto, deepest, what, where = np.zeros(6), np.inf, "", ""
    try:
        for at, q in grasps:
            world.show_state({robot.name: q}, {}, {robot.name: opening or robot.tool.max_opening})
            for i in mine:
                for j in theirs:
                    if (min(i, j), max(i, j)) in mounts:
                        continue
                    d = mujoco.mj_geomDistance(model, data, i, j, 0.05, fromto)
                    if d < deepest:
                        deepest, what, where = d, f"{names[i]} into {names[j]}", at
    finally:
        world.close()
    tol = TaskTolerances().position
    if deepest >= 0:
        return [Finding("ok", f"reach: {robot.name} clears the static objects at every "
                              f"grasp reached (least {100 * min(deepest, 0.05):.1f} cm)")]
    line = (f"reach: {robot.name} at the grasp with the part {where}: {what} by "
            f"{-deepest * 1e3:.2f} mm")
    if -deepest > tol:
        return [Finding("error", line + f", more than the task's {tol * 1e3:g} mm: contacts "
                                        f"push the arm back; raise the grasp")]
    return [Finding("warning", line + " (contacts push back in a world of MuJoCo's actuators)")]


def _workpiece(cell: Cell) -> Workpiece:
    """The part of the experiments: the cell file's ``experiments.workpiece`` (a line's first
    pick), else the first."""
    return cell.picked_workpieces()[0]


def _grasping(cell: Cell) -> Robot | None:
    setup = cell.experiments
    if setup.robot is not None:
        return cell.robot(setup.robot)
    return next((r for r in cell.robots if r.tool is not None), None)



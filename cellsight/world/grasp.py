"""Parallel-jaw grippers in the world: the jaws' motion and when a grasp engages
(:class:`Grippers`), by the grasp geometry of :mod:`cellsight.model.grasp`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from cellsight.geometry.transforms import invert_pose, transform_points
from cellsight.model import Cell
from cellsight.model.grasp import JawPads, PartSection, grasp_error, grasp_poses
from cellsight.world.mjcf import body_name, tcp_site_name
from cellsight.world.paths import PartMotion
from cellsight.world.scene import Scene


@dataclass(frozen=True)
class Grasp:
    """A grasp that engaged: the ``part`` welded to the TCP and how far the TCP was from the
    part's grasp pose at that instant (``position_error_m``, m; ``angle_error_rad``, rad)."""

    part: str
    position_error_m: float
    angle_error_rad: float


@dataclass
class _Jaws:
    """One gripper: ``opening`` and ``command`` (m); the workpiece the jaws are closed on
    (``clamped``), the one welded to the TCP (``holding``) and that grasp's error
    (``error``: m, rad)."""

    opening: float
    command: float
    clamped: str | None = None
    holding: str | None = None
    error: tuple[float, float] | None = None


class Grippers:
    """The pneumatic parallel grippers of every robot with a tool.

    The jaw opening moves towards the commanded opening at ``jaw_speed`` (m/s) and stops when
    both jaws touch a part lying between them (a jaw that touches first pushes the part
    sideways along the jaws' axis, in the horizontal plane, until the other one touches,
    centring it as a real parallel gripper does). The grasp engages only when the jaws are
    closed on the part *and* the TCP is within ``tolerance`` (m, rad) of the part's grasp pose
    (:func:`grasp_error`); from then on the part is welded to the TCP at its relative pose of
    that instant. It is released as soon as the jaws open. ``dt``: the control period (s).
    """

    def __init__(self, scene: Scene, cell: Cell, parts: PartMotion,
                 grasps: Mapping[str, np.ndarray], tolerance: tuple[float, float],
                 jaw_speed: float, dt: float) -> None:
        self.scene, self.parts = scene, parts
        self.tolerance = (float(tolerance[0]), float(tolerance[1]))
        self.jaw_speed, self.dt = float(jaw_speed), float(dt)
        self._grasp = grasp_poses(cell, grasps)
        self._sections = {p.name: PartSection(p.solid) for p in cell.workpieces}
        self._tools = {r.name: r.tool for r in cell.robots if r.tool is not None}
        self._jaws = {name: _Jaws(t.max_opening, t.max_opening) for name, t in self._tools.items()}
        self._pads = {name: JawPads.of(t) for name, t in self._tools.items()}
        m = scene.model
        self._jaw_adr = {
            name: [m.jnt_qposadr[m.joint(body_name(name, j)).id] for j in ("jaw1", "jaw2")]
            for name in self._tools
        }
        self._tool_body = {name: m.body(body_name(name, "tool")).id for name in self._tools}
        self._tcp_site = {name: m.site(tcp_site_name(name)).id for name in self._tools}
        for name in self._tools:
            self._write(name)

    def command(self, openings: Mapping[str, float]) -> None:
        """Command jaw openings (robot name -> m, clipped to the gripper's range); a command
        stays in force until the next one."""
        for name, opening in openings.items():
            self._jaws[name].command = float(min(max(float(opening), 0.0),
                                                 self._tools[name].max_opening))

    def step(self) -> None:
        """One control period: move every gripper's jaws, then the held parts with the TCPs."""
        for robot, jaws in self._jaws.items():
            if jaws.command > jaws.opening:
                self._open(robot)
            elif jaws.holding is None and (jaws.command != jaws.opening
                                           or jaws.clamped is not None):
                self._close(robot)
        for robot, jaws in self._jaws.items():
            if jaws.holding is not None:
                self.parts.carry(jaws.holding, self.tcp_pose(robot))

    def openings(self) -> dict[str, float]:
        """Jaw opening (m) of every robot with a gripper, read from MuJoCo."""
        qpos = self.scene.data.qpos
        return {name: self._tools[name].opening_of(qpos[adr[0]])
                for name, adr in self._jaw_adr.items()}

    def set_opening(self, robot: str, opening: float) -> None:
        """Put the jaws at an opening (m, clipped to the gripper's range) at once, holding
        nothing: a replayed state, not a motion."""
        jaws = self._jaws[robot]
        jaws.opening = jaws.command = float(np.clip(opening, 0.0, self._tools[robot].max_opening))
        jaws.clamped = jaws.holding = None
        self._write(robot)

    def clamped(self, robot: str) -> str | None:
        """The workpiece the robot's jaws are closed on (both jaws touch it), or None."""
        return self._jaws[robot].clamped

    def grasp(self, robot: str) -> Grasp | None:
        """The robot's engaged grasp (the part it holds and the TCP's error from its grasp pose
        then, :func:`grasp_error`), or None while it holds nothing."""
        jaws = self._jaws[robot]
        return None if jaws.holding is None else Grasp(jaws.holding, *jaws.error)

    def grasp_pose(self, name: str) -> np.ndarray:
        """``T_part_tcp`` of the grasp that engages for this workpiece."""
        return self._grasp[name].copy()

    def let_go(self, name: str) -> None:
        """No gripper holds this workpiece any more (it was moved by hand)."""
        for jaws in self._jaws.values():
            if jaws.holding == name:
                jaws.holding = None

    def tcp_pose(self, robot: str) -> np.ndarray:
        """``T_base_tcp`` of the robot's gripper, read from MuJoCo."""
        return self.scene.site_pose(self._tcp_site[robot])

    def _open(self, robot: str) -> None:
        """Opening: let go of everything."""
        jaws = self._jaws[robot]
        jaws.opening = min(jaws.command, jaws.opening + self.jaw_speed * self.dt)
        if jaws.holding is not None:
            self.parts.release(jaws.holding)
            jaws.holding = None
        jaws.clamped = None
        self._write(robot)

    def _close(self, robot: str) -> None:
        """Closing (or holding still, clamped): stop at the first part both jaws touch."""
        jaws = self._jaws[robot]
        T_base_tool = self.scene.body_pose(self._tool_body[robot])
        old = jaws.opening
        new = max(jaws.command, old - self.jaw_speed * self.dt)
        jaws.clamped = None
        for name in self.parts.free():
            new = self._squeeze(robot, name, T_base_tool, old, new)
        jaws.opening = new
        self._write(robot)

    def _squeeze(self, robot: str, name: str, T_base_tool: np.ndarray, old: float,
                 new: float) -> float:
        """The opening the jaws reach closing from ``old`` towards ``new`` (m) on workpiece
        ``name``: they push it to centre it, clamp it, and engage the grasp when the TCP is
        within tolerance of its grasp pose."""
        section, pads = self._sections[name], self._pads[robot]
        T_tool_part = invert_pose(T_base_tool) @ self.parts.pose(name)
        y_all = transform_points(T_tool_part, section.vertices)[:, 1]
        if y_all.max() <= 0.5 * new and y_all.min() >= -0.5 * new:
            return new  # the jaws cannot reach it yet (or it lies beyond their ends)
        r1 = section.y_range(T_tool_part, pads.jaw1)
        r2 = r1 if pads.jaw2 == pads.jaw1 else section.y_range(T_tool_part, pads.jaw2)
        if r1 is None or r2 is None:
            return new
        hi, lo = r1[1], r2[0]
        if hi > 0.5 * old + 1e-3 or lo < -0.5 * old - 1e-3:
            return new  # material beyond a jaw's face: the part is not between the jaws
        new = max(new, hi - lo)
        push = min(0.5 * new - hi, 0.0) + max(-0.5 * new - lo, 0.0)
        if push:
            shift = push * T_base_tool[:3, 1]
            shift[2] = 0.0
            self.parts.push(name, shift)
        if new <= hi - lo + 1e-9:
            jaws = self._jaws[robot]
            jaws.clamped = name
            T_base_grasp = self.parts.pose(name) @ self._grasp[name]
            error = grasp_error(T_base_tool @ self._tools[robot].T_tool_tcp, T_base_grasp)
            if error[0] <= self.tolerance[0] and error[1] <= self.tolerance[1]:
                self.parts.hold(name, self.tcp_pose(robot))
                jaws.holding, jaws.error = name, error
        return new

    def _write(self, robot: str) -> None:
        self.scene.set_qpos(self._jaw_adr[robot],
                            self._tools[robot].jaw_values(self._jaws[robot].opening))

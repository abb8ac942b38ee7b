"""Parallel-jaw grippers: where the jaws meet a part, when a grasp engages (:class:`Grippers`).

Tool frame (see :class:`~cellsight.model.ParallelGripper`): z is the approach direction, the
jaws close along y; jaw 1's gripping face is the plane y = +opening/2 (its body beyond it),
jaw 2's is y = -opening/2. A jaw *pad* is the (x, z) rectangle its solid spans in the tool
frame; the jaw touches the part where the part's material inside that rectangle ends along y.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from cellsight.geometry.polyhedron import Polyhedron
from cellsight.geometry.transforms import invert_pose, make_pose, transform_points
from cellsight.model import Cell, ParallelGripper, Workpiece
from cellsight.world.mjcf import body_name, tcp_site_name
from cellsight.world.paths import PartMotion
from cellsight.world.scene import Scene

_HALF_TURN_Z = np.diag([-1.0, -1.0, 1.0])


def default_grasp_pose(solid: Polyhedron, tool: ParallelGripper) -> np.ndarray:
    """``T_part_tcp`` of a top-down grasp: tool z along the part's -z, the jaws closing across
    the part's narrower horizontal side (part y when it is not wider than the part's x extent),
    the TCP at the centre of the part's bounding box along the other two axes and, along the
    jaws' axis, midway between the two places where the jaws touch the part there (so that
    closing the jaws does not push the part)."""
    lo, hi = solid.vertices.min(axis=0), solid.vertices.max(axis=0)
    ext = hi - lo
    if ext[1] <= ext[0]:  # jaws along part y: tool = (-x, y, -z) of the part
        R = np.diag([-1.0, 1.0, -1.0])
    else:  # jaws along part x: tool = (y, x, -z)
        R = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    T_part_tcp = make_pose(R, 0.5 * (lo + hi))
    contacts = jaw_contacts(solid, tool, T_part_tcp)
    if contacts is not None:
        T_part_tcp[:3, 3] += R[:, 1] * 0.5 * (contacts[0] + contacts[1])
    return T_part_tcp


def jaw_contacts(solid: Polyhedron, tool: ParallelGripper,
                 T_part_tcp: np.ndarray) -> tuple[float, float] | None:
    """Where the closing jaws of ``tool`` first touch ``solid`` held at ``T_part_tcp``: tool y
    (m) of jaw 1's contact (the largest y of the material under its pad) and of jaw 2's (the
    smallest under its own), or None when a pad meets no material."""
    T_tool_part = tool.T_tool_tcp @ invert_pose(T_part_tcp)
    pads, section = JawPads.of(tool), PartSection(solid)
    r1, r2 = section.y_range(T_tool_part, pads.jaw1), section.y_range(T_tool_part, pads.jaw2)
    return None if r1 is None or r2 is None else (r1[1], r2[0])


def grasp_error(T_base_tcp: np.ndarray, T_base_grasp: np.ndarray) -> tuple[float, float]:
    """Position error (m) and rotation error (rad) of the TCP from a grasp pose, the rotation
    taken as the smaller of the two grasps that differ by half a turn about the tool z axis
    (a parallel gripper holds the part either way round)."""
    dp = float(np.linalg.norm(T_base_tcp[:3, 3] - T_base_grasp[:3, 3]))
    R = T_base_grasp[:3, :3].T @ T_base_tcp[:3, :3]
    angles = [Rotation.from_matrix(M).magnitude() for M in (R, _HALF_TURN_Z @ R)]
    return dp, float(min(angles))


@dataclass(frozen=True)
class JawPads:
    """The (x, z) rectangles of jaw 1 and jaw 2 in the tool frame, each (x0, x1, z0, z1)."""

    jaw1: tuple[float, float, float, float]
    jaw2: tuple[float, float, float, float]

    @classmethod
    def of(cls, tool: ParallelGripper) -> JawPads:
        pads = []
        for jaw in tool.jaws:  # the jaws slide along tool y: their (x, z) spans stay
            v = transform_points(jaw.T_tool_jaw0, jaw.solid.vertices)
            pads.append((v[:, 0].min(), v[:, 0].max(), v[:, 2].min(), v[:, 2].max()))
        return cls(*pads)


class PartSection:
    """A part's material as seen by a jaw pad: the range along tool y of the part inside the
    infinite bar ``x0 <= x <= x1, z0 <= z <= z1`` (exact for any polyhedron: the extreme
    points are vertices inside the bar, edges crossing its side planes, or faces crossing its
    four edge lines)."""

    def __init__(self, solid: Polyhedron) -> None:
        self.vertices = solid.vertices
        edges = {tuple(sorted((f[i], f[i - 1]))) for f in solid.faces for i in range(len(f))}
        self.edges = np.array(sorted(edges), dtype=np.int64)
        self.triangles = solid.triangles()

    def y_range(self, T_tool_part: np.ndarray, pad: tuple[float, float, float, float]):
        """(y_min, y_max) of the part's material inside the pad's bar, or None if it has none."""
        x0, x1, z0, z1 = pad
        P = transform_points(T_tool_part, self.vertices)
        x, y, z = P.T
        found = [y[(x >= x0) & (x <= x1) & (z >= z0) & (z <= z1)]]
        a = P[self.edges[:, 0]]
        d = P[self.edges[:, 1]] - a
        A, B, C = (P[self.triangles[:, k]] for k in range(3))
        e1, e2 = (B - A)[:, [0, 2]], (C - A)[:, [0, 2]]
        r = np.array([[x0, z0], [x0, z1], [x1, z0], [x1, z1]])[:, None, :] - A[None, :, [0, 2]]
        with np.errstate(divide="ignore", invalid="ignore"):  # inf/NaN compare False below
            for axis, other, planes, (lo, hi) in ((0, 2, (x0, x1), (z0, z1)),
                                                  (2, 0, (z0, z1), (x0, x1))):
                t = (np.array(planes)[:, None] - a[:, axis]) / d[:, axis]  # edges x side planes
                o = a[:, other] + t * d[:, other]
                hit = (t >= 0) & (t <= 1) & (o >= lo) & (o <= hi)
                found.append((a[:, 1] + t * d[:, 1])[hit])
            det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]  # 0 for faces parallel to y
            u = (r[..., 0] * e2[:, 1] - r[..., 1] * e2[:, 0]) / det  # bar edge lines x faces
            v = (e1[:, 0] * r[..., 1] - e1[:, 1] * r[..., 0]) / det
            hit = (u >= 0) & (v >= 0) & (u + v <= 1)
            found.append((A[:, 1] + u * (B[:, 1] - A[:, 1]) + v * (C[:, 1] - A[:, 1]))[hit])
        y = np.concatenate(found)
        return (float(y.min()), float(y.max())) if y.size else None


def grasp_opening(solid: Polyhedron, tool: ParallelGripper, T_part_tcp: np.ndarray) -> float | None:
    """The opening (m) at which the jaws of ``tool`` close on ``solid`` held at the grasp
    ``T_part_tcp``: the width of the part's material between the two pads
    (:func:`jaw_contacts`), or None when a pad meets none."""
    contacts = jaw_contacts(solid, tool, T_part_tcp)
    return None if contacts is None else contacts[0] - contacts[1]


def grasp_pose(part: Workpiece, tool: ParallelGripper | None) -> np.ndarray:
    """``T_part_tcp`` of ``tool`` holding ``part``: the cell file's ``grasp``, else
    :func:`default_grasp_pose` (which needs the tool)."""
    if part.T_part_grasp is not None:
        return part.T_part_grasp.copy()
    return default_grasp_pose(part.solid, tool)


def grasp_poses(cell: Cell, overrides: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``T_part_tcp`` of each workpiece's grasp: ``overrides`` (workpiece name -> pose), else
    the cell file's ``grasp``, else :func:`default_grasp_pose` for the first robot's gripper (a
    cell without grippers has none). An override naming no workpiece is a KeyError."""
    overrides = dict(overrides)
    gripper = next((r.tool for r in cell.robots if r.tool is not None), None)
    out = {}
    for part in cell.workpieces:
        if part.name in overrides:
            out[part.name] = np.asarray(overrides.pop(part.name), dtype=float)
        elif part.T_part_grasp is not None or gripper is not None:
            out[part.name] = grasp_pose(part, gripper)
    if overrides:
        raise KeyError(f"grasp_poses: no workpiece named {sorted(overrides)}")
    return out


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

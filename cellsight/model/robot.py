"""Robots: a kinematic chain (DH or URDF) placed in the cell, solids per link, and a gripper.

Frames: ``T_base_robot`` is the robot's frame 0 in the cell base frame (from calibration); link
``i``'s solids are given in frame ``i`` of the chain (DH frame i, or the URDF child link of
actuated joint i; frame 0 for the robot's fixed base); the gripper is fixed to frame n by
``T_flange_tool`` (for a URDF robot this includes the fixed offset of its flange link, e.g.
``tool0``). Tool frame: z along the approach direction,
the jaws close along y; the tool centre point ``tcp`` is given in the tool frame (m).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cellsight.geometry.polyhedron import Polyhedron
from cellsight.geometry.transforms import make_pose
from cellsight.kinematics import KinematicChain

_FLIP_Z = make_pose(np.diag([-1.0, -1.0, 1.0]))  # half turn about the tool z axis


@dataclass(frozen=True)
class ParallelGripper:
    """Pneumatic parallel-jaw gripper. ``jaw`` is one jaw's solid in its own frame, with its
    gripping face on the plane y = 0 and its body at y > 0; the jaws sit at y = +-opening/2 in
    the tool frame, the second one turned half a turn about z. Opening in metres."""

    palm: tuple[Polyhedron, ...]
    jaw: Polyhedron
    T_flange_tool: np.ndarray
    max_opening: float
    tcp: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def jaw_poses(self, opening: float) -> tuple[np.ndarray, np.ndarray]:
        """Poses of the two jaws in the tool frame for an opening (m) clipped to [0, max]."""
        half = 0.5 * float(np.clip(opening, 0.0, self.max_opening))
        first = make_pose(None, (0.0, half, 0.0))
        second = make_pose(None, (0.0, -half, 0.0)) @ _FLIP_Z
        return first, second

    @property
    def T_tool_tcp(self) -> np.ndarray:
        """Pose of the tool centre point in the tool frame (same axes as the tool frame)."""
        return make_pose(None, self.tcp)

    def reach_across(self) -> float:
        """How far the palm and the open jaws reach from the TCP across the approach axis (m,
        in the tool's x-y plane): the room the gripper takes around a part it grasps."""
        jaws = [T[:3, :3] @ self.jaw.vertices.T + T[:3, 3:] for T in
                self.jaw_poses(self.max_opening)]
        points = np.hstack([p.vertices.T for p in self.palm] + jaws)
        return float(np.linalg.norm(points[:2] - self.tcp[:2, None], axis=0).max())


@dataclass(frozen=True)
class Robot:
    """A robot of the cell: name, calibrated base pose, kinematic chain, link solids and tool.

    ``link_solids[0]`` are fixed to frame 0 (the base), ``link_solids[i]`` to frame i.
    ``home`` and ``final`` are joint vectors (m for prismatic joints, rad for revolute ones).
    ``solid_links`` names, per frame and per solid, the link the solid belongs to (a URDF
    link's name; a link fixed to frame i carries its own name); None: ``link<i>`` (DH robots).
    Occlusion reports name a robot's link ``<robot>.<link>``. ``max_velocity``: each joint's
    rated speed (rad/s, m/s for a prismatic joint; a URDF's ``limit velocity``, inf where it
    gives none); None: not known (DH robots).
    """

    name: str
    T_base_robot: np.ndarray
    chain: KinematicChain
    link_solids: tuple[tuple[Polyhedron, ...], ...]
    tool: ParallelGripper | None
    home: np.ndarray
    final: np.ndarray | None = None
    solid_links: tuple[tuple[str, ...], ...] | None = None
    max_velocity: np.ndarray | None = None

    @property
    def n_joints(self) -> int:
        return self.chain.n

    def link_groups(self) -> list[tuple[int, str, tuple[Polyhedron, ...]]]:
        """(frame index, link name, its solids) of every link with solids, frame order then
        first appearance; a DH robot's link i is ``link<i>`` (listed even without solids)."""
        if self.solid_links is None:
            return [(i, f"link{i}", solids) for i, solids in enumerate(self.link_solids)]
        groups: list[tuple[int, str, tuple[Polyhedron, ...]]] = []
        for i, (solids, links) in enumerate(zip(self.link_solids, self.solid_links,
                                                strict=True)):
            for link in dict.fromkeys(links):
                groups.append((i, link, tuple(s for s, k in zip(solids, links, strict=True)
                                              if k == link)))
        return groups

    def link_poses(self, q) -> np.ndarray:
        """Poses of frames 0..n in the cell base frame, (n+1, 4, 4)."""
        return self.T_base_robot @ self.chain.fkine(q)

    def tool_pose(self, q) -> np.ndarray:
        """Tool frame in the cell base frame (paper: T^b_i = L^b_{l_i,i}(q) T^i)."""
        if self.tool is None:
            raise ValueError(f"robot {self.name} has no tool")
        return self.link_poses(q)[-1] @ self.tool.T_flange_tool

    def tcp_pose(self, q) -> np.ndarray:
        """Tool centre point in the cell base frame."""
        return self.tool_pose(q) @ self.tool.T_tool_tcp

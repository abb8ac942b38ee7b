"""Robots: a kinematic chain (DH or URDF) placed in the cell, solids per link, and a gripper.

Frames: ``T_base_robot`` is the robot's frame 0 in the cell base frame (from calibration); link
``i``'s solids are given in frame ``i`` of the chain (DH frame i, or the URDF child link of
actuated joint i; frame 0 for the robot's fixed base); the gripper is fixed to frame n by
``T_flange_tool`` (for a URDF robot this includes the fixed offset of its flange link, e.g.
``tool0``). Tool frame: z along the approach direction,
the jaws close along y; the tool centre point ``tcp`` is given in the tool frame (m).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from cellsight.geometry.polyhedron import Polyhedron
from cellsight.geometry.transforms import make_pose
from cellsight.kinematics import KinematicChain

_FLIP_Z = make_pose(np.diag([-1.0, -1.0, 1.0]))  # half turn about the tool z axis


@dataclass(frozen=True)
class Jaw:
    """One jaw of a parallel gripper: ``solid`` in the jaw's own frame, that frame's pose in the
    tool frame when the jaw's joint is at 0 (``T_tool_jaw0``), and the unit direction it slides
    along (``axis``, tool frame). Its joint value follows the gripper's leading joint ``q``
    (m): ``multiplier * q + offset`` (a URDF ``mimic``; 1 and 0 for the leader itself). A URDF
    finger also names its ``joint`` and ``link`` (None for cellsight's own jaws)."""

    solid: Polyhedron
    T_tool_jaw0: np.ndarray
    axis: np.ndarray
    multiplier: float = 1.0
    offset: float = 0.0
    joint: str | None = None
    link: str | None = None

    def value(self, q_leader: float) -> float:
        """This jaw's joint value (m) when the leading joint is at ``q_leader`` (m)."""
        return self.multiplier * float(q_leader) + self.offset

    def pose(self, q_leader: float) -> np.ndarray:
        """The jaw frame in the tool frame when the leading joint is at ``q_leader`` (m)."""
        return make_pose(None, self.value(q_leader) * self.axis) @ self.T_tool_jaw0


@dataclass(frozen=True)
class ParallelGripper:
    """A parallel-jaw gripper: palm solids fixed to the tool frame and two jaws (:class:`Jaw`)
    driven by one leading joint, jaw 1's. The opening is the distance between the jaws' frames
    along tool y: ``opening = opening_at_zero + opening_gain * q_leader`` (m), from 0 to
    ``max_opening``, the leading joint within ``leader_range`` (m). The jaws' gripping faces
    lie on their frames' x-z planes, so the faces are at y = +-opening/2 when the jaws are
    symmetric. :meth:`mirrored` is cellsight's own pneumatic gripper (one jaw's solid, the
    second turned half a turn about z); a URDF's fingers give theirs (:mod:`.urdf`)."""

    palm: tuple[Polyhedron, ...]
    jaws: tuple[Jaw, Jaw]
    T_flange_tool: np.ndarray
    max_opening: float
    tcp: np.ndarray = field(default_factory=lambda: np.zeros(3))
    opening_gain: float = 2.0
    opening_at_zero: float = 0.0
    leader_range: tuple[float, float] | None = None

    @classmethod
    def mirrored(cls, palm: tuple[Polyhedron, ...], jaw: Polyhedron, T_flange_tool: np.ndarray,
                 max_opening: float, tcp=(0.0, 0.0, 0.0)) -> ParallelGripper:
        """Two jaws of one solid (gripping face on its plane y = 0, body at y > 0), at
        y = +-opening/2 in the tool frame, the second turned half a turn about z."""
        y = np.array([0.0, 1.0, 0.0])
        return cls(tuple(palm), (Jaw(jaw, np.eye(4), y), Jaw(jaw, _FLIP_Z, -y)),
                   T_flange_tool, float(max_opening), np.asarray(tcp, dtype=float),
                   leader_range=(0.0, 0.5 * float(max_opening)))

    def leader_value(self, opening: float) -> float:
        """The leading joint's value (m) for an opening (m) clipped to [0, ``max_opening``]."""
        # min and max, not np.clip: a scalar's np.clip costs about 5 us, and every snapshot of
        # the cell clips twice per gripper
        opening = min(max(float(opening), 0.0), self.max_opening)
        q = (opening - self.opening_at_zero) / self.opening_gain
        if self.leader_range is None:
            return q
        low, high = self.leader_range
        return min(max(q, float(low)), float(high))

    def opening_of(self, q_leader: float) -> float:
        """The opening (m) when the leading joint is at ``q_leader`` (m)."""
        return self.opening_at_zero + self.opening_gain * float(q_leader)

    def jaw_values(self, opening: float) -> tuple[float, float]:
        """Both jaws' joint values (m) at an opening (m, clipped to the gripper's range)."""
        q = self.leader_value(opening)
        return self.jaws[0].value(q), self.jaws[1].value(q)

    def jaw_poses(self, opening: float) -> tuple[np.ndarray, np.ndarray]:
        """Poses of the two jaws in the tool frame for an opening (m) clipped to [0, max]."""
        q = self.leader_value(opening)
        return self.jaws[0].pose(q), self.jaws[1].pose(q)

    def with_jaw_solids(self, solids: tuple[Polyhedron, Polyhedron]) -> ParallelGripper:
        """The same gripper with other solids for its jaws (each in its jaw's frame)."""
        return replace(self, jaws=tuple(replace(j, solid=s)
                                        for j, s in zip(self.jaws, solids, strict=True)))

    @property
    def T_tool_tcp(self) -> np.ndarray:
        """Pose of the tool centre point in the tool frame (same axes as the tool frame)."""
        return make_pose(None, self.tcp)

    def reach_across(self) -> float:
        """How far the palm and the open jaws reach from the TCP across the approach axis (m,
        in the tool's x-y plane): the room the gripper takes around a part it grasps."""
        jaws = [T[:3, :3] @ jaw.solid.vertices.T + T[:3, 3:] for jaw, T in
                zip(self.jaws, self.jaw_poses(self.max_opening), strict=True)]
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

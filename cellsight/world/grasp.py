"""Parallel-jaw grasping geometry: where the jaws meet a part, and when a grasp may engage.

Tool frame (see :class:`~cellsight.model.ParallelGripper`): z is the approach direction, the
jaws close along y; jaw 1's gripping face is the plane y = +opening/2 (its body beyond it),
jaw 2's is y = -opening/2. A jaw *pad* is the (x, z) rectangle its solid spans in the tool
frame; the jaw touches the part where the part's material inside that rectangle ends along y.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from cellsight.geometry.polyhedron import Polyhedron
from cellsight.geometry.transforms import invert_pose, make_pose, transform_points
from cellsight.model import ParallelGripper

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
    T_tool_part = tool.T_tool_tcp @ invert_pose(T_part_tcp)
    pads, section = JawPads.of(tool), PartSection(solid)
    r1, r2 = section.y_range(T_tool_part, pads.jaw1), section.y_range(T_tool_part, pads.jaw2)
    if r1 is not None and r2 is not None:
        T_part_tcp[:3, 3] += R[:, 1] * 0.5 * (r1[1] + r2[0])
    return T_part_tcp


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
        v = tool.jaw.vertices  # jaw 1 is only shifted along y; jaw 2 is also turned about z
        x0, x1, z0, z1 = v[:, 0].min(), v[:, 0].max(), v[:, 2].min(), v[:, 2].max()
        return cls((x0, x1, z0, z1), (-x1, -x0, z0, z1))


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

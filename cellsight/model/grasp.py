"""A parallel gripper's grasp geometry, one home for every part of cellsight that needs it (the
task's planner, the world's grippers, the tracker's prior, ``check``, ``ik``, ``track``): the
grasp of a part (the cell file's, else :func:`default_grasp_pose`), its twin turned half a turn
about the approach axis (:data:`HALF_TURN_Z`, :func:`nearer_grasp`), where the closing jaws
touch the part, and the opening that holds it.

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
from cellsight.model.cell import Cell, Workpiece
from cellsight.model.robot import ParallelGripper

HALF_TURN_Z = make_pose(np.diag([-1.0, -1.0, 1.0]))
"""A half turn about the TCP's approach axis (z): a parallel gripper's grasp and its twin."""


def nearer_grasp(T_part_tcp: np.ndarray, T_base_part: np.ndarray,
                 T_near: np.ndarray) -> np.ndarray:
    """Of a parallel gripper's grasp ``T_part_tcp`` and its twin (turned half about the TCP's
    approach axis), the ``T_part_tcp`` whose TCP orientation at the part pose ``T_base_part`` is
    nearer to ``T_near``'s."""
    candidates = (T_part_tcp, T_part_tcp @ HALF_TURN_Z)
    angles = [Rotation.from_matrix(T_near[:3, :3].T @ T_base_part[:3, :3] @ c[:3, :3]).magnitude()
              for c in candidates]
    return candidates[int(np.argmin(angles))]


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
    angles = [Rotation.from_matrix(M).magnitude() for M in (R, HALF_TURN_Z[:3, :3] @ R)]
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


def grasp_pose(part: Workpiece, tool: ParallelGripper | None = None) -> np.ndarray:
    """``T_part_tcp`` of ``tool`` holding ``part``: the cell file's ``grasp``, else
    :func:`default_grasp_pose` (which needs the tool: a ValueError without one). Its twin,
    turned half a turn about the tool z axis, holds the part as well (:func:`nearer_grasp`)."""
    if part.T_part_grasp is not None:
        return part.T_part_grasp.copy()
    if tool is None:
        raise ValueError(f"workpiece {part.name}: no grasp in the cell file, and no gripper to "
                         f"choose one for")
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



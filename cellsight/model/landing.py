"""Where a workpiece let go comes to rest, as the cell file has it.

A part a gripper lets go of falls straight down, without turning, until one of its vertices
meets the top of a static object (a table, a conveyor): the shortest of the downward rays cast
from its vertices onto the static objects' faces (trimesh's ray casts, base frame, metres).
This is the tracker's side of the kinematic prior: the support a let-go part lies on, from the
cell file alone (the simulated world lets its own part fall the same way onto its own, as-built
objects, with MuJoCo's ray casts).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh

from cellsight.geometry.transforms import transform_points
from cellsight.model.cell import StaticObject

PRESSED_M = 0.02
"""A part let go with a vertex up to this far (m) below the top of a support (pressed into it
by jaws that put it down too low: a kinematic part goes where the jaws take it) rests on that
top, here and in the simulated world (:mod:`cellsight.world.paths`); the rays that find the
support start this far above each vertex."""


class Landing:
    """Static objects (a cell's ``static``) as one triangle mesh in the base frame, to drop parts
    on."""

    def __init__(self, static: Sequence[StaticObject]) -> None:
        vertices, triangles, start = [], [], 0
        for obj in static:
            for solid in obj.solids:
                vertices.append(transform_points(obj.T_base_obj, solid.vertices))
                triangles.append(solid.triangles() + start)
                start += len(solid.vertices)
        self._mesh = None if not vertices else trimesh.Trimesh(
            np.concatenate(vertices), np.concatenate(triangles), process=False)

    def rest_pose(self, vertices: np.ndarray, T_base_part: np.ndarray) -> np.ndarray | None:
        """``T_base_part`` lowered onto what lies below the part's ``vertices`` (V, 3, part
        frame) at ``T_base_part`` (4x4; raised onto it, when pressed into it); None when no
        static object lies below any of them."""
        drop = self.drop(vertices, T_base_part)
        if drop is None:
            return None
        T = np.array(T_base_part, dtype=float)
        T[2, 3] -= drop
        return T

    def drop(self, vertices: np.ndarray, T_base_part: np.ndarray) -> float | None:
        """How far (m) the part's ``vertices`` (V, 3, part frame) at ``T_base_part`` fall
        straight down before one meets a static object: 0 when one touches it, negative when
        one is pressed into it (by up to :data:`PRESSED_M`); None when no static object lies
        below any of them."""
        if self._mesh is None:
            return None
        origins = transform_points(T_base_part, vertices) + [0.0, 0.0, PRESSED_M]
        down = np.tile([0.0, 0.0, -1.0], (len(origins), 1))
        hits, rays, _ = self._mesh.ray.intersects_location(origins, down, multiple_hits=True)
        drops = origins[rays, 2] - hits[:, 2] - PRESSED_M
        drops = drops[drops >= -PRESSED_M]  # below the ray's start, not behind it
        return float(drops.min()) if len(drops) else None

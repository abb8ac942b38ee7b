"""Every surface of a cell in flat arrays, each in its own object's frame: what every
cell-level back-end (:mod:`cellsight.occlusion.predictor`) starts from."""

from __future__ import annotations

import numpy as np

from cellsight.model.cell import Cell, Snapshot
from cellsight.occlusion._frame_kernel import transform_vertices


class CellSurfaces:
    """The faces of every object of ``cell`` (``cell.objects`` order), in flat arrays.

    Polygon p is face ``poly_source[p]`` = (object index, face index) of the cell's objects:
    ``local_vertices[offsets[p]:offsets[p + 1]]`` (V, 3), in its object's frame (m), owned by
    object ``poly_owner[p]`` (P,) int32; ``vertex_owner`` (V,): each vertex's object. Object k
    owns polygons ``object_polys[k]:object_polys[k + 1]`` (K+1,), is a closed solid when
    ``object_closed[k]`` and has the kind ``kinds[k]`` (``"static"``, ``"workpiece"``, ...).
    ``static_vertices`` (V, 3): every vertex at the cell's nominal poses (base frame, m), final
    for the static objects, whose poses never change.
    """

    def __init__(self, cell: Cell) -> None:
        verts, offsets, owner, vertex_owner, self.poly_source = [], [0], [], [], []
        for k, obj in enumerate(cell.objects):
            for f, face in enumerate(obj.solid.faces):
                self.poly_source.append((k, f))
                verts.append(obj.solid.vertices[list(face)])
                offsets.append(offsets[-1] + len(face))
                owner.append(k)
                vertex_owner.extend([k] * len(face))
        self.local_vertices = np.concatenate(verts)
        self.offsets = np.asarray(offsets, dtype=np.int64)
        self.poly_owner = np.asarray(owner, dtype=np.int32)
        self.vertex_owner = np.asarray(vertex_owner, dtype=np.int64)
        self.object_closed = np.array([o.solid.closed for o in cell.objects])
        self.object_polys = np.searchsorted(self.poly_owner, np.arange(len(cell.objects) + 1))
        self.kinds = np.array([o.kind for o in cell.objects])
        self._moving = np.flatnonzero(self.kinds[self.vertex_owner] != "static")
        self.static_vertices = np.zeros_like(self.local_vertices)
        transform_vertices(self.local_vertices, self.vertex_owner,
                           np.arange(len(self.local_vertices)), cell.snapshot().poses,
                           self.static_vertices)

    def __len__(self) -> int:
        """The number of polygons."""
        return len(self.poly_owner)

    def world_vertices(self, snapshot: Snapshot) -> np.ndarray:
        """Every surface vertex in the base frame for this snapshot, (V, 3) (m)."""
        out = self.static_vertices.copy()
        transform_vertices(self.local_vertices, self.vertex_owner, self._moving, snapshot.poses,
                           out)
        return out

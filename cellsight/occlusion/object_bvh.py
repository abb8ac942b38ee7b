"""The ``object-bvh`` back-end (the default; issue 12): the static per-object hierarchies of
:mod:`.forest`, built once, offline, in each object's frame; per frame only the queries (the
optical centres and the features with their near-occluder rings) move into each object's
frame. Nothing is culled or rebuilt."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from cellsight.model.cell import Cell, Snapshot
from cellsight.occlusion._frame_kernel import Answer
from cellsight.occlusion.forest import ObjectForest
from cellsight.occlusion.predictor import CONTAIN_MARGIN, Projection, VisibilityPredictor
from cellsight.visibility import OBJECT_BVH


class ObjectBVH(VisibilityPredictor):
    """Visibility by each object's bounding-volume hierarchy (``forest``); options: those of
    :class:`~cellsight.occlusion.predictor.VisibilityPredictor`. Robots and static objects that
    are closed solids skip their back faces when the camera is outside them: a ring point that
    ends inside another solid can then be missed, rare, and only ever a missed
    ``near_occluder`` flag."""

    structure = OBJECT_BVH

    def __init__(self, cell: Cell, **options: Any) -> None:
        super().__init__(cell, **options)
        s = self.surfaces
        self.forest = ObjectForest(s.local_vertices, s.offsets, s.object_polys,
                                   s.object_closed & (s.kinds != "workpiece"), CONTAIN_MARGIN)
        self._every_poly = np.arange(len(s))  # the forest's occluders index every polygon

    def occluders(self, snapshot: Snapshot, centers: np.ndarray, starts: np.ndarray,
                  points: np.ndarray) -> np.ndarray:
        """For any viewpoints, not only the cell's cameras (camera placement): the nearest
        polygon (Q,) int32 (an index into ``surfaces.poly_owner``; -1: none) crossing each
        segment from viewpoint c's optical centre ``centers[c]`` (base frame, m) to
        ``points[starts[c]:starts[c + 1]]`` (base frame, m) in ``snapshot``, with this
        predictor's surface tolerance."""
        return self.forest.occluders(np.ascontiguousarray(snapshot.poses, dtype=np.float64),
                                     np.ascontiguousarray(centers, dtype=np.float64),
                                     np.ascontiguousarray(starts, dtype=np.int64),
                                     np.ascontiguousarray(points, dtype=np.float64),
                                     self.surface_tolerance)

    def stage_times(self, snapshot: Snapshot) -> dict[str, float]:
        """One prediction, timed by stage (s): ``cull`` (projecting the features), ``build``
        (0: nothing is built per frame), ``visit`` (the queries and labels), ``total``;
        ``kept``: every surface (a count)."""
        t0 = time.perf_counter()
        points, views = self._project(snapshot)
        t1 = time.perf_counter()
        self._labelled(points, views, self._answers(snapshot, points, views))
        t3 = time.perf_counter()
        return {"cull": t1 - t0, "build": 0.0, "visit": t3 - t1, "total": t3 - t0,
                "kept": len(self.surfaces)}

    def _answers(self, snapshot: Snapshot, points: np.ndarray,
                 views: Projection) -> list[Answer | None]:
        """Every camera's queries in one call of the hierarchies (cameras in parallel)."""
        queries = self._queries(points, views)
        starts = np.zeros(len(queries) + 1, dtype=np.int64)
        np.cumsum([len(q[1]) for q in queries], out=starts[1:])
        occ = self.forest.occluders(np.ascontiguousarray(snapshot.poses, dtype=np.float64),
                                    np.array([cam.center for cam in self.cameras]), starts,
                                    np.concatenate([q[1] for q in queries]),
                                    self.surface_tolerance)
        return [Answer(query, occ[a:b] < 0, occ[a:b], self._every_poly, n_ring)
                if query.size else None
                for (query, _, n_ring), a, b in zip(queries, starts[:-1], starts[1:],
                                                    strict=True)]

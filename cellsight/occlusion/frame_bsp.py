"""The ``frame-bsp`` back-end, the paper's: per frame, the surfaces are moved by the poses
(static objects once, offline), one BSP tree of them is built and visited back to front from
each camera's optical centre (culled first, see below).

Culling (``cull=True``; exact): a surface can hide a feature from a camera only if (1) it faces
the camera — for closed solids seen from outside, the first crossing of a line of sight is
always through a front face; a closed solid whose bounding box (grown by ``CONTAIN_MARGIN``)
holds the optical centre, where the camera may be inside it or on its boundary, keeps its back
faces too (cheap and conservative, so exact for non-convex solids as well), and (2) for some
feature in the image, part of it is nearer to the camera than the feature and its projection's
bounding box (grown by a margin that covers the near-occluder ring) holds the feature's image
(or it crosses the camera's focal plane): a line of sight crosses a surface at the feature's own
normalised image coordinates. Whole objects, then clusters of at most ``CLUSTER_SIZE`` nearby
polygons (:func:`polygon_clusters`), are skipped first by the same depth and image test on
their box in the object's frame (its 8 corners span it, so nothing the per-polygon test would
keep is skipped), and only the polygons of the clusters looked at are moved to the base frame.
The tree is built from the union over cameras of the surfaces that survive, plus every
workpiece surface. Surfaces that could hide nothing change no answer, so culled and unculled
answers agree (tests/test_cull_clusters.py checks both that and, directly, that every surface a
line of sight crosses while facing the camera is kept).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from cellsight.model.cell import Cell, Snapshot
from cellsight.occlusion._cull_kernel import (
    ClusterArrays,
    cull_camera,
    gather_polygons,
    place_polygons,
)
from cellsight.occlusion._frame_kernel import Answer
from cellsight.occlusion.bsp import BSPTree
from cellsight.occlusion.predictor import (
    CONTAIN_MARGIN,
    NEAR_BEHIND,
    Projection,
    VisibilityPredictor,
)
from cellsight.occlusion.soup import PolygonSoup
from cellsight.visibility import FRAME_BSP, STATUS_INSIDE

CULL_MARGIN_PX = 2.0  # safety margin of the image-box overlap test, pixels
CLUSTER_SIZE = 16  # polygons: most per cluster (a box culled as a whole before its polygons)


class FrameBSP(VisibilityPredictor):
    """Visibility by one BSP tree of the (culled) surfaces per frame; options: those of
    :class:`~cellsight.occlusion.predictor.VisibilityPredictor`, and ``cull`` (False: every
    surface goes into the tree; the answers are the same).

    Offline (constructor): clusters of nearby surfaces with their boxes. Per frame: cull,
    moving only the surfaces looked at into a buffer reused from frame to frame, build, visit.
    """

    structure = FRAME_BSP

    def __init__(self, cell: Cell, *, cull: bool = True, **options: Any) -> None:
        super().__init__(cell, **options)
        self.cull = cull
        s = self.surfaces
        cluster_polys, cluster_start, cluster_box, object_clusters, object_box = \
            polygon_clusters(s.local_vertices, s.offsets, s.object_polys, CLUSTER_SIZE)
        self._clusters = ClusterArrays(s.local_vertices, s.offsets, s.object_closed, object_box,
                                       object_clusters, cluster_box, cluster_polys,
                                       cluster_start, CONTAIN_MARGIN)
        cluster_object = np.repeat(np.arange(len(cell.objects)), np.diff(object_clusters))
        # clusters placed before any cull: the static ones (for good) and the workpieces'
        self._ready = (s.kinds[cluster_object] == "static") | np.isin(cluster_object,
                                                                      self.part_objects)
        self._vertices = s.static_vertices.copy()  # per-frame buffer, moving rows on demand
        part_polys = np.isin(s.poly_owner, self.part_objects)
        self._part_bits = np.where(part_polys, 255, 0).astype(np.uint8)  # kept for all

    def stage_times(self, snapshot: Snapshot) -> dict[str, float]:
        """One prediction, timed by stage (s): ``cull`` (projecting the features, moving and
        culling the surfaces), ``build`` (the tree), ``visit`` (the visits and labels),
        ``total``; ``kept``: the surfaces in the tree."""
        t0 = time.perf_counter()
        points, views = self._project(snapshot)
        vertices, keep = self._cull(snapshot, points, views)
        t1 = time.perf_counter()
        tree, polys = self._build(vertices, keep)
        t2 = time.perf_counter()
        self._labelled(points, views, self._visits(tree, polys, points, views, keep))
        t3 = time.perf_counter()
        return {"cull": t1 - t0, "build": t2 - t1, "visit": t3 - t2, "total": t3 - t0,
                "kept": int(len(polys))}

    def _answers(self, snapshot: Snapshot, points: np.ndarray,
                 views: Projection) -> list[Answer | None]:
        """Cull, build the tree, visit it from every camera."""
        vertices, keep = self._cull(snapshot, points, views)
        tree, polys = self._build(vertices, keep)
        return self._visits(tree, polys, points, views, keep)

    def _cull(self, snapshot: Snapshot, points: np.ndarray,
              views: Projection) -> tuple[np.ndarray, np.ndarray]:
        """The vertex buffer (base frame, m; the rows of the kept polygons filled) and
        ``keep`` (P,) uint8: bit ``camera_bit(c)`` set for the polygons that may hide one of
        the features ``points`` (N, 3) (base frame, m; ``views``: their projections) from the
        predictor's camera c (0: culled for every camera)."""
        if not self.cull:
            every = np.full(len(self.surfaces), 255, dtype=np.uint8)
            return self.surfaces.world_vertices(snapshot), every
        poses = np.ascontiguousarray(snapshot.poses, dtype=np.float64)
        frame = self._frame_start(poses)
        for c, cam in enumerate(self.cameras):
            status = views[c][1]
            if (status == STATUS_INSIDE).any():
                margin = (CULL_MARGIN_PX + self.near_px) / cam.focal_px
                cull_camera(self._clusters, poses, cam.T_cam_base, points, status, margin,
                            NEAR_BEHIND if self.near_px > 0 else 0.0, frame, camera_bit(c))
        return frame[0], frame[2]

    def _frame_start(self, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The frame's culling state ``(vertices, ready, keep)``: the vertex buffer (base frame,
        m) with the workpieces' rows placed at ``poses``, the clusters already placed, and the
        ``keep`` bits (all set for the workpiece polygons)."""
        s = self.surfaces
        for k in self.part_objects:
            place_polygons(s.local_vertices, s.offsets,
                           np.arange(s.object_polys[k], s.object_polys[k + 1]), poses[k],
                           self._vertices)
        return self._vertices, self._ready.copy(), self._part_bits.copy()

    def _build(self, vertices: np.ndarray, keep: np.ndarray) -> tuple[BSPTree, np.ndarray]:
        """BSP tree of the kept polygons, and their indices in the cell's polygon list."""
        polys = np.flatnonzero(keep != 0)
        soup = PolygonSoup.from_arrays(*gather_polygons(vertices, self.surfaces.offsets, polys))
        return BSPTree.build(soup), polys

    def _visits(self, tree: BSPTree, polys: np.ndarray, points: np.ndarray, views: Projection,
                keep: np.ndarray) -> list[Answer | None]:
        """The visits of ``tree`` (of the polygons ``polys``) from every camera; each camera's
        visit skips the polygons culled for it (``keep``, see :meth:`_cull`)."""
        answers = []
        for c, (cam, (query, queried, n_ring)) in enumerate(
                zip(self.cameras, self._queries(points, views), strict=True)):
            if not query.size:
                answers.append(None)
                continue
            vis, occ = tree.visibility(queried, cam.center, self.surface_tolerance,
                                       (keep[polys] & camera_bit(c)) != 0)
            answers.append(Answer(query, vis, occ, polys, n_ring))
        return answers


def camera_bit(c: int) -> int:
    """The bit of the predictor's camera ``c`` in the per-polygon ``keep`` bits (cameras past
    the 8th share the last one: a union of exact culls is exact)."""
    return 1 << min(c, 7)


def polygon_clusters(local: np.ndarray, offsets: np.ndarray, object_polys: np.ndarray,
                     size: int) -> tuple[np.ndarray, ...]:
    """Groups of at most ``size`` nearby polygons per object, for culling by boxes.

    ``local`` (V, 3): vertices in their object's frame (m); polygon p is
    ``local[offsets[p]:offsets[p + 1]]``; object k owns polygons
    ``object_polys[k]:object_polys[k + 1]``. Each object's polygons are split at the median
    of their centroids along the longest axis until a group has at most ``size``. Returns
    ``cluster_polys`` (P,) (polygon indices, grouped), ``cluster_start`` (C+1,),
    ``cluster_box`` (C, 6) (object-frame min xyz, max xyz of the group's vertices, m),
    ``object_clusters`` (K+1,) (object k owns clusters ``object_clusters[k]:[k+1]``) and
    ``object_box`` (K, 6).
    """
    starts = offsets[:-1]
    sizes = np.diff(offsets)
    centroid = np.add.reduceat(local, starts, axis=0) / sizes[:, None]
    lo = np.minimum.reduceat(local, starts, axis=0)
    hi = np.maximum.reduceat(local, starts, axis=0)
    groups, object_clusters = [], [0]
    for k in range(len(object_polys) - 1):
        todo = [np.arange(object_polys[k], object_polys[k + 1])]
        while todo:
            polys = todo.pop()
            if len(polys) <= size:
                groups.append(polys)
                continue
            c = centroid[polys]
            axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
            order = polys[np.argsort(c[:, axis], kind="stable")]
            todo += [order[len(order) // 2:], order[:len(order) // 2]]
        object_clusters.append(len(groups))
    cluster_polys = np.concatenate(groups).astype(np.int64)
    cluster_start = np.zeros(len(groups) + 1, dtype=np.int64)
    np.cumsum([len(g) for g in groups], out=cluster_start[1:])
    cluster_box = np.array([np.concatenate([lo[g].min(axis=0), hi[g].max(axis=0)])
                            for g in groups])
    bounds = np.array([[*lo[a:b].min(axis=0), *hi[a:b].max(axis=0)] if b > a else [0.0] * 6
                       for a, b in zip(object_polys[:-1], object_polys[1:], strict=True)])
    return (cluster_polys, cluster_start, cluster_box,
            np.asarray(object_clusters, dtype=np.int64), bounds)

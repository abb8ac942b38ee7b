"""Cell-level occlusion prediction (paper, Section III and Fig. 4).

Every object's surfaces are kept in the object's own frame. At each sampling time, with each
object's current pose (joint measurements for links and tools, the tracker's predicted pose
for workpieces, fixed for static objects), every workpiece feature point gets a label per
camera, by one of two structures (``structure``; same answers, tests/test_forest.py):

- ``"object-bvh"`` (default; issue 12): a bounding-volume hierarchy of each object's surfaces,
  built once, offline, in the object's frame (:mod:`.forest`); per frame only the queries (the
  optical centres and the features) are moved into each object's frame;
- ``"frame-bsp"`` (the paper's): the surfaces are moved by the poses (static objects once,
  offline), one BSP tree of them is built and visited back to front from each camera's
  optical centre (culled first, see below).

The labels:

- visible: its pixel coordinates are valid and no surface hides it;
- ``behind``: it lies behind the camera (depth <= 0);
- ``outside``: it projects outside the image;
- ``self``: hidden by a surface of its own workpiece (self-occlusion);
- an object label (``R7AX.gripper``, ``R6AX.link3``, ``table``): hidden by that object
  (mutual occlusion); the nearest occluder along the line of sight is named.

Culling (``frame-bsp`` mode, ``cull=True``; exact): a surface can hide a feature from a camera
only if (1) it faces the camera — for closed solids seen from outside, the first crossing of a
line of sight is always through a front face; a closed solid whose bounding box (grown by
``CONTAIN_MARGIN``) holds the optical centre, where the camera may be inside it or on its
boundary, keeps its back faces too (cheap and conservative, so exact for non-convex solids as
well), and (2) for some feature in the image, part of it is nearer to the camera than the
feature and its projection's bounding box (grown by a margin that covers the near-occluder
ring) holds the feature's image (or it crosses the camera's focal plane): a line of sight
crosses a surface at the feature's own normalised image coordinates. Whole objects, then
clusters of at most ``CLUSTER_SIZE`` nearby polygons (:func:`polygon_clusters`), are skipped
first by the same depth and image test on their box in the object's frame (its 8 corners span
it, so nothing the per-polygon test would keep is skipped), and only the polygons of the
clusters looked at are moved to the base frame. The tree is built from the union over cameras
of the surfaces that survive, plus every workpiece surface. Surfaces that could hide nothing
change no answer, so culled and unculled answers agree (tests/test_cull_clusters.py checks both
that and, directly, that every surface a line of sight crosses while facing the camera is
kept).
"""

from __future__ import annotations

import time

import numpy as np

from cellsight.errors import CellsightError
from cellsight.model.cell import Cell, Snapshot
from cellsight.occlusion._cull_kernel import (
    cull_camera,
    gather_polygons,
    label_answers,
    place_polygons,
    project_points,
    transform_vertices,
)
from cellsight.occlusion.bsp import BSPTree
from cellsight.occlusion.forest import ObjectForest
from cellsight.occlusion.soup import PolygonSoup
from cellsight.visibility import (  # noqa: F401 - the structures, also named from here
    FRAME_BSP,
    OBJECT_BVH,
    STATUS_INSIDE,
    STRUCTURES,
    CameraVisibility,
    Views,
)

CULL_MARGIN_PX = 2.0  # safety margin of the image-box overlap test, pixels
NEAR_SAMPLES = 8  # points on the ring around a feature for the near-occluder test
NEAR_DEPTH = 0.01  # m: a silhouette counts when at least this much nearer than the feature
CONTAIN_MARGIN = 1e-3  # m: growth of a solid's box in the camera-inside test (any >= 0 is exact)
CLUSTER_SIZE = 16  # polygons: most per cluster (a box culled as a whole before its polygons)


class VisibilityPredictor:
    """Predicts, for a cell snapshot, which workpiece features each camera sees.

    Offline (constructor): flat arrays of every surface in its object's frame and, for the
    ``structure`` (:data:`STRUCTURES`, module doc), each object's hierarchy, or the static
    surfaces in the base frame and clusters of nearby surfaces with their boxes. Per frame
    (:meth:`predict`): project the features, then query the hierarchies (cameras in parallel),
    or cull (moving only the surfaces looked at, into a buffer reused from frame to frame: do
    not share one predictor between threads), build, visit (:meth:`stage_times` times each).
    ``cull`` (``frame-bsp`` only) turns the exact cull off. ``cameras``
    restricts the prediction to some cameras (a non-empty list of indices into
    ``cell.cameras``; None: all).
    ``surface_tolerance`` (m): a feature within this distance of a surface's plane is not hidden
    by it, so that features resting on a support (the part's bottom corners on the conveyor)
    stay visible although the tracker's pose is off by a fraction of a millimetre.
    ``near_px`` (px): a visible feature whose ring of points this far around it (moved
    ``NEAR_DEPTH`` towards the camera) is partly hidden by another object is flagged
    ``near_occluder``: its image corner is a junction with that object's silhouette, a few
    pixels off (0 disables the test). Both must be finite and >= 0 (else
    :class:`CellsightError`). A ring point that ends inside another solid can be missed (that
    solid's back faces are skipped): rare, and only ever a missed flag.
    """

    def __init__(self, cell: Cell, *, cull: bool = True, cameras: list[int] | None = None,
                 surface_tolerance: float = 2e-3, near_px: float = 5.0,
                 structure: str = OBJECT_BVH) -> None:
        self.cell = cell
        self.cull = cull
        if structure not in STRUCTURES:
            raise CellsightError(f"VisibilityPredictor: structure must be one of "
                                 f"{', '.join(STRUCTURES)}, got {structure!r}")
        self.structure = structure
        self.surface_tolerance = _non_negative("surface_tolerance", surface_tolerance, "m")
        self.near_px = _non_negative("near_px", near_px, "px")
        n_cam = len(cell.cameras)
        if cameras is not None and (not len(cameras) or not all(
                isinstance(k, int | np.integer) and 0 <= k < n_cam for k in cameras)):
            raise CellsightError(f"VisibilityPredictor: cameras must be indices 0..{n_cam - 1} "
                                 f"of cell.cameras (None: all), got {cameras!r}")
        self.cameras = [cell.cameras[k] for k in (range(n_cam) if cameras is None else cameras)]
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
        self.poly_sizes = np.diff(self.offsets)
        self.vertex_poly = np.repeat(np.arange(len(owner)), self.poly_sizes)
        self.object_closed = np.array([o.solid.closed for o in cell.objects])
        self.object_polys = np.searchsorted(self.poly_owner, np.arange(len(cell.objects) + 1))
        kinds = np.array([o.kind for o in cell.objects])
        self._moving = np.flatnonzero(kinds[self.vertex_owner] != "static")
        # static poses never change: their vertices are placed once, here
        self._static_vertices = np.zeros_like(self.local_vertices)
        transform_vertices(self.local_vertices, self.vertex_owner,
                           np.arange(len(self.local_vertices)), cell.snapshot().poses,
                           self._static_vertices)
        self.part_objects = [cell.object_index(p.name) for p in cell.workpieces]
        self.part_features = [p.feature_points for p in cell.workpieces]
        self._feature_owner = np.repeat(self.part_objects, [len(f) for f in self.part_features])
        self.part_polys = np.isin(self.poly_owner, self.part_objects)
        self.labels = [o.label for o in cell.objects]
        (self._cluster_polys, self._cluster_start, self._cluster_box, self._object_clusters,
         self._object_box) = polygon_clusters(self.local_vertices, self.offsets,
                                              self.object_polys, CLUSTER_SIZE)
        cluster_object = np.repeat(np.arange(len(cell.objects)), np.diff(self._object_clusters))
        self._static_ready = kinds[cluster_object] == "static"
        self._part_clusters = np.isin(cluster_object, self.part_objects)
        self._vertices = self._static_vertices.copy()  # per-frame buffer, moving rows on demand
        self._ring_offsets: dict[str, np.ndarray] = {}  # camera name -> (K, 3) ring directions
        self._part_bits = np.where(self.part_polys, 255, 0).astype(np.uint8)  # kept for all
        self._every_poly = np.arange(len(self.poly_owner))  # the forest's occluder indices
        self._forest = None if structure == FRAME_BSP else ObjectForest(
            self.local_vertices, self.offsets, self.object_polys,
            self.object_closed & (kinds != "workpiece"), CONTAIN_MARGIN)

    def world_vertices(self, snapshot: Snapshot) -> np.ndarray:
        """Every surface vertex in the base frame for this snapshot, (V, 3)."""
        out = self._static_vertices.copy()
        transform_vertices(self.local_vertices, self.vertex_owner, self._moving, snapshot.poses,
                           out)
        return out

    def predict(self, joints=None, part_poses=None, openings=None) -> Views:
        """Visibility of every workpiece feature in every camera; see :meth:`predict_snapshot`."""
        return self.predict_snapshot(self.cell.snapshot(joints, part_poses, openings))

    def predict_snapshot(self, snapshot: Snapshot) -> Views:
        """Workpiece name -> one :class:`CameraVisibility` per camera (``cell.cameras`` order,
        or the predictor's ``cameras``)."""
        if self._forest is not None:
            points, views = self._project(snapshot)
            return self._forest_answer(snapshot, points, views)
        points, views, vertices, keep = self._cull(snapshot)
        tree, polys = self._build(vertices, keep)
        return self._answer(tree, polys, points, views, keep)

    def occluders(self, snapshot: Snapshot, centers: np.ndarray, starts: np.ndarray,
                  points: np.ndarray) -> np.ndarray:
        """For any viewpoints, not only the cell's cameras (camera placement): the nearest
        polygon (Q,) int32 (an index into :attr:`poly_owner`; -1: none) crossing each segment
        from viewpoint c's optical centre ``centers[c]`` (base frame, m) to
        ``points[starts[c]:starts[c + 1]]`` (base frame, m) in ``snapshot``, with this
        predictor's surface tolerance. ``object-bvh`` structure only."""
        if self._forest is None:
            raise CellsightError("VisibilityPredictor.occluders needs structure='object-bvh'")
        return self._forest.occluders(np.ascontiguousarray(snapshot.poses, dtype=np.float64),
                                      np.ascontiguousarray(centers, dtype=np.float64),
                                      np.ascontiguousarray(starts, dtype=np.int64),
                                      np.ascontiguousarray(points, dtype=np.float64),
                                      self.surface_tolerance)

    def stage_times(self, snapshot: Snapshot) -> dict[str, float]:
        """One prediction, timed by stage (s): ``cull`` (features, moving and culling the
        surfaces; ``object-bvh``: projecting the features), ``build`` (the tree; 0 for
        ``object-bvh``), ``visit`` (visits or queries, and labels), ``total``; ``kept``: the
        surfaces in the tree (``object-bvh``: every surface, a count)."""
        t0 = time.perf_counter()
        if self._forest is not None:
            points, views = self._project(snapshot)
            t1 = time.perf_counter()
            self._forest_answer(snapshot, points, views)
            t3 = time.perf_counter()
            return {"cull": t1 - t0, "build": 0.0, "visit": t3 - t1, "total": t3 - t0,
                    "kept": len(self.poly_owner)}
        points, views, vertices, keep = self._cull(snapshot)
        t1 = time.perf_counter()
        tree, polys = self._build(vertices, keep)
        t2 = time.perf_counter()
        self._answer(tree, polys, points, views, keep)
        t3 = time.perf_counter()
        return {"cull": t1 - t0, "build": t2 - t1, "visit": t3 - t2, "total": t3 - t0,
                "kept": int(len(polys))}

    def _cull(self, snapshot: Snapshot):
        """The features (N, 3) (base frame, m), per camera their pixels (N, 2) and status (N,),
        the vertex buffer (base frame, m; the rows of the kept polygons filled) and ``keep``
        (P,) uint8: bit ``camera_bit(c)`` set for the polygons that may hide a feature from the
        predictor's camera c (0: culled for every camera)."""
        points, views = self._project(snapshot)
        keep, vertices, ready, poses = self._frame_start(snapshot)
        for c, cam in enumerate(self.cameras):
            status = views[c][1]
            if self.cull and (status == STATUS_INSIDE).any():
                margin = (CULL_MARGIN_PX + self.near_px) / cam.focal_px
                cull_camera(self.local_vertices, self.offsets, poses, self.object_closed,
                            self._object_box, self._object_clusters, self._cluster_box,
                            self._cluster_polys, self._cluster_start, cam.T_cam_base, points,
                            status, margin, CONTAIN_MARGIN, vertices, ready, keep,
                            camera_bit(c))
        return points, views, vertices, keep

    def _project(self, snapshot: Snapshot) -> tuple[np.ndarray, list]:
        """The features (N, 3) (base frame, m) and, per camera, their pixels (N, 2) and
        status (N,)."""
        points = np.concatenate([
            local @ snapshot.poses[k][:3, :3].T + snapshot.poses[k][:3, 3]
            for k, local in zip(self.part_objects, self.part_features, strict=True)
        ])
        n = len(points)
        views = []
        for cam in self.cameras:
            px, status, box = np.empty((n, 2)), np.empty(n, dtype=np.int8), np.empty(5)
            project_points(points, cam.T_cam_base, cam.K, cam.dist5, cam.width, cam.height,
                           px, status, box)
            views.append((px, status))
        return points, views

    def _queries(self, points: np.ndarray, views) -> list[tuple[np.ndarray, np.ndarray, int]]:
        """Per camera: the features in its image (indices), their points followed by their
        near-occluder rings (base frame, m), and the ring size."""
        out = []
        for cam, (_, status) in zip(self.cameras, views, strict=True):
            query = np.flatnonzero(status == STATUS_INSIDE)
            ring = self._ring(cam, points[query])
            out.append((query, np.concatenate([points[query], ring.reshape(-1, 3)]),
                        ring.shape[1]))
        return out

    def _answer(self, tree: BSPTree, polys: np.ndarray, points: np.ndarray, views,
                keep: np.ndarray) -> Views:
        """The visits of ``tree`` (of the polygons ``polys``) from every camera, as labels; each
        camera's visit skips the polygons culled for it (``keep``, see :meth:`_cull`)."""
        answers = []
        for c, (cam, (query, queried, n_ring)) in enumerate(
                zip(self.cameras, self._queries(points, views), strict=True)):
            if not query.size:
                answers.append(None)
                continue
            vis, occ = tree.visibility(queried, cam.center, self.surface_tolerance,
                                       (keep[polys] & camera_bit(c)) != 0)
            answers.append((query, vis, occ, polys, n_ring))
        return self._labelled(points, views, answers)

    def _forest_answer(self, snapshot: Snapshot, points: np.ndarray, views) -> Views:
        """The answers of the static per-object hierarchies (``structure="object-bvh"``), as
        labels."""
        queries = self._queries(points, views)
        starts = np.zeros(len(queries) + 1, dtype=np.int64)
        np.cumsum([len(q[1]) for q in queries], out=starts[1:])
        occ = self._forest.occluders(np.ascontiguousarray(snapshot.poses, dtype=np.float64),
                                     np.array([cam.center for cam in self.cameras]), starts,
                                     np.concatenate([q[1] for q in queries]),
                                     self.surface_tolerance)
        answers = [(query, occ[a:b] < 0, occ[a:b], self._every_poly, n_ring) if query.size else None
                   for (query, _, n_ring), a, b in zip(queries, starts[:-1], starts[1:],
                                                       strict=True)]
        return self._labelled(points, views, answers)

    def _labelled(self, points: np.ndarray, views, answers) -> Views:
        """Per workpiece, one :class:`CameraVisibility` per camera from each camera's answers
        (``(query, vis, occ, polys, n_ring)``: see :func:`label_answers`; None: no feature in
        its image)."""
        n = len(points)
        result = {part.name: [] for part in self.cell.workpieces}
        for cam, (px, status), answer in zip(self.cameras, views, answers, strict=True):
            visible = np.zeros(n, dtype=bool)
            near = np.zeros(n, dtype=bool)
            occluder = np.full(n, -1, dtype=np.int32)
            if answer is not None:
                query, vis, occ, polys, n_ring = answer
                label_answers(vis, occ, polys, self.poly_owner, query, self._feature_owner,
                              n_ring, visible, occluder, near)
            start = 0
            for k, f in zip(self.part_objects, self.part_features, strict=True):
                sl = slice(start, start + len(f))
                start += len(f)
                result[self.cell.objects[k].name].append(CameraVisibility(
                    cam.name, visible[sl], px[sl], occluder[sl], status[sl], self.labels, k,
                    near[sl]))
        return result

    def _frame_start(self, snapshot: Snapshot):
        """The frame's ``keep`` bits (all set for the workpiece polygons, or for every polygon
        without culling; see :meth:`_cull`), vertex
        buffer (base frame, m; the workpieces' rows placed, every row without culling), cluster
        ``ready`` flags and contiguous poses."""
        poses = np.ascontiguousarray(snapshot.poses, dtype=np.float64)
        if not self.cull:
            return (np.full(len(self.poly_owner), 255, dtype=np.uint8),
                    self.world_vertices(snapshot), None, poses)
        vertices, ready = self._vertices, self._static_ready | self._part_clusters
        for k in self.part_objects:
            place_polygons(self.local_vertices, self.offsets,
                           np.arange(self.object_polys[k], self.object_polys[k + 1]), poses[k],
                           vertices)
        return self._part_bits.copy(), vertices, ready, poses

    def _ring(self, cam, points: np.ndarray) -> np.ndarray:
        """Per point (N, 3): ``NEAR_SAMPLES`` points (N, K, 3) around it, ``near_px`` pixels
        away in the image plane at its depth, each moved ``NEAR_DEPTH`` m towards the camera
        (so that only a silhouette at least that much in front hides one, not the surface the
        feature rests on)."""
        if self.near_px <= 0:
            return np.zeros((len(points), 0, 3))
        R = cam.T_base_cam[:3, :3]
        depth = (points - cam.center) @ R[:, 2]
        offsets = self._ring_offsets.get(cam.name)
        if offsets is None:  # unit directions in the image plane, once per camera
            angles = np.linspace(0.0, 2 * np.pi, NEAR_SAMPLES, endpoint=False)
            offsets = np.cos(angles)[:, None] * R[:, 0] + np.sin(angles)[:, None] * R[:, 1]
            self._ring_offsets[cam.name] = offsets
        ring = points[:, None, :] + (self.near_px * depth / cam.focal_px)[:, None, None] * offsets
        towards = cam.center - ring
        towards /= np.linalg.norm(towards, axis=2, keepdims=True)
        return ring + NEAR_DEPTH * towards

    def _build(self, vertices: np.ndarray, keep: np.ndarray) -> tuple[BSPTree, np.ndarray]:
        """BSP tree of the kept polygons, and their indices in this predictor's list."""
        polys = np.flatnonzero(keep != 0)
        soup = PolygonSoup.from_arrays(*gather_polygons(vertices, self.offsets, polys))
        return BSPTree.build(soup), polys


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


def _non_negative(name: str, value, unit: str) -> float:
    """``value`` as a float, or a :class:`CellsightError` naming ``name`` unless finite, >= 0."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = float("nan")
    if not (np.isfinite(number) and number >= 0.0):
        raise CellsightError(f"VisibilityPredictor: {name} must be a finite number >= 0 "
                             f"({unit}), got {value!r}")
    return number

"""Cell-level occlusion prediction (paper, Section III and Fig. 4).

At each sampling time: every object's surfaces, kept in the object's own frame, are moved by
its current pose (joint measurements for links and tools, the tracker's predicted pose for
workpieces; static objects are transformed once, offline); one BSP tree of the surfaces is
built; it is visited back to front from each camera's optical centre and every workpiece
feature point gets a label per camera:

- visible: its pixel coordinates are valid and no surface hides it;
- ``behind``: it lies behind the camera (depth <= 0);
- ``outside``: it projects outside the image;
- ``self``: hidden by a surface of its own workpiece (self-occlusion);
- an object label (``R7AX.gripper``, ``R6AX.link3``, ``table``): hidden by that object
  (mutual occlusion); the nearest occluder along the line of sight is named.

Culling (exact, ``cull=True``): a surface can hide a feature from a camera only if (1) it faces
the camera — for closed solids seen from outside, the first crossing of a line of sight is
always through a front face; a closed solid whose bounding box (grown by ``CONTAIN_MARGIN``)
holds the optical centre, where the camera may be inside it or on its boundary, keeps its back
faces too (cheap and conservative, so exact for non-convex solids as well), (2) part of it is
nearer to the camera than the farthest feature, and (3) its projection overlaps the features'
image bounding box (or it crosses the camera's focal plane). The tree is built from the union
over cameras of the surfaces that survive, plus every workpiece surface.
"""

from __future__ import annotations

import numpy as np

from cellsight.errors import CellsightError
from cellsight.model.cell import Cell, Snapshot
from cellsight.occlusion._cull_kernel import cull_polygons, project_points, transform_vertices
from cellsight.occlusion.bsp import BSPTree
from cellsight.occlusion.soup import PolygonSoup
from cellsight.visibility import STATUS_INSIDE, CameraVisibility, Views

CULL_MARGIN_PX = 2.0  # safety margin of the image-box overlap test, pixels
NEAR_SAMPLES = 8  # points on the ring around a feature for the near-occluder test
NEAR_DEPTH = 0.01  # m: a silhouette counts when at least this much nearer than the feature
CONTAIN_MARGIN = 1e-3  # m: growth of a solid's box in the camera-inside test (any >= 0 is exact)


class VisibilityPredictor:
    """Predicts, for a cell snapshot, which workpiece features each camera sees.

    Offline (constructor): flat arrays of every surface in its object's frame, static surfaces
    in the base frame. Per frame (:meth:`predict`): transform, cull, build, visit. ``cameras``
    restricts the prediction to some cameras (a non-empty list of indices into
    ``cell.cameras``; None: all).
    ``surface_tolerance`` (m): a feature within this distance of a surface's plane is not hidden
    by it, so that features resting on a support (the part's bottom corners on the conveyor)
    stay visible although the tracker's pose is off by a fraction of a millimetre.
    ``near_px`` (px): a visible feature whose ring of points this far around it (moved
    ``NEAR_DEPTH`` towards the camera) is partly hidden by another object is flagged
    ``near_occluder``: its image corner is a junction with that object's silhouette, a few
    pixels off (0 disables the test). Both must be finite and >= 0 (else
    :class:`CellsightError`). With culling, a ring point that ends inside another solid
    can be missed (that solid's back faces are culled): rare, and only ever a missed flag.
    """

    def __init__(self, cell: Cell, *, cull: bool = True, cameras: list[int] | None = None,
                 surface_tolerance: float = 2e-3, near_px: float = 5.0) -> None:
        self.cell = cell
        self.cull = cull
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
        cell = self.cell
        vertices = self.world_vertices(snapshot)
        features = [
            local @ snapshot.poses[k][:3, :3].T + snapshot.poses[k][:3, 3]
            for k, local in zip(self.part_objects, self.part_features, strict=True)
        ]
        points = np.concatenate(features)
        n = len(points)
        views = []
        keep = self.part_polys.copy()
        for cam in self.cameras:
            px, status, box = np.empty((n, 2)), np.empty(n, dtype=np.int8), np.empty(5)
            seen = project_points(points, cam.T_cam_base, cam.K, cam.dist5,
                                  cam.width, cam.height, px, status, box)
            views.append((px, status))
            if self.cull and seen:
                margin = (CULL_MARGIN_PX + self.near_px) / cam.focal_px
                cull_polygons(vertices, self.offsets, self.object_polys, self.object_closed,
                              cam.T_cam_base, box, margin, CONTAIN_MARGIN, keep)
        if not self.cull:
            keep[:] = True
        tree, polys = self._build(vertices, keep)
        result = {part.name: [] for part in cell.workpieces}
        for cam, (px, status) in zip(self.cameras, views, strict=True):
            visible = np.zeros(n, dtype=bool)
            near = np.zeros(n, dtype=bool)
            occluder = np.full(n, -1, dtype=np.int32)
            query = np.flatnonzero(status == STATUS_INSIDE)
            if query.size:
                ring = self._ring(cam, points[query])
                vis, occ = tree.visibility(np.concatenate([points[query], ring.reshape(-1, 3)]),
                                           cam.center, self.surface_tolerance)
                owner = np.where(vis, -1, self.poly_owner[polys[np.maximum(occ, 0)]])
                m = len(query)
                visible[query] = vis[:m]
                occluder[query] = owner[:m]
                ring_owner = owner[m:].reshape(ring.shape[:2])
                by_other = (ring_owner >= 0) & (ring_owner != self._feature_owner[query, None])
                near[query] = vis[:m] & by_other.any(axis=1)
            start = 0
            for k, f in zip(self.part_objects, features, strict=True):
                sl = slice(start, start + len(f))
                start += len(f)
                result[cell.objects[k].name].append(CameraVisibility(
                    cam.name, visible[sl], px[sl], occluder[sl], status[sl], self.labels, k,
                    near[sl]))
        return result

    def _ring(self, cam, points: np.ndarray) -> np.ndarray:
        """Per point (N, 3): ``NEAR_SAMPLES`` points (N, K, 3) around it, ``near_px`` pixels
        away in the image plane at its depth, each moved ``NEAR_DEPTH`` m towards the camera
        (so that only a silhouette at least that much in front hides one, not the surface the
        feature rests on)."""
        if self.near_px <= 0:
            return np.zeros((len(points), 0, 3))
        R = cam.T_base_cam[:3, :3]
        depth = (points - cam.center) @ R[:, 2]
        angles = np.linspace(0.0, 2 * np.pi, NEAR_SAMPLES, endpoint=False)
        offsets = np.cos(angles)[:, None] * R[:, 0] + np.sin(angles)[:, None] * R[:, 1]
        ring = points[:, None, :] + (self.near_px * depth / cam.focal_px)[:, None, None] * offsets
        towards = cam.center - ring
        towards /= np.linalg.norm(towards, axis=2, keepdims=True)
        return ring + NEAR_DEPTH * towards

    def _build(self, vertices: np.ndarray, keep: np.ndarray) -> tuple[BSPTree, np.ndarray]:
        """BSP tree of the kept polygons, and their indices in this predictor's list."""
        polys = np.flatnonzero(keep)
        offsets = np.zeros(len(polys) + 1, dtype=np.int64)
        np.cumsum(self.poly_sizes[polys], out=offsets[1:])
        soup = PolygonSoup.from_arrays(vertices[keep[self.vertex_poly]], offsets)
        return BSPTree.build(soup), polys


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

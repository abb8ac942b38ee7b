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
always through a front face, (2) part of it is nearer to the camera than the farthest feature,
and (3) its projection overlaps the features' image bounding box (or it crosses the camera's
focal plane). The tree is built from the union over cameras of the surfaces that survive,
plus every workpiece surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cellsight.model.cell import Cell, Snapshot
from cellsight.occlusion.bsp import BSPTree
from cellsight.occlusion.soup import PolygonSoup

VISIBLE, BEHIND, OUTSIDE, SELF = "", "behind", "outside", "self"


@dataclass
class CameraVisibility:
    """One workpiece seen by one camera at one sampling time.

    ``visible`` (F,) bool in feature order; ``pixels`` (F, 2) predicted (u, v) (NaN behind
    the camera); ``reason`` per feature: '' when visible, else 'behind', 'outside', 'self' or
    the occluding object's name; ``occluder`` (F,) cell object index or -1.
    """

    camera: str
    visible: np.ndarray
    pixels: np.ndarray
    reason: list[str]
    occluder: np.ndarray

    @property
    def count(self) -> int:
        return int(self.visible.sum())


class VisibilityPredictor:
    """Predicts, for a cell snapshot, which workpiece features each camera sees.

    Offline (constructor): flat arrays of every surface in its object's frame, static surfaces
    in the base frame. Per frame (:meth:`predict`): transform, cull, build, visit. ``cameras``
    restricts the prediction to some cameras (indices into ``cell.cameras``; default all).
    """

    def __init__(self, cell: Cell, *, cull: bool = True, cameras: list[int] | None = None) -> None:
        self.cell = cell
        self.cull = cull
        self.cameras = [cell.cameras[k] for k in (cameras or range(len(cell.cameras)))]
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
        self.vertex_poly = np.repeat(np.arange(len(owner)), np.diff(self.offsets))
        closed = np.array([o.solid.closed for o in cell.objects])
        self.poly_closed = closed[self.poly_owner]
        kinds = np.array([o.kind for o in cell.objects])
        self.vertex_static = kinds[self.vertex_owner] == "static"
        static_poses = cell.snapshot().poses  # static poses never change
        self._static_vertices = self._transform(static_poses, self.vertex_static)
        self.part_objects = [cell.object_index(p.name) for p in cell.workpieces]
        self.part_polys = np.isin(self.poly_owner, self.part_objects)
        self.labels = [o.label for o in cell.objects]

    def _transform(self, poses: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Vertices selected by ``mask`` moved by their objects' poses (base frame)."""
        T = poses[self.vertex_owner[mask]]
        v = self.local_vertices[mask]
        return np.einsum("nij,nj->ni", T[:, :3, :3], v) + T[:, :3, 3]

    def world_vertices(self, snapshot: Snapshot) -> np.ndarray:
        """Every surface vertex in the base frame for this snapshot, (V, 3)."""
        out = np.empty_like(self.local_vertices)
        out[self.vertex_static] = self._static_vertices
        moving = ~self.vertex_static
        out[moving] = self._transform(snapshot.poses, moving)
        return out

    def predict(
        self, joints=None, part_poses=None, openings=None
    ) -> dict[str, list[CameraVisibility]]:
        """Visibility of every workpiece feature in every camera; see :meth:`predict_snapshot`."""
        return self.predict_snapshot(self.cell.snapshot(joints, part_poses, openings))

    def predict_snapshot(self, snapshot: Snapshot) -> dict[str, list[CameraVisibility]]:
        """Workpiece name -> one :class:`CameraVisibility` per camera (``cell.cameras`` order,
        or the predictor's ``cameras``)."""
        cell = self.cell
        vertices = self.world_vertices(snapshot)
        features = [
            snapshot.poses[k][:3, :3] @ part.feature_points.T
            for k, part in zip(self.part_objects, cell.workpieces, strict=True)
        ]
        features = [
            (f + snapshot.poses[k][:3, 3:4]).T
            for f, k in zip(features, self.part_objects, strict=True)
        ]
        points = np.concatenate(features)
        point_owner = np.repeat(self.part_objects, [len(f) for f in features])

        depth, pixels, labels = [], [], []
        keep = self.part_polys.copy()
        for cam in self.cameras:
            cam_points = cam.to_camera(points)
            px = cam.project_camera(cam_points)
            in_front = cam_points[:, 2] > 1e-9
            inside = in_front & cam.in_image(px)
            depth.append(cam_points[:, 2])
            pixels.append(px)
            labels.append((in_front, inside))
            if self.cull and inside.any():
                keep |= self._candidates(vertices, cam, cam_points[inside])
            elif not self.cull:
                keep[:] = True

        polys = np.flatnonzero(keep)
        tree = self._build(vertices, polys)
        result = {part.name: [] for part in cell.workpieces}
        for c, cam in enumerate(self.cameras):
            in_front, inside = labels[c]
            visible = np.zeros(len(points), dtype=bool)
            occluder = np.full(len(points), -1, dtype=np.int32)
            query = np.flatnonzero(inside)
            if query.size:
                vis, occ = tree.visibility(points[query], cam.center)
                visible[query] = vis
                hidden = query[~vis]
                occluder[hidden] = self.poly_owner[polys[occ[~vis]]]
            reasons = np.where(~in_front, BEHIND, np.where(~inside, OUTSIDE, VISIBLE))
            reasons = reasons.astype(object)
            for i in np.flatnonzero(occluder >= 0):
                reasons[i] = SELF if occluder[i] == point_owner[i] else self.labels[occluder[i]]
            start = 0
            for part, f in zip(cell.workpieces, features, strict=True):
                sl = slice(start, start + len(f))
                start += len(f)
                result[part.name].append(CameraVisibility(
                    cam.name, visible[sl], pixels[c][sl], list(reasons[sl]), occluder[sl]))
        return result

    def _build(self, vertices: np.ndarray, polys: np.ndarray) -> BSPTree:
        """BSP tree of the selected polygons (indices into this predictor's polygon list)."""
        counts = np.diff(self.offsets)[polys]
        offsets = np.zeros(len(polys) + 1, dtype=np.int64)
        np.cumsum(counts, out=offsets[1:])
        take = np.concatenate([np.arange(self.offsets[p], self.offsets[p + 1]) for p in polys])
        soup = PolygonSoup.from_arrays(vertices[take], offsets, np.arange(len(polys)))
        return BSPTree.build(soup)

    def _candidates(self, vertices, cam, features_cam: np.ndarray) -> np.ndarray:
        """Polygons that may hide one of the features (camera frame, in front and inside the
        image) from ``cam``; see the module doc. Returns (P,) bool."""
        vc = cam.to_camera(vertices)
        z = vc[:, 2]
        starts = self.offsets[:-1]
        zmin = np.minimum.reduceat(z, starts)
        near = zmin < features_cam[:, 2].max()
        normals = self._plane_normals(vc)
        facing = ~self.poly_closed | (np.einsum("ij,ij->i", normals, -vc[starts]) > 0)
        crossing = zmin <= 1e-6
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = vc[:, 0] / z, vc[:, 1] / z
        fx, fy = features_cam[:, 0] / features_cam[:, 2], features_cam[:, 1] / features_cam[:, 2]
        margin = 2.0 / cam.focal_px  # 2 px, in normalised image coordinates
        overlap = (
            (np.maximum.reduceat(x, starts) >= fx.min() - margin)
            & (np.minimum.reduceat(x, starts) <= fx.max() + margin)
            & (np.maximum.reduceat(y, starts) >= fy.min() - margin)
            & (np.minimum.reduceat(y, starts) <= fy.max() + margin)
        )
        return near & facing & (overlap | crossing)

    def _plane_normals(self, v: np.ndarray) -> np.ndarray:
        """Newell normals (P, 3) of every polygon for vertices ``v`` (V, 3)."""
        nxt = np.arange(len(v)) + 1
        nxt[self.offsets[1:] - 1] = self.offsets[:-1]
        w = v[nxt]
        terms = np.column_stack([
            (v[:, 1] - w[:, 1]) * (v[:, 2] + w[:, 2]),
            (v[:, 2] - w[:, 2]) * (v[:, 0] + w[:, 0]),
            (v[:, 0] - w[:, 0]) * (v[:, 1] + w[:, 1]),
        ])
        return np.add.reduceat(terms, self.offsets[:-1], axis=0)

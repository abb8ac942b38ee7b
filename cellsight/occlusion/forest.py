"""Static structure per rigid object (issue 12): one bounding-volume hierarchy (BVH) of each
object's surfaces, built once, offline, in the object's own frame; per frame only the queries
(the optical centre and the points) move, into each object's frame (the ``object-bvh``
back-end, :class:`~cellsight.occlusion.object_bvh.ObjectBVH`).

The paper keeps every object's surfaces in its own frame and builds one BSP tree of all of
them per frame (the ``frame-bsp`` back-end, :class:`~cellsight.occlusion.frame_bsp.FrameBSP`).
Here nothing is rebuilt: a link's hierarchy stays valid however the arm moves, because a rigid
move changes no distance. A hierarchy node holds the box (object frame) of its polygons, each
grown by its plane thickness ``eps``; a node of more than ``LEAF_SIZE`` polygons is split at the
median of their centroids along the box's longest axis. A segment (camera -> point, moved to
the object's frame) descends into the nodes whose box it meets up to the nearest crossing found
so far; the leaves' polygons get the exact crossing test (:mod:`._crossing`, in
:mod:`._forest_kernel`), so the answers are the BSP visit's: same test, same nearest occluder.
"""

from __future__ import annotations

import numpy as np

from cellsight.occlusion._forest_kernel import (
    ForestArrays,
    forest_occluders,
    forest_occluders_serial,
)
from cellsight.occlusion.soup import PolygonSoup

LEAF_SIZE = 4  # polygons at most per leaf
#: Query points from which the cameras are answered in parallel threads (one per camera, at
#: most the process's share of cores, :mod:`cellsight.threads`); below it, one after the other
#: in the calling thread. A camera's few dozen points take microseconds, less than waking a
#: thread, and on a busy machine a woken thread may wait a scheduler slice (milliseconds).
PARALLEL_MIN_POINTS = 2048


class ObjectForest:
    """The hierarchies of every object's polygons, in flat arrays.

    ``local_vertices`` (V, 3) and ``offsets`` (P+1,): every polygon in its object's frame (m);
    object k owns polygons ``object_polys[k]:object_polys[k + 1]``; ``cull_backs`` (K,)
    bool: closed solids whose back faces are skipped when the camera is outside them (the
    predictor's rule: robots and static objects, not workpieces).
    """

    def __init__(self, local_vertices: np.ndarray, offsets: np.ndarray,
                 object_polys: np.ndarray, cull_backs: np.ndarray,
                 contain_margin: float) -> None:
        soup = PolygonSoup.from_arrays(np.ascontiguousarray(local_vertices, dtype=np.float64),
                                       np.ascontiguousarray(offsets, dtype=np.int64))
        self.soup = soup
        self.cull_backs = np.asarray(cull_backs, dtype=np.bool_)
        self.contain_margin = float(contain_margin)
        grown = soup.boxes + np.concatenate([-soup.eps[:, None].repeat(3, 1),
                                             soup.eps[:, None].repeat(3, 1)], axis=1)
        centroid = 0.5 * (soup.boxes[:, :3] + soup.boxes[:, 3:])
        boxes, links, polys, roots = [], [], [], []
        for a, b in zip(object_polys[:-1], object_polys[1:], strict=True):
            roots.append(len(boxes) if b > a else -1)
            if b > a:
                _build(np.arange(a, b), grown, centroid, boxes, links, polys)
        self.node_box = np.asarray(boxes, dtype=np.float64).reshape(-1, 6)
        self.node_links = np.asarray(links, dtype=np.int64).reshape(-1, 4)
        self.node_polys = np.asarray(polys, dtype=np.int64)
        self.object_root = np.asarray(roots, dtype=np.int64)
        # a ball around each object's root box (object frame), grown by rounding slack
        self.object_sphere = np.zeros((len(roots), 4))
        for k, root in enumerate(roots):
            if root >= 0:
                lo, hi = self.node_box[root, :3], self.node_box[root, 3:]
                self.object_sphere[k] = [*(0.5 * (lo + hi)),
                                         0.5 * float(np.linalg.norm(hi - lo)) + 1e-9]

    def occluders(self, poses: np.ndarray, views: np.ndarray, starts: np.ndarray,
                  points: np.ndarray, tol: float) -> np.ndarray:
        """Nearest occluding polygon (Q,) int32 (-1: visible) of each of ``points`` (Q, 3),
        base frame, m), those of camera c (optical centre ``views[c]``) being
        ``points[starts[c]:starts[c + 1]]``; ``poses`` (K, 4, 4) object -> base; ``tol`` (m):
        the surface tolerance (a point this near a polygon's plane is not hidden by it)."""
        parallel = len(views) > 1 and len(points) >= PARALLEL_MIN_POINTS
        kernel = forest_occluders if parallel else forest_occluders_serial
        return kernel(self.soup.arrays(), self.arrays(), poses, views, starts, points, float(tol))

    def arrays(self) -> ForestArrays:
        """The hierarchies as the compiled kernel reads them, as one argument."""
        return ForestArrays(self.node_box, self.node_links, self.node_polys, self.object_root,
                            self.object_sphere, self.cull_backs, self.contain_margin)

    @property
    def stats(self) -> dict[str, int]:
        """``nodes`` and ``polygons`` of the forest."""
        return {"nodes": len(self.node_box), "polygons": len(self.soup)}


def _build(polys: np.ndarray, grown: np.ndarray, centroid: np.ndarray, boxes: list,
           links: list, out_polys: list) -> int:
    """Append the hierarchy of ``polys`` (node arrays as lists), depth first; its root's index."""
    node = len(boxes)
    g = grown[polys]
    boxes.append(np.concatenate([g[:, :3].min(axis=0), g[:, 3:].max(axis=0)]))
    links.append([-1, -1, len(out_polys), 0])
    if len(polys) <= LEAF_SIZE:
        links[node][3] = len(polys)
        out_polys.extend(polys.tolist())
        return node
    c = centroid[polys]
    axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
    order = polys[np.argsort(c[:, axis], kind="stable")]
    half = len(order) // 2
    links[node][0] = _build(order[:half], grown, centroid, boxes, links, out_polys)
    links[node][1] = _build(order[half:], grown, centroid, boxes, links, out_polys)
    return node

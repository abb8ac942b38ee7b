"""BSP-tree visibility of points from a viewpoint (paper, Sections II and III-B).

:class:`BSPTree` partitions a :class:`~cellsight.occlusion.soup.PolygonSoup` by planes of its
own polygons (Section II) and answers which points a viewpoint (a camera's optical centre) sees
by the paper's back-to-front visit ``not_occluded`` / ``process_surfaces`` (Section III-B). The
build and the visit are each one compiled (numba) call on flat arrays; see
:mod:`._build_kernel` and :mod:`._visit_kernel` for the algorithms.

Semantics of ``visibility(points, viewpoint)``: a point is visible iff the open segment from the
viewpoint to the point crosses no polygon, where

- a crossing within the plane thickness ``eps`` of the point itself does not count: a point lying
  on a polygon is not hidden by it, so a vertex is never hidden by its own faces;
- a polygon whose plane passes within ``eps`` of the viewpoint is seen edge-on and hides nothing
  (the paper's ON_THE_PLANE case), even a coplanar polygon lying between the two;
- a point coincident with the viewpoint is visible (empty segment); a point "behind" the camera is
  judged like any other, since the segment test has no viewing direction: the field of view is
  the caller's business.

``eps`` is each polygon's own plane thickness (relative to its size, see :mod:`.soup`): local,
so a polygon added far away never changes the answers for the others. Answers may differ from
exact arithmetic only for points or viewpoints within a few ``eps`` of a polygon's plane, or
crossings within a few ``eps`` of a polygon's edge.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cellsight.errors import GeometryError
from cellsight.occlusion._build_kernel import build_tree
from cellsight.occlusion._cull_kernel import gather_polygons
from cellsight.occlusion._segment_kernel import cull_segments, segment_visible
from cellsight.occlusion._visit_kernel import (
    BAD_VIEWPOINT,
    NO_BAD_INPUT,
    TreeArrays,
    visit_tree,
)
from cellsight.occlusion.soup import PolygonSoup

#: Candidate splitters tested per node (all of them when a node has no more fragments).
DEFAULT_CANDIDATES = 8
#: Weight of the split count against the front/back imbalance in the splitter score.
DEFAULT_SPLIT_WEIGHT = 0.8
_SEED = 0x5EED


class BSPTree:
    """A BSP tree of a polygon soup, in flat arrays; build with :meth:`build`.

    ``node_planes`` (M, 4): partition plane ``(n, d)`` of each node (node 0 is the root);
    ``node_eps`` (M,): its thickness (its polygon's ``eps``, same unit as the soup);
    ``node_links`` (M, 4) int64: ``(front child, back child, first surface, surface count)``,
    -1 for an empty child; ``surfaces``: indices of the soup polygons stored in the nodes
    (a polygon split by a plane appears once per fragment); ``stats``: a dict with ``nodes``,
    ``splits`` (polygon fragments cut in two), ``depth`` (nodes on the longest root-leaf path),
    ``fragments`` (surfaces stored, = polygons + splits).
    """

    def __init__(
        self,
        soup: PolygonSoup,
        node_planes: np.ndarray,
        node_eps: np.ndarray,
        node_links: np.ndarray,
        surfaces: np.ndarray,
        splits: int,
        depth: int,
    ) -> None:
        self.soup = soup
        self.node_planes = node_planes
        self.node_eps = node_eps
        self.node_links = node_links
        self.surfaces = surfaces
        self.stats = {
            "nodes": int(node_planes.shape[0]),
            "splits": int(splits),
            "depth": int(depth),
            "fragments": int(surfaces.shape[0]),
        }

    @classmethod
    def build(
        cls,
        soup: PolygonSoup,
        *,
        candidates: int = DEFAULT_CANDIDATES,
        split_weight: float = DEFAULT_SPLIT_WEIGHT,
    ) -> BSPTree:
        """Build the tree of ``soup`` (one compiled call).

        At each node the splitter is the candidate plane with the lowest
        ``split_weight * splits + (1 - split_weight) * |front - back|``; the candidates are all
        the node's polygons when there are at most ``candidates``, else a seeded (reproducible)
        sample of ``candidates`` of them.
        """
        if candidates < 1 or not 0.0 <= split_weight <= 1.0:
            raise ValueError(
                f"candidates must be >= 1 and split_weight in [0, 1], got {candidates}, "
                f"{split_weight}"
            )
        node_planes, node_eps, node_links, surfaces, splits, depth = build_tree(
            soup.vertices, soup.offsets, soup.planes, soup.spheres, soup.eps,
            candidates, split_weight, _SEED,
        )
        return cls(soup, node_planes, node_eps, node_links, surfaces, splits, depth)

    def visibility(
        self,
        points: np.ndarray,
        viewpoint: np.ndarray,
        surface_tolerance: float = 0.0,
        relevant: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Which ``points`` (N, 3) the ``viewpoint`` (3,) sees, by the back-to-front visit.

        Returns ``visible`` (N,) bool and ``occluder`` (N,) int32: the index in the soup of the
        nearest polygon hiding the point (the first one crossed from the viewpoint), -1 when
        visible. A point within ``surface_tolerance`` (m; at least the polygon's ``eps``) of a
        polygon's plane is never hidden by that polygon. ``relevant`` (P,) bool: the soup
        polygons that may hide one of these points (an exact cull's answer; None: all), the
        others are skipped. Non-finite input raises :class:`GeometryError`.
        """
        points, viewpoint = _query_arrays(points, viewpoint)  # non-finite: found by the visit
        soup = self.soup
        if relevant is None:
            relevant = np.ones(len(soup), dtype=np.bool_)
        elif relevant.shape != (len(soup),) or relevant.dtype != np.bool_:
            raise GeometryError(
                f"relevant must be a bool array of {len(soup)} polygons, got {relevant.dtype} "
                f"{relevant.shape}"
            )
        visible, occluder, bad = visit_tree(soup.arrays(), self.arrays(), points, viewpoint,
                                            float(surface_tolerance), relevant)
        if bad == BAD_VIEWPOINT:
            raise GeometryError(f"viewpoint has a non-finite coordinate: {viewpoint.tolist()}")
        if bad != NO_BAD_INPUT:
            raise GeometryError(f"point {bad} has a non-finite coordinate: {points[bad].tolist()}")
        return visible, occluder

    def arrays(self) -> TreeArrays:
        """The tree as the compiled visit reads it, as one argument."""
        return TreeArrays(self.node_planes, self.node_eps, self.node_links, self.surfaces,
                          self.stats["depth"])


#: The direct (point, polygon) test is used when points * kept polygons is at most this many
#: pairs (rough estimate, not tuned: a pair test costs a few ns, a BSP build
#: ~5 us per polygon plus the visit), else the BSP tree of the kept polygons.
DIRECT_PAIRS = 1 << 22
#: ... and the number of points at most this many (the visit's cost grows slower in points).
DIRECT_POINTS = 512


def visible_mask(
    polygons: Sequence[np.ndarray] | np.ndarray | PolygonSoup, points: np.ndarray,
    viewpoint: np.ndarray, _method: str = "auto",
) -> np.ndarray:
    """Visible flags (N,) of ``points`` (N, 3) seen from ``viewpoint`` (3,) among ``polygons``:
    a sequence of (k_i, 3) vertex arrays, one (P, k, 3) array of polygons with k vertices
    each (a triangle mesh as ``vertices[triangles]``: no per-polygon copy), or a
    :class:`PolygonSoup` (a list joined once, ``PolygonSoup.from_polygons(polygons)``, for
    queries against the same polygons: the fastest input, as its joining, planes and checks
    are done once, not per call).

    Same answers as ``BSPTree.build(PolygonSoup.from_polygons(polygons)).visibility(points,
    viewpoint)[0]`` (module doc for the semantics and the per-polygon thickness ``eps``), and
    the same :class:`GeometryError` for bad input: every polygon is validated. Then the
    polygons that cannot cross any viewpoint->point segment are culled exactly
    (:func:`._segment_kernel.cull_segments`), and the kept ones answered by a direct
    compiled test of every (point, polygon) pair when that is cheap (at most
    ``DIRECT_POINTS`` points and ``DIRECT_PAIRS`` pairs), else by a BSP tree of the kept
    polygons. ``_method`` (testing and benchmarks only): ``"auto"``, ``"direct"``,
    ``"bsp"`` (cull then tree) or ``"full"`` (the tree of everything, no cull).
    """
    soup = _checked_soup(polygons)
    if _method == "full":
        return BSPTree.build(soup).visibility(points, viewpoint)[0]
    points, viewpoint = _checked_query(points, viewpoint)
    kept = cull_segments(soup.arrays(), soup.spheres, points, viewpoint)
    n_pairs = points.shape[0] * kept.shape[0]
    direct = points.shape[0] <= DIRECT_POINTS and n_pairs <= DIRECT_PAIRS
    if _method == "direct" or (_method == "auto" and direct):
        return segment_visible(soup.arrays(), kept, points, viewpoint, 0.0)
    if kept.shape[0] == 0:
        return np.ones(points.shape[0], dtype=np.bool_)
    sub = PolygonSoup.from_arrays(*gather_polygons(soup.vertices, soup.offsets, kept))
    return BSPTree.build(sub).visibility(points, viewpoint)[0]


def _checked_soup(polygons: Sequence[np.ndarray] | np.ndarray) -> PolygonSoup:
    """``PolygonSoup.from_polygons(polygons)`` (validated), with fast paths for a (P, k >= 3,
    3) real array (polygons of k vertices each, e.g. a mesh's triangles: no copy) and a list
    of (k >= 3, 3) real arrays (one concatenation instead of a conversion per polygon). Any
    failure falls back to ``from_polygons``, which raises the usual :class:`GeometryError`.
    A :class:`PolygonSoup` is used as it is, validated first if it has not been."""
    if isinstance(polygons, PolygonSoup):
        polygons._validate()
        return polygons
    try:
        if isinstance(polygons, np.ndarray) and polygons.ndim == 3:
            vertices = polygons.reshape(-1, polygons.shape[-1])
            counts = np.full(polygons.shape[0], polygons.shape[1], dtype=np.int64)
        else:
            vertices = np.concatenate(polygons)  # all (k_i, 3) when the result is (V, 3)
            counts = np.fromiter(map(len, polygons), dtype=np.int64, count=len(polygons))
        if vertices.ndim != 2 or vertices.shape[1] != 3 or vertices.dtype.kind not in "fiu":
            raise ValueError
        if counts.min() < 3:
            raise ValueError
        offsets = np.zeros(counts.size + 1, dtype=np.int64)
        np.cumsum(counts, out=offsets[1:])
        soup = PolygonSoup.from_arrays(vertices, offsets)
        soup._validate()
    except (AttributeError, TypeError, ValueError, GeometryError):
        return PolygonSoup.from_polygons(polygons)
    return soup


def _query_arrays(points, viewpoint) -> tuple[np.ndarray, np.ndarray]:
    """``points`` (N, 3) and ``viewpoint`` (3,) as contiguous float64, or a
    :class:`GeometryError` naming the shapes."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    viewpoint = np.ascontiguousarray(viewpoint, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or viewpoint.shape != (3,):
        raise GeometryError(
            f"expected points (N, 3) and a viewpoint (3,), got shapes {points.shape} and "
            f"{viewpoint.shape}"
        )
    return points, viewpoint


def _checked_query(points: np.ndarray, viewpoint: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``points`` (N, 3) and ``viewpoint`` (3,) as float64, with the same
    :class:`GeometryError` as :meth:`BSPTree.visibility` for a bad shape or a non-finite
    coordinate."""
    points, viewpoint = _query_arrays(points, viewpoint)
    if not np.isfinite(viewpoint).all():
        raise GeometryError(f"viewpoint has a non-finite coordinate: {viewpoint.tolist()}")
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if bad.size:
        raise GeometryError(
            f"point {bad[0]} has a non-finite coordinate: {points[bad[0]].tolist()}"
        )
    return points, viewpoint

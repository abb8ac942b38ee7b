"""A polygon soup in flat arrays: the input of the BSP tree.

Conventions: polygon ``i`` is ``vertices[offsets[i]:offsets[i + 1]]``, a closed loop of at least
three vertices, planar, simple (convex or not), in any orientation. Its unit normal ``normals[i]``
follows the right-hand rule of the vertex order (Newell's method) and its plane is
``normals[i] . x = d[i]``. Lengths are in the caller's unit (metres in cellsight).

Tolerances (all relative, so the soup's unit does not matter, and all per polygon):

- validation (``from_polygons(validate=True)``), with ``size`` the polygon's box diagonal:
  area > ``DEGENERATE_REL * size**2``, every vertex within ``PLANARITY_REL * size`` of the plane,
  non-adjacent edges farther apart than ``SIMPLE_REL * size`` (in the polygon's 2D projection);
- the plane thickness ``eps[i]`` of polygon ``i``, used by the tree for its plane
  (classification against it, point location, contacts):
  ``max(EPS_REL * size, ROUND_REL * magnitude, 2 * largest vertex deviation from its plane)``,
  ``size`` its box diagonal and ``magnitude`` its largest absolute coordinate. It is *local*:
  it depends on the polygon alone, so adding a polygon (however far away or large) never
  changes the tolerance of the others. Its own vertices lie on its plane, and rounding of a
  signed distance near it (~1e-16 * magnitude) stays far below it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cellsight.errors import GeometryError
from cellsight.occlusion._crossing import PolygonArrays
from cellsight.occlusion._soup_kernels import (
    STATUS_BAD_OFFSETS,
    STATUS_FEW_VERTICES,
    STATUS_NOT_FINITE,
    STATUS_OK,
    first_non_simple,
    polygon_planes,
)

DEGENERATE_REL = 1e-10
PLANARITY_REL = 1e-6
SIMPLE_REL = 1e-9
EPS_REL = 1e-9
ROUND_REL = 1e-12


class PolygonSoup:
    """Planar polygons in flat arrays, with their planes and bounds.

    Attributes: ``vertices`` (V, 3) float64, ``offsets`` (P+1,) int64, ``normals`` (P, 3) unit,
    ``d`` (P,), ``planes``
    (P, 4) = ``[normals | d]``, ``boxes`` (P, 6) axis-aligned bounds ``(min xyz, max xyz)``,
    ``spheres`` (P, 4) bounding spheres (vertex mean, radius), ``areas`` (P,), ``deviations``
    (P,) largest vertex distance from the plane, and ``eps`` (P,), each polygon's plane thickness
    (module doc).
    Build with :meth:`from_polygons` (checked) or :meth:`from_arrays` (hot path);
    ``validated`` says whether the geometric checks have passed (they run once).
    """

    def __init__(self, vertices: np.ndarray, offsets: np.ndarray) -> None:
        planes, boxes, spheres, areas, deviations, eps, status, where = polygon_planes(
            vertices, offsets, EPS_REL, ROUND_REL
        )
        if status != STATUS_OK:
            raise GeometryError(_status_message(status, where, vertices, offsets))
        self.vertices = vertices
        self.offsets = offsets
        self.planes = planes
        self.normals = planes[:, :3]
        self.d = planes[:, 3]
        self.boxes = boxes
        self.spheres = spheres
        self.areas = areas
        self.deviations = deviations
        self.eps = eps
        self.validated = False

    def __len__(self) -> int:
        return self.offsets.shape[0] - 1

    def arrays(self) -> PolygonArrays:
        """The arrays the compiled kernels read, as one argument."""
        return PolygonArrays(self.vertices, self.offsets, self.planes, self.eps, self.boxes)

    @classmethod
    def from_arrays(cls, vertices: np.ndarray, offsets: np.ndarray) -> PolygonSoup:
        """Soup from flat arrays, without geometric validation (the per-frame hot path).

        Planes come from one compiled pass. Only what would corrupt the tree is rejected
        (inconsistent offsets, fewer than 3 vertices, non-finite or zero-area polygons), with
        a :class:`GeometryError` naming the polygon.
        """
        vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        offsets = np.ascontiguousarray(offsets, dtype=np.int64)
        if vertices.ndim != 2 or vertices.shape[1] != 3 or offsets.ndim != 1 or offsets.size < 1:
            raise GeometryError(
                f"expected vertices (V, 3) and offsets (P+1,), got shapes {vertices.shape} "
                f"and {offsets.shape}"
            )
        return cls(vertices, offsets)

    @classmethod
    def from_polygons(
        cls,
        polygons: Sequence[np.ndarray],
        validate: bool = True,
    ) -> PolygonSoup:
        """Soup from a sequence of (k_i, 3) vertex arrays, checked when ``validate``.

        Raises :class:`GeometryError` naming the polygon index and the offending value for:
        a wrong shape or fewer than 3 vertices, a non-finite coordinate, a degenerate polygon
        (area below tolerance, e.g. collinear vertices), a non-planar polygon, or a polygon
        whose boundary touches or crosses itself (see the module doc for the tolerances).
        """
        arrays = [_polygon_array(i, p) for i, p in enumerate(polygons)]
        counts = np.array([a.shape[0] for a in arrays], dtype=np.int64)
        offsets = np.zeros(len(arrays) + 1, dtype=np.int64)
        np.cumsum(counts, out=offsets[1:])
        vertices = np.concatenate(arrays) if arrays else np.zeros((0, 3))
        soup = cls(vertices, offsets)
        if validate:
            soup._validate()
        return soup

    def _validate(self) -> None:
        """Degenerate, non-planar and non-simple polygons raise :class:`GeometryError`; once
        passed, :attr:`validated` is set and the checks do not run again."""
        if self.validated or len(self) == 0:
            self.validated = True
            return
        size = np.linalg.norm(self.boxes[:, 3:] - self.boxes[:, :3], axis=1)
        bad = np.flatnonzero(self.areas <= DEGENERATE_REL * size**2)
        if bad.size:
            i = int(bad[0])
            raise GeometryError(
                f"polygon {i} is degenerate: area {self.areas[i]:.3g} <= "
                f"{DEGENERATE_REL:g} * size^2 (size {size[i]:.3g}); are its vertices collinear?"
            )
        bad = np.flatnonzero(self.deviations > PLANARITY_REL * size)
        if bad.size:
            i = int(bad[0])
            raise GeometryError(
                f"polygon {i} is not planar: a vertex lies {self.deviations[i]:.3g} off its "
                f"plane (tolerance {PLANARITY_REL * size[i]:.3g})"
            )
        i, edge_a, edge_b, dist = first_non_simple(
            self.vertices, self.offsets, self.planes, SIMPLE_REL
        )
        if i >= 0:
            raise GeometryError(
                f"polygon {i} is not simple: edges {edge_a} and {edge_b} touch or cross "
                f"(distance {dist:.3g})"
            )
        self.validated = True


def _polygon_array(i: int, polygon: np.ndarray) -> np.ndarray:
    """Polygon ``i`` as a float64 (k, 3) array with k >= 3, or a :class:`GeometryError`."""
    array = np.asarray(polygon, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3:
        raise GeometryError(f"polygon {i}: expected a (k, 3) vertex array, got shape {array.shape}")
    if array.shape[0] < 3:
        raise GeometryError(f"polygon {i} has {array.shape[0]} vertices; at least 3 are needed")
    return array


def _status_message(status: int, where: int, vertices: np.ndarray, offsets: np.ndarray) -> str:
    """Message for a failing ``polygon_planes`` status."""
    if status == STATUS_BAD_OFFSETS:
        return (
            f"offsets must start at 0 and end at the vertex count {vertices.shape[0]}, "
            f"got {offsets[0]} ... {offsets[-1]}"
        )
    if status == STATUS_FEW_VERTICES:
        count = offsets[where + 1] - offsets[where]
        return f"polygon {where} has {count} vertices; at least 3 are needed"
    if status == STATUS_NOT_FINITE:
        rows = vertices[offsets[where] : offsets[where + 1]]
        bad = rows[~np.isfinite(rows).all(axis=1)][0]
        return f"polygon {where} has a non-finite vertex {bad.tolist()}"
    return f"polygon {where} is degenerate: zero area (Newell normal has length 0)"

"""Polyhedral solids: vertices, polygonal faces and named feature points.

Faces are lists of vertex indices, counter-clockwise seen from outside the solid (right-hand
normal points out; docs/design.md, "Conventions"). Feature points are vertices with names; by
default every vertex is a feature named ``f1``, ``f2``, ... in vertex order. Coordinates are
metres in the solid's own frame.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

import mapbox_earcut
import numpy as np

from cellsight.errors import GeometryError
from cellsight.geometry.polygon import check_polygon, newell_normal, plane_basis
from cellsight.geometry.transforms import transform_points


@dataclass(frozen=True)
class Polyhedron:
    """A polyhedral solid (or an open set of surfaces when ``closed=False``).

    Validated when built: every face has >= 3 distinct vertices, is planar, simple and
    non-degenerate; a closed solid has every edge shared by exactly two faces traversing it in
    opposite directions (consistent orientation) and a positive volume (outward normals).
    Errors name the solid and the face.
    """

    name: str
    vertices: np.ndarray
    faces: tuple[tuple[int, ...], ...]
    closed: bool = True
    feature_names: tuple[str, ...] = ()
    feature_vertices: tuple[int, ...] = ()
    normals: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        v = np.asarray(self.vertices, dtype=float)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
            raise GeometryError(f"solid '{self.name}': vertices must be (n>=3, 3), got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise GeometryError(f"solid '{self.name}': non-finite vertex coordinates")
        faces = tuple(tuple(int(i) for i in f) for f in self.faces)
        if not faces:
            raise GeometryError(f"solid '{self.name}': no faces")
        normals = np.empty((len(faces), 3))
        for k, face in enumerate(faces):
            label = f"solid '{self.name}' face {k}"
            if any(i < 0 or i >= len(v) for i in face):
                raise GeometryError(f"{label}: vertex index out of range 0..{len(v) - 1}: {face}")
            if len(set(face)) != len(face):
                raise GeometryError(f"{label}: repeats a vertex: {face}")
            pts = check_polygon(v[list(face)], label)
            n = newell_normal(pts)
            normals[k] = n / np.linalg.norm(n)
        if self.closed:
            _check_closed(self.name, v, faces)
        names, idx = self.feature_names, self.feature_vertices
        if not idx:
            idx = tuple(range(len(v)))
        if not names:
            names = tuple(f"f{i + 1}" for i in range(len(idx)))
        if len(names) != len(idx) or len(set(names)) != len(names):
            raise GeometryError(
                f"solid '{self.name}': feature names must be unique, one per feature vertex"
            )
        if any(i < 0 or i >= len(v) for i in idx):
            raise GeometryError(f"solid '{self.name}': feature vertex index out of range "
                                f"0..{len(v) - 1}: {[int(i) for i in idx]}")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", faces)
        object.__setattr__(self, "normals", normals)
        object.__setattr__(self, "feature_names", tuple(names))
        object.__setattr__(self, "feature_vertices", tuple(int(i) for i in idx))

    @property
    def feature_points(self) -> np.ndarray:
        """Feature points (F, 3) in the solid's frame, in feature order."""
        return self.vertices[list(self.feature_vertices)]

    def face_points(self, k: int) -> np.ndarray:
        """Vertices (k_i, 3) of face ``k``, in order."""
        return self.vertices[list(self.faces[k])]

    def polygons(self) -> list[np.ndarray]:
        """Every face as a (k_i, 3) vertex array, in face order."""
        return [self.face_points(k) for k in range(len(self.faces))]

    def volume(self) -> float:
        """Signed volume (m^3) by the divergence theorem; positive for outward faces."""
        total = 0.0
        for k in range(len(self.faces)):
            p = self.face_points(k)
            total += float(newell_normal(p) @ p[0]) / 6.0
        return total

    def transformed(self, T: np.ndarray, name: str | None = None) -> Polyhedron:
        """The same solid with its vertices moved by the pose ``T`` (4x4). A rigid ``T``
        (rotation orthonormal to ``RIGID_TOL``, det +1) keeps every face valid, so the result is
        not validated again; any other ``T`` gives a fully validated solid."""
        T = np.asarray(T, dtype=float)
        vertices = transform_points(T, self.vertices)
        if not _is_rigid(T):
            return Polyhedron(name or self.name, vertices, self.faces, self.closed,
                              self.feature_names, self.feature_vertices)
        return self._valid_copy(name or self.name, vertices, self.normals @ T[:3, :3].T)

    def renamed(self, name: str) -> Polyhedron:
        """The same solid under another name (not validated again; arrays shared)."""
        return self._valid_copy(name, self.vertices, self.normals)

    def _valid_copy(self, name: str, vertices: np.ndarray, normals: np.ndarray) -> Polyhedron:
        """This solid's faces and features over ``vertices``, which the caller guarantees
        keep them valid (a rigid move of this solid's), without the checks of construction."""
        copy = object.__new__(Polyhedron)
        for key, value in (("name", name), ("vertices", vertices), ("faces", self.faces),
                           ("closed", self.closed), ("feature_names", self.feature_names),
                           ("feature_vertices", self.feature_vertices), ("normals", normals)):
            object.__setattr__(copy, key, value)
        return copy

    def face_triangles(self, k: int) -> np.ndarray:
        """Triangles (t, 3) covering face ``k``, as positions in the face's vertex list, wound
        like the face. Earcut in the face's plane, so non-convex faces are right."""
        pts = self.face_points(k)
        xy = (pts - pts[0]) @ plane_basis(self.normals[k]).T
        tris = mapbox_earcut.triangulate_float64(xy, np.array([len(pts)], dtype=np.uint32))
        tris = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
        normals = np.cross(pts[tris[:, 1]] - pts[tris[:, 0]], pts[tris[:, 2]] - pts[tris[:, 0]])
        flip = normals @ self.normals[k] < 0
        tris[flip] = tris[flip][:, ::-1]
        return tris

    def triangles(self) -> np.ndarray:
        """Vertex-index triangles (T, 3) covering every face, wound like the faces (outward)."""
        return np.concatenate([
            np.asarray(face)[self.face_triangles(k)] for k, face in enumerate(self.faces)
        ])


RIGID_TOL = 1e-9  # largest |R^T R - I| entry of a rotation treated as exact


def _is_rigid(T: np.ndarray) -> bool:
    """Whether ``T`` is a 4x4 rigid transform: orthonormal rotation, det +1, last row 0 0 0 1."""
    R = T[:3, :3]
    return (T.shape == (4, 4) and bool(np.all(np.isfinite(T)))
            and bool(np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], rtol=0.0, atol=0.0))
            and float(np.abs(R.T @ R - np.eye(3)).max()) <= RIGID_TOL
            and float(np.linalg.det(R)) > 0.0)


def _check_closed(name: str, v: np.ndarray, faces: Sequence[Sequence[int]]) -> None:
    """Raise unless every directed edge appears once and its reverse once, volume > 0."""
    directed = Counter()
    owner: dict[tuple[int, int], int] = {}
    for k, face in enumerate(faces):
        for a, b in zip(face, face[1:] + face[:1], strict=True):
            directed[(a, b)] += 1
            owner.setdefault((a, b), k)
    for (a, b), count in directed.items():
        if count > 1:
            raise GeometryError(
                f"solid '{name}' face {owner[(a, b)]}: edge {a}->{b} is traversed in the same "
                f"direction by two faces (inconsistent orientation)"
            )
        if (b, a) not in directed:
            raise GeometryError(
                f"solid '{name}' face {owner[(a, b)]}: edge {a}->{b} has no opposite face "
                f"(solid is not closed)"
            )
    vol = sum(
        float(newell_normal(v[list(f)]) @ v[f[0]]) / 6.0 for f in faces
    )
    if vol <= 0:
        raise GeometryError(
            f"solid '{name}' face 0: faces are oriented inward (signed volume {vol:.3g} m^3); "
            f"list each face counter-clockwise seen from outside"
        )


def joined(name: str, solids: Sequence[Polyhedron]) -> Polyhedron:
    """One solid made of several (their vertices and faces side by side; closed when every one
    is): a rigid body of many parts, as a URDF link of several collision elements."""
    if len(solids) == 1:
        return solids[0].renamed(name)
    starts = np.cumsum([0] + [len(s.vertices) for s in solids])
    faces = tuple(tuple(int(i) + int(start) for i in face)
                  for s, start in zip(solids, starts, strict=False) for face in s.faces)
    return Polyhedron(name, np.vstack([s.vertices for s in solids]), faces,
                      all(s.closed for s in solids))


def box(name: str, size, center=(0.0, 0.0, 0.0)) -> Polyhedron:
    """Axis-aligned box of the given size (m) centred at ``center``, 8 vertices, 6 faces."""
    sx, sy, sz = (0.5 * float(s) for s in size)
    if min(sx, sy, sz) <= 0:
        raise GeometryError(f"solid '{name}': box size must be positive, got "
                            f"{[float(s) for s in size]}")
    c = np.asarray(center, dtype=float)
    corners = np.array(
        [[x, y, z] for z in (-sz, sz) for y in (-sy, sy) for x in (-sx, sx)], dtype=float
    )
    corners = corners[[0, 1, 3, 2, 4, 5, 7, 6]] + c
    faces = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    return Polyhedron(name, corners, tuple(faces))


def prism(name: str, polygon_xy, height: float, z0: float = 0.0, **features) -> Polyhedron:
    """Right prism: the simple polygon ``polygon_xy`` (k, 2) in the z = ``z0`` plane extruded by
    ``height`` along +z. Bottom vertices come first (1..k), then the top ones (k+1..2k); faces:
    bottom, top, then the sides. The polygon may be given in either orientation."""
    xy = np.asarray(polygon_xy, dtype=float)
    if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) < 3:
        raise GeometryError(f"solid '{name}': prism polygon must be (k>=3, 2), got {xy.shape}")
    if height <= 0:
        raise GeometryError(f"solid '{name}': prism height must be positive, got {float(height)}")
    signed = 0.5 * np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1])
    if signed < 0:
        xy = xy[::-1]
    k = len(xy)
    bottom = np.column_stack([xy, np.full(k, z0)])
    top = np.column_stack([xy, np.full(k, z0 + height)])
    faces = [tuple(range(k - 1, -1, -1)), tuple(range(k, 2 * k))]
    faces += [(i, (i + 1) % k, k + (i + 1) % k, k + i) for i in range(k)]
    return Polyhedron(name, np.vstack([bottom, top]), tuple(faces), **features)


def segment_box(name: str, start, end, width: float, height: float | None = None) -> Polyhedron:
    """Box whose long axis runs from ``start`` to ``end`` (m), with the given cross-section,
    extended by half the width beyond each end so that consecutive links overlap at joints."""
    a, b = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    height = width if height is None else height
    axis = b - a
    length = np.linalg.norm(axis)
    if length < 1e-9:
        return box(name, (width, height, width), a)
    x = axis / length
    helper = np.array([0.0, 0.0, 1.0]) if abs(x[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(helper, x)
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, z])
    T[:3, 3] = 0.5 * (a + b)
    return box(name, (length + width, width, height)).transformed(T)

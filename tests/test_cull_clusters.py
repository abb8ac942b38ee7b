"""The exact cull on cells with UR5 collision meshes (issue 11): whole objects and clusters of
nearby polygons are skipped by their boxes, then each polygon by the features it could cover.

Checked directly: every polygon that can hide a feature (or a near-occluder ring point) from a
camera — it crosses the line of sight and faces the camera, or its solid is open or may hold
the camera — is kept for that camera, whose visit skips the others (vectorised
segment/triangle test, independent of the cull); and culled answers equal unculled ones.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cellsight import load_cell
from cellsight.errors import GeometryError
from cellsight.occlusion.backends import visibility_predictor
from cellsight.occlusion.bsp import BSPTree
from cellsight.occlusion.frame_bsp import CLUSTER_SIZE, camera_bit, polygon_clusters
from cellsight.occlusion.predictor import VisibilityPredictor
from cellsight.occlusion.scenarios import random_snapshots
from cellsight.occlusion.soup import PolygonSoup
from cellsight.visibility import FRAME_BSP

ROOT = Path(__file__).resolve().parents[1]
CELLS = {"one UR5": ROOT / "tests" / "data" / "ur5_cell.yaml",
         "two UR5": ROOT / "bench" / "ur2_cell.yaml"}


@pytest.fixture(scope="module", params=list(CELLS))
def cell(request):
    return load_cell(CELLS[request.param])


def _triangles(predictor: VisibilityPredictor) -> tuple[np.ndarray, np.ndarray]:
    """Triangles (T, 3) over the predictor's flat vertex array and their polygon (T,)."""
    tris, owner = [], []
    surfaces = predictor.surfaces
    for k, (obj, face) in enumerate(surfaces.poly_source):
        t = surfaces.offsets[k] + predictor.cell.objects[obj].solid.face_triangles(face)
        tris.append(t)
        owner.append(np.full(len(t), k))
    return np.concatenate(tris), np.concatenate(owner)


def _crossed(a, b, c, view, points) -> np.ndarray:
    """(T, S) whether the segment view -> points[s] crosses triangle (a, b, c)[t] before the
    point (Moeller-Trumbore, with a little slack so that grazing crossings count)."""
    e1, e2 = b - a, c - a
    d = points - view  # (S, 3)
    h = np.cross(d[None], e2[:, None])  # (T, S, 3)
    det = np.einsum("tj,tsj->ts", e1, h)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = view - a  # (T, 3)
        u = np.einsum("tj,tsj->ts", s, h) * inv
        q = np.cross(s, e1)  # (T, 3)
        v = np.einsum("sj,tj->ts", d, q) * inv
        t = np.einsum("tj,tj->t", e2, q)[:, None] * inv
    slack = 1e-9
    return ((np.abs(det) > 1e-18) & (u >= -slack) & (v >= -slack) & (u + v <= 1 + slack)
            & (t > 0) & (t < 1 - 1e-7))


@pytest.mark.slow
@pytest.mark.parametrize("near_px", [0.0, 5.0])
def test_every_polygon_that_can_hide_a_feature_is_kept(cell, near_px) -> None:
    predictor = visibility_predictor(cell, near_px=near_px, structure=FRAME_BSP)
    tris, tri_poly = _triangles(predictor)
    closed = predictor.surfaces.object_closed[predictor.surfaces.poly_owner[tri_poly]]
    checked = needed = 0
    for snapshot in random_snapshots(cell, 30, seed=5):
        points, views = predictor._project(snapshot)
        _, keep = predictor._cull(snapshot, points, views)
        verts = predictor.surfaces.world_vertices(snapshot)
        a, b, c = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
        normal = np.cross(b - a, c - a)
        for k, (cam, (_, status)) in enumerate(zip(predictor.cameras, views, strict=True)):
            inside = points[status == 0]
            if not len(inside):
                continue
            ends = np.concatenate([inside, predictor._ring(cam, inside).reshape(-1, 3)])
            facing = np.einsum("tj,tj->t", cam.center - a, normal) > 0
            must = _crossed(a, b, c, cam.center, ends).any(axis=1) & (facing | ~closed)
            dropped = np.flatnonzero(must & ((keep[tri_poly] & camera_bit(k)) == 0))
            assert not dropped.size, (cam.name, tri_poly[dropped][:10])
            checked += 1
            needed += int(must.sum())
    assert checked > 45 and needed > 100  # the scenes really have occluders in front


def test_culled_answers_equal_unculled_ones(cell) -> None:
    culled = visibility_predictor(cell, structure=FRAME_BSP)
    full = visibility_predictor(cell, cull=False, structure=FRAME_BSP)
    hidden = 0
    for snapshot in random_snapshots(cell, 8, seed=9):
        fast, slow = culled.predict_snapshot(snapshot), full.predict_snapshot(snapshot)
        for a, b in zip(fast["part"], slow["part"], strict=True):
            np.testing.assert_array_equal(a.visible, b.visible)
            assert a.reason == b.reason
            hidden += int((a.status == 0).sum() - a.visible.sum())
    assert hidden > 0


def test_clusters_partition_each_object_within_their_boxes(cell) -> None:
    surfaces = visibility_predictor(cell).surfaces
    polys, start, box, object_clusters, object_box = polygon_clusters(
        surfaces.local_vertices, surfaces.offsets, surfaces.object_polys, CLUSTER_SIZE)
    assert np.array_equal(np.sort(polys), np.arange(len(surfaces)))
    assert np.diff(start).max() <= CLUSTER_SIZE and np.diff(start).min() >= 1
    for k in range(len(cell.objects)):
        for c in range(object_clusters[k], object_clusters[k + 1]):
            members = polys[start[c]:start[c + 1]]
            assert np.all(surfaces.poly_owner[members] == k)
            for p in members:
                v = surfaces.local_vertices[surfaces.offsets[p]:surfaces.offsets[p + 1]]
                assert np.all(v >= box[c, :3]) and np.all(v <= box[c, 3:])
                assert np.all(v >= object_box[k, :3]) and np.all(v <= object_box[k, 3:])


def test_a_visit_skips_the_polygons_it_is_told_cannot_hide() -> None:
    square = np.array([[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, 1.0]])
    tree = BSPTree.build(PolygonSoup.from_polygons([square, square + [0.0, 0.0, 1.0]]))
    points, view = np.array([[0.0, 0.0, 0.0]]), np.array([0.0, 0.0, 5.0])
    visible, occluder = tree.visibility(points, view)
    assert not visible[0] and occluder[0] == 1  # the nearer square
    visible, occluder = tree.visibility(points, view, relevant=np.array([True, False]))
    assert not visible[0] and occluder[0] == 0
    assert tree.visibility(points, view, relevant=np.array([False, False]))[0][0]
    with pytest.raises(GeometryError, match="relevant"):
        tree.visibility(points, view, relevant=np.ones(3, dtype=bool))

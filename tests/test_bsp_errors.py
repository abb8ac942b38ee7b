"""Bad input raises GeometryError naming the polygon and the value; hard inputs still build."""

from __future__ import annotations

import numpy as np
import pytest
from oracle import random_rotation, segment_oracle

from cellsight.errors import GeometryError
from cellsight.occlusion import BSPTree, PolygonSoup, visible_mask

SQUARE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])


def soup_with(bad: np.ndarray) -> list[np.ndarray]:
    """Two good squares, then the bad polygon at index 2."""
    return [SQUARE, SQUARE + [0.0, 0.0, 1.0], bad]


@pytest.mark.parametrize(
    ("bad", "words"),
    [
        (SQUARE + [[0, 0, 0], [0, 0, 0], [0, 0, 0.2], [0, 0, 0]],
         ["polygon 2", "not planar", "0.0495"]),
        (SQUARE[:2], ["polygon 2", "2 vertices"]),
        (np.where(np.eye(4, 3, dtype=bool), np.nan, SQUARE), ["polygon 2", "nan"]),
        (np.array([[0.0, 0, 0], [1, 1, 1], [2, 2, 2]]), ["polygon 2", "degenerate"]),
        (np.array([[0.0, 0, 0], [2, 2, 0], [2, 0, 0], [0, 1, 0]]), ["polygon 2", "not simple"]),
        (np.array([[0.0, 0, 0], [1, 0, 0], [1, 0, 0], [0, 1, 0]]), ["polygon 2", "not simple"]),
        (np.zeros((4, 2)), ["polygon 2", "shape"]),
    ],
    ids=["non-planar", "two-vertices", "nan", "collinear", "bow-tie", "repeated-vertex", "2d"],
)
def test_bad_polygon_names_index_and_value(bad, words):
    with pytest.raises(GeometryError) as info:
        PolygonSoup.from_polygons(soup_with(bad))
    message = str(info.value).lower()
    for word in words:
        assert word in message, message


def test_from_arrays_rejects_what_would_corrupt_the_tree():
    vertices = np.concatenate([SQUARE, SQUARE])
    vertices[5, 1] = np.inf
    with pytest.raises(GeometryError, match="polygon 1 has a non-finite vertex"):
        PolygonSoup.from_arrays(vertices, [0, 4, 8])
    with pytest.raises(GeometryError, match="polygon 1 has 2 vertices"):
        PolygonSoup.from_arrays(np.concatenate([SQUARE, SQUARE[:2]]), [0, 4, 6])
    with pytest.raises(GeometryError, match="offsets"):
        PolygonSoup.from_arrays(SQUARE, [0, 3])
    with pytest.raises(GeometryError, match="polygon 0 is degenerate"):
        PolygonSoup.from_arrays(np.zeros((3, 3)), [0, 3])


def test_validation_accepts_non_convex_and_collinear_vertices():
    l_shape = np.array([[0, 0, 0], [2, 0, 0], [2, 1, 0], [1, 1, 0], [1, 2, 0], [0, 2, 0.0]])
    straight = np.array([[0, 0, 0], [0.5, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])
    soup = PolygonSoup.from_polygons([l_shape, straight[::-1]])
    np.testing.assert_allclose(soup.normals, [[0, 0, 1], [0, 0, -1]], atol=1e-15)
    np.testing.assert_allclose(soup.areas, [3.0, 1.0])


@pytest.mark.parametrize(
    ("points", "view", "match"),
    [
        ([[0.5, 0.5, np.nan]], [0, 0, 5], "point 0"),
        ([[0.5, 0.5, 1.0]], [0, np.inf, 5], "viewpoint"),
        ([0.5, 0.5, 1.0], [0, 0, 5], "shape"),
    ],
)
def test_bad_query_raises(points, view, match):
    tree = BSPTree.build(PolygonSoup.from_polygons([SQUARE]))
    with pytest.raises(GeometryError, match=match):
        tree.visibility(np.array(points, dtype=float), np.array(view, dtype=float))


def test_viewpoint_on_a_polygon_plane_sees_it_edge_on():
    """A polygon whose plane contains the viewpoint hides nothing, even points behind it."""
    rng = np.random.default_rng(7)
    wall = np.array([[0, -1, -1], [0, 1, -1], [0, 1, 1], [0, -1, 1.0]])
    floor = np.array([[-3, -3, -2], [3, -3, -2], [3, 3, -2], [-3, 3, -2.0]])
    polygons = [wall, floor]
    view = np.array([0.0, -3.0, 0.5])  # in the wall's plane x = 0, beside the wall
    points = np.concatenate([rng.uniform(-2, 2, (300, 3)), [[0, 3, 0.5], [0, 0.5, 0.0]]])
    visible, occluder = BSPTree.build(PolygonSoup.from_polygons(polygons)).visibility(points, view)
    answer = segment_oracle(polygons, points, view)
    assert not (answer.hits[:, 0]).any()  # the oracle agrees: the wall hides nothing
    keep = ~answer.ambiguous
    assert keep.mean() > 0.98
    np.testing.assert_array_equal(visible[keep], answer.visible[keep])
    assert visible[-2] and visible[-1]  # straight through the wall's plane, and on the wall
    assert not (occluder == 0).any()


def test_points_at_or_around_the_viewpoint():
    view = np.array([0.5, 0.5, 2.0])
    points = np.array([view, [0.5, 0.5, -1.0], [0.5, 0.5, 3.0]])
    visible = visible_mask([SQUARE], points, view)
    np.testing.assert_array_equal(visible, [True, False, True])


def random_boxes(rng: np.random.Generator, n_boxes: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat arrays of ``n_boxes`` randomly rotated boxes on a jittered grid (6 quads each)."""
    corners = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
    faces = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4],
                      [1, 5, 7, 3]])
    side = int(np.ceil(n_boxes ** (1 / 3)))
    cells = np.stack(np.unravel_index(np.arange(n_boxes), (side, side, side)), axis=1)
    boxes = []
    for cell in cells:
        local = corners * rng.uniform(0.1, 0.3, 3) @ random_rotation(rng).T
        boxes.append((local + cell + rng.uniform(-0.1, 0.1, 3))[faces].reshape(-1, 3))
    return np.concatenate(boxes), np.arange(0, 24 * n_boxes + 1, 4)


def test_30000_polygons_build_and_answer():
    rng = np.random.default_rng(11)
    vertices, offsets = random_boxes(rng, 5000)
    tree = BSPTree.build(PolygonSoup.from_arrays(vertices, offsets))
    assert tree.stats["fragments"] == 30_000 + tree.stats["splits"]
    points = rng.uniform(0, 17, (64, 3))
    visible, _ = tree.visibility(points, np.array([-5.0, -4.0, 30.0]))
    assert 0 < visible.sum() < 64


def test_coplanar_heavy_input_builds():
    """5,000 coplanar squares on a grid plus stacks of parallel squares: deep but iterative."""
    grid = [SQUARE * 0.5 + [i, j, 0.0] for i in range(100) for j in range(50)]
    stacks = [SQUARE * 0.5 + [i, 0.0, 0.01 * (k + 1)] for i in range(3) for k in range(1500)]
    soup = PolygonSoup.from_polygons(grid + stacks)
    tree = BSPTree.build(soup)
    assert tree.stats["fragments"] == len(soup) + tree.stats["splits"]
    assert tree.stats["depth"] > 10
    points = np.array([[0.25, 0.25, -1.0], [50.25, 20.25, 1.0], [0.25, 0.25, 7.0]])
    visible, occluder = tree.visibility(points, np.array([0.25, 0.25, 20.0]))
    np.testing.assert_array_equal(visible, [False, True, False])
    assert occluder[0] == len(grid) + 1499 and occluder[2] == len(grid) + 1499


def test_chain_as_deep_as_the_polygon_count_is_iterative():
    """Rectangles tangent to a cylinder: every plane has all the others behind it, so the tree
    is one chain of 3,000 nodes (far beyond Python's recursion limit), visited without recursion.
    """
    n = 3000
    angles = 2 * np.pi * np.arange(n) / n
    half = 0.4 * np.pi / n  # tangential half-width: no rectangle reaches another one's plane
    normal = np.stack([np.cos(angles), np.sin(angles), np.zeros(n)], axis=1)
    tangent = np.stack([-np.sin(angles), np.cos(angles), np.zeros(n)], axis=1)
    up = np.array([0.0, 0.0, 1.0])
    rectangles = [
        np.stack([c - half * t - up, c + half * t - up, c + half * t + up, c - half * t + up])
        for c, t in zip(normal, tangent, strict=True)
    ]
    tree = BSPTree.build(PolygonSoup.from_polygons(rectangles))
    assert tree.stats["depth"] == n and tree.stats["splits"] == 0
    points = np.array([[2.0, 0.0, 0.0], [0.5, 0.0, 0.5], [0.0, -3.0, 0.0]])
    visible, occluder = tree.visibility(points, np.zeros(3))
    np.testing.assert_array_equal(visible, [False, True, False])
    assert occluder[0] == 0 and occluder[2] == 3 * n // 4


def test_empty_soup_hides_nothing():
    tree = BSPTree.build(PolygonSoup.from_polygons([]))
    assert tree.stats == {"nodes": 0, "splits": 0, "depth": 0, "fragments": 0}
    visible, occluder = tree.visibility(np.zeros((2, 3)), np.ones(3))
    assert visible.all() and (occluder == -1).all()


@pytest.mark.parametrize("seed", range(40))
def test_thin_triangles_are_non_simple_exactly_when_a_vertex_nears_the_opposite_edge(seed):
    """A triangle's vertex within SIMPLE_REL x its 2D box diagonal of the opposite edge makes it
    non-simple (the triangle path of ``first_non_simple``), distances computed here in numpy."""
    from cellsight.occlusion._soup_kernels import first_non_simple
    from cellsight.occlusion.soup import SIMPLE_REL

    rng = np.random.default_rng(seed)
    a, b = np.array([0.0, 0.0]), np.array([1.0, rng.uniform(-0.2, 0.2)])
    u = rng.uniform(-0.2, 1.2)
    away = rng.choice([0.3, 0.9, 1.1, 3.0]) * SIMPLE_REL * np.hypot(1.0, 1.2)
    normal = np.array([-(b - a)[1], (b - a)[0]]) / np.linalg.norm(b - a)
    c = a + u * (b - a) + away * normal
    tri2 = np.roll(np.array([a, b, c]), rng.integers(3), axis=0)
    tri = np.column_stack([tri2, np.zeros(3)])
    soup = PolygonSoup.from_arrays(tri, np.array([0, 3]))
    found, _, _, dist = first_non_simple(soup.vertices, soup.offsets, soup.planes, SIMPLE_REL)

    def to_edge(p, q, r):
        t = np.clip((p - q) @ (r - q) / ((r - q) @ (r - q)), 0.0, 1.0)
        return np.linalg.norm(p - q - t * (r - q))

    p0, p1, p2 = tri2
    nearest = min(to_edge(p2, p0, p1), to_edge(p0, p1, p2), to_edge(p1, p2, p0))
    tol = SIMPLE_REL * np.linalg.norm(tri2.max(axis=0) - tri2.min(axis=0))
    assert (found == 0) == (nearest <= tol)
    if found == 0:
        assert dist == pytest.approx(nearest, rel=1e-6, abs=1e-15)

"""The fast paths of :func:`cellsight.occlusion.visible_mask` (exact cull, then the direct
(point, polygon) test or the BSP of the kept polygons) against the BSP of everything, on random
soups and solids: no disagreement outside the oracle's ambiguous cases."""

from __future__ import annotations

import numpy as np
import pytest
from oracle import random_convex_solid, random_prism, random_soup, segment_oracle

from cellsight.errors import GeometryError
from cellsight.occlusion import PolygonSoup, visible_mask

METHODS = ("direct", "bsp", "auto")


def _scene(rng: np.random.Generator, kind: int):
    """Polygons, points (some on vertices) and a viewpoint of one random scene."""
    if kind == 0:
        polygons = random_soup(rng, int(rng.integers(1, 30)))
    else:
        polygons = []
        for _ in range(int(rng.integers(1, 5))):
            make = random_convex_solid if kind == 1 else random_prism
            faces, _ = make(rng, rng.uniform(-1, 1, 3), rng.uniform(0.3, 0.9))
            polygons.extend(faces)
    points = rng.uniform(-1.5, 1.5, (int(rng.integers(1, 40)), 3))
    verts = np.concatenate(polygons)
    some = rng.integers(0, len(verts), min(5, len(points)))
    points[: len(some)] = verts[some]
    viewpoint = rng.uniform(-3, 3, 3)
    return polygons, points, viewpoint


@pytest.mark.slow
@pytest.mark.parametrize("kind", [0, 1, 2])
def test_fast_paths_agree_with_the_full_bsp(kind):
    rng = np.random.default_rng(100 + kind)
    compared = 0
    for _ in range(350):
        polygons, points, viewpoint = _scene(rng, kind)
        full = visible_mask(polygons, points, viewpoint, _method="full")
        keep = ~segment_oracle(polygons, points, viewpoint).ambiguous
        for method in METHODS:
            fast = visible_mask(polygons, points, viewpoint, _method=method)
            np.testing.assert_array_equal(fast[keep], full[keep], err_msg=method)
        compared += int(keep.sum())
    assert compared > 2500


def test_a_soup_joined_once_answers_as_the_list():
    """The list joined once into a :class:`PolygonSoup` and reused: the same answers as the
    list itself, call after call, by every method."""
    rng = np.random.default_rng(11)
    for kind in (0, 1, 2):
        for _ in range(40):
            polygons, points, viewpoint = _scene(rng, kind)
            soup = PolygonSoup.from_polygons(polygons)
            for method in (*METHODS, "full"):
                np.testing.assert_array_equal(
                    visible_mask(soup, points, viewpoint, _method=method),
                    visible_mask(polygons, points, viewpoint, _method=method), err_msg=method)


def test_an_unchecked_soup_is_validated_once_with_the_lists_error():
    bent = [np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0.5], [0, 1, 0]], float)]
    soup = PolygonSoup.from_arrays(np.concatenate(bent), np.array([0, 4]))
    assert not soup.validated
    with pytest.raises(GeometryError) as from_soup:
        visible_mask(soup, np.zeros((1, 3)), np.ones(3))
    with pytest.raises(GeometryError) as from_list:
        visible_mask(bent, np.zeros((1, 3)), np.ones(3))
    assert str(from_soup.value) == str(from_list.value) and not soup.validated
    flat = bent[0] * [1.0, 1.0, 0.0]
    soup = PolygonSoup.from_arrays(flat, np.array([0, 4]))
    assert visible_mask(soup, np.array([[0.5, 0.5, -1.0]]), np.array([0.5, 0.5, 1.0])).tolist() \
        == [False]
    assert soup.validated


def test_far_and_outside_polygons_are_culled_without_changing_answers():
    rng = np.random.default_rng(7)
    polygons = random_soup(rng, 40) + [p + [0.0, 0.0, 50.0] for p in random_soup(rng, 40)]
    points = rng.uniform(-1, 1, (64, 3))
    viewpoint = np.array([0.0, 0.0, -3.0])
    full = visible_mask(polygons, points, viewpoint, _method="full")
    keep = ~segment_oracle(polygons, points, viewpoint).ambiguous
    for method in METHODS:
        np.testing.assert_array_equal(
            visible_mask(polygons, points, viewpoint, _method=method)[keep], full[keep])


@pytest.mark.parametrize("polygons", [
    [np.zeros((2, 3))], [np.zeros((3, 2))], [[[0, 0, 0], [1, 0, 0], [2, 0, 0]]],
    [np.array([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]])],
    [np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0.5], [0, 1, 0]])],
])
def test_bad_polygons_raise_as_from_polygons(polygons):
    with pytest.raises(GeometryError) as fast:
        visible_mask(polygons, np.zeros((1, 3)), np.ones(3))
    with pytest.raises(GeometryError) as full:
        visible_mask(polygons, np.zeros((1, 3)), np.ones(3), _method="full")
    assert str(fast.value) == str(full.value)


@pytest.mark.parametrize("points, view", [
    (np.zeros((2, 2)), np.ones(3)), (np.array([[0, 0, np.inf]]), np.ones(3)),
    (np.zeros((1, 3)), np.array([0, np.nan, 0])),
])
def test_bad_queries_raise_as_the_bsp(points, view):
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    with pytest.raises(GeometryError) as fast:
        visible_mask([square], points, view)
    with pytest.raises(GeometryError) as full:
        visible_mask([square], points, view, _method="full")
    assert str(fast.value) == str(full.value)


def test_empty_and_float32_input():
    points = np.array([[0.5, 0.5, -1.0], [0.5, 0.5, 3.0]])
    assert visible_mask([], points, np.zeros(3)).all()
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    np.testing.assert_array_equal(visible_mask([square], points, np.array([0.5, 0.5, 2.0])),
                                  [False, True])


def test_an_array_of_equal_polygons_answers_as_the_list():
    """(P, k, 3) input (a mesh's triangles, boxes' quads) against the oracle and the list."""
    rng = np.random.default_rng(12)
    triangles = np.concatenate([
        [tri for face in random_convex_solid(rng, rng.uniform(-1, 1, 3), 0.5)[0]
         for tri in _fan(face)] for _ in range(6)])
    points, view = rng.uniform(-1.5, 1.5, (64, 3)), rng.uniform(-4, 4, 3)
    answer = visible_mask(triangles, points, view)
    np.testing.assert_array_equal(answer, visible_mask(list(triangles), points, view))
    oracle = segment_oracle(list(triangles), points, view)
    sure = ~oracle.ambiguous
    np.testing.assert_array_equal(answer[sure], oracle.visible[sure])
    assert 0 < answer.sum() < len(points)


def _fan(face: np.ndarray) -> list[np.ndarray]:
    """The triangles of a convex face, fanned from its first vertex."""
    return [face[[0, i, i + 1]] for i in range(1, len(face) - 1)]


@pytest.mark.parametrize("bad, message", [
    (np.zeros((2, 2, 3)), "polygon 0 has 2 vertices"),
    (np.full((1, 3, 3), np.nan), "polygon 0 has a non-finite vertex"),
    (np.zeros((1, 3, 3)), "polygon 0 is degenerate"),
])
def test_a_bad_polygon_array_raises_as_from_polygons(bad, message):
    with pytest.raises(GeometryError, match=message):
        visible_mask(bad, np.zeros((1, 3)), np.ones(3))

"""Properties of BSP visibility (hypothesis): order independence, rigid-motion invariance,
polygons behind a point never hide it, and every reported occluder really crosses the segment.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from oracle import random_rotation, random_soup, segment_oracle, soup_and_solids

from cellsight.occlusion import BSPTree, PolygonSoup

SETTINGS = settings(max_examples=40, deadline=None)
seeds = st.integers(min_value=0, max_value=2**32 - 1)


def scene(seed: int) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Polygons (a soup plus two solids), query points (free and on vertices), a viewpoint."""
    rng = np.random.default_rng(seed)
    polygons, vertices = soup_and_solids(rng)
    points = np.concatenate([rng.uniform(-1.5, 1.5, (30, 3))] + vertices)
    return polygons, points, rng.uniform(-3, 3, 3)


def answer(polygons, points, view):
    """BSP visible flags and occluders."""
    return BSPTree.build(PolygonSoup.from_polygons(polygons)).visibility(points, view)


@SETTINGS
@given(seeds, st.randoms(use_true_random=False))
def test_independent_of_polygon_order(seed, random):
    polygons, points, view = scene(seed)
    order = list(range(len(polygons)))
    random.shuffle(order)
    visible, occluder = answer(polygons, points, view)
    shuffled_visible, shuffled_occluder = answer([polygons[i] for i in order], points, view)
    keep = ~segment_oracle(polygons, points, view).ambiguous
    np.testing.assert_array_equal(shuffled_visible[keep], visible[keep])
    mapped = np.where(shuffled_occluder >= 0, np.asarray(order)[shuffled_occluder], -1)
    np.testing.assert_array_equal(mapped[keep], occluder[keep])


@SETTINGS
@given(seeds, st.floats(-10, 10), st.floats(-10, 10), st.floats(-10, 10))
def test_invariant_under_rigid_motion(seed, tx, ty, tz):
    polygons, points, view = scene(seed)
    rotation = random_rotation(np.random.default_rng(seed + 1))
    shift = np.array([tx, ty, tz])

    def move(x):
        return x @ rotation.T + shift

    visible, occluder = answer(polygons, points, view)
    moved_visible, moved_occluder = answer([move(p) for p in polygons], move(points), move(view))
    keep = ~segment_oracle(polygons, points, view).ambiguous
    np.testing.assert_array_equal(moved_visible[keep], visible[keep])
    np.testing.assert_array_equal(moved_occluder[keep], occluder[keep])


@SETTINGS
@given(seeds, st.floats(0.05, 2.0))
def test_polygons_entirely_behind_the_point_never_hide_it(seed, gap):
    """Polygons all farther along the line of sight than the point's depth (plus a gap)."""
    rng = np.random.default_rng(seed)
    view = rng.uniform(-1, 1, 3)
    direction = random_rotation(rng)[:, 0]
    point = view + direction * rng.uniform(0.5, 3.0)
    depth = (point - view) @ direction
    polygons = []
    for polygon in random_soup(rng, int(rng.integers(1, 30))):
        along = (polygon - view) @ direction
        polygons.append(polygon + direction * (depth + gap - along.min()))
    visible, occluder = answer(polygons, point[None, :], view)
    assert visible[0] and occluder[0] == -1


@SETTINGS
@given(seeds)
def test_occluder_really_crosses_the_segment(seed):
    polygons, points, view = scene(seed)
    visible, occluder = answer(polygons, points, view)
    oracle = segment_oracle(polygons, points, view)
    hidden = np.flatnonzero((occluder >= 0) & ~oracle.ambiguous)
    assert np.array_equal(occluder >= 0, ~visible)
    assert oracle.hits[hidden, occluder[hidden]].all()
    nearest = oracle.t[hidden, oracle.occluder[hidden]]
    np.testing.assert_allclose(oracle.t[hidden, occluder[hidden]], nearest, rtol=0, atol=1e-9)

"""Exactness of the occlusion prediction under every configuration (issue 14).

- a camera inside a closed solid (a housing around the lens), convex or not, or on its boundary
  (a face, an edge): the culled predictor agrees with the unculled one and with the oracle;
- plane tolerances are local: a polygon added far away (1 km, 1000 km) never changes the
  answers for the others;
- the predictor's tolerances are checked.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from oracle import cell_scene, random_soup, segment_oracle, soup_and_solids

from cellsight import load_cell
from cellsight.errors import CellsightError
from cellsight.geometry.polyhedron import box, prism
from cellsight.model.cell import Cell, StaticObject
from cellsight.occlusion import BSPTree, PolygonSoup
from cellsight.occlusion.backends import visibility_predictor
from cellsight.occlusion.scenarios import random_snapshots
from cellsight.visibility import FRAME_BSP, STRUCTURES

L_SHAPE = [(-0.05, -0.05), (0.2, -0.05), (0.2, 0.05), (0.05, 0.05), (0.05, 0.2), (-0.05, 0.2)]
# housing solids in cam1's frame (z forward, optical centre at the origin), m
HOUSINGS = {
    "inside a box": (box("housing", (0.1, 0.1, 0.1)), "all hidden"),
    "inside a non-convex prism": (prism("housing", L_SHAPE, 0.1, z0=-0.05), "all hidden"),
    "on a face, looking in": (box("housing", (0.1, 0.1, 0.1), (0, 0, 0.05)), "all hidden"),
    "on a face, looking out": (box("housing", (0.1, 0.1, 0.1), (0, 0, -0.05)), "none hidden"),
    "on an edge": (box("housing", (0.1, 0.1, 0.1), (0.05, 0, 0.05)), "some hidden"),
    "on a vertex": (box("housing", (0.1, 0.1, 0.1), (0.05, 0.05, 0.05)), "some hidden"),
}


@pytest.fixture(scope="module")
def cell():
    return load_cell()


def _with_housing(cell: Cell, solid) -> Cell:
    """The cell plus a static solid placed in cam1's frame."""
    housing = StaticObject("housing", (solid,), cell.cameras[0].T_base_cam)
    return Cell(cell.name, cell.robots, cell.workpieces, [*cell.static, housing], cell.cameras,
                cell.source, cell.experiments)


@pytest.mark.parametrize("structure", STRUCTURES)
@pytest.mark.parametrize("case", list(HOUSINGS))
def test_camera_in_or_on_a_closed_solid(cell, case, structure) -> None:
    """Culled BSP (or hierarchies) == unculled BSP == oracle for cam1 inside / on a housing,
    at HOME and at random configurations; the housing really hides the features it should."""
    solid, expect = HOUSINGS[case]
    housed = _with_housing(cell, solid)
    culled = visibility_predictor(housed, structure=structure)
    full = visibility_predictor(housed, cull=False, structure=FRAME_BSP)
    snapshots = [housed.snapshot()] + random_snapshots(housed, 12, seed=3)
    checked = by_housing = seen_total = 0
    for snapshot in snapshots:
        fast = culled.predict_snapshot(snapshot)["part"][0]
        slow = full.predict_snapshot(snapshot)["part"][0]
        np.testing.assert_array_equal(fast.visible, slow.visible)
        assert fast.reason == slow.reason
        polygons, labels, features = cell_scene(housed, snapshot)
        seen = np.flatnonzero(fast.status == 0)
        if not seen.size:
            continue
        oracle = segment_oracle(polygons, features[seen], housed.cameras[0].center,
                                culled.surface_tolerance, prune=True)
        for j, i in enumerate(seen):
            if oracle.ambiguous[j]:
                continue
            checked += 1
            want = "" if oracle.visible[j] else labels[oracle.occluder[j]]
            assert fast.reason[i] == want, (case, i, fast.reason[i], want)
            by_housing += want == "housing"
        seen_total += seen.size
    assert checked >= 0.9 * seen_total > 0
    if expect == "all hidden":
        assert by_housing == checked
    elif expect == "none hidden":
        assert by_housing == 0
    else:
        assert 0 < by_housing < checked


# ------------------------------------------------------------- far-away polygons


def _square(centre, size, normal_axis=2) -> np.ndarray:
    """Axis-aligned square of side ``size`` (m) centred at ``centre``, normal along an axis."""
    h = 0.5 * size
    corners = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
    square = np.insert(corners, normal_axis, 0.0, axis=1)
    return square + np.asarray(centre, dtype=float)


def _answer(polygons, points, view):
    return BSPTree.build(PolygonSoup.from_polygons(polygons)).visibility(points, view)


@pytest.mark.parametrize("distance", [1e3, 1e6])
def test_far_polygon_does_not_make_a_point_behind_a_small_occluder_visible(distance) -> None:
    """A 1 cm occluder 1 m from the camera; points 0.5 mm, 0.01 mm and 1 um behind it stay
    hidden (and points as far in front stay visible) with a polygon 1 km or 1000 km away."""
    view = np.zeros(3)
    occluder = _square([0.0, 0.0, 1.0], 0.01)
    gaps = np.array([5e-4, 1e-5, 1e-6])
    points = np.concatenate([np.outer(1.0 + gaps, [0, 0, 1]), np.outer(1.0 - gaps, [0, 0, 1])])
    alone = _answer([occluder], points, view)
    np.testing.assert_array_equal(alone[0], [False] * 3 + [True] * 3)
    for far in (_square([distance, 0, 0], 1.0), _square([0, distance, -distance], 0.01, 0),
                _square([0, 0, -distance], 10.0)):
        visible, occluder_index = _answer([occluder, far], points, view)
        np.testing.assert_array_equal(visible, alone[0])
        np.testing.assert_array_equal(occluder_index, alone[1])


def _scene_and_far(seed: int, n_far: int):
    """A random scene (soup plus two solids, free points and solid vertices, a viewpoint) and
    ``n_far`` polygons far behind the viewpoint or beyond the farthest point (1 km to 1000 km
    away, 1 cm to 1/1000 of their distance wide): no segment can reach them."""
    rng = np.random.default_rng(seed)
    polygons, vertices = soup_and_solids(rng)
    # points just behind / in front of the soup polygons' centres: a plane tolerance grown by
    # a far polygon would take them for points on the polygon
    near = [p.mean(0) + sign * gap * np.cross(p[1] - p[0], p[2] - p[0])
            / np.linalg.norm(np.cross(p[1] - p[0], p[2] - p[0]))
            for p in polygons for sign in (-1, 1) for gap in (1e-4, 1e-5)]
    points = np.concatenate([rng.uniform(-1.5, 1.5, (30, 3)), np.array(near)] + vertices)
    view = rng.uniform(-3, 3, 3)
    far = []
    for _ in range(n_far):
        distance = 10 ** rng.uniform(3, 6)
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        if rng.random() < 0.5:  # behind the viewpoint, seen from the scene
            direction = view / np.linalg.norm(view) + 0.5 * direction
            direction /= np.linalg.norm(direction)
        size = distance * 10 ** rng.uniform(-5, -3)
        polygon = random_soup(rng, 1)[0]
        polygon = (polygon - polygon.mean(0)) * size + direction * distance
        far.append(polygon)
    return polygons, points, view, far


@pytest.mark.parametrize("seed", range(20))
def test_far_polygons_change_no_answer_on_random_scenes(seed) -> None:
    polygons, points, view, far = _scene_and_far(seed, 3)
    visible, occluder = _answer(polygons, points, view)
    with_far, occluder_far = _answer(polygons + far, points, view)
    np.testing.assert_array_equal(with_far, visible)
    np.testing.assert_array_equal(occluder_far, occluder)
    oracle = segment_oracle(polygons, points, view)
    keep = ~oracle.ambiguous
    np.testing.assert_array_equal(with_far[keep], oracle.visible[keep])


@settings(max_examples=40, deadline=None)
@given(st.integers(min_value=0, max_value=2**32 - 1), st.integers(min_value=1, max_value=6),
       st.booleans())
def test_adding_far_polygons_changes_nothing(seed, n_far, first) -> None:
    """Property: polygons far behind the viewpoint or beyond the farthest point, put before or
    after the others, change no visible flag and no occluder."""
    polygons, points, view, far = _scene_and_far(seed, n_far)
    visible, occluder = _answer(polygons, points, view)
    both = far + polygons if first else polygons + far
    with_far, occluder_far = _answer(both, points, view)
    np.testing.assert_array_equal(with_far, visible)
    shift = len(far) if first else 0
    np.testing.assert_array_equal(np.where(occluder_far >= 0, occluder_far - shift, -1), occluder)


# ------------------------------------------------------------- argument checks


@pytest.mark.parametrize("name", ["surface_tolerance", "near_px"])
@pytest.mark.parametrize("value", [float("nan"), -1e-3, float("inf"), "abc"])
def test_bad_tolerances_are_refused(cell, name, value) -> None:
    with pytest.raises(CellsightError, match=rf"{name} must be a finite number >= 0 .*"
                                             rf"got {value!r}".replace("(", r"\(")):
        visibility_predictor(cell, **{name: value})


def test_zero_tolerances_are_accepted(cell) -> None:
    predictor = visibility_predictor(cell, surface_tolerance=0, near_px=0.0)
    assert predictor.surface_tolerance == 0.0 and predictor.near_px == 0.0


def test_negative_or_nan_jaw_opening_is_refused(cell) -> None:
    """Checked by ``Cell.snapshot`` (it used to be clipped to 0 by ``Tool.jaw_poses``)."""
    predictor = visibility_predictor(cell)
    for bad in (-0.01, float("nan")):
        with pytest.raises(CellsightError, match=r"R7AX.*jaw opening"):
            predictor.predict(openings={"R7AX": bad})

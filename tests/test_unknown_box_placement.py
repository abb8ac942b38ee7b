"""The realism profiles' unknown box is never on the conveyor's path: wherever the seed puts
it, the part's footprint along the whole path (the polyline sampled every millimetre) keeps at
least ``PATH_CLEARANCE_M`` from the box's footprint (both outlines sampled every millimetre,
distances by a k-d tree), and so does the open gripper's reach around the path; a box drawn
clear of the path stays where it was drawn."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import ConvexHull, cKDTree

from cellsight import load_cell
from cellsight.geometry.transforms import transform_points
from cellsight.realism.unknown import PATH_CLEARANCE_M, table_box


def _outline(corners: np.ndarray, step: float = 1e-3) -> np.ndarray:
    """Points every ``step`` m along the closed polygon ``corners`` (k, 2)."""
    out = []
    for a, b in zip(corners, np.roll(corners, -1, axis=0), strict=True):
        n = max(int(np.ceil(np.linalg.norm(b - a) / step)), 1)
        out.append(a + np.linspace(0.0, 1.0, n, endpoint=False)[:, None] * (b - a))
    return np.vstack(out)


def _part_footprints(part, path: np.ndarray) -> np.ndarray:
    """The part's footprint outline (its convex hull in x, y) at every millimetre of the path
    from its start, translated (the conveyor does not turn the part)."""
    xy = transform_points(part.T_base_part, part.solid.vertices)[:, :2]
    hull = xy[ConvexHull(xy).vertices] - part.T_base_part[:2, 3]
    route = _outline(np.vstack([part.T_base_part[:2, 3], path, path[::-1]]))
    return (route[:, None, :] + _outline(hull)[None, :, :]).reshape(-1, 2)


CELL = load_cell()


@settings(max_examples=25, deadline=None)
@given(size=st.tuples(*[st.floats(0.05, 0.2)] * 3), camera=st.integers(0, 1),
       place=st.tuples(st.floats(0, 0.999), st.floats(0, 0.999)))
def test_the_box_keeps_clear_of_the_part_along_the_path(size, camera, place):
    part = CELL.workpieces[0]
    path = CELL.experiments.conveyor_points
    gripper = CELL.robot("R7AX").tool.reach_across()
    intruder = table_box(part, CELL.cameras[camera], np.array(size), np.array(place), path,
                         gripper)
    corners = transform_points(intruder.pose(0.0), intruder.solid.vertices)[:, :2]
    box = cKDTree(_outline(corners[ConvexHull(corners).vertices]))
    gap = box.query(_part_footprints(part, path))[0].min()
    assert gap >= PATH_CLEARANCE_M - 2e-3, gap
    route = _outline(np.vstack([part.T_base_part[:2, 3], path, path[::-1]]))
    assert box.query(route)[0].min() >= gripper + PATH_CLEARANCE_M - 2e-3


def test_a_box_clear_of_the_path_stays_where_drawn():
    part = CELL.workpieces[0]
    far = CELL.experiments.conveyor_points + [0.0, -5.0]  # the path moved 5 m away
    for place in ([0.2, 0.3], [0.9, 0.9]):
        drawn = table_box(part, CELL.cameras[0], np.full(3, 0.1), np.array(place))
        kept = table_box(part, CELL.cameras[0], np.full(3, 0.1), np.array(place), far[1:])
        np.testing.assert_array_equal(drawn.pose(0.0), kept.pose(0.0))


def test_the_grippers_reach_across_is_its_palms_corner():
    """The built-in gripper: a 8 x 15 cm palm centred on the TCP's axis, jaws 9 cm apart at
    most (each 3.5 x 1.2 cm): the palm's corner is the farthest, hypot(4, 7.5) cm."""
    assert CELL.robot("R7AX").tool.reach_across() == pytest.approx(np.hypot(0.04, 0.075))

"""Where a let-go part comes to rest (cellsight.model.landing), against the boxes of the
built-in cell's static objects read as boxes: under each vertex, the top of the highest box
whose footprint holds it and which lies below it, or less than ``PRESSED_M`` above it (a part
pressed into its support rests on its top)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsight import load_cell
from cellsight.geometry.transforms import pose_from_xyz_rpy, transform_points
from cellsight.model.landing import PRESSED_M, Landing

CELL = load_cell("dual-arm")
PART = CELL.workpieces[0]
LANDING = Landing(CELL.static)
BOXES = [(pts.min(axis=0), pts.max(axis=0))
         for obj in CELL.static for solid in obj.solids
         for pts in [transform_points(obj.T_base_obj, solid.vertices)]]


def _drop_on_boxes(vertices: np.ndarray) -> float | None:
    """How far the vertices (base frame) fall before one meets a box top; None: none below."""
    drops = []
    for v in vertices:
        for lo, hi in BOXES:
            if (np.all(lo[:2] <= v[:2]) and np.all(v[:2] <= hi[:2])
                    and hi[2] <= v[2] + PRESSED_M - 1e-9):
                drops.append(v[2] - hi[2])
    return min(drops) if drops else None


def test_the_built_in_cell_s_static_objects_are_boxes():
    """The oracle below reads each static solid as its bounding box: true for this cell."""
    for obj in CELL.static:
        for solid in obj.solids:
            pts = transform_points(obj.T_base_obj, solid.vertices)
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            assert len(pts) == 8 and np.all(np.isclose(pts, lo) | np.isclose(pts, hi))


@settings(max_examples=60, deadline=None)
@given(x=st.floats(-0.4, 1.9), y=st.floats(-0.7, 0.7), yaw=st.floats(-np.pi, np.pi),
       lift=st.floats(-0.015, 0.3))
def test_a_part_let_go_rests_on_the_highest_box_below_it(x, y, yaw, lift):
    T = pose_from_xyz_rpy([x, y, 0.62 + lift], [0.0, 0.0, yaw])
    rest = LANDING.rest_pose(PART.solid.vertices, T)
    drop = _drop_on_boxes(transform_points(T, PART.solid.vertices))
    if drop is None:
        assert rest is None
        return
    assert rest is not None
    np.testing.assert_allclose(rest[:3, :3], T[:3, :3])  # it falls without turning
    np.testing.assert_allclose(rest[:2, 3], T[:2, 3])
    assert abs((T[2, 3] - rest[2, 3]) - drop) < 1e-6

"""The kinematic prior's poses (cellsight.tracking.prior): where a gripper holds a part, decided
from joints and jaw openings alone, against poses built the other way round (the part placed
at the TCP times a grasp's inverse); and the prior's course through a grasp, against the cell
file's pose and a drop computed from the static boxes' tops."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsight import load_cell
from cellsight.geometry.transforms import invert_pose, pose_from_xyz_rpy, transform_points
from cellsight.model.grasp import HALF_TURN_Z, grasp_opening, grasp_pose
from cellsight.model.landing import Landing
from cellsight.tracking.prior import KinematicPrior, RecordedGrasp

CELL = load_cell("dual-arm")
PART = CELL.workpieces[0]
ROBOT = CELL.robot("R7AX")
GRASP = grasp_pose(PART)
OPENING = grasp_opening(PART.solid, ROBOT.tool, GRASP)
TOLERANCE = 0.005


def _recorded() -> RecordedGrasp:
    return RecordedGrasp(ROBOT, PART, GRASP, OPENING, TOLERANCE)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.booleans(), st.floats(-0.2, 0.2))
def test_the_part_is_held_where_the_tcp_and_the_nearer_grasp_put_it(seed, twin, tilt):
    """The part placed at the TCP times the inverse of the grasp or its twin; the tracker's
    estimate a few degrees and millimetres off that pose picks the same one."""
    q = ROBOT.chain.random_q(np.random.default_rng(seed))
    grasp = GRASP @ HALF_TURN_Z if twin else GRASP
    T_true = ROBOT.tcp_pose(q) @ invert_pose(grasp)
    estimate = T_true @ pose_from_xyz_rpy([0.003, -0.002, 0.001], [0.0, 0.0, tilt])
    held = _recorded().held_at(q, OPENING + 0.004, estimate)
    assert np.allclose(held, T_true, atol=1e-12)


def test_jaws_not_at_the_grasp_s_opening_hold_nothing_and_forget_the_grasp():
    grasp = _recorded()
    q = ROBOT.home
    for opening in (None, OPENING + 0.0051, OPENING - 0.0051, 0.0, ROBOT.tool.max_opening):
        assert grasp.held_at(q, opening, None) is None
        assert grasp.chosen is None
    twin = ROBOT.tcp_pose(q) @ invert_pose(GRASP @ HALF_TURN_Z)
    assert np.allclose(grasp.held_at(q, OPENING, twin), twin, atol=1e-12)
    assert grasp.held_at(q, 0.0, twin) is None and grasp.chosen is None
    # closed again: the grasp is chosen again, from the estimate then
    straight = ROBOT.tcp_pose(q) @ invert_pose(GRASP)
    assert np.allclose(grasp.held_at(q, OPENING, straight), straight, atol=1e-12)


def _table_top_under(T_base_part: np.ndarray) -> float:
    """The highest top of a static box below the part's vertices (the oracle of the drop)."""
    vertices = transform_points(T_base_part, PART.solid.vertices)
    tops = []
    for obj in CELL.static:
        for solid in obj.solids:
            pts = transform_points(obj.T_base_obj, solid.vertices)
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            below = [(np.all(lo[:2] <= v[:2]) and np.all(v[:2] <= hi[:2])) for v in vertices]
            if any(below) and hi[2] <= vertices[:, 2].min() + 1e-9:
                tops.append(hi[2])
    return max(tops)


def test_the_prior_lies_on_the_cell_file_pose_is_held_then_falls_onto_the_table():
    prior = KinematicPrior(PART, Landing(CELL.static))
    holders, supports = prior.update(None)
    assert holders is None and np.array_equal(supports[PART.name], PART.T_base_part)
    held = PART.T_base_part @ pose_from_xyz_rpy([0.0, 0.0, 0.05], [0.0, 0.0, 0.3])
    holders, supports = prior.update(held)
    assert supports is None and np.array_equal(holders[PART.name], held)
    holders, supports = prior.update(None)  # let go 5 cm up: it falls straight down
    rest = supports[PART.name]
    assert holders is None and np.array_equal(rest[:3, :3], held[:3, :3])
    assert np.allclose(rest[:2, 3], held[:2, 3])
    lowest = transform_points(rest, PART.solid.vertices)[:, 2].min()
    assert abs(lowest - _table_top_under(held)) < 1e-9
    assert np.array_equal(prior.update(None)[1][PART.name], rest)  # and stays there

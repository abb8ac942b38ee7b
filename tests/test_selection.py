"""Optimal feature selection: index formulas, constraints, spread, balance, exhaustive search."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsight.tracking import SelectionConfig, select_features, selection_quality


def _reference_indexes(px: np.ndarray, radius: float) -> tuple[float, float]:
    """Q_s and Q_a straight from their definitions (NumPy, complex exponentials of atan2)."""
    c = px.mean(axis=0)
    qs = min(1.0, np.mean(np.linalg.norm(px - c, axis=1)) / radius)
    theta = np.arctan2(px[:, 1] - c[1], px[:, 0] - c[0])
    m1, m2 = (abs(np.mean(np.exp(1j * k * theta))) for k in (1, 2))
    return qs, (1 - m1) * (1 - m2)


def _radius(px: np.ndarray) -> float:
    return float(np.max(np.linalg.norm(px - px.mean(axis=0), axis=1)))


def test_indexes_match_their_definitions():
    rng = np.random.default_rng(0)
    for _ in range(20):
        F = 10
        px = rng.uniform(0, 400, (2, F, 2))
        visible = np.ones((2, F), dtype=bool)
        sel = np.zeros((2, F), dtype=bool)
        sel[0, rng.choice(F, 5, replace=False)] = True
        sel[1, rng.choice(F, 4, replace=False)] = True
        rho = np.array([700.0, 500.0])
        J = selection_quality(px, visible, rho, sel, min_per_camera=4)
        w = rho / rho.sum()
        q = [np.prod(_reference_indexes(px[c][sel[c]], _radius(px[c]))) for c in range(2)]
        balance = 1 - np.sum(np.abs(sel.sum(axis=1) - 9 * w)) / 18
        assert J == pytest.approx(np.dot(w, q) * balance, abs=1e-12)


def test_angular_index_extremes():
    ring = np.column_stack([np.cos(np.arange(6) * np.pi / 3), np.sin(np.arange(6) * np.pi / 3)])
    arc = np.column_stack([np.cos(np.linspace(0, 0.2, 6)), np.sin(np.linspace(0, 0.2, 6))])
    line = np.column_stack([np.linspace(-1, 1, 6), 0.5 * np.linspace(-1, 1, 6)])
    px = 100 * np.stack([ring, arc, line]) + 300
    sel = select_features(px, np.ones((3, 6), bool), [1.0] * 3, SelectionConfig(18, 6))
    assert sel.angular[0] == pytest.approx(1.0, abs=1e-12)
    assert sel.angular[1] < 0.01 and sel.angular[2] < 1e-12
    assert sel.spread[0] == pytest.approx(1.0)


def test_spreads_the_points_to_the_outer_corners():
    grid = np.array([[u, v] for u in range(5) for v in range(5)], dtype=float) * 20 + 100
    px = grid[None]
    sel = select_features(px, np.ones((1, 25), bool), [1.0], SelectionConfig(4, 4))
    chosen = {tuple(p) for p in grid[sel.selected[0]]}
    assert chosen == {(100.0, 100.0), (100.0, 180.0), (180.0, 100.0), (180.0, 180.0)}


def test_balances_the_cameras_by_resolution():
    rng = np.random.default_rng(1)
    px = rng.uniform(0, 300, (2, 16, 2))
    vis = np.ones((2, 16), bool)
    equal = select_features(px, vis, [800.0, 800.0])
    assert equal.counts.sum() == 11 and abs(equal.counts[0] - equal.counts[1]) <= 1
    skewed = select_features(px, vis, [1500.0, 500.0], SelectionConfig(12, 3))
    assert skewed.counts[0] > skewed.counts[1] >= 3
    assert skewed.targets == pytest.approx([9.0, 3.0])


def _exhaustive(px, vis, rho, k, m_min):
    idx = [(c, f) for c in range(vis.shape[0]) for f in np.flatnonzero(vis[c])]
    best = -np.inf
    for comb in itertools.combinations(range(len(idx)), k):
        sel = np.zeros(vis.shape, dtype=bool)
        for q in comb:
            sel[idx[q]] = True
        best = max(best, selection_quality(px, vis, rho, sel, m_min))
    return best


@pytest.mark.parametrize("seed", range(12))
def test_matches_exhaustive_search_on_small_cases(seed):
    rng = np.random.default_rng(seed)
    F = 8
    px = rng.uniform(0, 300, (2, F, 2))
    vis = rng.random((2, F)) < 0.9
    rho = rng.uniform(300, 900, 2)
    sel = select_features(px, vis, rho, SelectionConfig(max_points=7, min_per_camera=3))
    best = _exhaustive(px, vis, rho, 7, 3)
    assert sel.quality == pytest.approx(best, abs=1e-9)
    assert selection_quality(px, vis, rho, sel.selected, 3) == pytest.approx(sel.quality, abs=1e-9)


def test_matches_exhaustive_search_with_three_cameras():
    rng = np.random.default_rng(7)
    px = rng.uniform(0, 300, (3, 5, 2))
    vis = np.ones((3, 5), bool)
    vis[2, 2:] = False  # camera 2 is not eligible (3 points < 4)
    rho = np.array([900.0, 400.0, 800.0])
    strict = SelectionConfig(max_points=8, min_per_camera=4, few_point_cameras=False)
    sel = select_features(px, vis, rho, strict)
    assert sel.counts[2] == 0
    assert sel.quality == pytest.approx(_exhaustive(px, vis, rho, 8, 4), abs=1e-9)


def test_a_camera_with_few_points_gives_all_of_them():
    """Camera 2 sees 2 points (< 4): both are selected, and the other 8 of the budget of 10 are
    the exhaustive optimum over cameras 0 and 1."""
    rng = np.random.default_rng(7)
    px = rng.uniform(0, 300, (3, 5, 2))
    vis = np.ones((3, 5), bool)
    vis[2, 2:] = False
    rho = np.array([900.0, 400.0, 800.0])
    sel = select_features(px, vis, rho, SelectionConfig(max_points=10, min_per_camera=4))
    assert sel.selected[2].tolist() == [True, True, False, False, False]
    assert sel.counts.sum() == 10 and not sel.fallback
    others = vis.copy()
    others[2] = False
    assert selection_quality(px, others, rho, sel.selected & others, 4) == pytest.approx(
        _exhaustive(px, others, rho, 8, 4), abs=1e-9)


def test_a_count_the_cameras_cannot_split_is_lowered():
    """5 + 5 visible points cannot give 6 with at least 4 per camera: 5 from one camera."""
    rng = np.random.default_rng(3)
    px = rng.uniform(0, 300, (2, 5, 2))
    sel = select_features(px, np.ones((2, 5), bool), [900.0, 400.0], SelectionConfig(6, 4))
    assert sorted(sel.counts.tolist()) == [0, 5] and sel.quality > 0


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    max_points=st.integers(4, 14),
    m_min=st.integers(1, 4),
    p_visible=st.floats(0.1, 1.0),
)
def test_respects_maximum_minimum_and_visibility(seed, max_points, m_min, p_visible):
    rng = np.random.default_rng(seed)
    C, F = 2, 16
    px = rng.uniform(0, 700, (C, F, 2))
    vis = rng.random((C, F)) < p_visible
    sel = select_features(px, vis, rng.uniform(100, 1000, C), SelectionConfig(max_points, m_min))
    assert not np.any(sel.selected & ~vis)
    assert sel.counts.sum() <= max_points
    n_visible = vis.sum(axis=1)
    eligible = n_visible >= m_min
    budget = max_points - n_visible[~eligible].sum()
    if eligible.any() and budget >= m_min:
        assert not sel.fallback
        assert np.all(sel.counts[~eligible] == n_visible[~eligible])  # few-point cameras: all
        assert np.all((sel.counts[eligible] == 0) | (sel.counts[eligible] >= m_min))
        assert sel.counts[eligible].sum() >= min(budget, n_visible[eligible].sum()) - m_min + 1
    elif eligible.any():  # no room for the few-point cameras: as if they saw nothing
        assert not sel.fallback and np.all(sel.counts[~eligible] == 0)
    else:
        assert sel.fallback and sel.counts.sum() == min(max_points, vis.sum())


def test_nothing_visible_selects_nothing():
    sel = select_features(np.zeros((2, 16, 2)), np.zeros((2, 16), bool), [1.0, 1.0])
    assert sel.counts.sum() == 0 and sel.fallback

"""Windows: size from the innovation covariance, clamps, conflicts, merging, grabbed fraction."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from cellsight.tracking import WindowConfig, plan_windows

W, H = 768, 576


def _pixels_in(box) -> tuple[np.ndarray, np.ndarray]:
    """Centres of the pixels a box grabs (columns, rows)."""
    return np.arange(box[0], box[2]), np.arange(box[1], box[3])


def _segment_hits_box(seg: np.ndarray, box, margin: float = 0.0) -> bool:
    """Dense sampling of a segment against the box's pixel-centre extent (independent check)."""
    t = np.linspace(0, 1, 2001)[:, None]
    p = seg[0] + t * (seg[1] - seg[0])
    u0, v0, u1, v1 = box[0] - margin, box[1] - margin, box[2] - 1 + margin, box[3] - 1 + margin
    return bool(np.any((p[:, 0] >= u0) & (p[:, 0] <= u1) & (p[:, 1] >= v0) & (p[:, 1] <= v1)))


def test_size_is_the_three_sigma_box_plus_support_within_clamps():
    cfg = WindowConfig(k_sigma=3.0, support_px=6.0, min_size_px=16, max_size_px=64)
    centres = np.array([[200.0, 200.0], [400.0, 300.0], [600.0, 100.0]])
    S = np.array([np.diag([2.0**2, 4.0**2]), np.diag([0.1, 0.1]), np.diag([30.0**2, 1.0])])
    plan = plan_windows(centres, [0, 1, 2], S, W, H, config=cfg)
    widths = plan.boxes[:, 2] - plan.boxes[:, 0]
    heights = plan.boxes[:, 3] - plan.boxes[:, 1]
    # window 0: half-widths 3*2+6 = 12 and 3*4+6 = 18 px -> 25 x 37 pixel centres
    assert (widths[0], heights[0]) == (25, 37)
    assert (widths[1], heights[1]) == (17, 17)  # clamped up to 16 px
    assert (widths[2], heights[2]) == (65, 19)  # clamped down to 64 px
    for box, c in zip(plan.boxes, centres, strict=True):
        us, vs = _pixels_in(box)
        assert abs(us.mean() - c[0]) <= 0.5 and abs(vs.mean() - c[1]) <= 0.5
    assert not plan.shrunk.any() and len(plan.dropped) == 0


def test_clipped_to_the_image_or_dropped_at_the_border():
    cfg = WindowConfig(support_px=6.0)
    centres = np.array([[10.0, 300.0], [3.0, 300.0], [760.0, 570.0]])
    plan = plan_windows(centres, [0, 1, 2], np.tile(25 * np.eye(2), (3, 1, 1)), W, H, config=cfg)
    assert list(plan.features) == [0]
    assert plan.boxes[0, 0] == 0 and plan.boxes[0, 2] == 10 + 22
    assert set(plan.dropped) == {1, 2}


def test_another_feature_inside_shrinks_the_window_or_drops_the_point():
    cfg = WindowConfig(support_px=6.0, margin_px=2.0)
    centres = np.array([[300.0, 300.0], [500.0, 300.0]])
    others = np.array([[300.0, 300.0], [315.0, 304.0], [500.0, 300.0], [503.0, 302.0]])
    S = np.tile(64 * np.eye(2), (2, 1, 1))
    plan = plan_windows(centres, [0, 1], S, W, H, others, own=[0, 2], config=cfg)
    assert list(plan.features) == [0] and list(plan.dropped) == [1]
    box = plan.boxes[0]
    assert plan.shrunk[0]
    assert not _segment_hits_box(np.array([others[1], others[1]]), box, margin=cfg.margin_px - 1e-9)
    assert box[0] <= 294 and box[2] - 1 >= 306 and box[1] <= 294 and box[3] - 1 >= 306


def test_overlapping_windows_merge_when_cheaper_and_fraction_counts_grabbed_pixels():
    cfg = WindowConfig(support_px=6.0, region_overhead_px=64.0, margin_px=0.0)
    S = np.tile(64 * np.eye(2), (3, 1, 1))
    centres = np.array([[300.0, 300.0], [306.0, 302.0], [600.0, 100.0]])
    plan = plan_windows(centres, [0, 1, 2], S, W, H, config=cfg)
    assert len(plan.regions) == 2
    assert plan.region_of[0] == plan.region_of[1] != plan.region_of[2]
    merged = plan.regions[plan.region_of[0]]
    area = lambda b: (b[2] - b[0]) * (b[3] - b[1])  # noqa: E731
    assert area(merged) + 64 < area(plan.boxes[0]) + area(plan.boxes[1]) + 128
    assert plan.grabbed_px == sum(area(r) for r in plan.regions)
    assert plan.fraction == plan.grabbed_px / (W * H)
    for w, r in enumerate(plan.region_of):  # every window lies inside its region
        b, g = plan.boxes[w], plan.regions[r]
        assert g[0] <= b[0] and g[1] <= b[1] and b[2] <= g[2] and b[3] <= g[3]
    apart = plan_windows(centres[[0, 2]], [0, 2], S[:2], W, H, config=cfg)
    assert len(apart.regions) == 2


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 100_000))
def test_kept_windows_hold_their_feature_and_no_intruder(seed):
    rng = np.random.default_rng(seed)
    cfg = WindowConfig(support_px=6.0, margin_px=2.0)
    pts = rng.uniform(100, 250, (10, 2))
    sel = rng.choice(10, 6, replace=False)
    S = np.stack([np.diag(rng.uniform(1, 60, 2)) for _ in sel])
    plan = plan_windows(pts[sel], sel, S, W, H, pts, own=sel, config=cfg)
    assert len(plan.features) + len(plan.dropped) == len(sel)
    for f, box in zip(plan.features, plan.boxes, strict=True):
        lo, hi = np.ceil(pts[f] - 6), np.floor(pts[f] + 6)  # pixel centres of the keep box
        assert box[0] <= lo[0] and box[2] - 1 >= hi[0]
        assert box[1] <= lo[1] and box[3] - 1 >= hi[1]
        for g in range(10):
            if g != f:
                assert not _segment_hits_box(np.array([pts[g], pts[g]]), box)

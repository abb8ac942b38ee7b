"""A custom part plugged into the tracker: the selector of docs/guides/your-cameras.md ("Plug
in your own selector"), its code block run as it stands, on the built-in cell's world images."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from cellsight.rates import VISION_HZ
from cellsight.tracking import OptimalSelector, Selection, TrackerParts
from cellsight.world import World

PAGE = Path(__file__).resolve().parent.parent / "docs/guides/your-cameras.md"


def _page_block(marker: str) -> str:
    """The first ``python`` code block after ``marker`` in docs/guides/your-cameras.md."""
    text = PAGE.read_text()
    start = text.index(marker)
    match = re.compile(r"```python\n(.*?)```", re.DOTALL).search(text, start)
    assert match is not None, f"no python block after {marker!r} in {PAGE}"
    return match.group(1)


def test_the_readme_selector_chooses_what_is_windowed_and_measured() -> None:
    namespace: dict = {}
    exec(_page_block("<!-- test: tests/test_custom_parts.py -->"), namespace)
    tracker, chooser = namespace["tracker"], namespace["FarthestPerCamera"](4)
    cell = namespace["cell"]
    part = cell.workpieces[0]
    world = World(cell, seed=0)
    records = []
    try:
        for k in range(6):
            t = k / VISION_HZ
            while world.time < t - 1e-9:
                world.step({}, {})
            records.append(tracker.step(world.render(), world.measured_joints(), t)
                           .parts[part.name])
    finally:
        world.close()
    assert records[0].status == "acquired"
    for rec in records[1:]:
        assert rec.status_text.startswith("degraded: acquired")  # tracked, still tentative
        usable = rec.visible & ~rec.near_occluder
        expected = chooser.select(rec.pixels, usable, np.ones(len(cell.cameras))).selected
        assert np.array_equal(rec.selected, expected)
        assert np.all(rec.selected.sum(axis=1) == 4)  # the default takes 11 in all
        assert np.isnan(rec.selection.quality)
        for c, plan in enumerate(rec.windows):
            assert set(plan.features.tolist()) <= set(np.flatnonzero(expected[c]).tolist())
        measured = np.isfinite(rec.measured[:, :, 0])
        assert np.all(measured <= expected) and measured.sum() >= 6


def test_a_custom_selection_is_a_plain_mask_and_the_default_is_the_optimal_selector() -> None:
    mask = np.array([[True, False, True], [False, False, False]])
    sel = Selection.of(mask)
    assert np.array_equal(sel.selected, mask) and sel.counts.tolist() == [2, 0]
    assert np.isnan(sel.quality) and not sel.fallback
    assert isinstance(TrackerParts().selector, OptimalSelector)

"""Stage timing of one tracker step: one wrapper instead of a stopwatch in every method."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

STAGES = ("occlusion", "selection", "windowing", "extraction", "ekf", "total")
"""The stages of one :meth:`~cellsight.tracking.Tracker.step` (``extraction``: in the windows,
and the whole-image search of a part being acquired, :mod:`.search`; ``ekf``: prediction +
update; ``total``: the whole step), in the order of the paper's Fig. 5."""


class StageTimer:
    """Accumulates wall-clock seconds per stage; ``with timer("selection"): ...``."""

    def __init__(self) -> None:
        self.seconds = dict.fromkeys(STAGES, 0.0)

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        if stage not in self.seconds:
            raise KeyError(f"unknown tracker stage {stage!r}; stages: {', '.join(STAGES)}")
        tic = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] += time.perf_counter() - tic

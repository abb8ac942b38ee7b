"""Stage timing of one tracker step: one wrapper instead of a stopwatch in every method."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

STAGES = ("occlusion", "selection", "windowing", "extraction", "ekf", "total", "grab")
"""The stages of one :meth:`~cellsight.tracking.Tracker.step`, in the order of the paper's
Fig. 5 (``extraction``: in the windows, and the whole-image search of a part being acquired,
:mod:`.search`; ``ekf``: prediction + update; ``total``: the whole step), then ``grab``: the
cameras' reading of the windows, or of whole images, where they are read on demand
(:mod:`.grabbing`). ``grab`` is the camera's time, not the tracker's: it counts in no other
stage, ``total`` included (a simulated camera renders then)."""


class StageTimer:
    """Accumulates wall-clock seconds per stage; ``with timer("selection"): ...``. The time of
    a ``grab`` inside another stage is not that stage's (:data:`STAGES`)."""

    def __init__(self) -> None:
        self.seconds = dict.fromkeys(STAGES, 0.0)

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        if stage not in self.seconds:
            raise KeyError(f"unknown tracker stage {stage!r}; stages: {', '.join(STAGES)}")
        grabbed, tic = self.seconds["grab"], time.perf_counter()
        try:
            yield
        finally:
            elapsed = time.perf_counter() - tic
            self.seconds[stage] += elapsed - (self.seconds["grab"] - grabbed) * (stage != "grab")

"""The simulated run's picture sinks: the key frames and ``views.mp4``
(:mod:`cellsight.session.protocols`). Both draw the truth's visibility beside the estimate, so
they need a source that knows the part's true pose."""

from __future__ import annotations

from contextlib import suppress

import numpy as np

from cellsight.experiments.keyframes import KeyFrames, draw_frame
from cellsight.experiments.views_video import ViewsVideo
from cellsight.rates import VISION_HZ
from cellsight.runfolder.writes import RunWrites, WriteError
from cellsight.session.frames import FrameRecord
from cellsight.session.protocols import RunContext
from cellsight.tracking.grabbing import grabbed


class KeyFramesSink:
    """``keyframes.json`` and ``keyframes/*.png`` (:class:`~.keyframes.KeyFrames`): the frames
    worth a picture. A picture that cannot be written is recorded; the run goes on.
    ``crossing``: the robot that crosses the views (None: none)."""

    def __init__(self, crossing: str | None) -> None:
        self.crossing = crossing
        self.keys: KeyFrames | None = None

    def start(self, run: RunContext) -> None:
        self.run = run
        with run.writes.guard(run.out / "keyframes"):
            self.keys = KeyFrames(run.out, [c.name for c in run.cell.cameras], run.robot.name,
                                  self.crossing)

    def frame(self, record: FrameRecord) -> None:
        run = self.run

        def draw(caption: str) -> np.ndarray:
            return draw_frame([grabbed(o) for o in record.shown()], record.result,
                              record.part.name, record.frame.truth.part.visible, run.cell.cameras,
                              caption, 1.0)

        with suppress(WriteError), run.writes.guard(run.out / "keyframes.json"):
            self.keys.offer_frame(record.t, record.phase, record.part, draw)

    def close(self, completed: bool) -> None:
        """Nothing to finish: each picture is written when it is the best so far."""


class VideoSink:
    """``views.mp4`` (:class:`~.views_video.ViewsVideo`): a frame every ``every`` vision
    frames."""

    def __init__(self, every: int) -> None:
        self.every = every
        self.video: ViewsVideo | None = None
        self.writes: RunWrites | None = None

    def start(self, run: RunContext) -> None:
        self.writes = run.writes
        self.video = ViewsVideo(run.out / "views.mp4", VISION_HZ / self.every, run.cell.cameras)

    def frame(self, record: FrameRecord) -> None:
        if record.frame.k % self.every:
            return
        caption = (f"t = {record.t:5.2f} s   {record.phase}   tracker: "
                   f"{record.part.status_text}")
        with self.writes.guard(self.video.path):
            self.video.add(record.shown(), record.result, record.part.name,
                           record.frame.truth.part.visible, caption)

    def close(self, completed: bool) -> None:
        self.writes.close(self.video.path, self.video.close)
